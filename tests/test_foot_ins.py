"""Foot-mounted INS (models/foot): mechanisation against hand-worked cases, the SHOE/GLRT statistic against its
formula on hand-computed windows, ZUPT bounding velocity, and the federated fusion against the information-form
combination worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from models.foot.federated import SharingFactors, fuse_information, share_information
from models.foot.ins import FootInsConfig, heading_jacobian, joseph_update, run_foot_ins, UwbFixes
from models.foot.mechanisation import (GRAVITY_ENU_M_S2, level_attitude, quat_to_dcm, strapdown_step, yaw_of)
from models.foot.stance import StanceConfig, count_strides, detect_stance, glrt_statistic

G = 9.80665


def _mechanise(q, f_b, w_b, n, dt, w_ie=np.zeros(3)):
    v, p = np.zeros(3), np.zeros(3)
    for _ in range(n):
        q, v, p, _ = strapdown_step(q, v, p, f_b, w_b, dt, GRAVITY_ENU_M_S2, w_ie)
    return q, v, p


def test_static_imu_does_not_drift_and_a_bias_drifts_as_half_b_t_squared():
    q0 = level_attitude(np.array([0.0, 0.0, G]), 0.0)     # body z up, x north
    q, v, p = _mechanise(q0, np.array([0.0, 0.0, G]), np.zeros(3), 1000, 0.01)
    assert np.abs(p).max() < 1e-9 and np.abs(v).max() < 1e-10
    # an accelerometer bias of 0.02 m/s² along body x (north): p = ½ b t² = 0.5·0.02·10² = 1.0 m north
    q, v, p = _mechanise(q0, np.array([0.02, 0.0, G]), np.zeros(3), 1000, 0.01)
    assert p[1] == pytest.approx(1.0, rel=1e-9) and v[1] == pytest.approx(0.2, rel=1e-9)
    assert abs(p[0]) < 1e-9 and abs(p[2]) < 1e-9


def test_constant_rotation_gives_the_known_attitude():
    q0 = level_attitude(np.array([0.0, 0.0, G]), 0.0)
    # π/2 rad/s about body z (up) for 1 s: counter-clockwise seen from above, x turns from north to west
    q, _, _ = _mechanise(q0, np.array([0.0, 0.0, G]), np.array([0.0, 0.0, math.pi / 2]), 100, 0.01)
    assert np.allclose(quat_to_dcm(q) @ [1, 0, 0], [-1, 0, 0], atol=1e-12)
    assert math.degrees(yaw_of(q)) == pytest.approx(-90.0, abs=1e-9)
    # π rad/s about body x for 1 s: y and z reverse (C = diag(1, −1, −1) from the identity start)
    q1 = np.array([1.0, 0.0, 0.0, 0.0])
    q, _, _ = _mechanise(q1, np.zeros(3), np.array([math.pi, 0.0, 0.0]), 250, 0.004)
    assert np.allclose(quat_to_dcm(q), np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_earth_rate_is_removed_from_a_still_gyro():
    lat = math.radians(30.0)
    w_ie_n = 7.2921151467e-5 * np.array([0.0, math.cos(lat), math.sin(lat)])
    q0 = level_attitude(np.array([0.0, 0.0, G]), math.radians(40.0))
    w_b = quat_to_dcm(q0).T @ w_ie_n                 # what a still gyro reads
    q, _, p = _mechanise(q0, quat_to_dcm(q0).T @ [0, 0, G], w_b, 6000, 0.01, w_ie_n)
    assert np.allclose(quat_to_dcm(q), quat_to_dcm(q0), atol=1e-12) and np.abs(p).max() < 1e-8


def test_leveling_of_a_tilted_imu_points_the_specific_force_up_and_sets_the_heading():
    f_b = np.array([3.0, -2.0, 9.0])
    q = level_attitude(f_b, math.radians(123.0))
    up = quat_to_dcm(q) @ (f_b / np.linalg.norm(f_b))
    assert np.allclose(up, [0, 0, 1], atol=1e-12)
    assert math.degrees(yaw_of(q)) == pytest.approx(123.0, abs=1e-9)


def test_glrt_statistic_against_hand_computed_windows():
    cfg = StanceConfig(sigma_acc_m_s2=1.0, sigma_gyro_rad_s=0.1, window=2, gamma=5.0, gravity_m_s2=10.0)
    acc = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 12.0], [6.0, 0.0, 8.0]])
    gyro = np.array([[0.1, 0.0, 0.0], [0.0, 0.0, 0.2], [0.0, 0.0, 0.0]])
    T = glrt_statistic(acc, gyro, cfg)
    # window 0: ȳ = (0, 0, 11) → g ȳ/|ȳ| = (0, 0, 10); Σ‖a − gu‖² = 0 + 4; Σ‖ω‖² = 0.01 + 0.04
    #   T = (4/1 + 0.05/0.01) / 2 = 4.5
    # window 1: ȳ = (3, 0, 10), |ȳ| = √109; Σ‖a‖² = 144 + 100 = 244, u·Σa = (0·6 + 12·10... ) — by hand:
    #   Σ‖a_k − g u‖² = Σ‖a_k‖² − 2 g u·Σa_k + W g² = 244 − 2·10·(√109·2) + 200 = 444 − 40√109
    #   Σ‖ω‖² = 0.04  →  T = (444 − 40√109 + 4) / 2
    assert T == pytest.approx([4.5, (448.0 - 40.0 * math.sqrt(109.0)) / 2.0], rel=1e-12)
    # stance where T < γ = 5: window 0 only → samples 0 and 1
    assert detect_stance(acc, gyro, cfg).tolist() == [True, True, False]


def test_stride_count_closes_short_gaps_and_drops_short_spells():
    rate = 100.0
    s = np.zeros(500, bool)
    for a, b in ((0, 50), (100, 150), (158, 200), (260, 262), (320, 400), (450, 500)):
        s[a:b] = True
    # gaps: 150-158 (0.08 s, closed), 262 (a 20 ms spell, dropped); swings 50-100, 200-320, 400-450 → 3
    assert count_strides(s, rate, StanceConfig(min_swing_s=0.25, min_stance_s=0.04)) == 3


def _still_record(n, rate, acc_bias=np.zeros(3), seed=0, mag=None):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    acc = np.tile([0.0, 0.0, G], (n, 1)) + acc_bias + rng.normal(0, 0.002, (n, 3))
    gyro = rng.normal(0, 1e-4, (n, 3))
    return t, acc, gyro


def test_zupt_keeps_the_velocity_of_a_biased_still_imu_bounded():
    """A horizontal accelerometer bias of 0.05 m/s² left alone gives 3 m/s and 90 m after 60 s; with the
    ZUPTs of the (everywhere-detected) stance the velocity stays at the measurement noise and the position
    within centimetres (the bias is absorbed as tilt, the classic unobservable pair)."""
    rate, n = 100.0, 6000
    t, acc, gyro = _still_record(n, rate, acc_bias=np.array([0.05, 0.0, 0.0]))
    q0 = level_attitude(np.array([0.0, 0.0, G]), 0.0)      # levelled on the true gravity
    _, v_free, p_free = _mechanise(q0, np.array([0.05, 0.0, G]), np.zeros(3), n, 1 / rate)
    assert np.linalg.norm(v_free) == pytest.approx(3.0, rel=1e-3)
    run = run_foot_ins(t, acc, gyro, cfg=FootInsConfig(stance=StanceConfig(gamma=1e6)))
    assert run.stance.all()
    assert np.abs(run.vel_m_s).max() < 0.01
    assert np.abs(run.pos_m[-1, :2]).max() < 0.02


def test_heading_jacobian_matches_a_numerical_derivative():
    m = np.array([5.0, 30.0, -40.0])        # east, north, up (a field dipping down, north-east)
    h = heading_jacobian(m)
    eps = 1e-7
    for i in range(3):
        phi = np.zeros(3)
        phi[i] = eps
        m_true = m + np.cross(m, phi)        # C = (I − [φ×]) Ĉ  →  m_true = m̂ − φ × m̂
        d = math.atan2(m_true[0], m_true[1]) - math.atan2(m[0], m[1])
        assert h[i] == pytest.approx(d / eps, abs=1e-6)
    assert h[2] == pytest.approx(1.0)          # a yaw error moves the azimuth one for one


def test_master_fusion_against_the_information_form_by_hand():
    x = np.array([[1.0, 0.0], [3.0, 2.0]])
    P = np.array([[[2.0, 1.0], [1.0, 2.0]], [[3.0, 0.0], [0.0, 4.0]]])
    xg, Pg = fuse_information(x, P, np.array([True, True]))
    # P1⁻¹ = [[2, −1], [−1, 2]]/3, P2⁻¹ = diag(1/3, 1/4); Σ = [[1, −1/3], [−1/3, 11/12]]
    # det = 11/12 − 1/9 = 29/36 → P_g = (36/29)[[11/12, 1/3], [1/3, 1]] = [[33, 12], [12, 36]]/29
    assert Pg == pytest.approx(np.array([[33.0, 12.0], [12.0, 36.0]]) / 29.0, abs=1e-12)
    # Σ Pᵢ⁻¹xᵢ = (2/3, −1/3) + (1, 1/2) = (5/3, 1/6);  x_g = P_g (5/3, 1/6) = (57, 26)/29
    assert xg == pytest.approx(np.array([57.0, 26.0]) / 29.0, abs=1e-12)
    # an inactive filter is left out
    xg1, Pg1 = fuse_information(x, P, np.array([False, True]))
    assert xg1 == pytest.approx(x[1]) and Pg1 == pytest.approx(P[1])


def test_sharing_factors_reproduce_the_centralised_update():
    """Prior x = 0, P = I shared with β = (1/4, 3/4) (P₁ = 4I, P₂ = 4/3 I); filter 1 measures state 0 = 2
    (R = 1), filter 2 state 1 = −1 (R = 2). By hand: x₁ = 4/5·2 = 1.6, P₁₀₀ = 0.8; x₂ = 0.4·(−1), P₂₁₁ = 0.8;
    fused: P₀₀ = 1/(1/0.8 + 3/4) = 0.5, x₀ = 0.5·1.6/0.8 = 1.0; P₁₁ = 1/(1/4 + 1/0.8) = 2/3,
    x₁ = (2/3)(−0.4/0.8) = −1/3 — the centralised Kalman update of the prior by both fixes (K = 1/2, 1/3).
    Sharing P·β instead of P/β gives P₀₀ = 0.2/1.05 ≠ 0.5."""
    beta = np.array([0.25, 0.75])
    X, Ps = np.zeros((2, 2)), np.zeros((2, 2, 2))
    share_information(np.zeros(2), np.eye(2), beta, np.array([True, True]), X, Ps)
    assert Ps[0] == pytest.approx(4 * np.eye(2)) and Ps[1] == pytest.approx(np.eye(2) * 4 / 3)
    X[0], Ps[0], _ = joseph_update(X[0], Ps[0], np.array([2.0]), np.array([[1.0, 0.0]]), np.array([[1.0]]))
    X[1], Ps[1], _ = joseph_update(X[1], Ps[1], np.array([-1.0]), np.array([[0.0, 1.0]]), np.array([[2.0]]))
    assert X[0, 0] == pytest.approx(1.6) and Ps[0][0, 0] == pytest.approx(0.8)
    assert X[1, 1] == pytest.approx(-0.4) and Ps[1][1, 1] == pytest.approx(0.8)
    xg, Pg = fuse_information(X, Ps, np.array([True, True]))
    assert xg == pytest.approx([1.0, -1.0 / 3.0], abs=1e-12)
    assert Pg == pytest.approx(np.diag([0.5, 2.0 / 3.0]), abs=1e-12)


def test_sharing_factors_are_normalised_over_the_active_filters():
    b = SharingFactors(0.5, 0.25, 0.25)
    assert b.normalised([True, True, True]) == pytest.approx([0.5, 0.25, 0.25])
    assert b.normalised([True, False, True]) == pytest.approx([2 / 3, 1.0, 1 / 3])
    with pytest.raises(ValueError, match="uwb"):
        SharingFactors(uwb=0.0)


def test_federated_run_with_reset_after_every_update_does_not_depend_on_beta():
    """Carlson's fusion-reset mode is the centralised filter whatever the β: two runs with different shares
    agree; a fusion period of 1 s (local filters run open between fusions) does depend on them."""
    rate, n = 100.0, 3000
    t, acc, gyro = _still_record(n, rate, acc_bias=np.array([0.03, -0.02, 0.0]), seed=4)
    rng = np.random.default_rng(5)
    tu = np.arange(0.3, 30.0, 1 / 3.5)
    uwb = UwbFixes(tu, rng.normal(0, 0.35, (len(tu), 2)), np.tile(np.eye(2) * 0.35 ** 2, (len(tu), 1, 1)))
    runs = []
    for beta, period in (((1 / 3, 1 / 3, 1 / 3), 0.0), ((0.7, 0.1, 0.2), 0.0), ((0.7, 0.1, 0.2), 1.0),
                         ((1 / 3, 1 / 3, 1 / 3), 1.0)):
        cfg = FootInsConfig(stance=StanceConfig(gamma=1e6), sharing=SharingFactors(*beta), fusion_period_s=period)
        runs.append(run_foot_ins(t, acc, gyro, cfg=cfg, uwb=uwb))
    assert runs[0].active.tolist() == [True, True, False]
    assert runs[0].sharing == pytest.approx([0.5, 0.5, 1.0])
    assert np.allclose(runs[0].pos_m, runs[1].pos_m, atol=1e-9)
    assert np.allclose(runs[0].P_pos_m2, runs[1].P_pos_m2, rtol=1e-7, atol=1e-12)
    assert not np.allclose(runs[2].pos_m, runs[3].pos_m, atol=1e-4)
    # the UWB fixes pull the still foot's position to their mean: σ/√m ≈ 0.35/√104 ≈ 3.4 cm
    assert np.linalg.norm(runs[0].pos_m[-1, :2] - uwb.en_m.mean(axis=0)) < 0.05
    assert runs[0].uwb_accepted.mean() > 0.98


def test_uwb_fixes_far_off_are_rejected_by_the_gate():
    rate, n = 100.0, 2000
    t, acc, gyro = _still_record(n, rate, seed=6)
    tu = np.arange(0.3, 20.0, 1 / 3.5)
    en = np.zeros((len(tu), 2))
    en[10::7] = [8.0, -6.0]                    # NLOS-like outliers 10 m away
    uwb = UwbFixes(tu, en, np.tile(np.eye(2) * 0.1, (len(tu), 1, 1)))
    run = run_foot_ins(t, acc, gyro, cfg=FootInsConfig(stance=StanceConfig(gamma=1e6)), uwb=uwb)
    bad = np.zeros(len(tu), bool)
    bad[10::7] = True
    assert not run.uwb_accepted[bad].any() and run.uwb_accepted[~bad].all()
    assert np.abs(run.pos_m[-1, :2]).max() < 0.05
