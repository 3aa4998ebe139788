"""Time bases of the acoustic receiver: beacon frames, the audio clock, detections.

Beacon protocol (docs/beacon_protocol.md; written by the transmit side in
``simulation/chirp.py``): frames of ``frame_s = n_slots·slot_s`` start at
integer multiples of ``frame_s`` of POSIX UTC time; beacon ``b`` starts its
chirp ``slot_b·slot_s`` after each frame start. On the walk's time base
(seconds since ``start_utc``) a chirp leaves beacon ``b`` at
``t_tx = frame_phase + k·frame_s + slot_b·slot_s`` with
``frame_phase = (−POSIX(start_utc)) mod frame_s``. The receiver states the walk
time of its first audio sample (``start_s``) only to within
``start_uncertainty_s``.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from typing import NamedTuple
from datetime import datetime, timezone
from pathlib import Path

from features.acoustic.audio import AudioWarning
from features.acoustic.cir import CirFeatures
from features.constants import SPEED_OF_SOUND_0C_M_S
from features.errors import ConfigError
from features.site import Site
from features.walk import WalkInfo

__all__ = ["speed_of_sound_m_s", "frame_phase_s", "AudioTiming", "ChirpDetection", "SearchWindow", "timing_from_walk",
           "MAX_START_UNCERTAINTY_S"]

_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


def speed_of_sound_m_s(temperature_c: float) -> float:
    """c = 331.3·sqrt(1 + T/273.15) m/s (ideal gas; Cramer 1993, JASA 93(5)).

    >>> round(speed_of_sound_m_s(20.0), 2)
    343.21
    """
    return SPEED_OF_SOUND_0C_M_S * math.sqrt(1.0 + temperature_c / 273.15)


def frame_phase_s(start_utc: datetime, frame_s: float) -> float:
    """Walk time of the first frame start at or after ``start_utc``: (−POSIX seconds) mod frame_s.

    Integer microseconds, so POSIX times of 1.8e9 s lose nothing.

    >>> frame_phase_s(datetime(2026, 5, 1, 8, 0, 0, 300000, tzinfo=timezone.utc), 0.8)
    0.5
    """
    if start_utc.tzinfo is None:
        raise ConfigError(f"start_utc must be timezone-aware (UTC), got {start_utc!r}")
    delta = start_utc - _EPOCH
    start_us = (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds
    frame_us = int(round(frame_s * 1e6))
    if frame_us <= 0:
        raise ConfigError(f"frame_s must be positive, got {frame_s}")
    return ((-start_us) % frame_us) / 1e6



@dataclass(frozen=True)
class AudioTiming:
    """How the audio's samples map onto the walk's time base and the beacon frames.

    ``start_s``: stated walk time of the first sample; ``start_uncertainty_s``:
    its stated uncertainty (half-width); ``frame_phase_s``: walk time of a frame
    start (see :func:`frame_phase_s`).
    """

    start_s: float = 0.0
    start_uncertainty_s: float = 0.01
    frame_phase_s: float = 0.0

    def __post_init__(self):
        for name in ("start_s", "start_uncertainty_s", "frame_phase_s"):
            if not math.isfinite(getattr(self, name)):
                raise ConfigError(f"audio timing {name} must be finite, got {getattr(self, name)!r}")
        if self.start_uncertainty_s < 0:
            raise ConfigError(f"start_uncertainty_s must be >= 0, got {self.start_uncertainty_s}")



class ChirpDetection(NamedTuple):
    """One beacon chirp heard by the receiver.

    ``frame`` counts frames on the walk time base (frame 0 starts at
    ``frame_phase_s``); ``tx_s`` is the emission time and ``arrival_s`` the first
    arrival, both walk time (``arrival_s`` on the receiver's stated clock);
    ``snr_db`` is the strongest tap's power over the noise power; ``associated``
    is False for a chirp heard in an acquisition window that could not be tied
    to its beacon (its features count, its time of arrival does not).
    """

    frame: int
    beacon_id: int
    tx_s: float
    arrival_s: float
    snr_db: float
    features: CirFeatures
    associated: bool = True



class SearchWindow(NamedTuple):
    """Where a beacon's chirp may start: sample indices [lo, hi] of the stream.

    ``expected``: sample index of the arrival predicted from the track (None in acquisition).
    """

    beacon_index: int
    tx_s: float
    lo: int
    hi: int
    associated: bool = True
    expected: int | None = None


MAX_START_UNCERTAINTY_S = 2.0
"""Largest stated audio-start uncertainty accepted, s: beyond a frame or two the TDMA schedule
cannot place chirps in their slots, and the acquisition search grows with it."""


def timing_from_walk(walk: WalkInfo | None, site: Site, uncertainty_override: float | None = None,
                     where: str | os.PathLike | None = None) -> AudioTiming:
    """The audio time base of a walk or survey cell: its ``[audio]`` table's ``start_s`` and
    ``start_uncertainty_s``, and the frame phase of its ``start_utc`` (see the module docstring).

    Without a walk (a bare WAV), the documented defaults: the first sample at t = 0 on a frame
    boundary, uncertainty 0.05 s. ``uncertainty_override`` replaces the stated uncertainty;
    ``where`` names the metadata file in messages (default: the walk's walk.toml / cell.toml).
    Warns (:class:`~features.acoustic.audio.AudioWarning`) when ``[audio] fs_hz`` is not 48 kHz.
    """
    if walk is None:
        u = 0.05 if uncertainty_override is None else uncertainty_override
        return AudioTiming(start_s=0.0, start_uncertainty_s=u, frame_phase_s=0.0)
    table = walk.streams.get("audio", {})
    start_s = table.get("start_s", 0.0)
    u = table.get("start_uncertainty_s", 0.05)
    if where is None or not Path(where).is_file():
        where = walk.directory / ("walk.toml" if (walk.directory / "walk.toml").is_file() else "cell.toml")
    for name, value in (("start_s", start_s), ("start_uncertainty_s", u)):
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ConfigError(f"{where}: [audio] {name} must be a finite number, got {value!r}")
    limit = (walk.duration_s or 0.0) + 3600.0
    if abs(start_s) > limit:
        raise ConfigError(f"{where}: [audio] start_s {start_s} lies more than an hour outside the walk")
    if not 0 <= u <= MAX_START_UNCERTAINTY_S:
        raise ConfigError(f"{where}: [audio] start_uncertainty_s must lie in [0, {MAX_START_UNCERTAINTY_S:g}] s, "
                          f"got {u}")
    fs = table.get("fs_hz")
    if fs is not None and (not isinstance(fs, (int, float)) or isinstance(fs, bool) or not fs > 0):
        raise ConfigError(f"{where}: [audio] fs_hz must be a positive number, got {fs!r}")
    if fs is not None and fs != 48_000:
        warnings.warn(f"[audio] fs_hz is {fs}; the file's own header rate is used", AudioWarning, stacklevel=2)
    if uncertainty_override is not None:
        u = uncertainty_override
    if walk.start_utc is None:
        raise ConfigError(f"{where}: no start_utc; the beacons' frames are tied to UTC, so audio needs it")
    return AudioTiming(start_s=float(start_s), start_uncertainty_s=float(u),
                       frame_phase_s=frame_phase_s(walk.start_utc, site.acoustic.frame_s))
