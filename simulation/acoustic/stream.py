"""``audio.wav``: every beacon's chirps through the time-varying channel, plus noise, as a 48 kHz int16 WAV.

Per chirp emission (a beacon's slot in a TDMA frame, :mod:`simulation.acoustic.chirp`)
the channel is evaluated once, static over the 10 ms chirp (the walker moves
≈ 1.5 cm), at the receiver's position at the moment the first path arrives
(found by fixed-point iteration t_a = t_e + L(x(t_a))/c), and rendered by
:class:`simulation.acoustic.synthesis.ChirpRenderer`; ambient noise, hum and corona
clicks come from :class:`simulation.acoustic.synthesis.AmbientNoise`. Emissions whose
free-field level could not rise out of the noise are skipped. Samples are
summed in a rolling buffer and written block by block, so memory stays
bounded for any length of walk. Emissions go in batches of 128: their first
look (true emission instant, effective speed of sound, arrival fixed point,
walker position, free-field screen, tweeter and torso factors), their arrival,
level and Doppler factor, the seeds of their tails' generators
(:func:`simulation.rng.stream_rngs`) and their plans (band, FFT length, H(f),
the tails' arithmetic) are computed over the batch at once, and the emissions of
equal FFT length are rendered as one group; every draw and every sample is what
one emission at a time gives (issue 25 item 2: the files of a seeded walk are
byte-identical to those of the per-emission code).

The receiver: its recording starts at ``start_s + U(−u, u)`` on the walk's time
base (stated ``start_s``, stated uncertainty ``u``), its sample clock runs
``drift_ppm`` fast or slow, the microphone maps ``full_scale_db_spl`` to a
full-scale sine, and samples are rounded to int16 (clipped only beyond full
scale). The true per-emission arrivals are written to ``audio_truth.csv`` for
evaluation; a receiver never reads it.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import heapq
import io
import itertools
import math
from dataclasses import dataclass, fields, replace
from typing import Iterator

import numpy as np
import soundfile as sf
from numba import njit

from features.errors import ConfigError
from features.fileio import atomic_path
from features.site import Site

from simulation.acoustic.channel import PATH_KINDS, PathSet, build_scene, channel_paths, clutter_index
from simulation.acoustic.atmosphere import absorption_db_per_m, fresnel_number, maekawa_loss_db
from simulation.acoustic.synthesis import CHUNK_SAMPLES, AmbientNoise, AudioConfig, ChirpRenderer, detection_range_m
from simulation.acoustic.air import Air, AirConfig
from simulation.acoustic.hardware import (CodecFilter, HardwareConfig, beacon_axes, beacon_delays_s,
                                         piston_directivity, torso_shadow, true_beacon_positions)
from simulation.acoustic.chirp import ChirpSpec, beacon_chirp, emission_times_s
from simulation.progress import Progress
from simulation.rng import stream_rng, stream_rngs
from simulation.streams import StreamContext, Trajectory

__all__ = ["AudioConfig", "AudioResult", "render_audio", "write_audio", "detection_range_m"]

_PRE_SAMPLES = 64          # flush margin: a segment starts this many samples before its first arrival


@dataclass(frozen=True)
class AudioResult:
    """What :func:`render_audio` did: true clock, counts and per-emission truth rows."""

    true_start_s: float
    drift_ppm: float
    n_samples: int
    n_emissions: int
    n_rendered: int
    n_clipped: int
    truth_csv: str | None


class _Accumulator:
    """A rolling float buffer of device samples; finished blocks leave through :meth:`pop_block`."""

    def __init__(self, block: int, n_total: int):
        self.block = block
        self.n_total = n_total
        self.base = 0
        self.buf = np.zeros(4 * block)
        self.used = 0           # buf[used:] is all zeros

    def add(self, start: int, seg: np.ndarray) -> None:
        lo, hi = max(start, self.base), min(start + len(seg), self.n_total)
        if hi <= lo:
            return
        need = hi - self.base
        if need > len(self.buf):
            self.buf = np.concatenate([self.buf, np.zeros(need - len(self.buf) + self.block)])
        self.buf[lo - self.base:hi - self.base] += seg[lo - start:hi - start]
        self.used = max(self.used, need)

    def pop_block(self) -> np.ndarray:
        n = min(self.block, self.n_total - self.base)
        out = self.buf[:n].copy()
        m = max(self.used, n)
        self.buf[:m - n] = self.buf[n:m]     # shift the written part in place (overlapping slices are safe)
        self.buf[m - n:m] = 0.0
        self.used = m - n
        self.base += n
        return out


def _positions_at(traj: Trajectory, t_s: np.ndarray) -> np.ndarray:
    """True device positions (east, north, up), m, at times ``t_s`` (n,): shape (n, 3), linear interpolation."""
    return np.column_stack([np.interp(t_s, traj.t_s, traj.east_m), np.interp(t_s, traj.t_s, traj.north_m),
                            np.interp(t_s, traj.t_s, traj.up_m)])


def _norms(d: np.ndarray) -> np.ndarray:
    """Euclidean norms of the rows of ``d`` (n, 3), as ``numpy.linalg.norm`` computes each (a dot product)."""
    return np.sqrt(np.vecdot(d, d))


def _velocity_table(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal velocity (v_east, v_north), m/s, shape (n,) each, from speed and heading (from north, clockwise)."""
    return traj.speed_m_s * np.sin(traj.heading_rad), traj.speed_m_s * np.cos(traj.heading_rad)


def _emission_batches(site: Site, start_utc, t_begin_s: float, t_end_s: float, size: int = 128) -> Iterator[list]:
    """Every (t_emit_s, beacon_id, index, beacon, spec) in [t_begin_s, t_end_s), in emission order, in lists of
    at most ``size``.

    A lazy k-way merge of the beacons' schedules: memory per beacon and batch, not per emission.
    """
    def one(b):
        spec = beacon_chirp(site, b)
        for i, t_e in enumerate(emission_times_s(site, b, start_utc, t_begin_s, t_end_s)):
            yield float(t_e), b.id, i, b, spec

    merged = heapq.merge(*(one(b) for b in site.beacons), key=lambda e: (e[0], e[1]))
    while batch := list(itertools.islice(merged, size)):
        yield batch


@dataclass(frozen=True)
class _Arrivals:
    """Straight-line first look at a batch of emissions: true emission times ``t_e_s``, the paths' effective
    speed of sound ``c_m_s``, arrival times ``t_a_s`` (t_a = t_e + |src − x(t_a)|/c, two fixed-point steps),
    the walker there ``rx`` (n, 3), the straight distance ``d_m``, whether the free-field level could rise out
    of the noise ``heard``, the walker's speed ``speed_m_s`` and the (gain, extra path m) of tweeter and torso
    there ``hardware`` (None without hardware); each (n,) unless stated."""

    t_e_s: np.ndarray
    c_m_s: np.ndarray
    t_a_s: np.ndarray
    rx: np.ndarray
    d_m: np.ndarray
    heard: np.ndarray
    speed_m_s: np.ndarray
    hardware: tuple[np.ndarray, np.ndarray] | None


class _Emitter:
    """Emissions through the time-varying channel: where the walker is when each arrives, its paths (with
    body and transducers), Doppler, clutter tail; the rendered samples. Built from the recording's true clock
    (``true_start``, ``fs_true``); draws the air from ``stream_rng(seed | crew, "audio", ...)``."""

    def __init__(self, site, trajectory, seed, cfg, air: AirConfig, crew: int, hardware, true_start, fs_true,
                 n_total):
        self.site, self.trajectory, self.seed, self.cfg, self.hardware = site, trajectory, seed, cfg, hardware
        self.true_start, self.fs_true, self.n_total = true_start, fs_true, n_total
        self.scene = build_scene(site, cfg.channel)
        self.air_state = Air(site, stream_rng(crew, "audio", "thermometer"), stream_rng(seed, "audio", "air"),
                             trajectory.duration_s, air)
        true_site = replace(site, atmosphere=replace(site.atmosphere, temperature_c=self.air_state.temperature_c))
        self.renderer = ChirpRenderer(true_site, cfg)
        self.renderer.c = self.c = self.air_state.mean_c()
        if hardware is not None:
            self.true_pos = true_beacon_positions(site, hardware)
            self.delays = beacon_delays_s(site, hardware)
            self.jitter_rng = stream_rng(seed, "audio", "emission_jitter")
            self.axes = beacon_axes(site, hardware.n_tweeters)
        else:
            self.true_pos = {b.id: np.array([b.east_m, b.north_m, b.up_m]) for b in site.beacons}
            self.delays = {b.id: 0.0 for b in site.beacons}
            self.jitter_rng, self.axes = None, None
        self.sl_db = site.acoustic.source_level_db
        self.noise_floor_db = cfg.inband_noise_db_spl
        self.level_scale = 10.0 ** ((self.sl_db - cfg.full_scale_db_spl) / 20.0)
        self.v_east, self.v_north = _velocity_table(trajectory)
        self.alpha_min: dict[ChirpSpec, float] = {}
        self.clutter_cache: dict[tuple[int, int], float] = {}
        self.path_cache: dict[tuple, PathSet] = {}     # a static receiver sees the same geometry every frame
        self.n_emissions = self.n_rendered = 0

    def render_batch(self, batch: list, recorder: _Recorder, truth: "_TruthWriter", bar) -> None:
        """Render a batch of emissions (t_sched_s, beacon_id, index, beacon, spec) in order: flush the recorder
        up to each one, add its samples, write its truth row."""
        t_sched = np.array([e[0] for e in batch])
        bids = [e[1] for e in batch]
        src = np.array([self.true_pos[bid] for bid in bids])
        t_e = t_sched      # the schedule slot (the truth file's key); t_e the true emission instant
        if self.jitter_rng is not None:  # the chirp leaves the tweeter late by the beacon's latency and jitter
            t_e = (t_sched + np.array([self.delays[bid] for bid in bids])
                   + self.hardware.emission_jitter_s * self.jitter_rng.standard_normal(len(batch)))
        arr = self.arrivals(t_e, src, bids, [e[4] for e in batch])
        heard = self.prepare(arr, bids, src, [e[4] for e in batch])
        emissions = [got[0] for got in heard if got is not None]
        if emissions:
            # the tail realisation belongs to the place (1 cm grid): a static receiver hears the same tail every
            # frame, a walker (≥ 1 m between a beacon's chirps, ≫ λ/2 ≈ 8 mm) an independent one
            rx = np.array([got[4] for got in heard if got is not None])
            keys = np.column_stack([[bids[j] for j, got in enumerate(heard) if got is not None],
                                    np.rint(rx * 100.0).astype(np.int64) + 10**8])
            rngs = stream_rngs(self.seed, ("audio", "tail"), keys)
            emissions = [(*e[:5], rng, e[6]) for e, rng in zip(emissions, rngs)]
        segments = iter(self.renderer.render_many(emissions))
        # audio seconds done, and the device sample up to which the recorder may write, at each emission
        done_s = np.minimum(np.maximum(t_e - self.true_start, 0.0), self.trajectory.duration_s).astype(int).tolist()
        flush_at = ((t_e - self.true_start) * self.fs_true - _PRE_SAMPLES - 2).tolist()
        for j, (t_s, bid, _, beacon, spec) in enumerate(batch):
            self.n_emissions += 1
            bar.set(done_s[j])
            if flush_at[j] >= recorder.next_due:
                recorder.flush_until(flush_at[j])
            if heard[j] is None:
                continue
            start, seg = next(segments)
            _, paths, t_a, first_sample, rx, eta = heard[j]
            recorder.acc.add(start, seg)
            self.n_rendered += 1
            if first_sample >= 0:
                truth.row(bid, beacon.slot, t_s, t_a, first_sample, PATH_KINDS[paths.kind[0]], paths.length_m[0],
                          paths.direct_m, int(paths.los), rx,
                          _first_path_db_spl(paths, spec, self.sl_db, self.renderer), eta)

    def paths_at(self, bid: int, src: np.ndarray, rx: np.ndarray, rx_key: list | None = None) -> PathSet:
        """The channel's paths from beacon ``bid`` at ``src`` to ``rx``, remembered by ``rx`` rounded to 0.1 mm
        (``rx_key``: ``np.round(rx, 4).tolist()``, when the caller has it)."""
        key = (bid, *(np.round(rx, 4).tolist() if rx_key is None else rx_key))
        if key not in self.path_cache:
            if len(self.path_cache) > 512:
                self.path_cache.clear()
            self.path_cache[key] = channel_paths(self.scene, src, rx)
        return self.path_cache[key]

    def arrivals(self, t_e: np.ndarray, src: np.ndarray, bids: list[int], specs: list[ChirpSpec]) -> _Arrivals:
        """The straight-line first look at emissions of beacons ``bids`` at true times ``t_e`` (n,) from
        ``src`` (n, 3)."""
        trajectory = self.trajectory
        for spec in set(specs) - set(self.alpha_min):
            self.alpha_min[spec] = float(absorption_db_per_m(spec.f0_hz, self.site.atmosphere))
        alpha = np.array([self.alpha_min[spec] for spec in specs])
        # receiver position when the first path arrives: t_a = t_e + L(x(t_a))/c, straight line first
        c_e = self.air_state.c_eff(t_e, src, _positions_at(trajectory, t_e))  # effective speed of each path
        t_a = t_e
        for _ in range(2):
            t_a = t_e + _norms(src - _positions_at(trajectory, t_a)) / c_e
        rx = _positions_at(trajectory, t_a)
        d = _norms(src - rx)
        # whether even in free field it could rise out of the noise
        floor_db = self.noise_floor_db - self.cfg.skip_margin_db
        heard = self.sl_db - 20.0 * np.log10(np.maximum(d, 1e-3)) - alpha * d >= floor_db
        return _Arrivals(t_e_s=t_e, c_m_s=c_e, t_a_s=t_a, rx=rx, d_m=d, heard=heard,
                         speed_m_s=np.interp(t_a, trajectory.t_s, trajectory.speed_m_s),
                         hardware=self.hardware_factors(t_e, src, rx, bids, specs))

    def hardware_factors(self, t_e: np.ndarray, src: np.ndarray, rx: np.ndarray, bids: list[int],
                         specs: list[ChirpSpec]) -> tuple[np.ndarray, np.ndarray] | None:
        """(gain, extra path m), each (n,), of tweeter and torso for emissions at ``t_e`` from ``src`` heard at
        ``rx``; None without hardware."""
        if self.hardware is None:
            return None
        traj = self.trajectory
        i = np.minimum(np.searchsorted(traj.t_s, t_e), len(traj.t_s) - 1)
        f_c = np.array([0.5 * (spec.f0_hz + spec.f1_hz) for spec in specs])
        return _hardware_factors(src, rx, np.array([self.axes[bid] for bid in bids]), f_c, self.renderer.c,
                                 traj.heading_rad[i], self.hardware)

    def prepare(self, arr: _Arrivals, bids: list[int], src: np.ndarray, specs: list[ChirpSpec]) -> list:
        """Per emission of the batch ``arr``: (the renderer's arguments, paths, t_a, first_sample, rx, η), or None
        when it cannot be heard (below the noise even in free field, no path, outside the recording). The
        arguments' tail generator is None: :meth:`render_batch` seeds the batch's at once. The paths per
        emission; arrival, level, first sample and Doppler factor as arrays over the emissions with paths (each
        value by the operations one emission alone would take)."""
        trajectory, cfg, c = self.trajectory, self.cfg, self.c
        sl_db, noise_floor_db, fs = self.sl_db, self.noise_floor_db, cfg.fs_hz
        out: list = [None] * len(bids)
        live, live_paths, live_rx = [], [], []
        rx_keys = np.round(arr.rx, 4).tolist()
        for j in np.flatnonzero(arr.heard).tolist():
            bid, spec, rx = bids[j], specs[j], arr.rx[j]
            c_e = float(arr.c_m_s[j])
            paths = self.paths_at(bid, src[j], rx, rx_keys[j])
            moved = bool(len(paths) and float(arr.speed_m_s[j]) * (paths.length_m[0] - float(arr.d_m[j])) / c_e
                         > 0.005)
            if moved:
                # a detour delays the arrival long enough for the walker to move: look again there
                rx = _positions_at(trajectory, np.array([float(arr.t_e_s[j]) + paths.length_m[0] / c_e]))[0]
                paths = self.paths_at(bid, src[j], rx)
            if len(paths) == 0:
                continue
            if arr.hardware is not None:
                gain, extra = arr.hardware[0][j], arr.hardware[1][j]
                if moved:
                    (gain,), (extra,) = self.hardware_factors(arr.t_e_s[j:j + 1], src[j][None], rx[None], [bid],
                                                              [spec])
                if gain != 1.0 or extra != 0.0:
                    paths = PathSet(kind=paths.kind, length_m=paths.length_m + extra, gain=paths.gain * gain,
                                    detour_m=paths.detour_m, box=paths.box, direct_m=paths.direct_m, los=paths.los)
            live.append(j), live_paths.append(paths), live_rx.append(rx)
        if not live:
            return out
        idx = np.array(live)
        first_m = np.array([paths.length_m[0] for paths in live_paths])
        alpha = np.array([self.alpha_min[specs[j]] for j in live])
        t_a = arr.t_e_s[idx] + first_m / arr.c_m_s[idx]
        log_gain = np.array([math.log10(max(paths.gain.max(), 1e-12)) for paths in live_paths])
        best_db = sl_db + 20.0 * log_gain - alpha * first_m
        first_sample = (t_a - self.true_start) * self.fs_true
        rx = np.array(live_rx)
        eta = np.ones(len(live))
        if cfg.doppler:       # moving observer: η = 1 + v·u/c, u the unit vector to the beacon
            d = src[idx] - rx
            u = d / np.maximum(_norms(d), 1e-6)[:, None]
            v = np.column_stack([np.interp(t_a, trajectory.t_s, self.v_east),
                                 np.interp(t_a, trajectory.t_s, self.v_north), np.zeros(len(live))])
            eta = 1.0 + np.vecdot(v, u) / c
        floor_db = noise_floor_db - cfg.skip_margin_db
        for r, j in enumerate(live):
            if best_db[r] < floor_db or not -fs <= first_sample[r] < self.n_total:
                continue
            cell = (int(math.floor(rx[r, 0])), int(math.floor(rx[r, 1])))      # clutter on a 1 m grid
            if cell not in self.clutter_cache:
                self.clutter_cache[cell] = clutter_index(self.scene, np.array([cell[0] + 0.5, cell[1] + 0.5]))
            paths, fs_r, eta_r = live_paths[r], float(first_sample[r]), float(eta[r])
            out[j] = ((paths, specs[j], eta_r, fs_r, self.clutter_cache[cell], None, self.level_scale), paths,
                      float(t_a[r]), fs_r, live_rx[r], eta_r)
        return out


def render_audio(site: Site, trajectory: Trajectory, seed: int, wav_path,
                 cfg: AudioConfig | None = None, truth_path=None, progress: bool = False,
                 air: AirConfig = AirConfig(), crew_seed: int | None = None,
                 hardware: HardwareConfig | None = HardwareConfig()) -> AudioResult:
    """Simulate the recording along ``trajectory`` into the int16 WAV at ``wav_path`` (atomic).

    The per-emission truth goes to ``truth_path`` (``audio_truth.csv``, atomic)
    as it is produced, or, without a path, into ``AudioResult.truth_csv``.
    Randomness comes only from ``stream_rng(seed, "audio", ...)``: the same
    seed gives the same bytes, whatever ``block_samples``. With a truth path,
    memory is bounded by the block size and a batch of emissions (128, rendered together: their arrivals
    vectorised, their FFTs batched; a few MB), not the recording's length.
    ``progress`` shows audio seconds rendered on stderr: a bar on a terminal, plain lines otherwise.
    ``air``: the true air (:mod:`simulation.acoustic.air`: the crew's thermometer error drawn from
    ``crew_seed`` (default ``seed``), hot air over transformers, humidity, wind); the site's stated
    temperature is what the receiver reads. ``hardware``: beacon survey errors, emission delays and
    jitter, the recorder's microphone/codec response (:mod:`simulation.acoustic.hardware`); None: ideal.
    """
    cfg = cfg or AudioConfig()
    clock_rng = stream_rng(seed, "audio", "clock")
    true_start = cfg.start_s + float(clock_rng.uniform(-1.0, 1.0)) * cfg.start_uncertainty_s
    drift_ppm = float(clock_rng.uniform(-1.0, 1.0)) * cfg.clock_drift_ppm
    fs_true = cfg.fs_hz * (1.0 + drift_ppm * 1e-6)        # device samples per second of true time
    n_total = int(math.floor(trajectory.duration_s * cfg.fs_hz))
    crew = seed if crew_seed is None else crew_seed
    emitter = _Emitter(site, trajectory, seed, cfg, air, crew, hardware, true_start, fs_true, n_total)
    codec = CodecFilter(cfg.fs_hz, stream_rng(crew, "audio", "codec"), hardware) if hardware is not None else None
    ambient = AmbientNoise(site, trajectory, seed, cfg, true_start, fs_true)
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(atomic_path(wav_path, suffix=".wav"))
        out = stack.enter_context(sf.SoundFile(tmp, "w", samplerate=cfg.fs_hz, channels=1, subtype="PCM_16",
                                               format="WAV"))
        if truth_path is None:
            truth_file = io.StringIO()
        else:
            truth_file = stack.enter_context(open(stack.enter_context(atomic_path(truth_path)), "w", newline=""))
        truth = _TruthWriter(truth_file)
        recorder = _Recorder(out, cfg.block_samples, n_total, ambient, codec)
        bar = stack.enter_context(Progress(int(math.ceil(trajectory.duration_s)), "audio", unit="s",
                                           enabled=progress))
        for batch in _emission_batches(site, trajectory.start_utc, true_start - 0.5, true_start + n_total / fs_true):
            emitter.render_batch(batch, recorder, truth, bar)
        recorder.flush_until(float(n_total))
        text = truth_file.getvalue() if truth_path is None else None
    return AudioResult(true_start_s=true_start, drift_ppm=drift_ppm, n_samples=n_total,
                       n_emissions=emitter.n_emissions, n_rendered=emitter.n_rendered, n_clipped=recorder.n_clipped,
                       truth_csv=text)


class _Recorder:
    """The device's sample stream: emissions summed in a rolling buffer, the ambient added chunk by chunk
    (click tails carried into the next chunk), the codec, rounding to int16; finished blocks go to ``out``."""

    def __init__(self, out, block_samples: int, n_total: int, ambient: AmbientNoise, codec: CodecFilter | None):
        self.out, self.ambient, self.codec, self.n_total = out, ambient, codec, n_total
        self.acc = _Accumulator(block_samples, n_total)
        self.next_chunk = 0
        self.carry = np.zeros(0)
        self.n_clipped = 0

    @property
    def next_due(self) -> float:
        """The device sample at which the next block ends (inf when all are written): flush_until writes
        nothing before it."""
        acc = self.acc
        return acc.base + min(acc.block, self.n_total - acc.base) if acc.base < self.n_total else math.inf

    def flush_until(self, sample: float) -> None:
        """Write every block that ends at or before device sample ``sample``."""
        acc, n_total = self.acc, self.n_total
        while acc.base < n_total and acc.base + min(acc.block, n_total - acc.base) <= sample:
            n = min(acc.block, n_total - acc.base)
            pieces = []
            while self.next_chunk * CHUNK_SAMPLES < acc.base + n:        # ambient of the chunks of this block
                m = min(CHUNK_SAMPLES, n_total - self.next_chunk * CHUNK_SAMPLES)
                amb = self.ambient.chunk(self.next_chunk, m)
                amb[:len(self.carry)] += self.carry                     # click tails from the previous chunk
                pieces.append(amb[:m])
                self.carry = amb[m:]
                self.next_chunk += 1
            mixed = acc.pop_block() + np.concatenate(pieces)
            if self.codec is not None:
                mixed = self.codec(mixed)
            pcm, clipped = _to_pcm16(mixed)
            self.n_clipped += clipped
            self.out.write(pcm)


@njit(cache=True)
def _to_pcm16(x: np.ndarray) -> tuple[np.ndarray, int]:
    """Full-scale floats to int16 PCM: round(x·32767) to the nearest (ties to even), clipped to the int16 range;
    and how many samples were over full scale (|round(x·32767)| > 32767). One pass."""
    out = np.empty(len(x), np.int16)
    clipped = 0
    for i in range(len(x)):
        q = np.rint(x[i] * 32767.0)
        if abs(q) > 32767.0:
            clipped += 1
        out[i] = np.int16(min(max(q, -32768.0), 32767.0))
    return out, clipped


def _hardware_factors(src: np.ndarray, rx: np.ndarray, axes: np.ndarray, f_c_hz: np.ndarray, c: float,
                      heading_rad: np.ndarray, hw: HardwareConfig) -> tuple[np.ndarray, np.ndarray]:
    """(pressure gain, extra path m), each (n,), of the tweeter's directivity and the wearer's torso for
    emissions from ``src`` (n, 3) heard at ``rx`` (n, 3) by the direct bearing (:mod:`simulation.acoustic.hardware`).

    axes : (n, k, 3) unit axes of each emitting beacon's k tweeters (the best-aimed one radiates); f_c_hz : (n,)
    band centres; heading_rad : (n,) the wearer's heading (held through stops, so a standing wearer shadows too).
    """
    d = rx - src
    dist = np.sqrt(np.vecdot(d, d))
    gain = np.ones(len(d))
    if hw.piston_radius_m > 0:
        cos_off = (axes @ d[:, :, None])[..., 0] / np.where(dist > 1e-6, dist, 1.0)[:, None]      # (n, k)
        theta = np.arccos(np.clip(cos_off, -1.0, 1.0))     # off each tweeter's axis
        piston = np.max(piston_directivity(theta, f_c_hz[:, None], hw.piston_radius_m, c, hw.piston_floor_db), axis=1)
        gain = np.where(dist > 1e-6, gain * piston, gain)
    bearing = np.arctan2(-d[:, 0], -d[:, 1])  # from the receiver towards the beacon, from north clockwise
    extra, loss_db = torso_shadow(bearing, heading_rad, hw)
    return gain * 10.0 ** (-loss_db / 20.0), extra


@functools.lru_cache(maxsize=64)
def _alpha_centre_db_per_m(spec: ChirpSpec, atmosphere) -> float:
    """ISO 9613-1 α at a chirp's band centre (one per beacon band and air, not per emission)."""
    return float(absorption_db_per_m(0.5 * (spec.f0_hz + spec.f1_hz), atmosphere))


def _first_path_db_spl(paths: PathSet, spec: ChirpSpec, source_level_db: float,
                       renderer: ChirpRenderer) -> float:
    """Level of the first path at the band centre: SL + 20·log10(g) − α(f_c)·L − ΔL_Maekawa(f_c), dB SPL."""
    f_c = 0.5 * (spec.f0_hz + spec.f1_hz)
    level = (source_level_db + 20.0 * math.log10(max(float(paths.gain[0]), 1e-12))
             - _alpha_centre_db_per_m(spec, renderer.atmosphere) * float(paths.length_m[0]))
    if paths.kind[0] == 3:
        level -= float(maekawa_loss_db(fresnel_number(paths.detour_m[0], f_c, renderer.c)))
    return level


class _TruthWriter:
    """``audio_truth.csv``: one row per recorded emission (true first arrival, for evaluation only)."""

    HEADER = ("beacon_id", "slot", "emit_t_s", "arrival_t_s", "arrival_sample", "first_path", "first_path_m",
              "direct_m", "los", "rx_east_m", "rx_north_m", "rx_up_m", "first_path_db_spl", "doppler")

    def __init__(self, stream):
        self._stream = stream
        csv.writer(stream, lineterminator="\n").writerow(self.HEADER)

    def row(self, beacon_id, slot, emit_t_s, arrival_t_s, arrival_sample, first_path, first_path_m, direct_m, los,
            rx, level_db_spl, doppler) -> None:
        """One row, as ``csv.writer`` writes it (no field holds a comma, quote or newline: none is quoted)."""
        self._stream.write(f"{beacon_id},{slot},{emit_t_s:.9f},{arrival_t_s:.9f},{arrival_sample:.3f},{first_path},"
                           f"{first_path_m:.4f},{direct_m:.4f},{los},{rx[0]:.3f},{rx[1]:.3f},{rx[2]:.3f},"
                           f"{level_db_spl:.1f},{doppler:.6f}\n")


def write_audio(ctx: StreamContext) -> dict:
    """Stream writer: ``audio.wav`` and ``audio_truth.csv`` into ``ctx.out_dir``; returns the ``[audio]`` table.

    Options (all on by default): ``acoustic_air`` (wind, warm air, humidity and the crew's thermometer error,
    :mod:`simulation.acoustic.air`), ``acoustic_hardware`` (beacon survey errors, emission delays, codec;
    :mod:`simulation.acoustic.hardware`): each true/false, or a table of
    :class:`~simulation.acoustic.air.AirConfig` / :class:`~simulation.acoustic.hardware.HardwareConfig` fields
    (e.g. ``{"wind_max_m_s": 0.0, "gust_floor_m_s": 0.0}``: every other term as default). Receiver tests that
    check one equation switch them off; ``bench/acoustic_error_causes.py`` switches them one at a time.
    """
    cfg = AudioConfig.from_options(ctx.options)
    air = _config_option(ctx.options, "acoustic_air", AirConfig)
    hardware = _config_option(ctx.options, "acoustic_hardware", HardwareConfig)
    render_audio(ctx.site, ctx.trajectory, ctx.seed, ctx.out_dir / "audio.wav", cfg,
                 truth_path=ctx.out_dir / "audio_truth.csv",
                 progress=ctx.kind == "walk" and bool(ctx.options.get("progress", True)),
                 air=air if air is not None else AirConfig(enabled=False), hardware=hardware,
                 crew_seed=ctx.person_seed)
    return {"audio": {"file": "audio.wav", "fs_hz": cfg.fs_hz, "start_s": cfg.start_s,
                      "start_uncertainty_s": cfg.start_uncertainty_s}}


def _config_option(options: dict, name: str, cls):
    """``options[name]`` as a config: true (default) → ``cls()``, false → None, a table → ``cls(**table)``."""
    value = options.get(name, True)
    if isinstance(value, bool):
        return cls() if value else None
    if not isinstance(value, dict):
        raise ConfigError(f"option {name} must be true, false or a table of {cls.__name__} fields, got {value!r}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(value) - known)
    if unknown:
        raise ConfigError(f"option {name}: unknown key(s) {unknown}; known: {sorted(known)}")
    return cls(**value)
