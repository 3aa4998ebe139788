"""Odometry dead reckoning (speed + yaw rate → displacement events) and the initial heading from GNSS fixes.

Real data: ../shared/data/gnss_urban_smartloc (smartLoc, TU Chemnitz, CC BY-SA 4.0); the reference is used
only to check, never as an input.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from features.errors import ConfigError, DataError
from features.gnss.pseudorange import OdometryTable, read_smartloc
from features.gnss.wls import solve_epochs, wls_positions
from features.vehicle.odometry import OdometryConfig, align_heading, integrate_odometry, odometry_dead_reckoning
from tests.conftest import shared_data


def _odometry(speed, yaw_rate, dt=0.2, var_v=0.0025, var_w=4e-6):
    speed = np.asarray(speed, float)
    n = len(speed)
    z = np.zeros(n)
    return OdometryTable(t_s=np.arange(n) * dt, velocity_body_m_s=np.column_stack([speed, z, z]),
                         rate_body_rad_s=np.column_stack([z, z, np.broadcast_to(yaw_rate, n)]),
                         velocity_var_m2_s2=np.full((n, 3), var_v), rate_var_rad2_s2=np.full((n, 3), var_w))


def test_a_left_turn_at_constant_rate_follows_the_circle():
    """v = 10 m/s, ω = +0.1 rad/s (counter-clockwise: a left turn), heading 0 (north) from the origin: a circle
    of radius v/ω = 100 m about (−100, 0): e(t) = −R + R cos ωt, n(t) = R sin ωt, heading −ωt."""
    odo = _odometry(np.full(101, 10.0), 0.1)
    dr = integrate_odometry(odo)
    t = dr.t_s
    assert len(dr) == 100 and abs(dr.distance_m - 200.0) < 1e-9
    assert np.allclose(dr.east_m, -100 + 100 * np.cos(0.1 * t), atol=0.01)
    assert np.allclose(dr.north_m, 100 * np.sin(0.1 * t), atol=0.01)
    assert np.allclose(dr.heading_rad, -0.1 * (t - 0.1), atol=1e-12)     # mid-segment heading


def test_noise_from_the_files_variances_by_hand():
    """σ_L = ½Δt·sqrt(2·0.0025) = 0.00707 m, σ_Δψ = ½Δt·sqrt(2·4e-6) = 2.83e-4 rad, q = σ_Δψ²/Δt = 4e-7 rad²/s."""
    dr = integrate_odometry(_odometry(np.full(11, 6.0), 0.0))
    assert np.allclose(dr.sigma_step_length_m, 0.1 * math.sqrt(0.005))
    assert np.allclose(dr.sigma_heading_increment_rad, 0.1 * math.sqrt(8e-6))
    assert abs(dr.heading_rw_rad2_s - 4e-7) < 1e-15


def test_standing_gives_no_event_and_the_position_holds():
    speed = np.r_[np.full(10, 5.0), np.zeros(20), np.full(10, 5.0)]
    dr = integrate_odometry(_odometry(speed, 0.0), initial_heading_rad=math.pi / 2, start_en_m=(3.0, 4.0))
    assert not np.any((dr.t_s > 2.0) & (dr.t_s < 5.8))                  # no event while stopped
    e, n = dr.position_at(np.array([0.0, 1.0, 3.0, 5.0, 7.8]))
    assert np.allclose(n, 4.0) and np.allclose(e, [3.0, 8.0, 3.0 + 9.5, 3.0 + 9.5, 3.0 + 19.0])


def test_initial_heading_recovered_from_noisy_fixes_with_outliers():
    """An L-shaped 400 m track rotated by 40 deg, fixes with σ = 5 m and 10 % outliers of 100 m (seeded)."""
    rng = np.random.default_rng(8)
    turn = np.zeros(401)
    turn[150:166] = 0.1                                                    # a 90 deg left turn over 3 s
    rel = integrate_odometry(_odometry(np.full(401, 5.0), turn))
    t = np.arange(0.0, 80.0, 0.2)
    e, n = rel.position_at(t)
    psi0, start = math.radians(40.0), (250.0, -30.0)
    fe = start[0] + e * math.cos(psi0) + n * math.sin(psi0) + rng.normal(0, 5, len(t))
    fn = start[1] - e * math.sin(psi0) + n * math.cos(psi0) + rng.normal(0, 5, len(t))
    bad = rng.random(len(t)) < 0.1
    fe[bad] += 100.0
    fit = align_heading(rel, t, fe, fn)
    err = abs(math.degrees(fit.heading_rad) - 40.0)
    assert err < 1.5 and err < 3 * math.degrees(fit.sigma_heading_rad) + 0.5
    assert math.hypot(fit.start_en_m[0] - start[0], fit.start_en_m[1] - start[1]) < 4.0


def test_no_motion_no_heading():
    rel = integrate_odometry(_odometry(np.zeros(50), 0.0))
    with pytest.raises(DataError, match="needs motion"):
        align_heading(rel, np.arange(50) * 0.2, np.zeros(50), np.zeros(50))
    with pytest.raises(ConfigError):
        OdometryConfig(loss="bisquare")


def test_drive_heading_from_fixes_and_dead_reckoning_against_the_reference():
    folder = shared_data("gnss_urban_smartloc")
    log = read_smartloc(folder / "Berlin_Potsdamer_Platz_Input.txt")
    ref = read_smartloc(folder / "Berlin_Potsdamer_Platz_GT.txt").reference
    lat, lon, h = pymap3d.ecef2geodetic(*ref.ecef_m[0])
    pos = wls_positions(solve_epochs(log.pseudoranges), lat, lon, h)
    dr, align = odometry_dead_reckoning(log.odometry, pos.t_s, pos.east_m, pos.north_m)
    re, rn, _ = pymap3d.ecef2enu(*ref.ecef_m.T, lat, lon, h)
    k = np.searchsorted(np.cumsum(np.r_[0.0, np.hypot(np.diff(re), np.diff(rn))]), 10.0)
    ref_heading = math.degrees(math.atan2(re[k] - re[0], rn[k] - rn[0]))   # 18.2 deg over the first 10 m
    err = abs(math.degrees(align.heading_rad) - ref_heading)
    assert err < 3 * math.degrees(align.sigma_heading_rad) and err < 4.0
    assert 2.0 < math.degrees(align.sigma_heading_rad) < 8.0
    # 30 s of fixes are not enough in this canyon: the window grew to 67 s (337 m)
    assert 60.0 < align.span_s[1] < 75.0
    e, n = dr.position_at(ref.t_s)
    d = np.hypot(e - re, n - rn)
    g = np.hypot(pos.east_m - re, pos.north_m - rn)
    # the aligned odometry track: median 15.3 m, end 39.9 m; the fixes it was aligned to: 20.6 m
    assert abs(np.median(d) - 15.26) < 0.3 and abs(d[-1] - 39.94) < 0.5 and abs(np.median(g) - 20.59) < 0.1
    assert len(dr) == 814 and abs(dr.distance_m - 868.7) < 0.1       # reference path: 864.3 m
