"""The UWB channel from an anchor to the tag among the yard's structures: discrete paths with their power.

Geometry is the acoustic channel's (:func:`simulation.acoustic.channel.channel_paths`: the direct segment,
the shortest path over or round the obstruction when it is blocked, the ground bounce, first-order
reflections off the vertical faces of solid boxes); the radio is this package's
(:mod:`simulation.uwb.radio`). Per path, received power (dBm)::

    direct, clear      P = P_tx + G_a − FSPL(d) − n_lattice·L_lattice
    direct, through    P = P_tx + G_a − FSPL(d) − Σ slab loss          (every crossed box penetrable)
                       length d + Σ t·(√ε' − 1)                         (the wave is slower in the wall)
    over / round       P = P_tx + G_a − FSPL(L) − J(ν(δ))              (ITU-R P.526 knife edge)
    ground bounce      P = P_tx + G_a − FSPL(L) − L_ground
    wall reflection    P = P_tx + G_a − FSPL(L) − 20·log10(1/|Γ|)      (Fresnel, the wall's material)

with ``G_a`` the anchor's gain towards the tag (front or back lobe). A fire wall (0.4 m of concrete,
≈ 60 dB) and steel (no transmission) are not crossed: the first path is then the diffracted or reflected
one, metres longer — the NLOS bias of ranging. A building is hollow: its two walls of
:data:`~simulation.uwb.radio.BUILDING_WALL_M` are crossed. Every path arrives as a cluster: its ray and a
dense tail of :data:`CLUSTER_TAIL_DB` re. the ray (Saleh & Valenzuela, IEEE JSAC 5(2), 1987; the
clusters of the IEEE 802.15.4a model, Molisch et al., IEEE Trans. Antennas Propag. 54(11), 2006), which
counts in the received total but not in the first path.

The arrival direction at the anchor of a bent path (over/round an edge, off a wall) is off the tag's
bearing by ≈ atan(√(2δ/d)) (the edge half-way, δ ≈ 2h²/d): a reflection from the reflecting box's side of
the straight line, a path round an obstruction from the other side (it passes the nearer edge).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from features.site import Site

from simulation.acoustic.channel import ChannelConfig, Scene, build_scene, channel_paths
from simulation.site.geometry import boxes_array
from simulation.uwb.radio import (ANCHOR_GAIN_DBI, BACK_LOBE_LOSS_DB, BUILDING_WALL_M, GROUND_REFLECTION_LOSS_DB,
                                  LATTICE_LOSS_DB, TX_POWER_DBM, free_space_loss_db, knife_edge_loss_db, material,
                                  reflection_loss_db, slab_excess_path_m, slab_loss_db)

__all__ = ["UwbScene", "build_uwb_scene", "UwbPaths", "uwb_paths", "segment_chords_m", "CLUSTER_TAIL_DB",
           "PATH_DIRECT", "PATH_THROUGH", "PATH_BENT"]

CLUSTER_TAIL_DB = -3.0
"""Energy of a cluster's dense tail re. its first ray, dB. Set so that a lone line-of-sight cluster gives the
first-path/received ratio the DW1000 reports in line of sight in ../shared/data/cir_uwb (LOS logs: median
FSL − RSL −2.9 to −4.1 dB, −3.0 over the six; one cluster alone: −10·log10(1 + 10^(−0.3)) = −1.8 dB, the ground bounce and
reflections lower it further). ``bench/bench_uwb.py`` prints both."""

PATH_DIRECT, PATH_THROUGH, PATH_BENT = 0, 1, 2
"""Kinds of :class:`UwbPaths`: clear direct path, direct path through walls, any bent path (edge, wall, ground)."""


@dataclass(frozen=True)
class UwbScene:
    """The site arranged for radio paths: the acoustic :class:`~simulation.acoustic.channel.Scene` (geometry)
    plus every layout box's array, material and kind."""

    geometry: Scene
    boxes: np.ndarray
    kinds: tuple[str, ...]
    materials: tuple
    porous: np.ndarray


def build_uwb_scene(site: Site) -> UwbScene:
    """Arrange ``site.layout`` for :func:`uwb_paths` (reflections up to 40 m longer than the direct path)."""
    geometry = build_scene(site, ChannelConfig(max_excess_m=40.0))
    return UwbScene(geometry=geometry, boxes=boxes_array(site.layout), kinds=tuple(b.kind for b in site.layout),
                    materials=tuple(material(b.material) for b in site.layout),
                    porous=np.array([b.porous for b in site.layout], bool))


@dataclass(frozen=True)
class UwbPaths:
    """One anchor→tag channel: arrays of shape (p,), sorted by length.

    ``excess_m``: path length minus the straight-line distance; ``power_dbm``: received power without
    fading; ``kind``: :data:`PATH_DIRECT` / :data:`PATH_THROUGH` / :data:`PATH_BENT`; ``angle_off_rad``:
    arrival direction at the anchor minus the tag's bearing.
    """

    excess_m: np.ndarray
    power_dbm: np.ndarray
    kind: np.ndarray
    angle_off_rad: np.ndarray
    direct_m: float


def segment_chords_m(a_xyz, b_xyz, boxes: np.ndarray) -> np.ndarray:
    """Length of the segment a→b inside each box (ground to top), m, shape (m,) (3-D slab method, Kay & Kajiya
    1986: the parameter interval shared by the three slabs, times the segment's length).

    >>> box = np.array([[4.0, 6.0, -1.0, 1.0, 5.0]])
    >>> segment_chords_m([0.0, 0.0, 1.0], [10.0, 0.0, 1.0], box).round(6).tolist()
    [2.0]
    """
    a = np.asarray(a_xyz, float)
    d = np.asarray(b_xyz, float) - a
    if len(boxes) == 0:
        return np.zeros(0)
    return _slab_chords(a, d, np.asarray(boxes, float), float(np.linalg.norm(d)))


@njit(cache=True)
def _slab_chords(a: np.ndarray, d: np.ndarray, boxes: np.ndarray, length: float) -> np.ndarray:
    """:func:`segment_chords_m` per box: along each axis the parameters t of the slab's two faces on a + t·d
    (a segment parallel to an axis: all or nothing, by whether a lies strictly between the faces), the interval
    shared by the three slabs, clipped to the segment [0, 1], times ``length`` = |d|."""
    out = np.empty(len(boxes))
    for b in range(len(boxes)):
        tmin, tmax = -np.inf, np.inf
        for ax in range(3):
            lo = boxes[b, 2 * ax] if ax < 2 else 0.0
            hi = boxes[b, 2 * ax + 1] if ax < 2 else boxes[b, 4]
            if abs(d[ax]) < 1e-12:
                inside = lo < a[ax] < hi
                t_in, t_out = (-np.inf, np.inf) if inside else (np.inf, -np.inf)
            else:
                t1, t2 = (lo - a[ax]) / d[ax], (hi - a[ax]) / d[ax]
                t_in, t_out = min(t1, t2), max(t1, t2)
            tmin, tmax = max(tmin, t_in), min(tmax, t_out)
        out[b] = max(min(tmax, 1.0) - max(tmin, 0.0), 0.0) * length
    return out


def _through(scene: UwbScene, chords: np.ndarray) -> tuple[float, float]:
    """Penetration loss (dB) and excess length (m) of the direct path through the solid boxes it crosses."""
    loss, excess = 0.0, 0.0
    for j in np.flatnonzero((chords > 1e-6) & ~scene.porous):
        mat = scene.materials[j]
        t = 2.0 * BUILDING_WALL_M if scene.kinds[j] == "building" else float(chords[j])
        loss += float(slab_loss_db(mat, t))
        excess += float(slab_excess_path_m(mat, t))
        if not math.isfinite(loss):
            return math.inf, math.inf
    return loss, excess


_reflection_loss_db = functools.lru_cache(maxsize=None)(reflection_loss_db)
"""reflection_loss_db per material, computed once (a site has a handful of materials)."""


def _bend_sign(scene: UwbScene, anchor: np.ndarray, tag: np.ndarray, box: int) -> float:
    """Side (±1, clockwise positive) of the box's centre from the straight line anchor→tag."""
    if box < 0:
        return 1.0
    c = 0.5 * (scene.boxes[box, 0] + scene.boxes[box, 1]), 0.5 * (scene.boxes[box, 2] + scene.boxes[box, 3])
    cross = (tag[0] - anchor[0]) * (c[1] - anchor[1]) - (tag[1] - anchor[1]) * (c[0] - anchor[0])
    return -1.0 if cross > 0 else 1.0   # box to the left of anchor→tag (counter-clockwise): arrives anticlockwise


def uwb_paths(scene: UwbScene, anchor_xyz, boresight_rad: float, tag_xyz) -> UwbPaths:
    """The anchor→tag channel (module docstring)."""
    anchor = np.asarray(anchor_xyz, float)
    tag = np.asarray(tag_xyz, float)
    geo = channel_paths(scene.geometry, anchor, tag)
    d = geo.direct_m
    bearing = math.atan2(tag[0] - anchor[0], tag[1] - anchor[1])
    rel = (bearing - boresight_rad + math.pi) % (2 * math.pi) - math.pi
    gain = ANCHOR_GAIN_DBI - (BACK_LOBE_LOSS_DB if abs(rel) > math.pi / 2 else 0.0)
    p0 = TX_POWER_DBM + gain
    chords = segment_chords_m(anchor, tag, scene.boxes)
    n_lattice = int(np.count_nonzero((chords > 1e-6) & scene.porous))
    fspl_d = float(free_space_loss_db(d))
    fspl = free_space_loss_db(geo.length_m).tolist()        # each path's, one call (the same values one by one)
    edge = geo.kind == 3
    knife = dict(zip(np.flatnonzero(edge).tolist(), knife_edge_loss_db(geo.detour_m[edge]).tolist()))
    excess, power, kind, off = [], [], [], []
    if geo.los:
        excess.append(0.0), power.append(p0 - fspl_d - n_lattice * LATTICE_LOSS_DB)
        kind.append(PATH_DIRECT), off.append(0.0)
    else:
        loss, extra = _through(scene, chords)
        if math.isfinite(loss):
            excess.append(extra), power.append(p0 - fspl_d - loss - n_lattice * LATTICE_LOSS_DB)
            kind.append(PATH_THROUGH), off.append(0.0)
    for i, (k, length, box) in enumerate(zip(geo.kind.tolist(), geo.length_m.tolist(), geo.box.tolist())):
        if k == 0:
            continue
        if k == 3:
            loss = knife[i]
        elif k == 1:
            loss = GROUND_REFLECTION_LOSS_DB
        else:
            loss = _reflection_loss_db(scene.materials[int(box)])
        ex = max(length - d, 0.0)
        excess.append(ex), power.append(p0 - fspl[i] - loss), kind.append(PATH_BENT)
        side = 0.0 if k == 1 else _bend_sign(scene, anchor, tag, int(box)) * (1.0 if k == 2 else -1.0)
        off.append(side * math.atan(math.sqrt(2.0 * ex / max(d, 0.1))))
    order = np.argsort(np.asarray(excess, float), kind="stable")
    return UwbPaths(excess_m=np.asarray(excess, float)[order], power_dbm=np.asarray(power, float)[order],
                    kind=np.asarray(kind, int)[order], angle_off_rad=np.asarray(off, float)[order], direct_m=d)
