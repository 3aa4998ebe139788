"""Impulse removal before the matched filter: corona and partial-discharge clicks taken out of the samples.

High-voltage equipment emits short acoustic impulses (corona and partial discharges,
tens of microseconds each, in bursts phase-locked to the mains; IEC 60270:2000 §3,
IEC TS 62478:2016 for their acoustic detection at 20–100 kHz). Through the matched
filter an impulse comes out as the filter's own impulse response: a 10 ms plateau,
and when two fall within a chirp length, or one meets an in-band tone, a beat
pattern whose narrow peaks pass the pulse-compression test of
:mod:`features.acoustic.detection` for chirps (``bench/false_chirps.py``: 10 impulses
a second gave 30–60 false chirps a minute on a 24-beacon deployment). They are
better removed before the filter, where they are still what they are: a few samples
that nothing before or after them predicts.

This is the click removal of audio restoration (Godsill & Rayner, "Digital Audio
Restoration", 1998, ch. 5):

* **Detection on the prediction error** (Vaseghi & Rayner 1990, "Detection and
  suppression of impulsive noise in speech communication systems", IEE Proc. I
  137(1)): an autoregressive model of order ``order`` is fitted to each segment of
  ``segment`` samples (autocorrelation method, Hann window, Levinson–Durbin;
  Makhoul 1975, Proc. IEEE 63(4)) and the next segment is passed through its
  prediction-error filter e[n] = x[n] − Σ aₖ·x[n−k]. Hum, an in-band tone (a phone's
  gesture tone, a magnetostriction harmonic) and the noise's colour are predicted
  and leave e; an impulse is not and stays. Where the model predicts little better
  than the second difference 1 − 2z⁻¹ + z⁻² (noise and hum alone, and before the
  first fit) that 3-tap filter is used instead: it already takes the hum out, and costs
  a quarter.
* **Threshold relative to the local level**: sample n is an impulse when |e[n]| >
  ``ratio`` · ē[n], ē the mean of |e| over ``context`` samples on both sides less a
  guard of ``guard`` samples each side (the impulse's own spread through the
  filter and the codec). Two-sided, because a strong chirp's onset rises far above
  the noise *before* it within a millisecond (15–17 times a one-sided mean) but
  never above its own continuation. In white noise |e| is half-normal,
  P(|e| > 8·E|e|) = P(|z| > 10) ≈ 1.5e-23 per sample; a chirp, even two beating
  paths, reads below 3.
* **Interpolation of the hole** (the samples from ``pre`` before an impulse to
  ``hold`` after the last one: microphone and codec ringing) by least squares under
  the same AR model (Janssen, Veldhuis & Vries 1986, "Adaptive interpolation of
  discrete-time signals that can be modelled as autoregressive processes", IEEE
  Trans. ASSP 34(2)): the missing samples minimise the prediction error over the
  hole and the ``order`` samples after it, which continues hum and tones through
  it. Zeroing a hole, or a straight line across a tone, would cut a 0.5 ms piece out
  of them: a new in-band click (measured: a line across a 0.05 20 kHz tone turned
  20 false chirps per 30 s into 33).

Streaming: segments are aligned on the stream's sample index and each is filtered
with the model of the one before it; a sample is decided once ``context + guard``
samples after it have been read and released once the hole it belongs to is closed
and ``order`` samples after it are read. Sample indices are unchanged (the matched
filter's timing too), and |e| is compared in integers (units of 2⁻²⁴ of full scale),
so the output does not depend on how the stream is cut into blocks.

Speed (issue 25): the compiled loops read ``q`` and ``x`` through slices at the loop's own index. An index
such as ``q[i − g − 1]``, which numba cannot prove non-negative, costs a wrap-around check on every access and
keeps the loop from vectorising. Replaying the 151 blocks of a 600 s walk (best of 7, process CPU):
:func:`_quantised_error` took 0.083 s before and 0.013 s after, :func:`_decide` 0.089 s before and 0.045 s after
(now, in chunks of 4,096 samples so that its work arrays are reused rather than fresh pages each block, a
sliding sum, a vectorised test, and the holds set from the few hits). The output is the same to the bit.
The AR fill's convolution layout is cached per hole length (:func:`_fill_layout`); its least squares stay
numpy's (LAPACK ``gelsd``): a Householder QR compiled with numba took a quarter of the time and gave the same
float32 samples on that walk, but differs from it by up to 1e-11 (relative) before rounding, so a sample
could round the other way somewhere; left for a change that may move fixes by round-off.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from features.errors import ConfigError

__all__ = ["ImpulseBlanker"]

_MAX_HOLD_S = 0.25
"""Longest run of impulses held back for its end, s; beyond it the run is released as it is
(continuous discharge noise is noise, not impulses: its own level soon raises the reference)."""

_AR_GAIN = 4.0
"""Excess (6 dB) of the second difference's output over white noise through it from which the fitted model
replaces it (module docstring)."""

_DECIDE_CHUNK = 4096
"""Samples :func:`_decide` handles at a time (its work arrays' length)."""

_MAX_LS_HOLE = 160
"""Holes longer than this many samples are filled by a straight line instead of the AR least squares."""


@njit(cache=True)
def _decide(q: np.ndarray, start: int, stop: int, wh: int, g: int, ratio: float, hold: int, hold_left: int):
    """Impulse mask of ``q[start:stop]`` (|e| of the prediction error in units of 2⁻²⁴, :func:`_quantised_error`;
    ``g + wh`` samples of ``q`` exist on either side of the range), the hold carried over, and the number of holes
    opened.

    The reference of sample i is Σ|e| over the ``wh`` samples before i − g and after i + g, kept as one sliding
    sum of integers (exact, whatever the order it is formed in). Three passes over each chunk of
    :data:`_DECIDE_CHUNK` samples: the sliding sums, the test of every sample (a loop numba vectorises), then
    the holds, which only the rare hits open. Each loop reads slices of ``q`` at the loop's own index: an index
    such as ``q[i − g − 1]``, which the compiler cannot prove non-negative, costs a wrap-around check per access
    and kept the old single loop from vectorising (with it this took twice as long)."""
    n = stop - start
    # In chunks of _DECIDE_CHUNK samples: the work arrays stay small (reused, no fresh pages per block).
    ref = np.empty(min(n, _DECIDE_CHUNK), dtype=np.int64)
    hit = np.empty(min(n, _DECIDE_CHUNK), dtype=np.bool_)
    mask = np.zeros(n, dtype=np.bool_)
    mask[:hold_left] = True
    covered = hold_left                    # samples before this are masked
    opened = 0
    two_wh = 2 * wh
    acc = np.int64(0)
    for v in q[start - g - wh: start - g]:
        acc += v
    for v in q[start + g + 1: start + g + 1 + wh]:
        acc += v
    for c0 in range(0, n, _DECIDE_CHUNK):
        m = min(n - c0, _DECIDE_CHUNK)
        i0 = start + c0
        # The reference of sample i0 + u: q[i − g − 1] and q[i + g + wh] enter it, q[i − g − wh − 1] and
        # q[i + g] leave it (the chunk's first sample's is ``acc`` already).
        ref[0] = acc
        enter_left, leave_left = q[i0 - g: i0 - g + m - 1], q[i0 - g - wh: i0 - g - wh + m - 1]
        enter_right, leave_right = q[i0 + g + wh + 1: i0 + g + wh + m], q[i0 + g + 1: i0 + g + m]
        for u in range(m - 1):
            acc += enter_left[u] - leave_left[u] + enter_right[u] - leave_right[u]
            ref[u + 1] = acc
        qs = q[i0: i0 + m]
        for u in range(m):
            qi = qs[u]
            hit[u] = (qi > 0) & (float(qi * two_wh) > ratio * float(ref[u]))
        # A hit at t masks t … t + hold; one within the hold of the one before extends its hole.
        for u in range(m):
            if hit[u]:
                t = c0 + u
                if t >= covered:
                    opened += 1
                covered = t + hold + 1
                mask[t: covered] = True
        if c0 + m < n:                     # on to the next chunk's first sample
            i = i0 + m
            acc += q[i - g - 1] - q[i - g - wh - 1] + q[i + g + wh] - q[i + g]
    return mask, max(covered - n, 0), opened


@njit(cache=True)
def _hann(n: int) -> np.ndarray:
    """The Hann window w[i] = ½ − ½·cos(2πi/(n − 1)) of the AR fit (:func:`_prediction_error_filter`); shape (n,)."""
    w = np.empty(n)
    for i in range(n):
        w[i] = 0.5 - 0.5 * math.cos(2.0 * math.pi * i / (n - 1))
    return w


@njit(cache=True)
def _prediction_error_filter(x: np.ndarray, order: int, window: np.ndarray) -> np.ndarray:
    """c = [1, −a₁, …, −a_p] of the AR(p) model of ``x`` (autocorrelation method over the Hann ``window``
    (:func:`_hann` of ``len(x)``), with a 1e-9 white-noise correction so that a pure tone stays regular;
    Levinson–Durbin recursion, Makhoul 1975 eqs. 38–40); shape (p + 1,). All zeros (use the second difference)
    when ``x`` is (nearly) silent or when the second difference's output power, 6r₀ − 8r₁ + 2r₂, is within
    :data:`_AR_GAIN` of what it makes of white noise at the model's prediction-error power (6·E): noise and hum
    alone, the common case, then cost 3 taps instead of p + 1."""
    n = x.shape[0]
    w = np.empty(n)
    for i in range(n):
        w[i] = x[i] * window[i]
    # r_k = Σ_i w_i·w_{i+k}, each sum in ascending i; the lags advance together (independent accumulators).
    r = np.zeros(order + 1)
    for i in range(n - order):
        wi = w[i]
        for k in range(order + 1):
            r[k] += wi * w[i + k]
    for i in range(n - order, n):
        for k in range(n - i):
            r[k] += w[i] * w[i + k]
    c = np.zeros(order + 1)
    if not r[0] > 1e-20 * n:
        return c
    r[0] *= 1.0 + 1e-9
    c[0] = 1.0
    err = r[0]
    prev = np.zeros(order + 1)
    for m in range(1, order + 1):
        # reflection coefficient k_m = −(Σ_{j<m} c_j r_{m−j}) / E_{m−1}
        acc = 0.0
        for j in range(m):
            acc += c[j] * r[m - j]
        km = -acc / err
        prev[:m] = c[:m]
        for j in range(1, m):
            c[j] = prev[j] + km * prev[m - j]
        c[m] = km
        err *= 1.0 - km * km
        if not err > 0.0:
            break
    # The second difference passes white noise of power E at 6E (|1 − 2z⁻¹ + z⁻²|² averages 6): it whitens as
    # well as the model unless its output exceeds that by more than _AR_GAIN (a tone or hum it cannot remove).
    if _AR_GAIN * 6.0 * err > 6.0 * r[0] - 8.0 * r[1] + 2.0 * r[2]:
        c[:] = 0.0
    return c


@njit(cache=True)
def _prediction_error_filters(x: np.ndarray, offsets: np.ndarray, n: int, order: int, window: np.ndarray) -> np.ndarray:
    """:func:`_prediction_error_filter` of ``x[o : o + n]`` for each ``o`` of ``offsets``; shape (len(offsets), p + 1)."""
    out = np.empty((offsets.shape[0], order + 1))
    for j in range(offsets.shape[0]):
        out[j] = _prediction_error_filter(x[offsets[j]: offsets[j] + n], order, window)
    return out


@njit(cache=True, fastmath={"contract"})
def _quantised_error(x: np.ndarray, coefs: np.ndarray, first_seg: int, segment: int, x_pos: int, lo: int,
                     hi: int) -> np.ndarray:
    """|e| in units of 2⁻²⁴, rounded (integers, so that the sliding sums of :func:`_decide` are exact), of the
    prediction error at stream positions [lo, hi), each segment of ``segment`` samples through its own filter
    ``coefs[seg − first_seg]``; ``x[i]`` is the sample at stream position ``x_pos + i``. Shape (hi − lo,), int64.

    e[n] = x[n] + Σ_k c_k·x[n − k], the non-zero taps in ascending k, each term one fused multiply-add (the
    ``contract`` flag: only the pairs a·b + c are fused, nothing is reordered). The second difference, most
    segments' filter, has its own loop; an AR model's taps are applied one after the other over the segment
    (the loop over the samples vectorises; each sample's terms still come in ascending k). Scaling by 2²⁴ is
    exact, so the rounding is that of |e|·2²⁴ + 0.5.

    >>> _quantised_error(np.array([0, 0, 1, 0, 0], np.float32), np.array([[1.0, -2.0, 1.0]]), 0, 8, 0, 2,
    ...                  5).tolist()
    [16777216, 33554432, 16777216]
    """
    q = np.empty(hi - lo, dtype=np.int64)
    lags = np.empty(coefs.shape[1], dtype=np.int64)
    work = np.empty(min(segment, hi - lo))
    pos = lo
    while pos < hi:
        seg = pos // segment
        stop = min(hi, (seg + 1) * segment)
        c = coefs[seg - first_seg]
        n_taps = 0
        for k in range(1, c.shape[0]):
            if c[k] != 0.0:
                lags[n_taps] = k
                n_taps += 1
        a, b = pos - x_pos, stop - x_pos
        # Slices read at the loop's own index (no wrap-around check per access: the loops vectorise).
        out = q[pos - lo: stop - lo]
        x0 = x[a:b]
        if n_taps == 2 and lags[0] == 1 and lags[1] == 2:
            c1, c2 = c[1], c[2]
            x1, x2 = x[a - 1: b - 1], x[a - 2: b - 2]
            for t in range(b - a):
                e = np.float64(x0[t])
                e = e + c1 * np.float64(x1[t])
                e = e + c2 * np.float64(x2[t])
                out[t] = np.int64(abs(e) * 16777216.0 + 0.5)
        else:
            # Tap by tap over the segment's samples (each sample's sum still in ascending k): the loop over
            # the samples vectorises.
            e = work[: b - a]
            for t in range(b - a):
                e[t] = np.float64(x0[t])
            for j in range(n_taps):
                k = lags[j]
                ck = c[k]
                xk = x[a - k: b - k]
                for t in range(b - a):
                    e[t] = e[t] + ck * np.float64(xk[t])
            for t in range(b - a):
                out[t] = np.int64(abs(e[t]) * 16777216.0 + 0.5)
        pos = stop
    return q


@functools.lru_cache(maxsize=512)
def _fill_layout(m: int, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the taps of an order-``p`` filter stand in the convolution matrix of :func:`_ar_fill` for a hole of
    ``m`` samples (it depends on the hole's length only): whether tap k = r + p − j exists at row r, column j
    (shape (m + p, m + 2p)), that k clipped to [0, p], and the columns of the known samples (p before, p after)."""
    k = np.arange(m + p)[:, None] + p - np.arange(m + 2 * p)[None, :]
    return (k >= 0) & (k <= p), np.clip(k, 0, p), np.concatenate([np.arange(p), np.arange(p + m, m + 2 * p)])


def _ar_fill(x: np.ndarray, a: int, b: int, c: np.ndarray) -> np.ndarray:
    """The samples x[a:b] that minimise Σ e² over n ∈ [a, b + p), e = c ∗ x (Janssen et al. 1986), from the
    p known samples before and after; shape (b − a,). ``x`` holds them (a ≥ p, b + p ≤ len(x))."""
    p, m = len(c) - 1, b - a
    # e[a + r] = Σ_k c_k·x[a + r − k], r = 0 … m + p − 1, over the samples x[a − p : b + p] (column j ↔ a − p + j).
    exists, tap, known_cols = _fill_layout(m, p)
    conv = np.where(exists, c[tap], 0.0)
    seg = x[a - p: b + p].astype(np.float64)
    unknown = conv[:, p: p + m]
    known = conv[:, known_cols] @ seg[known_cols]
    sol, *_ = np.linalg.lstsq(unknown, -known, rcond=None)
    return sol


class ImpulseBlanker:
    """Streaming impulse removal (see the module docstring).

    ``process(block)`` returns the cleaned samples released so far (float32, in stream
    order; fewer or more than the block), ``flush()`` the rest. ``ratio`` = 0 switches it
    off (samples pass unchanged, nothing held back). ``first_index``: the stream index of the
    first sample (a cut of a longer recording: its index in the whole), so that the segments
    lie where the whole recording's do and the cut's decisions, once a segment's model is
    fitted, are the whole's.

    Attributes: ``n_impulses`` (holes opened), ``n_blanked`` (samples replaced).
    """

    def __init__(self, fs_hz: float, ratio: float = 8.0, context_s: float = 0.001, guard_s: float = 0.0003,
                 hold_s: float = 0.0005, order: int = 12, segment: int = 4096, pre: int = 1, first_index: int = 0):
        if not all(math.isfinite(v) for v in (ratio, context_s, guard_s, hold_s)):
            raise ConfigError(f"impulse blanker parameters must be finite, got {ratio}, {context_s}, {guard_s}, {hold_s}")
        if ratio != 0 and not ratio >= 3.0:
            raise ConfigError(f"impulse ratio must be 0 (off) or >= 3 (a chirp's own peaks reach ~2.5), got {ratio}")
        self.enabled = ratio > 0
        self.ratio = float(ratio)
        self.wh = max(4, int(round(context_s * fs_hz)))
        self.g = max(order + 1, int(round(guard_s * fs_hz)))
        self.hold = max(0, int(round(hold_s * fs_hz)))
        self.pre, self.order, self.segment = max(0, int(pre)), int(order), int(segment)
        self.max_pending = int(_MAX_HOLD_S * fs_hz)
        self._lag = self.g + self.wh + self.order      # samples read beyond the last decided one
        self._second_difference = np.zeros(self.order + 1)
        self._second_difference[:3] = (1.0, -2.0, 1.0)
        self._window = _hann(self.segment // 4)
        # The stream so far from ``_buf_pos``: p + context zeros stand before its start.
        self._reach = self.g + self.wh + 2 * self.order + 2
        self._buf = np.zeros(self._reach, dtype=np.float32)
        first = int(first_index)
        self._buf_pos = first - self._reach
        self._end = first                              # stream index after the last sample read
        self._dec = first                              # next undecided sample
        self._rel = first                              # next unreleased sample
        self._mask = np.zeros(0, dtype=bool)           # decisions of [_rel, _dec)
        self._hold_left = 0
        self._filters: dict[int, np.ndarray] = {}      # segment index → its prediction-error filter
        self.n_impulses = 0
        self.n_blanked = 0

    # -- stream -----------------------------------------------------------------------------------
    def process(self, block: np.ndarray) -> np.ndarray:
        x = np.asarray(block, dtype=np.float32).ravel()
        if not self.enabled:
            return x
        self._append(x)
        self._decide_until(self._end - self._lag)
        return self._release(self._release_limit())

    def flush(self) -> np.ndarray:
        """Decide the last samples (zeros after the end) and release everything."""
        if not self.enabled:
            return np.zeros(0, dtype=np.float32)
        end = self._end
        self._append(np.zeros(self._lag, dtype=np.float32), count=False)
        self._decide_until(end)
        return self._release(end)

    def _append(self, x: np.ndarray, count: bool = True) -> None:
        self._buf = np.concatenate([self._buf, x])
        if count:
            self._end += len(x)
            # Segments completed by this block: their models serve the segment after each.
            s = self.segment
            done = [j for j in range(max(0, (self._end - len(x)) // s), self._end // s)
                    if j * s - self._buf_pos >= 0 and j + 1 not in self._filters]
            if done:
                # A quarter of the segment is plenty for p + 1 lags, and four times cheaper.
                offsets = np.array([j * s - self._buf_pos for j in done], dtype=np.int64)
                for j, c in zip(done, _prediction_error_filters(self._buf, offsets, s // 4, self.order, self._window)):
                    self._filters[j + 1] = c if c[0] == 1.0 else None

    def _filter_of(self, seg: int) -> np.ndarray:
        f = self._filters.get(seg)
        return self._second_difference if f is None else f

    def _quantised_error(self, lo: int, hi: int) -> np.ndarray:
        """Quantised |e| of the prediction error at stream positions [lo, hi), each segment through its own
        model (:func:`_quantised_error`)."""
        s = self.segment
        first = lo // s
        coefs = np.array([self._filter_of(j) for j in range(first, (hi - 1) // s + 1)])
        return _quantised_error(self._buf, coefs, first, s, self._buf_pos, lo, hi)

    def _decide_until(self, stop: int) -> None:
        if stop <= self._dec:
            return
        margin = self.g + self.wh
        q = self._quantised_error(self._dec - margin, stop + margin)
        mask, self._hold_left, opened = _decide(q, margin, margin + stop - self._dec, self.wh, self.g, self.ratio,
                                                self.hold, self._hold_left)
        if self.pre and opened:
            # The ``pre`` samples before each hole's start belong to it (the impulse's first samples).
            full = np.concatenate([self._mask, mask])
            for i in (np.flatnonzero(full[1:] & ~full[:-1]) + 1).tolist():
                full[max(0, i - self.pre):i] = True
            self._mask = full
        else:
            self._mask = np.concatenate([self._mask, mask])
        self.n_impulses += int(opened)
        self._dec = stop

    def _release_limit(self) -> int:
        """Release up to ``pre`` short of the decided samples, or to the start of a hole still open there."""
        r = self._dec - self.pre
        k = r - self._rel
        if k > 0 and self._mask[k - 1]:
            clear = np.flatnonzero(~self._mask[:k])
            held = self._rel + (int(clear[-1]) + 1 if len(clear) else 0)
            if r - held <= self.max_pending:
                r = held
        return max(r, self._rel)

    def _release(self, r: int) -> np.ndarray:
        k = r - self._rel
        i0 = self._rel - self._buf_pos
        out = self._buf[i0: i0 + k].copy()
        mask = self._mask[:k]
        if mask.any():
            self.n_blanked += int(np.count_nonzero(mask))
            self._fill(out, mask)
        self._mask = self._mask[k:]
        self._rel = r
        # Keep what the residual, the reference and the interpolation still need
        # (and the segment being read, whose model is fitted once it is complete).
        keep = min(self._rel - self.order - 1, self._dec - self._reach,
                   (self._end // self.segment) * self.segment) - self._buf_pos
        if keep > 0:
            self._buf = self._buf[keep:]
            self._buf_pos += keep
            for seg in [j for j in self._filters if (j + 1) * self.segment < self._buf_pos]:
                del self._filters[seg]
        return out

    def _fill(self, out: np.ndarray, mask: np.ndarray) -> None:
        """Replace each run of masked samples of ``out`` (stream positions from ``_rel``) in place."""
        p = self.order
        idx = np.flatnonzero(mask)
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > p) + 1)        # holes closer than p: one hole
        for run in runs:
            a, b = int(run[0]), int(run[-1]) + 1
            ia, ib = self._rel + a - self._buf_pos, self._rel + b - self._buf_pos
            if ia >= p and ib + p <= len(self._buf) and b - a <= _MAX_LS_HOLE:
                c = self._filter_of((self._rel + a) // self.segment)
                out[a:b] = _ar_fill(self._buf, ia, ib, c)
            else:
                left = float(self._buf[ia - 1]) if ia >= 1 else 0.0
                right = float(self._buf[ib]) if ib < len(self._buf) else left
                out[a:b] = left + (right - left) * np.arange(1, b - a + 1) / (b - a + 1)
