"""Walk logs and survey cells on disk: ``walk.toml`` / ``cell.toml`` metadata (docs/design.md §4).

A walk directory holds ``walk.toml``, ``gnss.nmea``, ``audio.wav``, ``imu.csv``
and optionally ``truth.csv``; each stream is described by its own table in
``walk.toml`` (``[gnss]``, ``[audio]``, ``[imu]``) and is optional.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from features.errors import ConfigError, DataError
from features.fileio import read_toml
from features.site import ENV_CLASSES, Site, load_site

__all__ = ["WalkInfo", "load_walk", "Truth", "read_truth", "parse_utc"]


def parse_utc(text: str, where: str = "start_utc") -> datetime:
    """Parse an ISO 8601 time (``Z`` allowed); a naive time is taken as UTC."""
    if not isinstance(text, str):
        raise ConfigError(f"{where} must be an ISO 8601 string, got {text!r}")
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        raise ConfigError(f"{where} {text!r} is not ISO 8601 (e.g. 2026-06-01T08:00:00Z)") from None
    return t if t.tzinfo else t.replace(tzinfo=timezone.utc)


@dataclass(frozen=True)
class WalkInfo:
    """Metadata of a walk log or survey cell directory.

    ``streams`` maps a stream name (``gnss``, ``audio``, ``imu``) to its table;
    :meth:`path` resolves a stream's file.
    """

    directory: Path
    name: str
    start_utc: datetime
    duration_s: float | None
    site_ref: str | None
    streams: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def path(self, stream: str) -> Path | None:
        """Path of the stream's file, or ``None`` when the walk has no such stream."""
        table = self.streams.get(stream)
        if not table:
            return None
        p = self.directory / table.get("file", "")
        return p if p.is_file() else None

    def load_site(self, override: str | os.PathLike | None = None) -> Site:
        """The walk's site: ``override`` if given, else the ``site`` path stored in the walk."""
        if override is not None:
            return load_site(override)
        if self.site_ref is None:
            raise ConfigError(f"{self.directory}: walk names no site; pass --site")
        return load_site((self.directory / self.site_ref).resolve())


_STREAMS = ("gnss", "audio", "imu")


def load_walk(directory: str | os.PathLike) -> WalkInfo:
    """Read ``walk.toml`` (or ``cell.toml``) from a walk or survey-cell directory."""
    d = Path(directory)
    if d.is_file():
        d, name = d.parent, d.name
    else:
        name = "walk.toml" if (d / "walk.toml").exists() else "cell.toml"
    if not d.is_dir():
        raise ConfigError(f"{d}: not a walk directory")
    data = read_toml(d / name)
    if "start_utc" not in data:
        raise ConfigError(f"{d / name}: missing start_utc")
    duration = data.get("duration_s")
    if duration is not None and (not isinstance(duration, (int, float)) or duration <= 0):
        raise ConfigError(f"{d / name}: duration_s must be a positive number, got {duration!r}")
    streams = {}
    for s in _STREAMS:
        if s in data:
            if not isinstance(data[s], dict) or "file" not in data[s]:
                raise ConfigError(f"{d / name}: [{s}] must be a table with a 'file' key")
            streams[s] = dict(data[s])
    extra = {k: v for k, v in data.items() if k not in _STREAMS}
    return WalkInfo(directory=d, name=str(data.get("name", data.get("id", d.name))),
                    start_utc=parse_utc(data["start_utc"], f"{d / name} start_utc"),
                    duration_s=None if duration is None else float(duration), site_ref=data.get("site"),
                    streams=streams, extra=extra)


@dataclass(frozen=True)
class Truth:
    """Ground truth of a walk: arrays of shape (n,)."""

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    env_class: np.ndarray  # int codes into ENV_CLASSES
    blocked_share: np.ndarray | None = None  # the continuous share behind the class, when truth.csv has it

    def at(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Interpolated (east_m, north_m) at times ``t_s``."""
        return np.interp(t_s, self.t_s, self.east_m), np.interp(t_s, self.t_s, self.north_m)

    def class_at(self, t_s) -> np.ndarray:
        """Class code of the nearest earlier truth sample."""
        i = np.clip(np.searchsorted(self.t_s, t_s, side="right") - 1, 0, len(self.t_s) - 1)
        return self.env_class[i]


def read_truth(path: str | os.PathLike) -> Truth:
    """Read ``truth.csv`` (t_s, east_m, north_m, env_class; optional blocked_sky_share).

    Refused with one :class:`~features.errors.DataError` naming the file and, for a bad row, its line: a
    file that is not UTF-8 text, without the columns, with fewer than two rows, a non-finite number (NaN, inf) or
    an unknown class, or whose times do not increase (truth is interpolated in time).
    """
    path = Path(path)
    if path.is_dir():
        path = path / "truth.csv"
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            rows = list(reader)
    except FileNotFoundError:
        raise DataError(f"{path}: file not found") from None
    except UnicodeDecodeError:
        raise DataError(f"{path}: not a text CSV file (not UTF-8)") from None
    except csv.Error as exc:
        raise DataError(f"{path}: not a CSV file ({exc})") from None
    need = {"t_s", "east_m", "north_m", "env_class"}
    if not need <= set(header):
        raise DataError(f"{path}: needs columns {sorted(need)}, found {sorted(h for h in header if h)[:8]}")
    if len(rows) < 2:
        raise DataError(f"{path}: has the columns but {'no rows' if not rows else 'one row'}; truth is "
                        "interpolated in time and needs at least two")
    has_share = "blocked_sky_share" in header
    t, e, n, share = (np.empty(len(rows)) for _ in range(4))
    c = np.empty(len(rows), int)
    for i, r in enumerate(rows):
        line = i + 2
        try:
            vals = [float(r[k]) for k in ("t_s", "east_m", "north_m")]
            sh = float(r["blocked_sky_share"]) if has_share and r["blocked_sky_share"] not in ("", None) else np.nan
        except (TypeError, ValueError):
            raise DataError(f"{path}: line {line}: t_s, east_m and north_m must be numbers, got "
                            f"{[r.get(k) for k in ('t_s', 'east_m', 'north_m')]}") from None
        if not all(np.isfinite(vals)):
            raise DataError(f"{path}: line {line}: non-finite value in {vals} (truth must be finite)")
        if r["env_class"] not in ENV_CLASSES:
            raise DataError(f"{path}: line {line}: env_class {r['env_class']!r} is not one of {list(ENV_CLASSES)}")
        t[i], e[i], n[i] = vals
        c[i] = ENV_CLASSES.index(r["env_class"])
        share[i] = sh
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise DataError(f"{path}: line {int(bad[0]) + 3}: t_s {t[bad[0] + 1]:g} does not increase "
                        f"(previous {t[bad[0]]:g})")
    return Truth(t, e, n, c, share if has_share else None)
