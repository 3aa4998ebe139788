"""Compiled path geometry of the acoustic channel: diffraction round boxes and first-order wall reflections.

The per-emission geometry of :func:`simulation.acoustic.channel.channel_paths` (issue 25 item 2: one
implementation, compiled with numba, no Python twin). Boxes are rows (east_min, east_max, north_min,
north_max, height); faces are rows (axis 0=east/1=north, plane coordinate, outward sign, lo, hi, height, |R|)
as :class:`simulation.acoustic.channel.Scene` stores them. Visibility is the slab test of
:func:`simulation.site.geometry.segment_hits_boxes`.

* :func:`over_top_length` — taut string over the box tops in the vertical plane through source and
  receiver: the upper convex hull of the crossed footprints' top edges (Andrew's monotone chain, 1979).
* :func:`lateral_length` — shortest path round the vertical edges: Dijkstra (1959) over the plan visibility
  graph of the obstructing boxes' corners, 3-D length sqrt(L_plan² + Δz²), boxes the route still hits join
  the obstacle set (at most four rounds).
* :func:`wall_reflections` — image sources in the solid boxes' vertical faces (Allen & Berkley 1979, JASA
  65(4)), kept when the specular point lies on the face and both legs are clear.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from simulation.site.geometry import footprint_slab, inverse_direction, segment_box_hits

__all__ = ["over_top_length", "lateral_length", "wall_reflections", "discrete_paths", "NUDGE_M"]

NUDGE_M = 1e-6
"""Step off a reflecting face or the ground onto the outer side before testing a leg's visibility, m."""

_CORNER_EPS_M = 1e-3        # corners of the visibility graph stand this far outside the box


@njit(cache=True)
def _upper_hull_length(u: np.ndarray, z: np.ndarray) -> float:
    """Length of the upper convex hull of points (u, z) sorted by u (Andrew's monotone chain, 1979)."""
    hu = np.empty(len(u))
    hz = np.empty(len(u))
    k = 0
    for i in range(len(u)):
        while k >= 2:
            cross = (hu[k - 1] - hu[k - 2]) * (z[i] - hz[k - 2]) - (hz[k - 1] - hz[k - 2]) * (u[i] - hu[k - 2])
            if cross >= 0:       # the last point lies on or below o→p: not on the upper hull
                k -= 1
            else:
                break
        hu[k], hz[k] = u[i], z[i]
        k += 1
    total = 0.0
    for i in range(1, k):
        total += math.hypot(hu[i] - hu[i - 1], hz[i] - hz[i - 1])
    return total


@njit(cache=True)
def over_top_length(solid: np.ndarray, src: np.ndarray, rx: np.ndarray) -> float:
    """Taut-string length over the box tops in the vertical plane through src and rx, m (inf if no box is
    crossed). solid : (m, 5); src, rx : (3,)."""
    d_h = math.hypot(rx[0] - src[0], rx[1] - src[1])
    if d_h < 1e-6 or solid.shape[0] == 0:
        return np.inf
    inv_e, inv_n = inverse_direction(math.atan2(rx[0] - src[0], rx[1] - src[1]))
    m = solid.shape[0]
    u = np.empty(2 * m)
    z = np.empty(2 * m)
    n = 0
    crossed = False
    for j in range(m):          # each crossed footprint's entry and exit edge at its top's height
        t_in, t_out = footprint_slab(src[0], src[1], inv_e, inv_n, solid[j])
        if np.isfinite(t_in) and t_in < d_h:
            crossed = True
            for t in (t_in, min(t_out, d_h)):
                if 0.0 < t < d_h:   # the end points stay the ends of the chain even when a box touches them
                    u[n], z[n] = t, solid[j, 4]
                    n += 1
    if not crossed:
        return np.inf
    order = np.argsort(u[:n], kind="mergesort")
    uu = np.empty(n + 2)
    zz = np.empty(n + 2)
    uu[0], zz[0] = 0.0, src[2]
    uu[n + 1], zz[n + 1] = d_h, rx[2]
    for i in range(n):
        uu[i + 1], zz[i + 1] = u[order[i]], z[order[i]]
    _sort_ties_by_height(uu, zz, 1, n + 1)
    return _upper_hull_length(uu, zz)


@njit(cache=True)
def _sort_ties_by_height(u: np.ndarray, z: np.ndarray, lo: int, hi: int) -> None:
    """Within runs of equal u in u[lo:hi] (already sorted by u), order by z ascending (a lexsort's tie rule)."""
    i = lo
    while i < hi:
        j = i + 1
        while j < hi and u[j] == u[i]:
            j += 1
        if j - i > 1:
            z[i:j] = np.sort(z[i:j])
        i = j


@njit(cache=True)
def _dijkstra_dense(w: np.ndarray, source: int) -> tuple[np.ndarray, np.ndarray]:
    """Shortest distances and predecessors from ``source`` over a dense (k, k) weight matrix (inf = no edge),
    Dijkstra (1959) with an O(k²) scan (a handful of corner nodes); ties go to the lowest index."""
    k = w.shape[0]
    dist = np.full(k, np.inf)
    pred = np.full(k, -1)
    done = np.zeros(k, np.bool_)
    dist[source] = 0.0
    for _ in range(k):
        u, best = -1, np.inf
        for i in range(k):
            if not done[i] and (u < 0 or dist[i] < best):
                u, best = i, dist[i]
        if not np.isfinite(dist[u]):
            break
        done[u] = True
        for i in range(k):
            alt = dist[u] + w[u, i]
            if alt < dist[i] and not done[i]:
                dist[i] = alt
                pred[i] = u
    return dist, pred


@njit(cache=True)
def _plan_route(ob: np.ndarray, src: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """Shortest plan route src→rx round the corners of the boxes ``ob`` (q, 5): its nodes (r, 2), or an empty
    array when the receiver cannot be reached."""
    q = ob.shape[0]
    eps = _CORNER_EPS_M
    nodes = np.empty((2 + 4 * q, 2))
    nodes[0], nodes[1] = src[:2], rx[:2]
    for j in range(q):              # corners in the order (e0, n0), (e0, n1), (e1, n0), (e1, n1), box by box
        nodes[2 + j, 0], nodes[2 + j, 1] = ob[j, 0] - eps, ob[j, 2] - eps
        nodes[2 + q + j, 0], nodes[2 + q + j, 1] = ob[j, 0] - eps, ob[j, 3] + eps
        nodes[2 + 2 * q + j, 0], nodes[2 + 2 * q + j, 1] = ob[j, 1] + eps, ob[j, 2] - eps
        nodes[2 + 3 * q + j, 0], nodes[2 + 3 * q + j, 1] = ob[j, 1] + eps, ob[j, 3] + eps
    k = nodes.shape[0]
    n_pairs = k * (k - 1) // 2
    a = np.ones((n_pairs, 3))        # every node pair as a plan segment at z = 1 against infinitely tall boxes
    b = np.ones((n_pairs, 3))
    pair = 0
    for i in range(k):
        for j in range(i + 1, k):
            a[pair, :2], b[pair, :2] = nodes[i], nodes[j]
            pair += 1
    tall = ob.copy()
    tall[:, 4] = 1e9
    hits = segment_box_hits(a, b, tall)
    w = np.full((k, k), np.inf)
    pair = 0
    for i in range(k):
        for j in range(i + 1, k):
            if not hits[pair].any():
                w[i, j] = w[j, i] = math.hypot(nodes[j, 0] - nodes[i, 0], nodes[j, 1] - nodes[i, 1])
            pair += 1
    dist, pred = _dijkstra_dense(w, 0)
    if not np.isfinite(dist[1]):
        return np.empty((0, 2))
    route = [1]
    while route[-1] != 0:
        route.append(pred[route[-1]])
    plan = np.empty((len(route), 2))
    for i in range(len(route)):
        plan[i] = nodes[route[len(route) - 1 - i]]
    return plan


@njit(cache=True)
def lateral_length(solid: np.ndarray, src: np.ndarray, rx: np.ndarray, blockers: np.ndarray) -> float:
    """Shortest 3-D path round the vertical edges of the boxes, m (inf if none within four rounds).

    solid : (m, 5); src, rx : (3,); blockers : int (b,) rows of ``solid`` the straight line hits. The route
    rises linearly from source to receiver: 3-D length sqrt(L_plan² + Δz²).
    """
    obstacles = np.zeros(solid.shape[0], np.bool_)
    obstacles[blockers] = True
    dz = rx[2] - src[2]
    for _round in range(4):
        plan = _plan_route(solid[np.flatnonzero(obstacles)], src, rx)
        if plan.shape[0] == 0:
            return np.inf
        r = plan.shape[0]
        cum = np.zeros(r)
        for i in range(1, r):
            cum[i] = cum[i - 1] + math.hypot(plan[i, 0] - plan[i - 1, 0], plan[i, 1] - plan[i - 1, 1])
        total = cum[-1]
        pts = np.empty((r, 3))
        pts[:, :2] = plan
        pts[:, 2] = src[2] + dz * cum / max(total, 1e-9)
        hits = segment_box_hits(pts[:-1], pts[1:], solid)
        grew = False
        for j in range(solid.shape[0]):
            if not obstacles[j] and hits[:, j].any():
                obstacles[j] = True
                grew = True
        if not grew:
            return math.hypot(total, dz)
    return np.inf


@njit(cache=True)
def _crossings(a: np.ndarray, b: np.ndarray, boxes: np.ndarray) -> int:
    """Number of boxes (m, 5) the segment a→b (3,) passes through."""
    return int(segment_box_hits(a.reshape(1, 3), b.reshape(1, 3), boxes).sum())


@njit(cache=True)
def wall_reflections(faces: np.ndarray, solid: np.ndarray, porous: np.ndarray, porous_loss_db: float,
                     src: np.ndarray, rx: np.ndarray, direct_m: float, max_excess_m: float):
    """First-order image-source reflections off vertical faces: (length_m, gain, face index), each (r,), in
    face order.

    Image of the source in face plane x_a = P: s'_a = 2P − s_a (Allen & Berkley 1979). Kept when source and
    receiver stand on the face's outer side, the path is at most ``max_excess_m`` longer than ``direct_m``,
    the specular point lies on the face (within its span and height) and neither leg crosses a solid box.
    Gain = |R| / L · 10^(−n·porous_loss_db/20) for n porous boxes crossed by each leg.
    """
    n_f = faces.shape[0]
    length = np.empty(n_f)
    gain = np.empty(n_f)
    index = np.empty(n_f, np.int64)
    n = 0
    for i in range(n_f):
        ax, plane, sign = int(faces[i, 0]), faces[i, 1], faces[i, 2]
        if not (sign * (src[ax] - plane) > 0 and sign * (rx[ax] - plane) > 0):
            continue
        image = src.copy()
        image[ax] = 2.0 * plane - src[ax]
        d = rx - image
        length_i = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if not length_i - direct_m <= max_excess_m:
            continue
        u = (plane - image[ax]) / (rx[ax] - image[ax])
        p = image + u * (rx - image)
        other = p[1 - ax]
        if not (faces[i, 3] <= other <= faces[i, 4] and 0.0 <= p[2] <= faces[i, 5]):
            continue
        p[ax] += sign * NUDGE_M          # step off the face onto the outer side
        if _crossings(src, p, solid) or _crossings(p, rx, solid):
            continue
        g = faces[i, 6] / length_i
        if porous.shape[0] and porous_loss_db != 0:
            g = g * 10.0 ** (-_crossings(src, p, porous) * porous_loss_db / 20.0)
            g = g * 10.0 ** (-_crossings(p, rx, porous) * porous_loss_db / 20.0)
        length[n], gain[n], index[n] = length_i, g, i
        n += 1
    return length[:n], gain[:n], index[:n]


@njit(cache=True)
def _porous_factor(a: np.ndarray, b: np.ndarray, porous: np.ndarray, porous_loss_db: float) -> float:
    """Pressure factor 10^(−n·loss/20) of the segment a→b crossing n porous boxes."""
    if porous.shape[0] == 0 or porous_loss_db == 0:
        return 1.0
    return 10.0 ** (-_crossings(a, b, porous) * porous_loss_db / 20.0)


@njit(cache=True)
def discrete_paths(solid: np.ndarray, solid_index: np.ndarray, porous: np.ndarray, faces: np.ndarray,
                   face_box: np.ndarray, porous_loss_db: float, ground_r: float, ground_reflection: bool,
                   reflections: bool, max_excess_m: float, src: np.ndarray, rx: np.ndarray):
    """Every discrete path from ``src`` to ``rx`` (3,), unsorted: (kind, length_m, gain, detour_m, box) arrays
    (kind: 0 direct, 1 ground, 2 reflection, 3 diffraction; box: ``solid_index`` of the box first hit by a
    diffracted path or of the reflecting face's box, −1 otherwise), the direct distance and line of sight.

    The direct path when the segment clears every solid box, else the shorter of :func:`over_top_length` and
    :func:`lateral_length`, gain 1/d either way (Maekawa's loss comes with frequency, at rendering); the ground
    reflection by the image source at z = −z_src with the ground's |R| when both legs are clear; the
    :func:`wall_reflections` (``face_box``: each face's row of ``solid``). Porous boxes crossed cost
    ``porous_loss_db`` each.
    """
    n_max = 2 + faces.shape[0]
    kind, box = np.full(n_max, -1), np.full(n_max, -1)
    length, gain, detour = np.zeros(n_max), np.zeros(n_max), np.zeros(n_max)
    dv = rx - src
    d = math.sqrt(np.dot(dv, dv))          # as numpy.linalg.norm computes it (BLAS ddot)
    hit = segment_box_hits(src.reshape(1, 3), rx.reshape(1, 3), solid)[0]
    los = not hit.any()
    n = 0
    if los:
        kind[0], length[0], gain[0] = 0, d, _porous_factor(src, rx, porous, porous_loss_db) / max(d, 1e-3)
        n = 1
    else:
        blockers = np.flatnonzero(hit)
        path = min(over_top_length(solid, src, rx), lateral_length(solid, src, rx, blockers))
        if np.isfinite(path):
            kind[0], length[0], gain[0] = 3, path, _porous_factor(src, rx, porous, porous_loss_db) / max(d, 1e-3)
            detour[0], box[0] = max(path - d, 0.0), solid_index[blockers[0]]
            n = 1
    u = src[2] / (src[2] + rx[2]) if src[2] > 0 and rx[2] > 0 else 0.0
    gp = src + u * (rx - src)              # the specular point on the ground, nudged above it
    gp[2] = 0.0 * gp[2] + NUDGE_M
    if u > 0 and ground_reflection and _crossings(src, gp, solid) == 0 and _crossings(gp, rx, solid) == 0:
        img = src.copy()
        img[2] = -src[2]
        gv = rx - img
        length[n] = math.sqrt(np.dot(gv, gv))
        kind[n] = 1
        gain[n] = (ground_r / length[n] * _porous_factor(src, gp, porous, porous_loss_db)
                   * _porous_factor(gp, rx, porous, porous_loss_db))
        n += 1
    if reflections:
        rl, rg, face = wall_reflections(faces, solid, porous, porous_loss_db, src, rx, d, max_excess_m)
        for i in range(len(rl)):
            kind[n], length[n], gain[n], box[n] = 2, rl[i], rg[i], solid_index[face_box[face[i]]]
            n += 1
    return kind[:n], length[:n], gain[:n], detour[:n], box[:n], d, los
