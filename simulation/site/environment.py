"""Ground-truth environment class of a position: the share of sky hidden by solid structures.

DESIGN.md §6: open < 10 %, light 10–40 %, heavy > 40 % of the sky above the
elevation mask, solid-angle weighted. Porous structures (lattice gantries) do
not count: they attenuate satellites but do not hide the sky. Survey cells take
the class at their capture point.
"""

from __future__ import annotations

import numpy as np

from features.constants import ELEVATION_MASK_DEG
from features.site import ENV_CLASSES, Site

from simulation.site.geometry import boxes_array, sky_blocked_fraction

__all__ = ["OPEN_MAX", "LIGHT_MAX", "solid_boxes", "blocked_share", "classify_share", "environment_class",
           "class_map"]

OPEN_MAX = 0.10
"""Largest blocked-sky share still called open (DESIGN.md §6)."""

LIGHT_MAX = 0.40
"""Largest blocked-sky share still called light; above it, heavy (DESIGN.md §6)."""


def solid_boxes(site: Site) -> np.ndarray:
    """Array (m, 5) of the site's solid (non-porous) boxes."""
    return boxes_array([b for b in site.layout if not b.porous])


def blocked_share(site: Site, east_m, north_m, mask_deg: float = ELEVATION_MASK_DEG, n_az: int = 360) -> np.ndarray:
    """Share of sky above ``mask_deg`` hidden by solid structures at device height, shape (n,)."""
    p = np.column_stack([np.ravel(east_m), np.ravel(north_m)])
    return sky_blocked_fraction(p, solid_boxes(site), site.device_height_m, mask_deg=mask_deg, n_az=n_az)


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
