"""Beacon and recorder hardware the site file does not describe (issue 10 item 4).

* **Beacon survey error**: the poles stand where the installer put them; the
  crew's survey of them (``site.toml``) is off by a few centimetres — GNSS RTK
  survey of a pole base plus the mounting offset: N(0, 2 cm) per horizontal
  axis, N(0, 3 cm) vertically, fixed per site and beacon.
* **Emission delay and jitter**: a beacon's chirp leaves the tweeter after
  the GNSS pulse-per-second edge by a fixed latency of its firmware, DAC and
  amplifier that its maker calibrates only to tens of microseconds (residual
  N(0, 30 µs) per beacon, ≈ 1 cm), plus a per-emission jitter of the audio
  clock re-alignment (N(0, 10 µs)); a u-blox timing receiver's PPS is itself
  good to ≈ 30 ns (NEO-M8T data sheet), negligible here.
* **Microphone and codec response**: the recorder's MEMS microphone and
  codec anti-alias filter roll off near the band's top (many phone codecs
  near 21–22 kHz): a 4th-order Butterworth low-pass whose corner is drawn
  per device in U(21, 23) kHz, applied to everything recorded (chirps and
  noise) with scipy's ``sosfilt``, state carried across blocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from features.errors import ConfigError
from features.site import Site
from simulation.rng import stream_rng

__all__ = ["HardwareConfig", "true_beacon_positions", "beacon_delays_s", "CodecFilter"]


@dataclass(frozen=True)
class HardwareConfig:
    """Hardware error parameters (m, s, Hz as named); each term off when its size is 0."""

    survey_sigma_h_m: float = 0.02
    survey_sigma_v_m: float = 0.03
    emission_delay_sigma_s: float = 30e-6
    emission_jitter_s: float = 10e-6
    codec_corner_min_hz: float = 21_000.0
    codec_corner_max_hz: float = 23_000.0
    codec_order: int = 4

    def __post_init__(self):
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"HardwareConfig.{name} must be finite and non-negative, got {value!r}")
        if self.codec_corner_max_hz < self.codec_corner_min_hz or self.codec_corner_max_hz >= 24_000.0:
            raise ConfigError("HardwareConfig needs codec_corner_min_hz <= codec_corner_max_hz < 24000")


def _site_seed(site: Site) -> int:
    return int(site.seed) if site.seed is not None else 0


def true_beacon_positions(site: Site, cfg: HardwareConfig = HardwareConfig()) -> dict[int, np.ndarray]:
    """Where each beacon really is, ENU m: ``site.toml``'s surveyed position plus the survey error (per site)."""
    out = {}
    for b in site.beacons:
        rng = stream_rng(_site_seed(site), "audio", "beacon_survey", b.id)
        d = rng.standard_normal(3) * np.array([cfg.survey_sigma_h_m, cfg.survey_sigma_h_m, cfg.survey_sigma_v_m])
        out[b.id] = np.array([b.east_m, b.north_m, b.up_m]) + d
    return out


def beacon_delays_s(site: Site, cfg: HardwareConfig = HardwareConfig()) -> dict[int, float]:
    """Fixed emission latency residual of each beacon, s (per site: the hardware stays on its pole)."""
    return {b.id: float(stream_rng(_site_seed(site), "audio", "beacon_delay", b.id).normal(0.0, 1.0)
                        * cfg.emission_delay_sigma_s) for b in site.beacons}


class CodecFilter:
    """The recorder's microphone + codec low-pass, applied block by block (state kept between blocks).

    >>> f = CodecFilter(48_000, np.random.default_rng(0))
    >>> x = np.sin(2 * np.pi * 17_000 * np.arange(4800) / 48_000)
    >>> bool(0.9 < np.std(f(x)[1000:]) / np.std(x) < 1.05)
    True
    """

    def __init__(self, fs_hz: float, rng: np.random.Generator, cfg: HardwareConfig = HardwareConfig()):
        self.corner_hz = float(rng.uniform(cfg.codec_corner_min_hz, cfg.codec_corner_max_hz))
        self.enabled = cfg.codec_order > 0
        if self.enabled:
            self.sos = signal.butter(int(cfg.codec_order), self.corner_hz, btype="low", fs=fs_hz, output="sos")
            self.zi = np.zeros((self.sos.shape[0], 2))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if not self.enabled:
            return x
        y, self.zi = signal.sosfilt(self.sos, x, zi=self.zi)
        return y
