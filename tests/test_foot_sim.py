"""The simulated foot-mounted IMU (simulation/imu/foot.py): its specific force and body rate integrate back to
its own trajectory, its stance phases are what the GLRT detector finds, its noise is the stated datasheet
density, and the writer's file goes through the reader."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from features.errors import ConfigError
from models.foot.mechanisation import GRAVITY_ENU_M_S2, dcm_to_quat, strapdown_step
from models.foot.stance import count_strides, detect_stance, StanceConfig
from simulation.imu.foot import (FootErrors, FootMotion, foot_csv_text, simulate_foot_imu, synthesise_foot_imu,
                                 write_imu_foot)

NO_ERRORS = FootErrors(**{k: 0.0 for k in ("acc_vrw_m_s2_sqrt_hz", "acc_bias_instability_m_s2", "acc_turn_on_m_s2",
                                           "gyro_arw_rad_s_sqrt_hz", "gyro_bias_instability_rad_s",
                                           "gyro_turn_on_rad_s", "scale_error", "mag_noise_ut", "mag_hard_iron_ut",
                                           "mag_soft_iron", "misalignment_rad")},
                       acc_range_m_s2=1e4, gyro_range_rad_s=1e3)


@pytest.fixture(scope="module")
def ctx():
    from simulation.rng import stream_rng
    from simulation.site.layout import generate_site
    from simulation.site.route import RouteConfig, plan_route, route_trajectory
    from simulation.streams import StreamContext
    from simulation.walk import default_start_utc

    site = generate_site(3)
    poly, stops, speed = plan_route(site, stream_rng(11, "route"), 60.0, RouteConfig())
    traj = route_trajectory(poly, stops, speed, 60.0, default_start_utc(11), site.device_height_m, RouteConfig())
    return StreamContext(site=site, trajectory=traj, out_dir=Path("."), seed=11, kind="walk", person_seed=11)


def test_error_free_foot_imu_integrates_back_to_its_trajectory(ctx):
    """Strapdown of the error-free 400 Hz output from the true start (no ZUPT) stays on the true track: a
    sign error in the body rate, gravity or the frame would leave it metres off within seconds."""
    imu, motion = simulate_foot_imu(ctx, 400.0, errors=NO_ERRORS)
    k = int(round(motion.rate_hz / 400.0))
    v_int = np.gradient(motion.pos_enu_m, 1 / motion.rate_hz, axis=0)
    pos_true = np.column_stack([np.interp(imu.t_s, motion.t_s, motion.pos_enu_m[:, i]) for i in range(3)])
    vel_true = np.column_stack([np.interp(imu.t_s, motion.t_s, v_int[:, i]) for i in range(3)])
    lat = math.radians(ctx.site.origin.lat_deg)
    w_ie = 7.2921151467e-5 * np.array([0.0, math.cos(lat), math.sin(lat)])
    j0 = max(int(np.argmin(motion.flat[::k])) - 40, 0)            # 0.1 s before the foot first moves
    q = dcm_to_quat(motion.C_bn[(j0 + 1) * k])                  # the attitude at the sample's stamp
    p, v = pos_true[j0].copy(), vel_true[j0].copy()
    n = 4000                                                      # 10 s
    for j in range(j0 + 1, j0 + n):
        q, v, p, _ = strapdown_step(q, v, p, imu.acc_m_s2[j], imu.gyro_rad_s[j], 1 / 400.0, GRAVITY_ENU_M_S2, w_ie)
    assert np.linalg.norm(p - pos_true[j0 + n - 1]) < 0.25
    assert np.linalg.norm(p[:2] - pos_true[j0, :2]) > 5.0         # the foot did walk


def test_stance_of_the_simulated_foot_is_what_the_detector_finds(ctx):
    imu, motion = simulate_foot_imu(ctx, 100.0)
    flat = motion.flat[:: int(round(motion.rate_hz / 100.0))][: len(imu.t_s)]
    assert 0.3 < flat.mean() < 0.6                                # foot flat ≈ 35 % of walking, plus standing
    still = detect_stance(imu.acc_m_s2, imu.gyro_rad_s, StanceConfig(gamma=1e5))
    assert np.mean(still & ~flat) < 0.02 and np.mean(~still & flat) < 0.02
    strides = count_strides(still, 100.0)
    assert abs(strides - len(motion.heel_strikes_s)) <= 1
    # the true velocity is zero while flat (the ZUPT's premise)
    both = motion.flat[1:] & motion.flat[:-1]
    assert np.abs(np.diff(motion.pos_enu_m, axis=0)[both]).max() < 1e-12
    # the output stays within the Ellipse2-A ranges a foot needs (±450 °/s, ±16 g)
    assert np.degrees(np.abs(imu.gyro_rad_s).max()) < 450.0 and np.abs(imu.acc_m_s2).max() < 16 * 9.81


def test_noise_of_a_still_foot_is_the_datasheet_density(ctx):
    rate, n = 100.0, 60_000
    t = np.arange(n) / (4 * rate)
    still = FootMotion(t, np.zeros((n, 3)), np.tile(np.eye(3), (n, 1, 1)), np.ones(n, bool), np.zeros(0), 4 * rate)
    e = FootErrors()
    imu = synthesise_foot_imu(still, ctx.site, rate, np.random.default_rng(1), e)
    # white noise σ = N √f_s: 0.18 °/√h → 5.24e-4 rad/s at 100 Hz; 0.03 m/s/√h → 5.0e-3 m/s²
    d_g = np.diff(imu.gyro_rad_s, axis=0).std(axis=0) / math.sqrt(2)
    d_a = np.diff(imu.acc_m_s2, axis=0).std(axis=0) / math.sqrt(2)
    assert d_g == pytest.approx(np.full(3, e.gyro_arw_rad_s_sqrt_hz * 10.0), rel=0.05)
    assert d_a == pytest.approx(np.full(3, e.acc_vrw_m_s2_sqrt_hz * 10.0), rel=0.05)
    # a still IMU reads gravity's magnitude within its turn-on bias (2 mg σ; 5σ bound)
    assert abs(np.linalg.norm(imu.acc_m_s2.mean(axis=0)) - 9.80665) < 5 * np.linalg.norm([e.acc_turn_on_m_s2] * 3)


def test_same_seed_same_file_and_the_reader_takes_it(ctx, tmp_path):
    from dataclasses import replace

    from features.imu.foot import read_foot_imu

    a = foot_csv_text(simulate_foot_imu(ctx, 100.0)[0])
    assert a == foot_csv_text(simulate_foot_imu(ctx, 100.0)[0])
    assert a != foot_csv_text(simulate_foot_imu(replace(ctx, seed=12), 100.0)[0])
    c = replace(ctx, out_dir=tmp_path, options={"foot_imu_rate_hz": 400})
    meta = write_imu_foot(c)
    assert meta["imu_foot"]["rate_hz"] == 400.0 and meta["imu_foot"]["file"] == "imu_foot.csv"
    imu = read_foot_imu(tmp_path / "imu_foot.csv")
    assert imu.rate_hz == pytest.approx(400.0) and imu.mag_ut is not None and imu.report.n_defects == 0
    assert write_imu_foot(replace(ctx, kind="survey")) == {}
    with pytest.raises(ConfigError, match="foot_imu_rate_hz"):
        write_imu_foot(replace(ctx, options={"foot_imu_rate_hz": 50}))


def test_zupt_bounds_the_velocity_of_the_walking_foot(ctx):
    """On the simulated walking foot (Ellipse2-A class errors, 100 Hz, a minute) the ZUPT filter keeps the
    velocity error at the centimetre-per-second level everywhere, where the same strapdown without updates
    drifts to metres per second; its stance velocity is the ZUPT's."""
    from models.foot.ins import FootInsConfig, run_foot_ins

    imu, motion = simulate_foot_imu(ctx, 100.0)
    v_int = np.gradient(motion.pos_enu_m, 1 / motion.rate_hz, axis=0)
    v_true = np.column_stack([np.interp(imu.t_s, motion.t_s, v_int[:, i]) for i in range(3)])
    run = run_foot_ins(imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, None, FootInsConfig(),
                       yaw_rad=float(np.arctan2(motion.C_bn[0, 0, 0], motion.C_bn[0, 1, 0])),
                       latitude_deg=ctx.site.origin.lat_deg)
    # the speed error (heading errors, unobservable without the magnetometer here, rotate the velocity only)
    dv = np.abs(np.linalg.norm(run.vel_m_s, axis=1) - np.linalg.norm(v_true, axis=1))
    # measured: 99th percentile 0.055 m/s over the minute (0.40 m/s when the samples were stamped at the start
    # of their interval instead of its end), stance speeds at the ZUPT's σ
    assert np.percentile(dv, 99) < 0.1 and np.percentile(dv[-1000:], 99) < 0.1
    assert np.percentile(np.linalg.norm(run.vel_m_s[run.stance], axis=1), 99) < 0.05
    lat = math.radians(ctx.site.origin.lat_deg)
    w_ie = 7.2921151467e-5 * np.array([0.0, math.cos(lat), math.sin(lat)])
    q, v, p = run.quat[0].copy(), np.zeros(3), np.zeros(3)
    for j in range(1, len(imu.t_s)):
        q, v, p, _ = strapdown_step(q, v, p, imu.acc_m_s2[j], imu.gyro_rad_s[j], 0.01, GRAVITY_ENU_M_S2, w_ie)
    assert np.linalg.norm(v - v_true[-1]) > 1.0
