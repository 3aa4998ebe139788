"""Streaming beacon-chirp detection: which beacon was heard when, and its CIR.

Frame and clock timing follow the beacon protocol as summarised in
:mod:`features.acoustic.timing` (docs/beacon_protocol.md).

Association. Beacons share one chirp and are told apart by time alone, so
the search window of each (frame, beacon) is narrowed as soon as the receiver
knows where it is: see :mod:`features.acoustic.tracking` (acquisition, then
tracking of the position and the drifting clock offset).

Detection (Neyman–Pearson on the matched-filter envelope; Kay, "Fundamentals
of Statistical Signal Processing, Vol. II: Detection", 1998, §7.6). For each
(frame, beacon) the chirp must start inside its window (in acquisition
``[t_tx − u, t_tx + u + r_max/c]``, u = start uncertainty, r_max = largest
range at which a beacon is heard). In noise alone the envelope of the analytic
matched-filter output is Rayleigh with scale σ, P(env > γ) = exp(−γ²/2σ²).
σ comes from the 25th percentile of the envelope over the preceding frame,
σ = q₂₅ / sqrt(−2 ln 0.75) — a quantile that stays on noise while up to three
quarters of the frame holds signal. The envelope decorrelates after about 1/B
(B = chirp bandwidth), so a window of W seconds holds N ≈ W·B independent
cells; requiring a false-alarm probability ``p_fa`` per window gives

    γ = σ · sqrt(2 ln(N / p_fa))

(union bound). With the defaults (p_fa = 1e-6, W ≈ 0.1 s, B = 6 kHz) γ ≈ 6.4σ,
16 dB above the noise scale: about one false chirp per 300 hours of audio.

Pulse compression (issue 12, item 2). An envelope maximum above γ is a chirp only if
the matched filter compressed it: a linear chirp of bandwidth B and length T folds
into a main lobe about 1/B wide (Cook & Bernfeld, "Radar Signals", 1967, ch. 6;
the pulse-compression ratio B·T = 60 here), while an impulse (a switching
transient, a corona click, the onset of a tone) or an in-band tone comes out of
the same filter as the template's own envelope, a plateau T long. So a
detection must have (i) a −6 dB peak width of at most ``_MAX_PEAK_WIDTH_S``
(1 ms = 6/B, room for an unresolved ground reflection) and (ii) at least
``_MIN_COMPRESSED_SHARE`` (10 %) of the signal energy (noise power subtracted)
of its timing span (±``max_lead_s``) within half a −20 dB main lobe of the peak — on
simulated walks the detections hold a median 75 % (1 % of them below 11 %),
a click's plateau about 20 % of its ±2.5 ms span, so the width test does
most of the work; it passes about 1 % of clicks (two clicks within a chirp
length beat into narrow peaks). Measured (``bench/false_chirps.py``): noise
with 2 clicks/s gave 5,550 false chirps per hour, then 72 (and none since impulses are removed before the
filter, :mod:`features.acoustic.impulses`: at the rates HV equipment emits them, 10 a second, the test
alone let 44 a minute through on a 24-beacon deployment); a 1 kHz tone 120
per hour, now 0; the real ultrasense phone recordings 0 before and after. On six
held-out simulated walks the test kept every true chirp the receiver found
before (6,496 against 6,319: tracking holds better) and removed 11 % of the
other detections; fixes 678 → 723.

A detected chirp's CIR spans ``max_lead_s`` before to ``cir_span_s`` (15 ms,
5 m of excess path) after the located arrival, on the decimated envelope;
:func:`features.acoustic.cir.first_arrivals` times its first arrival in the frame (tracking
needs it at once) and :func:`features.acoustic.cir.analyse_cirs` computes the nine
features for 32 frames at a time. The span is short on purpose:
slots are 0.1 s apart but ranges differ by tens of metres, so a 30 ms span
often takes in another beacon's chirp, which in open areas (many audible
beacons) inflated the mean excess delay above that of heavy cells (simulated
survey, 94 cells: 4.1 vs 3.6 ms with 30 ms; 1.0 vs 2.6 ms with 15 ms).
"""


from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Iterator

import numpy as np
from numba import njit

from features.acoustic.positions import AcousticFix, PositionConfig
from features.acoustic.timing import AudioTiming, ChirpDetection, SearchWindow, frame_phase_s, speed_of_sound_m_s
from features.acoustic.tracking import ClockPositionTracker, ReceiverState, acquisition_windows, frame_fix
from features.acoustic.audio import CLIP_LEVEL, AudioBlock, audio_info, count_clipped, iter_audio_blocks
from features.acoustic.cir import CirFeatures, analyse_cirs, first_arrivals
from features.constants import AUDIO_FS_HZ
from features.errors import ConfigError
from features.acoustic.impulses import ImpulseBlanker
from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank, StreamingMatchedFilter
from features.site import Beacon, Site

__all__ = ["AudioTiming", "DetectorConfig", "ChirpDetection", "FrameResult", "AudioStats", "speed_of_sound_m_s",
           "frame_phase_s", "beacon_chirp_spec", "detect_frames", "frame_fix", "max_site_range_m"]

_FEATURE_BATCH_FRAMES = 32
"""Frames whose CIR features are computed in one batch (results are yielded that much later)."""

_NO_FEATURES = CirFeatures(*([float("nan")] * 9))

_SIDELOBE_GUARD = 10 ** (25 / 20)
"""A maximum this much (25 dB) weaker than a neighbour within one chirp length is a sidelobe."""
_ECHO_SPAN_S = 0.015
"""Acquisition ignores maxima this soon after a stronger one (its echoes and diffuse tail), s."""
_MAX_PEAK_WIDTH_S = 0.001
"""Widest −6 dB peak accepted as a compressed chirp, s (6 times 1/B; a click's is the chirp's 10 ms)."""
_MIN_COMPRESSED_SHARE = 0.1
"""Least share of the timing span's signal energy within half a main lobe of a chirp's peak (module docstring)."""
_SILENCE_REL = 1e-6
"""Envelope values below this fraction of the segment's largest are digital silence, not noise
(float32 round-off of the matched filter over exact zeros is ~1e-7 of the block's largest output)."""
_RAYLEIGH_Q25 = math.sqrt(-2.0 * math.log(0.75))
"""25th percentile of a unit-scale Rayleigh variable."""




@dataclass(frozen=True)
class DetectorConfig:
    """Detection and CIR parameters (see the module docstring)."""

    p_fa: float = 1e-6
    max_range_m: float | None = None
    cir_span_s: float = 0.015
    max_lead_s: float = 0.0025
    block_s: float = 4.0
    fs_hz: int = AUDIO_FS_HZ
    impulse_ratio: float = 8.0
    impulse_hold_s: float = 0.0005

    def __post_init__(self):
        if not (self.impulse_ratio == 0 or 3.0 <= self.impulse_ratio < 1e6):
            raise ConfigError(f"impulse_ratio must be 0 (no blanking) or in [3, 1e6), got {self.impulse_ratio}")
        if not 0 <= self.impulse_hold_s <= 0.01:
            raise ConfigError(f"impulse_hold_s must lie in [0, 0.01] s, got {self.impulse_hold_s}")
        if not 0 < self.p_fa < 1:
            raise ConfigError(f"p_fa must lie in (0, 1), got {self.p_fa}")
        if self.max_range_m is not None and not self.max_range_m > 0:
            raise ConfigError(f"max_range_m must be positive, got {self.max_range_m}")
        for name in ("cir_span_s", "max_lead_s", "block_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be positive, got {getattr(self, name)}")



@dataclass
class AudioStats:
    """Per-bin statistics of the samples, for flagging windows (bins of ``bin_s``)."""

    bin_s: float
    n_samples: list
    n_clipped: list
    sum_sq: list
    truncated: bool = False
    duration_s: float = 0.0

    def add(self, block: AudioBlock, fs_hz: float) -> None:
        """Fold one block into the per-bin counts (bins of ``bin_s`` from the stream's first sample)."""
        bin_len = int(round(self.bin_s * fs_hz))
        x = block.samples
        if len(x) == 0:
            return
        first_bin = block.start_index // bin_len
        head = min(len(x), (first_bin + 1) * bin_len - block.start_index)
        parts = [(first_bin, x[:head])]
        body = x[head:]
        n_full = len(body) // bin_len
        need = first_bin + 1 + n_full + (1 if len(body) % bin_len else 0)
        for lst in (self.n_samples, self.n_clipped, self.sum_sq):
            lst.extend([0] * (need - len(lst)))
        any_clipped = count_clipped(x) > 0
        for b, seg in parts + [(first_bin + 1 + n_full, body[n_full * bin_len:])]:
            if len(seg):
                self.n_samples[b] += len(seg)
                self.n_clipped[b] += count_clipped(seg) if any_clipped else 0
                self.sum_sq[b] += float(np.dot(seg, seg))
        if n_full:
            full = body[: n_full * bin_len].reshape(n_full, bin_len)
            clipped = (np.count_nonzero(np.abs(full) >= CLIP_LEVEL, axis=1) if any_clipped
                       else np.zeros(n_full, dtype=int))
            # float32 sums (relative error ~1e-5 over a 0.1 s bin): the energy only flags silence.
            energy = np.einsum("ij,ij->i", full, full)
            bins = slice(first_bin + 1, first_bin + 1 + n_full)
            self.n_samples[bins] = [v + bin_len for v in self.n_samples[bins]]
            self.n_clipped[bins] = [v + int(k) for v, k in zip(self.n_clipped[bins], clipped.tolist())]
            self.sum_sq[bins] = [v + e for v, e in zip(self.sum_sq[bins], energy.tolist())]



def beacon_chirp_spec(site: Site, beacon: Beacon) -> ChirpSpec:
    """The chirp of ``beacon``: its own band/duration where given, else the site's ``[acoustic]``."""
    ac = site.acoustic
    return ChirpSpec(ac.f0_hz if beacon.f0_hz is None else beacon.f0_hz,
                     ac.f1_hz if beacon.f1_hz is None else beacon.f1_hz,
                     ac.chirp_duration_s if beacon.chirp_duration_s is None else beacon.chirp_duration_s,
                     ac.taper_fraction)


def max_site_range_m(site: Site) -> float:
    """Largest beacon-to-receiver distance on the site's grid (3-D, device at its height), m."""
    g = site.grid
    corners = [(e, n) for e in (g.east_min_m, g.east_max_m) for n in (g.north_min_m, g.north_max_m)]
    best = 0.0
    for b in site.beacons:
        for e, n in corners:
            best = max(best, math.dist((b.east_m, b.north_m, b.up_m), (e, n, site.device_height_m)))
    return best



@dataclass(frozen=True)
class FrameResult:
    """One TDMA frame: the chirps detected in it and the position fix (None if none); ``receiver_state`` the
    receiver's state before this frame when it was asked to keep it (:func:`detect_frames`), else None."""

    frame: int
    frame_start_s: float
    detections: tuple
    fix: AcousticFix | None
    tracking: bool
    receiver_state: ReceiverState | None = None


class _Stream:
    """Decimated matched-filter envelopes of the recent past, read on demand (impulses blanked first,
    :mod:`features.acoustic.impulses`)."""

    def __init__(self, path, config: DetectorConfig, mf: StreamingMatchedFilter, stats: AudioStats | None,
                 first_sample: int = 0):
        self.blocks = iter_audio_blocks(path, block_s=config.block_s, fs_out_hz=int(config.fs_hz),
                                        first_index=first_sample)
        self.mf, self.stats, self.fs = mf, stats, float(config.fs_hz)
        self.first_sample = first_sample
        self.blanker = ImpulseBlanker(self.fs, config.impulse_ratio, hold_s=config.impulse_hold_s,
                                      first_index=first_sample)
        self.read_end = first_sample  # input samples filtered so far (the blanker may hold a few back)
        self.env = np.zeros((mf.bank.n_templates, 0), dtype=np.float32)
        self.env_j0 = first_sample // mf.decimation   # the matched filter's first output (its decimation grid)
        self.eof = False

    def ensure(self, upto: int) -> None:
        """Read until input sample ``upto`` has been filtered (and its envelope exists) or the file ends."""
        while not self.eof and self.read_end < upto:
            block = next(self.blocks, None)
            if block is None:
                self.eof = True
                rest = self.blanker.flush()
                _, e = self.mf.process(rest)
                _, e2 = self.mf.flush()
                e = np.concatenate([e, e2], axis=1)
                self.read_end += len(rest)
            else:
                if self.stats is not None:           # per-bin statistics from the file's first sample
                    self.stats.add(dataclasses.replace(block, start_index=block.start_index - self.first_sample)
                                   if self.first_sample else block, self.fs)
                x = self.blanker.process(block.samples)
                self.read_end += len(x)
                _, e = self.mf.process(x)
            self.env = np.concatenate([self.env, e], axis=1) if self.env.shape[1] else e

    def env_range(self, j_lo: int, j_hi: int) -> tuple[int, np.ndarray]:
        a = max(j_lo - self.env_j0, 0)
        b = max(min(j_hi - self.env_j0, self.env.shape[1]), a)
        return self.env_j0 + a, self.env[:, a:b]

    def trim(self, keep_from: int) -> None:
        """Forget the envelope of chirps starting before input sample ``keep_from``."""
        cut_env = (keep_from + self.mf.bank.delay_samples) // self.mf.decimation - self.env_j0
        if cut_env > 0:
            self.env = self.env[:, cut_env:]
            self.env_j0 += cut_env



def detect_frames(path: str | os.PathLike, site: Site, timing: AudioTiming,
                  config: DetectorConfig = DetectorConfig(), stats: AudioStats | None = None,
                  positions: PositionConfig | None = None, resume: ReceiverState | None = None,
                  keep_state_from_s: float = math.inf, first_sample: int = 0) -> Iterator[FrameResult]:
    """Stream ``path`` frame by frame: the chirps detected in each TDMA frame and its fix.

    Per frame, in order (each step a method of :class:`_FrameDetector`):

    1. *track* — the search windows of the frame's (frame, beacon) pairs from the
       tracker (:class:`~features.acoustic.tracking.ClockPositionTracker`);
    2. *detect* — noise scale per template, envelope maxima above the
       Neyman–Pearson threshold (:meth:`_FrameDetector.detect`);
    3. *acquire* — without a lock, candidate arrivals are voted into a position
       and clock hypothesis (:func:`~features.acoustic.acquisition.acquisition_windows`);
    4. *assign* — one physical arrival per window (:meth:`_FrameDetector.assign_arrivals`);
    5. *time* — first arrival of each chirp on its CIR (:meth:`_FrameDetector.time_arrivals`);
    6. *solve* — the tracker's fix from the timed arrivals;
    7. *features* — the nine CIR features, in batches of frames (:meth:`_FrameDetector.flush_features`).

    Memory is bounded by one audio block plus about two frames of history,
    whatever the file length. ``stats`` (optional) receives per-bin sample
    counts, clipping and energy for window flags. ``positions`` defaults to a
    clock-offset bound of the stated start uncertainty plus 50 ms.

    A long walk read in cuts (``walks/segments.py``): ``resume``, the state a run over the preceding cut kept,
    replaces the tracker's before its frame (the frames before it are the cut's warm-up: the audio buffers
    fill); ``keep_state_from_s``: the first frame starting at or after this walk time carries the receiver's
    state before it (:attr:`FrameResult.receiver_state`), for the next cut.

    ``first_sample``: the index, in the whole recording, of the file's first sample when the file is such a
    cut; ``timing`` is then the whole recording's (``start_s`` the time of its sample 0). Every sample index of
    the receiver is then the whole recording's: the audio blocks, the impulse blanker's segments, the matched
    filter's FFT blocks and decimation grid lie where the whole run's do, and the search windows and arrival
    times are computed from the same numbers, so that once the buffers have filled (and the tracker is resumed)
    the cut's detections are the whole run's to the bit (whereas aligned on the cut's first sample, a round-off
    difference near a threshold could flip a detection or a tracking decision). 0 (a whole recording) is the
    recording's own alignment.
    """
    if not (isinstance(first_sample, (int, np.integer)) and first_sample >= 0):
        raise ConfigError(f"first_sample must be a sample index >= 0, got {first_sample!r}")
    if not site.beacons:
        return
    fs = float(config.fs_hz)
    info = audio_info(path)
    n_file = int(math.ceil(info.n_frames * fs / info.fs_hz))
    n_total = first_sample + n_file
    if stats is not None:
        stats.truncated = info.truncated
        stats.duration_s = n_file / fs
    timing = _frame_safe_timing(site, timing, config)
    if positions is None:
        positions = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05)
    det = _FrameDetector(path, site, timing, config, stats, positions, n_total, first_sample)
    yield from det.frames(resume, keep_state_from_s)


@njit(cache=True)
def _envelope_maxima(seg: np.ndarray, gamma: float, strong_level: float, dec: int, template_len: int) -> np.ndarray:
    """Indices (ascending) of the local maxima of the envelope ``seg`` (float32, length ≥ 3) above ``gamma``,
    less the sidelobes (see :meth:`_FrameDetector.prepare_maxima`).

    Interior maxima rise above the left neighbour and are not below the right one; the ends count when above
    the neighbour inside (as if padded with zeros). A maximum within one chirp length (``template_len``
    samples, taps ``dec`` apart) of one more than :data:`_SIDELOBE_GUARD` stronger is dropped; only a maximum
    above ``strong_level`` (γ·guard) can be one. Levels and products are float32, as numpy forms them for the
    float32 envelope and a Python float (NEP 50).

    Maxima above 1.5 at 0, 2, 4 and 6; 3 and 5 lie within 3 samples of 900 and more than 25 dB below it:

    >>> _envelope_maxima(np.array([2, 1, 3, 1, 900, 2, 5, 4], np.float32), 1.5, 1.5 * _SIDELOBE_GUARD, 1, 3).tolist()
    [0, 4]
    """
    n = seg.shape[0]
    g, gs, guard = np.float32(gamma), np.float32(strong_level), np.float32(_SIDELOBE_GUARD)
    idx = np.empty(n, dtype=np.int64)
    m = 0
    if seg[0] > g and seg[0] >= seg[1]:
        idx[m] = 0
        m += 1
    for i in range(1, n - 1):
        if seg[i] > g and seg[i] > seg[i - 1] and seg[i] >= seg[i + 1]:
            idx[m] = i
            m += 1
    if seg[n - 1] > g and seg[n - 1] > seg[n - 2]:
        idx[m] = n - 1
        m += 1
    strong = np.empty(m, dtype=np.int64)
    n_strong = 0
    for a in range(m):
        if seg[idx[a]] > gs:
            strong[n_strong] = idx[a]
            n_strong += 1
    if n_strong == 0 or m < 2:
        return idx[:m].copy()
    out = np.empty(m, dtype=np.int64)
    k = 0
    for a in range(m):
        level = seg[idx[a]] * guard
        sidelobe = False
        for b in range(n_strong):
            if abs(idx[a] - strong[b]) * dec <= template_len and seg[strong[b]] > level:
                sidelobe = True
                break
        if not sidelobe:
            out[k] = idx[a]
            k += 1
    return out[:k].copy()


def _noise_scales(seg: np.ndarray) -> np.ndarray:
    """Rayleigh scale σ = q₂₅ / sqrt(−2 ln 0.75) of each row of the envelope ``seg`` (n_templates, L ≥ 1),
    float32, from every 4th output (neighbours are correlated over ~1/B anyway, and it is 4× cheaper); shape
    (n_templates,). The quartile is an order statistic, the same value whichever selection finds it: numpy's
    introselect, five times faster here than numba's.

    Digital silence (exact zero samples: a muted or not yet started input) is not noise: its envelope is 0, or
    float32 round-off of the FFT blocks it shares with sound (below :data:`_SILENCE_REL` of the loudest output).
    Left in, it pulled the quantile to ~0, the SNR to 126–3000 dB, and let the first noise after it pass for
    chirps (issue 12, item 4). So when any row's quartile is not above that fraction of its largest output,
    every row's quartile is taken over its outputs above it (0 when there are none).

    >>> (_noise_scales(np.array([[0.0, 9, 9, 9, 1, 9, 9, 9, 2, 9, 9, 9, 3, 9, 9, 9]], np.float32))
    ...  * _RAYLEIGH_Q25).round(12).tolist()
    [1.0]
    """
    sub = seg[:, ::4]
    k = sub.shape[1] // 4
    q25 = np.partition(sub, k, axis=1)[:, k].astype(np.float64)
    peak = sub.max(axis=1).astype(np.float64)
    if np.all(q25 > _SILENCE_REL * peak):
        return q25 / _RAYLEIGH_Q25
    out = np.zeros(seg.shape[0])
    for t in range(seg.shape[0]):
        row = sub[t]
        nz = row[row > np.float32(_SILENCE_REL * peak[t])]          # compared in float32, as the row
        if len(nz):
            out[t] = np.float64(np.partition(nz, len(nz) // 4)[len(nz) // 4]) / _RAYLEIGH_Q25
    return out


@njit(cache=True)
def _thresholds(width: np.ndarray, bandwidth_hz: np.ndarray, sigma: np.ndarray, fs: float,
                log_inv_p_fa: float) -> np.ndarray:
    """Detection threshold γ of each window (module docstring): γ = σ·sqrt(2·(ln max(N, 1) + ln(1/p_fa))),
    N = W·B cells in a window ``width`` samples long, at least 1e-9; shape (n,).

    A 0.1 s window at 6 kHz (N = 600, p_fa = 1e-6): sqrt(2·(6.3969 + 13.8155)) = 6.358 σ.

    >>> round(float(_thresholds(np.array([4800]), np.array([6000.0]), np.array([1.0]), 48000.0,
    ...                         -math.log(1e-6))[0]), 3)
    6.358
    """
    out = np.empty(width.shape[0])
    for k in range(width.shape[0]):
        n_cells = width[k] / fs * bandwidth_hz[k]
        gamma = sigma[k] * math.sqrt(2.0 * (math.log(n_cells if n_cells > 1.0 else 1.0) + log_inv_p_fa))
        out[k] = gamma if gamma > 1e-9 else 1e-9
    return out


@njit(cache=True)
def _assign(jj: np.ndarray, hh: np.ndarray, t_off: np.ndarray, tmpl: np.ndarray, j_lo: np.ndarray, j_hi: np.ndarray,
            gamma: np.ndarray, associated: np.ndarray, expected: np.ndarray, has_expected: np.ndarray, dec: int,
            delay: int, gap: float, echo: float) -> tuple[np.ndarray, np.ndarray]:
    """The assignment of :meth:`_FrameDetector.assign_arrivals`, compiled: (window index, chirp start) of each
    claim, in the order claimed; shapes (n_claims,).

    Window k (template ``tmpl[k]``, decimated range ``[j_lo[k], j_hi[k])``, threshold ``gamma[k]``) takes from
    the frame's maxima of its template (``jj[t_off[t]:t_off[t + 1]]``, ascending, heights ``hh``) the peaks above
    its threshold, as chirp starts ``dec·j − delay``; an unassociated window its strongest only (the first of the
    largest). Windows with a peak are taken associated first, each group in window order. When no two first
    peaks of one template lie within ``gap`` samples, each window keeps its first; otherwise up to four rounds:
    each pending window takes its first peak that is not within [−gap, echo] of an arrival claimed in an earlier
    round; a rival within ``gap`` taken in this round keeps it unless both are associated and the newcomer's
    ``expected`` arrival (where ``has_expected``) lies strictly nearer; the loser waits for the next round.

    Two windows see the same arrival (starts 4·10 − 0 = 40 and 4·12 = 48, gap 10): the second, associated and
    predicted at 41, takes it from the first (predicted at 60), which then takes its next peak, 120:

    >>> [a.tolist() for a in _assign(np.array([10, 12, 30]), np.array([5.0, 6.0, 5.0], np.float32), np.array([0, 3]),
    ...     np.zeros(2, np.int64), np.array([0, 11]), np.array([40, 13]), np.array([1.0, 1.0]), np.array([True, True]),
    ...     np.array([60, 41]), np.array([True, True]), 4, 0, 10.0, 5.0)]
    [[1, 0], [48, 120]]
    """
    n = tmpl.shape[0]
    # Each window's candidate starts, flattened (window k's at [c_off[k], c_off[k + 1])).
    c_off = np.zeros(n + 1, dtype=np.int64)
    cand = np.empty(jj.shape[0] * n if n else 0, dtype=np.int64)
    m = 0
    for k in range(n):
        lo, hi = t_off[tmpl[k]], t_off[tmpl[k] + 1]
        best = -1
        for i in range(lo + np.searchsorted(jj[lo:hi], j_lo[k]), lo + np.searchsorted(jj[lo:hi], j_hi[k])):
            if np.float64(hh[i]) > gamma[k]:
                if associated[k]:
                    cand[m] = dec * jj[i] - delay
                    m += 1
                elif best < 0 or hh[i] > hh[best]:
                    best = i
        if best >= 0:
            cand[m] = dec * jj[best] - delay
            m += 1
        c_off[k + 1] = m
    pending = np.empty(n, dtype=np.int64)
    n_pending = 0
    for group in (True, False):
        for k in range(n):
            if associated[k] == group and c_off[k + 1] > c_off[k]:
                pending[n_pending] = k
                n_pending += 1
    first = np.empty(n_pending, dtype=np.int64)
    for a in range(n_pending):
        first[a] = cand[c_off[pending[a]]]
    # The common case: no two windows' first peaks are one arrival; each window keeps its own.
    by = np.argsort(first, kind="mergesort")
    by = by[np.argsort(tmpl[pending[by]], kind="mergesort")]
    clash = False
    for a in range(n_pending - 1):
        u, v = pending[by[a]], pending[by[a + 1]]
        if tmpl[u] == tmpl[v] and not first[by[a + 1]] - first[by[a]] > gap:
            clash = True
            break
    if not clash:
        return pending[:n_pending].copy(), first
    claim_w = np.empty(n, dtype=np.int64)
    claim_s = np.empty(n, dtype=np.int64)
    n_claims = 0
    taken_w = np.empty(n, dtype=np.int64)
    taken_s = np.empty(n, dtype=np.int64)
    losers = np.empty(n, dtype=np.int64)
    for _ in range(4):                       # a few rounds of re-assignment settle every case seen
        n_taken = 0
        n_losers = 0
        for a in range(n_pending):
            w = pending[a]
            t = tmpl[w]
            # Nor the echoes and tail of a claimed arrival (up to ``echo`` after it).
            sp = 0
            found = False
            for i in range(c_off[w], c_off[w + 1]):
                free = True
                for c in range(n_claims):
                    if tmpl[claim_w[c]] == t and -gap <= cand[i] - claim_s[c] <= echo:
                        free = False
                        break
                if free:
                    sp, found = cand[i], True
                    break
            if not found:
                continue
            rival = -1
            for r in range(n_taken):
                if tmpl[taken_w[r]] == t and abs(sp - taken_s[r]) <= gap:
                    rival = r
                    break
            if rival < 0:
                taken_w[n_taken], taken_s[n_taken] = w, sp
                n_taken += 1
                continue
            w2 = taken_w[rival]
            cost_w = abs(sp - expected[w]) if has_expected[w] else 0
            cost_w2 = abs(sp - expected[w2]) if has_expected[w2] else 0
            if associated[w] and associated[w2] and cost_w < cost_w2:
                taken_w[rival], taken_s[rival] = w, sp
                losers[n_losers] = w2
            else:
                losers[n_losers] = w
            n_losers += 1
        claim_w[n_claims: n_claims + n_taken] = taken_w[:n_taken]
        claim_s[n_claims: n_claims + n_taken] = taken_s[:n_taken]
        n_claims += n_taken
        if n_losers == 0:
            break
        pending[:n_losers] = losers[:n_losers]
        n_pending = n_losers
    return claim_w[:n_claims].copy(), claim_s[:n_claims].copy()


@njit(cache=True)
def _compressed(rows: np.ndarray, centre: int, main_taps: int, max_width_taps: int, noise_power: float) -> np.ndarray:
    """Whether each envelope row of ``rows`` (k, L) (a CIR's first taps, decimated) around tap ``centre`` is a
    compressed chirp: the −6 dB width of its peak at most ``max_width_taps``, and at least
    :data:`_MIN_COMPRESSED_SHARE` of the row's signal energy (noise power subtracted) within
    ``main_taps`` of the peak (see the module docstring, "Pulse compression"); (k,) bool.

    >>> lobe = [0.0] * 20 + [0.3, 1.0, 0.3] + [0.0] * 20
    >>> _compressed(np.array([lobe, [0.0] * 10 + [1.0] * 30 + [0.0] * 3]), 21, 2, 12, 1e-6).tolist()
    [True, False]
    """
    k, n = rows.shape
    out = np.zeros(k, dtype=np.bool_)
    lo = centre - 2 if centre > 2 else 0
    hi = centre + 3 if centre + 3 < n else n
    if lo >= hi:
        return out
    for r in range(k):
        row = rows[r]
        p = lo
        for i in range(lo + 1, hi):                        # the first of the largest
            if row[i] > row[p]:
                p = i
        half = 0.5 * row[p]
        left = p
        wide = False
        while left > 0 and row[left - 1] >= half:
            left -= 1
            if p - left >= max_width_taps:
                wide = True
                break
        right = p
        while not wide and right < n - 1 and row[right + 1] >= half:
            right += 1
            if right - left >= max_width_taps:
                wide = True
        if wide:
            continue
        a = p - main_taps if p > main_taps else 0
        b = min(p + main_taps + 1, n)
        e_main = 0.0
        for i in range(a, b):
            e_main += row[i] * row[i]
        e_main -= (b - a) * noise_power
        e_all = 0.0
        for i in range(n):
            e_all += row[i] * row[i]
        e_all -= n * noise_power
        out[r] = e_all > 0 and e_main >= _MIN_COMPRESSED_SHARE * e_all
    return out


@njit(cache=True)
def _candidates(jj: np.ndarray, hh: np.ndarray, t_off: np.ndarray, tmpl: np.ndarray, j_lo: np.ndarray,
                j_hi: np.ndarray, gamma: np.ndarray, dec: int, delay: int, echo: float, max_candidates: int):
    """The acquisition candidates of each window (:meth:`_FrameDetector.candidates`): (chirp starts, heights
    (float64), ``c_off`` (window k's at ``[c_off[k], c_off[k + 1])``), how many to keep, whether two heights tie).

    Window k (template ``tmpl[k]``, decimated range ``[j_lo[k], j_hi[k])``, threshold ``gamma[k]``) takes the
    frame's maxima of its template (``jj[t_off[t]:t_off[t + 1]]``, ascending, float32 heights ``hh``) above its
    threshold, as chirp starts ``dec·j − delay``; a maximum whose start lies within (0, ``echo``] samples after
    that of a stronger one is dropped; of the rest, in order of decreasing height, the first
    ``max_candidates`` are kept (the first ``n_kept[k]`` of the window's entries). Where two of the rest have
    equal heights the entries are left in start order (``tied``) for numpy's argsort to order them.

    Maxima at 10, 12 (an echo of 10, 8 samples later) and 40; threshold 1: starts 40 and 10, strongest first:

    >>> [a.tolist() for a in _candidates(np.array([10, 12, 40]), np.array([5.0, 2.0, 6.0], np.float32),
    ...     np.array([0, 3]), np.zeros(1, np.int64), np.array([0]), np.array([50]), np.array([1.0]), 4, 0, 10.0, 12)]
    [[160, 40], [6.0, 5.0], [0, 2], [2], [False]]
    """
    n = tmpl.shape[0]
    starts = np.empty(jj.shape[0] * n if n else 0, dtype=np.int64)
    heights = np.empty(starts.shape[0])
    c_off = np.zeros(n + 1, dtype=np.int64)
    n_kept = np.zeros(n, dtype=np.int64)
    tied = np.zeros(n, dtype=np.bool_)
    m = 0
    for k in range(n):
        lo, hi = t_off[tmpl[k]], t_off[tmpl[k] + 1]
        a = lo + np.searchsorted(jj[lo:hi], j_lo[k])
        b = max(a, lo + np.searchsorted(jj[lo:hi], j_hi[k]))
        first = m
        for i in range(a, b):
            if np.float64(hh[i]) > gamma[k]:
                starts[m] = dec * jj[i] - delay
                heights[m] = np.float64(hh[i])
                m += 1
        # Echoes: within (0, echo] after a stronger maximum.
        kept = first
        for x in range(first, m):
            shadowed = False
            for y in range(first, m):
                lag = starts[x] - starts[y]
                if lag > 0 and lag <= echo and heights[y] > heights[x]:
                    shadowed = True
                    break
            if not shadowed:
                starts[kept], heights[kept] = starts[x], heights[x]
                kept += 1
        m = kept
        c_off[k + 1] = m
        order = np.argsort(heights[first:m])
        for r in range(1, m - first):
            if heights[first + order[r]] == heights[first + order[r - 1]]:
                tied[k] = True
        if not tied[k]:
            # Distinct heights: one descending order whatever the sort; the strongest first.
            s_sorted = starts[first:m][order[::-1]].copy()
            h_sorted = heights[first:m][order[::-1]].copy()
            starts[first:m], heights[first:m] = s_sorted, h_sorted
        n_kept[k] = min(m - first, max_candidates)
    return starts[:m], heights[:m], c_off, n_kept, tied


def _frame_safe_timing(site: Site, timing: AudioTiming, config: DetectorConfig) -> AudioTiming:
    """The timing with a start uncertainty u for which one chirp falls in one frame's windows only.

    Acquisition looks for beacon b's chirp of frame k in ``[t_tx − u, t_tx + u + r_max/c]``;
    the same beacon's window in frame k + 1 starts ``frame_s`` later, so unless
    ``2u + r_max/c ≤ frame_s`` one emission can be found in two frames and counted twice
    (a phone FMCW system with 40 ms frames and the default ±0.05 s: a third of the
    detections were duplicates; issue 12, item 3). A larger u cannot be resolved anyway —
    the audio clock is then known only modulo a frame — so u is clamped to
    ``(frame_s − r_max/c)/2`` with an :class:`~features.acoustic.audio.AudioWarning`; frames
    shorter than the longest propagation delay are refused (:class:`ConfigError`).
    """
    frame_s = site.acoustic.frame_s
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    r_max = config.max_range_m if config.max_range_m is not None else max_site_range_m(site)
    delay_s = r_max / c
    if delay_s >= frame_s:
        raise ConfigError(f"TDMA frames of {frame_s:g} s are shorter than the longest propagation delay on the "
                          f"site ({r_max:.1f} m, {delay_s:.3f} s): chirps of consecutive frames cannot be told apart; "
                          f"give a smaller detector max_range_m or longer frames ([acoustic] slot_s × n_slots)")
    limit = 0.5 * (frame_s - delay_s)
    if timing.start_uncertainty_s <= limit:
        return timing
    import warnings

    from features.acoustic.audio import AudioWarning

    warnings.warn(f"audio start uncertainty ±{timing.start_uncertainty_s:g} s is more than frames of {frame_s:g} s "
                  f"can resolve with ranges up to {r_max:.1f} m (one chirp would be counted in two frames); "
                  f"clamped to ±{limit:.4f} s: the audio clock is then known only to a whole frame "
                  f"([audio] start_uncertainty_s / --start-uncertainty-s)", AudioWarning, stacklevel=3)
    return dataclasses.replace(timing, start_uncertainty_s=limit)


class _FrameDetector:
    """State of one recording's detection: matched filter, envelope history, tracker, pending CIRs."""

    def __init__(self, path, site: Site, timing: AudioTiming, config: DetectorConfig,
                 stats: AudioStats | None, positions: PositionConfig, n_total: int, first_sample: int = 0):
        fs = float(config.fs_hz)
        self.site, self.timing, self.config, self.fs, self.n_total = site, timing, config, fs, n_total
        self.first_sample = first_sample
        self.c = speed_of_sound_m_s(site.atmosphere.temperature_c)
        self.r_max = config.max_range_m if config.max_range_m is not None else max_site_range_m(site)
        specs = [beacon_chirp_spec(site, b) for b in site.beacons]
        unique = sorted(set(specs), key=lambda s: (s.f0_hz, s.f1_hz, s.duration_s))
        self.template_of = [unique.index(s) for s in specs]
        self.bandwidth = {b.id: s.bandwidth_hz for b, s in zip(site.beacons, specs)}
        self.bank = bank = MatchedFilterBank(unique, fs)
        mf = StreamingMatchedFilter(bank, first_index=first_sample)
        self.dec = dec = mf.decimation
        self.lead = lead = int(math.ceil(config.max_lead_s * fs))
        self.span = span = int(math.ceil(config.cir_span_s * fs))
        self.history = int(math.ceil(site.acoustic.frame_s * fs))
        self.stream = _Stream(path, config, mf, stats, first_sample)
        self.tracker = ClockPositionTracker(site, timing, fs, self.c, self.r_max, positions,
                                            {b.id: s.range_doppler_lag_s for b, s in zip(site.beacons, specs)})
        self.maxima: dict = {}       # template -> (decimated indices, heights), ascending lists, for the current frame
        self.delay = bank.delay_samples
        self.bandwidth_of = [self.bandwidth[b.id] for b in site.beacons]
        self.beacon_ids = [b.id for b in site.beacons]
        self.log_inv_p_fa = -math.log(config.p_fa)
        self.cir_taps = (lead + 8 + span) // dec
        self.toa_taps = (2 * lead + 9) // dec + 1   # the strongest tap is sought within ±max_lead_s of the located one
        self.first_tap = (lead + 8) // dec          # where the located arrival lies in its CIR
        self.lead_taps = int(math.ceil(config.max_lead_s / (dec / fs)))
        self.tap_offsets = np.arange(self.cir_taps)
        # Pulse-compression test (module docstring): half the −20 dB main lobe each side, and the widest peak.
        self.main_taps = [max(1, int(math.ceil(0.5 * m * fs / dec))) for m in bank.mainlobe_s]
        # The widest peak scales with 1/B (6/B: 1 ms at 6 kHz, 2.1 ms for a 2.9 kHz sub-band, whose
        # main lobe is twice as wide; with 1 ms the compression test dropped 47 % of the true chirps
        # of a two-band deployment's walk).
        self.max_width_taps = [max(3, int(math.ceil(max(_MAX_PEAK_WIDTH_S, 6.0 / s.bandwidth_hz) * fs / dec)))
                               for s in unique]
        self.pending_cirs: list = []  # (frame list index, detection index, template, cir row, search start, noise power)
        self.held: list = []          # frames waiting for their CIR features: [k, start, detections, fix, tracking, state]

    # -- the frame loop ------------------------------------------------------------------------

    def frames(self, resume: ReceiverState | None = None, keep_state_from_s: float = math.inf
               ) -> Iterator[FrameResult]:
        """Every TDMA frame that can hold a chirp of the recording, in order (``resume``, ``keep_state_from_s``:
        :func:`detect_frames`)."""
        site, timing, tracker, stream, fs = self.site, self.timing, self.tracker, self.stream, self.fs
        frame_s = site.acoustic.frame_s
        u = timing.start_uncertainty_s
        end_s = timing.start_s + self.n_total / fs
        first_s = timing.start_s + self.first_sample / fs          # the file's first sample
        k = math.floor((first_s - u - min(self.r_max / self.c, frame_s) - timing.frame_phase_s) / frame_s)
        while True:
            frame_start = timing.frame_phase_s + k * frame_s
            if frame_start - u > end_s:
                yield from self.release()
                return
            if resume is not None and k == resume.frame:
                self.tracker = tracker = resume.tracker.resumed(timing)
            kept = None
            if frame_start >= keep_state_from_s:
                kept, keep_state_from_s = ReceiverState(k, tracker.resumed(tracker.timing)), math.inf
            detections, tracking = self.detect_frame(k, frame_start)
            fix = tracker.frame_done(frame_start, detections, self.bandwidth)
            earlier = tracker.take_confirmed_tentative()
            held = self.held
            if earlier is not None and held and held[-1][3] is None:
                held[-1][3] = earlier          # the acquisition fix this frame confirmed
            held.append([k, frame_start, detections, fix, tracking, kept])
            if len(held) >= _FEATURE_BATCH_FRAMES:
                yield from self.release(keep_last=True)
            next_lo = int(math.floor((frame_start + frame_s - u - 0.05 - timing.start_s) * fs))
            stream.trim(next_lo - self.history - self.lead - 64)
            k += 1

    def detect_frame(self, k: int, frame_start: float) -> tuple[list[ChirpDetection], bool]:
        """Track, detect, acquire, assign and time the chirps of frame ``k``; and whether it was tracked."""
        tracker = self.tracker
        windows = [w for w in tracker.windows(frame_start) if w.hi >= self.first_sample and w.lo < self.n_total]
        tracking = tracker.tracking_at(frame_start)
        if not windows:
            return [], tracking
        self.stream.ensure(max(w.hi for w in windows) + self.span + self.bank.kernel_len + self.dec)
        sigmas = self.noise_scales(windows).tolist()
        gammas = self.thresholds(windows, sigmas)
        self.prepare_maxima(windows, gammas)
        if not tracking and tracker.skip_acquisition():
            windows = [w._replace(associated=False) for w in windows]
        elif not tracking:
            windows = self.acquire(windows, gammas)
            gammas = self.thresholds(windows, sigmas)
        found = self.assign_arrivals(windows, gammas)
        return (self.time_arrivals(found, sigmas, k, len(self.held)) if found else []), tracking

    def acquire(self, windows: list[SearchWindow], gammas: np.ndarray) -> list[SearchWindow]:
        """Without a lock: windows narrowed by a vote over candidate arrivals (see the tracker); ``gammas`` the
        windows' thresholds."""
        found = dict(zip(map(id, windows), self.candidates(windows, gammas)))
        return acquisition_windows(windows, lambda w: found[id(w)], self.tracker, self.timing, self.fs, self.lead)

    def release(self, keep_last: bool = False) -> Iterator[FrameResult]:
        """Compute the held frames' features and yield the frames; ``keep_last``: all but the last, which stays
        held (its features computed) for the next frame to hand it the acquisition fix that frame may confirm
        (:meth:`ClockPositionTracker.take_confirmed_tentative`). Released with the rest, a batch's last frame lost
        that fix whenever the confirmation came in the next batch's first frame: where the 32-frame batches fall
        depends on the read's first frame, so a long walk's cut and the whole walk lost different fixes."""
        held = self.held
        self.flush_features(held)
        n = len(held) - 1 if keep_last else len(held)
        for k_, start_, dets_, fix_, tracking_, kept_ in held[:n]:
            yield FrameResult(k_, start_, tuple(sorted(dets_, key=lambda d: d.tx_s)), fix_, tracking_, kept_)
        del held[:n]

    # -- detect ---------------------------------------------------------------------------------
    def noise_scales(self, windows: list[SearchWindow]) -> np.ndarray:
        """Rayleigh scale σ per template from the envelope of the frame before and under ``windows``
        (its exact zeros, digital silence, left out; 0 when nothing else is there)."""
        bank, dec, history, stream = self.bank, self.dec, self.history, self.stream
        j_hi = (max(w.hi for w in windows) + bank.delay_samples) // dec + 1
        j_lo = min((min(w.lo for w in windows) + bank.delay_samples) // dec, j_hi - history // dec)
        _, seg = stream.env_range(j_lo, j_hi)
        if seg.shape[1] == 0:
            return np.zeros(bank.n_templates)
        return _noise_scales(seg)

    def thresholds(self, windows: list[SearchWindow], sigmas: list) -> np.ndarray:
        """Detection threshold γ of each window of ``windows`` (:func:`_thresholds`; module docstring), ``sigmas``
        the noise scale per template; shape (len(windows),)."""
        template_of, bandwidth_of = self.template_of, self.bandwidth_of
        return _thresholds(np.array([w.hi - w.lo for w in windows], dtype=np.int64),
                           np.array([bandwidth_of[w.beacon_index] for w in windows], dtype=float),
                           np.array([sigmas[template_of[w.beacon_index]] for w in windows], dtype=float),
                           self.fs, self.log_inv_p_fa)

    def prepare_maxima(self, windows: list[SearchWindow], gammas: np.ndarray) -> None:
        """Envelope maxima of the whole frame, once per template, for the windows to slice.

        Windows overlap, and a local maximum is one whatever window looks at it, so the
        maxima above the lowest threshold of the frame (``gammas``: each window's) are found once,
        and the sidelobe guard (a maximum within one chirp length of one 25 dB stronger is dropped, so
        that the range sidelobes, −34.6 dB, of a strong arrival never pass for an earlier
        one) applied once, instead of per window. Kept as arrays (decimated indices, float32 heights)
        that :func:`_assign` and :func:`_candidates` search by bisection.
        """
        maxima, template_of, delay, dec, bank = self.maxima, self.template_of, self.delay, self.dec, self.bank
        maxima.clear()
        tmpl = [template_of[w.beacon_index] for w in windows]
        gammas = gammas.tolist()
        for t in set(tmpl):
            mine = [w for w, tw in zip(windows, tmpl) if tw == t]
            j_lo = -(-(min(w.lo for w in mine) + delay) // dec)
            j_hi = (max(w.hi for w in mine) + delay) // dec + 1
            j_first, seg = self.stream.env_range(j_lo, j_hi)
            seg = seg[t]
            gamma = min(g for g, tw in zip(gammas, tmpl) if tw == t)
            if len(seg) < 3:
                maxima[t] = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float32))
                continue
            idx = _envelope_maxima(seg, gamma, gamma * _SIDELOBE_GUARD, dec, bank.template_len)
            maxima[t] = (j_first + idx, seg[idx])

    def frame_maxima(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame's maxima (:meth:`prepare_maxima`) of all templates in one array: decimated indices, heights
        (float32), and where each template's start (``t_off``, template t's at ``[t_off[t], t_off[t + 1])``)."""
        maxima, n_t = self.maxima, self.bank.n_templates
        empty = np.zeros(0, dtype=np.int64)
        jj = np.concatenate([maxima[t][0] if t in maxima else empty for t in range(n_t)])
        hh = np.concatenate([maxima[t][1] if t in maxima else empty.astype(np.float32) for t in range(n_t)])
        t_off = np.cumsum([0] + [len(maxima[t][0]) if t in maxima else 0 for t in range(n_t)])
        return jj, hh, t_off

    def assign_arrivals(self, windows: list[SearchWindow], gammas: np.ndarray) -> list[tuple[SearchWindow, int]]:
        """(window, chirp start) of the chirps located in a frame, one physical arrival per window.

        Windows overlap (slots are 0.1 s apart, an NLOS arrival may come late), so one arrival
        can fall into several. Associated windows come first: an arrival belongs to its beacon
        before it can be claimed, for features only, by an unassociated window. Among tracked
        windows an arrival goes to the window whose predicted arrival it matches best; a window
        that loses it takes its next peak that is not the echo of a claimed one (up to ``_ECHO_SPAN_S``
        after it). Arrivals of different chirp templates (frequency-divided beacons) never collide.
        ``gammas``: each window's threshold. The rounds run compiled over the whole frame (:func:`_assign`).
        """
        if not windows:
            return []
        template_of, delay, dec = self.template_of, self.delay, self.dec
        jj, hh, t_off = self.frame_maxima()
        claim_w, claim_s = _assign(
            jj, hh, t_off, np.array([template_of[w.beacon_index] for w in windows], dtype=np.int64),
            np.array([-(-(w.lo + delay) // dec) for w in windows], dtype=np.int64),
            np.array([(w.hi + delay) // dec + 1 for w in windows], dtype=np.int64), gammas,
            np.array([w.associated for w in windows]),
            np.array([0 if w.expected is None else w.expected for w in windows], dtype=np.int64),
            np.array([w.expected is not None for w in windows]), dec, delay, 0.001 * self.fs, _ECHO_SPAN_S * self.fs)
        return [(windows[k], sp) for k, sp in zip(claim_w.tolist(), claim_s.tolist())]

    def cir_rows(self, t: int, j_a: list) -> tuple[np.ndarray, list]:
        """Decimated envelope rows ``[j, j + cir_taps)`` of template ``t`` for each ``j`` of ``j_a``
        (zeros outside the stream's history), and the first tap of each that the stream holds."""
        stream, cir_taps = self.stream, self.cir_taps
        if min(j_a) >= stream.env_j0 and max(j_a) + cir_taps <= stream.env_j0 + stream.env.shape[1]:
            return stream.env[t][(np.array(j_a) - stream.env_j0)[:, None] + self.tap_offsets], j_a
        cirs = np.zeros((len(j_a), cir_taps), dtype=np.float32)
        got = []
        for r, j in enumerate(j_a):
            j_got, seg = stream.env_range(j, j + cir_taps)
            cirs[r, j_got - j: j_got - j + seg.shape[1]] = seg[t]
            got.append(j_got)
        return cirs, got

    def time_arrivals(self, found: list[tuple[SearchWindow, int]], sigmas: list, frame: int,
                      slot: int) -> list[ChirpDetection]:
        """Arrival times of all chirps located in a frame, batched per template; CIRs queued for features.

        Each chirp's CIR is the decimated envelope from ``max_lead_s`` before the
        located peak to ``cir_span_s`` after it (taps ``decimation/fs`` apart). The
        first arrival is timed on it now (leading edge, then a log-parabolic peak:
        the decimated output is the full-rate analytic envelope sampled every
        ``decimation`` samples, and on simulated walks this timing agrees with a
        full-rate envelope to a median 0.03 samples, p95 0.3), because tracking
        needs it for the next frame; the nine features come later, for many
        frames in one batch (:meth:`flush_features`), from the same rows.
        """
        bank, dec, delay, lead, fs = self.bank, self.dec, self.delay, self.lead, self.fs
        template_of, first_tap, toa_taps, beacon_ids = self.template_of, self.first_tap, self.toa_taps, self.beacon_ids
        out = []
        for t in range(bank.n_templates):
            group = found if bank.n_templates == 1 else [(w, sp) for w, sp in found if template_of[w.beacon_index] == t]
            if not group:
                continue
            j_a = [-(-(sp - lead - 8 + delay) // dec) for _, sp in group]
            cirs, j_got = self.cir_rows(t, j_a)
            cir_lo = [min(max(-(-(w.lo + delay) // dec), g) - j, first_tap) for (w, _), g, j in zip(group, j_got, j_a)]
            noise_power = 2.0 * sigmas[t] ** 2   # Rayleigh envelope of scale σ: E[env²] = 2σ²
            # One tap beyond the search range, for the parabola of an arrival at its last tap (as the features see it).
            rows = np.ascontiguousarray(cirs[:, :toa_taps + 1], dtype=np.float64)
            valid, tau, snr_db = first_arrivals(rows, np.array(cir_lo, dtype=np.int64), toa_taps, self.lead_taps,
                                                noise_power, self.cir_taps)
            keep = (valid & _compressed(rows, first_tap, self.main_taps[t], self.max_width_taps[t], noise_power)).tolist()
            tau, snr_db = tau.tolist(), snr_db.tolist()
            for r, ((w, _), j, row, lo) in enumerate(zip(group, j_a, cirs, cir_lo)):
                if keep[r]:
                    self.pending_cirs.append((slot, len(out), t, row, lo, noise_power))
                    out.append(ChirpDetection(frame, beacon_ids[w.beacon_index], w.tx_s,
                                              self.timing.start_s + (dec * (j + tau[r]) - delay) / fs, snr_db[r],
                                              _NO_FEATURES, w.associated))
        return out

    def flush_features(self, frames: list[list]) -> None:
        """Compute the queued CIR features in one batch per template and put them into ``frames``."""
        pending_cirs, bank, dec, fs, config = self.pending_cirs, self.bank, self.dec, self.fs, self.config
        for t in sorted({q[2] for q in pending_cirs}):
            rows = pending_cirs if bank.n_templates == 1 else [q for q in pending_cirs if q[2] == t]
            feats = analyse_cirs(np.array([q[3] for q in rows]), dec / fs,
                                 noise_power=np.array([q[5] for q in rows]), max_lead_s=config.max_lead_s,
                                 pulse_width_s=float(bank.mainlobe_s[t]), search_start=np.array([q[4] for q in rows]),
                                 search_stop=self.toa_taps)
            for (slot, i, _, _, _, _), f in zip(rows, feats.features.tolist()):
                dets = frames[slot][2]
                d = dets[i]
                dets[i] = ChirpDetection(*d[:5], CirFeatures(*f), d[6])
        pending_cirs.clear()

    def candidates(self, windows: list[SearchWindow], gammas: np.ndarray, max_candidates: int = 12) -> list[list]:
        """Stated arrival times of candidate first arrivals in each window of ``windows`` (acquisition).

        The envelope maxima of a window above its threshold (``gammas``), less those within
        ``_ECHO_SPAN_S`` after a stronger one (taken for its echoes and tail, so that weak arrivals
        of far beacons, separate in time, are not crowded out by the echoes of near ones); of the
        rest, the strongest ``max_candidates``, strongest first. Compiled for the whole frame
        (:func:`_candidates`); where two of a window's heights are equal the order is numpy's argsort's.
        """
        delay, dec, fs, start_s = self.delay, self.dec, self.fs, self.timing.start_s
        jj, hh, t_off = self.frame_maxima()
        starts, heights, c_off, n_kept, tied = _candidates(
            jj, hh, t_off, np.array([self.template_of[w.beacon_index] for w in windows], dtype=np.int64),
            np.array([-(-(w.lo + delay) // dec) for w in windows], dtype=np.int64),
            np.array([(w.hi + delay) // dec + 1 for w in windows], dtype=np.int64), gammas, dec, delay,
            _ECHO_SPAN_S * fs, max_candidates)
        out = []
        for k, (a, n, tie) in enumerate(zip(c_off[:-1].tolist(), n_kept.tolist(), tied.tolist())):
            if tie:           # equal heights: their order as numpy's argsort gives it, the strongest first
                b = c_off[k + 1]
                order = np.argsort(heights[a:b])[::-1][:max_candidates]
                out.append([start_s + float(x) / fs for x in starts[a:b][order]])
            else:
                out.append([start_s + float(x) / fs for x in starts[a: a + n].tolist()])
        return out
