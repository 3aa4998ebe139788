"""Step detection and step length from the accelerometer.

Detection (any carrying position: waist, hand, pockets, bag, armband, neck)
    1. Norm of the specific force (orientation-free), low-pass filtered with a
       zero-phase Butterworth (4th order, 3 Hz: passes walking cadences up to
       ~2.5 Hz, removes impacts and jitter).
    2. Detrended by a 2 s moving mean (removes gravity and slow posture
       changes).
    3. Peaks (``scipy.signal.find_peaks``) at least ``min_interval_s`` apart
       whose prominence exceeds both an absolute floor and a multiple of the
       local RMS of the detrended signal (amplitude constraint, adaptive to
       the carrying position). The prominence is taken within ``max_interval_s``
       either side of the peak (``wlen``), so a step is judged by its own
       cycle, never by samples beyond a stop (a long walk's cut reads the same).
    4. Count regulation: peaks are grouped into bouts in which consecutive
       peaks are at most ``max_interval_s`` apart, and bouts of fewer than
       ``min_bout_steps`` peaks are discarded (Zhao 2010, "Full-featured
       pedometer design realized with 3-axis digital accelerometer", Analog
       Dialogue 44-06: a time window of 0.2-2 s between steps and counting
       only after several consecutive steps). A bout may start after any
       pause, so standing starts are kept.
    Per-step intervals inside a bout are the walking constraint (0.3-1.0 s by
    default; the issue's 0.2-0.7 s walking range sits inside it, with slack
    for slow steps).

Step length
    Weinberg (2002, Analog Devices AN-602 eq. 1): S = K·(a_max − a_min)^(1/4),
    a_max/a_min the extremes of the filtered norm over the step.
    Improved model: S = K·(a_max − a_min)^(1/4) + β·(Δā / T), Δā the mean
    absolute sample-to-sample change of the filtered norm over the step and T
    the step time — the "mean acceleration change per step time" term the
    source RTK/PDR work adds to Weinberg; (K, β) come from linear least squares
    over calibration segments of known length (GNSS or surveyed), in the
    spirit of Shin et al. (2007, IEEE SAS, "Adaptive step length estimation
    algorithm using low-cost MEMS inertial sensors"), who fit step length
    linearly in frequency and acceleration variance.

    Held-out status (tests/test_pdr_sim.py: simulated walks of one person at
    1.06-1.50 m/s, fitted on one walk, scored on five others): Weinberg
    +2.51 +0.06 +0.94 +0.80 +2.48 % distance error (mean |e| 1.36 %), the
    improved model −1.29 +1.21 −0.45 −0.64 −0.28 % (mean |e| 0.77 %). In
    that walker Weinberg's K drifts with cadence (K ∝ f^¼ for a pendulum)
    and β partly absorbs it; with an earlier walker that had Weinberg built
    in, the improved model was up to 12 % off. Its advantage therefore
    depends on the gait, so Weinberg stays the default (β = 0) and the CLI
    uses Weinberg only; :func:`fit_improved_model` keeps β only when it
    beats Weinberg on held-out data, best a *different* walk of known length
    (``validation``).

Step time
    A step is reported at the peak of the filtered acceleration norm. On a
    waist device this is heel strike: the pelvis vaults over the stance leg
    (inverted pendulum) and is lowest, with maximal upward acceleration, in
    double support (Zijlstra & Hof 2003, Gait & Posture 18:1-10). The
    zero-phase filter keeps the peak in place; the simulator's
    truth_steps.csv lists heel strikes, and on simulated walks the median
    |Δt| is ≈ 5 ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, signal

from features.errors import ConfigError, DataError

__all__ = ["StepDetectorConfig", "Steps", "StepLengthModel", "filtered_norm", "detect_steps",
           "weinberg_length", "calibrate_weinberg_k", "fit_improved_model"]


@dataclass(frozen=True)
class StepDetectorConfig:
    """Step detector parameters (defaults: see module docstring)."""

    lowpass_hz: float = 3.0
    filter_order: int = 4
    detrend_window_s: float = 2.0
    rms_window_s: float = 1.0
    min_interval_s: float = 0.3
    max_interval_s: float = 1.0
    min_prominence_m_s2: float = 0.5
    prominence_rms_factor: float = 1.4
    min_bout_steps: int = 4

    def __post_init__(self):
        for name in ("lowpass_hz", "detrend_window_s", "rms_window_s", "min_interval_s", "max_interval_s",
                     "min_prominence_m_s2", "prominence_rms_factor"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"StepDetectorConfig.{name} must be a positive number, got {value!r}")
        if self.max_interval_s <= self.min_interval_s:
            raise ConfigError(f"max_interval_s ({self.max_interval_s}) must exceed min_interval_s ({self.min_interval_s})")
        if not 1 <= self.filter_order <= 10 or self.min_bout_steps < 1:
            raise ConfigError("filter_order must lie in [1, 10] and min_bout_steps >= 1")


@dataclass(frozen=True)
class Steps:
    """Detected steps.

    Attributes (all ndarray of shape (n_steps,))
    ----------
    index : int sample index of the peak; ``t_s`` its time.
    window_start, window_end : int, the step's samples are ``[window_start, window_end)``
        (after the previous peak up to and including this one).
    duration_s : step time T (peak-to-peak; for a bout's first step the median of its next three).
    a_max_m_s2, a_min_m_s2 : extremes of the filtered norm over the step.
    mean_change_m_s2 : mean |Δa| between consecutive samples over the step.
    bout_start : bool, first step of a walking bout.
    """

    index: np.ndarray
    t_s: np.ndarray
    window_start: np.ndarray
    window_end: np.ndarray
    duration_s: np.ndarray
    a_max_m_s2: np.ndarray
    a_min_m_s2: np.ndarray
    mean_change_m_s2: np.ndarray
    bout_start: np.ndarray

    def __len__(self) -> int:
        return len(self.index)

    @property
    def weinberg_feature(self) -> np.ndarray:
        """(a_max − a_min)^(1/4), shape (n_steps,)."""
        return np.maximum(self.a_max_m_s2 - self.a_min_m_s2, 0.0) ** 0.25

    @property
    def change_rate_feature(self) -> np.ndarray:
        """Mean acceleration change per step time Δā / T, m/s³, shape (n_steps,)."""
        return self.mean_change_m_s2 / np.maximum(self.duration_s, 1e-3)


def filtered_norm(acc_m_s2: np.ndarray, rate_hz: float, config: StepDetectorConfig = StepDetectorConfig()) -> np.ndarray:
    """Zero-phase low-passed norm of the specific force, m/s², shape (n,)."""
    norm = np.sqrt(np.einsum("ij,ij->i", acc_m_s2, acc_m_s2))
    cutoff = min(config.lowpass_hz, 0.45 * rate_hz)
    sos = signal.butter(config.filter_order, cutoff, fs=rate_hz, output="sos")
    if len(norm) <= 3 * (2 * len(sos) + 1):
        return norm.copy()
    return signal.sosfiltfilt(sos, norm)


def _bouts(peaks_s: np.ndarray, max_interval_s: float, min_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Keep-mask of peaks in bouts of at least ``min_steps``; bout-start flags."""
    if len(peaks_s) == 0:
        return np.zeros(0, bool), np.zeros(0, bool)
    new_bout = np.r_[True, np.diff(peaks_s) > max_interval_s]
    bout_id = np.cumsum(new_bout) - 1
    sizes = np.bincount(bout_id)
    return sizes[bout_id] >= min_steps, new_bout


def detect_steps(acc_m_s2: np.ndarray, rate_hz: float, t_s: np.ndarray | None = None,
                 valid: np.ndarray | None = None, config: StepDetectorConfig = StepDetectorConfig()) -> Steps:
    """Detect steps in uniformly sampled accelerometer data.

    Parameters
    ----------
    acc_m_s2 : ndarray of shape (n, 3)
    rate_hz : float, sampling rate of the uniform grid
    t_s : ndarray of shape (n,), sample times (default ``arange(n)/rate_hz``)
    valid : bool ndarray of shape (n,), False inside data gaps (no step there)
    """
    acc = np.asarray(acc_m_s2, dtype=float)
    if acc.ndim != 2 or acc.shape[1] != 3:
        raise DataError(f"acc_m_s2 must have shape (n, 3), got {acc.shape}")
    n = len(acc)
    t = np.arange(n) / rate_hz if t_s is None else np.asarray(t_s, dtype=float)
    a = filtered_norm(acc, rate_hz, config)
    w = max(int(round(config.detrend_window_s * rate_hz)), 1)
    hp = a - ndimage.uniform_filter1d(a, w, mode="nearest")
    wr = max(int(round(config.rms_window_s * rate_hz)), 1)
    # a running mean (scipy keeps a running sum) of squares can come out a round-off below zero where the signal
    # falls from walking to an IMU held perfectly still: it is zero there, not NaN (which dropped any peak)
    rms = np.sqrt(np.maximum(ndimage.uniform_filter1d(hp * hp, wr, mode="nearest"), 0.0))
    # prominence judged within one longest step interval either side (``wlen``): without it a peak's bases were
    # sought out to the next higher peak, across a stop of any length, so whether the last step before a stop
    # (the first after one) counted depended on samples minutes away, and on where a long walk was cut
    peaks, props = signal.find_peaks(hp, distance=max(int(round(config.min_interval_s * rate_hz)), 1),
                                     prominence=config.min_prominence_m_s2,
                                     wlen=2 * max(int(round(config.max_interval_s * rate_hz)), 1) + 1)
    keep = props["prominences"] >= config.prominence_rms_factor * rms[peaks]
    if valid is not None:
        keep &= np.asarray(valid, bool)[peaks]
    peaks = peaks[keep]
    in_bout, _ = _bouts(t[peaks], config.max_interval_s, config.min_bout_steps)
    peaks = peaks[in_bout]
    _, bout_start = _bouts(t[peaks], config.max_interval_s, 1)
    return _step_features(a, t, peaks, bout_start, rate_hz)


FIRST_STEP_INTERVALS = 3
"""Intervals after a bout's first step whose median stands for its duration: odd (the median is one of them),
and as many as the shortest bout has by default (``min_bout_steps`` 4: three intervals); a shorter bout (a
lower ``min_bout_steps``) takes what it has."""


def _step_features(a: np.ndarray, t: np.ndarray, peaks: np.ndarray, bout_start: np.ndarray, rate_hz: float) -> Steps:
    m = len(peaks)
    if m == 0:
        z = np.zeros(0)
        zi = np.zeros(0, dtype=int)
        return Steps(zi, z, zi, zi, z, z, z, z, np.zeros(0, bool))
    interval = np.diff(t[peaks], prepend=np.nan)
    gap = np.diff(peaks, prepend=0)                        # the same in samples
    # first step of a bout: the median of its bout's next FIRST_STEP_INTERVALS intervals, in seconds for its
    # duration and in samples for its window (or 0.55 s, a typical step, for a lone step). Local: the median of
    # the whole bout depended on steps minutes later, and a long walk's cut ending inside the bout read another.
    bout_id = np.cumsum(bout_start) - 1
    inner = ~bout_start
    med = np.full(bout_id.max() + 1, 0.55)
    med_n = np.full(bout_id.max() + 1, int(round(0.55 * rate_hz)))
    for b in np.unique(bout_id[inner]):
        mine = np.flatnonzero(inner & (bout_id == b))[:FIRST_STEP_INTERVALS]
        med[b] = float(np.median(interval[mine]))
        med_n[b] = int(np.median(gap[mine]))             # an odd count of whole samples: one of them
    duration = np.where(bout_start, med[bout_id], interval)
    end = peaks + 1
    start = np.where(bout_start, peaks - med_n[bout_id] + 1, np.r_[0, peaks[:-1]] + 1)
    start = np.maximum(start, np.r_[0, end[:-1]])
    start = np.minimum(np.maximum(start, 0), peaks)
    # windows are contiguous or separated: reduce over [start_k, end_k) via interleaved reduceat
    edges = np.empty(2 * m, dtype=int)
    edges[0::2] = start
    edges[1::2] = end
    edges_r = edges[:-1] if end[-1] >= len(a) else edges
    a_max = np.maximum.reduceat(a, edges_r)[0::2][:m]
    a_min = np.minimum.reduceat(a, edges_r)[0::2][:m]
    da = np.abs(np.diff(a, prepend=a[0]))
    sum_da = np.add.reduceat(da, edges_r)[0::2][:m]
    mean_change = sum_da / np.maximum(end - start, 1)
    return Steps(index=peaks, t_s=t[peaks], window_start=start, window_end=end, duration_s=duration,
                 a_max_m_s2=a_max, a_min_m_s2=a_min, mean_change_m_s2=mean_change, bout_start=bout_start)


def weinberg_length(a_max_m_s2: np.ndarray, a_min_m_s2: np.ndarray, k: float) -> np.ndarray:
    """Weinberg step length S = K·(a_max − a_min)^(1/4), m (AN-602 eq. 1).

    >>> float(weinberg_length(np.array([16.0]), np.array([0.0]), 0.5)[0])
    1.0
    """
    return k * np.maximum(np.asarray(a_max_m_s2) - np.asarray(a_min_m_s2), 0.0) ** 0.25


@dataclass(frozen=True)
class StepLengthModel:
    """S = K·(a_max − a_min)^(1/4) + β·Δā/T; β = 0 (the default) is Weinberg's model.

    ``k`` default 0.47 is a typical adult value for a waist device; calibrate it
    (:func:`calibrate_weinberg_k`, :func:`fit_improved_model`) for metre-level
    distance.
    """

    k: float = 0.47
    beta: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.k) and 0.05 <= self.k <= 3.0):
            raise ConfigError(f"StepLengthModel.k must lie in [0.05, 3], got {self.k}")
        if not math.isfinite(self.beta):
            raise ConfigError(f"StepLengthModel.beta must be finite, got {self.beta}")

    def predict(self, steps: Steps) -> np.ndarray:
        """Step lengths, m, shape (n_steps,), never negative."""
        return np.maximum(self.k * steps.weinberg_feature + self.beta * steps.change_rate_feature, 0.0)


def calibrate_weinberg_k(steps: Steps, distance_m: float) -> float:
    """K such that the Weinberg lengths of ``steps`` add up to ``distance_m`` (a walk of known length).

    K = D / Σ (a_max − a_min)^(1/4).
    """
    if not (math.isfinite(distance_m) and distance_m > 0):
        raise DataError(f"calibration distance must be positive, got {distance_m}")
    total = float(steps.weinberg_feature.sum())
    if len(steps) < 4 or total <= 0:
        raise DataError(f"calibration walk has too few detected steps ({len(steps)})")
    return distance_m / total


def fit_improved_model(steps: Steps, segment_of_step: np.ndarray, segment_distance_m: np.ndarray,
                       select: bool = True, validation: tuple[Steps, float] | None = None) -> StepLengthModel:
    """Least-squares (K, β) of the improved model from segments of known length.

    Parameters
    ----------
    steps : Steps
    segment_of_step : int ndarray of shape (n_steps,), segment id per step (−1: not in any)
    segment_distance_m : ndarray of shape (n_segments,), true length of each segment (GNSS / survey)
    select : bool
        Keep the β term only if it predicts held-out data better than Weinberg
        alone (K = ΣD/ΣF); otherwise return Weinberg (β = 0).
    validation : (Steps, distance_m) or None
        A *different* walk of known length: the held-out data for ``select``
        (recommended: segments of one walk share its speed, so the default
        leave-one-segment-out check is optimistic — see the module docstring).
        Without it, leave-one-segment-out within the calibration walk decides.

    Needs at least three segments; solves D_j = K·Σ_j F_k + β·Σ_j G_k.
    """
    seg = np.asarray(segment_of_step, dtype=int)
    dist = np.asarray(segment_distance_m, dtype=float)
    if len(dist) < 3:
        raise DataError("the improved step-length model needs at least three calibration segments")
    ok = seg >= 0
    f = np.bincount(seg[ok], steps.weinberg_feature[ok], minlength=len(dist))
    g = np.bincount(seg[ok], steps.change_rate_feature[ok], minlength=len(dist))
    design = np.stack([f, g], axis=1)
    (k, beta), *_ = np.linalg.lstsq(design, dist, rcond=None)
    if not select:
        return StepLengthModel(k=float(k), beta=float(beta))
    k_w = float(dist.sum() / max(f.sum(), 1e-12))
    if validation is not None:
        val_steps, val_m = validation
        if not (math.isfinite(val_m) and val_m > 0):
            raise DataError(f"validation distance must be positive, got {val_m}")
        improved = StepLengthModel(k=float(k), beta=float(beta))
        err_i = abs(float(improved.predict(val_steps).sum()) - val_m)
        err_w = abs(k_w * float(val_steps.weinberg_feature.sum()) - val_m)
        return improved if err_i < err_w else StepLengthModel(k=k_w, beta=0.0)
    err_w = err_i = 0.0
    for j in range(len(dist)):
        rest = np.arange(len(dist)) != j
        k_w = dist[rest].sum() / max(f[rest].sum(), 1e-12)
        coef, *_ = np.linalg.lstsq(design[rest], dist[rest], rcond=None)
        err_w += (dist[j] - k_w * f[j]) ** 2
        err_i += (dist[j] - design[j] @ coef) ** 2
    if err_i < err_w:
        return StepLengthModel(k=float(k), beta=float(beta))
    return StepLengthModel(k=k_w, beta=0.0)
