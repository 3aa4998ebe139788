"""``audio.wav``: every beacon's chirps through the time-varying channel, plus noise, as a 48 kHz int16 WAV.

Per chirp emission (a beacon's slot in a TDMA frame, :mod:`simulation.acoustic.chirp`)
the channel is evaluated once, static over the 10 ms chirp (the walker moves
≈ 1.5 cm), at the receiver's position at the moment the first path arrives
(found by fixed-point iteration t_a = t_e + L(x(t_a))/c), and rendered by
:class:`simulation.acoustic.synthesis.ChirpRenderer`; ambient noise, hum and corona
clicks come from :class:`simulation.acoustic.synthesis.AmbientNoise`. Emissions whose
free-field level could not rise out of the noise are skipped. Samples are
summed in a rolling buffer and written block by block, so memory stays
bounded for any length of walk.

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
import heapq
import io
import math
from dataclasses import dataclass, fields, replace
from typing import Iterator

import numpy as np
import soundfile as sf

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
from simulation.rng import stream_rng
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

    def add(self, start: int, seg: np.ndarray) -> None:
        lo, hi = max(start, self.base), min(start + len(seg), self.n_total)
        if hi <= lo:
            return
        need = hi - self.base
        if need > len(self.buf):
            self.buf = np.concatenate([self.buf, np.zeros(need - len(self.buf) + self.block)])
        self.buf[lo - self.base:hi - self.base] += seg[lo - start:hi - start]

    def pop_block(self) -> np.ndarray:
        n = min(self.block, self.n_total - self.base)
        out = self.buf[:n].copy()
        self.buf = np.concatenate([self.buf[n:], np.zeros(n)])
        self.base += n
        return out


def _position_at(traj: Trajectory, t_s: float) -> np.ndarray:
    return np.array([np.interp(t_s, traj.t_s, traj.east_m), np.interp(t_s, traj.t_s, traj.north_m),
                     np.interp(t_s, traj.t_s, traj.up_m)])


def _velocity_table(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal velocity (v_east, v_north), m/s, shape (n,) each, from speed and heading (from north, clockwise)."""
    return traj.speed_m_s * np.sin(traj.heading_rad), traj.speed_m_s * np.cos(traj.heading_rad)


def _emissions(site: Site, start_utc, t_begin_s: float, t_end_s: float) -> Iterator[tuple]:
    """Every (t_emit_s, beacon_id, index, beacon, spec) in [t_begin_s, t_end_s), in emission order.

    A lazy k-way merge of the beacons' schedules: memory per beacon, not per emission.
    """
    def one(b):
        spec = beacon_chirp(site, b)
        for i, t_e in enumerate(emission_times_s(site, b, start_utc, t_begin_s, t_end_s)):
            yield float(t_e), b.id, i, b, spec

    return heapq.merge(*(one(b) for b in site.beacons), key=lambda e: (e[0], e[1]))


class _Emitter:
    """One emission through the time-varying channel: where the walker is when it arrives, its paths
    (with body and transducers), Doppler, clutter tail; the rendered samples."""

    def __init__(self, site, trajectory, seed, cfg, scene, renderer, air_state, hardware, axes, true_start,
                 fs_true, n_total):
        self.site, self.trajectory, self.seed, self.cfg = site, trajectory, seed, cfg
        self.scene, self.renderer, self.air_state, self.hardware, self.axes = scene, renderer, air_state, hardware, axes
        self.true_start, self.fs_true, self.n_total = true_start, fs_true, n_total
        self.c = renderer.c
        self.sl_db = site.acoustic.source_level_db
        self.noise_floor_db = cfg.inband_noise_db_spl
        self.level_scale = 10.0 ** ((self.sl_db - cfg.full_scale_db_spl) / 20.0)
        self.v_east, self.v_north = _velocity_table(trajectory)
        self.alpha_min: dict[ChirpSpec, float] = {}
        self.clutter_cache: dict[tuple[int, int], float] = {}
        self.path_cache: dict[tuple, PathSet] = {}     # a static receiver sees the same geometry every frame

    def paths_at(self, bid: int, src: np.ndarray, rx: np.ndarray) -> PathSet:
        key = (bid, *np.round(rx, 4).tolist())
        if key not in self.path_cache:
            if len(self.path_cache) > 512:
                self.path_cache.clear()
            self.path_cache[key] = channel_paths(self.scene, src, rx)
        return self.path_cache[key]

    def render(self, t_e: float, bid: int, src: np.ndarray, spec: ChirpSpec):
        """(start, samples, paths, t_a, first_sample, rx, η) of the emission at true time ``t_e``, or None
        when it cannot be heard (below the noise even in free field, no path, outside the recording)."""
        site, trajectory, cfg, air_state = self.site, self.trajectory, self.cfg, self.air_state
        sl_db, noise_floor_db, fs = self.sl_db, self.noise_floor_db, cfg.fs_hz
        if spec not in self.alpha_min:
            self.alpha_min[spec] = float(absorption_db_per_m(spec.f0_hz, site.atmosphere))
        alpha = self.alpha_min[spec]
        # receiver position when the first path arrives: t_a = t_e + L(x(t_a))/c, straight line first
        t_a = t_e
        c_e = air_state.c_eff(t_e, src, _position_at(trajectory, t_e))  # effective speed of this path
        for _ in range(2):
            t_a = t_e + float(np.linalg.norm(src - _position_at(trajectory, t_a))) / c_e
        rx = _position_at(trajectory, t_a)
        d = float(np.linalg.norm(src - rx))
        if sl_db - 20.0 * math.log10(max(d, 1e-3)) - alpha * d < noise_floor_db - cfg.skip_margin_db:
            return None          # even in free field it could not rise out of the noise
        paths = self.paths_at(bid, src, rx)
        speed = float(np.interp(t_a, trajectory.t_s, trajectory.speed_m_s))
        if len(paths) and speed * (paths.length_m[0] - d) / c_e > 0.005:
            # a detour delays the arrival long enough for the walker to move: look again there
            rx = _position_at(trajectory, t_e + paths.length_m[0] / c_e)
            paths = self.paths_at(bid, src, rx)
        if len(paths) == 0:
            return None
        if self.hardware is not None:
            paths = _hardware_paths(paths, src, rx, self.axes[bid], spec, self.renderer.c, trajectory, t_e,
                                    self.hardware)
        t_a = t_e + paths.length_m[0] / c_e
        best_db = sl_db + 20.0 * math.log10(max(paths.gain.max(), 1e-12)) - alpha * paths.length_m[0]
        first_sample = (t_a - self.true_start) * self.fs_true
        if best_db < noise_floor_db - cfg.skip_margin_db or not -fs <= first_sample < self.n_total:
            return None
        eta = 1.0
        if cfg.doppler:       # moving observer: η = 1 + v·u/c, u the unit vector to the beacon
            u = (src - rx) / max(np.linalg.norm(src - rx), 1e-6)
            v = np.array([np.interp(t_a, trajectory.t_s, self.v_east), np.interp(t_a, trajectory.t_s, self.v_north),
                          0.0])
            eta = 1.0 + float(v @ u) / self.c
        cell = (int(math.floor(rx[0])), int(math.floor(rx[1])))      # clutter on a 1 m grid
        if cell not in self.clutter_cache:
            self.clutter_cache[cell] = clutter_index(self.scene, np.array([cell[0] + 0.5, cell[1] + 0.5]))
        # the tail realisation belongs to the place (1 cm grid): a static receiver hears the same tail every
        # frame, a walker (≥ 1 m between a beacon's chirps, ≫ λ/2 ≈ 8 mm) an independent one
        rng = stream_rng(self.seed, "audio", "tail", bid, *(int(round(x_m * 100.0)) + 10**8 for x_m in rx))
        start, seg = self.renderer.render(paths, spec, eta, first_sample, self.clutter_cache[cell], rng,
                                          self.level_scale)
        return start, seg, paths, t_a, first_sample, rx, eta


def render_audio(site: Site, trajectory: Trajectory, seed: int, wav_path,
                 cfg: AudioConfig | None = None, truth_path=None, progress: bool = False,
                 air: AirConfig = AirConfig(), crew_seed: int | None = None,
                 hardware: HardwareConfig | None = HardwareConfig()) -> AudioResult:
    """Simulate the recording along ``trajectory`` into the int16 WAV at ``wav_path`` (atomic).

    The per-emission truth goes to ``truth_path`` (``audio_truth.csv``, atomic)
    as it is produced, or, without a path, into ``AudioResult.truth_csv``.
    Randomness comes only from ``stream_rng(seed, "audio", ...)``: the same
    seed gives the same bytes, whatever ``block_samples``. With a truth path,
    memory is bounded by the block size, not the recording's length.
    ``progress`` shows audio seconds rendered on stderr: a bar on a terminal, plain lines otherwise.
    ``air``: the true air (:mod:`simulation.acoustic.air`: the crew's thermometer error drawn from
    ``crew_seed`` (default ``seed``), hot air over transformers, humidity, wind); the site's stated
    temperature is what the receiver reads. ``hardware``: beacon survey errors, emission delays and
    jitter, the recorder's microphone/codec response (:mod:`simulation.acoustic.hardware`); None: ideal.
    """
    cfg = cfg or AudioConfig()
    fs = cfg.fs_hz
    clock_rng = stream_rng(seed, "audio", "clock")
    true_start = cfg.start_s + float(clock_rng.uniform(-1.0, 1.0)) * cfg.start_uncertainty_s
    drift_ppm = float(clock_rng.uniform(-1.0, 1.0)) * cfg.clock_drift_ppm
    fs_true = fs * (1.0 + drift_ppm * 1e-6)        # device samples per second of true time
    n_total = int(math.floor(trajectory.duration_s * fs))
    t_end = true_start + n_total / fs_true
    scene = build_scene(site, cfg.channel)
    air_state = Air(site, stream_rng(seed if crew_seed is None else crew_seed, "audio", "thermometer"),
                    stream_rng(seed, "audio", "air"), trajectory.duration_s, air)
    true_site = replace(site, atmosphere=replace(site.atmosphere, temperature_c=air_state.temperature_c))
    renderer = ChirpRenderer(true_site, cfg)
    renderer.c = air_state.mean_c()
    if hardware is not None:
        true_pos = true_beacon_positions(site, hardware)
        delays = beacon_delays_s(site, hardware)
        jitter_rng = stream_rng(seed, "audio", "emission_jitter")
        codec = CodecFilter(fs, stream_rng(seed if crew_seed is None else crew_seed, "audio", "codec"), hardware)
        axes = beacon_axes(site, hardware.n_tweeters)
    else:
        true_pos = {b.id: np.array([b.east_m, b.north_m, b.up_m]) for b in site.beacons}
        delays = {b.id: 0.0 for b in site.beacons}
        jitter_rng, codec = None, None
    ambient = AmbientNoise(site, trajectory, seed, cfg, true_start, fs_true)
    sl_db = site.acoustic.source_level_db
    emitter = _Emitter(site, trajectory, seed, cfg, scene, renderer, air_state, hardware,
                       axes if hardware is not None else None, true_start, fs_true, n_total)
    emissions = _emissions(site, trajectory.start_utc, true_start - 0.5, t_end)
    acc = _Accumulator(cfg.block_samples, n_total)
    counts = {"emissions": 0, "rendered": 0, "clipped": 0}
    next_chunk = 0
    carry = np.zeros(0)

    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(atomic_path(wav_path, suffix=".wav"))
        out = stack.enter_context(sf.SoundFile(tmp, "w", samplerate=fs, channels=1, subtype="PCM_16", format="WAV"))
        if truth_path is None:
            truth_file = io.StringIO()
        else:
            truth_file = stack.enter_context(open(stack.enter_context(atomic_path(truth_path)), "w", newline=""))
        truth = _TruthWriter(truth_file)

        def flush_until(sample: float) -> None:
            nonlocal next_chunk, carry
            while acc.base < n_total and acc.base + min(acc.block, n_total - acc.base) <= sample:
                n = min(acc.block, n_total - acc.base)
                pieces = []
                while next_chunk * CHUNK_SAMPLES < acc.base + n:        # ambient of the chunks of this block
                    m = min(CHUNK_SAMPLES, n_total - next_chunk * CHUNK_SAMPLES)
                    amb = ambient.chunk(next_chunk, m)
                    amb[:len(carry)] += carry                     # click tails from the previous chunk
                    pieces.append(amb[:m])
                    carry = amb[m:]
                    next_chunk += 1
                mixed = acc.pop_block() + np.concatenate(pieces)
                if codec is not None:
                    mixed = codec(mixed)
                q = np.rint(mixed * 32767.0)
                counts["clipped"] += int(np.count_nonzero(np.abs(q) > 32767))
                out.write(np.clip(q, -32768, 32767).astype(np.int16))

        bar = stack.enter_context(Progress(int(math.ceil(trajectory.duration_s)), "audio", unit="s",
                                           enabled=progress))
        for t_e, bid, i, b, spec in emissions:
            counts["emissions"] += 1
            t_sched = t_e  # the schedule slot (the truth file's key); t_e becomes the true emission instant
            if jitter_rng is not None:  # the chirp leaves the tweeter late by the beacon's latency and jitter
                t_e = t_e + delays[bid] + hardware.emission_jitter_s * float(jitter_rng.standard_normal())
            done = int(min(max(t_e - true_start, 0.0), trajectory.duration_s))
            bar.set(done)
            flush_until((t_e - true_start) * fs_true - _PRE_SAMPLES - 2)
            got = emitter.render(t_e, bid, true_pos[bid], spec)
            if got is None:
                continue
            start, seg, paths, t_a, first_sample, rx, eta = got
            acc.add(start, seg)
            counts["rendered"] += 1
            if first_sample >= 0:
                truth.row(bid, b.slot, t_sched, t_a, first_sample, PATH_KINDS[paths.kind[0]], paths.length_m[0],
                          paths.direct_m, int(paths.los), rx, _first_path_db_spl(paths, spec, sl_db, renderer), eta)
        flush_until(float(n_total))
        text = truth_file.getvalue() if truth_path is None else None
    return AudioResult(true_start_s=true_start, drift_ppm=drift_ppm, n_samples=n_total,
                       n_emissions=counts["emissions"],
                       n_rendered=counts["rendered"], n_clipped=counts["clipped"], truth_csv=text)


def _hardware_paths(paths: PathSet, src: np.ndarray, rx: np.ndarray, axis: np.ndarray, spec: ChirpSpec, c: float,
                    trajectory: Trajectory, t_s: float, hw: HardwareConfig) -> PathSet:
    """Apply the tweeter's directivity and the wearer's torso to every path of one emission (by the direct
    bearing; :mod:`simulation.acoustic.hardware`)."""
    d = rx - src
    dist = float(np.linalg.norm(d))
    gain = 1.0
    if hw.piston_radius_m > 0 and dist > 1e-6:
        theta = np.arccos(np.clip(axis @ d / dist, -1.0, 1.0))     # off each tweeter's axis
        gain *= float(np.max(piston_directivity(theta, 0.5 * (spec.f0_hz + spec.f1_hz), hw.piston_radius_m, c,
                                                hw.piston_floor_db)))
    i = min(int(np.searchsorted(trajectory.t_s, t_s)), len(trajectory.t_s) - 1)
    bearing = math.atan2(-d[0], -d[1])  # from the receiver towards the beacon, from north clockwise
    # the heading is held through stops, so a standing wearer shadows too
    extra, loss_db = torso_shadow(bearing, float(trajectory.heading_rad[i]), hw)
    gain *= 10.0 ** (-loss_db / 20.0)
    if gain == 1.0 and extra == 0.0:
        return paths
    return replace(paths, length_m=paths.length_m + extra, gain=paths.gain * gain)


def _first_path_db_spl(paths: PathSet, spec: ChirpSpec, source_level_db: float,
                       renderer: ChirpRenderer) -> float:
    """Level of the first path at the band centre: SL + 20·log10(g) − α(f_c)·L − ΔL_Maekawa(f_c), dB SPL."""
    f_c = 0.5 * (spec.f0_hz + spec.f1_hz)
    level = (source_level_db + 20.0 * math.log10(max(float(paths.gain[0]), 1e-12))
             - float(absorption_db_per_m(f_c, renderer.atmosphere)) * float(paths.length_m[0]))
    if paths.kind[0] == 3:
        level -= float(maekawa_loss_db(fresnel_number(paths.detour_m[0], f_c, renderer.c)))
    return level


class _TruthWriter:
    """``audio_truth.csv``: one row per recorded emission (true first arrival, for evaluation only)."""

    HEADER = ("beacon_id", "slot", "emit_t_s", "arrival_t_s", "arrival_sample", "first_path", "first_path_m",
              "direct_m", "los", "rx_east_m", "rx_north_m", "rx_up_m", "first_path_db_spl", "doppler")

    def __init__(self, stream):
        self._w = csv.writer(stream, lineterminator="\n")
        self._w.writerow(self.HEADER)

    def row(self, beacon_id, slot, emit_t_s, arrival_t_s, arrival_sample, first_path, first_path_m, direct_m, los,
            rx, level_db_spl, doppler) -> None:
        self._w.writerow([beacon_id, slot, f"{emit_t_s:.9f}", f"{arrival_t_s:.9f}", f"{arrival_sample:.3f}",
                          first_path, f"{first_path_m:.4f}", f"{direct_m:.4f}", los, f"{rx[0]:.3f}", f"{rx[1]:.3f}",
                          f"{rx[2]:.3f}", f"{level_db_spl:.1f}", f"{doppler:.6f}"])


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
