"""Channel impulse response (CIR) features, for any tap spacing.

One CIR is an envelope ``amplitude`` (n_taps,) sampled every ``tap_s``
seconds: the matched-filter envelope around a beacon chirp (tap = 1/48 kHz),
or a UWB accumulator (tap ≈ 1 ns). The same code serves both.

Steps (docs/design.md §5):

1. **Noise floor** ``noise_power`` (mean noise power per tap): given by the
   caller, or estimated robustly as ``median(|h|²)/ln 2`` (the median of an
   exponential power distribution is ``ln 2`` times its mean), valid when most
   taps are noise, as in a UWB accumulator window.
2. **Tap selection**: taps with power above ``max(peak − 20 dB, γ_n)``, with the
   noise threshold γ_n set from a false-alarm budget over the CIR (Kay,
   "Fundamentals of Statistical Signal Processing, Vol. II: Detection", 1998,
   §7.6, the union bound over cells as in :mod:`features.acoustic.detection`).
   In noise alone the envelope is Rayleigh, so a tap's power is exponential
   with mean N₀ and P(p > γ) = exp(−γ/N₀); requiring at most ``CIR_P_FA``
   (1 %) noise taps per CIR of ``n_taps`` taps gives

       γ_n = N₀ · ln(n_taps / CIR_P_FA)

   — 10.0 dB above the noise for the 211-tap audio CIR, 10.6 dB for the
   1016-tap UWB accumulator. The old rule, noise + 6 dB, let a noise tap through
   with probability e⁻⁴ ≈ 1.8 % each, about two per audio CIR: a noise tap
   10 ms after a 20 dB peak adds about 1 ms of rms delay, so the features
   measured SNR rather than multipath (docs/cir_features.md gives the figures).
   Taps after the search range from the first one stronger than the peak on
   (less one pulse width: its rising edge) are another chirp, not this one's
   multipath, and are cut, so every selected tap lies at or below the peak and
   every gain is ≤ 0 dB.
3. **First arrival τ₀ by leading-edge detection**: the earliest tap above the
   same threshold within ``max_lead_s`` before the strongest tap (with the
   budget above, a noise tap in a 30-tap lead window precedes the chirp with
   probability ≤ 30 · 1 %/211 ≈ 0.14 %, against 1 − (1 − e⁻⁴)³⁰ ≈ 42 % for the
   old 6 dB margin at the threshold's floor); τ₀ is the first
   local maximum at or after it (the peak of the first path's lobe), refined to
   a fraction of a tap by a parabola through the log-amplitudes of the peak
   and its neighbours (exact for a Gaussian lobe; Jacobsen & Kootsookos 2007,
   IEEE SP Mag. 24(3), for the interpolator family). Searching before the
   strongest tap finds a weak direct path ahead of a stronger reflection (the
   classic NLOS leading-edge problem; Dardari et al. 2009, Proc. IEEE 97(2)).
4. **Delay statistics** of the power-delay profile of the selected taps at or
   after the leading edge, delays ``τᵢ − τ₀`` (Rappaport, "Wireless
   Communications", 2nd ed., eq. 5.35–5.36): mean excess delay Σpτ/Σp, rms
   delay spread sqrt(Σp(τ − τ̄)²/Σp), and the power-weighted skewness and
   (Pearson, non-excess: 3 for a Gaussian) kurtosis of the delays.
5. **Rician K**: energy of the first path (taps within half a pulse width of
   τ₀) over the energy of every other selected tap, dB; capped at
   :data:`K_MAX_DB` when no other tap is selected.
6. **Gain statistics** of the selected taps' relative gains ``10·log10(pᵢ/p_max)``
   (dB, ≤ 0): mean, root-mean-square, skewness and Pearson kurtosis (population
   moments, equal to :func:`scipy.stats.skew` / :func:`scipy.stats.kurtosis`
   with ``fisher=False``; a test checks the agreement).

Undefined statistics (a single tap has no spread) are NaN, not zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from features.errors import DataError

__all__ = ["CirFeatures", "CirAnalysis", "CirBatch", "analyse_cir", "analyse_cirs", "first_arrivals", "find_paths", "robust_noise_power",
           "FEATURE_NAMES", "K_MAX_DB", "PEAK_DYNAMIC_RANGE_DB", "CIR_P_FA",
           "noise_threshold_factor"]

PEAK_DYNAMIC_RANGE_DB = 20.0
"""Taps more than this far below the strongest are ignored (docs/design.md §5)."""

CIR_P_FA = 1e-2
"""False-alarm budget of the tap selection: expected noise taps selected per CIR (module docstring, step 2)."""


def noise_threshold_factor(n_taps: int, p_fa: float = CIR_P_FA) -> float:
    """γ_n / N₀ = ln(n_taps / p_fa): the tap-power threshold over the mean noise power (step 2).

    Union bound over the taps of an exponential (Rayleigh-envelope) noise power
    (Kay 1998, Vol. II, §7.6). At least e (a 4.3 dB floor for tiny CIRs).

    >>> round(10 * math.log10(noise_threshold_factor(211)), 1), round(10 * math.log10(noise_threshold_factor(1016)), 1)
    (10.0, 10.6)
    """
    return max(math.log(max(n_taps, 1) / p_fa), 1.0)

K_MAX_DB = 40.0
"""Rician K reported when the first path is the only selected energy, dB."""


class CirFeatures(NamedTuple):
    """The nine acoustic channel features of docs/design.md §5 (names as in feature tables).

    A named tuple (immutable like a frozen dataclass, and three times cheaper to make:
    the receiver makes one per chirp heard).
    """

    mean_excess_delay_ms: float
    rms_delay_ms: float
    delay_kurtosis: float
    delay_skewness: float
    rician_k_db: float
    gain_mean_db: float
    gain_rms_db: float
    gain_kurtosis: float
    gain_skewness: float

    def as_array(self) -> np.ndarray:
        """Shape (9,), in :data:`FEATURE_NAMES` order."""
        return np.array(self, dtype=float)


FEATURE_NAMES = CirFeatures._fields
"""Column names of the nine CIR features, in order."""


@dataclass(frozen=True)
class CirAnalysis:
    """Result of :func:`analyse_cir`.

    ``first_arrival_tap`` is τ₀ in (fractional) taps from the start of the CIR;
    ``tap_index`` / ``tap_power`` are the selected taps; ``peak_snr_db`` is the
    strongest tap's power over the noise power.
    """

    features: CirFeatures
    first_arrival_tap: float
    first_arrival_amplitude: float
    peak_tap: int
    peak_snr_db: float
    threshold_power: float
    noise_power: float
    tap_index: np.ndarray
    tap_power: np.ndarray


def robust_noise_power(power: np.ndarray) -> float:
    """Mean noise power from the median tap power, ``median/ln 2`` (exponential law).

    >>> round(robust_noise_power(np.random.default_rng(0).exponential(2.0, 100_000)), 1)
    2.0
    """
    return float(np.median(power) / np.log(2.0))


def _parabolic_offset(y_m1: float, y0: float, y_p1: float) -> float:
    """Vertex offset in [-0.5, 0.5] of the parabola through three equally spaced points."""
    denom = y_m1 - 2.0 * y0 + y_p1
    if denom >= 0 or not np.isfinite(denom):
        return 0.0
    return float(np.clip(0.5 * (y_m1 - y_p1) / denom, -0.5, 0.5))


def _refine_peak(amplitude: np.ndarray, i: int) -> tuple[float, float]:
    """Sub-tap position and amplitude of the local maximum at ``i`` (log-parabolic interpolation)."""
    if i <= 0 or i >= len(amplitude) - 1:
        return float(i), float(amplitude[i])
    with np.errstate(divide="ignore"):
        y = np.log(np.maximum(amplitude[i - 1: i + 2], 1e-300))
    delta = _parabolic_offset(*y)
    peak_log = y[1] - 0.25 * (y[0] - y[2]) * delta
    return i + delta, float(np.exp(peak_log))


def find_paths(amplitude: np.ndarray, threshold_amplitude: float) -> tuple[np.ndarray, np.ndarray]:
    """Resolved paths: local maxima of the envelope above a threshold.

    Returns ``(positions, amplitudes)``, each of shape (n_paths,), positions in
    fractional taps (log-parabolic interpolation), in increasing delay.

    >>> a = np.exp(-0.5 * ((np.arange(100) - 30.25) / 2.0) ** 2) + 0.5 * np.exp(-0.5 * ((np.arange(100) - 60) / 2.0) ** 2)
    >>> pos, amp = find_paths(a, 0.1)
    >>> np.round(pos, 2).tolist(), np.round(amp, 3).tolist()
    ([30.25, 60.0], [1.0, 0.5])
    """
    a = np.asarray(amplitude, dtype=float)
    if len(a) < 3:
        return np.zeros(0), np.zeros(0)
    interior = (a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:]) & (a[1:-1] > threshold_amplitude)
    idx = np.flatnonzero(interior) + 1
    refined = [_refine_peak(a, int(i)) for i in idx]
    if not refined:
        return np.zeros(0), np.zeros(0)
    pos, amp = map(np.asarray, zip(*refined))
    return pos, amp


def _sparse_moments(row: np.ndarray, x: np.ndarray, w: np.ndarray, n: int, origin: np.ndarray):
    """Weighted moments of the values ``x`` (m,) with weights ``w`` (m,) grouped by ``row`` (m,) into n rows.

    Returns (mean − origin, std, Pearson kurtosis, skewness), each of shape (n,);
    kurtosis and skewness are NaN where the spread is zero, everything NaN for a row
    without values. Sums by :func:`numpy.bincount` over the selected taps only (a
    CIR's selected taps are a few of its hundreds).
    """
    total = np.bincount(row, weights=w, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(row, weights=w * x, minlength=n) / total
        c = x - mean[row]
        wc2 = w * c * c
        var = np.bincount(row, weights=wc2, minlength=n) / total
        m3 = np.bincount(row, weights=wc2 * c, minlength=n) / total
        m4 = np.bincount(row, weights=wc2 * c * c, minlength=n) / total
        spread = var > 1e-30 * np.maximum(mean * mean, 1e-300)
        skew = np.where(spread, m3 / np.where(spread, var, 1.0) ** 1.5, np.nan)
        kurt = np.where(spread, m4 / np.where(spread, var, 1.0) ** 2, np.nan)
    return mean - origin, np.sqrt(np.maximum(var, 0.0)), kurt, skew


def _first_arrivals(a: np.ndarray, power: np.ndarray, idx: np.ndarray, noise: np.ndarray, search_start,
                    search_stop, lead: int, length: int, noise_factor: float):
    """Steps 2–3 of the module docstring for the rows of ``a`` (n, L): the strongest tap in
    the search range, the tap threshold, validity, the leading edge and τ₀ (log-parabolic).

    ``a`` may be the first columns of CIRs ``length`` taps long, as long as it holds
    the search range and one tap more. Returns (valid, peak, p_peak, threshold, edge,
    tau0, amp0), each of shape (n,).
    """
    n = a.shape[0]
    rows = np.arange(n)
    # (np.minimum/np.maximum rather than np.clip, whose Python wrapper costs more than the work here.)
    stop = np.minimum(np.maximum(np.asarray(length if search_stop is None else search_stop, dtype=int), 1), length)
    start = np.minimum(np.maximum(np.asarray(search_start, dtype=int), 0), stop - 1)
    start_col = start[:, None] if start.ndim else start
    stop_col = stop[:, None] if stop.ndim else stop
    # Powers are >= 0, so -1 marks the taps outside the search range.
    peak = np.argmax(np.where((idx >= start_col) & (idx < stop_col), power, -1.0), axis=1)
    p_peak = power[rows, peak]
    threshold = np.maximum(p_peak * 10 ** (-PEAK_DYNAMIC_RANGE_DB / 10), noise * noise_factor)
    valid = np.isfinite(p_peak) & (p_peak > threshold)
    # Leading edge: the earliest tap above the threshold, at most ``lead`` taps before the peak.
    lo = np.maximum(start, peak - lead)
    edge = np.argmax((idx >= lo[:, None]) & (idx <= peak[:, None]) & (power >= threshold[:, None]), axis=1)
    # First local maximum at or after the edge: the first i >= edge with a[i+1] < a[i], or the peak.
    stop_here = idx == peak[:, None]
    stop_here[:, :-1] |= a[:, 1:] < a[:, :-1]
    first = np.minimum(np.argmax(stop_here & (idx >= edge[:, None]), axis=1), peak)
    # Log-parabolic refinement of the first path's peak.
    cols = np.minimum(np.maximum(first[:, None] + np.array([-1, 0, 1]), 0), a.shape[1] - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ym, y0, yp = np.log(np.maximum(a[rows[:, None], cols], 1e-300)).T
        denom = ym - 2.0 * y0 + yp
        interior = (first > 0) & (first < length - 1) & (denom < 0)
        delta = np.where(interior, np.minimum(np.maximum(0.5 * (ym - yp) / np.where(interior, denom, -1.0), -0.5),
                                              0.5), 0.0)
    return valid, peak, p_peak, threshold, edge, first + delta, np.exp(y0 - 0.25 * (ym - yp) * delta)


def first_arrivals(amplitude: np.ndarray, search_start: np.ndarray, search_stop: int, lead: int, noise_power: float,
                   n_taps: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2–3 of the module docstring for the few CIRs of a frame (the receiver's timing), compiled:
    per row whether a tap clears the threshold (k,) bool, τ₀ in fractional taps (k,) and the peak SNR
    in dB (k,) (zeros where none does).

    ``amplitude`` (k, L): envelopes; ``search_start`` (k,) and ``search_stop``: the strongest tap is
    sought in ``[start, stop)``; ``lead``: how many taps before it the leading edge may lie;
    ``n_taps``: the length of the whole CIR the noise threshold is budgeted over
    (:func:`noise_threshold_factor`; default L, give the full length when ``amplitude`` holds the
    first columns of longer CIRs). The same arithmetic as :func:`analyse_cirs` (``with_features=False``),
    which a test checks row for row; a loop over taps compiled with numba (issue 25), because the
    receiver times a handful of chirps per TDMA frame, where numpy's per-call overhead costs several
    times the arithmetic.
    """
    a = np.ascontiguousarray(amplitude, dtype=np.float64)
    if a.ndim != 2:
        raise DataError(f"first_arrivals needs amplitudes of shape (k, L), got {a.shape}")
    length = a.shape[1]
    noise_floor = noise_power * noise_threshold_factor(length if n_taps is None else n_taps)
    return _first_arrivals_rows(a, np.asarray(search_start, dtype=np.int64).reshape(-1), int(search_stop), int(lead),
                                float(noise_floor), 10 ** (-PEAK_DYNAMIC_RANGE_DB / 10), max(float(noise_power), 1e-300))


@njit(cache=True)
def _first_arrivals_rows(a, search_start, search_stop, lead, noise_floor, dynamic_range, snr_ref):
    """The loop of :func:`first_arrivals` (its arguments resolved: the noise floor, the dynamic range as
    a power ratio, the SNR's reference power)."""
    k, length = a.shape
    valid = np.zeros(k, dtype=np.bool_)
    tau = np.zeros(k)
    snr_db = np.zeros(k)
    if length == 0:
        return valid, tau, snr_db
    stop = min(max(search_stop, 1), length)
    for r in range(k):
        start = search_start[r]
        start = 0 if start < 0 else (stop - 1 if start > stop - 1 else start)
        peak = start
        m = a[r, start]
        for i in range(start + 1, stop):                   # the first of the largest
            if a[r, i] > m:
                m, peak = a[r, i], i
        p_peak = m * m
        threshold = p_peak * dynamic_range
        if threshold < noise_floor:
            threshold = noise_floor
        if not (math.isfinite(p_peak) and p_peak > threshold):
            continue
        first = peak
        for i in range(peak - lead if peak - lead > start else start, peak):          # leading edge
            if a[r, i] * a[r, i] >= threshold:
                first = i
                break
        while first < peak and not a[r, first + 1] < a[r, first]:    # first local maximum at or after it
            first += 1
        delta = 0.0
        if 0 < first < length - 1:
            am, a0, ap = a[r, first - 1], a[r, first], a[r, first + 1]
            ym = math.log(am if am > 1e-300 else 1e-300)
            y0 = math.log(a0 if a0 > 1e-300 else 1e-300)
            yp = math.log(ap if ap > 1e-300 else 1e-300)
            denom = ym - 2.0 * y0 + yp
            if denom < 0:
                delta = 0.5 * (ym - yp) / denom
                delta = -0.5 if delta < -0.5 else (0.5 if delta > 0.5 else delta)
        valid[r] = True
        tau[r] = first + delta
        snr_db[r] = 10.0 * math.log10(max(p_peak, 1e-300) / snr_ref)
    return valid, tau, snr_db


@dataclass(frozen=True)
class CirBatch:
    """Results of :func:`analyse_cirs` for n CIRs; rows with ``valid`` False found no tap.

    ``features`` (n, 9) in :data:`FEATURE_NAMES` order; ``first_arrival_tap`` (n,)
    fractional taps; ``peak_tap`` (n,); ``peak_snr_db`` (n,); ``tap_mask`` (n, L)
    the selected taps.
    """

    valid: np.ndarray
    features: np.ndarray
    first_arrival_tap: np.ndarray
    first_arrival_amplitude: np.ndarray
    peak_tap: np.ndarray
    peak_snr_db: np.ndarray
    threshold_power: np.ndarray
    noise_power: np.ndarray
    tap_mask: np.ndarray


def analyse_cirs(amplitude: np.ndarray, tap_s: float, *, noise_power=None, max_lead_s: float | None = None,
                 pulse_width_s: float | None = None, search_start=0, search_stop=None,
                 with_features: bool = True) -> CirBatch:
    """Vectorised :func:`analyse_cir` over the rows of ``amplitude`` (n, L).

    ``noise_power``, ``search_start`` and ``search_stop`` may be scalars or
    arrays of shape (n,). Written with masks rather than a loop, and with sums
    over the selected taps only, so that many frames' chirps, or a whole UWB log,
    cost a handful of numpy calls.
    ``with_features=False`` stops after the first arrival (features NaN).
    """
    a = np.asarray(amplitude, dtype=float)
    if a.ndim != 2 or a.shape[1] == 0:
        raise DataError(f"CIR batch must have shape (n, n_taps), got {a.shape}")
    if not tap_s > 0:
        raise DataError(f"CIR tap spacing must be positive, got {tap_s}")
    n, length = a.shape
    power = a * a
    idx = np.arange(length)[None, :]
    if noise_power is None:
        noise = np.median(power, axis=1) / np.log(2.0)
    else:
        noise = np.zeros(n) + np.asarray(noise_power, dtype=float)
    lead = length if max_lead_s is None else int(np.ceil(max_lead_s / tap_s))
    # Every index the first-arrival step returns lies before the search stop (plus one tap for the parabola).
    width = length if search_stop is None else min(length, int(np.max(search_stop)) + 1)
    valid, peak, p_peak, threshold, edge, tau0, amp0 = _first_arrivals(
        a[:, :width], power[:, :width], idx[:, :width], noise, search_start, search_stop, lead, length,
        noise_threshold_factor(length))
    sel = (power >= threshold[:, None]) & (idx >= edge[:, None]) & valid[:, None]
    if width < length:
        # Another chirp: from the first tap after the search range stronger than the peak, less one
        # pulse width (its rising edge), nothing belongs to this CIR (module docstring, step 2).
        over = power[:, width - 1:] > p_peak[:, None]
        has_over = over.any(axis=1)
        if has_over.any():
            pulse_taps = int(math.ceil((pulse_width_s if pulse_width_s is not None else tap_s) / tap_s))
            cut = np.where(has_over, np.maximum(width - 1 + np.argmax(over, axis=1) - pulse_taps, peak + 1), length)
            sel &= idx < cut[:, None]
    if not with_features:
        return CirBatch(valid=valid, features=np.full((n, len(FEATURE_NAMES)), np.nan), first_arrival_tap=tau0,
                        first_arrival_amplitude=amp0, peak_tap=peak,
                        peak_snr_db=10.0 * np.log10(np.maximum(p_peak, 1e-300) / np.maximum(noise, 1e-300)),
                        threshold_power=threshold, noise_power=noise, tap_mask=sel)
    rows, cols = np.nonzero(sel)
    p_sel = power[rows, cols]
    mean_excess, rms, kurt, skew = _sparse_moments(rows, cols * tap_s, p_sel, n, tau0 * tap_s)

    half_width = 0.5 * (pulse_width_s if pulse_width_s is not None else tap_s)
    in_first = np.abs(cols - tau0[rows]) * tap_s <= half_width + 1e-9 * tap_s
    e_first = np.bincount(rows, weights=np.where(in_first, p_sel, 0.0), minlength=n)
    e_rest = np.bincount(rows, weights=p_sel, minlength=n) - e_first
    count = np.bincount(rows, minlength=n).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        k_db = np.where(e_rest > 0, 10.0 * np.log10(np.maximum(e_first, 1e-300) / np.where(e_rest > 0, e_rest, 1.0)),
                        K_MAX_DB)
        k_db = np.minimum(k_db, K_MAX_DB)
        gain_db = 10.0 * np.log10(np.maximum(p_sel, 1e-300) / np.maximum(p_peak, 1e-300)[rows])
        snr_db = np.where(noise > 0, 10.0 * np.log10(np.maximum(p_peak, 1e-300) / np.where(noise > 0, noise, 1.0)),
                          np.inf)
        g_mean = np.bincount(rows, weights=gain_db, minlength=n) / count
        g_rms = np.sqrt(np.bincount(rows, weights=gain_db * gain_db, minlength=n) / count)
    # Equal weights: population skewness and Pearson kurtosis, as scipy.stats.skew /
    # kurtosis(fisher=False) with bias=True (a test checks the agreement).
    _, _, g_kurt, g_skew = _sparse_moments(rows, gain_db, np.ones(len(rows)), n, np.zeros(n))
    features = np.column_stack([1e3 * mean_excess, 1e3 * rms, kurt, skew, k_db, g_mean, g_rms, g_kurt, g_skew])
    features[~valid] = np.nan
    return CirBatch(valid=valid, features=features, first_arrival_tap=tau0, first_arrival_amplitude=amp0,
                    peak_tap=peak, peak_snr_db=snr_db, threshold_power=threshold, noise_power=noise, tap_mask=sel)


def analyse_cir(amplitude: np.ndarray, tap_s: float, *, noise_power: float | None = None,
                max_lead_s: float | None = None, pulse_width_s: float | None = None,
                search_start: int = 0, search_stop: int | None = None) -> CirAnalysis | None:
    """Features and first arrival of one CIR envelope; None when no tap clears the noise.

    Parameters
    ----------
    amplitude : ndarray of shape (n_taps,)
        Envelope |h| (linear amplitude, not power), ``tap_s`` seconds apart.
    tap_s : float
        Tap spacing, s (1/48000 for audio, ≈ 1.0e-9 for the DecaWave accumulator).
    noise_power : float, optional
        Mean noise power per tap; estimated with :func:`robust_noise_power` when omitted.
    max_lead_s : float, optional
        How far before the strongest tap the leading edge may lie (default: the whole CIR).
    pulse_width_s : float, optional
        Width of one path's lobe (≈ 1/bandwidth); taps within half of it around
        τ₀ count as first-path energy for K (default: one tap).
    search_start, search_stop : int
        The strongest tap is sought in ``[search_start, search_stop)`` (default:
        the whole CIR); taps before ``search_start`` are never the first arrival.

    >>> t = np.arange(200)
    >>> cir = np.exp(-0.5 * ((t - 50) / 2.0) ** 2) + 0.3 * np.exp(-0.5 * ((t - 80) / 2.0) ** 2)
    >>> r = analyse_cir(cir, 1e-3, noise_power=1e-8, pulse_width_s=8e-3)
    >>> round(r.first_arrival_tap, 2), round(r.features.rician_k_db, 1)
    (50.0, 10.8)
    """
    a = np.asarray(amplitude, dtype=float)
    if a.ndim != 1 or len(a) == 0:
        raise DataError(f"CIR must be a non-empty 1-D array, got shape {a.shape}")
    batch = analyse_cirs(a[None, :], tap_s, noise_power=noise_power, max_lead_s=max_lead_s,
                         pulse_width_s=pulse_width_s, search_start=search_start, search_stop=search_stop)
    if not batch.valid[0]:
        return None
    sel = np.flatnonzero(batch.tap_mask[0])
    return CirAnalysis(
        features=CirFeatures(*(float(v) for v in batch.features[0])),
        first_arrival_tap=float(batch.first_arrival_tap[0]),
        first_arrival_amplitude=float(batch.first_arrival_amplitude[0]),
        peak_tap=int(batch.peak_tap[0]),
        peak_snr_db=float(batch.peak_snr_db[0]),
        threshold_power=float(batch.threshold_power[0]),
        noise_power=float(batch.noise_power[0]),
        tap_index=sel,
        tap_power=a[sel] ** 2,
    )
