"""Receiver velocity (RMC speed and course) from simulated Doppler errors, never truth plus a constant noise.

Per satellite, the range-rate error is

* FLL tracking jitter, σ_f = 1/(2πT)·sqrt(4F·B_n/(C/N0)·(1 + 1/(T·C/N0))) Hz
  (Kaplan & Hegarty 2017, *Understanding GPS/GNSS*, 3rd ed., eq. (8.43) for
  the frequency-lock loop; F = 1, B_n = 2 Hz, T = 20 ms), times the wavelength,
  white from epoch to epoch; it grows as the C/N0 falls;
* for a reflected (NLOS) signal, the difference between the Doppler of the
  image source and of the satellite, v·cos(el)·ξ with ξ a Gauss–Markov process
  in distance walked (σ ``nlos_doppler_share``, correlation over
  ``nlos_corr_dist_m``): a walker moving along a wall sees the reflection's
  Doppler off the direct one by up to 2·v·cos(el).

The receiver solves velocity and clock drift by the same weighted least
squares as the position (:mod:`simulation.gnss.fix`), over the satellites used
in the fix; speed and course follow from the east/north velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from features.errors import ConfigError
from simulation.gnss.fix import _design, _wls, distance_gm_phi, gauss_markov

__all__ = ["VelocityConfig", "fll_jitter_hz", "velocity_errors"]


@dataclass(frozen=True)
class VelocityConfig:
    """Doppler tracking and NLOS parameters (Hz, s, m as named)."""

    fll_bandwidth_hz: float = 2.0
    integration_s: float = 0.02
    nlos_doppler_share: float = 0.7
    nlos_corr_dist_m: float = 10.0
    nlos_tau_s: float = 60.0
    floor_m_s: float = 0.01

    def __post_init__(self):
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"VelocityConfig.{name} must be finite and non-negative, got {value!r}")
        if self.integration_s <= 0 or self.nlos_corr_dist_m <= 0 or self.nlos_tau_s <= 0:
            raise ConfigError("VelocityConfig needs integration_s, nlos_corr_dist_m and nlos_tau_s > 0")


def fll_jitter_hz(cn0_dbhz, bandwidth_hz: float = 2.0, integration_s: float = 0.02) -> np.ndarray:
    """FLL frequency jitter σ_f, Hz (Kaplan & Hegarty 2017, eq. (8.43), F = 1).

    >>> [round(float(x), 3) for x in fll_jitter_hz(np.array([45.0, 30.0]))]
    [0.127, 0.729]
    """
    c = 10.0 ** (np.asarray(cn0_dbhz, float) / 10.0)
    t = integration_s
    return 1.0 / (2.0 * np.pi * t) * np.sqrt(4.0 * bandwidth_hz / c * (1.0 + 1.0 / (t * c)))


def velocity_errors(rng: np.random.Generator, az_rad: np.ndarray, el_rad: np.ndarray, sys_idx: np.ndarray,
                    used: np.ndarray, cn0_dbhz: np.ndarray, nlos: np.ndarray, speed_m_s: np.ndarray, dt_s: float,
                    wavelength_m: float, cfg: VelocityConfig = VelocityConfig()) -> np.ndarray:
    """East/north velocity error of the receiver's Doppler solution, (n, 2) m/s (NaN without a fix).

    Parameters
    ----------
    az_rad, el_rad, used, cn0_dbhz, nlos : (n, k); sys_idx : (k,); speed_m_s : (n,)
    """
    n, k = el_rad.shape
    cn0 = np.nan_to_num(cn0_dbhz, nan=25.0)
    sig = np.hypot(wavelength_m * fll_jitter_hz(cn0, cfg.fll_bandwidth_hz, cfg.integration_s), cfg.floor_m_s)
    rr = sig * rng.standard_normal((n, k))
    xi = cfg.nlos_doppler_share * gauss_markov(rng, distance_gm_phi(speed_m_s, dt_s, cfg.nlos_tau_s,
                                                                    cfg.nlos_corr_dist_m), (n, k))
    rr = rr + np.where(nlos, np.asarray(speed_m_s, float)[:, None] * np.cos(el_rad) * xi, 0.0)
    g = _design(az_rad, el_rad, sys_idx)
    w = np.where(used, 1.0 / sig ** 2, 0.0)
    theta, _ = _wls(g, w, rr)
    out = theta[:, :2].copy()
    out[used.sum(axis=1) < 4] = np.nan
    return out
