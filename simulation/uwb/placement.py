"""UWB anchors placed as an installer would: on the acoustic beacons' poles and wall mounts, aimed at the yard.

An installer adding UWB to a yard that has beacon poles reuses them: each pole or wall mount already has
power and was chosen so that every walkable point sees four of them in line of sight
(:mod:`simulation.site.coverage`), which is what multilateration needs too (three anchors and one spare).
Each anchor's PDoA array is aimed (boresight) where it is useful: a wall-mounted anchor straight out of
its wall, a pole-mounted one at the centroid of the walkable points it sees within ``aim_range_m`` (the
straight line clears every solid box), so most of its tags stand within ±60° of boresight where PDoA is
best. The mount is ``height_m`` above ground (a UWB anchor sits higher on the pole than the tweeter, clear
of heads and vehicles). ``site.toml`` holds the surveyed values; the simulator's true anchors differ by the
survey and mounting errors (:mod:`simulation.uwb.stream`).
"""

from __future__ import annotations

import math

import numpy as np

from features.site import Site, UwbAnchor

from simulation.site.coverage import segments_clear, walkable_points
from simulation.site.geometry import boxes_array

__all__ = ["place_uwb_anchors", "WALL_MOUNT_M"]

WALL_MOUNT_M = 0.5
"""A pole closer than this to a solid box's face is a wall mount (the coverage placer puts mounts 0.15 m off)."""


def _wall_normal(p: np.ndarray, solid: np.ndarray) -> float | None:
    """Outward normal bearing (rad) of the face of a solid box within :data:`WALL_MOUNT_M` of ``p``, or None."""
    best, bearing = WALL_MOUNT_M, None
    for e0, e1, n0, n1, _h in solid:
        inside_e, inside_n = e0 - WALL_MOUNT_M <= p[0] <= e1 + WALL_MOUNT_M, n0 - WALL_MOUNT_M <= p[1] <= n1 + WALL_MOUNT_M
        for dist, az, ok in ((e0 - p[0], -math.pi / 2, inside_n), (p[0] - e1, math.pi / 2, inside_n),
                             (n0 - p[1], math.pi, inside_e), (p[1] - n1, 0.0, inside_e)):
            if ok and 0.0 <= dist < best:
                best, bearing = dist, az
    return bearing


def place_uwb_anchors(site: Site, height_m: float = 3.0, aim_range_m: float = 40.0) -> tuple[UwbAnchor, ...]:
    """One anchor per acoustic beacon position of ``site`` (module docstring), ids as the beacons'."""
    solid = boxes_array([b for b in site.layout if not b.porous])
    pts = walkable_points(site, 4.0)
    rx = np.column_stack([pts, np.full(len(pts), site.device_height_m)])
    out = []
    for b in site.beacons:
        p = np.array([b.east_m, b.north_m, height_m])
        aim = _wall_normal(p, solid)
        if aim is None:
            near = np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1]) <= aim_range_m
            seen = rx[near][segments_clear(p[None, :], rx[near], solid)[0]] if len(solid) else rx[near]
            target = seen[:, :2].mean(axis=0) if len(seen) else np.array([
                0.5 * (site.grid.east_min_m + site.grid.east_max_m), 0.5 * (site.grid.north_min_m + site.grid.north_max_m)])
            aim = math.atan2(target[0] - p[0], target[1] - p[1])
        out.append(UwbAnchor(id=b.id, east_m=b.east_m, north_m=b.north_m, up_m=height_m,
                             boresight_deg=round(math.degrees(aim) % 360.0, 1)))
    return tuple(out)
