"""Foot-mounted INS with zero-velocity updates, fused with UWB positions and magnetic heading by a federated
Kalman filter.

The error-state (indirect, complementary) Kalman filter of a ZUPT-aided foot INS (Foxlin 2005, "Pedestrian
tracking with shoe-mounted inertial sensors", IEEE CG&A 25(6); in the OpenShoe formulation of Nilsson,
Skog, Händel & Hari 2012, IEEE/ION PLANS, §III) with the gyro and accelerometer biases added to the state:

    δx = [δp (3), δv (3), φ (3), δb_g (3), δb_a (3)]    (ENU position, velocity, attitude error, gyro and
    accelerometer bias errors)

true = nominal + error for p, v, b_g, b_a; C_true = (I − [φ×]) Ĉ for the attitude. Per sample of interval Δt
(Groves 2013, *Principles of GNSS, Inertial and Multisensor Integrated Navigation Systems*, 2nd ed.,
§14.2.4, first-order Φ = I + F Δt):

    δṗ = δv,   δv̇ = [f_n×] φ − Ĉ (δb_a + n_a),   φ̇ = Ĉ (δb_g + n_g),   δḃ_g = n_bg,   δḃ_a = n_ba

with Q = diag(0, N_a² Δt I, N_g² Δt I, N_bg² Δt I, N_ba² Δt I) (N the noise densities; Ĉ Ĉᵀ = I keeps Q
diagonal). The accelerometer bias is the 15-state extension of OpenShoe's 9 states (its vertical part is
observable in every stance, the rest as the foot rotates; a recording's scale error of a few per mille of g —
the x-io NGIMU reads 0.993 g at rest on the long walk — otherwise lifts the track by centimetres a stride).

Local filters of the federated filter (:mod:`models.foot.federated`, Carlson 1990), one per sensor:

0. **ZUPT-INS**: in stance (:func:`models.foot.stance.detect_stance`) the foot is still, so the velocity is
   zero: z = −v̂, H = [0 I 0 0 0], R = σ_v² I (OpenShoe σ_v = 0.01 m/s); optionally (``zaru_sigma_rad_s``)
   the gyro reads only its bias too (zero angular-rate update, ZARU): z = ω_b − b̂_g − Ĉᵀω_ie,
   H = [0 0 0 I 0] — off by default: a detected stance holds the foot's roll onto the toes at its edges,
   and on the x-io walks at γ = 10⁵ a ZARU of σ = 1–3 °/s made the loop-closure error worse (short walk
   667–1111 mm against 538 mm without, long walk 1067–2289 mm against 518 mm);
1. **UWB position**: a multilaterated fix (east, north) with covariance R, z = p_uwb − p̂_EN, H = [I₂ 0];
   a fix whose NIS exceeds the χ²₂ gate is rejected — :func:`models.fusion.core.kalman_update` (the shared
   core's 2-D update with its χ² gate) is this filter's update. A gate can lock the filter out: after a long
   stop the INS may leave on a wrong heading with a small P, and every later fix is then rejected (on the
   held-out study walks 7 of 15 tracks ended 4–20 m off). So after ``uwb_relock_n`` rejected fixes in a row
   the filter re-acquires: the position variance grows by the innovation's square and the yaw variance by
   ``relock_yaw_sigma_rad``², and the fix is tried again (a stated heuristic of track maintenance: a run of
   consecutive gate failures says the track, not the measurements, is lost; Bar-Shalom, Li & Kirubarajan
   2001, *Estimation with Applications to Tracking and Navigation*, §11.7 on track loss);
2. **magnetic heading** (in stance, when the field's magnitude and dip agree with the walk's undisturbed
   field within tolerances): the azimuth α̂ of the field Ĉ m_b against the declination D,
   z = wrap(D − α̂), H from ∂α/∂φ with ∂m_n = [m̂_n×] φ (exact to first order, tilt coupling included).

The core's ``kalman_update`` is written for 2-D measurements (its S⁻¹ is the closed 2×2 adjugate), so the
3-D ZUPT (6-D with the ZARU) and the scalar heading use :func:`joseph_update` here: the same Joseph-form algebra for any
measurement size. The master fuses and resets after every sample on which a local filter updated (with
``fusion_period_s`` > 0: at most once per period), feeds the fused error back into the nominal INS
(closed loop) and shares it out by the factors β. One local filter alone (β = 1) is the plain ZUPT-aided INS.

The per-sample loop is compiled with numba (≈ 60 000 samples per 10-minute walk at 100 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from features.constants import OMEGA_EARTH_RAD_S
from models.foot.federated import SharingFactors, fuse_information, share_information
from models.foot.mechanisation import GRAVITY_ENU_M_S2, dcm_to_quat, level_attitude, quat_to_dcm, skew, strapdown_step
from models.foot.stance import StanceConfig, count_strides, detect_stance, stance_segments
from models.fusion.core import GATE, kalman_update

__all__ = ["FootInsConfig", "FootInsRun", "UwbFixes", "run_foot_ins", "joseph_update", "N_STATES",
           "heading_jacobian", "CHI2_2_GATE"]

N_STATES = 15
"""Error states: δp (3), δv (3), φ (3), δb_g (3), δb_a (3)."""

CHI2_2_GATE = 13.82
"""χ²₂ 0.999 quantile: a UWB fix whose NIS exceeds it is rejected (one in a thousand good fixes lost)."""


@dataclass(frozen=True)
class FootInsConfig:
    """Settings of the foot INS and its filters.

    Noise densities (process noise of the error model; OpenShoe's per-sample σ_a = 0.5 m/s², σ_g = 0.5 °/s
    at 820 Hz, i.e. N = σ/√820 — deliberately above the sensor's own densities, to cover the foot's
    vibration and model errors): ``acc_psd`` in m/s²/√Hz, ``gyro_psd`` in rad/s/√Hz, ``gyro_bias_psd``
    in rad/s/√s. Measurement σ's: ``zupt_sigma_m_s`` (OpenShoe 0.01 m/s), ``zaru_sigma_rad_s`` (the foot
    still rolls a little in stance), ``heading_sigma_rad``. Initial σ's: tilt, yaw, gyro bias, position.
    The stance threshold γ = 10⁵ (OpenShoe's σ's and window): on the x-io NGIMU (400 Hz) it counts every
    stride counted by hand where OpenShoe's 3·10⁴ misses two of 37; on the simulated Ellipse2-A class IMU
    (100 Hz) it misses no stance sample. Heading update gates: field magnitude within ``mag_tolerance`` (relative) and dip within
    ``dip_tolerance_rad`` of the walk's median stance field.
    """

    stance: StanceConfig = field(default_factory=lambda: StanceConfig(gamma=1e5))
    acc_psd: float = 0.5 / math.sqrt(820.0)
    gyro_psd: float = math.radians(0.5) / math.sqrt(820.0)
    gyro_bias_psd: float = math.radians(8.0 / 3600.0) / math.sqrt(100.0)
    acc_bias_psd: float = 14e-6 * 9.80665 / math.sqrt(100.0)
    zupt_sigma_m_s: float = 0.01
    zaru_sigma_rad_s: float | None = None
    heading_sigma_rad: float = math.radians(5.0)
    init_tilt_sigma_rad: float = math.radians(1.0)
    init_yaw_sigma_rad: float = math.radians(10.0)
    init_gyro_bias_sigma_rad_s: float = math.radians(0.2)
    init_acc_bias_sigma_m_s2: float = 0.1
    init_pos_sigma_m: float = 1.0
    init_still_s: float = 0.5
    mag_tolerance: float = 0.1
    dip_tolerance_rad: float = math.radians(5.0)
    uwb_gate_nis: float = CHI2_2_GATE
    uwb_relock_n: int = 10
    relock_yaw_sigma_rad: float = math.radians(30.0)
    fusion_period_s: float = 0.0
    sharing: SharingFactors = field(default_factory=SharingFactors)

    def __post_init__(self):
        for name in ("acc_psd", "gyro_psd", "gyro_bias_psd", "acc_bias_psd", "init_acc_bias_sigma_m_s2",
                     "zupt_sigma_m_s",
                 "heading_sigma_rad",
                     "init_tilt_sigma_rad", "init_yaw_sigma_rad", "init_gyro_bias_sigma_rad_s", "init_pos_sigma_m",
                     "init_still_s", "mag_tolerance", "dip_tolerance_rad", "uwb_gate_nis", "relock_yaw_sigma_rad"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"FootInsConfig.{name} must be a positive number, got {v}")
        if not (isinstance(self.uwb_relock_n, (int, np.integer)) and self.uwb_relock_n >= 0):
            raise ValueError(f"FootInsConfig.uwb_relock_n must be an integer >= 0 (0: never), got {self.uwb_relock_n}")
        if not (np.isfinite(self.fusion_period_s) and self.fusion_period_s >= 0):
            raise ValueError(f"FootInsConfig.fusion_period_s must be >= 0, got {self.fusion_period_s}")
        if self.zaru_sigma_rad_s is not None and not (np.isfinite(self.zaru_sigma_rad_s) and self.zaru_sigma_rad_s > 0):
            raise ValueError(f"FootInsConfig.zaru_sigma_rad_s must be a positive number or None, got "
                             f"{self.zaru_sigma_rad_s}")


@dataclass(frozen=True)
class UwbFixes:
    """UWB position fixes for the UWB local filter: ``t_s`` (m,), ``en_m`` (m, 2) east/north in the INS's
    local frame, ``cov_m2`` (m, 2, 2)."""

    t_s: np.ndarray
    en_m: np.ndarray
    cov_m2: np.ndarray

    def __post_init__(self):
        m = len(self.t_s)
        if np.shape(self.en_m) != (m, 2) or np.shape(self.cov_m2) != (m, 2, 2):
            raise ValueError(f"UwbFixes: en_m must be ({m}, 2) and cov_m2 ({m}, 2, 2), got {np.shape(self.en_m)} "
                             f"and {np.shape(self.cov_m2)}")


@dataclass(frozen=True)
class FootInsRun:
    """A foot INS run. Arrays per IMU sample (n,): ``t_s``; ``pos_m`` (n, 3) ENU; ``vel_m_s`` (n, 3);
    ``quat`` (n, 4); ``P_pos_m2`` (n, 2, 2) the fused east/north covariance; ``stance`` (n,) bool;
    ``heading_used`` (n,) bool. Per UWB fix: ``uwb_nis``, ``uwb_accepted``. ``strides`` the swings counted;
    ``sharing`` the β used (3,); ``active`` which local filters ran (ZUPT, UWB, heading)."""

    t_s: np.ndarray
    pos_m: np.ndarray
    vel_m_s: np.ndarray
    quat: np.ndarray
    P_pos_m2: np.ndarray
    stance: np.ndarray
    heading_used: np.ndarray
    uwb_nis: np.ndarray
    uwb_accepted: np.ndarray
    strides: int
    sharing: np.ndarray
    active: np.ndarray
    gyro_bias_rad_s: np.ndarray


@njit(cache=True)
def joseph_update(x, P, nu, H, R):
    """Kalman update of (x (n,), P (n, n)) by the innovation ν (m,) with H (m, n), R (m, m); Joseph form
    (Bucy & Joseph 1968). Returns (x, P, NIS)."""
    PHt = P @ H.T
    # S = H P H' + R
    S = H @ PHt + R
    Si = np.linalg.inv(S)
    # K = P H' S⁻¹
    K = PHt @ Si
    # x = x + K ν
    xn = x + K @ nu
    # P = (I − KH) P (I − KH)' + K R K'
    IKH = np.eye(x.shape[0]) - K @ H
    Pn = IKH @ P @ IKH.T + K @ R @ K.T
    return xn, 0.5 * (Pn + Pn.T), float(nu @ Si @ nu)


@njit(cache=True)
def heading_jacobian(m_n):
    """∂α/∂φ (3,) of the field's azimuth α = atan2(m_e, m_n) (from north, clockwise) under the attitude error φ:
    ∂m = [m̂×] φ, ∂α = (m_N ∂m_E − m_E ∂m_N) / (m_E² + m_N²)  (ENU: index 0 east, 1 north)."""
    S = skew(m_n)
    h2 = m_n[0] ** 2 + m_n[1] ** 2
    return (m_n[1] * S[0] - m_n[0] * S[1]) / h2


@njit(cache=True)
def _wrap(a):
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _error_model(f_n, C, dt, qd):
    """Φ = I + F Δt of the error state (module docstring) and Q_Δt = diag(qd) as a matrix."""
    Phi = np.eye(N_STATES)
    for i in range(3):
        # δp += δv Δt
        Phi[i, 3 + i] = dt
    # δv += [f_n×] φ Δt
    Phi[3:6, 6:9] += skew(f_n) * dt
    # φ += Ĉ δb_g Δt
    Phi[6:9, 9:12] += C * dt
    # δv −= Ĉ δb_a Δt
    Phi[3:6, 12:15] -= C * dt
    return Phi, np.diag(qd)


@njit(cache=True)
def _run(dt, acc, gyro, mag, stance, head_ok, uwb_at, uwb_z, uwb_R, q0, p0, bg0, P0, qd, r_zupt, r_zaru,
         r_head, decl_rad, g_n, w_ie_n, beta, active, gate, fusion_period_s,
         pos, vel, quat, Ppos, head_used, uwb_nis, uwb_ok, bias_out, ba0, relock_n, relock_yaw_var):
    n = acc.shape[0]
    ns = N_STATES
    q = q0.copy()
    v = np.zeros(3)
    p = p0.copy()
    bg = bg0.copy()
    ba = ba0.copy()
    X = np.zeros((3, ns))
    Ps = np.empty((3, ns, ns))
    for i in range(3):
        Ps[i] = P0 / beta[i]
    nz = 6 if r_zaru > 0 else 3
    Hz = np.zeros((nz, ns))
    Rz = np.zeros((nz, nz))
    for i in range(3):
        Hz[i, 3 + i] = 1.0
        Rz[i, i] = r_zupt
        if nz == 6:
            Hz[3 + i, 9 + i] = 1.0
            Rz[3 + i, 3 + i] = r_zaru
    Hu = np.zeros((2, ns))
    Hu[0, 0] = 1.0
    Hu[1, 1] = 1.0
    Rh = np.array([[r_head]])
    pending = False
    t_since = 0.0
    miss = 0
    i0 = 0
    while not active[i0]:
        i0 += 1
    for k in range(n):
        # the nominal INS: strapdown with the gyro bias removed
        q, v, p, f_n = strapdown_step(q, v, p, acc[k] - ba, gyro[k] - bg, dt[k], g_n, w_ie_n)
        C = quat_to_dcm(q)
        Phi, Q = _error_model(f_n, C, dt[k], qd * dt[k])
        if not pending:
            # every local filter holds the fused state (xᵢ = 0 after feedback, Pᵢ = P_g/βᵢ), so
            # Φ (P_g/βᵢ) Φ' + Q/βᵢ = (Φ P_g Φ' + Q)/βᵢ: one propagation serves all of them
            Pg = Phi @ (Ps[i0] * beta[i0]) @ Phi.T + Q
            for i in range(3):
                if active[i]:
                    Ps[i] = Pg / beta[i]
        else:
            for i in range(3):
                if active[i]:
                    # xᵢ = Φ xᵢ;  Pᵢ = Φ Pᵢ Φ' + Q/βᵢ   (Carlson: each local filter carries Q/βᵢ)
                    X[i] = Phi @ X[i]
                    Ps[i] = Phi @ Ps[i] @ Phi.T + Q / beta[i]
        t_since += dt[k]
        if stance[k] and active[0]:
            # ZUPT (+ ZARU): ν = z − H xᵢ with z = −v̂ (; ω − b̂_g − Ĉᵀω_ie)
            z = np.empty(nz)
            z[:3] = -v
            if nz == 6:
                z[3:] = gyro[k] - bg - C.T @ w_ie_n
            X[0], Ps[0], _ = joseph_update(X[0], Ps[0], z - Hz @ X[0], Hz, Rz)
            pending = True
        j = uwb_at[k]
        if j >= 0 and active[1]:
            # UWB: z = p_uwb − p̂_EN, the core's 2-D update with its χ² gate
            zu = uwb_z[j] - p[:2]
            xn, Pn, _, _, _, _, nis, _, ok = kalman_update(X[1], Ps[1], zu, uwb_R[j], Hu, GATE, gate, 1.0, True)
            miss = 0 if ok else miss + 1
            if relock_n > 0 and miss >= relock_n:
                # re-acquisition: relock_n fixes in a row outside the gate — the INS, not every fix, is lost.
                # Every local filter's position variance grows by the innovation's square and its yaw variance
                # by relock_yaw_var (ΔP/βᵢ each, so the fused P_g grows by ΔP), and the fix is tried again
                d2 = zu[0] * zu[0] + zu[1] * zu[1]
                for i in range(3):
                    if active[i]:
                        Ps[i][0, 0] += d2 / beta[i]
                        Ps[i][1, 1] += d2 / beta[i]
                        Ps[i][8, 8] += relock_yaw_var / beta[i]
                xn, Pn, _, _, _, _, nis, _, ok = kalman_update(X[1], Ps[1], zu, uwb_R[j], Hu, GATE, gate, 1.0, True)
                miss = 0
            uwb_nis[j] = nis
            uwb_ok[j] = ok
            if ok:
                X[1] = xn
                Ps[1] = Pn
                pending = True
        if head_ok[k] and active[2]:
            m_n = C @ mag[k]
            # z = D − α̂,  H = ∂α/∂φ
            Hh = np.zeros((1, ns))
            Hh[0, 6:9] = heading_jacobian(m_n)
            zh = _wrap(decl_rad - math.atan2(m_n[0], m_n[1]))
            nu = np.array([_wrap(zh - (Hh @ X[2])[0])])
            X[2], Ps[2], _ = joseph_update(X[2], Ps[2], nu, Hh, Rh)
            head_used[k] = True
            pending = True
        if pending and t_since >= fusion_period_s:
            # master: P_g⁻¹ = Σ Pᵢ⁻¹, x_g = P_g Σ Pᵢ⁻¹ xᵢ;  closed loop: the fused error into the nominal INS
            xg, Pg = fuse_information(X, Ps, active)
            p += xg[:3]
            v += xg[3:6]
            # C = (I − [φ×]) Ĉ, re-orthonormalised through the quaternion
            Cn = (np.eye(3) - skew(xg[6:9])) @ C
            u, _, vt = np.linalg.svd(Cn)
            q = dcm_to_quat(u @ vt)
            bg += xg[9:12]
            ba += xg[12:15]
            # reset: xᵢ = 0 (fed back), Pᵢ = P_g/βᵢ
            share_information(np.zeros(ns), Pg, beta, active, X, Ps)
            pending = False
            t_since = 0.0
        dp = np.zeros(3)
        if pending:
            # between fusions the output is the information sum of the local filters (not yet fed back)
            xg, Pg_k = fuse_information(X, Ps, active)
            dp = xg[:3]
        else:
            for i in range(3):
                if active[i]:
                    Pg_k = Ps[i] * beta[i]
                    break
        pos[k] = p + dp
        vel[k] = v
        quat[k] = q
        Ppos[k] = Pg_k[:2, :2]
        bias_out[k] = bg




def _still_spell(stance: np.ndarray, rate_hz: float, min_s: float) -> slice:
    """The first stance spell of at least ``min_s`` within the record's first 10 s, else its first ``min_s``."""
    for a, b in stance_segments(stance):
        if a > 10.0 * rate_hz:
            break
        if b - a >= min_s * rate_hz:
            return slice(int(a), int(b))
    return slice(0, max(int(round(min_s * rate_hz)), 1))


def _heading_gate(acc: np.ndarray, mag: np.ndarray, stance: np.ndarray, cfg: FootInsConfig) -> np.ndarray:
    """The middle sample of every stance spell whose field agrees with the walk's undisturbed field: |‖m‖ − B| ≤ tol·B and
    |dip − dip_ref| ≤ dip_tol, B and dip_ref the medians over stance. The dip needs no attitude: in stance the
    specific force points up, so dip = asin(−m·f / (‖m‖‖f‖)) (ENU up against a field pointing down-north)."""
    norm_m = np.linalg.norm(mag, axis=1)
    dip = np.arcsin(np.clip(-np.sum(mag * acc, axis=1) / (norm_m * np.linalg.norm(acc, axis=1) + 1e-12), -1, 1))
    if not stance.any():
        return np.zeros(len(stance), bool)
    b_ref = float(np.median(norm_m[stance]))
    dip_ref = float(np.median(dip[stance]))
    ok = stance & (np.abs(norm_m - b_ref) <= cfg.mag_tolerance * b_ref) & (np.abs(dip - dip_ref)
                                                                            <= cfg.dip_tolerance_rad)
    # one update per stance spell, at its middle: the field's errors (hard iron, a nearby steel body) are the
    # same for every sample of a stance, so more updates would only repeat one error as if it were independent
    mid = np.zeros(len(stance), bool)
    for a, b in stance_segments(stance):
        mid[(a + b) // 2] = True
    return ok & mid


def run_foot_ins(t_s: np.ndarray, acc_m_s2: np.ndarray, gyro_rad_s: np.ndarray, mag_ut: np.ndarray | None = None,
                 cfg: FootInsConfig = FootInsConfig(), *, start_en_m=(0.0, 0.0), yaw_rad: float | None = None,
                 declination_rad: float = 0.0, latitude_deg: float | None = None, uwb: UwbFixes | None = None,
                 use_heading: bool = True) -> FootInsRun:
    """Run the foot INS with its federated filter on one record.

    ``t_s`` (n,), ``acc_m_s2``, ``gyro_rad_s``, ``mag_ut`` (n, 3): the foot IMU's samples (body frame). The
    record must start with the foot still (the first stance spell levels the INS and gives the gyro's turn-on
    bias). The initial heading: ``yaw_rad`` (of the body's x axis, from north clockwise) when given, else the
    tilt-compensated magnetic heading of the still spell plus ``declination_rad`` when there is a
    magnetometer, else 0. ``latitude_deg`` gives the Earth rate (None: left out). Local filters: ZUPT-INS
    always; UWB when ``uwb`` has fixes; heading when ``use_heading`` and there is a magnetometer.
    """
    t = np.asarray(t_s, float)
    acc = np.ascontiguousarray(acc_m_s2, float)
    gyro = np.ascontiguousarray(gyro_rad_s, float)
    n = len(t)
    if n < 10 or acc.shape != (n, 3) or gyro.shape != (n, 3):
        raise ValueError(f"run_foot_ins needs >= 10 samples of (n, 3) acc and gyro, got {acc.shape}, {gyro.shape}")
    dt = np.diff(t)
    if not np.all(dt > 0):
        raise ValueError("run_foot_ins needs strictly increasing sample times")
    rate = 1.0 / float(np.median(dt))
    dt = np.r_[np.median(dt), dt]
    stance = detect_stance(acc, gyro, cfg.stance)
    spell = _still_spell(stance, rate, cfg.init_still_s)
    f0 = acc[spell].mean(axis=0)
    lat = None if latitude_deg is None else math.radians(latitude_deg)
    w_ie_n = np.zeros(3) if lat is None else OMEGA_EARTH_RAD_S * np.array([0.0, math.cos(lat), math.sin(lat)])
    has_mag = mag_ut is not None and use_heading
    mag = np.ascontiguousarray(mag_ut, float) if mag_ut is not None else np.zeros((n, 3))
    if yaw_rad is None:
        yaw_rad = 0.0
        if mag_ut is not None:
            C0 = quat_to_dcm(level_attitude(f0, 0.0))
            m0 = C0 @ mag[spell].mean(axis=0)
            yaw_rad = declination_rad - math.atan2(m0[0], m0[1])
    q0 = level_attitude(f0, yaw_rad)
    bg0 = gyro[spell].mean(axis=0) - quat_to_dcm(q0).T @ w_ie_n
    head_ok = _heading_gate(acc, mag, stance, cfg) if has_mag else np.zeros(n, bool)
    m_fix = 0 if uwb is None else len(uwb.t_s)
    uwb_at = np.full(n, -1, np.int64)
    if m_fix:
        idx = np.searchsorted(t, np.asarray(uwb.t_s, float), side="left")
        inside = idx < n
        uwb_at[idx[inside]] = np.flatnonzero(inside)   # a later fix on the same sample wins
    active = np.array([True, m_fix > 0, has_mag])
    beta = cfg.sharing.normalised(active)
    P0 = np.diag(np.r_[[cfg.init_pos_sigma_m ** 2] * 2, 1e-4, [1e-4] * 3, [cfg.init_tilt_sigma_rad ** 2] * 2,
                       cfg.init_yaw_sigma_rad ** 2, [cfg.init_gyro_bias_sigma_rad_s ** 2] * 3,
                       [cfg.init_acc_bias_sigma_m_s2 ** 2] * 3])
    qd = np.r_[np.zeros(3), [cfg.acc_psd ** 2] * 3, [cfg.gyro_psd ** 2] * 3, [cfg.gyro_bias_psd ** 2] * 3,
               [cfg.acc_bias_psd ** 2] * 3]
    pos, vel = np.empty((n, 3)), np.empty((n, 3))
    quat, Ppos, bias = np.empty((n, 4)), np.empty((n, 2, 2)), np.empty((n, 3))
    head_used = np.zeros(n, bool)
    uwb_nis, uwb_ok = np.full(m_fix, np.nan), np.zeros(m_fix, bool)
    uz = np.ascontiguousarray(uwb.en_m, float) if m_fix else np.zeros((1, 2))
    uR = np.ascontiguousarray(uwb.cov_m2, float) if m_fix else np.zeros((1, 2, 2))
    p0 = np.array([float(start_en_m[0]), float(start_en_m[1]), 0.0])
    r_zaru = 0.0 if cfg.zaru_sigma_rad_s is None else cfg.zaru_sigma_rad_s ** 2
    _run(dt, acc, gyro, mag, stance, head_ok, uwb_at, uz, uR, q0, p0, bg0, P0, qd, cfg.zupt_sigma_m_s ** 2, r_zaru,
         cfg.heading_sigma_rad ** 2, float(declination_rad), GRAVITY_ENU_M_S2, w_ie_n,
         beta, active, cfg.uwb_gate_nis, cfg.fusion_period_s, pos, vel, quat, Ppos, head_used, uwb_nis, uwb_ok, bias,
         np.zeros(3), int(cfg.uwb_relock_n), cfg.relock_yaw_sigma_rad ** 2)
    return FootInsRun(t_s=t, pos_m=pos, vel_m_s=vel, quat=quat, P_pos_m2=Ppos, stance=stance, heading_used=head_used,
                      uwb_nis=uwb_nis, uwb_accepted=uwb_ok, strides=count_strides(stance, rate, cfg.stance),
                      sharing=beta, active=active, gyro_bias_rad_s=bias)
