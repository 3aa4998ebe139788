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
from numba import njit, types
from numba.typed import Dict as NumbaDict

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


@njit(cache=True)
def _wrap(x: float) -> float:
    return (x + math.pi) % (2 * math.pi) - math.pi


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


_DONE, _NEXT_BLOCK, _MISS, _FULL = 0, 1, 2, 3
"""What :func:`_poll_rounds` stopped for: the walk's rounds all done; the next block of rounds' poll positions
needed; a channel not computed yet; the output arrays full."""

_NO_SECOND = -(2 ** 62)
"""The channel second before the first poll (no second's cache yet)."""

_KEY = types.UniTuple(types.int64, 4)
"""A channel's key in the poll loop's cache: anchor, channel second, 0.5 m cell east and north."""


@njit(cache=True)
def _new_cache():
    """An empty channel cache, made by compiled code: ``numba.typed.Dict.empty`` called from Python compiles its
    helpers in every new process (0.11-0.13 s with numba already running; reading its items from Python, 0.35 s
    more), where this compiled call is read from numba's on-disk cache (2 ms)."""
    return NumbaDict.empty(key_type=_KEY, value_type=types.int64)


@njit(cache=True)
def _cache_items(cache) -> tuple[np.ndarray, np.ndarray]:
    """The cache's keys (m, 4) and channel numbers (m,) (read in compiled code, for the same reason)."""
    keys = np.empty((len(cache), 4), np.int64)
    pids = np.empty(len(cache), np.int64)
    m = 0
    for key, pid in cache.items():
        keys[m, 0], keys[m, 1], keys[m, 2], keys[m, 3] = key
        pids[m] = pid
        m += 1
    return keys, pids


@njit(cache=True)
def _cache_set(cache, keys: np.ndarray, pids: np.ndarray) -> None:
    for m in range(pids.shape[0]):
        cache[(keys[m, 0], keys[m, 1], keys[m, 2], keys[m, 3])] = pids[m]


_ROWS_START = 1 << 14
"""Rows the output arrays hold at first (doubled whenever full)."""

_EXACT_KEEP = 4096
"""Channels of exact positions kept (:func:`simulate_uwb`): at that many, forgotten (a bound on memory)."""


@njit(cache=True)
def _poll_rounds(rng, loop, t_rounds, block0, t_slot, pos_e, pos_n, pos_u, heard_dbm, heard_t, poll, xyz, bore,
                 delay, pdoa, ids, cache, path_at, path_len, path_power, path_excess, path_kind, path_off, rows,
                 first, q_noise, faded, faded_at, need, need_xyz, reach, max_per_round, discovery_every,
                 channel_rate_hz, fading_db, per_floor, quality_noise_db, range_sigma_m, az_sigma, nlos_factor,
                 sensitivity_dbm, fp_floor_dbm, fp_dynamic_db, direct):
    """The tag's poll rounds (module docstring), compiled, from where ``loop`` says until the walk's last round
    or until it needs what Python gives: the next block of rounds' poll times and positions (``t_slot``,
    ``pos_*`` (block, max_per_round) from round ``block0``), a channel (``need``: anchor, channel second, 0.5 m
    cell; ``need_xyz`` the tag's exact position: Python computes it, files it in the path arrays and its number
    in ``need[4]``, which the loop files in ``cache`` as it resumes) or room for more rows. Returns why it
    stopped; resumes at the same poll (nothing drawn before a stop).

    loop : int64 [round, poll index in the round (−1: the round's polls not chosen yet), polls chosen, discovery
    sweep, channel second of ``cache``, rows written, faded powers written]; poll : the round's anchors. The
    draws, in order per poll, from the walk's one generator: each path's fade, the packet loss, the quality
    noise, the range noise, the azimuth noise (each only where the branches before it let the packet through).
    rows : (cap, 7) t, anchor id, range, azimuth (deg) and, for benches, true distance, first path's kind, true
    azimuth (deg); first, q_noise : the first path's index and the quality noise; faded : each row's faded path
    powers, row m's from ``faded_at[m]``. The radio's constants come as arguments (a compiled function's cache
    holds the globals it read, and would keep an edited module's old values).
    """
    n_ids = ids.shape[0]
    n_rounds = t_rounds.shape[0]
    block = t_slot.shape[0]
    if need[4] >= 0:                       # the channel Python computed for the last stop, filed
        cache[(need[0], need[1], need[2], need[3])] = need[4]
        need[4] = -1
    while loop[0] < n_rounds:
        r = loop[0]
        if r < block0 or r >= block0 + block:
            return _NEXT_BLOCK
        rb = r - block0
        if loop[1] < 0:                    # the round's polls: the anchors heard strongest in the last 2 s
            fresh = np.flatnonzero(t_rounds[r] - heard_t <= 2.0)
            chosen = fresh[np.argsort(-heard_dbm[fresh], kind="mergesort")][:max_per_round]
            if r % discovery_every == 0 or chosen.shape[0] < 3:   # discovery: the next anchors in turn
                window = (loop[3] + np.arange(max_per_round)) % n_ids
                loop[3] += max_per_round
                chosen = np.unique(window) if n_ids > max_per_round else np.arange(n_ids)
            chosen = np.sort(chosen)
            loop[2] = chosen.shape[0]
            poll[:loop[2]] = chosen
            loop[1] = 0
        while loop[1] < loop[2]:
            kk = loop[1]
            j = poll[kk]
            t = t_slot[rb, kk]
            e, n, u = pos_e[rb, kk], pos_n[rb, kk], pos_u[rb, kk]
            aj0, aj1, aj2 = xyz[j, 0], xyz[j, 1], xyz[j, 2]
            d = math.sqrt((e - aj0) ** 2 + (n - aj1) ** 2 + (u - aj2) ** 2)
            if d > reach:
                loop[1] += 1
                continue
            tc = round(t * channel_rate_hz)
            if tc != loop[4]:
                cache.clear()
                loop[4] = tc
            key = (j, tc, round(e * 2.0), round(n * 2.0))
            if key not in cache:
                need[0], need[1], need[2], need[3] = key
                need_xyz[0], need_xyz[1], need_xyz[2] = e, n, u
                return _MISS
            pid = cache[key]
            at, n_paths = path_at[pid], path_len[pid]
            if loop[5] >= rows.shape[0] or loop[6] + n_paths > faded.shape[0]:
                return _FULL
            # the packet: each path faded, lost under the sensitivity or by the PER waterfall
            p = path_power[at:at + n_paths] + rng.normal(0.0, fading_db, n_paths)
            peak = -np.inf
            for v in p:
                if v == v and v > peak:
                    peak = v
            if not math.isfinite(peak):
                loop[1] += 1
                continue
            margin = peak - sensitivity_dbm
            if margin < 0 or rng.random() < per_floor + 1.0 / (1.0 + 10.0 ** (margin / 3.0)):
                loop[1] += 1
                continue
            floor = max(fp_floor_dbm, peak - fp_dynamic_db)
            i = 0
            while i < n_paths - 1 and not p[i] >= floor:     # the peak itself clears the floor
                i += 1
            qn = rng.normal(0.0, quality_noise_db)
            kind = path_kind[at + i]
            fp_margin = p[i] - sensitivity_dbm
            heard_dbm[j], heard_t[j] = fp_margin, t
            scale = math.sqrt(1.0 + 10.0 ** (-fp_margin / 10.0))
            rng_m = d + path_excess[at + i] + delay[j] + rng.normal(0.0, range_sigma_m * scale)
            true_rel = _wrap(math.atan2(e - aj0, n - aj1) - bore[j])
            rel = _wrap(true_rel + path_off[at + i] + pdoa[j])
            if abs(rel) > math.pi / 2:          # behind the array: its mirror image
                rel = math.copysign(math.pi, rel) - rel
            sig = az_sigma * scale / max(math.cos(rel), 0.26) * (1.0 if kind == direct else nlos_factor)
            az = min(max(rel + rng.normal(0.0, sig), -math.pi / 2), math.pi / 2)
            m = loop[5]
            rows[m, 0], rows[m, 1], rows[m, 2], rows[m, 3] = t, ids[j], max(rng_m, 0.01), math.degrees(az)
            rows[m, 4], rows[m, 5], rows[m, 6] = d, kind, math.degrees(true_rel)
            first[m], q_noise[m], faded_at[m] = i, qn, loop[6]
            faded[loop[6]:loop[6] + n_paths] = p
            loop[5] += 1
            loop[6] += n_paths
            loop[1] += 1
        loop[0] += 1
        loop[1] = -1
    return _DONE


class _PathStore:
    """The channels computed so far, end to end in arrays the compiled loop reads (path ``pid``'s entries from
    ``at[pid]``, ``length[pid]`` of them), grown by doubling."""

    def __init__(self, ids: int = 1024, entries: int = 16384):
        self.n = self.used = 0
        self.at, self.length = np.zeros(ids, np.int64), np.zeros(ids, np.int64)
        self.power, self.excess = np.zeros(entries), np.zeros(entries)
        self.kind, self.off = np.zeros(entries, np.int64), np.zeros(entries)

    def add(self, paths: UwbPaths) -> int:
        k = len(paths.power_dbm)
        if self.n == len(self.at):
            self.at, self.length = _grown(self.at), _grown(self.length)
        while self.used + k > len(self.power):
            self.power, self.excess, self.kind, self.off = (_grown(a) for a in (self.power, self.excess, self.kind,
                                                                                  self.off))
        u = self.used
        self.power[u:u + k], self.excess[u:u + k] = paths.power_dbm, paths.excess_m
        self.kind[u:u + k], self.off[u:u + k] = paths.kind, paths.angle_off_rad
        self.at[self.n], self.length[self.n] = u, k
        self.used += k
        self.n += 1
        return self.n - 1

    def arrays(self) -> tuple:
        return self.at, self.length, self.power, self.excess, self.kind, self.off


def _grown(a: np.ndarray) -> np.ndarray:
    out = np.zeros((2 * a.shape[0],) + a.shape[1:], a.dtype)
    out[:a.shape[0]] = a
    return out


def simulate_uwb(ctx: StreamContext, cfg: UwbSimConfig = UwbSimConfig()) -> tuple[UwbLog, UwbTruth]:
    """The walk's UWB log and the simulator's truth of each row (module docstring).

    The poll rounds run compiled (:func:`_poll_rounds`; in Python, with a call per poll, the stream took 0.93 s
    of CPU on the benchmark's 600 s walk, now 0.45 s, every row the same but ranges within 1.4e-14 m: the
    distance is summed plainly where ``math.dist`` rounds it more carefully); the channel
    (:func:`~simulation.uwb.channel.uwb_paths`) is computed here when the loop meets one it has not: once per
    anchor, channel second and 0.5 m of ground, at the first poll there (``cache``;
    keys of past seconds are never met again, so the loop empties it when the second changes). A walker
    standing still meets the same exact position second after second: ``uwb_paths`` is a function of it, and
    ``exact`` keeps the last few thousand (emptied when full, and the path arrays with it but for the
    current second's — a bound on memory, not a change of output).
    """
    site, traj = ctx.site, ctx.trajectory
    xyz, bore, delay, pdoa = _installation(site, cfg)
    ids = np.array([a.id for a in site.uwb_anchors], np.int64)
    scene = build_uwb_scene(site)
    rng = stream_rng(ctx.seed, "uwb")
    t0, t1 = float(traj.t_s[0]), float(traj.t_s[-1])
    t_rounds = np.arange(t0, t1 - cfg.max_per_round * cfg.slot_s, 1.0 / cfg.rate_hz)
    slots = np.arange(cfg.max_per_round) * cfg.slot_s
    block = 1024                                 # rounds whose poll slots are interpolated at once
    cache = _new_cache()
    store, exact = _PathStore(), {}
    loop = np.array([0, -1, 0, 0, _NO_SECOND, 0, 0], np.int64)
    heard_dbm = np.full(len(ids), -np.inf)       # the tag's memory: last first-path level per anchor
    heard_t = np.full(len(ids), -np.inf)
    poll = np.zeros(cfg.max_per_round, np.int64)
    cap = _ROWS_START                            # rows, grown by doubling (_FULL)
    rows, first, q_noise = np.zeros((cap, 7)), np.zeros(cap, np.int64), np.zeros(cap)
    faded, faded_at = np.zeros(8 * cap), np.zeros(cap, np.int64)
    need, need_xyz = np.array([0, 0, 0, 0, -1], np.int64), np.zeros(3)
    block0, t_slot = -block, np.zeros((block, cfg.max_per_round))
    pos = [np.zeros_like(t_slot)] * 3
    reach = _max_range_m()
    while len(ids):
        why = _poll_rounds(rng, loop, t_rounds, block0, t_slot, *pos, heard_dbm, heard_t, poll, xyz, bore, delay,
                           pdoa, ids, cache, *store.arrays(), rows, first, q_noise, faded, faded_at, need, need_xyz,
                           reach, cfg.max_per_round, cfg.discovery_every, float(cfg.channel_rate_hz),
                           float(cfg.fading_db), float(cfg.per_floor), float(cfg.quality_noise_db),
                           float(cfg.range_sigma_m), math.radians(cfg.azimuth_sigma_deg),
                           float(cfg.nlos_azimuth_factor), float(SENSITIVITY_DBM), float(FIRST_PATH_FLOOR_DBM),
                           float(FIRST_PATH_DYNAMIC_DB), PATH_DIRECT)
        if why == _DONE:
            break
        if why == _NEXT_BLOCK:                   # every slot's time and tag position (np.interp is elementwise)
            block0 = int(loop[0])
            t_slot = t_rounds[block0:block0 + block, None] + slots
            pos = [np.ascontiguousarray(v.reshape(t_slot.shape)) for v in traj.interp(t_slot.ravel())]
        elif why == _MISS:
            j = int(need[0])
            e, n, u = need_xyz.tolist()
            here = (j, struct.pack("3d", e, n, u))          # the exact bits (−0.0 is not 0.0 here)
            pid = exact.get(here)
            if pid is None:
                if len(exact) >= _EXACT_KEEP:
                    exact.clear()
                    store = _compacted(store, cache)
                pid = exact[here] = store.add(uwb_paths(scene, xyz[j], float(bore[j]), (e, n, u)))
            need[4] = pid                        # the loop files it under its key as it resumes
        else:                                    # _FULL
            rows, first, q_noise, faded_at = _grown(rows), _grown(first), _grown(q_noise), _grown(faded_at)
            faded = _grown(faded)
    m = int(loop[5])
    rows = rows[:m]
    ends = np.append(faded_at[1:m], loop[6]) if m else np.zeros(0, np.int64)
    powers = [faded[a:b] for a, b in zip(faded_at[:m].tolist(), ends.tolist())]
    log = UwbLog(t_s=rows[:, 0], anchor=rows[:, 1].astype(int), range_m=rows[:, 2], azimuth_deg=rows[:, 3],
                 quality=np.array(_quality_db(powers, first[:m].tolist(), q_noise[:m].tolist()), float).reshape(-1))
    return log, UwbTruth(true_range_m=rows[:, 4], first_kind=rows[:, 5].astype(int), true_azimuth_deg=rows[:, 6])


def _compacted(store: _PathStore, cache) -> _PathStore:
    """A store holding only the channels ``cache`` (the current second's) refers to, ``cache`` renumbered."""
    fresh = _PathStore()
    keys, pids = _cache_items(cache)
    renumbered = np.array([fresh.add(UwbPaths(excess_m=store.excess[a:a + k], power_dbm=store.power[a:a + k],
                                              kind=store.kind[a:a + k], angle_off_rad=store.off[a:a + k],
                                              direct_m=0.0))
                           for a, k in zip(store.at[pids].tolist(), store.length[pids].tolist())], np.int64)
    _cache_set(cache, keys, renumbered.reshape(-1))
    return fresh


def write_uwb_stream(ctx: StreamContext) -> dict:
    """Write ``uwb.csv`` for a walk on a site with UWB anchors; the ``[uwb]`` table of ``walk.toml``."""
    if ctx.kind != "walk" or not ctx.site.uwb_anchors:
        return {}
    cfg = UwbSimConfig.from_options(ctx.options)
    log, _truth = simulate_uwb(ctx, cfg)
    write_uwb(ctx.out_dir / UWB_FILE, log)
    return {"uwb": {"file": UWB_FILE, "rate_hz": float(cfg.rate_hz), "ranging": "DS-TWR",
                    "angle": "PDoA at the anchor, clockwise from its boresight"}}
