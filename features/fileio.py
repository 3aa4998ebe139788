"""Atomic file and directory writing: nothing is ever half-written.

Files are written to a temporary name in the same directory and renamed over
the target (``os.replace`` is atomic on POSIX). Directories are built under a
temporary sibling name and renamed into place when complete.

What is not a regular file is never replaced: ``-`` means standard output;
an existing device, FIFO or socket, and a descriptor's name (``/dev/fd/N``,
``/proc/...``; ``/dev/stdout`` is standard output even when the shell
redirected it to a file), is written through once the content is complete; a symbolic link is followed and its
target replaced atomically, the link kept.

Temporary names carry the writer's process id (``.NAME.<pid>.XXXX.partial``,
``.tmp``); one left by a process that no longer runs (killed by SIGKILL, a
power cut) is removed the next time the same output is written.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import os
import re
import shutil
import stat
import sys
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


__all__ = ["atomic_write_text", "atomic_write_bytes", "atomic_write_many", "atomic_path", "atomic_directory",
           "read_toml", "write_toml", "STDOUT", "is_stdout", "data_stdout", "same_file", "clean_stale_temporaries",
           "sha256_file"]

STDOUT = "-"
"""The output name meaning standard output."""

_DATA_STDOUT: contextvars.ContextVar = contextvars.ContextVar("envfuse_data_stdout", default=None)


_STDOUT_ALIASES = ("/dev/stdout", "/dev/fd/1", "/proc/self/fd/1")


def is_stdout(path) -> bool:
    """True for ``-`` and the names of this process's standard output (``/dev/stdout``, ``/dev/fd/1``).

    >>> is_stdout("-"), is_stdout("/dev/stdout"), is_stdout("out.csv")
    (True, True, False)
    """
    return path is not None and (str(path) == STDOUT or str(path) in _STDOUT_ALIASES)


@contextlib.contextmanager
def data_stdout(stream) -> Iterator[None]:
    """Send ``-`` outputs to ``stream`` (the CLI passes the real stdout while it prints its summary to stderr)."""
    token = _DATA_STDOUT.set(stream)
    try:
        yield
    finally:
        _DATA_STDOUT.reset(token)


def _write_stdout(data: bytes) -> None:
    stream = _DATA_STDOUT.get() or sys.stdout
    buf = getattr(stream, "buffer", None)
    if buf is not None:
        stream.flush()
        buf.write(data)
        buf.flush()
    else:
        stream.write(data.decode("utf-8", errors="replace"))
        stream.flush()


def same_file(a, b) -> bool:
    """True when paths ``a`` and ``b`` name the same file (an existing one by inode, else by resolved path)."""
    a, b = Path(a), Path(b)
    with contextlib.suppress(OSError):
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def _special(path: Path) -> bool:
    """An existing path (symlinks followed) that is neither a regular file nor a directory."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary siblings of ``path`` left by writers that no longer run; return them.

    A name ``.NAME.<pid>.XXXX.{partial,tmp,old}`` is stale when process <pid>
    is gone; one without a pid (written before pids were recorded) always is.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    removed = []
    pattern = re.compile(r"^\." + re.escape(path.name) + r"\.(?:(\d+)\.)?[^.]+\.(?:tmp[^/]*|partial|old)$")
    try:
        entries = list(parent.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = pattern.match(entry.name)
        if m is None:
            continue
        if m.group(1) is not None and _pid_alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed.append(entry)
    return removed


def _prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}."


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path for ``path``; on success move it to ``path``, on error delete it.

    ``-`` (standard output) and existing non-regular files get the complete
    content written through; a symlink's target is replaced, not the link.
    """
    through = is_stdout(path)
    path = Path(path)
    # /dev/stdout, /dev/fd/N, /proc/self/fd/N name an open descriptor (a pipe, a terminal, or the file a
    # shell redirected to): write through it, never replace what it resolves to (/dev/shm/x stays atomic)
    through = through or os.path.abspath(path).startswith(("/dev/fd/", "/dev/stderr", "/proc/"))
    if not through and path.is_dir():
        raise EnvfuseError(f"cannot write {path}: it is a directory")
    if not through and path.is_symlink():
        path = Path(os.path.realpath(path))
        if path.is_dir():
            raise EnvfuseError(f"cannot write {path}: it is a directory")
    through = through or _special(path)
    try:
        if through:
            fd, tmp = tempfile.mkstemp(prefix=".envfuse.", suffix=".tmp" + suffix)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            clean_stale_temporaries(path)
            fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=".tmp" + suffix, dir=path.parent)
    except OSError as exc:
        raise EnvfuseError(f"cannot write {path}: {exc.strerror or exc}") from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if not through:
            _publish_mode(tmp_path, directory=False)
            os.replace(tmp_path, path)
        elif is_stdout(path):
            _write_stdout(tmp_path.read_bytes())
        else:
            try:
                with open(path, "wb") as fh:
                    fh.write(tmp_path.read_bytes())
            except OSError as exc:
                raise EnvfuseError(f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()


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
    if is_stdout(path):
        raise EnvfuseError("a directory output cannot be standard output ('-')")
    if path.exists() and not path.is_dir():
        raise EnvfuseError(f"output {path} exists and is not a directory")
    if path.is_dir() and any(path.iterdir()) and not overwrite:
        raise EnvfuseError(f"output directory {path} is not empty (use --force to replace it)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temporaries(path)
        tmp = Path(tempfile.mkdtemp(prefix=_prefix(path), suffix=".partial", dir=path.parent))
    except OSError as exc:
        raise EnvfuseError(f"cannot create {path}: {exc.strerror or exc}") from None
    try:
        yield tmp
        _publish_mode(tmp, directory=True)
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=_prefix(path), suffix=".old", dir=path.parent))
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
    renames happen only once every one of them is written. Two outputs naming one file are refused."""
    paths = [p for p in outputs if not is_stdout(p)]
    for i, a in enumerate(paths):
        for b in paths[i + 1:]:
            if same_file(a, b):
                raise EnvfuseError(f"two outputs name the same file {a}")
    if sum(is_stdout(p) for p in outputs) > 1:
        raise EnvfuseError("only one output can be standard output ('-')")
    with contextlib.ExitStack() as stack:
        for path, text in outputs.items():
            tmp = stack.enter_context(atomic_path(path))
            tmp.write_bytes(text.encode("utf-8"))


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes, read in 1 MiB blocks (source-file hashes, model bundles, libraries)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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
