"""The site's environment map from its drawing: the only place below the CLI that reads simulator code.

The map baseline ``kf_map`` (the paper's method 1) looks up the environment
class at the filter's last estimate in a map of the site. For a simulated
site that map is its layout's blocked-sky share (:mod:`simulation.site.environment`,
DESIGN's environment truth) on a 2 m grid; for a real site it would be a
surveyed map. :func:`class_map_for` builds it as the callable
:class:`~models.fusion.events.ClassMap` the filter takes, and
:func:`share_grid` gives the share itself for the site plot.
"""

from __future__ import annotations

import functools

from models.fusion.events import ClassMap

__all__ = ["class_map_for", "share_grid", "MAP_RESOLUTION_M"]

MAP_RESOLUTION_M = 2.0
"""Grid spacing of the map baseline's class map, m (~0.2 s to compute for a 120 × 80 m yard)."""


def share_grid(site, resolution_m: float = 1.0, n_az: int = 180):
    """(east_m (nx,), north_m (ny,), blocked-sky share (ny, nx), NaN inside solid structures) of ``site``, and
    the class thresholds (open below ``OPEN_MAX``, heavy above ``LIGHT_MAX``)."""
    from simulation.site.environment import LIGHT_MAX, OPEN_MAX, class_map

    east, north, share = class_map(site, resolution_m=resolution_m, n_az=n_az)
    return east, north, share, OPEN_MAX, LIGHT_MAX


def classify(share):
    """Class codes 0/1/2 (open/light/heavy) of blocked-sky shares; NaN (inside a structure) counts as heavy."""
    from simulation.site.environment import classify_share

    return classify_share(share)


@functools.lru_cache(maxsize=8)
def class_map_for(site) -> ClassMap | None:
    """The class map of ``site`` for ``kf_map`` (once per site and process: every walk of a site shares it), or
    None when the site has no layout."""
    if not site.layout:
        return None
    east, north, share, _, _ = share_grid(site, resolution_m=MAP_RESOLUTION_M)
    return ClassMap.from_axes(east, north, classify(share))
