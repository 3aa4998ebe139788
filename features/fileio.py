"""Atomic file and directory writing: nothing is ever half-written.

Files are written to a temporary name in the same directory and renamed over
the target (``os.replace`` is atomic on POSIX). Directories are built under a
temporary sibling name and renamed into place when complete.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import tomllib
from pathlib import Path
from typing import Iterator

import tomli_w

from features.errors import ConfigError, EnvfuseError

def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _publish_mode(path: Path, directory: bool) -> None:
    """Give a temporary file/dir the permissions a plain open()/mkdir() would (mkstemp uses 0600/0700)."""
    os.chmod(path, (0o777 if directory else 0o666) & ~_umask())


__all__ = ["atomic_write_text", "atomic_write_bytes", "atomic_write_many", "atomic_path", "atomic_directory", "read_toml", "write_toml"]


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``, on error delete it."""
    path = Path(path)
    if path.is_dir():
        raise EnvfuseError(f"cannot write {path}: it is a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + suffix, dir=path.parent)
    except OSError as exc:
        raise EnvfuseError(f"cannot write {path}: {exc.strerror or exc}") from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _publish_mode(tmp_path, directory=False)
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (newlines written as given)."""
    atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Build a directory under a temporary sibling name, then rename it to ``path``.

    An existing non-empty ``path`` is refused unless ``overwrite``; with it, the
    old directory is replaced only once the new one is complete.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise EnvfuseError(f"output {path} exists and is not a directory")
    if path.is_dir() and any(path.iterdir()) and not overwrite:
        raise EnvfuseError(f"output directory {path} is not empty (use --force to replace it)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    except OSError as exc:
        raise EnvfuseError(f"cannot create {path}: {exc.strerror or exc}") from None
    try:
        yield tmp
        _publish_mode(tmp, directory=True)
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.replace(path, old / "d")
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def atomic_write_many(outputs: dict) -> None:
    """Write several text files, all or none: each goes to a temporary file first, and the
    renames happen only once every one of them is written."""
    with contextlib.ExitStack() as stack:
        for path, text in outputs.items():
            tmp = stack.enter_context(atomic_path(path))
            tmp.write_bytes(text.encode("utf-8"))


def read_toml(path: str | os.PathLike) -> dict:
    """Read a TOML file; a missing or malformed file raises :class:`ConfigError` naming it."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: malformed TOML ({exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file") from None


def write_toml(path: str | os.PathLike, data: dict) -> None:
    """Write ``data`` as TOML atomically."""
    atomic_write_text(path, tomli_w.dumps(data))
