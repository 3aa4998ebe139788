"""Walking routes through a site's aisles, time-parameterised into a :class:`Trajectory`.

The walker works as a maintenance crew does: rounds of visits, each round a
random order of the three environment classes, each class visited with
probability ``visit_probability`` (open ground is mostly crossed on the way,
not a destination), so every walk sees open, light and heavy ground. A visit in a class is, with probability
``inspect_probability`` of that class, an **inspection stop** at a piece of
equipment of the site's layout (transformers, apparatus, buildings and kiosks:
the boxes whose ``kind`` is in ``inspect_kinds``) — the walker stands beside it,
on a free point within ``inspect_reach_m`` of its face, for 30–300 s
(``inspect_stop_s``; routine inspections of a transformer, a breaker or a panel
take minutes) — otherwise a transit waypoint with a short standing stop now and
then. The stand point is drawn among the equipment's stand points of the
visit's class, so heavy visits stand beside tanks and fire walls, where the
static multipath lasts as long as the stop. A stop never takes more than
``max_stop_share`` of the walk, so a short walk still holds several visits.

Between waypoints the walker follows the shortest 8-connected path on a 0.5 m
occupancy grid (Dijkstra, scipy.sparse.csgraph), with corners cut where the
line of sight is clear (string pulling) and rounded by Gaussian smoothing.
Speed: a cruising speed of 1.0–1.5 m/s (typical adult walking, Bohannon 1997:
1.27–1.46 m/s comfortable), slowed in turns so lateral acceleration stays below
0.8 m/s², with ±0.5 m/s² acceleration limits; a standing start.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from features.site import Site

from simulation.site.environment import classify_share, blocked_share
from simulation.site.geometry import boxes_array, inside_boxes
from simulation.streams import Trajectory

__all__ = ["RouteConfig", "walkable_grid", "inspection_points", "plan_route", "route_trajectory",
           "static_trajectory"]


@dataclass(frozen=True)
class RouteConfig:
    """Route and gait-speed parameters."""

    resolution_m: float = 0.5
    clearance_m: float = 0.7
    speed_m_s: tuple[float, float] = (1.0, 1.5)
    max_lateral_acc_m_s2: float = 0.8
    max_acc_m_s2: float = 0.5
    stop_probability: float = 0.25
    stop_s: tuple[float, float] = (5.0, 15.0)
    start_stand_s: tuple[float, float] = (3.0, 6.0)
    rate_hz: float = 100.0
    visit_probability: tuple[float, float, float] = (0.35, 1.0, 1.0)
    inspect_probability: tuple[float, float, float] = (0.15, 0.7, 0.9)
    inspect_stop_s: tuple[float, float] = (30.0, 300.0)
    inspect_kinds: tuple[str, ...] = ("transformer", "equipment", "building", "firewall")
    inspect_reach_m: float = 1.5
    max_stop_share: float = 0.3

    def __post_init__(self):
        if not 1.0 <= self.speed_m_s[0] <= self.speed_m_s[1] <= 2.0:
            raise ValueError(f"speed_m_s must lie within [1.0, 2.0] and be ordered, got {self.speed_m_s}")
        if self.resolution_m <= 0 or self.clearance_m < 0:
            raise ValueError("resolution_m must be positive and clearance_m non-negative")
        for name in ("visit_probability", "inspect_probability"):
            v = getattr(self, name)
            if len(v) != 3 or not all(0.0 <= p <= 1.0 for p in v):
                raise ValueError(f"{name} must be three probabilities (open, light, heavy), got {v}")
        if max(self.visit_probability) <= 0.0:
            raise ValueError("visit_probability must allow at least one class")
        if not 0.0 <= self.inspect_stop_s[0] <= self.inspect_stop_s[1]:
            raise ValueError(f"inspect_stop_s must be an ordered pair of non-negative seconds, got {self.inspect_stop_s}")
        if not self.inspect_reach_m > 0 or not 0.0 < self.max_stop_share <= 1.0:
            raise ValueError(f"inspect_reach_m must be positive and max_stop_share in (0, 1], got "
                             f"{self.inspect_reach_m}, {self.max_stop_share}")


def walkable_grid(site: Site, cfg: RouteConfig):
    """Occupancy grid: True where a person can stand (outside solid structures by ``clearance_m``).

    Porous structures (gantries) are walkable beneath. Returns (east_m (nx,), north_m (ny,), free (ny, nx)).
    """
    g = site.grid
    r = cfg.resolution_m
    east = np.arange(g.east_min_m + r / 2, g.east_max_m, r)
    north = np.arange(g.north_min_m + r / 2, g.north_max_m, r)
    ee, nn = np.meshgrid(east, north)
    solid = boxes_array([b for b in site.layout if not b.porous])
    free = ~inside_boxes(np.column_stack([ee.ravel(), nn.ravel()]), solid, margin_m=cfg.clearance_m)
    free = free.reshape(ee.shape)
    border = int(np.ceil(1.0 / r))
    free[:border, :] = free[-border:, :] = False
    free[:, :border] = free[:, -border:] = False
    return east, north, free


def _graph(free: np.ndarray, r: float):
    ny, nx = free.shape
    idx = np.arange(ny * nx).reshape(ny, nx)
    rows, cols, w = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = free[max(0, -dy):ny - max(0, dy), max(0, -dx):nx - max(0, dx)]
        ys, xs = np.nonzero(a)
        ys0, xs0 = ys + max(0, -dy), xs + max(0, -dx)
        ys1, xs1 = ys0 + dy, xs0 + dx
        ok = free[ys1, xs1]
        if dx != 0 and dy != 0:  # no diagonal squeeze between two blocked cells
            ok &= free[ys0 + dy, xs0] & free[ys0, xs0 + dx]
        rows.append(idx[ys0[ok], xs0[ok]])
        cols.append(idx[ys1[ok], xs1[ok]])
        w.append(np.full(ok.sum(), r * np.hypot(dx, dy)))
    rows, cols, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    return coo_matrix((w, (rows, cols)), shape=(ny * nx, ny * nx)).tocsr()


def _line_free(p, q, free, east, north, r):
    n = max(2, int(np.ceil(np.hypot(*(q - p)) / (r / 2))))
    s = np.linspace(0, 1, n)[:, None]
    pts = p + s * (q - p)
    ix = np.clip(np.round((pts[:, 0] - east[0]) / r).astype(int), 0, len(east) - 1)
    iy = np.clip(np.round((pts[:, 1] - north[0]) / r).astype(int), 0, len(north) - 1)
    return bool(free[iy, ix].all())


def _string_pull(path, free, east, north, r):
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1 and not _line_free(path[i], path[j], free, east, north, r):
            j = max(i + 1, i + (j - i) // 2) if j - i > 8 else j - 1
        out.append(path[j])
        i = j
    return np.array(out)


def inspection_points(site: Site, east: np.ndarray, north: np.ndarray, free: np.ndarray,
                      cfg: RouteConfig = RouteConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Where a crew stands to inspect each piece of equipment: free grid cells beside its faces.

    A cell is a stand point of a box whose ``kind`` is in ``cfg.inspect_kinds`` when it is free and
    its horizontal distance to the box is at most ``clearance_m + inspect_reach_m``. Returns
    (flat cell indices (p,) into ``free``, box index (p,)), sorted by box.
    """
    ee, nn = np.meshgrid(east, north)
    flat_free = np.flatnonzero(free.ravel())
    pe, pn = ee.ravel()[flat_free], nn.ravel()[flat_free]
    reach = cfg.clearance_m + cfg.inspect_reach_m
    cells, owner = [], []
    for j, b in enumerate(site.layout):
        if b.kind not in cfg.inspect_kinds or b.porous:
            continue
        de = np.maximum(np.maximum(b.east_min_m - pe, pe - b.east_max_m), 0.0)
        dn = np.maximum(np.maximum(b.north_min_m - pn, pn - b.north_max_m), 0.0)
        near = np.flatnonzero(np.hypot(de, dn) <= reach)
        cells.append(flat_free[near])
        owner.append(np.full(near.size, j))
    if not cells:
        return np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(cells), np.concatenate(owner)


def _stand_pools(site, east, north, free, main_cells, cfg, rng):
    """Per class, the inspection stand points (flat cells) in the walkable region: a list of 3 arrays.

    Each box contributes at most 6 stand points (drawn), so a long wall does not outweigh a breaker.
    """
    cells, owner = inspection_points(site, east, north, free, cfg)
    keep = np.isin(cells, main_cells)
    cells, owner = cells[keep], owner[keep]
    pick = []
    for j in np.unique(owner):
        idx = np.flatnonzero(owner == j)
        pick.append(rng.choice(idx, size=min(6, idx.size), replace=False))
    if not pick:
        return [np.zeros(0, int)] * 3
    cells = cells[np.sort(np.concatenate(pick))]
    iy, ix = np.divmod(cells, free.shape[1])
    cls = classify_share(blocked_share(site, east[ix], north[iy], n_az=72))
    return [cells[cls == c] for c in range(3)]


def plan_route(site: Site, rng: np.random.Generator, duration_s: float, cfg: RouteConfig = RouteConfig()):
    """Waypoints and polyline of a walk long enough for ``duration_s`` (module docstring: rounds of visits).

    Returns (polyline (k, 2) ENU metres, stop_at (k,) seconds of standing at each vertex, speed_m_s).
    """
    east, north, free = walkable_grid(site, cfg)
    r = cfg.resolution_m
    graph = _graph(free, r)
    fy, fx = np.nonzero(free)
    # Waypoint candidates: a random sample of free cells, classified by blocked sky.
    pick = rng.choice(len(fy), size=min(len(fy), 4000), replace=False)
    fy, fx = fy[pick], fx[pick]
    flat = fy * free.shape[1] + fx
    cls = classify_share(blocked_share(site, east[fx], north[fy], n_az=72))
    speed = float(rng.uniform(*cfg.speed_m_s))
    # Walk only within the largest connected free region.
    _, comp = connected_components(graph, directed=False)
    main_label = np.bincount(comp[flat]).argmax()
    main = comp[flat] == main_label
    pool = [np.flatnonzero(main & (cls == c)) for c in range(3)]
    pool = [p if len(p) else np.flatnonzero(main) for p in pool]
    budget_m = duration_s * speed * 1.1 + 50.0
    # Stand points are drawn only when inspections are on: with them off the draws are those of the transit-only
    # routes before issue 21, so a walk of that kind is the same walk.
    empty = np.zeros(0, int)
    stands = (_stand_pools(site, east, north, free, np.flatnonzero(comp == main_label), cfg, rng)
              if max(cfg.inspect_probability) > 0 else [empty, empty, empty])
    max_stop = cfg.max_stop_share * duration_s
    nodes = [flat[np.flatnonzero(main)[rng.integers(main.sum())]]]
    inspect_stop: list = [None]
    length = 0.0  # metres walked, plus the metres the walker would have covered while inspecting
    while length < budget_m and len(nodes) < 400:
        for c in rng.permutation(3):
            if cfg.visit_probability[c] < 1.0 and rng.random() >= cfg.visit_probability[c]:
                continue
            p_insp = cfg.inspect_probability[c]
            if p_insp > 0.0 and stands[c].size > 0 and rng.random() < p_insp:
                nodes.append(int(stands[c][rng.integers(stands[c].size)]))
                inspect_stop.append(min(float(rng.uniform(*cfg.inspect_stop_s)), max_stop))
                length += speed * inspect_stop[-1]
            else:
                nodes.append(flat[pool[c][rng.integers(len(pool[c]))]])
                inspect_stop.append(None)
            ay, ax = np.divmod(nodes[-2], free.shape[1])
            by, bx = np.divmod(nodes[-1], free.shape[1])
            length += 1.3 * r * float(np.hypot(bx - ax, by - ay))  # detour factor of aisles
    pts_all = []
    stops = []
    for a, b, insp in zip(nodes[:-1], nodes[1:], inspect_stop[1:]):
        _, pred = dijkstra(graph, indices=a, directed=False, return_predecessors=True)
        seq = [b]
        while seq[-1] != a and pred[seq[-1]] >= 0:
            seq.append(pred[seq[-1]])
        if seq[-1] != a:
            continue
        seq = seq[::-1]
        iy, ix = np.divmod(np.array(seq), free.shape[1])
        seg = np.column_stack([east[ix], north[iy]])
        seg = _string_pull(seg, free, east, north, r)
        if pts_all:
            seg = seg[1:]
        stops.extend([0.0] * (len(seg) - 1))
        pts_all.append(seg)
        stop = insp if insp is not None else (
            float(rng.uniform(*cfg.stop_s)) if rng.random() < cfg.stop_probability else 0.0)
        stops.append(stop)
    poly = np.vstack(pts_all)
    stops = np.array(stops[:len(poly)])
    stops[0] = float(rng.uniform(*cfg.start_stand_s))
    return poly, stops, speed


def route_trajectory(poly: np.ndarray, stops: np.ndarray, speed_m_s: float, duration_s: float,
                     start_utc: datetime, z_m: float, cfg: RouteConfig = RouteConfig()) -> Trajectory:
    """Time-parameterise a polyline into a 100 Hz :class:`Trajectory` of ``duration_s``.

    Corners are rounded by Gaussian smoothing (σ = 0.5 m of arc length); speed
    is capped by the lateral-acceleration limit v ≤ sqrt(a_lat/κ) and by the
    forward/backward acceleration limit; each vertex's stop is inserted where
    the path passes it.
    """
    ds = 0.05
    seg_len = np.hypot(*np.diff(poly, axis=0).T)
    s_vert = np.concatenate([[0.0], np.cumsum(seg_len)])
    s = np.arange(0.0, s_vert[-1], ds)
    xy = np.column_stack([np.interp(s, s_vert, poly[:, 0]), np.interp(s, s_vert, poly[:, 1])])
    xy = gaussian_filter1d(xy, sigma=0.5 / ds, axis=0, mode="nearest")
    d = np.gradient(xy, ds, axis=0)
    dd = np.gradient(d, ds, axis=0)
    kappa = np.abs(d[:, 0] * dd[:, 1] - d[:, 1] * dd[:, 0]) / np.maximum(np.hypot(*d.T) ** 3, 1e-9)
    v = np.minimum(speed_m_s, np.sqrt(cfg.max_lateral_acc_m_s2 / np.maximum(kappa, 1e-6)))
    v = np.maximum(v, 0.3)
    stop_idx = np.clip(np.searchsorted(s, s_vert), 0, len(s) - 1)
    v[0] = 0.0
    v[-1] = 0.0
    v[stop_idx[stops > 0]] = 0.0
    a = cfg.max_acc_m_s2
    for i in range(1, len(v)):  # forward pass: v² ≤ v_prev² + 2 a ds
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * a * ds))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * a * ds))
    v_mid = np.maximum(0.5 * (v[1:] + v[:-1]), 0.05)
    t_path = np.concatenate([[0.0], np.cumsum(ds / v_mid)])
    # insert stops: shift time after each stop vertex
    extra = np.zeros_like(t_path)
    for k, st in zip(stop_idx, stops):
        if st > 0:
            extra[k:] += st
    t_knots = t_path + extra
    # Duplicate knots at stops so position holds (and speed is 0) during the stop.
    t_k, s_k, v_k = [], [], []
    for i in range(len(s)):
        if i > 0 and extra[i] > extra[i - 1]:
            t_k.append(t_path[i] + extra[i - 1])
            s_k.append(s[i])
            v_k.append(0.0)
        t_k.append(t_knots[i])
        s_k.append(s[i])
        v_k.append(v[i])
    t_k, s_k, v_k = np.array(t_k), np.array(s_k), np.array(v_k)
    if stops[0] > 0:  # standing start before the first knot
        t_k = np.concatenate([[0.0], t_k + stops[0]])
        s_k = np.concatenate([[0.0], s_k])
        v_k = np.concatenate([[0.0], v_k])
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / cfg.rate_hz)
    s_t = np.interp(t, t_k, s_k)
    east = np.interp(s_t, s, xy[:, 0])
    north = np.interp(s_t, s, xy[:, 1])
    heading_path = np.arctan2(d[:, 0], d[:, 1])
    heading = np.interp(s_t, s, np.unwrap(heading_path))
    heading = np.mod(heading, 2 * np.pi)
    speed = np.interp(t, t_k, v_k)
    return Trajectory(t_s=t, east_m=east, north_m=north, up_m=np.full_like(t, z_m), heading_rad=heading,
                      speed_m_s=speed, start_utc=start_utc, rate_hz=cfg.rate_hz)


def static_trajectory(east_m: float, north_m: float, z_m: float, duration_s: float, start_utc: datetime,
                      heading_rad: float = 0.0, rate_hz: float = 100.0) -> Trajectory:
    """A receiver standing still (a survey capture)."""
    t = np.arange(0.0, duration_s + 1e-9, 1.0 / rate_hz)
    ones = np.ones_like(t)
    return Trajectory(t_s=t, east_m=east_m * ones, north_m=north_m * ones, up_m=z_m * ones,
                      heading_rad=heading_rad * ones, speed_m_s=0.0 * ones, start_utc=start_utc, rate_hz=rate_hz)
