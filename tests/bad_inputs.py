"""A corpus of bad inputs through every command, and how each outcome is judged (issue 20).

Each :class:`Case` builds its inputs in a private copy of a small *world* (a site, three short walks cut
from a simulated one, a synthetic fingerprint library, an environment and a fusion model, a three-cell
survey; :func:`build_world`), runs one ``envfuse`` command on them and is judged (:func:`judge`):

``data lost``       a file that existed before the command (inputs, models, libraries, other reports) is
                    changed or gone, beyond what the case names as its own output;
``internal error``  exit status 3 (or any other than 0, 1, 2), a traceback or "internal error" on stderr;
``silent wrong``    a bad input accepted (exit 0 where 1 or 2 is due), or an accepted run whose result is
                    wrong or unexplained (the case's own check: a stale plot left, NaN metrics, no note);
``unclear``         the right refusal but not one clear line: another exit status (1 for 2), the message
                    not naming the problem, or a library's raw warning on stderr;
``clean``           none of the above.

The same corpus runs in-process as a test (``tests/test_bad_inputs.py``) and, through
``bench/bad_inputs.py``, as a subprocess per case against any source tree (the before → after table).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["Case", "World", "build_world", "cases", "prepare", "judge", "run_inprocess", "Outcome", "KINDS"]

KINDS = ("clean", "internal error", "silent wrong", "data lost", "unclear")


# ---------------------------------------------------------------------------------------------- world


@dataclass(frozen=True)
class World:
    """Paths of the world in one directory ``root`` (every case gets its own copy)."""

    root: Path

    def __getattr__(self, name):
        where = {"site": "site", "w": "walks/w", "w2": "walks/w2", "wa": "walks/wa", "walks": "walks",
                 "lib": "lib.sqlite", "env": "env", "fm": "fm", "survey": "survey"}
        if name in where:
            return self.root / where[name]
        raise AttributeError(name)


def _cut_nmea(text: str, t0_s: float, t1_s: float) -> str:
    """NMEA lines of the epochs whose RMC time lies in [t0_s, t1_s) seconds after the first epoch."""
    out, keep, first = [], False, None
    for line in text.splitlines(keepends=True):
        if line[3:6] == "RMC":
            hhmmss = line.split(",")[1]
            t = int(hhmmss[:2]) * 3600 + int(hhmmss[2:4]) * 60 + float(hhmmss[4:])
            first = t if first is None else first
            keep = t0_s <= t - first < t1_s
        if keep:
            out.append(line)
    return "".join(out)


def _trim_walk(src: Path, dst: Path, duration_s: float, site_rel: str, audio: bool) -> None:
    """The first ``duration_s`` of walk ``src`` as a walk in ``dst`` (with or without its audio)."""
    import soundfile as sf
    import tomli_w

    from features.fileio import read_toml

    dst.mkdir(parents=True)
    doc = read_toml(src / "walk.toml")
    doc["site"] = site_rel
    doc["duration_s"] = float(duration_s)
    doc["name"] = dst.name
    (dst / "gnss.nmea").write_text(_cut_nmea((src / "gnss.nmea").read_text(), 0.0, duration_s))
    lines = (src / "imu.csv").read_text().splitlines(keepends=True)
    (dst / "imu.csv").write_text(lines[0] + "".join(r for r in lines[1:] if float(r.split(",", 1)[0]) < duration_s))
    lines = (src / "truth.csv").read_text().splitlines(keepends=True)
    (dst / "truth.csv").write_text(lines[0] + "".join(r for r in lines[1:] if float(r.split(",", 1)[0]) <= duration_s))
    if audio:
        data, fs = sf.read(src / "audio.wav", dtype="int16", frames=int(duration_s * 48000))
        sf.write(dst / "audio.wav", data, fs, subtype="PCM_16")
    else:
        doc.pop("audio", None)
    (dst / "walk.toml").write_text(tomli_w.dumps(doc))


def _synthetic_library(path: Path, site, site_toml: Path, n_cells: int = 40, per_cell: int = 3, seed: int = 0,
                       window_s: float = 2.0, classes=None) -> None:
    """A library of ``n_cells`` cells of ``per_cell`` windows with the synthetic features of
    :mod:`tests.env_synth` (class by cell), labelled, for ``site``."""
    from features.fileio import sha256_file
    from features.gnss.features import Cn0Reference
    from fingerprints.library import CellCapture, FingerprintLibrary
    from fingerprints.sql import FEATURES
    from models.embedding import ENV_FEATURES
    from tests.env_synth import _MODEL, CLASSES

    rng = np.random.default_rng(seed)
    y_cell = rng.choice(3, size=n_cells, p=(0.5, 0.3, 0.2)) if classes is None else np.asarray(classes)
    # each cell's windows drawn for its class, as tests.env_synth draws them
    X = np.empty((n_cells * per_cell, len(ENV_FEATURES)))
    for i in range(n_cells * per_cell):
        c = y_cell[i // per_cell]
        for j, name in enumerate(ENV_FEATURES):
            base, step, sd = _MODEL[name]
            X[i, j] = base + step * c + rng.normal(0.0, sd)
    col = {name: j for j, name in enumerate(ENV_FEATURES)}
    params = {"window_s": window_s, "hop_s": 1.0, "receiver": "default", "cn0_reference": Cn0Reference().to_dict()}
    with FingerprintLibrary.open(path) as lib:
        o = site.origin
        lib.add_site(site.name, lat_deg=o.lat_deg, lon_deg=o.lon_deg, alt_m=o.alt_m,
                     site_toml_sha256=sha256_file(site_toml))
        lib.add_receiver(site.name, "default", Cn0Reference().to_dict(), calibrated=True)
        g = site.grid
        for k in range(n_cells):
            e = g.east_min_m + 10.0 * (k % 12) + 5.0
            n = g.north_min_m + 10.0 * (k // 12) + 5.0
            cap = CellCapture(f"C{k:03d}", e, n, "2026-06-01T08:00:00Z", 3.0 + window_s, CLASSES[y_cell[k]],
                              [0.05, 0.25, 0.6][y_cell[k]], (), "", f"{k:064x}", None, dict(params))
            rows = {"t_s": [window_s / 2 + i for i in range(per_cell)], "gnss_available": [1] * per_cell,
                    "acoustic_available": [1] * per_cell}
            for name in FEATURES:
                rows[name] = [float(X[k * per_cell + i, col[name]]) for i in range(per_cell)]
            lib.ingest_cell(site.name, cap, rows, receiver="default")


def build_world(root: Path, site_dir: Path, walk_dir: Path) -> World:
    """The shared world in ``root`` from a simulated site and a walk of it (≥ 20 s, with audio)."""
    import soundfile as sf
    import tomli_w

    from features.site import load_site
    from models.bp import BPConfig
    from models.fusion.model import save_fusion_model
    from training.env import fit_env_model, save_env_model, training_set
    from training.filters import train_fusion

    W = World(Path(root))
    W.root.mkdir(parents=True, exist_ok=True)
    W.site.mkdir()
    shutil.copyfile(Path(site_dir) / "site.toml", W.site / "site.toml")
    site = load_site(W.site / "site.toml")
    _trim_walk(Path(walk_dir), W.w, 20.0, "../../site/site.toml", audio=False)
    _trim_walk(Path(walk_dir), W.w2, 14.0, "../../site/site.toml", audio=False)
    _trim_walk(Path(walk_dir), W.wa, 10.0, "../../site/site.toml", audio=True)
    _synthetic_library(W.lib, site, W.site / "site.toml")
    clf, info = fit_env_model(training_set(W.lib), "supervised")
    save_env_model(clf, W.env, info, library=W.lib)
    model = train_fusion([W.w, W.w2], clf, bp_config=BPConfig(n_members=1, epochs=15, patience=5),
                         meta={"env_meta": info})
    save_fusion_model(model, W.fm)
    # a survey of three 3 s cells cut from the audio walk
    (W.survey / "cells").mkdir(parents=True)
    shutil.copyfile(W.site / "site.toml", W.survey / "site.toml")
    from features.walk import load_walk, read_truth

    info_w = load_walk(W.wa)
    truth = read_truth(W.wa)
    text = (W.wa / "gnss.nmea").read_text()
    audio, fs = sf.read(W.wa / "audio.wav", dtype="int16")
    from datetime import timedelta

    for k in range(3):
        d = W.survey / "cells" / f"c{k}"
        d.mkdir()
        t0 = 3.0 * k
        (d / "gnss.nmea").write_text(_cut_nmea(text, t0, t0 + 3.0))
        sf.write(d / "audio.wav", audio[int(t0 * fs): int((t0 + 3.0) * fs)], fs, subtype="PCM_16")
        e, n = truth.at(np.array([t0 + 1.5]))
        cls = ["open", "light", "heavy"][int(truth.class_at(np.array([t0 + 1.5]))[0])]
        start = (info_w.start_utc + timedelta(seconds=t0)).strftime("%Y-%m-%dT%H:%M:%S.000Z")
        (d / "cell.toml").write_text(tomli_w.dumps({
            "id": f"c{k}", "east_m": float(e[0]), "north_m": float(n[0]), "start_utc": start, "duration_s": 3.0,
            "map_label": cls, "gnss": {"file": "gnss.nmea", "rate_hz": 5.0},
            "audio": {"file": "audio.wav", "fs_hz": 48000, "start_s": 0.0, "start_uncertainty_s": 0.02}}))
    return W


_LINK_SUFFIXES = (".wav", ".nmea")


def copy_world(world: World, dest: Path) -> World:
    """A private copy of ``world`` in ``dest``: large read-only recordings hard-linked (every command
    replaces a file by rename, never in place; the corpus's own edits unlink first), the rest copied."""
    def copy(src, dst):
        if src.endswith(_LINK_SUFFIXES):
            try:
                os.link(src, dst)
                return dst
            except OSError:
                pass
        return shutil.copy2(src, dst)

    shutil.copytree(world.root, dest, copy_function=copy, symlinks=True)
    return World(dest)


# ---------------------------------------------------------------------------------------------- edits


def put(path: Path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` as a new file (unlinked first: never through a hard link)."""
    path = Path(path)
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    path.parent.mkdir(parents=True, exist_ok=True)
    (path.write_bytes if isinstance(data, bytes) else path.write_text)(data)
    return path


def rehash(bundle: Path) -> None:
    """Recompute the SHA-256 of a bundle's array files in its bundle.json (an edited, re-hashed bundle)."""
    from features.fileio import sha256_file

    doc = json.loads((bundle / "bundle.json").read_text())
    doc["files"] = {name: sha256_file(bundle / name) for name in doc["files"]}
    put(bundle / "bundle.json", json.dumps(doc))


def edit_array(bundle: Path, part: str, fn: Callable[[dict], None]) -> None:
    """Apply ``fn`` to the arrays of ``<part>.safetensors`` (a dict, edited in place), save and re-hash."""
    from safetensors.numpy import load_file, save_file

    arrays = dict(load_file(str(bundle / f"{part}.safetensors")))
    fn(arrays)
    (bundle / f"{part}.safetensors").unlink()
    save_file({k: np.ascontiguousarray(v) for k, v in arrays.items()}, str(bundle / f"{part}.safetensors"))
    rehash(bundle)


def edit_json(bundle: Path, fn: Callable[[dict], None]) -> None:
    doc = json.loads((bundle / "bundle.json").read_text())
    fn(doc)
    put(bundle / "bundle.json", json.dumps(doc))


def edit_toml(path: Path, fn: Callable[[dict], None]) -> None:
    import tomli_w

    from features.fileio import read_toml

    doc = read_toml(path)
    fn(doc)
    put(path, tomli_w.dumps(doc))


def _wav(path: Path, data: np.ndarray, fs: int, subtype: str) -> None:
    import soundfile as sf

    with contextlib.suppress(FileNotFoundError):
        Path(path).unlink()
    sf.write(path, data, fs, subtype=subtype)


RANDOM = bytes(np.random.default_rng(20).integers(0, 256, 4096, dtype=np.uint8))
"""Random bytes (seeded) for files that are not what they claim to be."""


# ---------------------------------------------------------------------------------------------- cases


@dataclass(frozen=True)
class Case:
    """One bad input: ``setup(W, d)`` edits the world copy ``W`` (scratch folder ``d``) and returns the
    argv; ``expect`` the exit status due; ``says`` substrings stderr (stdout for 0) must hold;
    ``may_change`` paths (relative to ``d``) the command may replace; ``check(W, d, out, err)`` returns
    what is wrong with an accepted run, or None."""

    name: str
    group: str
    setup: Callable
    expect: int
    says: tuple = ()
    may_change: tuple = ()
    check: Callable | None = None
    timeout_s: float = 120.0


def _methods() -> list[str]:
    return ["--methods", "gnss", "kf", "adaptive"]


def _run(walk: str = "w", out: str = "track.csv", model: str = "fm", extra=()):
    def setup(W, d):
        return ["run", str(getattr(W, walk)), "--model", str(getattr(W, model)), "--out", str(d / out), *extra]
    return setup


def _eval(walks=("w",), report: str = "rep", model: str = "fm", extra=()):
    def setup(W, d):
        return (["evaluate", *[str(getattr(W, w)) for w in walks], "--model", str(getattr(W, model)), "--report",
                 str(d / report), "--workers", "1", "--no-plots", *_methods(), *extra])
    return setup


def _with(setup, edit):
    """``setup`` after ``edit(W, d)``."""
    def s(W, d):
        edit(W, d)
        return setup(W, d)
    return s


def _output_cases() -> list[Case]:
    C = []
    add = C.append
    for rel in ("walks/w/gnss.nmea", "walks/w/truth.csv", "walks/w/walk.toml", "walks/w/imu.csv",
                "fm/bundle.json", "fm/classifier.safetensors", "fm/track.csv", "site/site.toml"):
        add(Case(f"run --out {rel}", "outputs", lambda W, d, rel=rel: ["run", str(W.w), "--model", str(W.fm),
                                                                        "--out", str(W.root / rel)], 2, ("--out",)))
    add(Case("run --out wa/audio.wav", "outputs", lambda W, d: ["run", str(W.wa), "--model", str(W.fm), "--out",
                                                                 str(W.wa / "audio.wav")], 2, ("input",)))

    def link(W, d):
        (d / "alias.csv").symlink_to(W.w / "gnss.nmea")
        return ["run", str(W.w), "--model", str(W.fm), "--out", str(d / "alias.csv")]
    add(Case("run --out symlink to gnss.nmea", "outputs", link, 2, ("input",)))
    add(Case("run --out MODEL dir", "outputs", lambda W, d: ["run", str(W.w), "--model", str(W.fm), "--out",
                                                              str(W.fm)], 2, ("--out",)))
    add(Case("run --out WALK dir", "outputs", lambda W, d: ["run", str(W.w), "--model", str(W.fm), "--out",
                                                             str(W.w)], 2, ("--out",)))
    for name, rel in (("MODEL", "fm"), ("WALK", "walks/w"), ("walks parent", "walks"), ("SITE dir", "site"),
                      ("survey", "survey"), ("inside MODEL", "fm/rep")):
        add(Case(f"evaluate --report {name}", "outputs",
                 lambda W, d, rel=rel: ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(W.root / rel),
                                        "--workers", "1", *_methods()], 2, ("--report",)))
    add(Case("evaluate --report .", "outputs", lambda W, d: ["evaluate", str(W.w), "--model", str(W.fm), "--report",
                                                              ".", "--workers", "1", *_methods()], 2, ("--report",)))

    def notes_dir(W, d):
        put(d / "notes" / "notes.txt", "my notes\n")
        return ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(d / "notes"), "--workers", "1",
                *_methods()]
    add(Case("evaluate --report folder of notes", "outputs", notes_dir, 2, ("--report",)))
    add(Case("evaluate the same walk twice", "outputs", _eval(("w", "w")), 2, ("twice",)))

    def twice_spelled(W, d):
        argv = _eval(("w",))(W, d)
        return argv[:2] + [str(W.walks / "." / "w")] + argv[2:]
    add(Case("evaluate a walk twice by two spellings", "outputs", twice_spelled, 2, ("twice",)))

    def stale_report(W, d):
        put(d / "rep" / "metrics.csv", "walk,method\nold,old\n")
        put(d / "rep" / "trajectory_old_walk.png", b"\x89PNG old")
        put(d / "rep" / "error_time_old_walk.png", b"\x89PNG old")
        return ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(d / "rep"), "--workers", "1",
                *_methods()]

    def stale_check(W, d, out, err):
        rep = d / "rep"
        if (rep / "trajectory_old_walk.png").exists() or (rep / "error_time_old_walk.png").exists():
            return "plots of a walk no longer in the report were left beside the new metrics"
        if "old,old" in (rep / "metrics.csv").read_text():
            return "old metrics kept"
        return None
    add(Case("evaluate into an existing report", "outputs", stale_report, 0, ("walks",), ("rep",), stale_check))
    # survey map
    for name, args in (("--csv LIBRARY", lambda W, d: ["--out", str(d / "m.png"), "--csv", str(W.lib)]),
                       ("--csv SURVEY/site.toml", lambda W, d: ["--out", str(d / "m.png"), "--csv",
                                                               str(W.survey / "site.toml")]),
                       ("--out x.png --csv x.png", lambda W, d: ["--out", str(d / "x.png"), "--csv", str(d / "x.png")]),
                       ("--csv MODEL/bundle.json", lambda W, d: ["--out", str(d / "m.png"), "--csv",
                                                                str(W.env / "bundle.json")]),
                       ("--csv cell.toml", lambda W, d: ["--out", str(d / "m.png"), "--csv",
                                                        str(W.survey / "cells" / "c0" / "cell.toml")]),
                       ("--out inside MODEL", lambda W, d: ["--out", str(W.env / "map.png")]),
                       ("--out map.txt", lambda W, d: ["--out", str(d / "map.txt")])):
        add(Case(f"survey map {name}", "outputs",
                 lambda W, d, args=args: ["survey", "map", str(W.survey), "--library", str(W.lib), "--model",
                                          str(W.env), *args(W, d)], 2, ("--",)))
    # train env
    for name, target in (("survey", lambda W, d: W.survey), ("folder holding the library", lambda W, d: W.root),
                         ("the library file", lambda W, d: W.lib), ("WALK", lambda W, d: W.w),
                         ("a fusion model", lambda W, d: W.fm), ("SITE dir", lambda W, d: W.site)):
        add(Case(f"train env --out {name} --overwrite", "outputs",
                 lambda W, d, target=target: ["train", "env", "--library", str(W.lib), "--out", str(target(W, d)),
                                              "--overwrite"], 2, ("--out",)))
    add(Case("train env --out . --overwrite", "outputs",
             lambda W, d: ["train", "env", "--library", str(W.lib), "--out", ".", "--overwrite"], 2, ("--out",)))

    def empty_out(W, d):
        (d / "empty").mkdir()
        return ["train", "env", "--library", str(W.lib), "--out", str(d / "empty")]
    add(Case("train env --out existing folder without --overwrite", "outputs", empty_out, 2, ("--overwrite",)))

    def env_check(W, d, out, err):
        from training.env import load_env_model
        load_env_model(W.env)
        return None
    add(Case("train env --out ENV --overwrite (same kind)", "outputs",
             lambda W, d: ["train", "env", "--library", str(W.lib), "--out", str(W.env), "--overwrite"], 0,
             ("environment model",), ("world/env",), env_check))
    add(Case("train env --plots LIBRARY", "outputs",
             lambda W, d: ["train", "env", "--library", str(W.lib), "--out", str(d / "e"), "--plots", str(W.lib)],
             2, ("--plots",)))
    # train fusion
    for name, target in (("the --env-model input", lambda W, d: W.env), ("a training walk", lambda W, d: W.w),
                         ("the walks' parent", lambda W, d: W.walks), ("survey", lambda W, d: W.survey),
                         ("inside the --env-model", lambda W, d: W.env / "sub")):
        add(Case(f"train fusion --out {name} --overwrite", "outputs",
                 lambda W, d, target=target: ["train", "fusion", "--walks", str(W.w), "--env-model", str(W.env),
                                              "--out", str(target(W, d)), "--overwrite", "--no-bp"], 2, ("--out",)))
    add(Case("train fusion --walks W W", "outputs",
             lambda W, d: ["train", "fusion", "--walks", str(W.w), str(W.w), "--env-model", str(W.env), "--out",
                           str(d / "f"), "--no-bp"], 2, ("twice",)))
    # benchmark / demo
    for name, target in (("survey", lambda W, d: W.survey), ("WALK", lambda W, d: W.w), ("MODEL", lambda W, d: W.fm)):
        add(Case(f"benchmark --out {name}", "outputs",
                 lambda W, d, target=target: ["benchmark", "--out", str(target(W, d)), "--workers", "1"], 2,
                 ("--out",), timeout_s=60))

    def user_folder(W, d):
        put(d / "mine" / "notes.txt", "keep me\n")
        shutil.copytree(W.env, d / "mine" / "env_model")
        return ["benchmark", "--out", str(d / "mine"), "--workers", "1"]
    add(Case("benchmark --out a user's folder with its own env_model", "outputs", user_folder, 2, ("--out",),
             timeout_s=60))
    add(Case("demo --out survey", "outputs", lambda W, d: ["demo", "--out", str(W.survey), "--workers", "1"], 2,
             ("--out",), timeout_s=60))
    add(Case("demo --out .", "outputs", lambda W, d: ["demo", "--out", ".", "--workers", "1"], 2, ("--out",),
             timeout_s=60))
    # simulate
    for name, argv in (("walk --out SITE dir", lambda W, d: ["simulate", "walk", str(W.site), "--seed", "1", "--out",
                                                             str(W.site), "--force"]),
                       ("walk --out survey --force", lambda W, d: ["simulate", "walk", str(W.site), "--seed", "1",
                                                                   "--out", str(W.survey), "--force",
                                                                   "--duration-s", "2"]),
                       ("walk --out MODEL --force", lambda W, d: ["simulate", "walk", str(W.site), "--seed", "1",
                                                                  "--out", str(W.fm), "--force", "--duration-s", "2"]),
                       ("survey --out WALK --force", lambda W, d: ["simulate", "survey", str(W.site), "--out",
                                                                   str(W.w), "--force", "--cell-size-m", "50",
                                                                   "--capture-s", "1"]),
                       ("site --out survey --force", lambda W, d: ["simulate", "site", "--seed", "1", "--out",
                                                                   str(W.survey), "--force"]),
                       ("site --out . --force", lambda W, d: ["simulate", "site", "--seed", "1", "--out", ".",
                                                              "--force"])):
        add(Case(f"simulate {name}", "outputs", argv, 2, ("--out",), timeout_s=60))
    # features
    add(Case("features gnss --out NMEA", "outputs",
             lambda W, d: ["features", "gnss", str(W.w / "gnss.nmea"), "--out", str(W.w / "gnss.nmea")], 2, ("input",)))
    add(Case("features gnss --out walk.toml beside", "outputs",
             lambda W, d: ["features", "gnss", str(W.w / "gnss.nmea"), "--out", str(W.w / "walk.toml")], 2,
             ("input",)))
    add(Case("features gnss --epochs NMEA", "outputs",
             lambda W, d: ["features", "gnss", str(W.w / "gnss.nmea"), "--out", str(d / "f.csv"), "--epochs",
                           str(W.w / "gnss.nmea")], 2, ("input",)))
    add(Case("features gnss --out = --positions", "outputs",
             lambda W, d: ["features", "gnss", str(W.w / "gnss.nmea"), "--out", str(d / "a.csv"), "--positions",
                           str(d / "a.csv")], 2, ("same file",)))
    add(Case("features imu --out IMU", "outputs",
             lambda W, d: ["features", "imu", str(W.w / "imu.csv"), "--out", str(W.w / "imu.csv")], 2, ("input",)))
    add(Case("features audio --out walk.toml", "outputs",
             lambda W, d: ["features", "audio", str(W.wa / "audio.wav"), "--site", str(W.site), "--walk",
                           str(W.wa / "walk.toml"), "--out", str(W.wa / "walk.toml")], 2, ("input",)))
    add(Case("survey build --library SURVEY/site.toml", "outputs",
             lambda W, d: ["survey", "build", str(W.survey), "--library", str(W.survey / "site.toml"), "--quiet"],
             2, ("--library",)))
    add(Case("survey export --out LIBRARY", "outputs",
             lambda W, d: ["survey", "export", "--library", str(W.lib), "--out", str(W.lib)], 2, ("input",)))
    return C


# truth.csv variants: (name, text or bytes)
TRUTH_BAD = (
    ("random bytes", RANDOM),
    ("0 bytes", b""),
    ("header only", "t_s,east_m,north_m,env_class\n"),
    ("a column missing", "t_s,east_m,env_class\n0,1,open\n1,2,open\n"),
    ("a NaN row", None),
    ("an inf row", None),
    ("a word for a number", None),
    ("an unknown class", None),
    ("time going back", None),
    ("a repeated time", None),
    ("latin-1 bytes", None),
    ("one row", "t_s,east_m,north_m,env_class\n0.0,60.0,59.0,open\n"),
)


def _truth_variant(name: str, good: str):
    lines = good.splitlines(keepends=True)
    head, rows = lines[0], lines[1:]

    def row(i, **kw):
        parts = rows[i].rstrip("\n").split(",")
        cols = head.strip().split(",")
        for k, v in kw.items():
            parts[cols.index(k)] = v
        return ",".join(parts) + "\n"
    if name == "a NaN row":
        return head + "".join(rows[:50]) + row(50, east_m="nan") + "".join(rows[51:])
    if name == "an inf row":
        return head + "".join(rows[:50]) + row(50, north_m="inf") + "".join(rows[51:])
    if name == "a word for a number":
        return head + "".join(rows[:50]) + row(50, t_s="five") + "".join(rows[51:])
    if name == "an unknown class":
        return head + "".join(rows[:50]) + row(50, env_class="medium") + "".join(rows[51:])
    if name == "time going back":
        return head + "".join(rows[:50]) + row(50, t_s="0.5") + "".join(rows[51:])
    if name == "a repeated time":
        return head + "".join(rows[:51]) + rows[50] + "".join(rows[51:])
    if name == "latin-1 bytes":
        return (head + "".join(rows[:50])).encode() + "5.0,1,1,\xe9t\xe9\n".encode("latin-1")
    return dict(TRUTH_BAD)[name]


def _truth_cases() -> list[Case]:
    C = []
    for name, _ in TRUTH_BAD:
        def edit(W, d, name=name):
            put(W.w / "truth.csv", _truth_variant(name, (W.w / "truth.csv").read_text()))
        C.append(Case(f"evaluate, truth.csv: {name}", "truth.csv", _with(_eval(("w",)), edit), 1,
                      ("truth.csv", "walks/w")))
        C.append(Case(f"train fusion, truth.csv: {name}", "truth.csv",
                      _with(lambda W, d: ["train", "fusion", "--walks", str(W.w), "--env-model", str(W.env), "--out",
                                          str(d / "f"), "--no-bp"], edit), 1, ("truth.csv",)))
        C.append(Case(f"run ignores truth.csv: {name}", "truth.csv", _with(_run("w"), edit), 0, ("epochs",),
                      (), lambda W, d, out, err: None if (d / "track.csv").is_file() else "no track written"))

    def mixed(W, d):
        put(W.w2 / "truth.csv", _truth_variant("a NaN row", (W.w2 / "truth.csv").read_text()))
        return _eval(("w", "w2"))(W, d)

    def mixed_check(W, d, out, err):
        text = (d / "rep" / "metrics.csv").read_text() if (d / "rep" / "metrics.csv").is_file() else ""
        if "walks/w," not in text:
            return "the good walk's metrics were not written"
        if "walks/w2," in text or "nan" in text.lower():
            return "the bad walk's rows were kept"
        return None
    C.append(Case("evaluate two walks, one with a NaN truth row", "truth.csv", mixed, 1, ("walks/w2", "skipped"),
                  ("rep",), mixed_check))

    def mixed_dask(W, d):
        put(W.w2 / "truth.csv", _truth_variant("random bytes", (W.w2 / "truth.csv").read_text()))
        argv = _eval(("w", "w2"))(W, d)
        return [a if a != "1" or argv[i - 1] != "--workers" else "2" for i, a in enumerate(argv)]
    C.append(Case("evaluate --workers 2, one walk with truth.csv of random bytes", "truth.csv", mixed_dask, 1,
                  ("walks/w2", "skipped"), ("rep",), mixed_check, timeout_s=180))

    def no_truth(W, d):
        (W.w2 / "truth.csv").unlink()
        return _eval(("w", "w2"))(W, d)
    C.append(Case("evaluate two walks, one without truth.csv", "truth.csv", no_truth, 1, ("walks/w2", "truth.csv"),
                  ("rep",), mixed_check))
    C.append(Case("evaluate one walk without truth.csv", "truth.csv",
                  _with(_eval(("w",)), lambda W, d: (W.w / "truth.csv").unlink()), 1, ("truth.csv",)))
    return C


NMEA_BAD = ("0 bytes", "random bytes", "no timed sentence", "every checksum wrong", "one epoch", "cut mid-line",
            "NUL bytes", "one 1 MB line", "absent")


def _nmea_variant(name: str, good: str) -> bytes | None:
    lines = good.splitlines(keepends=True)
    if name == "0 bytes":
        return b""
    if name == "random bytes":
        return RANDOM
    if name == "no timed sentence":
        return "".join(x for x in lines if x[3:6] == "GSV").encode()
    if name == "every checksum wrong":
        return "".join(re.sub(r"\*[0-9A-F]{2}", "*00", x) for x in lines).encode()
    if name == "one epoch":
        return _cut_nmea(good, 0.0, 0.1).encode()
    if name == "cut mid-line":
        return good[: len(good) // 2 + 17].encode()
    if name == "NUL bytes":
        return b"\x00" * 2048 + good[:2000].encode() + b"\x00" * 100
    if name == "one 1 MB line":
        return b"$GPGSV," + b"9" * (1 << 20)
    return None


def _nmea_cases() -> list[Case]:
    """On the walk with audio, so that without GNSS it still has acoustic positions and PDR: a GNSS file
    that is absent, empty or unusable is read as absent (a note says so) and the walk is fused without it."""
    C = []
    for name in NMEA_BAD:
        def edit(W, d, name=name):
            data = _nmea_variant(name, (W.wa / "gnss.nmea").read_text())
            if data is None:
                (W.wa / "gnss.nmea").unlink()
            else:
                put(W.wa / "gnss.nmea", data)
        usable = name in ("cut mid-line", "one epoch", "NUL bytes")   # the reader keeps the good lines
        note = () if usable else ("gnss",)
        C.append(Case(f"run, gnss.nmea: {name}", "NMEA", _with(_run("wa"), edit), 0, note))
        C.append(Case(f"evaluate, gnss.nmea: {name}", "NMEA", _with(_eval(("wa",)), edit), 0, note, ("rep",)))

        def feat(W, d, name=name):
            data = _nmea_variant(name, (W.w / "gnss.nmea").read_text())
            p = put(d / "x.nmea", data if data is not None else b"")
            if data is None:
                p.unlink()
            return ["features", "gnss", str(p), "--site", str(W.site), "--out", str(d / "f.csv")]
        ok = {"cut mid-line": (), "one epoch": (), "NUL bytes": (), "every checksum wrong": ("bad checksum",)}
        C.append(Case(f"features gnss: {name}", "NMEA", feat, 0 if name in ok else 1, ok.get(name, ("x.nmea",))))
    for name in ("0 bytes", "random bytes", "one epoch"):
        def cell(W, d, name=name):
            p = W.survey / "cells" / "c1" / "gnss.nmea"
            put(p, _nmea_variant(name, p.read_text()))
            return ["survey", "build", str(W.survey), "--library", str(d / "s.sqlite"), "--quiet"]

        def stored_missing(W, d, out, err):
            con = sqlite3.connect(d / "s.sqlite")
            try:
                row = con.execute("SELECT missing_streams FROM cells WHERE cell_id = 'c1'").fetchone()
            finally:
                con.close()
            return None if row and "gnss" in row[0] else f"cell c1 stored with missing_streams {row!r}"
        C.append(Case(f"survey build, a cell's gnss.nmea: {name}", "NMEA", cell, 0, ("gnss",), (), stored_missing))
    return C


WAV_BAD = ("0 bytes", "random bytes", "header without samples", "truncated data", "8 kHz", "stereo",
           "float with NaN samples", "a text file", "absent")


def _wav_variant(name: str, path: Path) -> None:
    import soundfile as sf

    if name == "absent":
        path.unlink()
    elif name == "0 bytes":
        put(path, b"")
    elif name == "random bytes":
        put(path, RANDOM)
    elif name == "a text file":
        put(path, "this is not audio\n" * 20)
    elif name == "header without samples":
        _wav(path, np.zeros(0, np.int16), 48000, "PCM_16")
    elif name == "truncated data":
        put(path, path.read_bytes()[:5000])
    else:
        data, fs = sf.read(path, dtype="float32")
        if name == "8 kHz":
            _wav(path, data[::6], 8000, "PCM_16")
        elif name == "stereo":
            _wav(path, np.column_stack([data, data]), fs, "PCM_16")
        elif name == "float with NaN samples":
            data = data.copy()
            data[::7] = np.nan
            _wav(path, data, fs, "FLOAT")


def _wav_cases() -> list[Case]:
    C = []
    for name in WAV_BAD:
        def edit(W, d, name=name):
            _wav_variant(name, W.wa / "audio.wav")
        C.append(Case(f"run, audio.wav: {name}", "WAV", _with(_run("wa"), edit), 0, ("audio",)))

        def feat(W, d, name=name):
            _wav_variant(name, W.wa / "audio.wav")
            return ["features", "audio", str(W.wa / "audio.wav"), "--site", str(W.site), "--walk",
                    str(W.wa / "walk.toml"), "--out", str(d / "f.csv")]
        said = {"truncated data": ("truncated",), "stereo": ("first only",), "float with NaN samples": ("non-finite",)}
        C.append(Case(f"features audio: {name}", "WAV", feat, 0 if name in said else 1, said.get(name, ("audio.wav",))))
    for name in ("0 bytes", "random bytes", "header without samples", "8 kHz"):
        def cell(W, d, name=name):
            _wav_variant(name, W.survey / "cells" / "c2" / "audio.wav")
            return ["survey", "build", str(W.survey), "--library", str(d / "s.sqlite"), "--quiet"]

        def stored_missing(W, d, out, err):
            con = sqlite3.connect(d / "s.sqlite")
            try:
                row = con.execute("SELECT missing_streams FROM cells WHERE cell_id = 'c2'").fetchone()
            finally:
                con.close()
            return None if row and "audio" in row[0] else f"cell c2 stored with missing_streams {row!r}"
        C.append(Case(f"survey build, a cell's audio.wav: {name}", "WAV", cell, 0, ("audio",), (), stored_missing))
    return C


IMU_BAD = ("0 bytes", "header only", "columns missing", "every row NaN", "text junk", "time going back",
           "one row", "absent", "values of 1e30")


def _imu_variant(name: str, good: str) -> bytes | None:
    lines = good.splitlines(keepends=True)
    head = lines[0]
    if name == "0 bytes":
        return b""
    if name == "header only":
        return head.encode()
    if name == "columns missing":
        return ("t_s,ax,ay\n" + "".join(",".join(x.split(",")[:3]) + "\n" for x in lines[1:])).encode()
    if name == "every row NaN":
        n = len(head.split(","))
        return (head + "".join(f"{i * 0.01:.2f}," + ",".join(["nan"] * (n - 1)) + "\n" for i in range(500))).encode()
    if name == "text junk":
        return b"hello, world\nthis is, not an imu\n" * 50
    if name == "time going back":
        return (head + "".join(lines[1:200]) + "".join(lines[100:300])).encode()
    if name == "one row":
        return (head + lines[1]).encode()
    if name == "values of 1e30":
        return (head + "".join(",".join([x.split(",")[0]] + ["1e30"] * (len(x.split(",")) - 1)) + "\n"
                               for x in lines[1:])).encode()
    return None


def _imu_cases() -> list[Case]:
    C = []
    for name in IMU_BAD:
        def edit(W, d, name=name):
            data = _imu_variant(name, (W.w / "imu.csv").read_text())
            if data is None:
                (W.w / "imu.csv").unlink()
            else:
                put(W.w / "imu.csv", data)
        C.append(Case(f"run, imu.csv: {name}", "IMU", _with(_run("w"), edit), 0, ("imu",)))

        def feat(W, d, name=name):
            data = _imu_variant(name, (W.w / "imu.csv").read_text())
            p = d / "x.csv"
            if data is not None:
                put(p, data)
            return ["features", "imu", str(p), "--out", str(d / "steps.csv")]
        C.append(Case(f"features imu: {name}", "IMU", feat, 0 if name == "time going back" else 1,
                      ("repaired",) if name == "time going back" else ("x.csv",)))
    return C


def _toml_cases() -> list[Case]:
    C = []
    add = C.append
    add(Case("run, walk.toml malformed", "TOML", _with(_run("w"), lambda W, d: put(W.w / "walk.toml", "name = \n[gnss")),
             1, ("walk.toml",)))
    add(Case("run, walk.toml random bytes", "TOML", _with(_run("w"), lambda W, d: put(W.w / "walk.toml", RANDOM)), 1,
             ("walk.toml",)))
    add(Case("run, walk.toml without start_utc", "TOML",
             _with(_run("w"), lambda W, d: edit_toml(W.w / "walk.toml", lambda t: t.pop("start_utc"))), 1,
             ("start_utc",)))
    add(Case("run, walk.toml names a missing site", "TOML",
             _with(_run("w"), lambda W, d: edit_toml(W.w / "walk.toml", lambda t: t.update(site="../nowhere.toml"))),
             1, ("nowhere",)))
    add(Case("run, walk.toml [gnss] not a table", "TOML",
             _with(_run("w"), lambda W, d: edit_toml(W.w / "walk.toml", lambda t: t.update(gnss="gnss.nmea"))), 1,
             ("[gnss]",)))
    add(Case("run, walk.toml duration negative", "TOML",
             _with(_run("w"), lambda W, d: edit_toml(W.w / "walk.toml", lambda t: t.update(duration_s=-4.0))), 1,
             ("duration_s",)))
    add(Case("run, site.toml malformed", "TOML", _with(_run("w"), lambda W, d: put(W.site / "site.toml", "[[beacons]\n")),
             1, ("site.toml",)))
    add(Case("run, site.toml without origin", "TOML",
             _with(_run("w"), lambda W, d: edit_toml(W.site / "site.toml", lambda t: t.pop("origin"))), 1,
             ("origin",)))
    add(Case("run, a folder without walk.toml", "TOML", lambda W, d: ["run", str(W.site), "--model", str(W.fm), "--out",
                                                                       str(d / "t.csv")], 1, ("walk.toml",)))
    add(Case("run, walk folder absent", "TOML", lambda W, d: ["run", str(d / "nowalk"), "--model", str(W.fm), "--out",
                                                               str(d / "t.csv")], 1, ("nowalk",)))
    survey = lambda W, d: ["survey", "build", str(W.survey), "--library", str(d / "s.sqlite"), "--quiet"]  # noqa: E731
    add(Case("survey build, cell.toml malformed", "TOML",
             _with(survey, lambda W, d: put(W.survey / "cells" / "c0" / "cell.toml", "id = ")), 1, ("cell.toml",)))
    add(Case("survey build, cell.toml without east_m", "TOML",
             _with(survey, lambda W, d: edit_toml(W.survey / "cells" / "c0" / "cell.toml", lambda t: t.pop("east_m"))),
             1, ("east_m",)))
    add(Case("survey build, no cells/ folder", "TOML",
             _with(survey, lambda W, d: shutil.rmtree(W.survey / "cells")), 1, ("cells",)))
    add(Case("survey build, no site.toml", "TOML",
             _with(survey, lambda W, d: (W.survey / "site.toml").unlink()), 1, ("site.toml",)))
    return C


def _fusion_bundle_edits() -> list[tuple[str, Callable]]:
    def noise(fn):
        return lambda b: edit_array(b, "noise", fn)

    def cls(fn):
        return lambda b: edit_array(b, "classifier", fn)

    def first(arrays, suffix):
        return next(k for k in sorted(arrays) if k.endswith(suffix))

    def link_out(b):
        outside = b.parent / "elsewhere.safetensors"
        shutil.copyfile(b / "noise.safetensors", outside)
        (b / "noise.safetensors").unlink()
        (b / "noise.safetensors").symlink_to(outside)

    def bp_nan(a):
        a[first(a, ".w1")][0, 0] = np.nan
    return [
        ("no bundle.json", lambda b: (b / "bundle.json").unlink()),
        ("bundle.json random bytes", lambda b: put(b / "bundle.json", RANDOM)),
        ("bundle.json a list", lambda b: put(b / "bundle.json", "[]")),
        ("another format", lambda b: edit_json(b, lambda d: d.update(format="other"))),
        ("a newer format version", lambda b: edit_json(b, lambda d: d.update(format_version=99))),
        ("an array file missing", lambda b: (b / "noise.safetensors").unlink()),
        ("an array file changed", lambda b: put(b / "noise.safetensors", (b / "noise.safetensors").read_bytes()[:-8]
                                                + b"\x00" * 8)),
        ("R of the wrong shape, re-hashed", noise(lambda a: a.update({"cls.R_gnss": np.eye(3)}))),
        ("a negative R, re-hashed", noise(lambda a: a.update({"fixed.R_gnss": -np.eye(2)}))),
        ("an R not positive definite, re-hashed", noise(lambda a: a.update({"fixed.R_acoustic": np.array([[1.0, 2.0],
                                                                                                          [2.0, 1.0]])}))),
        ("NaN in an R, re-hashed", noise(lambda a: a.update({"map.R_gnss": a["map.R_gnss"] * np.nan}))),
        ("NaN classifier weights, re-hashed", cls(lambda a: a.update({first(a, ".coef"): a[first(a, ".coef")] * np.nan}))),
        ("inf classifier intercept, re-hashed", cls(lambda a: a.update({first(a, ".intercept"): np.full_like(
            a[first(a, ".intercept")], np.inf)}))),
        ("prior of the wrong length, re-hashed", cls(lambda a: a.update({"prior": np.ones(5) / 5}))),
        ("NaN BP weight, re-hashed", lambda b: edit_array(b, "bp", bp_nan)),
        ("an array file linked from outside", link_out),
        ("an array file named ../x", lambda b: edit_json(b, lambda d: d["files"].update({"../x.safetensors": "0"}))),
        ("a negative UERE", lambda b: edit_json(b, lambda d: d["params"]["quality"]["uere_m"].update({"1": -2.0}))),
        ("a zero GST scale", lambda b: edit_json(b, lambda d: d["params"]["quality"].update(gst_scale=0.0))),
        ("an empty folder", lambda b: [p.unlink() for p in list(b.iterdir())]),
        ("an environment model", lambda b: (shutil.rmtree(b), shutil.copytree(b.parent / "env", b))),
    ]


def _bundle_cases() -> list[Case]:
    C = []
    for name, edit in _fusion_bundle_edits():
        C.append(Case(f"run, fusion model: {name}", "bundles", _with(_run("w"), lambda W, d, e=edit: e(W.fm)), 1,
                      ("fm",)))
    for name, edit in _fusion_bundle_edits()[7:15]:
        C.append(Case(f"evaluate, fusion model: {name}", "bundles", _with(_eval(("w",)), lambda W, d, e=edit: e(W.fm)),
                      1, ("fm",)))
    C.append(Case("run, --model is a file", "bundles", lambda W, d: ["run", str(W.w), "--model", str(W.lib), "--out",
                                                                      str(d / "t.csv")], 1, ("lib.sqlite",)))

    def cls_edit(fn):
        return lambda W, d: edit_array(W.env, "classifier", fn)

    def key(a, suffix):
        return next(k for k in sorted(a) if k.endswith(suffix))
    env_edits = [
        ("NaN weights", cls_edit(lambda a: a.update({key(a, ".coef"): a[key(a, ".coef")] * np.nan}))),
        ("a mean of the wrong shape", cls_edit(lambda a: a.update({key(a, ".mean"): np.zeros(3)}))),
        ("a precision not positive definite", cls_edit(lambda a: a.update({key(a, ".precision"):
                                                                           -a[key(a, ".precision")]}))),
        ("a zero scale", cls_edit(lambda a: a.update({key(a, ".scale"): np.zeros_like(a[key(a, ".scale")])}))),
        ("a fusion model", lambda W, d: (shutil.rmtree(W.env), shutil.copytree(W.fm, W.env))),
        ("bundle.json changed", lambda W, d: edit_json(W.env, lambda doc: doc["files"].update(
            {"classifier.safetensors": "0" * 64}))),
    ]
    for name, edit in env_edits:
        C.append(Case(f"train fusion, environment model: {name}", "bundles",
                      _with(lambda W, d: ["train", "fusion", "--walks", str(W.w), "--env-model", str(W.env), "--out",
                                          str(d / "f"), "--no-bp"], edit), 1, ("env",)))
        C.append(Case(f"survey map, environment model: {name}", "bundles",
                      _with(lambda W, d: ["survey", "map", str(W.survey), "--library", str(W.lib), "--model",
                                          str(W.env), "--out", str(d / "m.png")], edit), 1, ("env",)))
    return C


def _library_cases() -> list[Case]:
    C = []

    def lib_variant(name):
        def edit(W, d):
            p = W.lib
            if name == "random bytes":
                put(p, RANDOM)
            elif name == "SQLite header, then garbage":
                raw = p.read_bytes()
                put(p, raw[:100] + RANDOM * (len(raw) // len(RANDOM) + 1))
            elif name == "truncated to 8 KiB":
                put(p, p.read_bytes()[:8192])
            elif name == "0 bytes":
                put(p, b"")
            elif name == "a folder":
                p.unlink()
                p.mkdir()
            elif name == "a text file":
                put(p, "not a library\n")
            elif name == "another SQLite database":
                p.unlink()
                con = sqlite3.connect(p)
                con.execute("CREATE TABLE t (x)")
                con.commit()
                con.close()
        return edit

    for name in ("random bytes", "SQLite header, then garbage", "truncated to 8 KiB", "0 bytes", "a folder",
                 "a text file", "another SQLite database"):
        C.append(Case(f"train env, library: {name}", "libraries",
                      _with(lambda W, d: ["train", "env", "--library", str(W.lib), "--out", str(d / "e")],
                            lib_variant(name)), 1, ("lib.sqlite",)))
    for name in ("random bytes", "SQLite header, then garbage", "0 bytes"):
        C.append(Case(f"survey map, library: {name}", "libraries",
                      _with(lambda W, d: ["survey", "map", str(W.survey), "--library", str(W.lib), "--model",
                                          str(W.env), "--out", str(d / "m.png")], lib_variant(name)), 1,
                      ("lib.sqlite",)))

    def one_class(W, d):
        from features.site import load_site
        W.lib.unlink()
        _synthetic_library(W.lib, load_site(W.site / "site.toml"), W.site / "site.toml", classes=[0] * 40)
        return ["train", "env", "--library", str(W.lib), "--out", str(d / "e")]
    C.append(Case("train env, a library of one class", "libraries", one_class, 1, ("two classes",)))

    def few(W, d):
        from features.site import load_site
        W.lib.unlink()
        _synthetic_library(W.lib, load_site(W.site / "site.toml"), W.site / "site.toml", n_cells=5)
        return ["train", "env", "--library", str(W.lib), "--out", str(d / "e")]
    C.append(Case("train env, a library of 15 windows", "libraries", few, 1, ("30",)))
    C.append(Case("train env --site of another library", "libraries",
                  lambda W, d: ["train", "env", "--library", str(W.lib), "--site", "nosuch", "--out", str(d / "e")], 1,
                  ("nosuch",)))

    def mixed(W, d):
        from features.site import load_site
        site = load_site(W.site / "site.toml")
        W.lib.unlink()
        _synthetic_library(W.lib, site, W.site / "site.toml", n_cells=40)
        other = d / "other.sqlite"
        _synthetic_library(other, site, W.site / "site.toml", n_cells=20, seed=3, window_s=4.0)
        # cells of 4 s windows into the same library under other ids
        con = sqlite3.connect(W.lib)
        con.execute("ATTACH DATABASE ? AS o", (str(other),))
        offset = con.execute("SELECT max(cell_pk) FROM cells").fetchone()[0]
        cols = [r[1] for r in con.execute("PRAGMA table_info(cells)") if r[1] != "cell_pk"]
        con.execute(f"INSERT INTO cells (cell_pk, {', '.join(cols)}) SELECT cell_pk + {offset}, "
                    + ", ".join("'X' || cell_id" if c == "cell_id" else c for c in cols) + " FROM o.cells")
        scols = [r[1] for r in con.execute("PRAGMA table_info(samples)") if r[1] not in ("sample_id",)]
        con.execute(f"INSERT INTO samples ({', '.join(scols)}) SELECT "
                    + ", ".join(f"cell_pk + {offset}" if c == "cell_pk" else c for c in scols) + " FROM o.samples")
        con.commit()
        con.close()
        return ["train", "env", "--library", str(W.lib), "--out", str(d / "e")]
    C.append(Case("train env, a library mixing 2 s and 4 s windows", "libraries", mixed, 1, ("window",)))

    def four_s(W, d):
        from features.site import load_site
        from training.env import fit_env_model, save_env_model, training_set
        site = load_site(W.site / "site.toml")
        lib = d / "four.sqlite"
        _synthetic_library(lib, site, W.site / "site.toml", window_s=4.0)
        clf, info = fit_env_model(training_set(lib), "supervised")
        info.setdefault("window_s", 4.0)
        info.setdefault("hop_s", 1.0)
        save_env_model(clf, d / "env4", info, library=lib)
        return ["train", "fusion", "--walks", str(W.w), "--env-model", str(d / "env4"), "--out", str(d / "f"),
                "--no-bp"]
    C.append(Case("train fusion with a model of 4 s windows", "libraries", four_s, 1, ("4 s",)))
    return C


def _option_cases() -> list[Case]:
    C = []
    add = C.append
    ev = ["--methods", "kf", "--no-plots"]
    add(Case("evaluate --scheduler notaurl", "options",
             lambda W, d: ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(d / "r"), "--scheduler",
                           "notaurl", *ev], 2, ("--scheduler",)))

    add(Case("evaluate --scheduler on a refused port", "options",
             lambda W, d: ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(d / "r"), "--scheduler",
                           "tcp://127.0.0.1:9", *ev], 1, ("--scheduler",), timeout_s=8))
    for bad in ("0", "-1", "abc"):
        add(Case(f"evaluate --workers {bad}", "options",
                 lambda W, d, bad=bad: ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(d / "r"),
                                        "--workers", bad, *ev], 2, ("--workers",)))
    for bad in ("-1", "0"):
        add(Case(f"train fusion --hidden {bad}", "options",
                 lambda W, d, bad=bad: ["train", "fusion", "--walks", str(W.w), "--env-model", str(W.env), "--out",
                                        str(d / "f"), "--hidden", bad], 2, ("--hidden",)))
    add(Case("survey build --window-s 1 --hop-s 5", "options",
             lambda W, d: ["survey", "build", str(W.survey), "--library", str(d / "s.sqlite"), "--window-s", "1",
                           "--hop-s", "5", "--quiet"], 2, ("--window-s",)))
    add(Case("survey build --window-s 3600 on 3 s captures", "options",
             lambda W, d: ["survey", "build", str(W.survey), "--library", str(d / "s.sqlite"), "--window-s", "3600",
                           "--quiet"], 1, ("--window-s",)))
    add(Case("run --method bogus", "options", _run("w", extra=("--method", "bogus")), 2, ("--method",)))
    add(Case("run --format xml", "options", _run("w", extra=("--format", "xml")), 2, ("--format",)))
    add(Case("evaluate --methods bogus", "options",
             lambda W, d: ["evaluate", str(W.w), "--model", str(W.fm), "--report", str(d / "r"), "--methods", "bogus"],
             2, ("--methods",)))
    add(Case("train env --seed -1", "options",
             lambda W, d: ["train", "env", "--library", str(W.lib), "--out", str(d / "e"), "--seed", "-1"], 2,
             ("--seed",)))
    add(Case("train env --mode bogus", "options",
             lambda W, d: ["train", "env", "--library", str(W.lib), "--out", str(d / "e"), "--mode", "bogus"], 2,
             ("--mode",)))
    add(Case("benchmark --split nosuch", "options", lambda W, d: ["benchmark", "--split", "nosuch", "--out",
                                                                   str(d / "b")], 2, ("--split",)))
    add(Case("benchmark --workers 0", "options", lambda W, d: ["benchmark", "--out", str(d / "b"), "--workers", "0"],
             2, ("--workers",), timeout_s=60))
    add(Case("demo --workers 0", "options", lambda W, d: ["demo", "--out", str(d / "b"), "--workers", "0"], 2,
             ("--workers",), timeout_s=60))
    add(Case("evaluate without walks", "options", lambda W, d: ["evaluate", "--model", str(W.fm), "--report",
                                                                 str(d / "r")], 2, ("walks",)))
    add(Case("run without --out", "options", lambda W, d: ["run", str(W.w), "--model", str(W.fm)], 2, ("--out",)))
    add(Case("features imu --k 20", "options",
             lambda W, d: ["features", "imu", str(W.w / "imu.csv"), "--out", str(d / "s.csv"), "--k", "20"], 2,
             ("--k",)))
    add(Case("features gnss --elevation-mask-deg 95", "options",
             lambda W, d: ["features", "gnss", str(W.w / "gnss.nmea"), "--out", str(d / "g.csv"),
                           "--elevation-mask-deg", "95"], 2, ("--elevation-mask-deg",)))
    add(Case("run --model absent", "options", lambda W, d: ["run", str(W.w), "--model", str(d / "none"), "--out",
                                                             str(d / "t.csv")], 1, ("none",)))

    def other_site(W, d):
        edit_toml(W.site / "site.toml", lambda t: t.update(name="another-site"))
        return ["run", str(W.w), "--model", str(W.fm), "--out", str(d / "t.csv")]
    add(Case("run a walk of another site", "options", other_site, 1, ("--force",)))
    add(Case("run a walk of another site --force", "options",
             lambda W, d: other_site(W, d) + ["--force"], 0, ("epochs",)))

    def other_site_eval(W, d):
        edit_toml(W.site / "site.toml", lambda t: t.update(name="another-site"))
        return _eval(("w",))(W, d)
    add(Case("evaluate a walk of another site", "options", other_site_eval, 1, ("--force", "walks/w")))
    return C


def _semantic_cases() -> list[Case]:
    C = []
    add = C.append

    def ood_said(W, d, out, err):
        return None if "out of the environment model's training distribution" in out else \
            "the share of epochs out of distribution is not in the summary"
    add(Case("run reports its out-of-distribution share", "semantics", _run("w"), 0, ("out of",), (), ood_said))

    def no_gnss(W, d):
        edit_toml(W.wa / "walk.toml", lambda t: t.pop("gnss"))
        return ["train", "fusion", "--walks", str(W.wa), "--env-model", str(W.env), "--out", str(d / "f"), "--no-bp"]

    def default_r(W, d, out, err):
        return None if "default R" in err and "GNSS" in err else "a default GNSS R was kept without a word"
    add(Case("train fusion on a walk without GNSS", "semantics", no_gnss, 0, ("GNSS",), (), default_r))

    def no_fix(W, d):
        edit_toml(W.w / "walk.toml", lambda t: t.pop("gnss"))
        return ["train", "fusion", "--walks", str(W.w), "--env-model", str(W.env), "--out", str(d / "f"), "--no-bp"]
    add(Case("train fusion on a walk without any fix", "semantics", no_fix, 1, ("fix",)))

    def empty_vs_absent(W, d):
        put(W.wa / "gnss.nmea", b"")
        shutil.copytree(W.wa, W.walks / "wb")
        (W.walks / "wb" / "gnss.nmea").unlink()
        argv = _eval(("wa",))(W, d)
        return argv[:2] + [str(W.walks / "wb")] + argv[2:]

    def same_metrics(W, d, out, err):
        import csv
        rows = list(csv.DictReader(open(d / "rep" / "metrics.csv")))
        a = {(r["method"], r["env_class"]): r["mean_m"] for r in rows if r["walk"] == "walks/wa"}
        b = {(r["method"], r["env_class"]): r["mean_m"] for r in rows if r["walk"] == "walks/wb"}
        if not a or a != b:
            return f"a 0-byte gnss.nmea and an absent one give different results ({len(a)} vs {len(b)} rows)"
        return None
    add(Case("evaluate: a 0-byte gnss.nmea is read as an absent one", "semantics", empty_vs_absent, 0, ("gnss",),
             ("rep",), same_metrics))

    def plots_every_walk(W, d):
        return ["evaluate", str(W.w), str(W.w2), "--model", str(W.fm), "--report", str(d / "rep"), "--workers", "1",
                *_methods()]

    def both_plotted(W, d, out, err):
        names = {p.name for p in (d / "rep").glob("trajectory_*.png")}
        return None if len(names) == 2 else f"per-walk plots for {len(names)} of 2 walks: {sorted(names)}"
    add(Case("evaluate draws the per-walk plots of every walk", "semantics", plots_every_walk, 0, ("walks",), ("rep",),
             both_plotted))
    return C


def cases() -> list[Case]:
    """The whole corpus, in a fixed order."""
    out = (_output_cases() + _truth_cases() + _nmea_cases() + _wav_cases() + _imu_cases() + _toml_cases()
           + _bundle_cases() + _library_cases() + _option_cases() + _semantic_cases())
    names = [c.name for c in out]
    assert len(set(names)) == len(names), [n for n in names if names.count(n) > 1]
    return out


# ---------------------------------------------------------------------------------------------- running


@dataclass
class Outcome:
    """What a case did: exit status, output, elapsed time, the files it changed, and the verdict."""

    status: int | None
    out: str
    err: str
    elapsed_s: float
    changed: list = field(default_factory=list)
    kind: str = ""
    why: str = ""


def _fingerprint(root: Path) -> dict:
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in filenames:
            p = Path(dirpath) / name
            with contextlib.suppress(OSError):
                st = p.lstat()
                out[p] = (st.st_ino, st.st_size, st.st_mtime_ns)
    return out


def prepare(case: Case, world: World, d: Path) -> tuple[World, list[str], dict]:
    """The case's world copy in ``d/world``, its argv, and the fingerprint of every file before the run."""
    W = copy_world(world, d / "world")
    argv = [str(a) for a in case.setup(W, d)]
    return W, argv, _fingerprint(d)


_OWN_LINE = re.compile(r"^(envfuse|plot ->|survey build:|evaluate:|train fusion:|simulate|\[|\s)")


def _error_lines(err: str) -> list[str]:
    """Lines of an error (``envfuse: error: ...`` or the parser's ``envfuse run: ...``), not warnings or notes."""
    return [line for line in err.splitlines() if line.startswith("envfuse")
            and not line.startswith(("envfuse: warning", "envfuse: note"))]


def judge(case: Case, W: World, d: Path, before: dict, o: Outcome) -> Outcome:
    """Classify ``o`` (see the module docstring)."""
    after = _fingerprint(d)
    keep = [d / m for m in case.may_change]
    changed = [str(p.relative_to(d)) for p, fp in before.items()
               if not any(p == k or k in p.parents for k in keep) and after.get(p) != fp]
    o.changed = changed
    text = o.err + o.out
    if changed:
        o.kind, o.why = "data lost", f"changed or removed: {', '.join(changed[:4])}"
    elif o.status not in (0, 1, 2) or "Traceback" in o.err or "internal error" in o.err:
        o.kind, o.why = "internal error", f"status {o.status}: {o.err.strip().splitlines()[-1] if o.err.strip() else ''}"
    elif case.expect != 0 and o.status == 0:
        o.kind, o.why = "silent wrong", "accepted (exit 0)"
    elif case.expect == 0 and o.status != 0:
        o.kind, o.why = "unclear", f"refused a usable input: {o.err.strip()[-200:]}"
    elif case.expect == 0 and case.check is not None and (msg := case.check(W, d, o.out, o.err)):
        o.kind, o.why = "silent wrong", msg
    elif o.status != case.expect:
        o.kind, o.why = "unclear", f"exit {o.status}, expected {case.expect}: {o.err.strip()[:200]}"
    elif case.expect != 0 and len(_error_lines(o.err)) != 1 and not (o.status == 1 and "envfuse: warning" in o.err):
        o.kind, o.why = "unclear", f"not one clear error line: {o.err.strip()[:200]}"
    elif any(s not in text for s in case.says):
        o.kind, o.why = "unclear", f"does not say {[s for s in case.says if s not in text]}: {o.err.strip()[:200]}"
    elif any(not _OWN_LINE.match(line) for line in o.err.splitlines() if line.strip()):
        bad = [line for line in o.err.splitlines() if line.strip() and not _OWN_LINE.match(line)]
        o.kind, o.why = "unclear", f"raw output on stderr: {bad[0][:160]}"
    else:
        o.kind, o.why = "clean", ""
    return o


def run_inprocess(argv: list[str], cwd: Path) -> Outcome:
    """``envfuse argv`` in this process (stdout and stderr captured, working directory ``cwd``)."""
    from pipeline.cli import main

    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    t0 = time.perf_counter()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                status = main(argv)
            except SystemExit as exc:      # argparse's --help / --version
                status = int(exc.code or 0)
            except BaseException as exc:   # noqa: BLE001 - a raise out of main is an internal error
                import traceback
                err.write("Traceback (escaped main)\n" + "".join(traceback.format_exception(exc)))
                status = None
    finally:
        os.chdir(here)
    return Outcome(status, out.getvalue(), err.getvalue(), time.perf_counter() - t0)
