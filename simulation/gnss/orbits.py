"""GPS and BeiDou-3 constellations on circular Keplerian orbits; azimuth/elevation at a site.

Model
-----
Every satellite moves on a circular two-body orbit: radius ``a``, inclination
``i``, right ascension of the ascending node ``Ω`` (fixed in inertial space:
no J2 nodal regression, no eccentricity) and argument of latitude
``u(t) = u0 + n·(t − t_ref)`` with the mean motion ``n = sqrt(GM/a³)``
(Kepler's third law). The inertial (ECI, true-of-date is not distinguished
from J2000 at this accuracy) position is

    r_ECI = a · [cosΩ·cos u − sinΩ·sin u·cos i,
                 sinΩ·cos u + cosΩ·sin u·cos i,
                 sin u·sin i]

(Montenbruck & Gill 2000, *Satellite Orbits*, eq. 2.50 with e = 0) and the
Earth-fixed (ECEF) position follows from a rotation about z by the Greenwich
mean sidereal time θ_g (IAU 1982 model, Vallado 2013, *Fundamentals of
Astrodynamics and Applications*, eq. 3-47). Polar motion, nutation and
UT1 − UTC (< 0.9 s) are ignored: they move a satellite by well under a
kilometre, i.e. < 0.002° in elevation. GEO satellites are placed directly at
their fixed ECEF slot.

Constellations
--------------
* **GPS**: the 24 baseline slots of the GPS SPS Performance Standard (2001,
  Table 3-1; also Kaplan & Hegarty 2017, Table 3.1): six planes 60° apart in
  RAAN, i = 55°, a = 26 559.7 km, unevenly phased, with RAAN and argument of
  latitude given at the defined epoch 1993-07-01 00:00 UT. Seven more
  satellites bring the count to 31, each placed in the middle of the widest
  remaining in-plane gap (a fixed, deterministic reference arrangement;
  planes in order A..F). PRNs 1–32 without PRN 31 (:data:`GPS_PRNS`).
  Because real orbits precess (≈ −0.04°/day) and this model does not, the
  sky is a plausible GPS sky, not the real one of a given date.
* **BeiDou-3**: 24 MEO in a Walker 55°:24/3/1 constellation at a =
  6378.137 + 21 528 km (BDS-SIS-ICD; Yang et al. 2019, "Introduction to
  BeiDou-3 navigation satellite system", Navigation 66(1)); 3 IGSO at the
  geostationary radius, i = 55°, planes 120° apart, sharing one figure-8 ground
  track whose ascending node lies at 118° E; 3 GEO at 80°, 110.5° and 140° E.

Times are UTC POSIX seconds (float) or timezone-aware datetimes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np
import pymap3d

from features.constants import GEO_RADIUS_M, GM_EARTH_M3_S2

__all__ = [
    "Satellites", "gps_constellation", "beidou_constellation", "all_satellites",
    "gmst_rad", "to_unix_s", "eci_positions", "ecef_positions", "azel",
    "GPS_PRNS", "BDS_MEO_PRNS", "BDS_IGSO_PRNS", "BDS_GEO_PRNS",
    "SYSTEM_GPS", "SYSTEM_BDS",
]

SYSTEM_GPS = "GPS"
SYSTEM_BDS = "BDS"

GPS_A_M = 26_559_700.0
"""GPS nominal semi-major axis, m (SPS Performance Standard 2001, §3.1)."""

BDS_MEO_A_M = 6_378_137.0 + 21_528_000.0
"""BeiDou-3 MEO semi-major axis, m: Earth radius + 21 528 km altitude (BDS-SIS-ICD)."""

_GPS_EPOCH_UNIX_S = datetime(1993, 7, 1, tzinfo=timezone.utc).timestamp()
"""Defined epoch of the GPS reference slot table, 1993-07-01 00:00 UT."""

_BDS_EPOCH_UNIX_S = datetime(2020, 1, 1, tzinfo=timezone.utc).timestamp()
"""Reference epoch chosen for the BeiDou Walker and IGSO phasing (a modelling choice)."""

# GPS SPS Performance Standard (2001), Table 3-1: slot → (RAAN°, argument of latitude°) at the defined epoch.
_GPS_SLOTS = {
    "A": (272.847, (268.126, 161.786, 11.676, 41.806)),
    "B": (332.847, (80.956, 173.336, 309.976, 204.376)),
    "C": (32.847, (111.876, 11.796, 339.666, 241.556)),
    "D": (92.847, (135.226, 265.446, 35.156, 167.356)),
    "E": (152.847, (197.046, 302.596, 66.066, 333.686)),
    "F": (212.847, (238.886, 345.226, 105.206, 135.346)),
}

GPS_PRNS = tuple(p for p in range(1, 33) if p != 31)
"""31 GPS PRNs (1–32 without one; PRN 31 is the one left out here)."""

BDS_MEO_PRNS = tuple(range(19, 31)) + tuple(range(32, 38)) + tuple(range(41, 47))
"""24 BeiDou-3 MEO PRNs: C19–C30, C32–C37, C41–C46."""

BDS_IGSO_PRNS = (38, 39, 40)
BDS_GEO_PRNS = (59, 60, 61)
BDS_GEO_LON_DEG = (140.0, 80.0, 110.5)
"""GEO slots of C59, C60, C61 (degrees east)."""

BDS_IGSO_NODE_LON_DEG = 118.0
"""Geographic longitude of the IGSO ground track's ascending node (docs/design.md §6)."""


@dataclass(frozen=True, eq=False)
class Satellites:
    """A set of satellites on circular orbits; every array has shape (k,).

    Attributes
    ----------
    system : ndarray of str
        ``"GPS"`` or ``"BDS"``.
    prn : ndarray of int
        The system's own satellite number (GPS PRN, BeiDou C-number).
    orbit : ndarray of str
        ``"MEO"``, ``"IGSO"`` or ``"GEO"``.
    a_m, inc_rad, raan_rad, u0_rad, t_ref_unix_s : ndarrays of float
        Radius, inclination, RAAN and argument of latitude at ``t_ref_unix_s``.
    geo_lon_rad : ndarray of float
        Fixed longitude of GEO satellites (NaN for the others).
    """

    system: np.ndarray
    prn: np.ndarray
    orbit: np.ndarray
    a_m: np.ndarray
    inc_rad: np.ndarray
    raan_rad: np.ndarray
    u0_rad: np.ndarray
    t_ref_unix_s: np.ndarray
    geo_lon_rad: np.ndarray

    def __post_init__(self):
        k = len(self.prn)
        for name in ("system", "orbit", "a_m", "inc_rad", "raan_rad", "u0_rad", "t_ref_unix_s", "geo_lon_rad"):
            if len(getattr(self, name)) != k:
                raise ValueError(f"Satellites.{name} has length {len(getattr(self, name))}, expected {k}")
        for name in ("system", "prn", "orbit", "a_m", "inc_rad", "raan_rad", "u0_rad", "t_ref_unix_s", "geo_lon_rad"):
            getattr(self, name).flags.writeable = False  # shared through the cache: never altered in place

    def __len__(self) -> int:
        return len(self.prn)

    @property
    def mean_motion_rad_s(self) -> np.ndarray:
        """n = sqrt(GM / a³), rad/s (Kepler's third law)."""
        return np.sqrt(GM_EARTH_M3_S2 / self.a_m ** 3)

    @property
    def period_s(self) -> np.ndarray:
        """Orbital period T = 2π / n, s."""
        return 2.0 * np.pi / self.mean_motion_rad_s

    def select(self, mask: np.ndarray) -> "Satellites":
        """The subset ``mask`` (bool or index array)."""
        return Satellites(*(getattr(self, f)[mask] for f in (
            "system", "prn", "orbit", "a_m", "inc_rad", "raan_rad", "u0_rad", "t_ref_unix_s", "geo_lon_rad")))

    @staticmethod
    def concat(*parts: "Satellites") -> "Satellites":
        names = ("system", "prn", "orbit", "a_m", "inc_rad", "raan_rad", "u0_rad", "t_ref_unix_s", "geo_lon_rad")
        return Satellites(*(np.concatenate([getattr(p, n) for p in parts]) for n in names))


def to_unix_s(times) -> np.ndarray:
    """UTC POSIX seconds from floats, a datetime or a sequence of datetimes (naive = UTC).

    >>> float(to_unix_s(datetime(1970, 1, 2, tzinfo=timezone.utc))[0])
    86400.0
    """
    if isinstance(times, datetime):
        times = [times]
    arr = np.asarray(times)
    if arr.dtype == object:
        out = []
        for t in arr.ravel():
            if isinstance(t, datetime):
                out.append((t if t.tzinfo else t.replace(tzinfo=timezone.utc)).timestamp())
            else:
                out.append(float(t))
        return np.asarray(out, float).reshape(arr.shape)
    return np.atleast_1d(arr.astype(float))


def gmst_rad(unix_s) -> np.ndarray:
    """Greenwich mean sidereal time, rad in [0, 2π), IAU 1982 model (Vallado 2013, eq. 3-47).

    θ_GMST [s] = 67310.54841 + (876600·3600 + 8640184.812866)·T + 0.093104·T² − 6.2e−6·T³,
    T = (JD_UT1 − 2451545.0) / 36525, with UT1 ≈ UTC.

    >>> t = datetime(1993, 7, 1, tzinfo=timezone.utc).timestamp()  # GPS SPS PS: GHA 18h36m14.4s
    >>> round(float(np.degrees(gmst_rad(t))) / 15.0, 4)
    18.6037
    """
    t = np.asarray(unix_s, float)
    # Split the Julian centuries so the large term keeps full precision.
    days = (t - 946_728_000.0) / 86400.0  # 946728000 = 2000-01-01 12:00 UTC (JD 2451545.0)
    tc = days / 36525.0
    whole_days = np.floor(days)
    frac = days - whole_days
    # 876600 h·T = days·86400 s·(36525·24·3600/36525/86400) → the sidereal rotation's integer-day part drops mod 86400.
    sec = (67310.54841 + frac * 86400.0 + (8640184.812866 * tc) + 0.093104 * tc ** 2 - 6.2e-6 * tc ** 3)
    return np.mod(np.radians(np.mod(sec, 86400.0) / 240.0), 2.0 * np.pi)


def _gps() -> Satellites:
    planes = list(_GPS_SLOTS)
    slots = {p: list(_GPS_SLOTS[p][1]) for p in planes}
    # Seven spares, each in the middle of the widest in-plane gap left (planes in order A..F, ties to the first).
    for _ in range(len(GPS_PRNS) - 24):
        best = None
        for p in planes:
            u = sorted(slots[p])
            gaps = [((u[(j + 1) % len(u)] - u[j]) % 360.0, u[j]) for j in range(len(u))]
            g, start = max(gaps)
            if best is None or g > best[0] + 1e-9:
                best = (g, start, p)
        g, start, p = best
        slots[p].append((start + g / 2.0) % 360.0)
    raan, u0 = [], []
    for p in planes:
        for u in slots[p]:
            raan.append(_GPS_SLOTS[p][0])
            u0.append(u)
    k = len(raan)
    return Satellites(
        system=np.full(k, SYSTEM_GPS), prn=np.asarray(GPS_PRNS, int), orbit=np.full(k, "MEO"),
        a_m=np.full(k, GPS_A_M), inc_rad=np.full(k, np.radians(55.0)), raan_rad=np.radians(raan),
        u0_rad=np.radians(u0), t_ref_unix_s=np.full(k, _GPS_EPOCH_UNIX_S), geo_lon_rad=np.full(k, np.nan))


def gps_constellation() -> Satellites:
    """The 31-satellite GPS reference constellation (see the module docstring)."""
    return _cached("gps")


def _beidou() -> Satellites:
    # MEO: Walker i:T/P/F = 55°:24/3/1 → plane RAAN 360/P·p, in-plane spacing 360P/T, phasing F·360/T between planes.
    n_t, n_p, f = 24, 3, 1
    s = n_t // n_p
    p_idx = np.repeat(np.arange(n_p), s)
    j_idx = np.tile(np.arange(s), n_p)
    raan_meo = np.radians(360.0 / n_p * p_idx)
    u_meo = np.radians(360.0 / s * j_idx + f * 360.0 / n_t * p_idx)
    # IGSO: n = ω_E (a = GEO radius), u_k(t0) = −120°·k; the ascending node lies at λ_an when
    # Ω_k − θ_g(t_node) = λ_an with t_node = t0 − u_k(t0)/n, i.e. Ω_k = λ_an + θ_g(t0) − u_k(t0).
    theta0 = float(gmst_rad(_BDS_EPOCH_UNIX_S)[()])
    u_igso = np.radians(np.array([0.0, -120.0, -240.0]))
    raan_igso = np.radians(BDS_IGSO_NODE_LON_DEG) + theta0 - u_igso
    n_meo, n_igso, n_geo = 24, 3, 3
    return Satellites(
        system=np.full(n_meo + n_igso + n_geo, SYSTEM_BDS),
        prn=np.asarray(BDS_MEO_PRNS + BDS_IGSO_PRNS + BDS_GEO_PRNS, int),
        orbit=np.array(["MEO"] * n_meo + ["IGSO"] * n_igso + ["GEO"] * n_geo),
        a_m=np.concatenate([np.full(n_meo, BDS_MEO_A_M), np.full(n_igso + n_geo, GEO_RADIUS_M)]),
        inc_rad=np.concatenate([np.full(n_meo + n_igso, np.radians(55.0)), np.zeros(n_geo)]),
        raan_rad=np.concatenate([raan_meo, np.mod(raan_igso, 2 * np.pi), np.zeros(n_geo)]),
        u0_rad=np.concatenate([u_meo, np.mod(u_igso, 2 * np.pi), np.zeros(n_geo)]),
        t_ref_unix_s=np.full(n_meo + n_igso + n_geo, _BDS_EPOCH_UNIX_S),
        geo_lon_rad=np.concatenate([np.full(n_meo + n_igso, np.nan), np.radians(BDS_GEO_LON_DEG)]),
    )


def beidou_constellation() -> Satellites:
    """BeiDou-3: 24 MEO (Walker 24/3/1), 3 IGSO, 3 GEO (see the module docstring)."""
    return _cached("bds")


def all_satellites() -> Satellites:
    """GPS followed by BeiDou-3 (61 satellites)."""
    return _cached("all")


@functools.lru_cache(maxsize=None)
def _cached(which: str) -> Satellites:
    if which == "gps":
        return _gps()
    if which == "bds":
        return _beidou()
    return Satellites.concat(_cached("gps"), _cached("bds"))


def eci_positions(sats: Satellites, unix_s) -> np.ndarray:
    """Inertial positions, m, ndarray of shape (n_epochs, k, 3) (Montenbruck & Gill eq. 2.50, e = 0).

    GEO satellites are returned at their ECEF slot rotated by θ_g, i.e. consistently inertial.
    """
    t = to_unix_s(unix_s)
    u = sats.u0_rad[None, :] + sats.mean_motion_rad_s[None, :] * (t[:, None] - sats.t_ref_unix_s[None, :])
    geo = np.isfinite(sats.geo_lon_rad)
    if geo.any():
        # A GEO sits at u + Ω = λ + θ_g(t) with i = 0.
        theta = gmst_rad(t)[:, None]
        u = np.where(geo[None, :], np.nan_to_num(sats.geo_lon_rad)[None, :] + theta - sats.raan_rad[None, :], u)
    cu, su = np.cos(u), np.sin(u)
    co, so = np.cos(sats.raan_rad)[None, :], np.sin(sats.raan_rad)[None, :]
    ci, si = np.cos(sats.inc_rad)[None, :], np.sin(sats.inc_rad)[None, :]
    a = sats.a_m[None, :]
    return np.stack([a * (co * cu - so * su * ci), a * (so * cu + co * su * ci), a * su * si], axis=-1)


def ecef_positions(sats: Satellites, unix_s) -> np.ndarray:
    """Earth-fixed positions, m, shape (n_epochs, k, 3): r_ECEF = R_z(θ_g) · r_ECI."""
    t = to_unix_s(unix_s)
    r = eci_positions(sats, t)
    th = gmst_rad(t)[:, None]
    c, s = np.cos(th), np.sin(th)
    return np.stack([c * r[..., 0] + s * r[..., 1], -s * r[..., 0] + c * r[..., 1], r[..., 2]], axis=-1)


def azel(times, origin, sats: Satellites | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation of every satellite seen from ``origin``.

    Parameters
    ----------
    times : float POSIX seconds (UTC), datetime, or sequence of either; shape (n_epochs,)
    origin : features.site.Origin or (lat_deg, lon_deg, alt_m)
    sats : Satellites, default :func:`all_satellites`

    Returns
    -------
    az_rad, el_rad : ndarrays of shape (n_epochs, k)
        Azimuth from north, clockwise, in [0, 2π); elevation in [−π/2, π/2].
        Computed with ``pymap3d.ecef2aer`` on the WGS-84 ellipsoid.
    """
    sats = all_satellites() if sats is None else sats
    lat, lon, alt = (origin.lat_deg, origin.lon_deg, origin.alt_m) if hasattr(origin, "lat_deg") else origin
    r = ecef_positions(sats, times)
    az, el, _ = pymap3d.ecef2aer(r[..., 0], r[..., 1], r[..., 2], lat, lon, alt, deg=True)
    return np.mod(np.radians(az), 2.0 * np.pi), np.radians(el)
