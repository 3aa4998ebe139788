"""Inputs are never outputs: what each command reads, and the checks made before anything is written.

Every command names its inputs before it reads them:

- plain input files (a library, an NMEA file, a site.toml);
- the files a walk reads (:func:`walk_files`: ``walk.toml``, the stream files it names, ``truth.csv``,
  the site it names);
- *sealed* directories, whose whole content is input and inside which nothing is ever written: a model
  bundle (``bundle.json`` and its array files), a survey's ``cells/`` folder.

:func:`check_outputs` then refuses (:class:`~pipeline.args.UsageError`, exit status 2), before anything is
read, an output that is an input, lies inside a sealed directory, or — for a directory output, which may be
replaced — holds an input or is the current directory or one above it; and two outputs naming one file.

``--overwrite`` / ``--force`` replace an existing directory only when it holds nothing but what the same
command writes (:func:`check_replaceable`, by :func:`directory_kind`): a model folder is replaced only by a
model of its kind, a walk only by a walk; never a survey, a library's folder or ``.``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from pipeline.args import UsageError

__all__ = ["check_outputs", "check_replaceable", "directory_kind", "walk_files", "survey_inputs", "model_inputs",
           "refuse_repeated", "shipped_or_directory", "plural", "check_writable", "KINDS"]

_HIDDEN = re.compile(r"^\.")

KINDS = {
    "environment model": (re.compile(r"^(bundle\.json|[A-Za-z0-9_-]+\.safetensors)$"), "bundle.json"),
    "fusion model": (re.compile(r"^(bundle\.json|[A-Za-z0-9_-]+\.safetensors)$"), "bundle.json"),
    "walk": (re.compile(r"^(walk\.toml|gnss\.nmea|audio\.wav|imu\.csv|truth\.csv|audio_truth\.csv|truth_steps\.csv"
                        r"|uwb\.csv|imu_foot\.csv|sources\.(png|pdf|svg))$"), "walk.toml"),
    "survey": (re.compile(r"^(site\.toml|site\.png|survey\.toml|cells)$"), "cells"),
    "site": (re.compile(r"^(site\.toml|site\.png)$"), "site.toml"),
    "report": (re.compile(r"^(metrics\.csv|[A-Za-z0-9_.+-]+\.png)$"), None),
    "benchmark": (re.compile(r"^(data|fingerprints\.sqlite(-wal|-shm|-journal)?|env_model|fusion_model|report)$"),
                  "data"),
}
"""What each kind of output directory may hold (non-hidden entries) and the entry that marks it (None:
any of its entries)."""


def _real(p) -> Path:
    return Path(os.path.realpath(p))


def _inside(child, parent) -> bool:
    """``child`` is ``parent`` or lies below it (symbolic links resolved)."""
    c, p = _real(child), _real(parent)
    return c == p or p in c.parents


def _same(a, b) -> bool:
    from features.fileio import same_file

    return same_file(a, b)


def directory_kind(path: str | os.PathLike) -> str | None:
    """What an existing directory holds: ``"empty"``, one of :data:`KINDS`, or None (anything else).

    A model folder is told by its ``bundle.json`` (``kind`` ``environment`` or ``fusion``); the other kinds by
    their marker entry and by holding nothing a command of that kind does not write. Hidden entries
    (temporaries, ``.DS_Store``) are ignored.
    """
    import json

    path = Path(path)
    try:
        names = [e.name for e in path.iterdir() if not _HIDDEN.match(e.name)]
    except OSError:
        return None
    if not names:
        return "empty"
    if "bundle.json" in names:
        try:
            kind = json.loads((path / "bundle.json").read_text()).get("kind")
        except (OSError, ValueError, AttributeError):
            return None
        label = f"{kind} model"
        pattern = KINDS.get(label, (None,))[0]
        return label if pattern is not None and all(pattern.match(n) for n in names) else None
    for label, (pattern, marker) in KINDS.items():
        if label.endswith("model"):
            continue
        if (marker is None or marker in names) and all(pattern.match(n) for n in names):
            return label
    return None


def check_replaceable(path: str | os.PathLike, kind: str, option: str = "--out", flag: str = "--overwrite") -> None:
    """Refuse (exit 2) to replace ``path`` unless it is absent, an empty directory or a directory of ``kind``.

    Never the current directory or one above it, whatever it holds.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return
    if _inside(Path.cwd(), path):
        raise UsageError(f"{option} {path} is the current directory or holds it: {flag} never replaces it; "
                         "name a new directory")
    if not path.is_dir():
        raise UsageError(f"{option} {path} exists and is not a directory: {flag} replaces only a {kind} folder")
    found = directory_kind(path)
    if found not in ("empty", kind):
        what = f"a {found}" if found else "other files"
        raise UsageError(f"{option} {path} holds {what}, not a {kind}: {flag} replaces only a {kind} folder "
                         "(nothing else is ever deleted); name a new directory")


def walk_files(walk_dir: str | os.PathLike, label: str = "WALK") -> dict:
    """The files a walk is read from, keyed by a label naming them: ``walk.toml`` (or ``cell.toml``), every
    stream file it names (present or not), ``truth.csv`` and the site file it names."""
    walk_dir = Path(walk_dir)
    out = {}
    for name in ("walk.toml", "cell.toml", "truth.csv", "gnss.nmea", "audio.wav", "imu.csv"):
        out[f"{label}'s {name}"] = walk_dir / name
    try:
        from features.fileio import read_toml

        doc = read_toml(walk_dir / "walk.toml") if (walk_dir / "walk.toml").is_file() else {}
    except Exception:  # noqa: BLE001 - a malformed walk.toml is reported by the reader, not here
        doc = {}
    for stream in ("gnss", "audio", "imu"):
        table = doc.get(stream)
        if isinstance(table, dict) and isinstance(table.get("file"), str):
            out[f"{label}'s {stream} file {table['file']}"] = walk_dir / table["file"]
    if isinstance(doc.get("site"), str):
        site = walk_dir / doc["site"]
        site = site / "site.toml" if site.is_dir() else site
        out[f"{label}'s site"] = site
    return out


def survey_inputs(survey_dir: str | os.PathLike, label: str = "SURVEY_DIR") -> tuple[dict, dict]:
    """(files, sealed directories) of a survey: its ``site.toml`` and its ``cells/`` folder."""
    survey_dir = Path(survey_dir)
    return {f"{label}'s site.toml": survey_dir / "site.toml"}, {f"{label}'s cells/": survey_dir / "cells"}


def model_inputs(model_dir: str | os.PathLike, label: str) -> dict:
    """The sealed directory of a model bundle (every file in it is input)."""
    return {label: Path(model_dir)}


def shipped_or_directory(spec, option: str) -> Path | None:
    """None when ``spec`` names the environment model shipped in envfuse (the word ``default``), else the model
    directory it names (:func:`training.default_env.names_shipped_model`). A file or folder called ``default``
    in the working directory is read as the model folder the user may mean (as before the shipped model
    existed) and said on stderr, so that neither reading is silent."""
    import sys

    from training.default_env import DEFAULT, names_shipped_model

    if names_shipped_model(spec):
        return None
    if str(spec) != DEFAULT:
        return Path(spec)
    print(f"envfuse: note: {option} default: ./{DEFAULT} exists in the working directory and is read as the model "
          f"folder it names, not as the model shipped in envfuse; to use the shipped one, run from another "
          f"directory or rename ./{DEFAULT}", file=sys.stderr)
    return Path(DEFAULT)


def check_writable(path: str | os.PathLike, option: str) -> None:
    """Refuse (:class:`~features.errors.EnvfuseError`, exit 1) an output whose folder cannot be written, before
    the work that would fill it: a temporary entry is made and removed in its nearest existing folder (a
    permission test by ``os.access`` says yes to root on a read-only or immutable folder; trying does not)."""
    import tempfile

    from features.errors import EnvfuseError

    parent = Path(os.path.abspath(path)).parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    try:
        probe = tempfile.mkdtemp(prefix=".envfuse-write-test.", dir=parent)
    except OSError as exc:
        raise EnvfuseError(f"cannot write {option} {path}: {parent}: {exc.strerror or exc}") from None
    os.rmdir(probe)


def plural(n: int, noun: str) -> str:
    """``"1 cell"``, ``"3 cells"``."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


def refuse_repeated(paths, option: str) -> None:
    """Refuse (exit 2) a directory given twice (by any spelling): it would count twice."""
    seen = []
    for p in paths:
        for q in seen:
            if _same(p, q):
                raise UsageError(f"{option}: {p} is given twice (as {q}); each walk counts once")
        seen.append(p)


def check_outputs(inputs: dict, outputs: dict, directory_outputs: dict | None = None,
                  sealed: dict | None = None) -> None:
    """Refuse an output that would overwrite or delete an input, or two outputs naming one file (exit 2).

    ``inputs`` (files), ``outputs`` (files), ``directory_outputs`` and ``sealed`` (input directories whose
    whole content is input) map the option the user wrote (``"--out"``, ``"NMEA"``) to a path or None;
    ``-`` (standard output) never clashes.

    - a file output may not be an input file, nor lie inside a sealed directory;
    - a directory output may not be or hold an input or a sealed directory, nor lie inside a sealed
      directory, nor be the current directory or one above it.
    """
    from features.fileio import is_stdout

    def clean(d):
        return {k: Path(v) for k, v in (d or {}).items() if v is not None and not is_stdout(v)}

    ins, outs, dirs, seal = clean(inputs), clean(outputs), clean(directory_outputs), clean(sealed)
    for ko, o in outs.items():
        for ki, i in ins.items():
            if _same(o, i):
                raise UsageError(f"{ko} {o} is the input {ki}: an output never overwrites an input")
        if o.is_dir():
            raise UsageError(f"{ko} {o} is a directory; name a file")
        for ks, s in seal.items():
            if _inside(o, s):
                raise UsageError(f"{ko} {o} lies inside the input {ks} ({s}): nothing is ever written there")
    names = list(outs.items()) + list(dirs.items())
    for n, (ka, a) in enumerate(names):
        for kb, b in names[n + 1:]:
            if _same(a, b):
                raise UsageError(f"{ka} and {kb} name the same file {a}")
    for ko, d in dirs.items():
        if _inside(Path.cwd(), d):
            raise UsageError(f"{ko} {d} is the current directory or holds it: an output directory is created or "
                             "replaced whole; name a new directory")
        for ki, i in list(ins.items()) + list(seal.items()):
            if _inside(i, d):
                raise UsageError(f"{ko} {d} holds the input {ki} ({i}): an output never replaces an input")
        for ks, s in seal.items():
            if _inside(d, s):
                raise UsageError(f"{ko} {d} lies inside the input {ks} ({s}): nothing is ever written there")
