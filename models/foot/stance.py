"""Stance-phase (zero-velocity) detection on a foot-mounted IMU: the GLRT / SHOE detector, and step counting.

The stance hypothesis detector of Skog, Händel, Nilsson & Rantakokko (2010), "Zero-velocity detection — an
algorithm evaluation", IEEE Trans. Biomed. Eng. 57(11) — the SHOE (stance hypothesis optimal
estimation) detector, the generalised likelihood-ratio test of "the IMU is still" against "it moves" with
white Gaussian sensor noise:

    T(zₙ) = (1/W) Σ_{k ∈ Ωₙ} [ (1/σ_a²) ‖y_k^a − g ȳₙ^a/‖ȳₙ^a‖‖² + (1/σ_ω²) ‖y_k^ω‖² ]

over the window Ωₙ = {n, …, n + W − 1} of W samples, ȳₙ^a the window's mean specific force; the foot is
still (a stance sample) where T < γ. As OpenShoe (Nilsson et al. 2012) does it, a window below γ marks all
of its W samples as stance. Defaults are OpenShoe's: σ_a = 0.01 m/s², σ_ω = 0.1 °/s, W = 3, γ = 0.3·10⁵
(chosen for an 820 Hz MIMU22BT; the test statistic scales with the noise the σ's stand for, so γ is a
per-sensor setting: :class:`StanceConfig`).

A step of the instrumented foot (a stride) is one swing between two stances; :func:`count_strides` counts
them after closing stance gaps shorter than ``min_swing_s`` (a jolt inside a stance) and dropping stance
spells shorter than ``min_stance_s`` (a pause of the statistic inside a swing). A swing lasts about 40 % of a
gait cycle of 1.0–1.2 s, ≈ 0.4 s (Perry & Burnfield 2010, *Gait Analysis*, 2nd ed., ch. 1), so
``min_swing_s`` = 0.25 s keeps every real swing and closes the brief motion of a heel strike or a toe roll.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["StanceConfig", "glrt_statistic", "detect_stance", "count_strides", "stance_segments", "stance_spells"]


@dataclass(frozen=True)
class StanceConfig:
    """The SHOE detector's settings (module docstring); σ's in SI units, ``gamma`` dimensionless."""

    sigma_acc_m_s2: float = 0.01
    sigma_gyro_rad_s: float = float(np.radians(0.1))
    window: int = 3
    gamma: float = 0.3e5
    gravity_m_s2: float = 9.80665
    min_swing_s: float = 0.25
    min_stance_s: float = 0.04

    def __post_init__(self):
        for name in ("sigma_acc_m_s2", "sigma_gyro_rad_s", "gamma", "gravity_m_s2"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"StanceConfig.{name} must be a positive number, got {v}")
        if not (isinstance(self.window, (int, np.integer)) and self.window >= 1):
            raise ValueError(f"StanceConfig.window must be an integer >= 1, got {self.window}")
        for name in ("min_swing_s", "min_stance_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"StanceConfig.{name} must be >= 0, got {v}")


def glrt_statistic(acc_m_s2: np.ndarray, gyro_rad_s: np.ndarray, cfg: StanceConfig = StanceConfig()) -> np.ndarray:
    """The SHOE test statistic T(zₙ) of every window start n (Skog et al. 2010; module docstring).

    ``acc_m_s2``, ``gyro_rad_s`` : ndarray of shape (N, 3). Returns ndarray of shape (N − W + 1,).
    """
    a = np.asarray(acc_m_s2, float)
    w = np.asarray(gyro_rad_s, float)
    W = cfg.window
    if a.shape != w.shape or a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"acc and gyro must both be (N, 3), got {a.shape} and {w.shape}")
    if len(a) < W:
        return np.zeros(0)
    # ȳₙ^a: moving mean over the window (cumulative sums)
    c = np.vstack([np.zeros((1, 3)), np.cumsum(a, axis=0)])
    mean = (c[W:] - c[:-W]) / W
    u = mean / np.linalg.norm(mean, axis=1, keepdims=True)
    # Σ_k ‖y_k^a − g u‖² = Σ ‖y_k‖² − 2 g u·Σ y_k + W g²   (u a unit vector)
    a2 = np.r_[0.0, np.cumsum(np.sum(a * a, axis=1))]
    sum_a2 = a2[W:] - a2[:-W]
    g = cfg.gravity_m_s2
    acc_term = sum_a2 - 2.0 * g * np.sum(u * (c[W:] - c[:-W]), axis=1) + W * g * g
    w2 = np.r_[0.0, np.cumsum(np.sum(w * w, axis=1))]
    gyro_term = w2[W:] - w2[:-W]
    return (acc_term / cfg.sigma_acc_m_s2 ** 2 + gyro_term / cfg.sigma_gyro_rad_s ** 2) / W


def detect_stance(acc_m_s2: np.ndarray, gyro_rad_s: np.ndarray, cfg: StanceConfig = StanceConfig()) -> np.ndarray:
    """Stance samples, bool (N,): every sample of a window whose T < γ (OpenShoe's rule)."""
    T = glrt_statistic(acc_m_s2, gyro_rad_s, cfg)
    n = len(acc_m_s2)
    still = np.zeros(n, bool)
    starts = np.flatnonzero(T < cfg.gamma)
    for j in range(cfg.window):
        still[starts + j] = True
    return still


def stance_segments(stance: np.ndarray) -> np.ndarray:
    """[start, stop) index pairs of the True runs of ``stance``, shape (n_runs, 2)."""
    d = np.diff(np.r_[0, np.asarray(stance, np.int8), 0])
    return np.column_stack([np.flatnonzero(d == 1), np.flatnonzero(d == -1)])


def _cleaned(stance: np.ndarray, rate_hz: float, cfg: StanceConfig) -> np.ndarray:
    """Stance with gaps shorter than ``min_swing_s`` closed and spells shorter than ``min_stance_s`` dropped."""
    s = np.asarray(stance, bool).copy()
    runs = stance_segments(s)
    for (a0, a1), (b0, _) in zip(runs[:-1], runs[1:]):
        if (b0 - a1) < cfg.min_swing_s * rate_hz:
            s[a1:b0] = True
    for a, b in stance_segments(s):
        if (b - a) < cfg.min_stance_s * rate_hz:
            s[a:b] = False
    return s


def stance_spells(stance: np.ndarray, rate_hz: float, cfg: StanceConfig = StanceConfig()) -> np.ndarray:
    """[start, stop) index pairs (n_spells, 2) of the stance spells after :func:`_cleaned` (gaps shorter than
    ``min_swing_s`` closed, spells shorter than ``min_stance_s`` dropped): one per footfall."""
    return stance_segments(_cleaned(stance, rate_hz, cfg))


def count_strides(stance: np.ndarray, rate_hz: float, cfg: StanceConfig = StanceConfig()) -> int:
    """Strides of the instrumented foot: swings between two stance spells (:func:`stance_spells`)."""
    return max(len(stance_spells(stance, rate_hz, cfg)) - 1, 0)
