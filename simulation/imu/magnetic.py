"""Magnetic field at a substation: Earth's main field plus steel disturbances.

Earth's field
    Degree-1 (centred dipole) part of IGRF-13 at epoch 2020.0 (Alken et al.
    2021, "International Geomagnetic Reference Field: the thirteenth
    generation", Earth Planets Space 73:49, Table 2): g10 = -29404.8 nT,
    g11 = -1450.9 nT, h11 = 4652.5 nT. Field components at the Earth's
    surface from the potential V = a (a/r)^2 [g10 cos θ + (g11 cos φ + h11 sin φ) sin θ]
    (Langel 1987, "The main field", eqs. 4, 7): X = (1/r)∂V/∂θ (north),
    Y = -(1/(r sin θ))∂V/∂φ (east), Z = ∂V/∂r (down), θ = colatitude.

    This is a *stated approximation*: a centred dipole gets the intensity and
    inclination right to ~10-15 % / ~10° and the declination to a few degrees
    (e.g. 30° N 114° E: dipole D = +1.2°, I = 37°, F = 35 µT; the full IGRF gives
    about -4°, 45°, 50 µT). PDR needs only a field that is consistent between
    simulator and the stated declination in walk.toml, which it is.

Disturbances
    A steel body (transformer tank, steel structure) in the Earth field H0 =
    B0/μ0 is modelled as a highly permeable sphere of the same volume, radius
    R: its external field is that of a dipole of moment m = 4π R³ H0
    (Jackson, *Classical Electrodynamics*, 3rd ed., §5.11, μ → ∞ limit), plus
    a remanent moment of random direction. The dipole field is
    B(r) = μ0/(4π) [3 r̂ (r̂·m) - m] / r³ (Jackson eq. 5.56), so on its axis
    the disturbance is 2 B0 (R/r)³: tens of µT a metre or two from a
    transformer, below 1 µT beyond ~4 R. Distances are floored at R (the walker
    never enters a box).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from features.site import Box, Site

__all__ = ["IGRF13_DIPOLE_NT", "earth_field_ned_ut", "field_elements", "SteelDipoles", "steel_dipoles",
           "site_steel_dipoles", "disturbance_ned_ut", "is_magnetic"]

IGRF13_DIPOLE_NT = (-29404.8, -1450.9, 4652.5)
"""IGRF-13 degree-1 Gauss coefficients (g10, g11, h11) at 2020.0, nT (Alken et al. 2021, Table 2)."""

MU0_OVER_4PI = 1e-7
"""μ0/(4π), T·m/A (SI)."""


def earth_field_ned_ut(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Centred-dipole (IGRF-13 degree 1) field at the surface, µT, shape (3,) north-east-down.

    >>> b = earth_field_ned_ut(0.0, 0.0)      # equator, Greenwich: X = -g10, Y = -h11, Z = -2 g11
    >>> [round(float(v), 3) for v in b]
    [29.405, -4.652, 2.902]
    """
    g10, g11, h11 = IGRF13_DIPOLE_NT
    theta = math.radians(90.0 - lat_deg)
    phi = math.radians(lon_deg)
    gh = g11 * math.cos(phi) + h11 * math.sin(phi)
    x_nt = -g10 * math.sin(theta) + gh * math.cos(theta)
    y_nt = g11 * math.sin(phi) - h11 * math.cos(phi)
    z_nt = -2.0 * (g10 * math.cos(theta) + gh * math.sin(theta))
    return np.array([x_nt, y_nt, z_nt]) * 1e-3


def field_elements(b_ned_ut: np.ndarray) -> tuple[float, float, float]:
    """Declination (rad, east of true north positive), inclination (rad, down positive), intensity (µT)."""
    x, y, z = (float(v) for v in b_ned_ut)
    return math.atan2(y, x), math.atan2(z, math.hypot(x, y)), math.sqrt(x * x + y * y + z * z)


def is_magnetic(box: Box) -> bool:
    """Steel structures and transformers disturb the field; concrete, lattice and buildings are ignored."""
    return box.kind == "transformer" or box.material.lower() in {"steel", "iron", "metal"}


@dataclass(frozen=True)
class SteelDipoles:
    """Equivalent dipoles of the site's steel bodies.

    Attributes
    ----------
    centre_ned_m : ndarray of shape (k, 3)
        Dipole positions: north, east, down (down = minus height above ground).
    moment_ned_a_m2 : ndarray of shape (k, 3)
        Dipole moments, A·m².
    radius_m : ndarray of shape (k,)
        Equivalent-sphere radii (distance floor).
    """

    centre_ned_m: np.ndarray
    moment_ned_a_m2: np.ndarray
    radius_m: np.ndarray


def steel_dipoles(site: Site, earth_ned_ut: np.ndarray, rng: np.random.Generator,
                  remanent_fraction: float = 0.3) -> SteelDipoles:
    """Induced (4πR³H0) plus remanent (random direction, ``remanent_fraction`` of it) dipole per steel box."""
    boxes = [b for b in site.layout if is_magnetic(b)]
    k = len(boxes)
    centre = np.zeros((k, 3))
    moment = np.zeros((k, 3))
    radius = np.zeros(k)
    h0_a_m = np.asarray(earth_ned_ut) * 1e-6 / (4.0 * math.pi * MU0_OVER_4PI)
    for i, b in enumerate(boxes):
        e, n = b.centre_en
        vol_m3 = (b.east_max_m - b.east_min_m) * (b.north_max_m - b.north_min_m) * b.height_m
        r = (3.0 * vol_m3 / (4.0 * math.pi)) ** (1.0 / 3.0)
        centre[i] = (n, e, -0.5 * b.height_m)
        induced = 4.0 * math.pi * r**3 * h0_a_m
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        moment[i] = induced + remanent_fraction * np.linalg.norm(induced) * direction
        radius[i] = r
    return SteelDipoles(centre, moment, radius)


def site_steel_dipoles(site: Site) -> SteelDipoles:
    """The site's steel dipoles in its Earth field, remanence drawn from ``stream_rng(site.seed, "steel-remanence")``
    (the same for every walk on the site; scoring code uses it to know where the field is disturbed)."""
    from simulation.rng import stream_rng

    return steel_dipoles(site, earth_field_ned_ut(site.origin.lat_deg, site.origin.lon_deg),
                         stream_rng(site.seed or 0, "steel-remanence"))


def disturbance_ned_ut(dipoles: SteelDipoles, pos_ned_m: np.ndarray) -> np.ndarray:
    """Sum of dipole fields at positions ``pos_ned_m`` (n, 3), µT, shape (n, 3).

    Dipole field B = μ0/(4π) [3 r̂(r̂·m) − m]/r³ (Jackson eq. 5.56), r floored at the sphere radius.

    >>> d = SteelDipoles(np.zeros((1, 3)), np.array([[1000.0, 0.0, 0.0]]), np.array([0.5]))
    >>> round(float(disturbance_ned_ut(d, np.array([[10.0, 0.0, 0.0]]))[0, 0]), 6)   # 2·1e-7·1000/1000 T
    0.2
    """
    pos = np.ascontiguousarray(np.atleast_2d(np.asarray(pos_ned_m, dtype=float)))
    k = len(dipoles.radius_m)
    if pos.shape[1:] != (3,) or np.shape(dipoles.centre_ned_m) != (k, 3) or np.shape(dipoles.moment_ned_a_m2) != (k, 3):
        raise ValueError(f"dipole field: positions {pos.shape} (n, 3), centres {np.shape(dipoles.centre_ned_m)} and "
                         f"moments {np.shape(dipoles.moment_ned_a_m2)} ({k}, 3) for {k} radii")
    out = np.zeros_like(pos)
    _add_dipole_fields(pos, np.ascontiguousarray(dipoles.centre_ned_m, dtype=float),
                       np.ascontiguousarray(dipoles.moment_ned_a_m2, dtype=float),
                       np.ascontiguousarray(dipoles.radius_m, dtype=float), out)
    return out


@njit(cache=True, error_model="numpy")
def _add_dipole_fields(pos: np.ndarray, centre: np.ndarray, moment: np.ndarray, radius: np.ndarray,
                       out: np.ndarray) -> None:
    """out[i] += Σ_j B_j(pos[i]) in µT, dipole by dipole in order (:func:`disturbance_ned_ut`). Compiled: numpy's
    form made a dozen (n, 3) temporaries per dipole (0.44 s of a 600 s walk's 300,000 IMU positions and 22
    dipoles; 0.18 s compiled). r̂·m is summed in order where numpy's matrix product took BLAS's order: values move
    by ≤ 4e-12 relative, below the 1e-3 µT the CSV writes."""
    for i in range(pos.shape[0]):
        for j in range(centre.shape[0]):
            d0, d1, d2 = pos[i, 0] - centre[j, 0], pos[i, 1] - centre[j, 1], pos[i, 2] - centre[j, 2]
            r = max(math.sqrt(d0 * d0 + d1 * d1 + d2 * d2), radius[j])
            u0, u1, u2 = d0 / r, d1 / r, d2 / r
            um = u0 * moment[j, 0] + u1 * moment[j, 1] + u2 * moment[j, 2]
            r3 = r ** 3.0
            out[i, 0] += MU0_OVER_4PI * (3.0 * u0 * um - moment[j, 0]) / r3 * 1e6
            out[i, 1] += MU0_OVER_4PI * (3.0 * u1 * um - moment[j, 1]) / r3 * 1e6
            out[i, 2] += MU0_OVER_4PI * (3.0 * u2 * um - moment[j, 2]) / r3 * 1e6
