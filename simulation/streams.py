"""Sensor streams written into a walk or survey-cell directory.

The walk and survey generators build a :class:`Trajectory` (the receiver's true
motion) and hand a :class:`StreamContext` to every writer listed in
:data:`STREAM_WRITERS`. Each writer puts its own file(s) into ``ctx.out_dir``
(a temporary directory renamed into place only when all writers succeed) and
returns the entries it wants in ``walk.toml`` / ``cell.toml``.

A new stream (audio, IMU, ...) adds one ``"module:function"`` entry here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from features.site import Site

__all__ = ["Trajectory", "StreamContext", "STREAM_WRITERS", "run_stream_writers"]


@dataclass(frozen=True)
class Trajectory:
    """True receiver motion on the walk's time base.

    Attributes
    ----------
    t_s : ndarray of shape (n,)
        Seconds since the walk's start, uniformly sampled at ``rate_hz``.
    east_m, north_m : ndarray of shape (n,)
        Horizontal position of the device, ENU metres about the site origin.
    up_m : ndarray of shape (n,)
        Device height above the site origin's ground, metres.
    heading_rad : ndarray of shape (n,)
        Direction of travel, radians from north, clockwise (navigation
        convention); held through stops.
    speed_m_s : ndarray of shape (n,)
        Horizontal speed, m/s (0 while standing).
    start_utc : datetime
        UTC time of ``t_s == 0`` (timezone-aware).
    rate_hz : float
        Sampling rate of the arrays.
    """

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    up_m: np.ndarray
    heading_rad: np.ndarray
    speed_m_s: np.ndarray
    start_utc: datetime
    rate_hz: float

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) if len(self.t_s) else 0.0

    def interp(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (east_m, north_m, up_m) at arbitrary times, linear interpolation."""
        return (np.interp(t_s, self.t_s, self.east_m), np.interp(t_s, self.t_s, self.north_m),
                np.interp(t_s, self.t_s, self.up_m))


@dataclass(frozen=True)
class StreamContext:
    """Everything a stream writer may use.

    ``kind`` is ``"walk"`` or ``"survey"`` (a static capture in one cell);
    ``seed`` is the walk's (or the survey cell's) seed, ``person_seed`` the
    walker's identity (same person → same gait constants across walks).
    Writers draw randomness only via ``simulation.rng.stream_rng(ctx.seed, name)``.
    """

    site: Site
    trajectory: Trajectory
    out_dir: Path
    seed: int
    kind: str
    person_seed: int = 0
    options: dict = field(default_factory=dict)


STREAM_WRITERS: tuple[str, ...] = (
    "simulation.gnss.stream:write_gnss",
    "simulation.imu.stream:write_imu",
    "simulation.acoustic.stream:write_audio",
    "simulation.uwb.stream:write_uwb_stream",
    "simulation.imu.foot:write_imu_foot",
)
"""Writers run in order for every walk and survey cell, as ``"module:function"``."""


def run_stream_writers(ctx: StreamContext, writers: tuple[str, ...] = STREAM_WRITERS) -> dict:
    """Run every writer; merge the TOML entries they return."""
    meta: dict = {}
    for spec in writers:
        module_name, func_name = spec.split(":")
        func = getattr(importlib.import_module(module_name), func_name)
        entries = func(ctx) or {}
        meta.update(entries)
    return meta
