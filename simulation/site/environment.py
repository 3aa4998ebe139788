"""Ground-truth environment class of a position: the share of sky hidden by solid structures.

docs/design.md §6: open < 10 %, light 10–40 %, heavy > 40 % of the sky above the
elevation mask. Porous structures (lattice gantries) do not count: they
attenuate satellites but do not hide the sky. Survey cells take the class at
their capture point.

Two ways of weighting the sky (``sky=``):

- ``"satellites"`` (the default since issue 13): weighted by where this
  site's GPS and BeiDou satellites actually pass over a day
  (:class:`SatelliteSky`) — the share of satellite time blocked, which is what
  the receiver's signal statistics can see;
- ``"uniform"`` (the definition the project started with): solid-angle
  weighted, every direction above the mask alike. At 30° N, say, no GPS satellite ever passes near the north
  celestial pole and the BeiDou GEO belt hangs in the south, so a fire wall
  north of a walker hides much uniform sky and few satellites: the uniform
  label calls heavy what the receiver sees as light (issue 13 item 0).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import numpy as np
from numba import njit

from features.constants import ELEVATION_MASK_DEG
from features.site import ENV_CLASSES, Site

from simulation.site.geometry import boxes_array, sky_blocked_fraction

__all__ = ["OPEN_MAX", "LIGHT_MAX", "SKY_WEIGHTINGS", "SatelliteSky", "satellite_sky", "solid_boxes",
           "blocked_share", "classify_share", "environment_class", "class_map"]

SKY_WEIGHTINGS = ("uniform", "satellites")
"""Ways of weighting the sky in :func:`blocked_share` (see the module docstring)."""

SKY_DAY_UTC = datetime(2026, 6, 1, tzinfo=timezone.utc)
"""The day whose satellite passes weight the ``"satellites"`` sky (GPS ground tracks repeat every sidereal
day, BeiDou MEO every 7 days, so one day is representative to within a few percent)."""

SKY_STEP_S = 120.0
"""Sampling of the satellites' sky tracks over that day, s."""


@njit(cache=True)
def _samples_below(hor: np.ndarray, el_flat: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Per skyline (row of ``hor``, (n, n_az)): the number of sky samples below it, Σ_b #{e in bin b : e < hor_b};
    bin b's elevations are ``el_flat[starts[b]:starts[b + 1]]``, ascending (a binary search each, numpy's
    ``searchsorted(side="left")``). Returns float counts (n,)."""
    n, n_az = hor.shape
    out = np.zeros(n)
    for b in range(n_az):
        e = el_flat[starts[b]:starts[b + 1]]
        if e.shape[0]:
            out += np.searchsorted(e, hor[:, b], side="left")
    return out


@dataclass(frozen=True)
class SatelliteSky:
    """The satellites' sky tracks over a day, binned by azimuth.

    ``el_sorted[b]`` holds the elevations (rad, ascending) of every (satellite, epoch) sample above
    the mask in azimuth bin ``b`` of ``n_az``; ``n_samples`` their total. The blocked share of a
    skyline ``hor`` (rad, per bin) is the share of samples below it:
    Σ_b #{e ∈ el_sorted[b] : e < hor_b} / n_samples.
    """

    el_sorted: tuple
    n_samples: int

    @functools.cached_property
    def _flat(self) -> tuple[np.ndarray, np.ndarray]:
        """The bins' elevations end to end and each bin's first index (n_az + 1,), for the compiled count."""
        sizes = [len(e) for e in self.el_sorted]
        flat = np.concatenate([np.asarray(e, np.float64) for e in self.el_sorted]) if sizes else np.zeros(0)
        return flat, np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

    def blocked(self, hor_rad: np.ndarray) -> np.ndarray:
        """Shares (n,) of skylines ``hor_rad`` of shape (n, n_az)."""
        hor = np.ascontiguousarray(np.atleast_2d(hor_rad), dtype=np.float64)
        if hor.shape[1] != len(self.el_sorted):
            raise ValueError(f"skylines have {hor.shape[1]} azimuth bins, the sky {len(self.el_sorted)}")
        return _samples_below(hor, *self._flat) / max(self.n_samples, 1)


@functools.lru_cache(maxsize=16)
def satellite_sky(lat_deg: float, lon_deg: float, mask_deg: float = ELEVATION_MASK_DEG, n_az: int = 360,
                  day_utc: datetime = SKY_DAY_UTC, step_s: float = SKY_STEP_S) -> SatelliteSky:
    """The GPS + BeiDou sky of a site over one day (:func:`simulation.gnss.orbits.azel`), binned for
    :func:`blocked_share`."""
    from simulation.gnss.orbits import azel

    times = [day_utc + timedelta(seconds=float(t)) for t in np.arange(0.0, 86_400.0, step_s)]
    az, el = azel(times, (lat_deg, lon_deg, 0.0))
    keep = el >= np.radians(mask_deg)
    az, el = az[keep], el[keep]
    b = np.minimum((az / (2.0 * np.pi) * n_az).astype(int), n_az - 1)
    return SatelliteSky(tuple(np.sort(el[b == k]) for k in range(n_az)), int(el.size))

OPEN_MAX = 0.10
"""Largest blocked-sky share still called open (docs/design.md §6)."""

LIGHT_MAX = 0.40
"""Largest blocked-sky share still called light; above it, heavy (docs/design.md §6)."""


def solid_boxes(site: Site) -> np.ndarray:
    """Array (m, 5) of the site's solid (non-porous) boxes."""
    return boxes_array([b for b in site.layout if not b.porous])


def blocked_share(site: Site, east_m, north_m, mask_deg: float = ELEVATION_MASK_DEG, n_az: int = 360,
                  sky: str = "satellites") -> np.ndarray:
    """Share of sky above ``mask_deg`` hidden by solid structures at device height, shape (n,).

    ``sky``: ``"uniform"`` (solid angle) or ``"satellites"`` (this site's satellite passes over a day).
    """
    if sky not in SKY_WEIGHTINGS:
        raise ValueError(f"sky must be one of {SKY_WEIGHTINGS}, got {sky!r}")
    p = np.column_stack([np.ravel(east_m), np.ravel(north_m)])
    weights = None
    if sky == "satellites":
        weights = satellite_sky(round(site.origin.lat_deg, 4), round(site.origin.lon_deg, 4), mask_deg, n_az)
    return sky_blocked_fraction(p, solid_boxes(site), site.device_height_m, mask_deg=mask_deg, n_az=n_az, sky=weights)


def classify_share(share) -> np.ndarray:
    """Class index 0/1/2 (open/light/heavy) of blocked-sky shares.

    >>> classify_share([0.05, 0.10, 0.25, 0.41]).tolist()
    [0, 1, 1, 2]
    """
    s = np.asarray(share, float)
    return np.where(s < OPEN_MAX, 0, np.where(s <= LIGHT_MAX, 1, 2))


def environment_class(site: Site, east_m, north_m) -> list[str]:
    """Class names (``open``/``light``/``heavy``) at positions."""
    return [ENV_CLASSES[i] for i in classify_share(blocked_share(site, east_m, north_m))]


def class_map(site: Site, resolution_m: float = 1.0, n_az: int = 180):
    """Blocked-sky share on a regular grid over the site's extent.

    Returns
    -------
    east_m : ndarray (nx,), north_m : ndarray (ny,) — cell centres
    share : ndarray (ny, nx); NaN inside solid structures
    """
    g = site.grid
    east = np.arange(g.east_min_m + resolution_m / 2, g.east_max_m, resolution_m)
    north = np.arange(g.north_min_m + resolution_m / 2, g.north_max_m, resolution_m)
    ee, nn = np.meshgrid(east, north)
    share = blocked_share(site, ee, nn, n_az=n_az).reshape(ee.shape)
    from simulation.site.geometry import inside_boxes
    inside = inside_boxes(np.column_stack([ee.ravel(), nn.ravel()]), solid_boxes(site)).reshape(ee.shape)
    share[inside] = np.nan
    return east, north, share
