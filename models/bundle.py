"""Model bundles on disk: JSON for parameters and metadata, safetensors for arrays. Never pickle.

A bundle is a directory::

    MODEL_DIR/
        bundle.json          format, kind, format version, envfuse version, created (UTC),
                             parameters and metadata (feature order, class names, training hashes, ...),
                             and the SHA-256 of every array file
        <part>.safetensors   named float / int arrays (safetensors: a JSON header plus raw bytes,
                             so loading can never run code; Hugging Face's format)

:func:`save_bundle` writes into a temporary sibling directory and renames it
into place, so a bundle is complete or absent; an existing bundle is replaced
only with ``overwrite=True``, only when it is a bundle of the same kind holding
nothing else (never a survey, a walk or another kind of model), and only after
the new one is complete. Folders and files get the permissions a plain
``mkdir``/``open`` would give (0755/0644 under the usual umask), so colleagues
on a shared drive can read a model.
:func:`load_bundle` checks the format, the kind, the version (a bundle from a
newer format fails with one clear message), that no file is a link out of the
folder, and each array file's hash (a damaged bundle fails, naming the file),
and returns plain dicts; what the numbers mean is checked by each model's
loader (:mod:`models.checks`).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from features.errors import EnvfuseError
from features.fileio import sha256_file

__all__ = ["BundleError", "Bundle", "save_bundle", "load_bundle", "bundle_kind", "bundle_digest", "FORMAT", "FORMAT_VERSION"]

FORMAT = "envfuse-model"
"""Value of ``format`` in every bundle.json."""

FORMAT_VERSION = 1
"""Bundle layout version this code writes and the newest it reads."""


class BundleError(EnvfuseError, ValueError):
    """A model bundle is missing, damaged, of another kind, or from a newer version."""


@dataclass(frozen=True)
class Bundle:
    """A loaded bundle: ``kind``, ``params`` (JSON), ``arrays`` (part → name → ndarray), ``meta`` (JSON)."""

    kind: str
    params: dict
    arrays: dict
    meta: dict
    path: Path


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("envfuse")
    except Exception:  # noqa: BLE001 - not installed as a distribution (a source checkout): say so
        return "unknown"


def save_bundle(path: str | os.PathLike, kind: str, params: dict, arrays: dict, meta: dict | None = None,
                overwrite: bool = False) -> Path:
    """Write a bundle directory atomically.

    Parameters
    ----------
    kind : str
        What the bundle holds (``"environment"``, ``"fusion"``, ...); checked on load.
    params, meta : dict
        JSON-serialisable parameters and metadata.
    arrays : dict
        ``{part: {name: ndarray}}``; each part becomes ``<part>.safetensors``.
    """
    from safetensors.numpy import save_file

    path = given = Path(path)
    if path.exists() and not overwrite:
        raise BundleError(f"{path} exists; pass overwrite to replace it")
    if path.exists() and not path.is_dir():
        raise BundleError(f"{path} exists and is not a directory")
    if path.is_symlink():
        # a link to a model folder: the folder it points to is replaced and the link kept (as for file outputs)
        path = path.resolve()
    if path.exists():
        _check_replaceable(path, kind)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    except OSError as exc:
        raise BundleError(f"cannot write {given}: {exc.strerror or exc}") from None
    mask = _umask()
    try:
        hashes = {}
        for part, named in arrays.items():
            if not part.replace("_", "").replace("-", "").isalnum():
                raise BundleError(f"bundle part name {part!r} must be alphanumeric")
            clean = {k: np.ascontiguousarray(np.asarray(v)) for k, v in named.items()}
            for k, v in clean.items():
                if v.dtype == object:
                    raise BundleError(f"array {part}/{k} has dtype object; bundles hold numeric arrays only")
            f = tmp / f"{part}.safetensors"
            save_file(clean, str(f))
            hashes[f.name] = sha256_file(f)
        doc = {"format": FORMAT, "format_version": FORMAT_VERSION, "kind": kind, "envfuse_version": _version(),
               "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), "params": params,
               "meta": meta or {}, "files": hashes}
        (tmp / "bundle.json").write_text(json.dumps(doc, indent=2, sort_keys=True, allow_nan=False) + "\n")
        # readable by colleagues as a plain mkdir/open would make them (mkdtemp gives 0700), umask respected
        for f in tmp.iterdir():
            os.chmod(f, 0o666 & ~mask)
        os.chmod(tmp, 0o777 & ~mask)
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            if old.is_symlink() or old.is_file():
                old.unlink()                # left by an older envfuse, which moved a link here
            elif old.exists():
                shutil.rmtree(old)
            os.replace(path, old)
            try:
                os.replace(tmp, path)
            except OSError:
                os.replace(old, path)       # the old model back in place: nothing is lost
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise BundleError(f"cannot write {given}: {exc.strerror or exc}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return given


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def bundle_kind(path: str | os.PathLike) -> str | None:
    """The ``kind`` of the bundle at ``path`` (``"environment"``, ``"fusion"``), or None when it holds none."""
    try:
        doc = json.loads((Path(path) / "bundle.json").read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return doc.get("kind") if isinstance(doc, dict) and doc.get("format") == FORMAT else None


def bundle_digest(path: str | os.PathLike) -> str | None:
    """Hex SHA-256 of the bundle folder's content: every regular file in it (``bundle.json`` and the array files),
    by name and by the SHA-256 of its bytes, in name order; None when the folder cannot be read.

    Two folders with the same digest hold the same model, whatever their modification times: a cache keyed by
    it never serves a model whose folder was replaced (a copy with ``cp -p`` or ``rsync -a`` keeps the old
    times; a coarse file system may give two writes the same one). A bundle is a few tens of KiB to a few MiB,
    so the digest costs well under a millisecond to a few milliseconds."""
    import hashlib

    h = hashlib.sha256()
    try:
        for f in sorted((e for e in Path(path).iterdir() if e.is_file()), key=lambda e: e.name):
            h.update(f"{f.name}\0{sha256_file(f)}\n".encode())
    except OSError:
        return None
    return h.hexdigest()


def _check_replaceable(path: Path, kind: str) -> None:
    """Replace only an empty directory or a bundle of the same kind holding nothing else (never a survey, a
    walk, a library's folder, another kind of model)."""
    entries = [e for e in path.iterdir() if not e.name.startswith(".")]
    if not entries:
        return
    found = bundle_kind(path)
    if found != kind:
        what = f"a {found!r} model" if found else "no envfuse model"
        raise BundleError(f"{path} holds {what}: only a {kind!r} model folder is replaced; name a new directory")
    foreign = [e.name for e in entries if not (e.name == "bundle.json" or e.name.endswith(".safetensors"))]
    if foreign:
        raise BundleError(f"{path} holds files a model does not ({', '.join(sorted(foreign)[:5])}): it is not "
                          "replaced; name a new directory")


def _within(f: Path, root: Path) -> bool:
    """``f`` (symbolic links followed) lies inside ``root``."""
    real, base = Path(os.path.realpath(f)), Path(os.path.realpath(root))
    return base in real.parents


def load_bundle(path: str | os.PathLike, kind: str) -> Bundle:
    """Read and check a bundle written by :func:`save_bundle`; raises :class:`BundleError` with one clear line."""
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    path = Path(path)
    doc_path = path / "bundle.json"
    if not path.is_dir():
        hint = ("; 'default' names the environment model shipped in envfuse, not a fusion model: fit one with "
                "'envfuse train fusion --walks ... --env-model default --out MODEL'"
                if kind == "fusion" and path.name == "default" and not path.exists() else "")
        raise BundleError(f"{path}: not a model directory{hint}")
    if not doc_path.is_file():
        raise BundleError(f"{path}: no bundle.json (not an envfuse model, or an incomplete one)")
    if not _within(doc_path, path):
        raise BundleError(f"{doc_path}: is a link out of the model folder; a bundle's files lie inside it")
    try:
        doc = json.loads(doc_path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise BundleError(f"{doc_path}: damaged ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise BundleError(f"{doc_path}: not an envfuse model bundle")
    version = doc.get("format_version")
    if not isinstance(version, int):
        raise BundleError(f"{doc_path}: format_version missing or not an integer")
    if version > FORMAT_VERSION:
        raise BundleError(f"{path}: written by a newer envfuse (bundle format {version}, this version reads up "
                          f"to {FORMAT_VERSION}; envfuse {doc.get('envfuse_version', '?')}); upgrade envfuse")
    if doc.get("kind") != kind:
        raise BundleError(f"{path}: holds a {doc.get('kind')!r} model, expected {kind!r}")
    files = doc.get("files")
    if not isinstance(files, dict):
        raise BundleError(f"{doc_path}: 'files' missing")
    arrays = {}
    for name, digest in files.items():
        f = path / name
        if Path(name).name != name or not name.endswith(".safetensors"):
            raise BundleError(f"{doc_path}: bad array file name {name!r}")
        if not f.is_file():
            raise BundleError(f"{path}: {name} is missing")
        if not _within(f, path):
            raise BundleError(f"{path}: {name} is a link out of the model folder; a bundle's files lie inside it")
        if sha256_file(f) != digest:
            raise BundleError(f"{path}: {name} is damaged (its SHA-256 differs from bundle.json)")
        try:
            arrays[name[: -len(".safetensors")]] = load_file(str(f))
        except (SafetensorError, OSError, ValueError) as exc:
            raise BundleError(f"{path}: {name} cannot be read ({exc})") from None
    return Bundle(kind=kind, params=doc.get("params", {}), arrays=arrays, meta=doc.get("meta", {}), path=path)
