"""Beacon deployment as an installer would do it: every walkable point hears at least four beacons.

An installer walks the yard with a test receiver and adds poles until no spot
is left with fewer than four beacons heard. Here that is a greedy set cover
(Chvátal 1979, "A greedy heuristic for the set covering problem", Math. Oper.
Res. 4(3): repeatedly take the candidate that covers most of the remaining
demand) over candidate pole positions on a grid of free ground, with the
demand of each walkable point being ``k_required`` beacons.

"Hears" is the link budget of :func:`simulation.acoustic.synthesis.detection_range_m`
on the geometric first path: a beacon is heard at a point when the straight
line from the tweeter to the device clears every solid box and the point lies
within ``los_margin``·(free-field detection range), or, when a box is in the
way, within ``diffracted_range_m`` (a path bent round one edge loses
10·log10(3 + 20N) ≈ 13–20 dB at 20 kHz for detours of decimetres, Maekawa
1968, which divides the range by 4–10). The exact channel decides what a
receiver really detects; :func:`coverage_counts` is the installer's
planning rule, and ``bench/calibrate_sim.py`` reports the share of frames
with a fix on simulated walks.

Candidates are poles on a grid of free ground and wall mounts on fire walls and
buildings (:func:`_mount_points`); at most ``max_beacons`` = 24, so that two bands
of 80 ms slots make a frame of at most 0.96 s. On site 2 the mounts raised the
share of heavy points hearing four by the planning rule from 0.41 (20 poles) to
0.48, and by the simulated channel (:func:`heard_by_channel`) from 0.79 to 0.97.

Bands and slots: beacons alternate between ``bands`` (frequency division:
each beacon's chirp sweeps its own sub-band, ``f0_hz``/``f1_hz`` in
``site.toml``), and within a band take TDMA slots greedily so that slot-mates
stand at least ``reuse_distance_m`` apart (see docs/beacon_protocol.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simulation.site.geometry import boxes_array, inside_boxes

__all__ = ["CoverageConfig", "segments_clear", "coverage_counts", "place_beacons", "walkable_points"]


@dataclass(frozen=True)
class CoverageConfig:
    """Deployment rule (m, counts as named)."""

    k_required: int = 4
    detection_range_m: float = 60.0
    los_margin: float = 0.75
    diffracted_range_m: float = 12.0
    candidate_spacing_m: float = 7.0
    demand_spacing_m: float = 4.0
    max_beacons: int = 24
    min_beacon_separation_m: float = 15.0
    pole_clearance_m: float = 1.2
    device_height_m: float = 1.0
    mount_kinds: tuple[str, ...] = ("firewall", "building")
    mount_spacing_m: float = 3.0
    mount_offset_m: float = 0.15
    mount_separation_m: float = 6.0

    def __post_init__(self):
        if self.k_required < 1 or self.max_beacons < self.k_required:
            raise ValueError("CoverageConfig needs 1 <= k_required <= max_beacons")
        for name in ("detection_range_m", "los_margin", "diffracted_range_m", "candidate_spacing_m",
                     "demand_spacing_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"CoverageConfig.{name} must be positive, got {getattr(self, name)}")


def segments_clear(a_xyz: np.ndarray, b_xyz: np.ndarray, solid_boxes: np.ndarray) -> np.ndarray:
    """Whether each segment a→b misses every box, bool (n, m) for a (n, 3) and b (m, 3).

    Slab test of a segment against axis-aligned boxes [e0, e1] × [n0, n1] × [0, h]
    (Kay & Kajiya 1986, "Ray tracing complex scenes", SIGGRAPH): the segment
    a + t·(b − a), t ∈ [0, 1], meets the box when the parameter intervals of the
    three slabs overlap. ``solid_boxes`` : (k, 5) rows (e0, e1, n0, n1, h).

    >>> box = np.array([[4.0, 6.0, -1.0, 1.0, 5.0]])
    >>> segments_clear(np.array([[0.0, 0.0, 1.0]]), np.array([[10.0, 0.0, 1.0], [10.0, 0.0, 12.0]]), box).tolist()
    [[False, True]]
    """
    a = np.asarray(a_xyz, float)[:, None, None, :]
    d = np.asarray(b_xyz, float)[None, :, None, :] - a
    lo = np.stack([solid_boxes[:, 0], solid_boxes[:, 2], np.zeros(len(solid_boxes))], axis=-1)[None, None]
    hi = np.stack([solid_boxes[:, 1], solid_boxes[:, 3], solid_boxes[:, 4]], axis=-1)[None, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - a) / d
        t2 = (hi - a) / d
    inside = (a >= lo) & (a <= hi)
    parallel = d == 0
    t_min = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_max = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter = np.maximum(t_min.max(axis=-1), 0.0)
    leave = np.minimum(t_max.min(axis=-1), 1.0)
    hit = enter <= leave
    return ~hit.any(axis=-1)


def walkable_points(site, spacing_m: float, clearance_m: float = 0.5) -> np.ndarray:
    """Grid points of free ground (outside solid structures by ``clearance_m``), (n, 2) ENU m."""
    g = site.grid
    e = np.arange(g.east_min_m + spacing_m / 2, g.east_max_m, spacing_m)
    n = np.arange(g.north_min_m + spacing_m / 2, g.north_max_m, spacing_m)
    ee, nn = np.meshgrid(e, n)
    pts = np.column_stack([ee.ravel(), nn.ravel()])
    solid = boxes_array([b for b in site.layout if not b.porous])
    return pts[~inside_boxes(pts, solid, margin_m=clearance_m)]


def _heard(beacons_xyz: np.ndarray, points_en: np.ndarray, solid: np.ndarray, cfg: CoverageConfig) -> np.ndarray:
    """Planning rule of the module docstring, bool (n_points, n_beacons)."""
    rx = np.column_stack([points_en, np.full(len(points_en), cfg.device_height_m)])
    dist = np.linalg.norm(rx[:, None, :] - beacons_xyz[None, :, :], axis=-1)
    if not len(solid):
        clear = np.ones(dist.shape, bool)
    else:
        # In blocks of points: the slab test holds (points × beacons × boxes × 3) floats, 0.8 GB
        # at once for a yard's 600 points, 330 candidates and 60 boxes.
        clear = np.concatenate([segments_clear(rx[i:i + 32], beacons_xyz, solid)
                                for i in range(0, len(rx), 32)]) if len(rx) else np.zeros(dist.shape, bool)
    return (clear & (dist <= cfg.los_margin * cfg.detection_range_m)) | (dist <= cfg.diffracted_range_m)


def coverage_counts(site, points_en: np.ndarray, cfg: CoverageConfig = CoverageConfig(),
                    beacons_xyz: np.ndarray | None = None) -> np.ndarray:
    """Number of beacons heard at each point, (n,), by the planning rule."""
    solid = boxes_array([b for b in site.layout if not b.porous])
    if beacons_xyz is None:
        beacons_xyz = np.array([[b.east_m, b.north_m, b.up_m] for b in site.beacons]).reshape(-1, 3)
    if len(beacons_xyz) == 0:
        return np.zeros(len(points_en), int)
    return _heard(beacons_xyz, points_en, solid, cfg).sum(axis=1)


def _mount_points(layout, cfg: CoverageConfig, solid: np.ndarray) -> np.ndarray:
    """Wall-mount candidates (n, 2) ENU m: along every face of fire walls and buildings, ``mount_offset_m``
    off the face every ``mount_spacing_m``, and just beyond each end of a wall.

    Where poles cannot stand (the 1.2–2 m gaps between a transformer tank and its fire walls, the
    passage between buildings) an installer screws the beacon to the concrete: fire walls are the one
    structure every transformer bay has (IEEE Std 979), and they face the tanks the staff inspect.
    """
    out = []
    o, sp = cfg.mount_offset_m, cfg.mount_spacing_m
    for b in layout:
        if b.porous or b.kind not in cfg.mount_kinds:
            continue
        e0, e1, n0, n1 = b.east_min_m, b.east_max_m, b.north_min_m, b.north_max_m
        along_n = np.linspace(n0, n1, max(2, int(np.ceil((n1 - n0) / sp)) + 1))
        along_e = np.linspace(e0, e1, max(2, int(np.ceil((e1 - e0) / sp)) + 1))
        out += [(e0 - o, n) for n in along_n] + [(e1 + o, n) for n in along_n]
        out += [(e, n0 - o) for e in along_e] + [(e, n1 + o) for e in along_e]
    if not out:
        return np.zeros((0, 2))
    pts = np.array(out)
    return pts[~inside_boxes(pts, solid, margin_m=0.5 * o)]


def place_beacons(site_layout_only, rng: np.random.Generator, height_m: tuple[float, float],
                  cfg: CoverageConfig = CoverageConfig()) -> np.ndarray:
    """Pole and wall-mount positions (n, 3) ENU m chosen by greedy set cover (module docstring).

    ``site_layout_only`` needs ``grid`` and ``layout``; ``rng`` jitters the
    candidate grid and draws pole heights from ``height_m``. Candidates are poles
    on a grid of free ground and mounts on fire walls and buildings
    (:func:`_mount_points`); poles keep ``min_beacon_separation_m`` from any chosen beacon, wall
    mounts the smaller ``mount_separation_m`` (the next bay's wall is 10–12 m away).
    """
    g = site_layout_only.grid
    solid = boxes_array([b for b in site_layout_only.layout if not b.porous])
    s = cfg.candidate_spacing_m
    e = np.arange(g.east_min_m + 2.0, g.east_max_m - 1.0, s)
    n = np.arange(g.north_min_m + 2.0, g.north_max_m - 1.0, s)
    ee, nn = np.meshgrid(e, n)
    cand = np.column_stack([ee.ravel(), nn.ravel()]) + rng.uniform(-0.3 * s, 0.3 * s, (ee.size, 2))
    cand[:, 0] = np.clip(cand[:, 0], g.east_min_m + 1.0, g.east_max_m - 1.0)
    cand[:, 1] = np.clip(cand[:, 1], g.north_min_m + 1.0, g.north_max_m - 1.0)
    cand = cand[~inside_boxes(cand, solid, margin_m=cfg.pole_clearance_m)]
    mounts = _mount_points(site_layout_only.layout, cfg, solid)
    mounts = mounts[(mounts[:, 0] > g.east_min_m) & (mounts[:, 0] < g.east_max_m)
                    & (mounts[:, 1] > g.north_min_m) & (mounts[:, 1] < g.north_max_m)]
    is_mount = np.r_[np.zeros(len(cand), bool), np.ones(len(mounts), bool)]
    cand = np.vstack([cand, mounts])
    heights = rng.uniform(height_m[0], height_m[1], len(cand))
    cand_xyz = np.column_stack([cand, heights])
    pts = walkable_points(site_layout_only, cfg.demand_spacing_m)
    heard = _heard(cand_xyz, pts, solid, cfg)                  # (n_points, n_candidates)
    need = np.full(len(pts), cfg.k_required)
    chosen: list[int] = []
    available = np.ones(len(cand), bool)
    while len(chosen) < cfg.max_beacons and need.max() > 0:
        # weigh by how badly each point is served, so the worst spots (heavy zones) are filled first
        gain = (heard * need[:, None]).sum(axis=0) * available
        j = int(np.argmax(gain))
        if gain[j] <= 0:
            break
        chosen.append(j)
        need = np.maximum(need - heard[:, j], 0)
        d = np.hypot(cand[:, 0] - cand[j, 0], cand[:, 1] - cand[j, 1])
        available &= d >= np.where(is_mount & is_mount[j], cfg.mount_separation_m, cfg.min_beacon_separation_m)
    return cand_xyz[chosen]


def heard_by_channel(site, points_en: np.ndarray, noise_db_spl: float | None = None,
                     snr_db: float = 12.0) -> np.ndarray:
    """Whether each beacon is heard at each point by the simulated channel, bool (n_points, n_beacons).

    The issue's criterion, not the planning rule: the first geometric path
    (:func:`simulation.acoustic.channel.channel_paths`: direct, or round/over an edge) reaches the
    device at a matched-filter SNR of at least ``snr_db`` — source level, 1/r spreading, ISO 9613-1
    absorption at the band centre and, for a diffracted path, Maekawa's 10·log10(3 + 20N), against
    the default in-band noise (:class:`simulation.acoustic.synthesis.AudioConfig`, scaled to the
    beacon's band) with the pulse-compression gain 10·log10(T·B) (the link budget of
    :func:`simulation.acoustic.synthesis.detection_range_m`). Reflections do not count: they give a
    range, but not the beacon's.
    """
    import math

    from simulation.acoustic.atmosphere import absorption_db_per_m, fresnel_number, maekawa_loss_db, speed_of_sound_m_s
    from simulation.acoustic.channel import build_scene, channel_paths
    from simulation.acoustic.synthesis import AudioConfig

    scene = build_scene(site)
    noise = AudioConfig().inband_noise_db_spl if noise_db_spl is None else noise_db_spl
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    a = site.acoustic
    out = np.zeros((len(points_en), len(site.beacons)), bool)
    for j, b in enumerate(site.beacons):
        f0 = b.f0_hz if b.f0_hz is not None else a.f0_hz
        f1 = b.f1_hz if b.f1_hz is not None else a.f1_hz
        fc, t_s = 0.5 * (f0 + f1), b.chirp_duration_s or a.chirp_duration_s
        margin = 10.0 * math.log10(t_s * (f1 - f0)) - (noise + 10.0 * math.log10((f1 - f0) / 6000.0)) - snr_db
        alpha = float(absorption_db_per_m(fc, site.atmosphere))
        for i, p in enumerate(points_en):
            paths = channel_paths(scene, (b.east_m, b.north_m, b.up_m), (p[0], p[1], site.device_height_m))
            if len(paths) == 0 or int(paths.kind[0]) not in (0, 3):
                continue
            level = a.source_level_db + 20.0 * math.log10(max(float(paths.gain[0]), 1e-12)) \
                - alpha * float(paths.length_m[0])
            if paths.kind[0] == 3:
                level -= float(maekawa_loss_db(fresnel_number(paths.detour_m[0], fc, c)))
            out[i, j] = level + margin >= 0.0
    return out
