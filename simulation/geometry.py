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

import numpy as np

from features.site import Box

__all__ = ["boxes_array", "footprint_entry", "horizon_elevation", "sky_blocked_fraction",
           "ray_blockers", "segment_hits_boxes", "inside_boxes"]


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
    p = np.asarray(p_en, float)
    az = np.asarray(az_rad, float)
    if az.ndim == 1:
        az = np.broadcast_to(az, (p.shape[0], az.shape[0]))
    de = np.sin(az)[..., None]
    dn = np.cos(az)[..., None]
    pe = p[:, 0][:, None, None]
    pn = p[:, 1][:, None, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_e = np.where(np.abs(de) > 1e-12, 1.0 / de, np.inf)
        inv_n = np.where(np.abs(dn) > 1e-12, 1.0 / dn, np.inf)
        t1 = (boxes[:, 0] - pe) * inv_e
        t2 = (boxes[:, 1] - pe) * inv_e
        t3 = (boxes[:, 2] - pn) * inv_n
        t4 = (boxes[:, 3] - pn) * inv_n
    # Rays parallel to a slab: inside the slab → (-inf, inf), outside → empty.
    par_e = ~np.isfinite(inv_e)
    par_n = ~np.isfinite(inv_n)
    in_e = (pe >= boxes[:, 0]) & (pe <= boxes[:, 1])
    in_n = (pn >= boxes[:, 2]) & (pn <= boxes[:, 3])
    lo_e = np.where(par_e, np.where(in_e, -np.inf, np.inf), np.minimum(t1, t2))
    hi_e = np.where(par_e, np.where(in_e, np.inf, -np.inf), np.maximum(t1, t2))
    lo_n = np.where(par_n, np.where(in_n, -np.inf, np.inf), np.minimum(t3, t4))
    hi_n = np.where(par_n, np.where(in_n, np.inf, -np.inf), np.maximum(t3, t4))
    t_lo = np.maximum(lo_e, lo_n)
    t_hi = np.minimum(hi_e, hi_n)
    hit = (t_hi >= np.maximum(t_lo, 0.0))
    t_in = np.where(hit, np.maximum(t_lo, 0.0), np.inf)
    t_out = np.where(hit, t_hi, np.inf)
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
    with np.errstate(divide="ignore"):
        el = np.arctan2(dz, t_in)  # t_in=inf → 0; t_in=0 → π/2 (when dz > 0)
    el = np.where(np.isfinite(t_in) & (dz > 0), el, 0.0)
    return el.max(axis=-1)


def sky_blocked_fraction(p_en: np.ndarray, boxes: np.ndarray, z0_m: float, mask_deg: float = 10.0,
                         n_az: int = 360, chunk: int = 512) -> np.ndarray:
    """Share of the sky above the elevation mask hidden by ``boxes``, per point.

    Solid-angle weighted: the sky between the mask and elevation ``e`` along one
    azimuth spans ∫cos(e')de' = sin(e) − sin(mask), the whole sky above the mask
    2π(1 − sin(mask)). Returns ndarray of shape (n,) in [0, 1].
    """
    p = np.atleast_2d(np.asarray(p_en, float))
    az = (np.arange(n_az) + 0.5) * (2.0 * np.pi / n_az)
    s_mask = np.sin(np.radians(mask_deg))
    out = np.empty(p.shape[0])
    for i in range(0, p.shape[0], chunk):
        hor = horizon_elevation(p[i:i + chunk], az, boxes, z0_m)
        out[i:i + chunk] = np.clip(np.sin(hor) - s_mask, 0.0, None).mean(axis=1) / (1.0 - s_mask)
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
    """Whether 3-D segments a→b pass through boxes (ground to top), slab test in 3-D.

    a_xyz, b_xyz : ndarray of shape (n, 3) (east, north, up). Returns bool (n, m).
    Endpoints lying exactly on a face do not count as hits.
    """
    a = np.asarray(a_xyz, float)[:, None, :]
    d = np.asarray(b_xyz, float)[:, None, :] - a
    lo = np.stack([boxes[:, 0], boxes[:, 2], np.zeros(len(boxes))], axis=-1)[None]
    hi = np.stack([boxes[:, 1], boxes[:, 3], boxes[:, 4]], axis=-1)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.abs(d) > 1e-12, 1.0 / d, np.inf)
        t1 = (lo - a) * inv
        t2 = (hi - a) * inv
    par = ~np.isfinite(inv)
    inside = (a > lo) & (a < hi)
    tmin = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    t_enter = tmin.max(axis=-1)
    t_exit = tmax.min(axis=-1)
    eps = 1e-9
    return (t_exit > t_enter + eps) & (t_exit > eps) & (t_enter < 1.0 - eps)


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
