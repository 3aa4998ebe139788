"""``audio.wav``: every beacon's chirps through the time-varying channel, plus noise, as a 48 kHz int16 WAV.

Per chirp emission (a beacon's slot in a TDMA frame, :mod:`simulation.chirp`)
the channel is evaluated once, static over the 10 ms chirp (the walker moves
≈ 1.5 cm), at the receiver's position at the moment the first path arrives
(found by fixed-point iteration t_a = t_e + L(x(t_a))/c). Each discrete path of
:func:`simulation.acoustic_channel.channel_paths` is a delayed, filtered copy of
the chirp, built in the frequency domain over the chirp's band::

    Y(f) = S_η(f) · [ Σ_p g_p · 10^(−(α(f)·L_p + ΔL_p(f))/20) · e^(−j2πf·τ_p) + T(f) ]

with S_η the chirp as heard with the Doppler factor η = 1 + v_r/c of the
receiver's closing speed on the beacon (one factor for all paths of the
emission), α(f) the ISO 9613-1 absorption (dB/m), ΔL_p Maekawa's loss of a
diffracted path, τ_p the fractional-sample delay (a phase ramp), and T(f) the
diffuse tail (:func:`simulation.acoustic_channel.tail_model`, Poisson arrivals
of Gaussian amplitude, absorbed over the direct distance). Emissions whose
free-field level could not rise above the noise floor are skipped.

Added to the sum of chirps, per block of samples (memory stays bounded for
any length of walk):

* in-band noise, white Gaussian: the acoustic ambient (``noise_db_spl``) and
  the recorder's own floor (``device_noise_dbfs``, measured on real phone audio)
  (see :class:`AudioConfig` for the level's justification);
* transformer hum (100 Hz and harmonics for a 50 Hz grid, magnetostriction)
  falling 1/r from the nearest tank — far out of band, it only tests the
  receiver's band-pass;
* corona clicks near HV equipment: a Poisson process whose rate decays with the
  distance to the nearest transformer, gantry or apparatus; each click an
  exponentially decaying broadband burst.

The receiver: its recording starts at ``start_s + U(−u, u)`` on the walk's time
base (stated ``start_s``, stated uncertainty ``u``), its sample clock runs
``drift_ppm`` fast or slow, the microphone maps ``full_scale_db_spl`` to a
full-scale sine, and samples are rounded to int16 (clipped only beyond full
scale). The true per-emission arrivals are written to ``audio_truth.csv`` for
evaluation; a receiver never reads it.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field, fields

import numpy as np
import scipy.fft as sfft
import soundfile as sf

from features.errors import ConfigError
from features.fileio import atomic_path, atomic_write_text
from features.site import Site

from .acoustic_channel import PATH_KINDS, ChannelConfig, PathSet, build_scene, channel_paths, clutter_index, tail_model
from .acoustics import absorption_db_per_m, fresnel_number, maekawa_loss_db, speed_of_sound_m_s
from .chirp import ChirpSpec, beacon_chirp, chirp_waveform, emission_times_s
from .geometry import boxes_array
from .rng import stream_rng
from .streams import StreamContext, Trajectory

__all__ = ["AudioConfig", "AudioResult", "render_audio", "write_audio", "detection_range_m"]

_HV_KINDS = ("transformer", "gantry", "equipment")
_CHUNK = 16384            # ambient noise is drawn per chunk of this many samples
_PRE_SAMPLES = 64          # segment margin before the first arrival (zero-phase filters smear both ways)
_POST_SAMPLES = 64


@dataclass(frozen=True)
class AudioConfig:
    """Receiver, noise and rendering parameters of the audio stream.

    noise_db_spl : acoustic ambient noise within ``noise_band_hz``, dB SPL.
        35 dB: outdoors at 17–23 kHz wind in equipment, gravel steps and corona
        hiss give broadband noise (transformer hum, 60–75 dB(A), lies below
        2 kHz). An assumed level, not a measurement.
    device_noise_dbfs : the recorder's own noise (microphone, preamp, ADC)
        within ``noise_band_hz``, dB re. full scale squared (mean square of
        samples scaled to ±1). −63 dB is measured: the median over the five
        Galaxy S3 recordings in ../shared/data/audio_ultrasense of the Welch
        PSD in 17–19.5 and 20.5–22 kHz (clear of their 20 kHz tone) times 6 kHz
        (−62.3 … −63.3 dB). With ``full_scale_db_spl`` = 110 it equals 50 dB SPL
        at the microphone and dominates the ambient term, which puts the
        free-field detection range near 47 m (:func:`detection_range_m`).
    full_scale_db_spl : SPL of a full-scale sine (RMS): 110 dB, i.e. a 120 dB
        SPL AOP microphone with 10 dB of recording gain.
    start_s, start_uncertainty_s : the stated audio start on the walk's time
        base and its uncertainty; the true start is uniform within ± it.
    clock_drift_ppm : the sample clock's error is uniform within ± this.
    hum_db_spl_1m : transformer hum at 1 m from the tank (100 Hz line), dB SPL.
    corona_rate_hz : corona clicks per second next to HV equipment; the rate
        falls as exp(−d/``corona_scale_m``).
    corona_peak_db_spl : range of a click's peak level at 1 m, dB SPL.
    doppler : render the chirp with the receiver's Doppler factor.
    max_excess_delay_s : paths later than this after the first one are dropped.
    skip_margin_db : emissions whose best free-field level stays this far below
        the in-band noise are not rendered (post-matched-filter SNR < −7 dB).
    block_samples : samples written per block.
    channel : geometric channel parameters.
    """

    fs_hz: int = 48_000
    noise_db_spl: float = 35.0
    device_noise_dbfs: float = -63.0
    noise_band_hz: tuple[float, float] = (17_000.0, 23_000.0)
    full_scale_db_spl: float = 110.0
    start_s: float = 0.0
    start_uncertainty_s: float = 0.02
    clock_drift_ppm: float = 10.0
    hum_db_spl_1m: float = 75.0
    mains_hz: float = 50.0
    corona_rate_hz: float = 1.0
    corona_scale_m: float = 10.0
    corona_peak_db_spl: tuple[float, float] = (60.0, 80.0)
    doppler: bool = True
    max_excess_delay_s: float = 0.12
    skip_margin_db: float = 25.0
    block_samples: int = 1 << 16
    channel: ChannelConfig = field(default_factory=ChannelConfig)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v) and f.name != "hum_db_spl_1m":
                raise ConfigError(f"audio {f.name} must be finite, got {v}")
        if not isinstance(self.fs_hz, int) or self.fs_hz < 8_000:
            raise ConfigError(f"audio fs_hz must be an integer >= 8000, got {self.fs_hz!r}")
        lo, hi = self.noise_band_hz
        if not 0 <= lo < hi <= self.fs_hz / 2:
            raise ConfigError(f"audio noise_band_hz must lie within (0, fs/2), got {self.noise_band_hz}")
        if self.start_uncertainty_s < 0 or self.clock_drift_ppm < 0 or self.corona_rate_hz < 0:
            raise ConfigError("audio start_uncertainty_s, clock_drift_ppm and corona_rate_hz must be >= 0")
        if abs(self.clock_drift_ppm) > 1000:
            raise ConfigError(f"audio clock_drift_ppm must be below 1000, got {self.clock_drift_ppm}")
        if not isinstance(self.block_samples, int) or self.block_samples < _CHUNK or self.block_samples % _CHUNK:
            raise ConfigError(f"audio block_samples must be a positive multiple of {_CHUNK}, "
                              f"got {self.block_samples!r}")
        if not self.max_excess_delay_s > 0:
            raise ConfigError(f"audio max_excess_delay_s must be positive, got {self.max_excess_delay_s}")

    @property
    def inband_noise_db_spl(self) -> float:
        """Total in-band noise (ambient + device), dB SPL (a full-scale sine, mean square ½, is full_scale_db_spl)."""
        device_db_spl = self.full_scale_db_spl + self.device_noise_dbfs + 10.0 * math.log10(2.0)
        return 10.0 * math.log10(10.0 ** (self.noise_db_spl / 10.0) + 10.0 ** (device_db_spl / 10.0))

    @classmethod
    def from_options(cls, options: dict | None) -> "AudioConfig":
        """Build from ``ctx.options["audio"]`` (a table of field values), naming any unknown key."""
        table = dict((options or {}).get("audio", {}) or {})
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise ConfigError(f"options [audio]: unknown key(s) {sorted(unknown)}")
        for key in ("noise_band_hz", "corona_peak_db_spl"):
            if key in table:
                table[key] = tuple(table[key])
        if "channel" in table and isinstance(table["channel"], dict):
            table["channel"] = ChannelConfig(**table["channel"])
        return cls(**table)


@dataclass(frozen=True)
class AudioResult:
    """What :func:`render_audio` did: true clock, counts and per-emission truth rows."""

    true_start_s: float
    drift_ppm: float
    n_samples: int
    n_emissions: int
    n_rendered: int
    n_clipped: int
    truth_csv: str


def detection_range_m(source_level_db: float, noise_db_spl: float, spec: ChirpSpec, atmosphere,
                      snr_db: float = 12.0) -> float:
    """Free-field range at which a chirp's matched-filter SNR falls to ``snr_db``.

    Link budget: SNR(r) = SL − 20·log10(r) − α(f_c)·r − N + 10·log10(T·B), with
    the pulse-compression gain T·B of a linear chirp (Skolnik, *Radar
    Handbook*, 3rd ed., §8.2) and α at the band centre (ISO 9613-1). Solved by
    bisection on [1, 2000] m.
    """
    alpha = float(absorption_db_per_m(0.5 * (spec.f0_hz + spec.f1_hz), atmosphere))
    gain = 10.0 * math.log10(spec.time_bandwidth)

    def snr(r):
        return source_level_db - 20.0 * math.log10(r) - alpha * r - noise_db_spl + gain

    if snr(1.0) < snr_db:
        return 1.0
    lo, hi = 1.0, 2000.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if snr(mid) > snr_db else (lo, mid)
    return 0.5 * (lo + hi)


class _Accumulator:
    """A rolling float buffer of device samples; finished blocks leave through ``emit``."""

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


class _Renderer:
    """Per-emission frequency-domain rendering of a chirp through a :class:`PathSet` (see module docstring)."""

    def __init__(self, site: Site, cfg: AudioConfig):
        self.cfg = cfg
        self.fs = float(cfg.fs_hz)
        self.c = speed_of_sound_m_s(site.atmosphere.temperature_c)
        self.atmosphere = site.atmosphere
        self._alpha_cache: dict[tuple[int, int, int], np.ndarray] = {}

    def _band(self, n_fft: int, spec: ChirpSpec, eta: float) -> tuple[int, int]:
        df = self.fs / n_fft
        k0 = max(0, int(math.floor((spec.f0_hz * eta - 2000.0) / df)))
        k1 = min(n_fft // 2, int(math.ceil((spec.f1_hz * eta + 2000.0) / df)))
        return k0, k1 + 1

    def _alpha(self, n_fft: int, k0: int, k1: int) -> np.ndarray:
        key = (n_fft, k0, k1)
        if key not in self._alpha_cache:
            self._alpha_cache[key] = absorption_db_per_m(np.arange(k0, k1) * self.fs / n_fft, self.atmosphere)
        return self._alpha_cache[key]

    def render(self, paths: PathSet, spec: ChirpSpec, eta: float, first_sample: float, clutter: float,
               rng: np.random.Generator, level_scale: float) -> tuple[int, np.ndarray]:
        """Return (start sample, segment) of one emission as recorded (digital full-scale units)."""
        fs, c = self.fs, self.c
        chirp = chirp_waveform(spec, fs, eta)
        start = int(math.floor(first_sample)) - _PRE_SAMPLES
        rel = first_sample - start + (paths.length_m - paths.length_m[0]) / c * fs   # (p,) samples
        keep = rel - rel[0] <= self.cfg.max_excess_delay_s * fs
        tail = tail_model(clutter)
        tail_len = int(5.0 * tail.decay_ms * 1e-3 * fs)
        tail0 = rel[0] + tail.onset_ms * 1e-3 * fs
        n_fft = sfft.next_fast_len(int(max(rel[keep].max(), tail0 + tail_len)) + len(chirp) + _POST_SAMPLES, real=True)
        k0, k1 = self._band(n_fft, spec, eta)
        k = np.arange(k0, k1)
        f = k * fs / n_fft
        alpha = self._alpha(n_fft, k0, k1)
        # H(f) = Σ_p g_p · 10^(−(α(f)·L_p + ΔL_p(f))/20) · exp(−j2π k τ_p / n_fft)
        g, length, detour, kind = paths.gain[keep], paths.length_m[keep], paths.detour_m[keep], paths.kind[keep]
        loss_db = alpha[None, :] * length[:, None]
        diff = kind == 3
        if diff.any():
            loss_db[diff] += maekawa_loss_db(fresnel_number(detour[diff, None], f[None, :], c))
        phase = np.exp(-2j * np.pi * np.outer(rel[keep], k) / n_fft)
        h = (g[:, None] * 10.0 ** (-loss_db / 20.0) * phase).sum(axis=0)
        # diffuse tail: Poisson arrivals, Gaussian amplitudes, envelope exp(−t/decay); E[Σa²] = level·(1/d²)
        n_taps = rng.poisson(tail.density_per_ms * 5.0 * tail.decay_ms)
        if n_taps:
            t_ms = rng.uniform(0.0, 5.0 * tail.decay_ms, n_taps)
            e_target = 10.0 ** (tail.level_db / 10.0) / max(paths.direct_m, 1e-3) ** 2
            scale = math.sqrt(e_target / (tail.density_per_ms * tail.decay_ms / 2.0))
            amp = rng.standard_normal(n_taps) * np.exp(-t_ms / tail.decay_ms) * scale
            taps = np.zeros(n_fft)
            np.add.at(taps, np.minimum((tail0 + t_ms * 1e-3 * fs).astype(int), n_fft - 1), amp)
            h += sfft.rfft(taps)[k0:k1] * 10.0 ** (-alpha * paths.direct_m / 20.0)
        spectrum = np.zeros(n_fft // 2 + 1, complex)
        spectrum[k0:k1] = sfft.rfft(chirp, n_fft)[k0:k1] * h
        return start, sfft.irfft(spectrum, n_fft) * level_scale


def _position_at(traj: Trajectory, t_s: float) -> np.ndarray:
    return np.array([np.interp(t_s, traj.t_s, traj.east_m), np.interp(t_s, traj.t_s, traj.north_m),
                     np.interp(t_s, traj.t_s, traj.up_m)])


def _velocity_table(traj: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal velocity (v_east, v_north), m/s, shape (n,) each, from speed and heading (from north, clockwise)."""
    return traj.speed_m_s * np.sin(traj.heading_rad), traj.speed_m_s * np.cos(traj.heading_rad)


def _distance_to_boxes(p_en: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Horizontal distance from points (n, 2) to the nearest box footprint (0 inside); (n,), inf if none."""
    if boxes.shape[0] == 0:
        return np.full(len(p_en), np.inf)
    de = np.maximum(np.maximum(boxes[:, 0] - p_en[:, :1], p_en[:, :1] - boxes[:, 1]), 0.0)
    dn = np.maximum(np.maximum(boxes[:, 2] - p_en[:, 1:2], p_en[:, 1:2] - boxes[:, 3]), 0.0)
    return np.hypot(de, dn).min(axis=1)


def _db_to_digital_rms(level_db_spl: float, cfg: AudioConfig) -> float:
    """RMS of a signal at ``level_db_spl`` in full-scale units (a full-scale sine has RMS 1/√2)."""
    return 10.0 ** ((level_db_spl - cfg.full_scale_db_spl) / 20.0) / math.sqrt(2.0)


class _Ambient:
    """Noise, hum and corona clicks of one recording, drawn per fixed chunk of samples.

    Chunk ``k`` (``_CHUNK`` samples) takes its draws from
    ``stream_rng(seed, "audio", "noise", k)``, so the recording does not depend
    on the block size used to write it.
    """

    def __init__(self, site: Site, trajectory: Trajectory, seed: int, cfg: AudioConfig, true_start: float,
                 fs_true: float):
        self.traj, self.seed, self.cfg = trajectory, seed, cfg
        self.true_start, self.fs_true = true_start, fs_true
        fs = cfg.fs_hz
        band = cfg.noise_band_hz[1] - cfg.noise_band_hz[0]
        # white noise over 0..fs/2 whose share within the band has the stated level
        self.noise_rms = _db_to_digital_rms(cfg.inband_noise_db_spl, cfg) * math.sqrt((fs / 2.0) / band)
        self.hv = boxes_array([b for b in site.layout if b.kind in _HV_KINDS])
        self.tanks = boxes_array([b for b in site.layout if b.kind == "transformer"])
        self.hum_phase = stream_rng(seed, "audio", "hum").uniform(0.0, 2.0 * np.pi, 4)

    def chunk(self, k: int, n: int) -> np.ndarray:
        """Ambient samples of chunk ``k`` (device samples k·_CHUNK …), length ``n`` plus click overhang."""
        cfg, fs = self.cfg, self.cfg.fs_hz
        rng = stream_rng(self.seed, "audio", "noise", k)
        click_len = int(0.002 * fs)
        out = np.zeros(n + click_len)
        out[:n] = rng.standard_normal(n) * self.noise_rms
        b0 = k * _CHUNK
        grid = self.true_start + (b0 + np.array([0.0, n / 2.0, float(n)])) / self.fs_true
        pos = np.column_stack([np.interp(grid, self.traj.t_s, self.traj.east_m),
                               np.interp(grid, self.traj.t_s, self.traj.north_m)])
        if self.tanks.shape[0] and cfg.hum_db_spl_1m > -np.inf:
            t_true = self.true_start + (b0 + np.arange(n)) / self.fs_true
            d = np.maximum(_distance_to_boxes(pos, self.tanks), 1.0)
            amp = np.interp(t_true, grid, _db_to_digital_rms(cfg.hum_db_spl_1m, cfg) * math.sqrt(2.0) / d)
            # 2·mains and harmonics (magnetostriction), −3 dB each: Im(z^h·e^{jφ_h}), z = e^{j2π·2f_m·t}
            z = np.exp(2j * np.pi * 2.0 * cfg.mains_hz * t_true)
            zh = np.ones(n, complex)
            hum = np.zeros(n)
            for h in range(4):
                zh *= z
                hum += 10.0 ** (-3.0 * h / 20.0) * (zh * np.exp(1j * self.hum_phase[h])).imag
            out[:n] += amp * hum
        if self.hv.shape[0] and cfg.corona_rate_hz > 0:
            d_mid = float(_distance_to_boxes(pos[1:2], self.hv)[0])
            rate = cfg.corona_rate_hz * math.exp(-d_mid / cfg.corona_scale_m)
            tt = np.arange(click_len) / fs
            for s0 in np.sort(rng.integers(0, n, rng.poisson(rate * n / fs))):
                peak_db = rng.uniform(*cfg.corona_peak_db_spl) - 20.0 * math.log10(max(d_mid, 1.0))
                click = rng.standard_normal(click_len) * np.exp(-tt / 1.5e-4)
                click *= 10.0 ** ((peak_db - cfg.full_scale_db_spl) / 20.0) * math.sqrt(2.0) / np.abs(click).max()
                out[s0:s0 + click_len] += click
        return out


def _emissions(site: Site, start_utc, t_begin_s: float, t_end_s: float) -> list[tuple]:
    """Every (t_emit_s, beacon_id, index, beacon, spec) in [t_begin_s, t_end_s), in emission order."""
    out = []
    for b in site.beacons:
        spec = beacon_chirp(site, b)
        for i, t_e in enumerate(emission_times_s(site, b, start_utc, t_begin_s, t_end_s)):
            out.append((float(t_e), b.id, i, b, spec))
    out.sort(key=lambda e: (e[0], e[1]))
    return out


def render_audio(site: Site, trajectory: Trajectory, seed: int, wav_path,
                 cfg: AudioConfig | None = None) -> AudioResult:
    """Simulate the recording along ``trajectory`` into the int16 WAV at ``wav_path`` (atomic).

    Randomness comes only from ``stream_rng(seed, "audio", ...)``: the same
    seed gives the same bytes, whatever ``block_samples``. Memory is bounded by
    the block size, not the recording's length. Returns an :class:`AudioResult`.
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
    renderer = _Renderer(site, cfg)
    ambient = _Ambient(site, trajectory, seed, cfg, true_start, fs_true)
    c = renderer.c
    sl_db = site.acoustic.source_level_db
    noise_floor_db = cfg.inband_noise_db_spl
    level_scale = 10.0 ** ((sl_db - cfg.full_scale_db_spl) / 20.0)
    v_east, v_north = _velocity_table(trajectory)
    emissions = _emissions(site, trajectory.start_utc, true_start - 0.5, t_end)
    alpha_min: dict[ChirpSpec, float] = {}
    clutter_cache: dict[tuple[int, int], float] = {}
    path_cache: dict[tuple, PathSet] = {}         # a static receiver sees the same geometry every frame
    acc = _Accumulator(cfg.block_samples, n_total)
    rows = []
    counts = {"rendered": 0, "clipped": 0}
    next_chunk = 0
    carry = np.zeros(0)

    def paths_at(bid: int, src: np.ndarray, rx: np.ndarray) -> PathSet:
        key = (bid, *np.round(rx, 4).tolist())
        if key not in path_cache:
            if len(path_cache) > 4096:
                path_cache.clear()
            path_cache[key] = channel_paths(scene, src, rx)
        return path_cache[key]

    with atomic_path(wav_path, suffix=".wav") as tmp, \
            sf.SoundFile(tmp, "w", samplerate=fs, channels=1, subtype="PCM_16", format="WAV") as out:

        def flush_until(sample: float) -> None:
            nonlocal next_chunk, carry
            while acc.base < n_total and acc.base + min(acc.block, n_total - acc.base) <= sample:
                n = min(acc.block, n_total - acc.base)
                pieces = []
                while next_chunk * _CHUNK < acc.base + n:        # ambient of the chunks of this block
                    m = min(_CHUNK, n_total - next_chunk * _CHUNK)
                    amb = ambient.chunk(next_chunk, m)
                    amb[:len(carry)] += carry                     # click tails from the previous chunk
                    pieces.append(amb[:m])
                    carry = amb[m:]
                    next_chunk += 1
                q = np.rint((acc.pop_block() + np.concatenate(pieces)) * 32767.0)
                counts["clipped"] += int(np.count_nonzero(np.abs(q) > 32767))
                out.write(np.clip(q, -32768, 32767).astype(np.int16))

        for t_e, bid, i, b, spec in emissions:
            flush_until((t_e - true_start) * fs_true - _PRE_SAMPLES - 2)
            src = np.array([b.east_m, b.north_m, b.up_m])
            if spec not in alpha_min:
                alpha_min[spec] = float(absorption_db_per_m(spec.f0_hz, site.atmosphere))
            # receiver position when the first path arrives: t_a = t_e + L(x(t_a))/c, straight line first
            t_a = t_e
            for _ in range(2):
                t_a = t_e + float(np.linalg.norm(src - _position_at(trajectory, t_a))) / c
            rx = _position_at(trajectory, t_a)
            d = float(np.linalg.norm(src - rx))
            if sl_db - 20.0 * math.log10(max(d, 1e-3)) - alpha_min[spec] * d < noise_floor_db - cfg.skip_margin_db:
                continue          # even in free field it could not rise out of the noise
            paths = paths_at(bid, src, rx)
            speed = float(np.interp(t_a, trajectory.t_s, trajectory.speed_m_s))
            if len(paths) and speed * (paths.length_m[0] - d) / c > 0.005:
                # a detour delays the arrival long enough for the walker to move: look again there
                rx = _position_at(trajectory, t_e + paths.length_m[0] / c)
                paths = paths_at(bid, src, rx)
            if len(paths) == 0:
                continue
            t_a = t_e + paths.length_m[0] / c
            best_db = sl_db + 20.0 * math.log10(max(paths.gain.max(), 1e-12)) - alpha_min[spec] * paths.length_m[0]
            first_sample = (t_a - true_start) * fs_true
            if best_db < noise_floor_db - cfg.skip_margin_db or not -fs <= first_sample < n_total:
                continue
            eta = 1.0
            if cfg.doppler:       # moving observer: η = 1 + v·u/c, u the unit vector to the beacon
                u = (src - rx) / max(np.linalg.norm(src - rx), 1e-6)
                v = np.array([np.interp(t_a, trajectory.t_s, v_east), np.interp(t_a, trajectory.t_s, v_north), 0.0])
                eta = 1.0 + float(v @ u) / c
            cell = (int(math.floor(rx[0])), int(math.floor(rx[1])))      # clutter on a 1 m grid
            if cell not in clutter_cache:
                clutter_cache[cell] = clutter_index(scene, np.array([cell[0] + 0.5, cell[1] + 0.5]))
            # the tail realisation belongs to the place (1 cm grid): a static receiver hears the same tail every
            # frame, a walker (≥ 1 m between a beacon's chirps, ≫ λ/2 ≈ 8 mm) an independent one
            rng = stream_rng(seed, "audio", "tail", bid, *(int(round(v * 100.0)) + 10**8 for v in rx))
            start, seg = renderer.render(paths, spec, eta, first_sample, clutter_cache[cell], rng, level_scale)
            acc.add(start, seg)
            counts["rendered"] += 1
            if first_sample >= 0:
                rows.append((bid, b.slot, t_e, t_a, first_sample, PATH_KINDS[paths.kind[0]], paths.length_m[0],
                             paths.direct_m, int(paths.los), *rx, _first_path_db_spl(paths, spec, sl_db, renderer),
                             eta))
        flush_until(float(n_total))
    return AudioResult(true_start_s=true_start, drift_ppm=drift_ppm, n_samples=n_total, n_emissions=len(emissions),
                       n_rendered=counts["rendered"], n_clipped=counts["clipped"], truth_csv=_truth_csv(rows))


def _first_path_db_spl(paths: PathSet, spec: ChirpSpec, source_level_db: float, renderer: _Renderer) -> float:
    """Level of the first path at the band centre: SL + 20·log10(g) − α(f_c)·L − ΔL_Maekawa(f_c), dB SPL."""
    f_c = 0.5 * (spec.f0_hz + spec.f1_hz)
    level = (source_level_db + 20.0 * math.log10(max(float(paths.gain[0]), 1e-12))
             - float(absorption_db_per_m(f_c, renderer.atmosphere)) * float(paths.length_m[0]))
    if paths.kind[0] == 3:
        level -= float(maekawa_loss_db(fresnel_number(paths.detour_m[0], f_c, renderer.c)))
    return level


def _truth_csv(rows: list[tuple]) -> str:
    """``audio_truth.csv``: one row per recorded emission (true first arrival, for evaluation only)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["beacon_id", "slot", "emit_t_s", "arrival_t_s", "arrival_sample", "first_path", "first_path_m",
                "direct_m", "los", "rx_east_m", "rx_north_m", "rx_up_m", "first_path_db_spl", "doppler"])
    for r in rows:
        w.writerow([r[0], r[1], f"{r[2]:.9f}", f"{r[3]:.9f}", f"{r[4]:.3f}", r[5], f"{r[6]:.4f}", f"{r[7]:.4f}",
                    r[8], f"{r[9]:.3f}", f"{r[10]:.3f}", f"{r[11]:.3f}", f"{r[12]:.1f}", f"{r[13]:.6f}"])
    return buf.getvalue()


def write_audio(ctx: StreamContext) -> dict:
    """Stream writer: ``audio.wav`` and ``audio_truth.csv`` into ``ctx.out_dir``; returns the ``[audio]`` table."""
    cfg = AudioConfig.from_options(ctx.options)
    result = render_audio(ctx.site, ctx.trajectory, ctx.seed, ctx.out_dir / "audio.wav", cfg)
    atomic_write_text(ctx.out_dir / "audio_truth.csv", result.truth_csv)
    return {"audio": {"file": "audio.wav", "fs_hz": cfg.fs_hz, "start_s": cfg.start_s,
                      "start_uncertainty_s": cfg.start_uncertainty_s}}
