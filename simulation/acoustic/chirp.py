"""The beacon waveform and its TDMA schedule (transmit side; docs/beacon_protocol.md).

Waveform. Beacon ``b`` emits a tapered linear up-chirp from ``f0`` to ``f1`` Hz
over ``T`` seconds (site ``[acoustic]``, overridden per beacon by
``f0_hz``/``f1_hz``/``chirp_duration_s`` in ``[[beacons]]``)::

    s(t) = w(t) · sin(2π (f0·t + ½·k·t²)),  k = (f1 − f0)/T,  0 ≤ t < T

sampled at ``t_n = n/fs``, ``n = 0 … N−1``, ``N = round(T·fs)``; ``w`` is the
Tukey window of ``scipy.signal.windows.tukey(N, alpha=taper_fraction)``
(symmetric, raised-cosine flanks each ``alpha/2`` of the chirp long). Peak
amplitude 1; the source level ``[acoustic] source_level_db`` is the RMS sound
pressure of the untapered part at 1 m, dB SPL.

Schedule. Beacons are synchronised to GNSS-disciplined UTC. Frames of
``frame_s = n_slots·slot_s`` start at integer multiples of ``frame_s`` of POSIX
UTC time (seconds since 1970-01-01T00:00:00Z, leap seconds not counted); beacon
``b`` starts its chirp ``slot_b·slot_s`` after each frame start. On a walk's
time base (seconds since ``start_utc``) the emissions are therefore at
``t = k·frame_s + slot·slot_s − (start_utc mod frame_s)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np
from scipy.signal.windows import tukey

from features.errors import ConfigError
from features.site import Beacon, Site

__all__ = ["ChirpSpec", "beacon_chirp", "chirp_length", "chirp_waveform", "reference_chirp", "frame_phase_s",
           "emission_times_s", "slot_reuse_conflicts"]

_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)


@dataclass(frozen=True)
class ChirpSpec:
    """One beacon's chirp: band ``f0_hz``→``f1_hz``, ``duration_s``, Tukey ``taper_fraction``."""

    f0_hz: float
    f1_hz: float
    duration_s: float
    taper_fraction: float

    def __post_init__(self):
        for name in ("f0_hz", "f1_hz", "duration_s", "taper_fraction"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ConfigError(f"chirp {name} must be a finite number, got {v!r}")
        if not 0 < self.f0_hz < self.f1_hz:
            raise ConfigError(f"chirp band must satisfy 0 < f0_hz < f1_hz, got {self.f0_hz}..{self.f1_hz}")
        if self.duration_s <= 0:
            raise ConfigError(f"chirp duration_s must be positive, got {self.duration_s}")
        if not 0.0 <= self.taper_fraction <= 1.0:
            raise ConfigError(f"chirp taper_fraction must lie in [0, 1], got {self.taper_fraction}")

    @property
    def sweep_rate_hz_s(self) -> float:
        """k = (f1 − f0)/T, Hz/s."""
        return (self.f1_hz - self.f0_hz) / self.duration_s

    @property
    def time_bandwidth(self) -> float:
        """T·B: the matched filter's pulse-compression gain as a power ratio."""
        return self.duration_s * (self.f1_hz - self.f0_hz)


def beacon_chirp(site: Site, beacon: Beacon) -> ChirpSpec:
    """The chirp of ``beacon``: its own band/duration where given, else the site's ``[acoustic]``."""
    ac = site.acoustic
    spec = ChirpSpec(f0_hz=ac.f0_hz if beacon.f0_hz is None else beacon.f0_hz,
                     f1_hz=ac.f1_hz if beacon.f1_hz is None else beacon.f1_hz,
                     duration_s=ac.chirp_duration_s if beacon.chirp_duration_s is None else beacon.chirp_duration_s,
                     taper_fraction=ac.taper_fraction)
    if spec.f1_hz > 24_000.0:
        raise ConfigError(f"beacon {beacon.id}: f1_hz {spec.f1_hz} lies above the 24 kHz Nyquist limit of 48 kHz audio")
    if spec.duration_s >= ac.slot_s:
        raise ConfigError(f"beacon {beacon.id}: chirp_duration_s {spec.duration_s} does not fit its {ac.slot_s} s slot")
    return spec


def _tukey_continuous(x: np.ndarray, alpha: float) -> np.ndarray:
    """Tukey window on x ∈ [0, 1] (0 outside): scipy's ``tukey`` with x = n/(N−1) (Harris 1978, eq. 38)."""
    w = np.zeros_like(x)
    inside = (x >= 0.0) & (x <= 1.0)
    w[inside] = 1.0
    if alpha > 0:
        half = alpha / 2.0
        lo = inside & (x < half)
        hi = inside & (x > 1.0 - half)
        w[lo] = 0.5 * (1.0 - np.cos(np.pi * x[lo] / half))
        w[hi] = 0.5 * (1.0 - np.cos(np.pi * (1.0 - x[hi]) / half))
    return w


def chirp_length(spec: ChirpSpec, fs_hz: float, time_scale: float = 1.0) -> int:
    """Samples of the chirp heard with Doppler factor η = ``time_scale``: ceil(N/η), N = round(T·fs).

    >>> chirp_length(ChirpSpec(17000.0, 23000.0, 0.010, 0.2), 48000.0, 1.001)
    480
    """
    if not 0.9 < time_scale < 1.1:
        raise ValueError(f"time_scale must lie near 1 (|v| << c), got {time_scale}")
    n_ref = int(round(spec.duration_s * fs_hz))
    if n_ref < 2:
        raise ConfigError(f"chirp of {spec.duration_s} s is shorter than two samples at {fs_hz} Hz")
    return int(math.ceil(n_ref / time_scale))


def chirp_waveform(spec: ChirpSpec, fs_hz: float, time_scale: float = 1.0) -> np.ndarray:
    """Sampled chirp ``s(η·t_n)``, t_n = n/fs: the waveform as heard with Doppler factor η.

    ``time_scale`` η = 1 + v/c for a receiver closing on the source at v m/s
    (moving-observer Doppler: every frequency scaled by η and the chirp shortened
    by 1/η). With η = 1 this is exactly the reference of the module docstring.

    Returns
    -------
    ndarray of shape (ceil(N/η),), float64, peak amplitude ≤ 1.

    >>> spec = ChirpSpec(17000.0, 23000.0, 0.010, 0.2)
    >>> s = chirp_waveform(spec, 48000.0)
    >>> s.shape, float(s[0]), round(float(np.abs(s).max()), 3)
    ((480,), 0.0, 1.0)
    """
    n_ref = int(round(spec.duration_s * fs_hz))
    t = np.arange(chirp_length(spec, fs_hz, time_scale)) * (time_scale / fs_hz)
    x = t * fs_hz / (n_ref - 1)
    w = _tukey_continuous(x, spec.taper_fraction)
    phase = 2.0 * np.pi * (spec.f0_hz * t + 0.5 * spec.sweep_rate_hz_s * t * t)
    return w * np.sin(phase)


def reference_chirp(spec: ChirpSpec, fs_hz: float) -> np.ndarray:
    """The documented reference with scipy's own Tukey window (equals ``chirp_waveform`` at η = 1)."""
    n = int(round(spec.duration_s * fs_hz))
    t = np.arange(n) / fs_hz
    phase = 2.0 * np.pi * (spec.f0_hz * t + 0.5 * spec.sweep_rate_hz_s * t * t)
    return tukey(n, alpha=spec.taper_fraction) * np.sin(phase)


def frame_phase_s(start_utc: datetime, frame_s: float) -> float:
    """Time since the last frame start at ``start_utc``: (POSIX seconds of start_utc) mod frame_s.

    Computed in integer microseconds so that 1.8e9 s of POSIX time lose no precision.

    >>> from datetime import datetime, timezone
    >>> frame_phase_s(datetime(2026, 5, 1, 8, 0, 0, 300000, tzinfo=timezone.utc), 0.8)
    0.3
    """
    if start_utc.tzinfo is None:
        raise ConfigError(f"start_utc must be timezone-aware (UTC), got {start_utc!r}")
    delta = start_utc - _EPOCH
    start_us = (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds
    frame_us = int(round(frame_s * 1e6))
    if frame_us <= 0:
        raise ConfigError(f"frame_s must be positive, got {frame_s}")
    return (start_us % frame_us) / 1e6


def emission_times_s(site: Site, beacon: Beacon, start_utc: datetime, t_begin_s: float,
                     t_end_s: float) -> np.ndarray:
    """Chirp start instants of ``beacon`` in [t_begin_s, t_end_s) on the walk's time base.

    Returns ndarray of shape (n,), ascending: ``k·frame_s + slot·slot_s − phase``.

    >>> from datetime import datetime, timezone
    >>> from features.site import Site, Origin, Beacon
    >>> b = Beacon(id=1, east_m=0.0, north_m=0.0, up_m=3.0, slot=2)
    >>> site = Site(name="t", origin=Origin(31.0, 118.0), beacons=(b,))
    >>> start = datetime(2026, 5, 1, 8, 0, 0, 100000, tzinfo=timezone.utc)
    >>> emission_times_s(site, b, start, 0.0, 2.0).round(6).tolist()
    [0.1, 0.9, 1.7]
    """
    ac = site.acoustic
    frame_s = ac.frame_s
    offset = beacon.slot * ac.slot_s - frame_phase_s(start_utc, frame_s)
    k0 = math.ceil((t_begin_s - offset) / frame_s - 1e-9)
    k1 = math.ceil((t_end_s - offset) / frame_s - 1e-9)
    return offset + frame_s * np.arange(k0, max(k0, k1), dtype=float)


def slot_reuse_conflicts(site: Site, min_separation_m: float) -> list[tuple[int, int, float]]:
    """Pairs of beacons sharing a TDMA slot (and band) closer than ``min_separation_m`` (horizontal).

    A receiver that can hear both beacons of a pair cannot tell their chirps
    apart, so slot-mates must stand at least twice the detection range apart
    (then no point hears both). Returns (id_a, id_b, distance_m) tuples.
    """
    out = []
    bs = site.beacons
    for i in range(len(bs)):
        for j in range(i + 1, len(bs)):
            a, b = bs[i], bs[j]
            if a.slot != b.slot or beacon_chirp(site, a) != beacon_chirp(site, b):
                continue
            d = math.hypot(a.east_m - b.east_m, a.north_m - b.north_m)
            if d < min_separation_m:
                out.append((a.id, b.id, d))
    return out
