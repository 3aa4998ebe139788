"""Receiver fixes → site ENU positions with a measurement standard deviation, for the fusion filter.

The ellipsoidal height is GGA's altitude above mean sea level plus its geoid
separation (NMEA 0183 GGA fields 9 and 11; when the separation is empty the
altitude is taken as ellipsoidal, as receivers without a geoid model report
it); ENU about the site origin via :mod:`features.geodesy` (pymap3d).

Standard deviation per horizontal axis, σ = UERE(quality) · HDOP / √2, from
the classic error model σ_position = UERE · DOP (Kaplan & Hegarty,
*Understanding GPS*, 2nd ed. 2006, ch. 7), the horizontal error split
equally between east and north. The UERE per fix mode are order-of-magnitude
values of typical error budgets and receiver datasheets, chosen here, not
measured: they only seed the fusion filter, whose per-class measurement
noise is learnt from training walks (DESIGN.md §7).

=======  ==========================  ============  =========================================
quality  mode (GGA field 6)          UERE (1σ)     reasoning
=======  ==========================  ============  =========================================
1        autonomous (SPS)            4.0 m         single-frequency code, broadcast
                                                   ionosphere: metres
2, 9     DGNSS / SBAS                1.0 m         code corrections from a nearby base or
                                                   SBAS remove most common-mode error
3        PPS                         2.8 m         as autonomous, dual-frequency ionosphere
4        RTK fixed                   0.03 m        carrier phase, integer ambiguities:
                                                   datasheets quote ≈ 1 cm + 1 ppm
5        RTK float                   0.4 m         float ambiguities: decimetres
6        dead reckoning              15 m          estimated, not measured: weak update
=======  ==========================  ============  =========================================

so σ_axis = UERE·HDOP/√2 (e.g. RTK fixed ≈ 0.02 m·HDOP, DGNSS ≈ 0.7 m·HDOP).
Vertical: σ_up = UERE·VDOP when VDOP is known, else UERE·1.5·HDOP (VDOP ≈
1.5 HDOP for typical open-sky geometry). When HDOP is missing, 2.0 is assumed
(a middling geometry) and the row is flagged ``hdop_assumed``. Qualities 0
(no fix), 7 (manual input) and 8 (simulator) produce no row: they are not
measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from features.errors import DataError
from features.geodesy import geodetic_to_enu

__all__ = ["UERE_BY_QUALITY_M", "ASSUMED_HDOP", "GnssPositions", "fixes_to_enu", "sigma_axis_m"]

UERE_BY_QUALITY_M = {1: 4.0, 2: 1.0, 3: 2.8, 4: 0.03, 5: 0.4, 6: 15.0, 9: 1.0}
"""User-equivalent range error (1σ, metres) per GGA quality code (module docstring table)."""

ASSUMED_HDOP = 2.0
"""HDOP assumed when a fix reports none."""


def sigma_axis_m(quality: int, hdop: float) -> float:
    """Per-axis horizontal σ in metres: UERE(quality) · HDOP / √2.

    >>> round(sigma_axis_m(4, 1.0), 4), round(sigma_axis_m(2, 1.0), 3)
    (0.0212, 0.707)
    """
    return UERE_BY_QUALITY_M[quality] * hdop / math.sqrt(2.0)


@dataclass(frozen=True)
class GnssPositions:
    """Fix positions on the site's ENU frame; every array of shape (n,).

    ``sigma_en_m`` is σ per horizontal axis (east and north alike).
    """

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    up_m: np.ndarray
    sigma_en_m: np.ndarray
    sigma_up_m: np.ndarray
    quality: np.ndarray
    n_used: np.ndarray
    hdop: np.ndarray
    hdop_assumed: np.ndarray

    COLUMNS = ("t_s", "east_m", "north_m", "up_m", "sigma_en_m", "sigma_up_m", "quality", "n_used", "hdop",
               "hdop_assumed")

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def fixes_to_enu(epochs: Sequence, lat0_deg: float, lon0_deg: float, alt0_m: float) -> GnssPositions:
    """Convert the epochs' fixes to ENU about (lat0, lon0, alt0 ellipsoidal); no fix → no row."""
    for name, value in (("lat0_deg", lat0_deg), ("lon0_deg", lon0_deg), ("alt0_m", alt0_m)):
        if not math.isfinite(value):
            raise DataError(f"site origin {name} must be finite, got {value}")
    rows = []
    for e in epochs:
        f = e.fix
        if not f.has_position or f.quality not in UERE_BY_QUALITY_M:
            continue
        hdop = f.hdop
        assumed = hdop is None
        hdop = ASSUMED_HDOP if assumed else hdop
        uere = UERE_BY_QUALITY_M[f.quality]
        alt = (f.alt_m or 0.0) + (f.geoid_sep_m or 0.0) if f.alt_m is not None else alt0_m
        sigma_up = uere * (f.vdop if f.vdop is not None else 1.5 * hdop)
        rows.append((e.t_s, f.lat_deg, f.lon_deg, alt, uere * hdop / math.sqrt(2.0), sigma_up, f.quality,
                     -1 if f.n_used is None else f.n_used, hdop, assumed))
    if not rows:
        empty = np.zeros(0)
        return GnssPositions(empty, empty, empty, empty, empty, empty, np.zeros(0, int), np.zeros(0, int), empty,
                             np.zeros(0, bool))
    cols = list(zip(*rows))
    lat, lon, alt = (np.asarray(c, dtype=float) for c in cols[1:4])
    e, n, u = geodetic_to_enu(lat, lon, alt, lat0_deg, lon0_deg, alt0_m)
    return GnssPositions(
        t_s=np.asarray(cols[0], float), east_m=np.asarray(e, float), north_m=np.asarray(n, float),
        up_m=np.asarray(u, float), sigma_en_m=np.asarray(cols[4], float), sigma_up_m=np.asarray(cols[5], float),
        quality=np.asarray(cols[6], int), n_used=np.asarray(cols[7], int), hdop=np.asarray(cols[8], float),
        hdop_assumed=np.asarray(cols[9], bool),
    )
