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
only with ``overwrite=True`` (and then only after the new one is complete).
:func:`load_bundle` checks the format, the kind, the version (a bundle from a
newer format fails with one clear message) and each array file's hash (a
damaged bundle fails, naming the file), and returns plain dicts.
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

__all__ = ["BundleError", "Bundle", "save_bundle", "load_bundle", "FORMAT", "FORMAT_VERSION"]

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

    path = Path(path)
    if path.exists() and not overwrite:
        raise BundleError(f"{path} exists; pass overwrite to replace it")
    if path.exists() and not path.is_dir():
        raise BundleError(f"{path} exists and is not a directory")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
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
        if path.exists():
            old = path.with_name(f".{path.name}.old")
            if old.exists():
                shutil.rmtree(old)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path


def load_bundle(path: str | os.PathLike, kind: str) -> Bundle:
    """Read and check a bundle written by :func:`save_bundle`; raises :class:`BundleError` with one clear line."""
    from safetensors import SafetensorError
    from safetensors.numpy import load_file

    path = Path(path)
    doc_path = path / "bundle.json"
    if not path.is_dir():
        raise BundleError(f"{path}: not a model directory")
    if not doc_path.is_file():
        raise BundleError(f"{path}: no bundle.json (not an envfuse model, or an incomplete one)")
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
        if sha256_file(f) != digest:
            raise BundleError(f"{path}: {name} is damaged (its SHA-256 differs from bundle.json)")
        try:
            arrays[name[: -len(".safetensors")]] = load_file(str(f))
        except (SafetensorError, OSError, ValueError) as exc:
            raise BundleError(f"{path}: {name} cannot be read ({exc})") from None
    return Bundle(kind=kind, params=doc.get("params", {}), arrays=arrays, meta=doc.get("meta", {}), path=path)
