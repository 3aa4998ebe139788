"""Pseudorange variance models σᵢ² (m²) for weighted least squares and its integrity test.

The weight of satellite i is 1/σᵢ². Relative weights shape the position; the absolute σ sets
the chi-square test of RAIM (:mod:`features.gnss.wls`) and each fix's covariance, so every model
here states its variance in metres², with the constants' sources:

* :class:`EqualVariance` — σ = 4 m for every satellite: the SPS user-equivalent range error the
  NMEA path assumes for an autonomous fix (:data:`features.gnss.positions.UERE_BY_QUALITY_M`,
  Kaplan & Hegarty 2006 ch. 7); the unweighted solution.
* :class:`Cn0Variance` — the SIGMA-ε model (Hartinger & Brunner 1999, "Variances of GPS phase
  observations: the SIGMA-ε model", GPS Solutions 2(4) 35–43; Wieser & Brunner 2000, Earth Planets
  Space 52), σᵢ² = C·10^(−C/N0ᵢ/10): the tracking-loop noise variance falls as 1/(C/N0). Weights
  10^(C/N0/10) are what the smartLoc README calls "C/N0 weights". C defaults to 1.43·10⁴ m²·Hz,
  the C/N0 term of :class:`RtklibVariance` alone (R·c)²·10^(SNR_max/10): σ = 0.30 m at 52 dB-Hz,
  1.2 m at 40, 3.8 m at 30.
* :class:`StatedVariance` — the variance the source states per pseudorange
  (``pseudorange_var_m2``; smartLoc's u-blox values are 25–144 m²).
* :class:`RtklibVariance` — **the published model this project uses by default** (both
  elevation and C/N0): RTKLIB's pseudorange error variance (``pntpos.c`` ``varerr``; RTKLIB
  2.4.2 manual, Appendix E.6, elevation part; the C/N0 term added in rtklibexplorer's demo5 fork),

      σᵢ² = F_s² · R² · (a² + b²/sin elᵢ + c²·10^(0.1·max(SNR_max − C/N0ᵢ, 0))),

  with RTKLIB's defaults a = b = 0.003 m, R = 100 (code/phase error ratio, ``stats-eratio1``),
  F_s = 1 for GPS, Galileo, BeiDou, QZSS, 1.5 for GLONASS (EFACT_GLO), 3 for SBAS (EFACT_SBS),
  el floored at 5° (MIN_EL), SNR_max = 52 dB-Hz (demo5's ``stats-snrmax``). demo5 ships the C/N0
  term off (c = 0); here c = 0.003 m, equal to a and b, so that the C/N0 term equals the zenith
  floor at SNR_max and grows 10 dB per 10 dB-Hz below it — the SIGMA-ε slope. Chosen over the
  elevation-only RTKLIB model because in a street canyon or a substation the elevation says
  little about a satellite's error: a high satellite behind a wall arrives as a weak reflection
  with a long path, and only C/N0 shows it (the smartLoc README: residual median 35.5 m below
  30 dB-Hz, 6.5 m at 45 dB-Hz and above); chosen over SIGMA-ε alone because a strong low
  satellite still carries the elevation-dependent atmospheric residuals the floor a² + b²/sin el
  describes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from features.errors import ConfigError
from features.gnss.positions import UERE_BY_QUALITY_M

__all__ = ["EqualVariance", "Cn0Variance", "StatedVariance", "RtklibVariance", "WEIGHT_MODELS", "weight_model"]

_RTKLIB_SYSTEM_FACTOR = {"G": 1.0, "E": 1.0, "C": 1.0, "J": 1.0, "I": 1.0, "R": 1.5, "S": 3.0}
"""RTKLIB EFACT_* per RINEX system letter (``rtklib.h``: EFACT_GPS 1, EFACT_GLO 1.5, EFACT_SBS 3; the others 1)."""


def _positive(owner: str, **values):
    for name, v in values.items():
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ConfigError(f"{owner}.{name} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class EqualVariance:
    """σ² = sigma_m² for every satellite (the unweighted solution)."""

    sigma_m: float = UERE_BY_QUALITY_M[1]
    name: str = "equal"

    def __post_init__(self):
        _positive("EqualVariance", sigma_m=self.sigma_m)

    def variance_m2(self, cn0_dbhz, elevation_deg, system, stated_var_m2) -> np.ndarray:
        """σ² per satellite, shape of ``cn0_dbhz``."""
        return np.full(np.shape(cn0_dbhz), self.sigma_m ** 2)


@dataclass(frozen=True)
class Cn0Variance:
    """SIGMA-ε: σ² = constant_m2_hz · 10^(−C/N0/10) (module docstring).

    >>> round(float(Cn0Variance().variance_m2(np.array(40.0), 0, "G", 0)) ** 0.5, 2)
    1.19
    """

    constant_m2_hz: float = (100.0 * 0.003) ** 2 * 10.0 ** (52.0 / 10.0)
    name: str = "cn0"

    def __post_init__(self):
        _positive("Cn0Variance", constant_m2_hz=self.constant_m2_hz)

    def variance_m2(self, cn0_dbhz, elevation_deg, system, stated_var_m2) -> np.ndarray:
        """σ² per satellite; a satellite without C/N0 (NaN) gets infinite variance (no weight)."""
        cn0 = np.asarray(cn0_dbhz, dtype=float)
        return np.where(np.isfinite(cn0), self.constant_m2_hz * 10.0 ** (-np.nan_to_num(cn0) / 10.0), np.inf)


@dataclass(frozen=True)
class StatedVariance:
    """σ² as the source states it per pseudorange (``pseudorange_var_m2``); NaN → no weight."""

    name: str = "stated"

    def variance_m2(self, cn0_dbhz, elevation_deg, system, stated_var_m2) -> np.ndarray:
        v = np.asarray(stated_var_m2, dtype=float)
        return np.where(np.isfinite(v) & (v > 0), v, np.inf)


@dataclass(frozen=True)
class RtklibVariance:
    """RTKLIB (demo5) pseudorange variance from elevation and C/N0 (module docstring).

    >>> m = RtklibVariance()
    >>> [round(float(m.variance_m2(np.array(c), np.array(e), np.array("G"), 0)), 4) for c, e in ((52, 90), (42, 30))]
    [0.27, 1.17]
    """

    a_m: float = 0.003
    b_m: float = 0.003
    c_m: float = 0.003
    error_ratio: float = 100.0
    snr_max_dbhz: float = 52.0
    min_elevation_deg: float = 5.0
    name: str = "rtklib"

    def __post_init__(self):
        _positive("RtklibVariance", a_m=self.a_m, error_ratio=self.error_ratio, snr_max_dbhz=self.snr_max_dbhz,
                  min_elevation_deg=self.min_elevation_deg)
        for name in ("b_m", "c_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"RtklibVariance.{name} must be a number >= 0, got {v!r}")

    def variance_m2(self, cn0_dbhz, elevation_deg, system, stated_var_m2) -> np.ndarray:
        """σ² per satellite; without an elevation the 5° floor is used, without C/N0 SNR_max − C/N0 = 0."""
        el = np.asarray(elevation_deg, dtype=float)
        el = np.radians(np.maximum(np.where(np.isfinite(el), el, self.min_elevation_deg), self.min_elevation_deg))
        cn0 = np.asarray(cn0_dbhz, dtype=float)
        deficit = np.maximum(self.snr_max_dbhz - np.where(np.isfinite(cn0), cn0, self.snr_max_dbhz), 0.0)
        # var = R²·(a² + b²/sin el + c²·10^(0.1·(SNR_max − SNR)))      (RTKLIB demo5 pntpos.c varerr)
        var = self.error_ratio ** 2 * (self.a_m ** 2 + self.b_m ** 2 / np.sin(el)
                                       + self.c_m ** 2 * 10.0 ** (0.1 * deficit))
        letters, index = np.unique(np.asarray(system), return_inverse=True)
        fact = np.array([_RTKLIB_SYSTEM_FACTOR.get(str(k), 1.0) for k in letters.ravel()])[index.reshape(np.shape(system))]
        return fact ** 2 * var


WEIGHT_MODELS = {"equal": EqualVariance, "cn0": Cn0Variance, "stated": StatedVariance, "rtklib": RtklibVariance}
"""Weight model by name (command-line choices)."""


def weight_model(name: str):
    """The default-parameter model of that name (one of :data:`WEIGHT_MODELS`)."""
    try:
        return WEIGHT_MODELS[name]()
    except KeyError:
        raise ConfigError(f"weight model must be one of {sorted(WEIGHT_MODELS)}, got {name!r}") from None
