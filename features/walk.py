"""Walk logs and survey cells on disk: ``walk.toml`` / ``cell.toml`` metadata (docs/design.md §4).

A walk directory holds ``walk.toml``, ``gnss.nmea``, ``audio.wav``, ``imu.csv``
and optionally ``truth.csv``; each stream is described by its own table in
``walk.toml`` (``[gnss]``, ``[audio]``, ``[imu]``) and is optional.

A vehicle's drive (``envfuse convert smartloc``) holds raw GNSS and odometry
instead: ``[gnss_pseudoranges]`` (``gnss_pseudoranges.csv``, per-satellite
pseudoranges, solved by the reader) and ``[odometry]`` (``odometry.csv``, speed
and yaw rate), :mod:`features.raw_tables`. A walk holds at most one GNSS stream
(``gnss`` or ``gnss_pseudoranges``) and one dead-reckoning stream (``imu`` or
``odometry``).

``start_utc`` (ISO 8601) places the walk's ``t_s = 0`` in UTC. It is required
where the processing needs it — NMEA (its times are UTC of day) and audio (the
beacons' TDMA frames are tied to UTC) — and may be left out of a walk that holds
neither (a log whose file states only relative times, as smartLoc's do); its
tables then have an empty ``time_utc``.

``truth.csv``'s ``env_class`` is ``open``, ``light``, ``heavy`` or
``unknown`` (:data:`UNKNOWN_CLASS`, code −1): a reference trajectory from a
survey-grade receiver says where the device was, not what the sky was like
there. Per-class metrics leave unknown epochs out; they count in ``all``.
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

__all__ = ["WalkInfo", "load_walk", "Truth", "read_truth", "parse_utc", "STREAMS", "UNKNOWN_CLASS",
           "UNKNOWN_CLASS_NAME"]

UNKNOWN_CLASS = -1
"""Class code of a truth epoch whose environment class is not known (``env_class = unknown``)."""

UNKNOWN_CLASS_NAME = "unknown"
"""The ``env_class`` text of :data:`UNKNOWN_CLASS` in ``truth.csv``."""


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

    ``streams`` maps a stream name (:data:`STREAMS`) to its table; :meth:`path` resolves a stream's
    file. ``start_utc`` is None when ``walk.toml`` states none (module docstring).
    """

    directory: Path
    name: str
    start_utc: datetime | None
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


STREAMS = ("gnss", "audio", "imu", "gnss_pseudoranges", "odometry", "uwb", "imu_foot")
"""Stream tables a ``walk.toml`` may hold, each with a ``file`` key."""

_NEEDS_UTC = ("gnss", "audio")
"""Streams whose processing needs ``start_utc`` (NMEA times of day, TDMA frames tied to UTC)."""

_EXCLUSIVE = (("gnss", "gnss_pseudoranges"), ("imu", "odometry"))
"""Stream pairs a walk holds at most one of (one GNSS stream, one dead-reckoning stream)."""


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
    duration = data.get("duration_s")
    if duration is not None and (not isinstance(duration, (int, float)) or duration <= 0):
        raise ConfigError(f"{d / name}: duration_s must be a positive number, got {duration!r}")
    streams = {}
    for s in STREAMS:
        if s in data:
            if not isinstance(data[s], dict) or not isinstance(data[s].get("file"), str):
                raise ConfigError(f"{d / name}: [{s}] must be a table with a 'file' key (a file name)")
            streams[s] = dict(data[s])
    for a, b in _EXCLUSIVE:
        if a in streams and b in streams:
            raise ConfigError(f"{d / name}: holds both [{a}] and [{b}]; a walk has one of them")
    if "start_utc" not in data and any(s in streams for s in _NEEDS_UTC):
        need = " and ".join(f"[{s}]" for s in _NEEDS_UTC if s in streams)
        raise ConfigError(f"{d / name}: missing start_utc (needed by its {need} stream)")
    start = parse_utc(data["start_utc"], f"{d / name} start_utc") if "start_utc" in data else None
    extra = {k: v for k, v in data.items() if k not in STREAMS}
    return WalkInfo(directory=d, name=str(data.get("name", data.get("id", d.name))), start_utc=start,
                    duration_s=None if duration is None else float(duration), site_ref=data.get("site"),
                    streams=streams, extra=extra)


@dataclass(frozen=True)
class Truth:
    """Ground truth of a walk: arrays of shape (n,)."""

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    env_class: np.ndarray  # int codes into ENV_CLASSES, UNKNOWN_CLASS (−1) where unknown
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

    ``env_class`` is a name of :data:`~features.site.ENV_CLASSES` or ``unknown`` (code :data:`UNKNOWN_CLASS`).
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
    names = {c: k for k, c in enumerate(ENV_CLASSES)} | {UNKNOWN_CLASS_NAME: UNKNOWN_CLASS}
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
        if r["env_class"] not in names:
            raise DataError(f"{path}: line {line}: env_class {r['env_class']!r} is not one of {list(names)}")
        t[i], e[i], n[i] = vals
        c[i] = names[r["env_class"]]
        share[i] = sh
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        raise DataError(f"{path}: line {int(bad[0]) + 3}: t_s {t[bad[0] + 1]:g} does not increase "
                        f"(previous {t[bad[0]]:g})")
    return Truth(t, e, n, c, share if has_share else None)
