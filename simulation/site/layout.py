"""Synthetic 220 kV-class substation layouts (docs/design.md §6).

A yard of about 120 × 80 m with, from one long side to the other:

* a row of 2–4 main transformers (≈ 8 × 5 m, 5–6 m tall, steel) separated by
  concrete fire walls (0.4 m thick, 10 m long, 8–10 m tall) 1.2–2 m from the
  tanks — IEEE Std 979 / IEC 61936-1 §8.7 call for walls between oil-filled
  transformers closer than the required separation;
* switchyard bays (≈ 13–15 m wide) with lattice gantries 12–15 m tall
  (porous) and rows of steel apparatus supports (breakers, disconnectors, CTs);
* a relay/control building (6–10 m tall) and often a switch building, with a
  narrow passage between them; small relay kiosks;
* aisles (roads) between bays and round the yard.

Beacons stand on 2.5–3 m poles or are screwed to fire walls and building faces,
placed as an installer would (:mod:`simulation.site.coverage`: greedy set cover
until every walkable point, heavy zones included, hears four; at most 24 — the
default since issue 10 item 7), alternating between two 2.9 kHz sub-bands
(frequency division), with 80 ms TDMA slots assigned greedily per band so that
slot-mates are at least ``reuse_distance_m`` apart: a frame of ≤ 12 slots,
≤ 0.96 s (docs/beacon_protocol.md). ``beacon_placement="grid"`` keeps the
earlier 25–35 m grid with one full-band slot each. A layout is redrawn (deterministically) until each
environment class covers at least ``min_class_share`` of the walkable area, so
every site has a real share of all three.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from features.site import AcousticConfig, Atmosphere, Beacon, Box, EmiZone, Grid, Origin, Site

from simulation.site.coverage import CoverageConfig, place_beacons
from simulation.site.environment import class_map, classify_share
from simulation.site.geometry import boxes_array, inside_boxes
from simulation.rng import stream_rng
from simulation.uwb.placement import place_uwb_anchors

__all__ = ["LayoutConfig", "generate_site", "assign_slots"]


@dataclass(frozen=True)
class LayoutConfig:
    """Parameters of the site generator (defaults: docs/design.md §6)."""

    lat_deg: float = 31.2
    lon_deg: float = 118.8
    alt_m: float = 20.0
    width_m: tuple[float, float] = (110.0, 130.0)
    depth_m: tuple[float, float] = (72.0, 88.0)
    n_transformers: tuple[int, int] = (2, 4)
    beacon_spacing_m: tuple[float, float] = (25.0, 35.0)
    beacon_height_m: tuple[float, float] = (2.5, 3.0)
    reuse_distance_m: float = 145.0  # ≥ 2 × the ≈ 70 m free-field detection range (tests/test_acoustic_sim.py)
    beacon_placement: str = "coverage"  # the installer's rule (simulation.site.coverage), or "grid"
    bands_hz: tuple[tuple[float, float], ...] = ((17_000.0, 19_900.0), (20_100.0, 23_000.0))
    slot_s: float = 0.08
    coverage: CoverageConfig = CoverageConfig()
    emi_zones: bool = True
    min_class_share: float = 0.04
    max_attempts: int = 20
    cell_size_m: float = 5.0
    device_height_m: float = 1.0
    uwb_anchors: bool = True  # a UWB anchor on every beacon pole / mount (simulation.uwb.placement)

    def __post_init__(self):
        if self.width_m[0] < 60 or self.depth_m[0] < 45:
            raise ValueError(f"site extent too small for a 220 kV yard: width_m={self.width_m}, depth_m={self.depth_m}")
        if self.beacon_placement not in ("coverage", "grid"):
            raise ValueError(f"beacon_placement must be 'coverage' or 'grid', got {self.beacon_placement!r}")
        if not self.bands_hz or any(not 0 < lo < hi <= 24_000.0 for lo, hi in self.bands_hz):
            raise ValueError(f"bands_hz must be non-empty (f0, f1) pairs in (0, 24000], got {self.bands_hz}")
        if not 0.02 < self.slot_s <= 1.0:
            raise ValueError(f"slot_s must lie in (0.02, 1], got {self.slot_s}")
        if not 0 <= self.min_class_share < 0.33:
            raise ValueError(f"min_class_share must lie in [0, 0.33), got {self.min_class_share}")


def _box(kind, material, porous, e0, e1, n0, n1, h):
    return Box(kind=kind, material=material, porous=porous, east_min_m=round(float(e0), 3),
               east_max_m=round(float(e1), 3), north_min_m=round(float(n0), 3), north_max_m=round(float(n1), 3),
               height_m=round(float(h), 3))


def _transformer_row(rng, width, depth, south: bool):
    """Transformers with fire walls between (and usually at the ends of) the row."""
    n_tr = int(rng.integers(2, 5))
    tr_e = rng.uniform(7.5, 9.0)
    tr_n = rng.uniform(4.5, 5.5)
    gap = rng.uniform(1.2, 2.0)
    wall_t = 0.4
    wall_len = rng.uniform(9.5, 11.0)
    pitch = tr_e + 2 * gap + wall_t
    row_len = n_tr * pitch + wall_t
    e0 = rng.uniform(8.0, max(8.5, width - row_len - 8.0))
    n_c = rng.uniform(10.0, 13.0) if south else depth - rng.uniform(10.0, 13.0)
    boxes, emi = [], []
    for i in range(n_tr + 1):
        we = e0 + i * pitch
        end_wall = i in (0, n_tr)
        if end_wall and rng.random() < 0.35:
            continue  # not every row closes its ends
        boxes.append(_box("firewall", "concrete", False, we, we + wall_t, n_c - wall_len / 2, n_c + wall_len / 2,
                          rng.uniform(8.0, 10.0)))
    for i in range(n_tr):
        te = e0 + wall_t + gap + i * pitch
        boxes.append(_box("transformer", "steel", False, te, te + tr_e, n_c - tr_n / 2, n_c + tr_n / 2,
                          rng.uniform(5.0, 6.0)))
        emi.append(EmiZone(east_m=round(te + tr_e / 2, 2), north_m=round(n_c, 2), radius_m=round(rng.uniform(10, 15), 2),
                           loss_db=round(rng.uniform(2.0, 5.0), 2)))
    return boxes, emi, (e0, e0 + row_len, n_c - wall_len / 2, n_c + wall_len / 2)


def _buildings(rng, width, depth, south_row: bool):
    """Relay/control building at a corner opposite the transformers, often a switch building beside it."""
    boxes = []
    bw, bd = rng.uniform(18.0, 26.0), rng.uniform(10.0, 14.0)
    left = rng.random() < 0.5
    e0 = rng.uniform(4.0, 8.0) if left else width - rng.uniform(4.0, 8.0) - bw
    n0 = depth - rng.uniform(4.0, 7.0) - bd if south_row else rng.uniform(4.0, 7.0)
    boxes.append(_box("building", "concrete", False, e0, e0 + bw, n0, n0 + bd, rng.uniform(6.0, 10.0)))
    if rng.random() < 0.75:
        sw, sd = rng.uniform(12.0, 20.0), rng.uniform(8.0, 12.0)
        passage = rng.uniform(2.0, 3.5)
        se0 = e0 + bw + passage if left else e0 - passage - sw
        sn0 = n0 + (bd - sd) * rng.uniform(0.0, 1.0)
        boxes.append(_box("building", "concrete", False, se0, se0 + sw, sn0, sn0 + sd, rng.uniform(6.0, 9.0)))
    return boxes


def _switchyard(rng, width, depth, keep_out):
    """Gantries (porous lattice) across the yard and rows of steel apparatus in the bays."""
    boxes = []
    bay_w = rng.uniform(13.0, 15.0)
    n_bays = int((width - 16.0) // bay_w)
    e_start = (width - n_bays * bay_w) / 2
    free_n = [n for n in np.arange(depth * 0.3, depth * 0.72, 1.0)]
    gantry_rows = sorted(rng.choice(free_n, size=2, replace=False)) if len(free_n) >= 2 else []
    for gn in gantry_rows:
        if gantry_rows and abs(gn - gantry_rows[0]) < 12 and gn != gantry_rows[0]:
            gn = gantry_rows[0] + 14.0
        boxes.append(_box("gantry", "steel lattice", True, e_start, e_start + n_bays * bay_w, gn - 0.5, gn + 0.5,
                          rng.uniform(12.0, 15.0)))
    # apparatus rows: breakers / disconnectors / CTs on steel supports, 1.2-2 m square, 3.5-5 m tall
    n_rows = int(rng.integers(2, 4))
    row_ns = np.linspace(depth * 0.32, depth * 0.68, n_rows)
    for b in range(n_bays):
        for rn in row_ns:
            if rng.random() < 0.2:
                continue  # an empty bay position (spare bay)
            for k in range(int(rng.integers(1, 3))):
                ce = e_start + (b + 0.5) * bay_w + rng.uniform(-3.0, 3.0) + (k - 0.5) * 4.0 * (k > 0)
                cn = rn + rng.uniform(-1.5, 1.5)
                s = rng.uniform(1.2, 2.0)
                box = _box("equipment", "steel", False, ce - s / 2, ce + s / 2, cn - s / 2, cn + s / 2,
                           rng.uniform(3.5, 5.0))
                if not (_overlaps(box, keep_out, margin=2.0)
                        or _overlaps(box, [o for o in boxes if not o.porous], margin=0.5)):
                    boxes.append(box)  # clear of the other apparatus too (two supports never share ground)
    return boxes


def _overlaps(box: Box, others, margin: float) -> bool:
    for o in others:
        if (box.east_min_m < o.east_max_m + margin and box.east_max_m > o.east_min_m - margin
                and box.north_min_m < o.north_max_m + margin and box.north_max_m > o.north_min_m - margin):
            return True
    return False


def _kiosks(rng, width, depth, existing):
    boxes = []
    for _ in range(int(rng.integers(2, 5))):
        for _try in range(30):
            w, d = rng.uniform(2.5, 4.0), rng.uniform(2.0, 3.0)
            e0, n0 = rng.uniform(3.0, width - 3.0 - w), rng.uniform(3.0, depth - 3.0 - d)
            box = _box("building", "steel", False, e0, e0 + w, n0, n0 + d, rng.uniform(2.6, 3.2))
            if not _overlaps(box, existing + boxes, margin=3.0):
                boxes.append(box)
                break
    return boxes


def assign_slots(east_m: np.ndarray, north_m: np.ndarray, reuse_distance_m: float) -> np.ndarray:
    """Greedy TDMA slot colouring: a beacon takes the lowest slot none of whose holders is nearer than the reuse distance.

    >>> assign_slots(np.array([0., 30., 200.]), np.array([0., 0., 0.]), 100.0).tolist()
    [0, 1, 0]
    """
    slots = np.full(len(east_m), -1, int)
    for i in range(len(east_m)):
        s = 0
        while True:
            holders = np.flatnonzero(slots == s)
            d = np.hypot(east_m[holders] - east_m[i], north_m[holders] - north_m[i])
            if np.all(d >= reuse_distance_m):
                break
            s += 1
        slots[i] = s
    return slots


def _grid_beacons(rng, width, depth, boxes, cfg: LayoutConfig, z0: float):
    spacing = rng.uniform(*cfg.beacon_spacing_m)
    n_e = max(2, int(round((width - 10.0) / spacing)) + 1)
    n_n = max(2, int(round((depth - 10.0) / spacing)) + 1)
    es = np.linspace(5.0, width - 5.0, n_e)
    ns = np.linspace(5.0, depth - 5.0, n_n)
    arr = boxes_array(boxes)
    pts = []
    for n in ns:
        for e in es:
            p = np.array([e, n]) + rng.uniform(-3.0, 3.0, 2)
            for radius in np.arange(0.0, 12.0, 0.5):  # nearest free spot, 1.2 m from any structure
                ang = rng.uniform(0, 2 * np.pi, 16)
                cand = p + radius * np.column_stack([np.cos(ang), np.sin(ang)])
                ok = ~inside_boxes(cand, arr, margin_m=1.2)
                ok &= (cand[:, 0] > 1) & (cand[:, 0] < width - 1) & (cand[:, 1] > 1) & (cand[:, 1] < depth - 1)
                if ok.any():
                    pts.append(cand[np.flatnonzero(ok)[0]])
                    break
    pts = np.array(pts)
    slots = assign_slots(pts[:, 0], pts[:, 1], cfg.reuse_distance_m)
    beacons = tuple(Beacon(id=i + 1, east_m=round(float(p[0]), 2), north_m=round(float(p[1]), 2),
                           up_m=round(float(rng.uniform(*cfg.beacon_height_m)), 2), slot=int(s))
                    for i, (p, s) in enumerate(zip(pts, slots)))
    return beacons, int(slots.max()) + 1


def _coverage_beacons(rng, width, depth, boxes, cfg: LayoutConfig):
    """Beacons placed by the installer's rule (:mod:`simulation.site.coverage`), bands alternating, slots per band.

    Returns (beacons, n_slots): frequency division lets one slot hold one beacon per band, so a frame
    lasts ⌈n / n_bands⌉ slots (docs/beacon_protocol.md §2).
    """
    probe = Site(name="probe", origin=Origin(0.0, 0.0), grid=Grid(cell_size_m=cfg.cell_size_m, east_min_m=0.0,
                 east_max_m=round(width, 2), north_min_m=0.0, north_max_m=round(depth, 2)), layout=tuple(boxes))
    xyz = place_beacons(probe, rng, cfg.beacon_height_m, cfg.coverage)
    # Bands alternate along a sweep of the yard, so neighbours differ in band.
    order = np.lexsort((xyz[:, 0], np.round(xyz[:, 1] / 10.0)))
    xyz = xyz[order]
    band = np.arange(len(xyz)) % len(cfg.bands_hz)
    slots = np.zeros(len(xyz), int)
    for k in range(len(cfg.bands_hz)):
        sel = np.flatnonzero(band == k)
        if sel.size:
            slots[sel] = assign_slots(xyz[sel, 0], xyz[sel, 1], cfg.reuse_distance_m)
    beacons = tuple(Beacon(id=i + 1, east_m=round(float(p[0]), 2), north_m=round(float(p[1]), 2),
                           up_m=round(float(p[2]), 2), slot=int(s),
                           f0_hz=float(cfg.bands_hz[b][0]), f1_hz=float(cfg.bands_hz[b][1]))
                    for i, (p, s, b) in enumerate(zip(xyz, slots, band)))
    return beacons, int(slots.max()) + 1


def _draw(seed: int, attempt: int, cfg: LayoutConfig) -> Site:
    rng = stream_rng(seed, "layout", attempt)
    width = float(rng.uniform(*cfg.width_m))
    depth = float(rng.uniform(*cfg.depth_m))
    south = bool(rng.random() < 0.5)
    tr_boxes, emi, _row = _transformer_row(rng, width, depth, south)
    bld = _buildings(rng, width, depth, south)
    yard = _switchyard(rng, width, depth, tr_boxes + bld)
    kiosks = _kiosks(rng, width, depth, tr_boxes + bld + yard)
    boxes = tuple(tr_boxes + bld + yard + kiosks)
    # The grid beacons are drawn in every case (the layout's later draws follow them); the coverage
    # placement replaces them in generate_site once the layout is accepted.
    beacons, n_slots = _grid_beacons(rng, width, depth, boxes, cfg, cfg.device_height_m)
    acoustic = AcousticConfig(n_slots=n_slots)
    atmo = Atmosphere(temperature_c=round(float(rng.uniform(5.0, 30.0)), 1),
                      relative_humidity_pct=round(float(rng.uniform(40.0, 85.0)), 1))
    return Site(
        name=f"sim-{seed:04d}",
        origin=Origin(lat_deg=cfg.lat_deg, lon_deg=cfg.lon_deg, alt_m=cfg.alt_m),
        device_height_m=cfg.device_height_m,
        atmosphere=atmo,
        grid=Grid(cell_size_m=cfg.cell_size_m, east_min_m=0.0, east_max_m=round(width, 2), north_min_m=0.0,
                  north_max_m=round(depth, 2)),
        acoustic=acoustic,
        beacons=beacons,
        layout=boxes,
        emi_zones=tuple(emi) if cfg.emi_zones else (),
        seed=seed,
    )


def class_shares(site: Site, resolution_m: float = 1.0) -> np.ndarray:
    """Share of the walkable area (outside solid structures) in each class, shape (3,)."""
    _, _, share = class_map(site, resolution_m=resolution_m, n_az=120)
    cls = classify_share(share[np.isfinite(share)])
    return np.bincount(cls, minlength=3) / max(cls.size, 1)


def generate_site(seed: int, config: LayoutConfig | None = None) -> Site:
    """A plausible substation for ``seed``; same seed, same site.

    Redraws (attempt 1, 2, ...) until each class covers ``min_class_share`` of
    the walkable area; raises ``RuntimeError`` if none of ``max_attempts`` does.
    """
    cfg = config or LayoutConfig()
    for attempt in range(cfg.max_attempts):
        site = _draw(seed, attempt, cfg)
        if class_shares(site, resolution_m=2.0).min() >= cfg.min_class_share:
            if cfg.beacon_placement == "coverage":
                g = site.grid
                beacons, n_slots = _coverage_beacons(stream_rng(seed, "beacons", attempt), g.east_max_m,
                                                     g.north_max_m, site.layout, cfg)
                site = replace(site, beacons=beacons, acoustic=replace(site.acoustic, n_slots=n_slots,
                                                                       slot_s=cfg.slot_s))
            if cfg.uwb_anchors:
                site = replace(site, uwb_anchors=place_uwb_anchors(site))
            return site
    raise RuntimeError(f"no layout for seed {seed} reached min_class_share={cfg.min_class_share} "
                       f"in {cfg.max_attempts} attempts")
