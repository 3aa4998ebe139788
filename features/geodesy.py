"""Geodetic ↔ ENU conversions about a site origin (pymap3d), and sky-direction helpers.

Frames: ENU metres about the origin; azimuth in radians from north, clockwise
(navigation convention); elevation in radians above the local horizontal.
"""

from __future__ import annotations

import numpy as np
import pymap3d

__all__ = ["geodetic_to_enu", "enu_to_geodetic", "ecef_to_enu", "azel_to_unit_enu", "unit_enu_to_azel"]


def geodetic_to_enu(lat_deg, lon_deg, alt_m, lat0_deg: float, lon0_deg: float, alt0_m: float):
    """Geodetic (WGS-84) to ENU metres about the origin.

    >>> e, n, u = geodetic_to_enu(30.001, 120.0, 10.0, 30.0, 120.0, 10.0)
    >>> print(f"{float(e):.3f} {float(n):.1f} {float(u):.3f}")
    0.000 110.9 -0.001
    """
    return pymap3d.geodetic2enu(lat_deg, lon_deg, alt_m, lat0_deg, lon0_deg, alt0_m)


def enu_to_geodetic(east_m, north_m, up_m, lat0_deg: float, lon0_deg: float, alt0_m: float):
    """ENU metres about the origin to geodetic (lat_deg, lon_deg, alt_m)."""
    return pymap3d.enu2geodetic(east_m, north_m, up_m, lat0_deg, lon0_deg, alt0_m)


def ecef_to_enu(x_m, y_m, z_m, lat0_deg: float, lon0_deg: float, alt0_m: float):
    """ECEF metres to ENU metres about the origin."""
    return pymap3d.ecef2enu(x_m, y_m, z_m, lat0_deg, lon0_deg, alt0_m)


def azel_to_unit_enu(az_rad, el_rad):
    """Unit line-of-sight vectors in ENU from azimuth (from north, clockwise) and elevation.

    Returns ndarray of shape (..., 3).

    >>> np.round(azel_to_unit_enu(np.pi / 2, 0.0), 6).tolist()
    [1.0, 0.0, 0.0]
    """
    az = np.asarray(az_rad, dtype=float)
    el = np.asarray(el_rad, dtype=float)
    ce = np.cos(el)
    return np.stack([ce * np.sin(az), ce * np.cos(az), np.sin(el)], axis=-1)


def unit_enu_to_azel(v):
    """Azimuth (from north, clockwise, in [0, 2π)) and elevation of ENU vectors of shape (..., 3)."""
    v = np.asarray(v, dtype=float)
    horiz = np.hypot(v[..., 0], v[..., 1])
    az = np.mod(np.arctan2(v[..., 0], v[..., 1]), 2.0 * np.pi)
    el = np.arctan2(v[..., 2], horiz)
    return az, el
