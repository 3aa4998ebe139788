"""The compiled CIR kernel against the vectorised numpy implementation it replaced.

``reference_analyse_cirs`` below is that numpy code (masks, sums over the
selected taps with numpy.bincount), kept as an independent oracle: every output
of :func:`features.cir.analyse_cirs` must match it on random CIRs with one to
four paths, noise given or estimated, several tap spacings and search ranges.
"""

from __future__ import annotations

import numpy as np
import pytest

from features.cir import K_MAX_DB, NOISE_MARGIN_DB, PEAK_DYNAMIC_RANGE_DB, analyse_cirs, first_arrivals


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
                    search_stop, lead: int, length: int):
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
    threshold = np.maximum(p_peak * 10 ** (-PEAK_DYNAMIC_RANGE_DB / 10), noise * 10 ** (NOISE_MARGIN_DB / 10))
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


def reference_analyse_cirs(amplitude: np.ndarray, tap_s: float, *, noise_power=None, max_lead_s: float | None = None,
                           pulse_width_s: float | None = None, search_start=0, search_stop=None,
                           with_features: bool = True) -> dict:
    """The former vectorised ``analyse_cirs``: masks over (n, L), sums over the selected taps."""
    a = np.asarray(amplitude, dtype=float)
    if a.ndim != 2 or a.shape[1] == 0:
        raise ValueError(f"CIR batch must have shape (n, n_taps), got {a.shape}")
    if not tap_s > 0:
        raise ValueError(f"CIR tap spacing must be positive, got {tap_s}")
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
        a[:, :width], power[:, :width], idx[:, :width], noise, search_start, search_stop, lead, length)
    sel = (power >= threshold[:, None]) & (idx >= edge[:, None]) & valid[:, None]
    if not with_features:
        raise AssertionError('the reference is used with features')
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
    return dict(valid=valid, features=features, first_arrival_tap=tau0, first_arrival_amplitude=amp0,
                peak_tap=peak, peak_snr_db=snr_db, threshold_power=threshold, noise_power=noise, tap_mask=sel)


def _random_cirs(seed: int, n: int = 300, length: int = 120) -> np.ndarray:
    rng = np.random.default_rng(seed)
    amp = rng.rayleigh(1.0, (n, length))
    lobe = np.array([0.3, 0.8, 1.0, 0.8, 0.3])
    for row in amp:
        for _ in range(rng.integers(1, 5)):
            k = int(rng.integers(2, length - 2))
            row[k - 2: k + 3] += rng.choice([0.5, 3.0, 10.0, 40.0]) * lobe
    return amp.astype(np.float32)


@pytest.mark.parametrize("seed, tap_s, noise, lead_s, pulse_s, stop", [
    (0, 1e-3, 2.0, 0.030, 8e-3, 70),
    (1, 4 / 48000, None, None, 5e-4, None),
    (2, 1e-9, 2.0, 12e-9, 3e-9, 120),
    (3, 1e-3, np.linspace(0.5, 4.0, 300), 0.010, None, 90),
])
def test_kernel_matches_the_numpy_reference(seed, tap_s, noise, lead_s, pulse_s, stop):
    amp = _random_cirs(seed)
    starts = np.random.default_rng(seed + 100).integers(0, 50, len(amp))
    got = analyse_cirs(amp, tap_s, noise_power=noise, max_lead_s=lead_s, pulse_width_s=pulse_s, search_start=starts,
                       search_stop=stop)
    ref = reference_analyse_cirs(amp, tap_s, noise_power=noise, max_lead_s=lead_s, pulse_width_s=pulse_s,
                                 search_start=starts, search_stop=stop)
    ok = ref["valid"]
    assert 0 < ok.sum() < len(amp) or noise is None
    np.testing.assert_array_equal(got.valid, ok)
    np.testing.assert_array_equal(got.peak_tap, ref["peak_tap"])
    np.testing.assert_allclose(got.threshold_power, ref["threshold_power"], rtol=1e-12)
    np.testing.assert_allclose(got.first_arrival_tap[ok], ref["first_arrival_tap"][ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.first_arrival_amplitude[ok], ref["first_arrival_amplitude"][ok], rtol=1e-9)
    np.testing.assert_allclose(got.peak_snr_db[ok], ref["peak_snr_db"][ok], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got.tap_mask, ref["tap_mask"])
    np.testing.assert_allclose(got.features, ref["features"], rtol=1e-9, atol=1e-9, equal_nan=True)
    assert np.isfinite(got.features[ok][:, [0, 1, 4, 5, 6]]).all()
    assert np.isnan(got.features[~ok]).all()


def test_first_arrivals_is_the_kernel_without_features():
    amp = _random_cirs(7, n=200, length=64)
    starts = np.random.default_rng(7).integers(0, 40, len(amp))
    valid, tau, snr = first_arrivals(amp, starts, 57, 30, 2.0)
    ref = reference_analyse_cirs(amp, 1.0, noise_power=2.0, max_lead_s=30.0, search_start=starts, search_stop=57)
    np.testing.assert_array_equal(valid, ref["valid"])
    np.testing.assert_allclose(tau[valid], ref["first_arrival_tap"][valid], rtol=0, atol=1e-9)
    np.testing.assert_allclose(snr[valid], ref["peak_snr_db"][valid], rtol=0, atol=1e-9)
    assert np.isnan(tau[~valid]).all() and np.isnan(snr[~valid]).all()
