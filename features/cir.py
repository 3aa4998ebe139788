"""Channel impulse response (CIR) features, for any tap spacing.

One CIR is an envelope ``amplitude`` (n_taps,) sampled every ``tap_s``
seconds: the matched-filter envelope around a beacon chirp (tap = 1/48 kHz),
or a UWB accumulator (tap ≈ 1 ns). The same code serves both.

Steps (DESIGN.md §5):

1. **Noise floor** ``noise_power`` (mean noise power per tap): given by the
   caller, or estimated robustly as ``median(|h|²)/ln 2`` (the median of an
   exponential power distribution is ``ln 2`` times its mean), valid when most
   taps are noise, as in a UWB accumulator window.
2. **Tap selection**: taps with power above ``max(peak − 20 dB, noise + 6 dB)``.
3. **First arrival τ₀ by leading-edge detection**: the earliest tap above the
   threshold within ``max_lead_s`` before the strongest tap; τ₀ is the first
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

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .errors import DataError
from .jit import jit

__all__ = ["CirFeatures", "CirAnalysis", "CirBatch", "analyse_cir", "analyse_cirs", "first_arrivals", "find_paths", "robust_noise_power",
           "FEATURE_NAMES", "K_MAX_DB", "PEAK_DYNAMIC_RANGE_DB", "NOISE_MARGIN_DB"]

PEAK_DYNAMIC_RANGE_DB = 20.0
"""Taps more than this far below the strongest are ignored (DESIGN.md §5)."""

NOISE_MARGIN_DB = 6.0
"""Taps must exceed the noise floor by this much (DESIGN.md §5)."""

K_MAX_DB = 40.0
"""Rician K reported when the first path is the only selected energy, dB."""


class CirFeatures(NamedTuple):
    """The nine acoustic channel features of DESIGN.md §5 (names as in feature tables).

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


def first_arrivals(amplitude: np.ndarray, search_start, search_stop: int, lead: int,
                   noise_power) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Steps 2–3 of the module docstring only: ``(valid, τ₀ in fractional taps, peak SNR in
    dB)``, each of shape (n,) (τ₀ and SNR NaN where not valid).

    ``amplitude`` (n, L): envelopes; ``search_start`` (n,) and ``search_stop``: the
    strongest tap is sought in ``[start, stop)``; ``lead``: how many taps before it
    the leading edge may lie; ``noise_power``: scalar or (n,). The receiver times a
    handful of chirps per TDMA frame with it, through the same compiled kernel as
    :func:`analyse_cirs` (without the features).
    """
    a = np.asarray(amplitude)
    n = a.shape[0]
    starts = np.asarray(search_start, dtype=np.int64)
    if starts.shape != (n,):
        starts = np.broadcast_to(starts, (n,)).copy()
    noise = np.asarray(noise_power, dtype=float)
    if noise.shape != (n,):
        noise = np.full(n, float(noise))
    valid, _, _, _, _, tau, _, snr, _, _ = _cir_kernel(a, starts, int(search_stop), int(lead), noise, 1.0, 0.5,
                                                         False)
    snr[~valid] = np.nan
    return valid, tau, snr


_DYNAMIC_RANGE = 10 ** (-PEAK_DYNAMIC_RANGE_DB / 10)
_NOISE_MARGIN = 10 ** (NOISE_MARGIN_DB / 10)


def analyse_cirs(amplitude: np.ndarray, tap_s: float, *, noise_power=None, max_lead_s: float | None = None,
                 pulse_width_s: float | None = None, search_start=0, search_stop=None,
                 with_features: bool = True) -> CirBatch:
    """:func:`analyse_cir` over the rows of ``amplitude`` (n, L), in one compiled loop.

    ``noise_power`` and ``search_start`` may be scalars or arrays of shape (n,);
    ``search_stop`` a scalar (or an array of one value). ``with_features=False``
    stops after the first arrival (features NaN, tap mask empty). Rows with no
    tap above the threshold are not ``valid``: their features, τ₀ and amplitude
    are NaN. Compiled (:mod:`features.jit`) rather than vectorised: a frame's
    few chirps would cost ~100 numpy calls, far more than the arithmetic.
    """
    a = np.asarray(amplitude)
    if a.dtype != np.float32:
        a = a.astype(float)                  # float32 envelopes go in as they are (taps read as float64)
    if a.ndim != 2 or a.shape[1] == 0:
        raise DataError(f"CIR batch must have shape (n, n_taps), got {a.shape}")
    if not tap_s > 0:
        raise DataError(f"CIR tap spacing must be positive, got {tap_s}")
    n, length = a.shape
    if noise_power is None:
        power = a.astype(float) ** 2
        noise = np.median(power, axis=1) / np.log(2.0)
    else:
        noise = np.zeros(n) + np.asarray(noise_power, dtype=float)
    lead = length if max_lead_s is None else int(np.ceil(max_lead_s / tap_s))
    starts = np.zeros(n, dtype=np.int64) + np.asarray(search_start, dtype=np.int64)
    stop = length if search_stop is None else int(np.max(search_stop))
    if search_stop is not None and np.ndim(search_stop) and np.any(np.asarray(search_stop) != stop):
        raise DataError("search_stop must be the same for every CIR of a batch")
    half_width = 0.5 * (pulse_width_s if pulse_width_s is not None else tap_s)
    valid, peak, p_peak, threshold, edge, tau0, amp0, snr_db, features, sel = _cir_kernel(
        a, starts, stop, lead, noise, float(tap_s), float(half_width), bool(with_features))
    return CirBatch(valid=valid, features=features, first_arrival_tap=tau0, first_arrival_amplitude=amp0,
                    peak_tap=peak, peak_snr_db=snr_db, threshold_power=threshold, noise_power=noise, tap_mask=sel)


@jit
def _cir_kernel(a, starts, search_stop, lead, noise, tap_s, half_width, with_features):
    """Compiled loop of :func:`analyse_cirs` over the rows of ``a`` (n, L), float64 arithmetic.

    Steps 2–6 of the module docstring for each row: the strongest tap in
    ``[start, stop)``, the tap threshold, the leading edge within ``lead`` taps
    before it, τ₀ (first local maximum at or after the edge, log-parabolic),
    then over the selected taps (at or after the edge, above the threshold)
    the delay moments (two passes, Rappaport eq. 5.35–5.36), Rician K and the
    gain moments. Returns (valid, peak, p_peak, threshold, edge, τ₀, amplitude
    at τ₀, peak SNR dB, features (n, 9), tap mask (n, L)); without features the
    features are NaN and the mask empty.
    """
    n, length = a.shape
    valid = np.zeros(n, np.bool_)
    peak_tap = np.zeros(n, np.int64)
    p_peak_out = np.zeros(n)
    threshold_out = np.zeros(n)
    edge_out = np.zeros(n, np.int64)
    tau = np.full(n, np.nan)
    amp0 = np.full(n, np.nan)
    snr = np.full(n, np.nan)
    features = np.full((n, 9), np.nan)
    mask = np.zeros((n, length if with_features else 0), np.bool_)
    stop = min(max(search_stop, 1), length)
    for r in range(n):
        start = min(max(starts[r], 0), stop - 1)
        peak = start
        m = np.float64(a[r, start])
        for i in range(start + 1, stop):
            v = np.float64(a[r, i])
            if v > m:
                m = v
                peak = i
        p_peak = m * m
        threshold = max(p_peak * _DYNAMIC_RANGE, noise[r] * _NOISE_MARGIN)
        peak_tap[r], p_peak_out[r], threshold_out[r] = peak, p_peak, threshold
        snr[r] = 10.0 * np.log10(max(p_peak, 1e-300) / noise[r]) if noise[r] > 0 else np.inf
        if not (np.isfinite(p_peak) and p_peak > threshold):
            continue
        valid[r] = True
        edge = peak
        for i in range(max(start, peak - lead), peak):           # leading edge
            v = np.float64(a[r, i])
            if v * v >= threshold:
                edge = i
                break
        first = edge
        while first < peak and not a[r, first + 1] < a[r, first]:   # first local maximum at or after it
            first += 1
        y0 = np.log(max(np.float64(a[r, first]), 1e-300))
        delta = 0.0
        if 0 < first < length - 1:
            ym = np.log(max(np.float64(a[r, first - 1]), 1e-300))
            yp = np.log(max(np.float64(a[r, first + 1]), 1e-300))
            denom = ym - 2.0 * y0 + yp
            if denom < 0:
                delta = min(max(0.5 * (ym - yp) / denom, -0.5), 0.5)
                y0 = y0 - 0.25 * (ym - yp) * delta
        edge_out[r] = edge
        tau[r] = first + delta
        amp0[r] = np.exp(y0)
        if not with_features:
            continue
        # Selected taps: at or after the edge, above the threshold. Power-weighted delay moments.
        e_all = e_first = sum_pt = 0.0
        count = 0
        for i in range(edge, length):
            v = np.float64(a[r, i])
            p = v * v
            if p >= threshold:
                mask[r, i] = True
                e_all += p
                sum_pt += p * (i * tap_s)
                count += 1
                if abs(i - tau[r]) * tap_s <= half_width + 1e-9 * tap_s:
                    e_first += p
        mean = sum_pt / e_all
        c2 = c3 = c4 = 0.0
        g_sum = g_sq = 0.0
        for i in range(edge, length):
            if mask[r, i]:
                v = np.float64(a[r, i])
                p = v * v
                dev = i * tap_s - mean
                c2 += p * dev * dev
                c3 += p * dev * dev * dev
                c4 += p * dev * dev * dev * dev
                g = 10.0 * np.log10(max(p, 1e-300) / max(p_peak, 1e-300))
                g_sum += g
                g_sq += g * g
        var, m3, m4 = c2 / e_all, c3 / e_all, c4 / e_all
        features[r, 0] = 1e3 * (mean - tau[r] * tap_s)
        features[r, 1] = 1e3 * np.sqrt(max(var, 0.0))
        if var > 1e-30 * max(mean * mean, 1e-300):
            features[r, 2] = m4 / var ** 2
            features[r, 3] = m3 / var ** 1.5
        e_rest = e_all - e_first
        features[r, 4] = min(10.0 * np.log10(max(e_first, 1e-300) / e_rest), K_MAX_DB) if e_rest > 0 else K_MAX_DB
        g_mean = g_sum / count
        features[r, 5] = g_mean
        features[r, 6] = np.sqrt(g_sq / count)
        # Equal weights: population skewness and Pearson kurtosis, as scipy.stats.skew /
        # kurtosis(fisher=False) with bias=True (a test checks the agreement).
        d2 = d3 = d4 = 0.0
        for i in range(edge, length):
            if mask[r, i]:
                v = np.float64(a[r, i])
                dev = 10.0 * np.log10(max(v * v, 1e-300) / max(p_peak, 1e-300)) - g_mean
                d2 += dev * dev
                d3 += dev * dev * dev
                d4 += dev * dev * dev * dev
        g_var, g3, g4 = d2 / count, d3 / count, d4 / count
        if g_var > 1e-30 * max(g_mean * g_mean, 1e-300):
            features[r, 7] = g4 / g_var ** 2
            features[r, 8] = g3 / g_var ** 1.5
    return valid, peak_tap, p_peak_out, threshold_out, edge_out, tau, amp0, snr, features, mask


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
