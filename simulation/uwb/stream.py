"""The UWB stream of a walk: ``uwb.csv``, a DW3000-class tag ranging to the site's anchors.

Writer for :data:`simulation.streams.STREAM_WRITERS`; survey cells and sites without ``[[uwb_anchors]]``
get no UWB (the writer returns ``{}``). Format: :mod:`features.uwb.reader`.

The tag runs double-sided two-way ranging (DS-TWR, IEEE 802.15.4z §6.9.7) rounds at ``rate_hz``: each
round polls up to ``max_per_round`` anchors, ``slot_s`` apart — the ones it heard strongest in the last
rounds, every ``discovery_every``-th round all of them (the tag knows only what it received). Per poll the
channel of :mod:`simulation.uwb.channel` (computed at ``channel_rate_hz`` and for each 0.5 m of ground;
the straight-line distance exactly at the poll's time) gets a lognormal fade per path (``fading_db``), then:

- **packet**: lost when the strongest path is under the DW3000's sensitivity, or at random with the packet
  error rate ``per_floor + 1/(1 + 10^(margin/3 dB))`` (margin = peak − sensitivity, a PER waterfall);
- **range**: the first path the leading-edge detector finds (:data:`~simulation.uwb.radio.FIRST_PATH_FLOOR_DBM`,
  within :data:`~simulation.uwb.radio.FIRST_PATH_DYNAMIC_DB` of the peak) — its length is the range, so
  a blocked direct path leaves the positive NLOS bias of the wall's slower wave or of the detour — plus
  N(0, σ_r), σ_r = ``range_sigma_m``·√(1 + 10^(−m/10)) at first-path margin m dB (the time-of-arrival
  CRLB grows as 1/SNR; DW3000 datasheet: ±10 cm ranging accuracy in LOS), plus the anchor's antenna-delay
  calibration residual (``antenna_delay_sigma_m``, fixed per anchor);
- **azimuth**: the first path's arrival direction relative to the anchor's true boresight (its mounting
  error ``boresight_sigma_deg`` unknown to the crew), plus the anchor's PDoA offset residual, plus
  N(0, σ_φ), σ_φ = ``azimuth_sigma_deg``·√(1 + 10^(−m/10)) / max(cos φ, 0.26), × ``nlos_azimuth_factor``
  when the first path is not the clear direct one (a bent or attenuated first path is mixed with close
  multipath in the phase the array measures). Two antennas λ/2 apart tell front from back not at all: a
  tag behind the array is reported at its mirror image; the result is clipped to ±90°. PDoA error of
  DW1000/DW3000 arrays: a few degrees RMS in LOS after calibration (Dotlic et al., "Angle of arrival
  estimation using Decawave DW1000 integrated circuits", WPNC 2017; Qorvo DW3000 PDoA: ±5° typical);
- **quality**: what the chip computes from its CIR: first-path power over received power, dB
  (DW3000 User Manual §4.7), from the faded paths and their clusters' tails, + N(0, ``quality_noise_db``).

Installation (per site, from ``stream_rng(site seed, "uwb", "install")``, the same for every walk on a
site): true anchor positions = surveyed ± ``survey_sigma_m`` per axis (a total-station / RTK survey),
boresight ± ``boresight_sigma_deg``, antenna delay and PDoA offset residuals. Per walk:
``stream_rng(seed, "uwb")``.
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, fields

import numpy as np

from features.errors import ConfigError
from features.uwb.reader import UwbLog, write_uwb

from simulation.rng import stream_rng
from simulation.streams import StreamContext
from simulation.uwb.channel import CLUSTER_TAIL_DB, PATH_DIRECT, UwbPaths, build_uwb_scene, uwb_paths
from simulation.uwb.radio import (ANCHOR_GAIN_DBI, FIRST_PATH_DYNAMIC_DB, FIRST_PATH_FLOOR_DBM, SENSITIVITY_DBM,
                                  TX_POWER_DBM, free_space_loss_db)

__all__ = ["UwbSimConfig", "UwbTruth", "simulate_uwb", "write_uwb_stream", "UWB_FILE"]

UWB_FILE = "uwb.csv"


@dataclass(frozen=True)
class UwbSimConfig:
    """The simulated tag and installation (module docstring); ``[uwb]`` of the simulate options."""

    rate_hz: float = 10.0
    slot_s: float = 0.003
    max_per_round: int = 8
    discovery_every: int = 10
    channel_rate_hz: float = 1.0
    range_sigma_m: float = 0.08
    azimuth_sigma_deg: float = 3.0
    nlos_azimuth_factor: float = 2.5
    fading_db: float = 2.0
    quality_noise_db: float = 0.5
    per_floor: float = 0.02
    survey_sigma_m: float = 0.02
    boresight_sigma_deg: float = 1.5
    antenna_delay_sigma_m: float = 0.03
    pdoa_offset_sigma_deg: float = 1.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"uwb.{f.name} must be a non-negative number, got {v!r}")
        if not 0.5 <= self.rate_hz <= 50.0:
            raise ConfigError(f"uwb.rate_hz must lie in [0.5, 50], got {self.rate_hz}")
        if not isinstance(self.max_per_round, int) or self.max_per_round < 1:
            raise ConfigError(f"uwb.max_per_round must be a positive integer, got {self.max_per_round!r}")
        if self.max_per_round * self.slot_s >= 1.0 / self.rate_hz:
            raise ConfigError(f"uwb: {self.max_per_round} polls of {self.slot_s} s do not fit in a round of "
                              f"{1.0 / self.rate_hz:g} s")
        if not isinstance(self.discovery_every, int) or self.discovery_every < 1:
            raise ConfigError(f"uwb.discovery_every must be a positive integer, got {self.discovery_every!r}")
        if not 0.0 < self.channel_rate_hz <= 20.0:
            raise ConfigError(f"uwb.channel_rate_hz must lie in (0, 20], got {self.channel_rate_hz}")
        if self.per_floor >= 1.0:
            raise ConfigError(f"uwb.per_floor must lie in [0, 1), got {self.per_floor}")

    @classmethod
    def from_options(cls, options: dict) -> "UwbSimConfig":
        table = options.get("uwb", {}) or {}
        if not isinstance(table, dict):
            raise ConfigError(f"simulate option 'uwb' must be a table, got {table!r}")
        unknown = set(table) - {f.name for f in fields(cls)}
        if unknown:
            raise ConfigError(f"[uwb] unknown key(s) {sorted(unknown)}")
        return cls(**table)


@dataclass(frozen=True)
class UwbTruth:
    """What the simulator knows of each written row (benches only; never read downstream): arrays (n,).

    ``true_range_m``: distance from the tag to the anchor's true position; ``first_kind``: the first path's
    kind (:data:`~simulation.uwb.channel.PATH_DIRECT` = clear line of sight); ``true_azimuth_deg``: the tag's
    true angle from the anchor's true boresight (not mirrored).
    """

    true_range_m: np.ndarray
    first_kind: np.ndarray
    true_azimuth_deg: np.ndarray


def _site_seed(site) -> int:
    return int(site.seed) if site.seed is not None else zlib.crc32(site.name.encode())


def _installation(site, cfg: UwbSimConfig):
    """True anchors (k, 3), true boresights (k,) rad, antenna-delay and PDoA-offset residuals (k,)."""
    rng = stream_rng(_site_seed(site), "uwb", "install")
    k = len(site.uwb_anchors)
    surveyed = np.array([[a.east_m, a.north_m, a.up_m] for a in site.uwb_anchors], float).reshape(k, 3)
    xyz = surveyed + rng.normal(0.0, cfg.survey_sigma_m, (k, 3))
    bore = np.radians([a.boresight_deg for a in site.uwb_anchors]) + np.radians(rng.normal(0.0, cfg.boresight_sigma_deg, k))
    delay = rng.normal(0.0, cfg.antenna_delay_sigma_m, k)
    pdoa = np.radians(rng.normal(0.0, cfg.pdoa_offset_sigma_deg, k))
    return xyz, bore, delay, pdoa


def _max_range_m() -> float:
    """Distance beyond which even a clear front-lobe path is under the first-path floor, m (+10 % margin
    for fading)."""
    budget = TX_POWER_DBM + ANCHOR_GAIN_DBI - FIRST_PATH_FLOOR_DBM + 6.0
    return 1.1 * 10.0 ** ((budget - float(free_space_loss_db(1.0))) / 20.0)


def _wrap(x: float) -> float:
    return (x + math.pi) % (2 * math.pi) - math.pi


def _measure(rng, paths: UwbPaths, cfg: UwbSimConfig):
    """One poll: ``None`` (lost) or (first path's index, faded path powers dBm (p,), its quality noise dB).

    The quality itself (first-path power over the received total) does not steer the polling and is computed
    for every row at once by :func:`_quality_db`."""
    p = paths.power_dbm + rng.normal(0.0, cfg.fading_db, len(paths.power_dbm))
    pl = p.tolist()
    if not any(math.isfinite(v) for v in pl):
        return None
    peak = max(v for v in pl if v == v)                  # nanmax
    margin = peak - SENSITIVITY_DBM
    if margin < 0 or rng.random() < cfg.per_floor + 1.0 / (1.0 + 10.0 ** (margin / 3.0)):
        return None
    floor = max(FIRST_PATH_FLOOR_DBM, peak - FIRST_PATH_DYNAMIC_DB)
    i = next(k for k, v in enumerate(pl) if v >= floor)
    return i, p, rng.normal(0.0, cfg.quality_noise_db)


def _quality_db(p: list, first: list, noise: list) -> list:
    """Per row: first-path power over the received total, dB — every cluster's ray and its dense tail
    (:data:`simulation.uwb.channel.CLUSTER_TAIL_DB`) — plus its noise, at most 0; ``p`` the rows' faded path
    powers (dBm arrays), ``first`` their first paths' indices."""
    if not p:
        return []
    flat = np.concatenate(p)
    finite = np.isfinite(flat)
    lin = 10.0 ** (flat[finite] / 10.0)                  # one call: the same values row by row
    ends = np.cumsum([len(row) for row in p])
    counts = np.add.reduceat(finite.astype(int), ends - [len(row) for row in p])   # rows hold ≥ 1 path
    stops = np.cumsum(counts).tolist()
    tail = 1.0 + 10.0 ** (CLUSTER_TAIL_DB / 10.0)
    out = []
    for row, i, n, e, q in zip(p, first, counts.tolist(), stops, noise):
        total = 10.0 * math.log10(float(np.sum(lin[e - n:e])) * tail)
        out.append(min(float(row[i]) - total + q, 0.0))
    return out


def simulate_uwb(ctx: StreamContext, cfg: UwbSimConfig = UwbSimConfig()) -> tuple[UwbLog, UwbTruth]:
    """The walk's UWB log and the simulator's truth of each row (module docstring)."""
    site, traj = ctx.site, ctx.trajectory
    xyz, bore, delay, pdoa = _installation(site, cfg)
    ids = np.array([a.id for a in site.uwb_anchors], int)
    xyz_rows = [tuple(row) for row in xyz.tolist()]
    scene = build_uwb_scene(site)
    rng = stream_rng(ctx.seed, "uwb")
    reach = _max_range_m()
    # The channel is computed once per anchor, channel second and 0.5 m of ground, at the first poll there
    # (``cache``; keys of past seconds are never met again, so it is emptied when the second changes); a walker
    # standing still meets the same exact position second after second: ``uwb_paths`` is a function of it, and
    # ``exact`` keeps the last few thousand (emptied when full — a bound on memory, not a change of output).
    cache: dict = {}
    exact: dict = {}
    tc_now = None
    heard_dbm = np.full(len(ids), -np.inf)       # the tag's memory: last first-path level per anchor
    heard_t = np.full(len(ids), -np.inf)
    rows, truth, faded, first, q_noise, sweep = [], [], [], [], [], 0
    t0, t1 = float(traj.t_s[0]), float(traj.t_s[-1])
    t_rounds = np.arange(t0, t1 - cfg.max_per_round * cfg.slot_s, 1.0 / cfg.rate_hz)
    slots = np.arange(cfg.max_per_round) * cfg.slot_s
    az_sigma = math.radians(cfg.azimuth_sigma_deg)
    block = 1024                                 # rounds whose poll slots are interpolated at once
    for r, t_round in enumerate(t_rounds):
        if r % block == 0:                       # every slot's time and tag position (np.interp is elementwise)
            t_slot = t_rounds[r:r + block, None] + slots
            pos = [v.reshape(t_slot.shape).tolist() for v in traj.interp(t_slot.ravel())]
            t_slot = t_slot.tolist()
        fresh = np.flatnonzero(t_round - heard_t <= 2.0)
        poll = fresh[np.argsort(-heard_dbm[fresh], kind="stable")][:cfg.max_per_round]
        if r % cfg.discovery_every == 0 or len(poll) < 3:   # discovery: the next anchors in turn
            window = (sweep + np.arange(cfg.max_per_round)) % len(ids)
            sweep += cfg.max_per_round
            poll = np.unique(window) if len(ids) > cfg.max_per_round else np.arange(len(ids))
        rb = r % block
        for k, j in enumerate(sorted(poll.tolist())):
            t = t_slot[rb][k]
            e, n, u = pos[0][rb][k], pos[1][rb][k], pos[2][rb][k]
            aj = xyz_rows[j]
            d = math.dist((e, n, u), aj)
            if d > reach:
                continue
            tc = round(t * cfg.channel_rate_hz)
            if tc != tc_now:
                cache.clear()
                tc_now = tc
            key = (j, tc, round(e * 2.0), round(n * 2.0))
            paths = cache.get(key)
            if paths is None:
                here = (j, struct.pack("3d", e, n, u))          # the exact bits (−0.0 is not 0.0 here)
                paths = exact.get(here)
                if paths is None:
                    if len(exact) >= 4096:
                        exact.clear()
                    paths = exact[here] = uwb_paths(scene, xyz[j], float(bore[j]), (e, n, u))
                cache[key] = paths
            got = _measure(rng, paths, cfg)
            if got is None:
                continue
            i, p, qn = got
            kind = int(paths.kind[i])
            fp_margin = float(p[i] - SENSITIVITY_DBM)
            heard_dbm[j], heard_t[j] = fp_margin, t
            scale = math.sqrt(1.0 + 10.0 ** (-fp_margin / 10.0))
            rng_m = d + float(paths.excess_m[i]) + delay[j] + rng.normal(0.0, cfg.range_sigma_m * scale)
            true_rel = _wrap(math.atan2(e - aj[0], n - aj[1]) - bore[j])
            rel = _wrap(true_rel + float(paths.angle_off_rad[i]) + pdoa[j])
            if abs(rel) > math.pi / 2:          # behind the array: its mirror image
                rel = math.copysign(math.pi, rel) - rel
            sig = (az_sigma * scale / max(math.cos(rel), 0.26)
                   * (1.0 if kind == PATH_DIRECT else cfg.nlos_azimuth_factor))
            az = min(max(rel + rng.normal(0.0, sig), -math.pi / 2), math.pi / 2)
            rows.append((t, ids[j], max(rng_m, 0.01), math.degrees(az)))
            truth.append((d, kind, math.degrees(true_rel)))
            faded.append(p), first.append(i), q_noise.append(qn)
    data = np.array(rows, float).reshape(-1, 4)
    tr = np.array(truth, float).reshape(-1, 3)
    log = UwbLog(t_s=data[:, 0], anchor=data[:, 1].astype(int), range_m=data[:, 2], azimuth_deg=data[:, 3],
                 quality=np.array(_quality_db(faded, first, q_noise), float).reshape(-1))
    return log, UwbTruth(true_range_m=tr[:, 0], first_kind=tr[:, 1].astype(int), true_azimuth_deg=tr[:, 2])


def write_uwb_stream(ctx: StreamContext) -> dict:
    """Write ``uwb.csv`` for a walk on a site with UWB anchors; the ``[uwb]`` table of ``walk.toml``."""
    if ctx.kind != "walk" or not ctx.site.uwb_anchors:
        return {}
    cfg = UwbSimConfig.from_options(ctx.options)
    log, _truth = simulate_uwb(ctx, cfg)
    write_uwb(ctx.out_dir / UWB_FILE, log)
    return {"uwb": {"file": UWB_FILE, "rate_hz": float(cfg.rate_hz), "ranging": "DS-TWR",
                    "angle": "PDoA at the anchor, clockwise from its boresight"}}
