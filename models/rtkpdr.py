"""The RTK/PDR extended Kalman filter of Zhang et al. (2023), on the project's filter core.

Zhang, Zhou, Wang, Wang & Huang (2023), "Personnel Localization of Real-Time Kinematic Based on
Pedestrian Heading Projection Compensation in Substation Signal Interference Environment", J. Sensor
Technology 13, 37–50: PDR with an improved step-length model and a gyroscope–accelerometer–
magnetometer complementary heading, fused with RTK positions by an EKF whose state is position and
heading.

Heading (:func:`complementary_heading_seed`), per IMU sample k (ΔT = 1/rate)::

    # φ_k = β·(φ_{k−1} + ω_k·ΔT) + (1 − β)·φ_k^am

ω the yaw rate (the gyro about the vertical, :func:`features.imu.heading.yaw_rate`), φ^am the
accelerometer-levelled magnetic heading (:func:`features.imu.heading.magnetic_heading`), unwrapped so
the blend never crosses ±π; β = τ/(τ + ΔT) for a time constant τ. A linear recursion, run as one IIR
filter (``scipy.signal.lfilter``). A step's heading is its samples' circular mean
(:func:`features.imu.pdr.step_heading`), its length the improved model S = K·(a_max − a_min)^¼ + β_s·Δā/T
(:class:`features.imu.steps.StepLengthModel`), K and β_s fitted on training walks.

Filter (:class:`RtkPdrEKF`), state x = [east_m, north_m, φ_rad]; per step of length L whose
complementary heading moved by Δφ since the previous step::

    # φ⁻ = φ + Δφ + w_φ,   e⁻ = e + L·sin φ⁻,   n⁻ = n + L·cos φ⁻
    # F = ∂f/∂x = [[1, 0, L cos φ⁻], [0, 1, −L sin φ⁻], [0, 0, 1]]
    # P⁻ = F (P + diag(0, 0, σ_φ²)) F' + g g' σ_L²,   g = (sin φ⁻, cos φ⁻, 0)

with the paper's PDR noise σ_φ = 0.65° and σ_L = 0.07 m per step (a step split at fix times takes its
share in proportion to its length); between events the position random walk of the project's EKF
(:func:`models.fusion.core.time_update`). An RTK (GNSS) fix updates the position through
:func:`models.fusion.core.kalman_update` (Joseph form), H = [I₂ 0]. The paper handles no outliers:
``outlier="none"`` is the default, the core's gate and Huber weights are available.
The run is a :class:`models.fusion.ekf.FilterRun`, so the RTS smoother applies as to every filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from features.imu.heading import down_in_body, magnetic_heading, yaw_rate
from features.imu.pdr import step_heading
from models.fusion.core import kalman_update, time_update
from models.fusion.ekf import OUTLIER_CODES, FilterError, FilterRun, empty_records
from models.fusion.events import STEP, EventStream

__all__ = ["SeedConfig", "RtkPdrEKF", "complementary_heading_seed", "seed_step_headings", "seed_step",
           "SEED_SIGMA_HEADING_RAD", "SEED_SIGMA_STEP_M"]

SEED_SIGMA_HEADING_RAD = math.radians(0.65)
"""PDR heading noise per step, rad (Zhang et al. 2023: 0.65°)."""

SEED_SIGMA_STEP_M = 0.07
"""PDR step-length noise per step, m (Zhang et al. 2023: 0.07 m)."""


def complementary_heading_seed(rate_rad_s: np.ndarray, am_heading_rad: np.ndarray, rate_hz: float,
                               tau_s: float) -> np.ndarray:
    """φ_k = β(φ_{k−1} + ω_k ΔT) + (1 − β)φ_k^am, β = τ/(τ + ΔT), φ_0 = φ_0^am; shapes (n,) → (n,), unwrapped.

    >>> phi = complementary_heading_seed(np.array([0.0, 1.0, 1.0]), np.zeros(3), 10.0, 0.9)   # β = 0.9
    >>> [round(float(v), 4) for v in phi]                        # 0; 0.9·0.1; 0.9·(0.09 + 0.1)
    [0.0, 0.09, 0.171]
    """
    if not (math.isfinite(tau_s) and tau_s > 0):
        raise FilterError(f"tau_s must be finite and > 0, got {tau_s}")
    dt = 1.0 / rate_hz
    beta = tau_s / (tau_s + dt)
    w = np.asarray(rate_rad_s, float)
    am = np.unwrap(np.asarray(am_heading_rad, float))
    u = beta * w * dt + (1.0 - beta) * am
    # y_k = β y_{k−1} + u_k, started at y_0 = am_0: the initial condition zi = β·am_0 gives y_0 = β am_0 + u_0
    # with u_0 replaced so that y_0 = am_0 exactly
    u = u.copy()
    u[0] = am[0]
    y, _ = signal.lfilter([1.0], [1.0, -beta], u, zi=[0.0])
    return y


def seed_step_headings(imu, steps, declination_rad: float, tau_s: float) -> np.ndarray:
    """Per-step seed heading (rad from north, clockwise), shape (n_steps,): the complementary heading of the
    IMU samples (``imu``: :class:`features.imu.reader.ImuData` with gyro and magnetometer) averaged over
    each step (``steps``: :class:`features.imu.steps.Steps`)."""
    if imu.gyro_rad_s is None or imu.mag_ut is None:
        raise FilterError("the seed's complementary heading needs gyro and magnetometer")
    down = down_in_body(imu.acc_m_s2, imu.rate_hz)
    am, _, _ = magnetic_heading(imu.mag_ut, down, declination_rad)
    phi = complementary_heading_seed(yaw_rate(imu.gyro_rad_s, down), am, imu.rate_hz, tau_s)
    return step_heading(phi, steps)


@dataclass(frozen=True)
class SeedConfig:
    """Settings of :class:`RtkPdrEKF` (the paper's PDR noise by default; q per second of walk time)."""

    sigma_step_length_m: float = SEED_SIGMA_STEP_M
    sigma_heading_rad: float = SEED_SIGMA_HEADING_RAD
    q_walk_m2_s: float = 1e-3
    q_stand_m2_s: float = 1e-5
    sigma0_pos_m: float = 5.0
    sigma0_heading_rad: float = 0.3
    outlier: str = "none"
    gate_prob: float = 0.999
    huber_k: float = 2.5

    def __post_init__(self):
        for name in ("sigma_step_length_m", "sigma_heading_rad", "q_walk_m2_s", "q_stand_m2_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise FilterError(f"{name} must be finite and >= 0, got {v}")
        for name in ("sigma0_pos_m", "sigma0_heading_rad", "huber_k"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise FilterError(f"{name} must be finite and > 0, got {v}")
        if self.outlier not in OUTLIER_CODES:
            raise FilterError(f"outlier must be one of {tuple(OUTLIER_CODES)}, got {self.outlier!r}")
        if not 0 < self.gate_prob < 1:
            raise FilterError(f"gate_prob must lie in (0, 1), got {self.gate_prob}")


def seed_step(x: np.ndarray, P: np.ndarray, length_m: float, dphi_rad: float, sl2: float, sp2: float):
    """The paper's step (module docstring): returns (x⁻ (3,), P⁻ (3, 3), F (3, 3))."""
    phi = x[2] + dphi_rad
    s, c = math.sin(phi), math.cos(phi)
    xp = np.array([x[0] + length_m * s, x[1] + length_m * c, phi])
    F = np.array([[1.0, 0.0, length_m * c], [0.0, 1.0, -length_m * s], [0.0, 0.0, 1.0]])
    # P⁻ = F (P + diag(0, 0, σ_φ²)) F' + g g' σ_L²
    Pw = P.copy()
    Pw[2, 2] += sp2
    g = np.array([s, c, 0.0])
    Pp = F @ Pw @ F.T + np.outer(g, g) * sl2
    return xp, 0.5 * (Pp + Pp.T), F


class RtkPdrEKF:
    """The seed's EKF over an event stream whose steps carry the seed heading (see the module docstring).

    ``run(stream, r_event, step_fraction)``: ``r_event`` (m, 2, 2) R of every fix (NaN on steps),
    ``step_fraction`` (m,) the share of its step each (sub-)step event is (1 for whole steps).
    """

    def __init__(self, config: SeedConfig | None = None, method: str = "ekf_rtk_pdr"):
        self.config = config
        self.method = method

    def run(self, stream: EventStream, r_event: np.ndarray, step_fraction: np.ndarray | None = None,
            x0_en=None) -> FilterRun:
        cfg = self.config or SeedConfig()
        m = len(stream)
        r = np.asarray(r_event, float)
        if r.shape != (m, 2, 2):
            raise FilterError(f"r_event must have shape ({m}, 2, 2), got {r.shape}")
        frac = np.ones(m) if step_fraction is None else np.asarray(step_fraction, float)
        steps = np.flatnonzero(stream.kind == STEP)
        fixes = np.flatnonzero(stream.available & (stream.kind != STEP))
        if x0_en is None:
            if fixes.size == 0:
                raise FilterError("no initial position: the stream has no available fix")
            x0_en = stream.z_m[fixes[0]]
        psi0 = float(stream.heading_rad[steps[0]]) if steps.size else 0.0
        x = np.array([x0_en[0], x0_en[1], psi0], float)
        P = np.diag([cfg.sigma0_pos_m ** 2] * 2 + [cfg.sigma0_heading_rad ** 2])
        x0, P0 = x.copy(), P.copy()
        rec = empty_records(m, 3)
        H = np.zeros((2, 3))
        H[0, 0] = H[1, 1] = 1.0
        ones = np.ones(3)
        sl2, sp2 = cfg.sigma_step_length_m ** 2, cfg.sigma_heading_rad ** 2
        code, gate = OUTLIER_CODES[cfg.outlier], -2.0 * math.log1p(-cfg.gate_prob)
        psi_prev = psi0
        for k in range(m):
            dt, st = float(stream.dt_s[k]), float(stream.dt_stand_s[k])
            qp = cfg.q_walk_m2_s * (dt - st) + cfg.q_stand_m2_s * st
            time_update(x, P, ones, np.array([qp, qp, 0.0]))
            if stream.kind[k] == STEP:
                psi = float(stream.heading_rad[k])
                dphi = math.remainder(psi - psi_prev, 2 * math.pi)
                psi_prev = psi
                x, P, F = seed_step(x, P, float(stream.step_length_m[k]), dphi, sl2 * frac[k], sp2 * frac[k])
                rec["F"][k] = F
            rec["x_prior"][k], rec["P_prior"][k] = x, P
            if stream.kind[k] != STEP and stream.available[k] and np.all(np.isfinite(r[k])):
                xn, Pn, nu, S, K, Ru, nis, w, ok = kalman_update(x, P, stream.z_m[k], r[k], H, code, gate,
                                                                 cfg.huber_k, True)
                rec["nu"][k], rec["S"][k], rec["R"][k], rec["nis"][k], rec["weight"][k] = nu, S, Ru, nis, w
                rec["updated"][k], rec["accepted"][k] = True, ok
                if ok:
                    rec["K"][k] = K
                    x, P = xn, Pn
            rec["x"][k], rec["P"][k] = x, P
        return FilterRun(self.method, stream.t_s, stream.kind, x0, P0, available=stream.available, **rec)
