"""Ray and segment tests against the site's axis-aligned boxes (vectorised).

A box stands on the ground (z = 0) with a flat top at ``height_m``. A ray from
a receiver at height ``z0`` in azimuth ``az`` (from north, clockwise) enters a
box's footprint at horizontal distance ``t_in`` (2-D slab method, Kay & Kajiya
1986; Williams et al. 2005) and is blocked at elevation ``el`` iff
``t_in·tan(el) < height − z0`` (the top face is flat, so the nearest top edge
along the ray decides). The highest elevation a box hides along an azimuth is
therefore ``atan((height − z0) / t_in)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from features.site import Box

__all__ = ["boxes_array", "footprint_entry", "horizon_elevation", "sky_blocked_fraction",
           "ray_blockers", "segment_hits_boxes", "segment_box_hits", "inside_boxes", "inverse_direction",
           "footprint_slab"]


def boxes_array(boxes) -> np.ndarray:
    """Stack boxes to an array of shape (m, 5): east_min, east_max, north_min, north_max, height."""
    if len(boxes) == 0:
        return np.zeros((0, 5))
    return np.array([[b.east_min_m, b.east_max_m, b.north_min_m, b.north_max_m, b.height_m] for b in boxes], float)


def footprint_entry(p_en: np.ndarray, az_rad: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal entry and exit distances of rays into box footprints (2-D slab test).

    Parameters
    ----------
    p_en : ndarray of shape (n, 2)
        Ray origins (east, north), metres.
    az_rad : ndarray of shape (n, k) or (k,)
        Azimuths, radians from north, clockwise.
    boxes : ndarray of shape (m, 5)

    Returns
    -------
    t_in, t_out : ndarrays of shape (n, k, m)
        Entry distance (0 when the origin is inside) and exit distance; ``t_in``
        is ``inf`` where the ray misses the footprint or the box lies behind.
    """
    p = np.ascontiguousarray(p_en, dtype=float).reshape(-1, 2)
    az = np.asarray(az_rad, float)
    az = np.ascontiguousarray(az[None, :] if az.ndim == 1 else az)
    if p.shape[0] == 1 and az.shape[0] > 1:       # one origin, rows of azimuths: broadcast as numpy would
        p = np.repeat(p, az.shape[0], axis=0)
    if az.shape[0] not in (1, p.shape[0]):
        raise ValueError(f"az_rad of shape {az.shape} does not match {p.shape[0]} origins")
    return _footprint_kernel(p, az, np.ascontiguousarray(boxes, dtype=float).reshape(-1, 5))


@njit(cache=True)
def inverse_direction(az_rad: float) -> tuple[float, float]:
    """(1/sin az, 1/cos az) of a horizontal ray, a component of exactly 0 nudged to 1e-12: the slab bounds then
    become ±1e12-scale numbers, which the min/max logic treats exactly like the infinite slab of a parallel ray
    (Williams et al. 2005)."""
    de, dn = math.sin(az_rad), math.cos(az_rad)
    return 1.0 / (1e-12 if abs(de) < 1e-12 else de), 1.0 / (1e-12 if abs(dn) < 1e-12 else dn)


@njit(cache=True)
def footprint_slab(pe: float, pn: float, inv_e: float, inv_n: float, box: np.ndarray) -> tuple[float, float]:
    """Entry and exit distances of the horizontal ray from (pe, pn) with inverse direction (inv_e, inv_n) (from
    :func:`inverse_direction`) into the footprint of ``box`` (5,): 2-D slab test (Kay & Kajiya 1986); (inf, inf)
    when it misses or the box lies behind, entry 0 when the origin is inside."""
    t1, t2 = (box[0] - pe) * inv_e, (box[1] - pe) * inv_e
    t3, t4 = (box[2] - pn) * inv_n, (box[3] - pn) * inv_n
    t_lo = max(max(min(t1, t2), min(t3, t4)), 0.0)
    t_hi = min(max(t1, t2), max(t3, t4))
    if t_hi >= t_lo:
        return t_lo, t_hi
    return np.inf, np.inf


@njit(cache=True)
def _footprint_kernel(p: np.ndarray, az: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`footprint_entry` of origins p (n, 2), azimuths az (1 or n, k), boxes (m, 5): t_in, t_out (n, k, m)."""
    n, k, m = p.shape[0], az.shape[1], boxes.shape[0]
    t_in = np.empty((n, k, m))
    t_out = np.empty((n, k, m))
    for i in range(n):
        for j in range(k):
            inv_e, inv_n = inverse_direction(az[i if az.shape[0] > 1 else 0, j])
            for b in range(m):
                t_in[i, j, b], t_out[i, j, b] = footprint_slab(p[i, 0], p[i, 1], inv_e, inv_n, boxes[b])
    return t_in, t_out


def horizon_elevation(p_en: np.ndarray, az_rad: np.ndarray, boxes: np.ndarray, z0_m: float) -> np.ndarray:
    """Elevation (rad) of the skyline of ``boxes`` seen from ``p_en`` at height ``z0_m``.

    Returns ndarray of shape (n, k); 0 where nothing stands above the receiver
    along that azimuth, π/2 where the receiver is inside a box.
    """
    if boxes.shape[0] == 0:
        az = np.asarray(az_rad)
        return np.zeros((np.asarray(p_en).shape[0], az.shape[-1]))
    t_in, _ = footprint_entry(p_en, az_rad, boxes)
    dz = boxes[:, 4] - z0_m
    # max over boxes of tan(elevation) = dz / t_in (t_in = 0 inside → +inf → π/2)
    with np.errstate(divide="ignore"):
        tan_el = np.where(dz > 0, dz / t_in, 0.0).max(axis=-1)
    return np.arctan(tan_el)


def sky_blocked_fraction(p_en: np.ndarray, boxes: np.ndarray, z0_m: float, mask_deg: float = 10.0,
                         n_az: int = 360, tile_m: float = 8.0, sky=None) -> np.ndarray:
    """Share of the sky above the elevation mask hidden by ``boxes``, per point.

    Solid-angle weighted by default: the sky between the mask and elevation ``e``
    along one azimuth spans ∫cos(e')de' = sin(e) − sin(mask), the whole sky above
    the mask 2π(1 − sin(mask)). With ``sky`` (an object whose ``blocked(hor_rad)``
    maps skyline elevations of shape (n, n_az) to shares of shape (n,), e.g.
    :class:`simulation.site.environment.SatelliteSky`), the share of that sky
    distribution instead. Returns ndarray of shape (n,) in [0, 1].

    Points are processed in square tiles of ``tile_m``; a box is tested only
    against tiles within its reach (h − z0)/tan(mask), beyond which it cannot
    rise above the mask — the result is exact, only faster.
    """
    p = np.atleast_2d(np.asarray(p_en, float))
    az = (np.arange(n_az) + 0.5) * (2.0 * np.pi / n_az)
    mask = np.radians(mask_deg)
    s_mask = np.sin(mask)
    out = np.zeros(p.shape[0])
    tall = boxes[boxes[:, 4] > z0_m] if boxes.shape[0] else boxes
    if tall.shape[0] == 0 or p.shape[0] == 0:
        return out
    reach = (tall[:, 4] - z0_m) / max(np.tan(mask), 1e-6)
    tiles = np.floor(p / tile_m).astype(np.int64)
    keys, inverse = np.unique(tiles, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    order = np.argsort(inverse, kind="stable")
    bounds = np.searchsorted(inverse[order], np.arange(len(keys) + 1))
    for k in range(len(keys)):
        idx = order[bounds[k]:bounds[k + 1]]
        lo = keys[k] * tile_m
        hi = lo + tile_m
        # distance from the tile's square to each footprint
        de = np.maximum(0.0, np.maximum(tall[:, 0] - hi[0], lo[0] - tall[:, 1]))
        dn = np.maximum(0.0, np.maximum(tall[:, 2] - hi[1], lo[1] - tall[:, 3]))
        near = np.hypot(de, dn) <= reach
        if not near.any():
            continue
        hor = horizon_elevation(p[idx], az, tall[near], z0_m)
        if sky is None:
            out[idx] = np.clip(np.sin(hor) - s_mask, 0.0, None).mean(axis=1) / (1.0 - s_mask)
        else:
            out[idx] = sky.blocked(hor)
    return out


def ray_blockers(p_en: np.ndarray, az_rad: np.ndarray, el_rad: np.ndarray, boxes: np.ndarray,
                 z0_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which boxes a ray toward the sky (az, el) passes through.

    Parameters
    ----------
    p_en : (n, 2) receiver positions; az_rad, el_rad : (n, k) directions.

    Returns
    -------
    blocked : bool ndarray (n, k, m)
        The ray passes through box j below its top.
    clearance_m : ndarray (n, k, m)
        Height of the box top above the ray where it enters the footprint
        (positive = blocked by that much, negative = passes above by that
        much; ``-inf`` where the footprint is missed). Used for knife-edge
        diffraction at the roof edge.
    t_in_m : ndarray (n, k, m)
        Horizontal distance to the footprint entry (``inf`` if missed).
    """
    t_in, _ = footprint_entry(p_en, az_rad, boxes)
    el = np.asarray(el_rad, float)[..., None]
    ray_z = z0_m + t_in * np.tan(el)
    clearance = np.where(np.isfinite(t_in), boxes[:, 4] - ray_z, -np.inf)
    blocked = clearance > 0.0
    return blocked, clearance, t_in


def segment_hits_boxes(a_xyz: np.ndarray, b_xyz: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Whether 3-D segments a→b pass through boxes (ground to top), slab test in 3-D (Kay & Kajiya 1986).

    a_xyz, b_xyz : ndarray of shape (n, 3) (east, north, up); boxes : (m, 5). Returns bool (n, m).
    Endpoints lying exactly on a face do not count as hits.
    """
    a = np.ascontiguousarray(a_xyz, dtype=float).reshape(-1, 3)
    b = np.ascontiguousarray(b_xyz, dtype=float).reshape(-1, 3)
    return segment_box_hits(a, b, np.ascontiguousarray(boxes, dtype=float).reshape(-1, 5))


@njit(cache=True)
def segment_box_hits(a: np.ndarray, b: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Slab test of every segment a[i]→b[i] (n, 3) against every box (m, 5); bool (n, m). Compiled: callable
    from other compiled code with float arrays (:func:`segment_hits_boxes` converts any input).

    Per axis k with direction d_k = b_k − a_k: entry/exit parameters (lo_k − a_k)/d_k and (hi_k − a_k)/d_k
    (computed as products with 1/d_k); an axis with |d_k| ≤ 1e-12 is parallel and admits all t when a_k lies
    strictly inside the slab, none otherwise. The segment hits when t_exit > t_enter + ε, t_exit > ε and
    t_enter < 1 − ε (ε = 1e-9), i.e. it runs a positive length inside the box within t ∈ (0, 1).
    """
    n, m = a.shape[0], boxes.shape[0]
    out = np.zeros((n, m), np.bool_)
    eps = 1e-9
    for i in range(n):
        for j in range(m):
            t_enter, t_exit = -np.inf, np.inf
            for k in range(3):
                lo = boxes[j, 2 * k] if k < 2 else 0.0
                hi = boxes[j, 2 * k + 1] if k < 2 else boxes[j, 4]
                d = b[i, k] - a[i, k]
                if abs(d) > 1e-12:
                    inv = 1.0 / d
                    t1 = (lo - a[i, k]) * inv
                    t2 = (hi - a[i, k]) * inv
                    t_enter = max(t_enter, min(t1, t2))
                    t_exit = min(t_exit, max(t1, t2))
                elif not (a[i, k] > lo and a[i, k] < hi):
                    t_enter, t_exit = np.inf, -np.inf
            out[i, j] = (t_exit > t_enter + eps) and (t_exit > eps) and (t_enter < 1.0 - eps)
    return out


def inside_boxes(p_en: np.ndarray, boxes: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
    """Whether points (n, 2) lie inside any box footprint grown by ``margin_m``. Returns bool (n,)."""
    p = np.atleast_2d(np.asarray(p_en, float))
    if boxes.shape[0] == 0:
        return np.zeros(p.shape[0], bool)
    e = p[:, 0][:, None]
    n = p[:, 1][:, None]
    ins = ((e >= boxes[:, 0] - margin_m) & (e <= boxes[:, 1] + margin_m)
           & (n >= boxes[:, 2] - margin_m) & (n <= boxes[:, 3] + margin_m))
    return ins.any(axis=1)
