"""IMU walker physics: invariants and closed forms on noise-free and noisy synthetic walks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from features.imu.heading import down_in_body, yaw_rate
from features.site import Box, Origin, Site
from dataclasses import replace

from features.imu.heading import magnetic_heading, wrap_pi
from simulation.imu.walker import (MIN_EXCURSION_STEP_M, SensorErrors, person_gait, place_steps, synthesise_imu,
                                   trajectory_from_waypoints)
from simulation.imu.magnetic import (SteelDipoles, disturbance_ned_ut, earth_field_ned_ut, field_elements,
                                 steel_dipoles)
from simulation.rng import stream_rng

SITE = Site(name="walker-test", origin=Origin(30.0, 114.0, 0.0), seed=2)
NO_ERRORS = SensorErrors(acc_noise_m_s2=0.0, acc_bias_m_s2=0.0, gyro_noise_rad_s=0.0, gyro_bias_rad_s=0.0,
                         gyro_bias_walk_rad_s_sqrt_s=0.0, gyro_scale_error=0.0, mag_noise_ut=0.0,
                         mag_hard_iron_ut=0.0, mag_soft_iron=0.0, mount_tilt_rad=0.0, mount_yaw_rad=0.0,
                         acc_tc_m_s2_per_k=0.0, gyro_tc_rad_s_per_k=0.0, busbar_current_a=0.0)
WAYPOINTS = np.array([[0.0, 0.0], [0.0, 30.0], [20.0, 30.0], [20.0, 10.0]])


@pytest.fixture(scope="module")
def clean_walk():
    traj = trajectory_from_waypoints(WAYPOINTS, 1.3, stops_s={2: 4.0})
    gait = replace(person_gait(11), excursion_variability=0.0)
    steps, count = place_steps(traj, gait, stream_rng(1, "steps"))
    imu = synthesise_imu(traj, SITE, gait, steps, count, stream_rng(1, "sensor"), NO_ERRORS)
    return traj, gait, steps, count, imu


def test_steps_cover_the_path_and_follow_the_cadence(clean_walk):
    traj, gait, steps, _, _ = clean_walk
    path_m = float(np.sum(traj.speed_m_s[:-1] * np.diff(traj.t_s)))
    assert steps.step_length_m.sum() == pytest.approx(path_m, rel=0.01)
    cruise = steps.step_length_m[(steps.step_length_m > 0.6)]
    expected = 1.3 / float(gait.cadence_hz(np.array([1.3]))[0])          # S = v / f in steady walking
    assert np.median(cruise) == pytest.approx(expected, rel=0.03)
    # no step while standing: none in the first 2 s, the 4 s stop or the last 2 s
    moving = np.interp(steps.t_s - 0.05, traj.t_s, traj.speed_m_s) > 0.0
    assert moving.all() and steps.t_s[0] > 2.0
    intervals = np.diff(steps.t_s)
    assert np.all(intervals[intervals < 1.0] > 0.35)


def test_vertical_motion_is_the_inverted_pendulum_peaking_at_heel_strike(clean_walk):
    """Level device, no errors, no step variability: over step k the vertical specific-force swing is the
    second derivative of z = h(1 − cos 2πc)/2, i.e. 4π²·h(S_k)/T_k² with h from Zijlstra & Hof's pendulum,
    and the upward maximum falls at the heel strike that ends the step."""
    traj, gait, steps, count, imu = clean_walk
    down = down_in_body(imu.acc_m_s2, 100.0)
    vert = -np.einsum("ij,ij->i", imu.acc_m_s2, down)                 # upward specific force ≈ g + a_up
    k_idx = np.ceil(count - 1e-9).astype(int) - 1
    checked = 0
    for k in range(2, len(steps.t_s) - 2):
        s = steps.step_length_m[k]
        period = steps.t_s[k] - steps.t_s[k - 1]
        if s < 0.6 or period > 1.0:
            continue
        sel = k_idx == k
        swing = vert[sel].max() - vert[sel].min()
        h = float(gait.excursion_m(np.array([s]))[0])
        assert swing == pytest.approx(4 * math.pi ** 2 * h / period ** 2, rel=0.12)
        around = np.abs(traj.t_s - steps.t_s[k]) < 0.25 * period
        assert abs(traj.t_s[around][np.argmax(vert[around])] - steps.t_s[k]) <= 0.03
        checked += 1
    assert checked > 40
    # Weinberg's K implied by the pendulum varies with cadence: S/(2A)^(1/4) is not one constant
    assert MIN_EXCURSION_STEP_M == 0.5
    h07 = float(gait.excursion_m(np.array([0.7]))[0])
    assert 0.03 <= h07 <= 0.06                                        # 3-6 cm pelvis excursion (Zijlstra & Hof)


def test_device_errors_mounting_yaw_and_magnetometer_residual():
    """The mounting yaw offset turns the magnetometer heading by that angle; hard/soft iron change the
    intensity far from steel by about their size."""
    traj = trajectory_from_waypoints(WAYPOINTS, 1.3)
    gait = person_gait(11)
    steps, count = place_steps(traj, gait, stream_rng(1, "steps"))
    yaw_only = replace(NO_ERRORS, mount_yaw_rad=math.radians(5.0))
    imu = synthesise_imu(traj, SITE, gait, steps, count, stream_rng(3, "sensor"), yaw_only)
    assert 0.2 < abs(math.degrees(imu.mount_yaw_rad)) < 15.0
    still = slice(0, 150)
    b = earth_field_ned_ut(30.0, 114.0)
    decl = field_elements(b)[0]
    psi, _, _ = magnetic_heading(imu.mag_ut[still], down_in_body(imu.acc_m_s2, 100.0)[still], decl)
    offset = float(np.mean(wrap_pi(psi - traj.heading_rad[still])))
    assert offset == pytest.approx(imu.mount_yaw_rad, abs=math.radians(0.2))
    iron = replace(NO_ERRORS, mag_hard_iron_ut=1.5, mag_soft_iron=0.02)
    imu2 = synthesise_imu(traj, SITE, gait, steps, count, stream_rng(3, "sensor"), iron)
    dev = np.linalg.norm(imu2.mag_ut, axis=1) - field_elements(b)[2]
    assert 0.1 < np.abs(dev).max() < 4.0 and np.ptp(dev) > 0.1        # heading-dependent residual


def test_standing_reads_gravity_and_gyro_follows_the_route(clean_walk):
    traj, _, _, _, imu = clean_walk
    still = slice(0, 150)
    assert np.linalg.norm(imu.acc_m_s2[still], axis=1).mean() == pytest.approx(9.80665, abs=1e-3)
    assert imu.acc_m_s2[still, 2].mean() == pytest.approx(-9.80665, abs=1e-3)     # FRD: z down reads −g
    rate = yaw_rate(imu.gyro_rad_s, down_in_body(imu.acc_m_s2, 100.0))
    turned = float(np.sum(rate) / 100.0)
    route_turn = float(np.unwrap(traj.heading_rad)[-1] - np.unwrap(traj.heading_rad)[0])   # +90°, +90°
    assert turned == pytest.approx(route_turn, abs=math.radians(1.5))
    # far from any steel the magnetometer sees exactly the Earth field's intensity
    _, _, total = field_elements(earth_field_ned_ut(30.0, 114.0))
    np.testing.assert_allclose(np.linalg.norm(imu.mag_ut, axis=1), total, rtol=1e-9)


def test_steel_dipole_on_axis_closed_form_and_decay():
    """Induced moment of a permeable sphere 4πR³H0: on its axis the field is 2·B0·(R/r)³."""
    b0 = np.array([30.0, 0.0, 0.0])                                    # µT along north
    site = Site(name="s", origin=Origin(30.0, 114.0), layout=(
        Box("transformer", "steel", False, -2.0, 2.0, -2.0, 2.0, 4.0),), seed=1)
    d = steel_dipoles(site, b0, np.random.default_rng(0), remanent_fraction=0.0)
    r_sphere = float(d.radius_m[0])
    assert r_sphere == pytest.approx((3 * 64.0 / (4 * math.pi)) ** (1 / 3))
    for r in (4.0, 8.0, 16.0):
        pos = d.centre_ned_m[0] + np.array([[r, 0.0, 0.0]])
        b = disturbance_ned_ut(d, pos)[0]
        assert b[0] == pytest.approx(2 * 30.0 * (r_sphere / r) ** 3, rel=1e-9)
        assert abs(b[1]) < 1e-12 and abs(b[2]) < 1e-12
        # on the equator (east of it) the field is antiparallel and half as strong: −B0·(R/r)³ (Jackson eq. 5.56)
        b = disturbance_ned_ut(d, d.centre_ned_m[0] + np.array([[0.0, r, 0.0]]))[0]
        assert b[0] == pytest.approx(-30.0 * (r_sphere / r) ** 3, rel=1e-9)
        assert abs(b[1]) < 1e-12 and abs(b[2]) < 1e-12
    # r is floored at the sphere's radius R, a cap (a walker never stands inside steel): continuous at R, and
    # nowhere inside stronger than the surface's 2·B0
    at = disturbance_ned_ut(d, d.centre_ned_m[0] + np.array([[r_sphere * (1 - 1e-9), 0.0, 0.0],
                                                             [r_sphere * (1 + 1e-9), 0.0, 0.0]]))
    assert at[0, 0] == pytest.approx(at[1, 0], rel=1e-6) and at[1, 0] == pytest.approx(60.0, rel=1e-6)
    inside = d.centre_ned_m[0] + np.random.default_rng(1).uniform(-1, 1, (500, 3)) * r_sphere / np.sqrt(3)
    assert np.linalg.norm(disturbance_ned_ut(d, inside), axis=1).max() <= 60.0 * (1 + 1e-9)
    with pytest.raises(ValueError, match="dipole field"):
        disturbance_ned_ut(SteelDipoles(d.centre_ned_m, d.moment_ned_a_m2[:, :2], d.radius_m), inside)
    # two dipoles superpose, row by row (the compiled sum, issue 25)
    two = SteelDipoles(np.vstack([d.centre_ned_m, d.centre_ned_m + [0.0, 0.0, -30.0]]),
                       np.vstack([d.moment_ned_a_m2] * 2), np.repeat(d.radius_m, 2))
    pos = d.centre_ned_m[0] + np.array([[8.0, 0.0, 0.0], [0.0, 0.0, -22.0]])
    one_each = [SteelDipoles(two.centre_ned_m[j:j + 1], two.moment_ned_a_m2[j:j + 1], two.radius_m[j:j + 1])
                for j in range(2)]
    np.testing.assert_allclose(disturbance_ned_ut(two, pos), sum(disturbance_ned_ut(o, pos) for o in one_each),
                               rtol=1e-12)
    # 8 m straight below the second dipole, whose moment points north: on its equator, −B0·(R/8)³
    assert disturbance_ned_ut(one_each[1], pos[1:])[0, 0] == pytest.approx(-30.0 * (r_sphere / 8.0) ** 3, rel=1e-9)
    empty = SteelDipoles(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    assert not disturbance_ned_ut(empty, np.zeros((2, 3))).any()


def test_dipole_earth_field_elements_at_known_points():
    """Centred dipole: horizontal at the geomagnetic equator, vertical (down) near the geomagnetic north pole."""
    decl, incl, total = field_elements(earth_field_ned_ut(80.65, -72.68))   # IGRF-13 dipole pole, 2020
    assert math.degrees(incl) == pytest.approx(90.0, abs=0.5)
    assert total == pytest.approx(2 * 29.7738, rel=0.01)                   # 2·B0, B0 = sqrt(g10²+g11²+h11²)
    _, incl_s, _ = field_elements(earth_field_ned_ut(-30.0, 114.0))
    assert incl_s < 0 < field_elements(earth_field_ned_ut(30.0, 114.0))[1]
