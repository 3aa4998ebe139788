"""Sample synthesis for ``audio.wav``: the recorder's parameters, one chirp through its channel, ambient noise.

One emission (:class:`ChirpRenderer`). Each discrete path of
:func:`simulation.acoustic.channel.channel_paths` is a delayed, filtered copy of
the chirp, built in the frequency domain over the chirp's band::

    Y(f) = S_η(f) · [ Σ_p g_p · 10^(−(α(f)·L_p + ΔL_p(f))/20) · e^(−j2πf·τ_p) + T(f) ]

with S_η the chirp as heard with the Doppler factor η = 1 + v_r/c of the
receiver's closing speed on the beacon (one factor for all paths of the
emission), α(f) the ISO 9613-1 absorption (dB/m), ΔL_p Maekawa's loss of a
diffracted path, τ_p the fractional-sample delay (a phase ramp), and T(f) the
diffuse tail (:func:`simulation.acoustic.channel.tail_model`: Poisson arrivals
of Gaussian amplitude on integer samples, absorbed over the direct distance).

Ambient sound (:class:`AmbientNoise`), drawn per fixed chunk of samples:

* in-band noise, white Gaussian: the acoustic ambient (``noise_db_spl``) and
  the recorder's own floor (``device_noise_dbfs``, a MEMS datasheet figure,
  bounded above by real phone audio); see :class:`AudioConfig`;
* transformer hum (100 Hz and harmonics for a 50 Hz grid, magnetostriction)
  falling 1/r from the nearest tank — far out of band, it only tests the
  receiver's band-pass;
* corona and partial-discharge pulses from the HV equipment's insulators and
  bushings, in bursts phase-locked to the mains (:mod:`simulation.acoustic.discharge`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields

import numpy as np
import scipy.fft as sfft
from numba import njit

from features.errors import ConfigError
from features.site import Site

from simulation.acoustic.channel import ChannelConfig, PathSet, tail_model
from simulation.acoustic.atmosphere import absorption_db_per_m, fresnel_number, maekawa_loss_db, speed_of_sound_m_s
from simulation.acoustic.chirp import ChirpSpec, chirp_length, chirp_waveform
from simulation.acoustic.discharge import DischargeConfig, DischargeSources
from simulation.site.geometry import boxes_array
from simulation.rng import stream_rng, stream_rngs
from simulation.streams import Trajectory

__all__ = ["AudioConfig", "ChirpRenderer", "AmbientNoise", "detection_range_m", "CHUNK_SAMPLES", "band_response",
           "hum_samples", "add_hum", "interp_like_numpy"]

CHUNK_SAMPLES = 16384
"""Ambient noise is drawn per chunk of this many samples (block sizes must be multiples of it)."""
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
        samples scaled to ±1). −85 dB from a datasheet: a MEMS microphone of
        65 dB(A) SNR at −26 dBFS/94 dB SPL (InvenSense ICS-43434) has a
        −91 dBFS(A) floor over 20 kHz, ≈ −96 dBFS within the 6 kHz band,
        −86 dB after 10 dB of gain (28 dB SPL equivalent, below the ambient).
        Upper bound from real audio: the five Galaxy S3 recordings in
        ../shared/data/audio_ultrasense show −63 dB (median Welch PSD over
        17–19.5 and 20.5–22 kHz × 6 kHz; −62.3 … −63.3 dB), but they were made
        while the phone's own speaker played a 20 kHz tone at −20 … −24 dB re.
        full scale², 40 dB above that floor, so the emitting chain's noise is
        in it. Set −63 to stress the receiver: detection range falls from
        ≈ 70 m to ≈ 47 m (:func:`detection_range_m`).
    full_scale_db_spl : SPL of a full-scale sine (RMS): 110 dB, i.e. a 120 dB
        SPL AOP microphone with 10 dB of recording gain.
    start_s, start_uncertainty_s : the stated audio start on the walk's time
        base and its uncertainty; the true start is uniform within ± it.
    clock_drift_ppm : the sample clock's error is uniform within ± this.
    hum_db_spl_1m : transformer hum at 1 m from the tank (100 Hz line), dB SPL.
    corona_rate_hz : discharge pulses per second of an active source on HV equipment
        (0: none); corona_active_share : share of candidate sources (bushings,
        insulator strings) that discharge; corona_level_db_spl : (mean, sd) of a
        pulse's 17–23 kHz peak level at 1 m, dB re 20 µPa; corona_phase_window_deg :
        half-width of the phase window about each voltage peak
        (:mod:`simulation.acoustic.discharge`, its sources and assumptions).
    doppler : render the chirp with the receiver's Doppler factor.
    max_excess_delay_s : paths later than this after the first one are dropped.
    skip_margin_db : emissions whose best free-field level stays this far below
        the in-band noise are not rendered (post-matched-filter SNR < −7 dB).
    block_samples : samples written per block.
    channel : geometric channel parameters.
    """

    fs_hz: int = 48_000
    noise_db_spl: float = 35.0
    device_noise_dbfs: float = -85.0
    noise_band_hz: tuple[float, float] = (17_000.0, 23_000.0)
    full_scale_db_spl: float = 110.0
    start_s: float = 0.0
    start_uncertainty_s: float = 0.02
    clock_drift_ppm: float = 10.0
    hum_db_spl_1m: float = 75.0
    mains_hz: float = 50.0
    corona_rate_hz: float = 10.0
    corona_active_share: float = 0.5
    corona_level_db_spl: tuple[float, float] = (60.0, 8.0)
    corona_phase_window_deg: float = 30.0
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
        if not 0.0 <= self.corona_active_share <= 1.0 or not 0.0 < self.corona_phase_window_deg <= 90.0:
            raise ConfigError(f"audio corona_active_share must lie in [0, 1] and corona_phase_window_deg in (0, 90], "
                              f"got {self.corona_active_share}, {self.corona_phase_window_deg}")
        if not self.corona_level_db_spl[1] >= 0:
            raise ConfigError(f"audio corona_level_db_spl spread must be >= 0, got {self.corona_level_db_spl}")
        if abs(self.clock_drift_ppm) > 1000:
            raise ConfigError(f"audio clock_drift_ppm must be below 1000, got {self.clock_drift_ppm}")
        blk = self.block_samples
        if not isinstance(blk, int) or blk < CHUNK_SAMPLES or blk % CHUNK_SAMPLES:
            raise ConfigError(f"audio block_samples must be a positive multiple of {CHUNK_SAMPLES}, "
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
        for key in ("noise_band_hz", "corona_level_db_spl"):
            if key in table:
                table[key] = tuple(table[key])
        if "channel" in table and isinstance(table["channel"], dict):
            table["channel"] = ChannelConfig(**table["channel"])
        return cls(**table)


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


class ChirpRenderer:
    """Per-emission frequency-domain rendering of a chirp through a :class:`PathSet` (see module docstring)."""

    def __init__(self, site: Site, cfg: AudioConfig):
        self.cfg = cfg
        self.fs = float(cfg.fs_hz)
        self.c = speed_of_sound_m_s(site.atmosphere.temperature_c)
        self.atmosphere = site.atmosphere
        self._alpha_cache: dict[int, np.ndarray] = {}
        self._chirp_cache: dict[tuple, np.ndarray] = {}

    def _alpha(self, n_fft: int, k0: int, k1: int) -> np.ndarray:
        """ISO 9613-1 α (dB/m) on bins k0..k1 of an n_fft grid; cached per n_fft (a handful of fast lengths)."""
        if n_fft not in self._alpha_cache:
            self._alpha_cache[n_fft] = absorption_db_per_m(np.arange(n_fft // 2 + 1) * self.fs / n_fft, self.atmosphere)
        return self._alpha_cache[n_fft][k0:k1]

    def render(self, paths: PathSet, spec: ChirpSpec, eta: float, first_sample: float, clutter: float,
               rng: np.random.Generator, level_scale: float) -> tuple[int, np.ndarray]:
        """Return (start sample, segment) of one emission as recorded (digital full-scale units)."""
        return self.render_many([(paths, spec, eta, first_sample, clutter, rng, level_scale)])[0]

    def render_many(self, emissions: list[tuple]) -> list[tuple[int, np.ndarray]]:
        """(start sample, segment) of each emission given as (paths, spec, η, first_sample, clutter, rng,
        level_scale), sample for sample what :meth:`render` gives it alone. The emissions of equal FFT length
        go as one group: their tails' taps scattered into one matrix, their spectra assembled on the band by one
        compiled pass (:func:`band_rows`), each FFT one call over the rows (pocketfft transforms each row as it
        would alone)."""
        if not emissions:
            return []
        plans = self._plans(emissions)
        chirps = self._chirp_spectra([(e[1], e[2], p.n_fft) for e, p in zip(emissions, plans)])
        by_n: dict[int, list[int]] = {}
        for i, p in enumerate(plans):
            by_n.setdefault(p.n_fft, []).append(i)
        out: list = [None] * len(plans)
        for n_fft, idx in by_n.items():
            group = [plans[i] for i in idx]
            k0 = np.array([p.k0 for p in group])
            k1 = np.array([p.k1 for p in group])
            with_tail = [r for r, p in enumerate(group) if p.taps is not None]
            tail_row = np.full(len(group), -1)
            tail_row[with_tail] = np.arange(len(with_tail))
            taps = np.zeros((len(with_tail), n_fft))
            if with_tail:
                tails = [group[r] for r in with_tail]
                scatter_taps(taps, np.repeat(np.arange(len(tails)), [len(p.taps[0]) for p in tails]),
                             np.concatenate([p.taps[0] for p in tails]), np.concatenate([p.taps[1] for p in tails]))
                tail_spectra = sfft.rfft(taps, n_fft, axis=-1)
                tail_gain = np.concatenate([p.tail_gain for p in tails])
            else:
                tail_spectra, tail_gain = np.zeros((0, n_fft // 2 + 1), complex), np.zeros(0)
            # Y = S_η · (H + T·10^(−α·d/20)) over the bins any row's band covers (zero elsewhere)
            u0, u1 = int(k0.min()), int(k1.max())
            x = band_rows(u0, u1, k0, k1, np.concatenate([p.h for p in group]), tail_spectra, tail_row, tail_gain)
            y = np.zeros((len(group), n_fft // 2 + 1), complex)
            np.multiply(np.stack([chirps[i][u0:u1] for i in idx]), x, out=y[:, u0:u1])
            segments = sfft.irfft(y, n_fft, axis=-1)
            for r, i in enumerate(idx):
                out[i] = (group[r].start, segments[r] * emissions[i][6])
        return out

    def _plans(self, emissions: list[tuple]) -> list["_Plan"]:
        """Everything of each emission (paths, spec, η, first_sample, clutter, rng, ...) but its FFTs: the
        discrete paths' H(f) on the band, the tail's taps. The emissions' scalars and paths as arrays over the
        batch (each value by the operations one emission alone would take), H by one compiled pass
        (:func:`band_responses`), the tails' draws from each emission's own generator in its order."""
        fs, c, cfg = self.fs, self.c, self.cfg
        m = len(emissions)
        paths = [e[0] for e in emissions]
        specs = [e[1] for e in emissions]
        eta = np.array([e[2] for e in emissions], float)
        first = np.array([e[3] for e in emissions], float)
        tails = [tail_model(e[4]) for e in emissions]
        onset, decay = np.array([t.onset_ms for t in tails]), np.array([t.decay_ms for t in tails])
        n_paths = np.array([len(p) for p in paths])
        at = np.repeat(np.arange(m), n_paths)                        # the emission of each path
        first_of = np.cumsum(n_paths) - n_paths                      # each emission's first path
        length = np.concatenate([p.length_m for p in paths])
        start = np.floor(first).astype(np.int64) - _PRE_SAMPLES
        rel = (first - start)[at] + (length - length[first_of][at]) / c * fs      # (Σp,) samples
        rel0 = rel[first_of]
        keep = rel - rel0[at] <= cfg.max_excess_delay_s * fs
        tail_len = (5.0 * decay * 1e-3 * fs).astype(np.int64)
        tail0 = rel0 + onset * 1e-3 * fs
        last = np.maximum.reduceat(np.where(keep, rel, -np.inf), first_of)
        n_used = np.maximum(last, tail0 + tail_len).astype(np.int64) + _chirp_lengths(specs, fs, eta) + _POST_SAMPLES
        n_fft = np.array([_fast_len(int(n)) for n in n_used])
        df = fs / n_fft
        # the band, 2 kHz beyond the chirp's as heard: bins k0 … k1 − 1
        f0, f1 = np.array([s.f0_hz for s in specs]), np.array([s.f1_hz for s in specs])
        k0 = np.maximum(0, np.floor((f0 * eta - 2000.0) / df).astype(np.int64))
        k1 = np.minimum(n_fft // 2, np.ceil((f1 * eta + 2000.0) / df).astype(np.int64)) + 1
        alphas = [self._alpha(int(n), int(a), int(b)) for n, a, b in zip(n_fft, k0, k1)]
        # H(f) = Σ_p g_p · 10^(−(α(f)·L_p + ΔL_p(f))/20) · exp(−j2π k τ_p / n_fft), over the kept paths
        kind = np.concatenate([p.kind for p in paths])
        diffracted = np.flatnonzero(keep & (kind == 3))
        detour = np.concatenate([p.detour_m for p in paths])
        # ΔL of each kept diffracted path on its emission's band, one after another
        fresnel = [fresnel_number(detour[i], np.arange(k0[at[i]], k1[at[i]]) * fs / n_fft[at[i]], c)
                   for i in diffracted.tolist()]
        barrier_db = maekawa_loss_db(np.concatenate(fresnel)) if fresnel else np.zeros(0)
        h = band_responses(np.concatenate([p.gain for p in paths]), length, rel, keep, kind == 3, first_of, n_paths,
                           np.concatenate(alphas), k0, k1, n_fft, barrier_db)
        h_end = np.cumsum(k1 - k0)
        # diffuse tail: Poisson arrivals, Gaussian amplitudes, envelope exp(−t/decay); E[Σa²] = level·(1/d²); the
        # draws from each emission's generator, the arithmetic over all taps of the batch at once
        drawn, t_ms, z, scale = [], [], [], []
        for j, (e, p, tail) in enumerate(zip(emissions, paths, tails)):
            rng = e[5]
            n_taps = rng.poisson(tail.density_per_ms * 5.0 * tail.decay_ms)
            if not n_taps:
                continue
            t_ms.append(rng.uniform(0.0, 5.0 * tail.decay_ms, n_taps))
            level_db = tail.level_db + cfg.channel.tail_offset_db
            e_target = 10.0 ** (level_db / 10.0) / max(p.direct_m, 1e-3) ** 2
            scale.append(math.sqrt(e_target / (tail.density_per_ms * tail.decay_ms / 2.0)))
            z.append(rng.standard_normal(n_taps))
            drawn.append(j)
        if drawn:
            n_taps = np.array([len(t) for t in t_ms])
            of_tap = np.repeat(np.array(drawn), n_taps)
            t_ms = np.concatenate(t_ms)
            amp = np.concatenate(z) * np.exp(-t_ms / decay[of_tap]) * np.repeat(np.array(scale), n_taps)
            sample = np.minimum((tail0[of_tap] + t_ms * 1e-3 * fs).astype(int), n_fft[of_tap] - 1)
            n_band = (k1 - k0)[drawn]
            direct = np.array([paths[j].direct_m for j in drawn])
            tail_gain = 10.0 ** (-np.concatenate([alphas[j] for j in drawn]) * np.repeat(direct, n_band) / 20.0)
            tap_end, gain_end = np.cumsum(n_taps).tolist(), np.cumsum(n_band).tolist()
        plans, at_drawn = [], 0
        for j in range(m):
            h_j = h[h_end[j] - (k1[j] - k0[j]):h_end[j]]
            taps = gain = None
            if at_drawn < len(drawn) and drawn[at_drawn] == j:
                t0, t1 = (tap_end[at_drawn - 1] if at_drawn else 0), tap_end[at_drawn]
                g0, g1 = (gain_end[at_drawn - 1] if at_drawn else 0), gain_end[at_drawn]
                taps, gain = (sample[t0:t1], amp[t0:t1]), tail_gain[g0:g1]
                at_drawn += 1
            plans.append(_Plan(int(start[j]), int(n_fft[j]), int(k0[j]), int(k1[j]), h_j, taps, gain))
        return plans

    def _chirp_spectra(self, keys: list[tuple[ChirpSpec, float, int]]) -> list[np.ndarray]:
        """rfft of the chirp heard with Doppler factor η, zero-padded to n_fft, for each (spec, η, n_fft); the
        last few kept (a standing walker, η = 1, hears the same chirp frame after frame)."""
        missing = [key for key in dict.fromkeys(keys) if key not in self._chirp_cache]
        rows = []
        for spec, eta, n_fft in missing:
            x = np.zeros(n_fft)
            w = chirp_waveform(spec, self.fs, eta)
            x[:len(w)] = w
            rows.append((n_fft, x))
        new = dict(zip(missing, _by_length(_rfft_rows, rows)))
        out = [new[key] if key in new else self._chirp_cache[key] for key in keys]
        for key, spectrum in new.items():
            self._chirp_cache[key] = spectrum
            if len(self._chirp_cache) > 64:
                self._chirp_cache.pop(next(iter(self._chirp_cache)))
        return out


_ROTATION_BLOCK = 16
"""Bins (band_response) or samples (hum_samples) per exact sin/cos of a phase; rotation in between."""


@njit(cache=True)
def _rotation_table(step_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """θ_i = step·i, cos θ_i, sin θ_i for i < _ROTATION_BLOCK (the in-block rotations of a linear phase)."""
    theta = step_rad * np.arange(_ROTATION_BLOCK)
    return theta, np.cos(theta), np.sin(theta)


@njit(cache=True)
def _rotated(ar: float, ai: float, theta: np.ndarray, c: np.ndarray, s: np.ndarray, i: int,
             eps: float) -> tuple[float, float]:
    """(a_r + j·a_i)·e^{j(θ_i + ε)} with e^{jε} = 1 + jε (ε a few ulp of a rounded phase: error ε²/2 < 1e-19)."""
    sr, si = c[i] - eps * s[i], s[i] + eps * c[i]
    return ar * sr - ai * si, ar * si + ai * sr


@njit(cache=True)
def band_response(gain: np.ndarray, loss_db: np.ndarray, delay_samples: np.ndarray, k0: int,
                  n_fft: int) -> np.ndarray:
    """H on bins k0 … k0+K−1 of an n_fft grid of paths p with pressure gain g_p, frequency-dependent loss
    L_p(f) (dB) and delay τ_p (samples), the sum of delayed, attenuated copies (the module docstring's Y(f))::

        H[k] = Σ_p g_p · 10^(−L_p[k]/20) · exp(−j·2π·k·τ_p / n_fft)

    gain : (p,); loss_db : (p, K); delay_samples : (p,). Returns (K,) complex, the paths summed in their order.
    Compiled, one pass (numpy's form built three (p, K) temporaries per emission). The phase θ = −2π·k·τ/n as
    numpy rounds it: its cos and sin every ``_ROTATION_BLOCK`` bins, a rotation by the table's −2π·i·τ/n
    corrected by the rounding residual in between (:func:`_rotated`); agrees with exp(jθ) to a few ulp.
    """
    n_paths, n_bins = loss_db.shape
    h = np.zeros(n_bins, np.complex128)
    inv_n = 1.0 / n_fft
    ln10_20 = math.log(10.0) / 20.0
    for p in range(n_paths):
        theta, c, s = _rotation_table(-2.0 * np.pi * delay_samples[p] * inv_n)
        for b in range(0, n_bins, _ROTATION_BLOCK):
            phi_b = -2.0 * np.pi * (delay_samples[p] * (k0 + b)) * inv_n
            ar, ai = math.cos(phi_b), math.sin(phi_b)
            for j in range(b, min(b + _ROTATION_BLOCK, n_bins)):
                phi = -2.0 * np.pi * (delay_samples[p] * (k0 + j)) * inv_n
                zr, zi = _rotated(ar, ai, theta, c, s, j - b, (phi - phi_b) - theta[j - b])
                a = gain[p] * math.exp(-loss_db[p, j] * ln10_20)
                h[j] += complex(a * zr, a * zi)
    return h


_HUM_WEIGHTS = 10.0 ** (-3.0 * np.arange(4) / 20.0)
"""Amplitude of the hum's harmonics 2·f_m, 4·f_m, 6·f_m, 8·f_m re. the first: −3 dB each (an assumed spectrum)."""


@njit(cache=True)
def hum_samples(t_s: np.ndarray, dt_s: float, omega_rad_s: float, phase_rad: np.ndarray,
                weight: np.ndarray) -> np.ndarray:
    """Transformer hum of unit amplitude at the evenly spaced times ``t_s`` (n,; spacing ``dt_s``):
    magnetostriction vibrates the core at twice the mains frequency, so its sound lies at even multiples of
    f_m (IEC 60076-10:2016, transformer sound levels); ω = 2π·2f_m and the lines h·ω, h = 1 … H::

        x(t) = Σ_h w_h · sin(h·ω·t + φ_h) = Σ_h w_h · Im(z^h · e^{jφ_h}),  z = e^{jωt}

    phase_rad, weight : (H,). z = e^{jy}, y = ω·t as rounded: cos y and sin y every ``_ROTATION_BLOCK``
    samples (y_b), in between e^{jy_b} rotated by the table's ω·i·dt and the rounding residual ε = (y − y_b) −
    ω·i·dt (:func:`_rotated`), so z agrees with cos y + j·sin y to a few ulp (1e-15). z^h by repeated complex
    multiplication. Two passes, each sample's operations in the same order: z of every sample, then the
    harmonics one after another over all samples (a loop the compiler vectorises: twice as fast).
    """
    n = t_s.shape[0]
    rot_re, rot_im = np.cos(phase_rad), np.sin(phase_rad)
    theta, c, s = _rotation_table(omega_rad_s * dt_s)
    zr, zi = np.empty(n), np.empty(n)
    for b in range(0, n, _ROTATION_BLOCK):
        y_b = omega_rad_s * t_s[b]
        ar, ai = math.cos(y_b), math.sin(y_b)
        for i in range(b, min(b + _ROTATION_BLOCK, n)):
            zr[i], zi[i] = _rotated(ar, ai, theta, c, s, i - b, (omega_rad_s * t_s[i] - y_b) - theta[i - b])
    hr, hi, out = np.ones(n), np.zeros(n), np.zeros(n)      # z^h, h = 0 first; the sum over h
    for h in range(weight.shape[0]):
        w, pr, pi = weight[h], rot_re[h], rot_im[h]
        for i in range(n):
            hr[i], hi[i] = hr[i] * zr[i] - hi[i] * zi[i], hr[i] * zi[i] + hi[i] * zr[i]
            out[i] += w * (hr[i] * pi + hi[i] * pr)
    return out


@njit(cache=True)
def interp_like_numpy(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``numpy.interp(x, xp, fp)`` for a short ascending ``xp`` (≤ 4 points, where numpy searches linearly) and
    more x than xp, value for value as numpy's ``arr_interp`` computes it: the slopes (fp[j+1] − fp[j]) /
    (xp[j+1] − xp[j]) first, then slope·(x − xp[j]) + fp[j] on [xp[j], xp[j+1]), fp[j] at xp[j] and at the
    last point, the end values beyond the ends. x : (n,); xp, fp : (m,), 2 ≤ m ≤ 4. Returns (n,)."""
    m = xp.shape[0]
    slopes = np.empty(m - 1)
    for j in range(m - 1):
        slopes[j] = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    out = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        v = x[i]
        if v != v:                  # NaN stays NaN
            y = v
        elif v > xp[m - 1]:
            y = fp[m - 1]
        elif v < xp[0]:
            y = fp[0]
        else:
            j = 0
            while j + 1 < m and v >= xp[j + 1]:
                j += 1
            if j == m - 1 or xp[j] == v:
                y = fp[j]
            else:
                y = slopes[j] * (v - xp[j]) + fp[j]
                if y != y:          # numpy tries the other end, then a flat segment's value
                    y = slopes[j] * (v - xp[j + 1]) + fp[j + 1]
                    if y != y and fp[j] == fp[j + 1]:
                        y = fp[j]
        out[i] = y
    return out


@njit(cache=True)
def add_hum(out: np.ndarray, n: int, true_start_s: float, first_sample: int, fs_true: float, grid_s: np.ndarray,
            amp_grid: np.ndarray, omega_rad_s: float, phase_rad: np.ndarray, weight: np.ndarray) -> None:
    """Add transformer hum to device samples ``first_sample`` … +n−1 held in ``out[:n]``: the samples' true
    times t_i = true_start + (first_sample + i)/fs_true, the unit-amplitude hum there (:func:`hum_samples`)
    times its amplitude interpolated linearly over ``grid_s`` (≤ 4 times, ascending) through ``amp_grid``
    (:func:`interp_like_numpy`). Compiled: numpy's form built the times, the amplitudes and the product as
    chunk-long arrays, each a pass over memory.
    """
    t_s = np.empty(n)
    for i in range(n):
        t_s[i] = true_start_s + (first_sample + i) / fs_true
    hum = hum_samples(t_s, 1.0 / fs_true, omega_rad_s, phase_rad, weight)
    amp = interp_like_numpy(t_s, grid_s, amp_grid)
    for i in range(n):
        out[i] += hum[i] * amp[i]


@dataclass
class _Plan:
    """One emission ready for its FFTs: its first sample, FFT length, band bins [k0, k1), the discrete paths'
    H on the band, the tail's taps (sample indices, amplitudes; each (n_taps,)) and their absorption on the band
    (None without taps)."""

    start: int
    n_fft: int
    k0: int
    k1: int
    h: np.ndarray
    taps: tuple[np.ndarray, np.ndarray] | None
    tail_gain: np.ndarray | None


@njit(cache=True)
def scatter_taps(taps: np.ndarray, row: np.ndarray, sample: np.ndarray, amplitude: np.ndarray) -> None:
    """taps[row[i], sample[i]] += amplitude[i] for every i in order (``numpy.bincount`` with weights, row by
    row: coinciding taps summed in the order drawn). taps : (m, n); row, sample, amplitude : (n_taps,)."""
    for i in range(row.shape[0]):
        taps[row[i], sample[i]] += amplitude[i]


@njit(cache=True)
def band_rows(u0: int, u1: int, k0: np.ndarray, k1: np.ndarray, h: np.ndarray, tail_spectra: np.ndarray,
              tail_row: np.ndarray, tail_gain: np.ndarray) -> np.ndarray:
    """The channel of each emission of a group on bins u0 … u1−1 (every row's band within them), zero off a
    row's band: row r, bins k0[r] … k1[r]−1, is H_r[k] + T_r[k]·g_r[k] (the discrete paths' response, the
    tail's spectrum times its absorption), or H_r alone when ``tail_row[r]`` is −1.

    k0, k1, tail_row : (m,); h : the rows' H concatenated, Σ(k1 − k0); tail_spectra : (m_t, n_fft/2 + 1)
    complex; tail_gain : the tails' g concatenated, one band per row with a tail. Returns (m, u1 − u0) complex,
    column j being bin u0 + j. T·g as numpy multiplies a complex by a real (the real promoted:
    (T_re·g − T_im·0) + j(T_re·0 + T_im·g)).
    """
    out = np.zeros((k0.shape[0], u1 - u0), np.complex128)
    at_h = at_g = 0
    for r in range(k0.shape[0]):
        t = tail_row[r]
        for k in range(k0[r], k1[r]):
            v = h[at_h]
            if t >= 0:
                tr, ti, g = tail_spectra[t, k].real, tail_spectra[t, k].imag, tail_gain[at_g]
                v += complex(tr * g - ti * 0.0, tr * 0.0 + ti * g)
                at_g += 1
            out[r, k - u0] = v
            at_h += 1
    return out


@njit(cache=True)
def band_responses(gain: np.ndarray, length_m: np.ndarray, delay_samples: np.ndarray, keep: np.ndarray,
                   diffracted: np.ndarray, first_path: np.ndarray, n_paths: np.ndarray, alpha_db_m: np.ndarray,
                   k0: np.ndarray, k1: np.ndarray, n_fft: np.ndarray, barrier_db: np.ndarray) -> np.ndarray:
    """:func:`band_response` of each emission of a batch over its kept paths, the loss of path p on bin k
    L_p[k] = α[k]·L_p (+ ΔL_p[k] for a diffracted path, Maekawa's barrier loss).

    Paths of all emissions concatenated (gain, length_m, delay_samples, keep, diffracted : (Σp,)), emission e's
    from ``first_path[e]``, ``n_paths[e]`` of them; alpha_db_m : α on each emission's band k0[e] … k1[e]−1,
    concatenated; barrier_db : ΔL of each kept diffracted path on its emission's band, in path order,
    concatenated. Returns the emissions' H concatenated, Σ(k1 − k0) complex.
    """
    out = np.empty(np.sum(k1 - k0), np.complex128)
    at_h = at_barrier = 0
    for e in range(k0.shape[0]):
        n_bins = k1[e] - k0[e]
        rows = np.flatnonzero(keep[first_path[e]:first_path[e] + n_paths[e]]) + first_path[e]
        loss_db = np.empty((rows.shape[0], n_bins))
        for r in range(rows.shape[0]):
            p = rows[r]
            for k in range(n_bins):
                loss_db[r, k] = alpha_db_m[at_h + k] * length_m[p]
            if diffracted[p]:
                for k in range(n_bins):
                    loss_db[r, k] += barrier_db[at_barrier + k]
                at_barrier += n_bins
        out[at_h:at_h + n_bins] = band_response(gain[rows], loss_db, delay_samples[rows], k0[e], n_fft[e])
        at_h += n_bins
    return out


def _chirp_lengths(specs: list[ChirpSpec], fs_hz: float, eta: np.ndarray) -> np.ndarray:
    """:func:`~simulation.acoustic.chirp.chirp_length` of each (spec, η): ceil(round(T·fs)/η), (n,) integers."""
    if not np.all((eta > 0.9) & (eta < 1.1)):
        raise ValueError(f"time_scale must lie near 1 (|v| << c), got {eta[~((eta > 0.9) & (eta < 1.1))][0]}")
    n_ref = np.array([chirp_length(spec, fs_hz) for spec in specs])
    return np.ceil(n_ref / eta).astype(np.int64)


@functools.lru_cache(maxsize=4096)
def _fast_len(n: int) -> int:
    """``scipy.fft.next_fast_len(n, real=True)``, remembered (an emission's length recurs)."""
    return sfft.next_fast_len(n, real=True)


def _rfft_rows(x: np.ndarray, n: int) -> np.ndarray:
    return sfft.rfft(x, n, axis=-1)


def _by_length(transform, rows: list[tuple[int, np.ndarray | None]]) -> list[np.ndarray | None]:
    """``transform(stack, n)`` over the rows of each length n at once; None rows stay None. Row order kept."""
    out: list[np.ndarray | None] = [None] * len(rows)
    by_n: dict[int, list[int]] = {}
    for i, (n, x) in enumerate(rows):
        if x is not None:
            by_n.setdefault(n, []).append(i)
    for n, idx in by_n.items():
        result = transform(np.stack([rows[i][1] for i in idx]), n)
        for j, i in enumerate(idx):
            out[i] = result[j]
    return out


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


class AmbientNoise:
    """Noise, hum and corona clicks of one recording, drawn per fixed chunk of samples.

    Chunk ``k`` (``CHUNK_SAMPLES`` samples) takes its draws from
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
        self.tanks = boxes_array([b for b in site.layout if b.kind == "transformer"])
        self.hum_phase = stream_rng(seed, "audio", "hum").uniform(0.0, 2.0 * np.pi, 4)
        self.discharges = DischargeSources(
            site, DischargeConfig(rate_hz=cfg.corona_rate_hz, active_share=cfg.corona_active_share,
                                  level_db_spl=cfg.corona_level_db_spl, phase_window_deg=cfg.corona_phase_window_deg,
                                  mains_hz=cfg.mains_hz),
            fs, float(stream_rng(seed, "audio", "mains").uniform(0.0, 2.0 * np.pi)), speed_of_sound_m_s(
                site.atmosphere.temperature_c))
        # Pulses more than 10 dB below the in-band noise are not rendered (they are drawn all the same).
        self.pulse_floor_db_spl = cfg.inband_noise_db_spl - 10.0
        self._rngs: dict[int, np.random.Generator] = {}

    def chunk(self, k: int, n: int) -> np.ndarray:
        """Ambient samples of chunk ``k`` (device samples k·CHUNK_SAMPLES …), length ``n`` plus click overhang."""
        cfg = self.cfg
        if k not in self._rngs:     # the next chunks' generators seeded at once (they are met in order)
            self._rngs = dict(zip(range(k, k + 64), stream_rngs(self.seed, ("audio", "noise"),
                                                               np.arange(k, k + 64)[:, None])))
        rng = self._rngs.pop(k)
        click_len = self.discharges.template_len
        out = np.zeros(n + click_len)
        rng.standard_normal(n, out=out[:n])          # drawn in place: the same values as into a new array
        out[:n] *= self.noise_rms
        b0 = k * CHUNK_SAMPLES
        grid = self.true_start + (b0 + np.array([0.0, n / 2.0, float(n)])) / self.fs_true
        pos = np.column_stack([np.interp(grid, self.traj.t_s, self.traj.east_m),
                               np.interp(grid, self.traj.t_s, self.traj.north_m)])
        if self.tanks.shape[0] and cfg.hum_db_spl_1m > -np.inf:
            d = np.maximum(_distance_to_boxes(pos, self.tanks), 1.0)
            # 2·mains and harmonics (magnetostriction), −3 dB each, falling 1/r from the nearest tank
            add_hum(out, n, self.true_start, b0, self.fs_true, grid,
                    _db_to_digital_rms(cfg.hum_db_spl_1m, cfg) * math.sqrt(2.0) / d, 2.0 * np.pi * 2.0 * cfg.mains_hz,
                    self.hum_phase, _HUM_WEIGHTS)
        if cfg.corona_rate_hz > 0:
            t0 = self.true_start + b0 / self.fs_true
            up = float(np.interp(grid[1], self.traj.t_s, self.traj.up_m))
            self.discharges.add_pulses(out, rng, t0, t0 + n / self.fs_true, self.fs_true,
                                       np.array([pos[1, 0], pos[1, 1], up]), cfg.full_scale_db_spl,
                                       self.pulse_floor_db_spl)
        return out
