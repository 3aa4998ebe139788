"""Geometric acoustic channel from a beacon to a receiver among the yard's boxes.

For one source (beacon) and one receiver position the channel is a small set
of discrete paths plus a diffuse tail:

* **direct** path, spherical spreading 1/d, when the segment clears every solid
  box; porous boxes (lattice gantries) crossed cost ``porous_loss_db`` each;
* **diffraction** instead of a blocked direct path: the shortest path round the
  obstruction, either over the tops in the vertical plane through source and
  receiver (taut string = upper convex hull of the box-top edges) or round the
  vertical edges in plan (shortest path in the visibility graph of the box
  corners, lengthened for the height change), whichever is shorter. Its
  frequency-dependent loss re. free field at the direct distance is Maekawa's
  ΔL(N), N = 2δ/λ, δ = path − direct (``simulation.acoustic.atmosphere``); for several
  edges the total detour is used (a single-screen approximation);
* **ground** reflection by the image source mirrored in z = 0, coefficient of
  the yard's crushed rock;
* first-order **specular reflections** off the vertical faces of solid boxes
  by image sources (Allen & Berkley 1979, JASA 65(4)), kept when the specular
  point lies on the face and both legs are unobstructed (visibility test with
  ``simulation.site.geometry.segment_hits_boxes``), coefficient of the box's
  material. Box tops are not used: beacons (2.5–3 m) and receivers (≈ 1 m)
  stand below every solid top, so no specular point can lie on one;
* a **diffuse tail** standing for scattering off fins, insulators, lattice and
  higher-order reflections, described by :class:`TailModel` from the local
  clutter (share of directions with a solid face within 15 m).

Air absorption (ISO 9613-1) and Maekawa's loss depend on frequency and are
applied when the channel is rendered (``simulation.acoustic.stream``); here every
path carries its length, a frequency-independent pressure gain re. 1 m and its
diffraction detour. The channel is static over one chirp (the receiver moves
≈ 1.5 cm in 10 ms).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from features.errors import ConfigError
from features.site import Site

from simulation.acoustic.atmosphere import GROUND_MATERIAL, reflection_coefficient, speed_of_sound_m_s
from simulation.acoustic.path_geometry import discrete_paths
from simulation.site.geometry import boxes_array, footprint_entry

__all__ = ["PATH_KINDS", "PathSet", "ChannelConfig", "Scene", "build_scene", "channel_paths", "clutter_index",
           "TailModel", "tail_model", "beacon_arrivals"]

PATH_KINDS = ("direct", "ground", "reflection", "diffraction")
"""Path kind names, indexed by :attr:`PathSet.kind`."""


@dataclass(frozen=True)
class ChannelConfig:
    """Parameters of the geometric channel.

    porous_loss_db : loss of a path crossing one porous (lattice) box, dB. Steel
        members shadow ≈ 15–30 % of a gantry's face; at λ ≈ 17 mm they act as
        geometric obstacles, so ≈ 1–2 dB is lost in transmission.
    max_excess_m : reflections longer than the direct distance by more than this
        are dropped (≥ 120 ms late, and 1/r weaker): they belong to the tail.
    clutter_radius_m : radius within which solid faces count as clutter.
    ground_material : key of ``simulation.acoustic.atmosphere.ABSORPTION_COEFFICIENTS``.
    tail_offset_db : added to the diffuse tail's level of :func:`tail_model`
        (0 = the model; −100 ≈ no tail, for tests of the discrete paths).
    ground_reflection, wall_reflections : keep the ground's image-source path and the first-order
        reflections off vertical faces (both on; off only to measure what multipath costs a receiver,
        ``bench/acoustic_error_causes.py``).
    """

    porous_loss_db: float = 1.5
    max_excess_m: float = 40.0
    clutter_radius_m: float = 15.0
    ground_material: str = GROUND_MATERIAL
    tail_offset_db: float = 0.0
    ground_reflection: bool = True
    wall_reflections: bool = True

    def __post_init__(self):
        if not 0.0 <= self.porous_loss_db < 40.0:
            raise ConfigError(f"porous_loss_db must lie in [0, 40), got {self.porous_loss_db}")
        if not self.max_excess_m > 0:
            raise ConfigError(f"max_excess_m must be positive, got {self.max_excess_m}")
        if not self.clutter_radius_m > 0:
            raise ConfigError(f"clutter_radius_m must be positive, got {self.clutter_radius_m}")
        if not -200.0 <= self.tail_offset_db <= 20.0:
            raise ConfigError(f"tail_offset_db must lie in [-200, 20], got {self.tail_offset_db}")


@dataclass(frozen=True)
class PathSet:
    """Discrete paths of one beacon→receiver channel, sorted by length (= delay).

    Attributes
    ----------
    kind : int ndarray (p,)        index into :data:`PATH_KINDS`
    length_m : ndarray (p,)        path length (delay = length / c)
    gain : ndarray (p,)            frequency-independent pressure gain re. 1 m from the source:
                                   spreading × reflection coefficient × porous losses
    detour_m : ndarray (p,)        diffraction detour δ (0 for undiffracted paths)
    box : int ndarray (p,)         reflecting / diffracting box (index into ``site.layout``), −1 if none
    direct_m : float               straight-line source–receiver distance
    los : bool                     the straight line clears every solid box
    """

    kind: np.ndarray
    length_m: np.ndarray
    gain: np.ndarray
    detour_m: np.ndarray
    box: np.ndarray
    direct_m: float
    los: bool

    def __len__(self) -> int:
        return len(self.length_m)

    def delays_s(self, speed_m_s: float) -> np.ndarray:
        """Propagation delays, s, shape (p,)."""
        return self.length_m / speed_m_s

    def kind_names(self) -> list[str]:
        return [PATH_KINDS[k] for k in self.kind]


@dataclass(frozen=True)
class Scene:
    """The site's boxes arranged for fast channel evaluation (built by :func:`build_scene`).

    solid : (m, 5) boxes (east_min, east_max, north_min, north_max, height); solid_index : (m,) their
    index in ``site.layout``; porous : (q, 5); faces : (4m, 7) vertical faces as
    (axis 0=east/1=north, plane coordinate, outward sign, lo, hi, height, |R|); face_box : (4m,)
    index into ``solid``; ground_r : |R| of the ground.
    """

    solid: np.ndarray
    solid_index: np.ndarray
    porous: np.ndarray
    faces: np.ndarray
    face_box: np.ndarray
    ground_r: float
    config: ChannelConfig


def build_scene(site: Site, config: ChannelConfig | None = None) -> Scene:
    """Arrange ``site.layout`` for :func:`channel_paths`."""
    config = config or ChannelConfig()
    solid_idx = [i for i, b in enumerate(site.layout) if not b.porous]
    solid = boxes_array([site.layout[i] for i in solid_idx])
    porous = boxes_array([b for b in site.layout if b.porous])
    faces, face_box = [], []
    for j, i in enumerate(solid_idx):
        e0, e1, n0, n1, h = solid[j]
        r = reflection_coefficient(site.layout[i].material)
        faces += [(0, e0, -1, n0, n1, h, r), (0, e1, 1, n0, n1, h, r),
                  (1, n0, -1, e0, e1, h, r), (1, n1, 1, e0, e1, h, r)]
        face_box += [j] * 4
    return Scene(solid=solid, solid_index=np.asarray(solid_idx, int), porous=porous,
                 faces=np.asarray(faces, float).reshape(-1, 7), face_box=np.asarray(face_box, int),
                 ground_r=reflection_coefficient(config.ground_material), config=config)


def channel_paths(scene: Scene, src_xyz, rx_xyz) -> PathSet:
    """Discrete paths from a source to a receiver (ENU metres, up = height above ground).

    Parameters
    ----------
    scene : from :func:`build_scene`
    src_xyz, rx_xyz : sequences of 3 floats (east, north, up)

    Returns
    -------
    PathSet sorted by length.
    """
    src = np.ascontiguousarray(src_xyz, dtype=float)
    rx = np.ascontiguousarray(rx_xyz, dtype=float)
    cfg = scene.config
    kind, length, gain, detour, box, d, los = discrete_paths(
        scene.solid, scene.solid_index, scene.porous, scene.faces, scene.face_box, cfg.porous_loss_db, scene.ground_r,
        cfg.ground_reflection, cfg.wall_reflections, cfg.max_excess_m, src, rx)
    order = np.argsort(length, kind="stable")
    return PathSet(kind=kind[order], length_m=length[order], gain=gain[order], detour_m=detour[order], box=box[order],
                   direct_m=float(d), los=bool(los))


def clutter_index(scene: Scene, rx_en, n_azimuths: int = 72) -> float:
    """Share of horizontal directions in which a solid face lies within ``clutter_radius_m``, in [0, 1].

    An enclosure measure: 0 in the open, ≈ 0.5 in an aisle between two rows of
    equipment, → 1 in a court closed on all sides.
    """
    p = np.asarray(rx_en, float)[:2]
    bx = scene.solid
    if bx.shape[0] == 0:
        return 0.0
    gap_e = np.maximum(np.maximum(bx[:, 0] - p[0], p[0] - bx[:, 1]), 0.0)
    gap_n = np.maximum(np.maximum(bx[:, 2] - p[1], p[1] - bx[:, 3]), 0.0)
    near = bx[np.hypot(gap_e, gap_n) <= scene.config.clutter_radius_m]
    if near.shape[0] == 0:
        return 0.0
    az = (np.arange(n_azimuths) + 0.5) * (2.0 * np.pi / n_azimuths)
    t_in, _ = footprint_entry(p[None], az, near)
    return float((t_in[0].min(axis=1) <= scene.config.clutter_radius_m).mean())


@dataclass(frozen=True)
class TailModel:
    """Diffuse tail of one channel (an assumed model; docs/beacon_protocol.md §Channel).

    Poisson arrivals at ``density_per_ms`` with zero-mean Gaussian pressure
    amplitudes under an exponential envelope exp(−t/``decay_ms``) starting
    ``onset_ms`` after the geometric direct delay; total energy
    ``level_db`` re. the free-field direct energy at the source–receiver distance.
    """

    onset_ms: float
    decay_ms: float
    density_per_ms: float
    level_db: float


@functools.lru_cache(maxsize=4096)
def tail_model(clutter: float) -> TailModel:
    """Tail parameters from the clutter index c ∈ [0, 1] (linear in c).

    decay 3 → 23 ms, density 0.5 → 10 arrivals/ms and level −20 → −6 dB as c
    goes 0 → 1: an open area keeps a faint, short, sparse tail (ground
    roughness, distant structures), a court of steel tanks and walls a dense,
    long, strong one, which lowers the Rician K and raises τ_rms there. Cached
    (a walk meets a few hundred clutter values, one per metre cell).

    >>> tail_model(0.0)
    TailModel(onset_ms=0.5, decay_ms=3.0, density_per_ms=0.5, level_db=-20.0)
    """
    c = min(max(float(clutter), 0.0), 1.0)
    return TailModel(onset_ms=0.5, decay_ms=3.0 + 20.0 * c, density_per_ms=0.5 + 9.5 * c, level_db=-20.0 + 14.0 * c)


def beacon_arrivals(site: Site, rx_xyz, scene: Scene | None = None) -> dict[int, tuple[float, str, PathSet]]:
    """True first arrival of every beacon at a receiver position: {beacon id: (delay_s, kind, paths)}.

    ``delay_s`` is the first discrete path's propagation delay at the site's
    air temperature (``inf`` and kind ``"none"`` when no path exists).

    >>> from features.site import Site, Origin, Beacon
    >>> site = Site(name="t", origin=Origin(31.0, 118.0), beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),))
    >>> delay, kind, paths = beacon_arrivals(site, (20.0, 0.0, 1.0))[1]
    >>> round(delay * 1e3, 3), kind, paths.kind_names()
    (58.563, 'direct', ['direct', 'ground'])
    """
    scene = scene or build_scene(site)
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    out = {}
    for b in site.beacons:
        paths = channel_paths(scene, (b.east_m, b.north_m, b.up_m), rx_xyz)
        if len(paths) == 0:
            out[b.id] = (math.inf, "none", paths)
        else:
            out[b.id] = (float(paths.length_m[0] / c), PATH_KINDS[int(paths.kind[0])], paths)
    return out
