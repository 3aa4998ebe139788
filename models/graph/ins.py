"""The seed's SINS/GNSS form: IMU preintegration factors with GNSS and acoustic position factors.

Yang, Zhou, Li, Wu & Liu (2023), "Personnel Localization Method in Transformer Substation Based on Factor
Graph", J. Computer and Communications 11, 96–106: inertial and satellite measurements as factors, the
navigation states as variables, solved by Gauss–Newton. Here on gtsam's on-manifold preintegration
(Forster, Carlone, Dellaert & Scaramuzza 2017, IEEE T-RO 33(1)):

* variables per keyframe i: pose ``x<i>`` (``gtsam.Pose3``, body → site ENU, the body the device's
  forward-right-down axes), velocity ``v<i>`` (ENU, m/s), IMU bias ``b<i>`` (``imuBias.ConstantBias``);
* keyframes at every fix time (GNSS 5 Hz, acoustic frames: non-equidistant), with one at least every
  ``max_gap_s`` through outages;
* between keyframes an ``ImuFactor`` of the 100 Hz specific force and angular rate integrated
  (``PreintegratedImuMeasurements``, gravity −g along ENU up), and a bias random walk
  (``BetweenFactorConstantBias``);
* a fix z (east, north) with covariance R is a ``GPSFactor`` on the pose's position (z, h) with
  covariance diag(R, σ_h²) (h the device height: the walker stays on the ground) under the Huber kernel;
* priors on the first pose (position σ0, roll/pitch from the accelerometer's gravity, yaw from the PDR
  heading of the body's forward axis), velocity and bias (consumer MEMS turn-on bias).

Noise: a consumer MEMS IMU (datasheet densities of the BMI160 class, 180 µg/√Hz and 0.007 °/s/√Hz),
inflated for the waist's vibration; all in :class:`InsConfig`. Initial values: the positions of a
PDR-based graph solution, velocities from their differences, attitudes from gravity and the PDR heading —
a starting point only; the solution is the INS graph's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from features.constants import GRAVITY_M_S2
from features.imu.heading import down_in_body
from models.fusion.events import EventStream
from models.graph.build import FixNoise
from models.graph.config import GraphError
from models.graph.robust import noise_model
from models.graph.solve import GraphRun

__all__ = ["InsConfig", "solve_ins", "keyframe_times", "attitude_from_down_heading"]


@dataclass(frozen=True)
class InsConfig:
    """IMU noise (continuous-time densities), bias random walks, priors, keyframe spacing, kernels."""

    accel_noise_m_s2_sqrt_hz: float = 0.02
    gyro_noise_rad_s_sqrt_hz: float = 0.002
    accel_bias_rw_m_s3_sqrt_hz: float = 1e-3
    gyro_bias_rw_rad_s2_sqrt_hz: float = 1e-4
    sigma0_accel_bias_m_s2: float = 0.1
    sigma0_gyro_bias_rad_s: float = 0.05
    sigma0_pos_m: float = 5.0
    sigma0_tilt_rad: float = 0.05
    sigma0_yaw_rad: float = 0.3
    sigma0_vel_m_s: float = 1.0
    sigma_height_m: float = 0.3
    max_gap_s: float = 1.0
    gnss_width: float = 2.5
    acoustic_width: float = 2.5
    lm_max_iterations: int = 50

    def __post_init__(self):
        for name, v in self.__dict__.items():
            if name == "lm_max_iterations":
                if not (isinstance(v, int) and v >= 1):
                    raise GraphError(f"{name} must be an integer >= 1, got {v!r}")
            elif not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise GraphError(f"{name} must be finite and > 0, got {v!r}")


def keyframe_times(fix_t_s: np.ndarray, t_start: float, t_end: float, max_gap_s: float) -> np.ndarray:
    """Fix times inside [t_start, t_end], gaps longer than ``max_gap_s`` filled evenly, sorted and unique.

    >>> keyframe_times(np.array([0.0, 0.2, 3.0]), 0.0, 3.0, 1.0).tolist()
    [0.0, 0.2, 1.133333, 2.066667, 3.0]
    """
    t = np.unique(np.asarray(fix_t_s, float))
    t = t[(t >= t_start) & (t <= t_end)]
    if t.size == 0:
        return t
    out = [t[:1]]
    for a, b in zip(t[:-1], t[1:]):
        n = int(math.ceil((b - a) / max_gap_s))
        out.append(a + (b - a) * np.arange(1, n + 1) / n)
    return np.round(np.concatenate(out), 6)


def attitude_from_down_heading(down_b: np.ndarray, heading_rad: float) -> np.ndarray:
    """R_nb (3, 3), body → ENU, from the unit down vector in the body frame and the heading of the body's
    forward axis (from north, clockwise): rows are east, north, up in body coordinates (see module)."""
    up = -np.asarray(down_b, float)
    up /= np.linalg.norm(up)
    h = np.array([1.0, 0.0, 0.0]) - up[0] * up
    h /= max(np.linalg.norm(h), 1e-9)
    w = np.cross(up, h)
    s, c = math.sin(heading_rad), math.cos(heading_rad)
    east = s * h - c * w
    north = c * h + s * w
    return np.vstack([east, north, up])


def _preintegrate(pim_params, imu, t_a: float, t_b: float, bias):
    import gtsam

    pim = gtsam.PreintegratedImuMeasurements(pim_params, bias)
    t = imu.t_s
    dt_s = 1.0 / imu.rate_hz
    i0 = max(int(np.searchsorted(t, t_a, side="right")) - 1, 0)
    i1 = int(np.searchsorted(t, t_b, side="left"))
    for i in range(i0, max(i1, i0 + 1)):
        lo, hi = max(t[i], t_a), min(t[i] + dt_s, t_b)
        if hi > lo:
            pim.integrateMeasurement(imu.acc_m_s2[i], imu.gyro_rad_s[i], hi - lo)
    return pim


def _ins_graph(imu, stream: EventStream, noise: FixNoise, start_track: tuple, step_t_s, step_heading_rad,
               cfg: InsConfig, height_m: float):
    """The INS graph and its initial values (module docstring): (graph, values, keyframe times (n,))."""
    import gtsam
    from gtsam.symbol_shorthand import B, V
    from gtsam.symbol_shorthand import X as XP

    fixes = np.flatnonzero(noise.use)
    kt = keyframe_times(stream.t_s[fixes], float(imu.t_s[0]), float(imu.t_s[-1]), cfg.max_gap_s)
    if kt.size < 2:
        raise GraphError("fewer than two fixes inside the IMU record")
    st, se, sn = (np.asarray(a, float) for a in start_track)
    pe, pn = np.interp(kt, st, se), np.interp(kt, st, sn)
    ok = np.isfinite(step_heading_rad)
    z = np.exp(1j * np.asarray(step_heading_rad, float)[ok])
    yaw = np.angle(np.interp(kt, step_t_s[ok], z.real) + 1j * np.interp(kt, step_t_s[ok], z.imag))
    down = down_in_body(imu.acc_m_s2, imu.rate_hz)
    di = np.clip(np.searchsorted(imu.t_s, kt), 0, len(imu.t_s) - 1)
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY_M_S2)
    params.setAccelerometerCovariance(np.eye(3) * cfg.accel_noise_m_s2_sqrt_hz ** 2)
    params.setGyroscopeCovariance(np.eye(3) * cfg.gyro_noise_rad_s_sqrt_hz ** 2)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    bias0 = gtsam.imuBias.ConstantBias()
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    vel = np.zeros((kt.size, 3))
    vel[1:-1, 0] = (pe[2:] - pe[:-2]) / (kt[2:] - kt[:-2])
    vel[1:-1, 1] = (pn[2:] - pn[:-2]) / (kt[2:] - kt[:-2])
    for i in range(kt.size):
        R = gtsam.Rot3(attitude_from_down_heading(down[di[i]], float(yaw[i])))
        v.insert(XP(i), gtsam.Pose3(R, np.array([pe[i], pn[i], height_m])))
        v.insert(V(i), vel[i])
        v.insert(B(i), bias0)
    g.add(gtsam.PriorFactorPose3(XP(0), v.atPose3(XP(0)), gtsam.noiseModel.Diagonal.Sigmas(np.array(
        [cfg.sigma0_tilt_rad, cfg.sigma0_tilt_rad, cfg.sigma0_yaw_rad] + [cfg.sigma0_pos_m] * 3))))
    g.add(gtsam.PriorFactorVector(V(0), vel[0], gtsam.noiseModel.Isotropic.Sigma(3, cfg.sigma0_vel_m_s)))
    g.add(gtsam.PriorFactorConstantBias(B(0), bias0, gtsam.noiseModel.Diagonal.Sigmas(np.array(
        [cfg.sigma0_accel_bias_m_s2] * 3 + [cfg.sigma0_gyro_bias_rad_s] * 3))))
    rw = np.array([cfg.accel_bias_rw_m_s3_sqrt_hz] * 3 + [cfg.gyro_bias_rw_rad_s2_sqrt_hz] * 3)
    for i in range(1, kt.size):
        g.add(gtsam.ImuFactor(XP(i - 1), V(i - 1), XP(i), V(i), B(i - 1),
                              _preintegrate(params, imu, kt[i - 1], kt[i], bias0)))
        # bias random walk: b_i − b_{i−1} ~ N(0, q·Δt)
        g.add(gtsam.BetweenFactorConstantBias(B(i - 1), B(i), bias0, gtsam.noiseModel.Diagonal.Sigmas(
            np.sqrt(kt[i] - kt[i - 1]) * rw)))
    node = np.searchsorted(kt, np.round(stream.t_s[fixes], 6))
    for k, i in zip(fixes, node):
        if i >= kt.size or abs(kt[i] - stream.t_s[k]) > 1e-5:
            continue
        cov = np.zeros((3, 3))
        cov[:2, :2] = noise.cov_m2[k]
        cov[2, 2] = cfg.sigma_height_m ** 2
        width = cfg.gnss_width if stream.kind[k] == 1 else cfg.acoustic_width
        z3 = np.array([stream.z_m[k, 0], stream.z_m[k, 1], height_m])
        g.add(gtsam.GPSFactor(XP(int(i)), z3, noise_model(cov, "huber", width)))
    return g, v, kt


def solve_ins(imu, stream: EventStream, noise: FixNoise, start_track: tuple, step_t_s: np.ndarray,
              step_heading_rad: np.ndarray, cfg: InsConfig = InsConfig(), method: str = "fg_ins",
              height_m: float = 0.0) -> GraphRun:
    """Batch Levenberg–Marquardt of the INS graph (module docstring). ``imu``: ImuData with gyro;
    ``start_track``: (t_s, east_m, north_m) initial positions; ``step_*``: PDR step times and headings
    (initial yaw). Returns one row per keyframe (its marginal covariance included)."""
    import gtsam
    from gtsam.symbol_shorthand import B
    from gtsam.symbol_shorthand import X as XP

    t0 = time.perf_counter()
    if imu.gyro_rad_s is None:
        raise GraphError("IMU preintegration needs the gyro")
    g, v, kt = _ins_graph(imu, stream, noise, start_track, np.asarray(step_t_s, float),
                          np.asarray(step_heading_rad, float), cfg, height_m)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(cfg.lm_max_iterations)
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, lm)
    res = opt.optimize()
    poses = [res.atPose3(XP(i)) for i in range(kt.size)]
    pos = np.array([p.translation() for p in poses])
    covs = np.full((kt.size, 2, 2), np.nan)
    try:
        marg = gtsam.Marginals(g, res)
        for i, p in enumerate(poses):
            Rm = p.rotation().matrix()
            # the pose's tangent covariance is [rotation, translation in the body frame]: rotate to ENU
            covs[i] = (Rm @ marg.marginalCovariance(XP(i))[3:, 3:] @ Rm.T)[:2, :2]
    except RuntimeError:
        pass
    bias_end = res.atConstantBias(B(kt.size - 1))
    info = {"seconds": time.perf_counter() - t0, "keyframes": int(kt.size), "iterations": opt.iterations(),
            "error": g.error(res), "accel_bias_end": bias_end.accelerometer().tolist(),
            "gyro_bias_end": bias_end.gyroscope().tolist()}
    return GraphRun(method, kt, np.full(kt.size, 1, np.int8), pos[:, 0], pos[:, 1], covs, info)
