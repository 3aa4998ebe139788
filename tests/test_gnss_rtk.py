"""RTK decided from observables, wrong fixes, carrier smoothing, correlated errors, Doppler velocity;
the direction of the fix error (issue 12 item 22)."""

import numpy as np
import pytest

from simulation.gnss.fix import (FixConfig, QUALITY_RTK_FIXED, QUALITY_RTK_FLOAT, distance_gm_phi,
                                 float_ambiguity_bias, gauss_markov, hatch_smooth, pseudorange_errors, solve_fixes)
from simulation.gnss.velocity import fll_jitter_hz, velocity_errors

# A fixed sky of 12 satellites: 4 azimuths × 3 elevations, 6 GPS and 6 BeiDou.
AZ = np.radians(np.repeat([0.0, 90.0, 180.0, 270.0], 3) + np.tile([0.0, 30.0, 60.0], 4))
EL = np.radians(np.tile([20.0, 45.0, 70.0], 4))
SYS = np.array([0, 1] * 6)


def _sky(n):
    return np.tile(AZ, (n, 1)), np.tile(EL, (n, 1))


def _zero_errors(n, k=12):
    z = np.zeros((n, k))
    return {"noise": z.copy(), "multipath": z.copy(), "nlos_bias": z.copy(), "atmosphere": z.copy(), "carrier": z.copy()}


def test_wall_to_the_east_pushes_the_fix_west():
    """Long (reflected) ranges to the eastern satellites move the solution away from them, i.e. west."""
    n = 5
    az, el = _sky(n)
    err = _zero_errors(n)
    east = np.sin(AZ) > 0.5  # satellites whose azimuth lies east of the receiver
    err["nlos_bias"][:, east] = 4.0
    cn0 = np.full((n, 12), 45.0)
    fix = solve_fixes(np.random.default_rng(0), az, el, SYS, np.ones((n, 12), bool), cn0, err,
                      np.zeros((n, 12), bool), 0.2, corrections=False, cfg=FixConfig(raim_max_exclusions=0))
    assert np.all(fix.error_enu_m[:, 0] < -0.5)
    assert np.all(np.abs(fix.error_enu_m[:, 1]) < 0.5 * np.abs(fix.error_enu_m[:, 0]))
    # Independent reference: ordinary least squares x = (GᵀG)⁻¹Gᵀb with G built here (equal C/N0 = equal weights).
    ce = np.cos(EL)
    g = np.column_stack([-ce * np.sin(AZ), -ce * np.cos(AZ), -np.sin(EL), SYS == 0, SYS == 1]).astype(float)
    b = err["nlos_bias"][0]
    x_ref = np.linalg.solve(g.T @ g, g.T @ b)
    assert fix.error_enu_m[0] == pytest.approx(x_ref[:3], abs=1e-6)


def test_rtk_decision_does_not_read_the_nlos_flags():
    """With the same observables, flipping the true NLOS flags changes no reported quality (wrong fixes off)."""
    n = 400
    az, el = _sky(n)
    rng = np.random.default_rng(1)
    err = _zero_errors(n)
    err["noise"] = 0.3 * rng.standard_normal((n, 12))
    cn0 = np.full((n, 12), 44.0)
    cn0[200:260, :4] = 30.0  # weak carriers (below the elevation SNR mask) for a while: the acceptance test sees them
    slip = np.zeros((n, 12), bool)
    cfg = FixConfig(wrong_fix_base_prob=0.0, wrong_fix_nlos_prob=0.0)
    q = []
    for nlos_value in (False, True):
        nlos = np.full((n, 12), nlos_value)
        fix = solve_fixes(np.random.default_rng(2), az, el, SYS, np.ones((n, 12), bool), cn0, err, nlos, 0.2,
                          cfg=cfg, slip=slip)
        q.append(fix.quality)
    assert np.array_equal(q[0], q[1])
    assert np.all(q[0][200 + 5:260] != QUALITY_RTK_FIXED)  # 4 of 12 weak > 30 %: no fix
    assert np.mean(q[0][60:200] == QUALITY_RTK_FIXED) > 0.95
    # Re-fix after the weak spell takes the time-to-fix of 3-10 s.
    back = np.flatnonzero(q[0][260:] == QUALITY_RTK_FIXED)[0] * 0.2
    assert 3.0 - 0.2 <= back <= 10.0 + 0.2


def test_wrong_fixes_need_reflected_carriers_and_persist():
    n = 3000
    az, el = _sky(n)
    err = _zero_errors(n)
    err["nlos_bias"][:, :2] = 3.0
    cn0 = np.full((n, 12), 44.0)
    nlos = np.zeros((n, 12), bool)
    nlos[:, :2] = True
    slip = np.zeros((n, 12), bool)
    slip[::150, :2] = True  # the reflected carriers re-lock every 30 s: a new ambiguity each time
    cfg = FixConfig(wrong_fix_nlos_prob=0.5, wrong_fix_base_prob=0.0)
    fix = solve_fixes(np.random.default_rng(3), az, el, SYS, np.ones((n, 12), bool), cn0, err, nlos, 0.2,
                      cfg=cfg, slip=slip)
    herr = np.hypot(fix.error_enu_m[:, 0], fix.error_enu_m[:, 1])
    wrong = (fix.quality == QUALITY_RTK_FIXED) & (herr > 0.2)
    assert 0.05 < wrong.mean() < 0.6
    # Episodes last seconds, not single epochs, and are metre-level at most a few metres.
    starts = np.flatnonzero(np.diff(wrong.astype(int)) == 1)
    ends = np.flatnonzero(np.diff(wrong.astype(int)) == -1)
    lengths = (ends[: len(starts)] - starts[: len(ends)]) * 0.2
    assert np.median(lengths) > 2.0
    assert 0.2 < np.median(herr[wrong]) < 5.0
    # No reflected carriers: no wrong fix at all with p0 = 0.
    clean = solve_fixes(np.random.default_rng(3), az, el, SYS, np.ones((n, 12), bool), cn0, _zero_errors(n),
                        np.zeros((n, 12), bool), 0.2, cfg=cfg, slip=slip)
    h2 = np.hypot(clean.error_enu_m[:, 0], clean.error_enu_m[:, 1])
    assert np.nanmax(h2[clean.quality == QUALITY_RTK_FIXED]) < 0.01


def test_float_ambiguity_keeps_a_bias_held_in_lock_until_a_slip():
    """A code bias held while the carriers stayed locked stays in the float solution after it is gone; a slip
    (a new ambiguity) clears it. The float filter is not restarted by the receiver's fix state."""
    n = 400
    az, el = _sky(n)
    err = _zero_errors(n)
    err["nlos_bias"][100:200, :3] = 3.0  # three satellites reflected for 20 s, direct again afterwards
    cn0 = np.full((n, 12), 44.0)
    cfg = FixConfig(rtk_min_sats=12, rtk_conv_lock_s=1e6)  # float throughout
    out = []
    for slip_at_end in (False, True):
        slip = np.zeros((n, 12), bool)
        slip[200, :3] = slip_at_end
        fix = solve_fixes(np.random.default_rng(0), az, el, SYS, np.ones((n, 12), bool), cn0, err,
                          np.zeros((n, 12), bool), 0.2, cfg=cfg, slip=slip)
        assert np.all(fix.quality[20:] == QUALITY_RTK_FLOAT)
        out.append(np.hypot(fix.error_enu_m[:, 0], fix.error_enu_m[:, 1]))
    held, slipped = out
    assert held[199] > 0.1                                     # the bias entered the float ambiguities
    # Without a slip it is still there 20 s later (the mean since lock: 100 of 500 epochs at 3 m) ...
    assert held[300] > 0.5 * held[199]
    # ... with a slip the new ambiguities start from the clean code: gone once the navigation filter (τ 8 s)
    # has settled.
    assert slipped[380] < 0.1 * held[380]
    # Growing-window mean, the reference: 1/N-weighted, restarted where the lock age does not grow.
    e = np.array([[2.0], [4.0], [6.0], [0.0], [0.0]])
    age = np.array([[10.0], [10.2], [10.4], [0.0], [0.2]])
    assert float_ambiguity_bias(e, age, 0.2)[:, 0] == pytest.approx([2.0, 2.0 + 2.0 / 52, 2.0 + 2.0 / 52
                                                                     + (6.0 - 2.0 - 2.0 / 52) / 53, 0.0, 0.0])


def test_fix_waits_for_converged_carriers():
    """Carriers that slip every 10 s never stay locked the 20 s a single-frequency engine needs: float, never
    fixed; with the convergence requirement off the same sky fixes."""
    n = 1500
    az, el = _sky(n)
    cn0 = np.full((n, 12), 44.0)
    slip = np.zeros((n, 12), bool)
    slip[::50] = True
    q = {}
    for conv in (20.0, 0.0):
        q[conv] = solve_fixes(np.random.default_rng(4), az, el, SYS, np.ones((n, 12), bool), cn0, _zero_errors(n),
                              np.zeros((n, 12), bool), 0.2, cfg=FixConfig(rtk_conv_lock_s=conv), slip=slip).quality
    assert not np.any(q[20.0] == QUALITY_RTK_FIXED) and np.mean(q[20.0] == QUALITY_RTK_FLOAT) > 0.5
    assert np.mean(q[0.0] == QUALITY_RTK_FIXED) > 0.1


def test_hatch_filter_reduces_white_code_noise_by_sqrt_n():
    rng = np.random.default_rng(4)
    e = rng.standard_normal((20_000, 4))
    reset = np.zeros_like(e, bool)
    reset[0] = True
    s = hatch_smooth(e, reset, 100)[1000:]
    # Steady state of ê = e/N + (N-1)/N·ê: variance 1/(2N-1).
    assert s.std() == pytest.approx(np.sqrt(1.0 / 199.0), rel=0.1)


def test_multipath_is_correlated_over_metres_and_a_standing_minute():
    phi_walk = distance_gm_phi(np.full(1, 1.3), 0.2, 120.0, 5.0)[0]
    phi_stand = distance_gm_phi(np.zeros(1), 0.2, 120.0, 5.0)[0]
    # After 5 m of walking the correlation is e^-1 (minus the time floor); standing 60 s, e^-0.5.
    assert phi_walk ** (5.0 / 1.3 / 0.2) == pytest.approx(np.exp(-1.0 - 5.0 / 1.3 / 120.0), rel=1e-6)
    assert phi_stand ** 300 == pytest.approx(np.exp(-0.5), rel=1e-6)
    x = gauss_markov(np.random.default_rng(5), phi_stand, (20_000, 20))
    lag = 300
    rho = np.mean(x[:-lag] * x[lag:]) / np.mean(x * x)
    assert rho == pytest.approx(np.exp(-0.5), abs=0.1)


def test_carrier_smoothing_keeps_nlos_bias_and_slows_errors():
    n, k = 1500, 6
    el = np.full((n, k), np.radians(30.0))
    cn0 = np.full((n, k), 40.0)
    nlos = np.zeros((n, k), bool)
    nlos[:, 0] = True
    extra = np.where(nlos, 10.0, 0.0)
    speed = np.full(n, 1.3)
    e = pseudorange_errors(np.random.default_rng(6), el, cn0, nlos, extra, np.zeros(n), speed, 0.2, 0.19)
    assert 5.0 < e["nlos_bias"][:, 0].mean() < 15.0 and np.all(e["nlos_bias"][:, 1:] == 0)
    code = e["noise"] + e["multipath"]
    lag = 25  # 5 s
    rho = np.mean(code[:-lag] * code[lag:]) / np.mean(code * code)
    assert rho > 0.5


def test_doppler_velocity_noise_grows_with_weak_and_reflected_signals():
    assert fll_jitter_hz(45.0) == pytest.approx(0.127, abs=0.002)
    n = 4000
    az, el = _sky(n)
    used = np.ones((n, 12), bool)
    speed = np.full(n, 1.3)
    strong = velocity_errors(np.random.default_rng(7), az, el, SYS, used, np.full((n, 12), 45.0),
                             np.zeros((n, 12), bool), speed, 0.2, 0.19)
    weak_nlos = velocity_errors(np.random.default_rng(7), az, el, SYS, used, np.full((n, 12), 30.0),
                                np.ones((n, 12), bool), speed, 0.2, 0.19)
    s1 = np.hypot(*strong.T).mean()
    s2 = np.hypot(*weak_nlos.T).mean()
    assert 0.005 < s1 < 0.05
    assert s2 > 5 * s1


def test_receivers_differ_and_the_body_masks_the_sky_behind():
    from datetime import datetime, timezone

    from features.site import Origin, Site
    from simulation.gnss.stream import simulate_gnss
    from simulation.site.route import static_trajectory

    site = Site("open", Origin(35.0, 115.0, 50.0))
    traj = static_trajectory(0.0, 0.0, 1.0, 20.0, datetime(2026, 5, 1, 3, 0, tzinfo=timezone.utc))  # facing north
    offs = [simulate_gnss(site, traj, seed=1, receiver_seed=r).receiver_offset_db for r in range(8)]
    assert all(-5.0 <= o <= 0.0 for o in offs) and np.ptp(offs) > 1.0
    front = simulate_gnss(site, traj, seed=1, receiver_seed=0, body=False)
    worn = simulate_gnss(site, traj, seed=1, receiver_seed=0, body=True)
    az = np.degrees(front.az_rad)
    el = np.degrees(front.el_rad)
    behind = (np.abs(((az - 180.0) + 180.0) % 360.0 - 180.0) < 60.0) & (el > 5) & (el < 35) & front.in_view
    ahead = (np.abs(((az + 180.0) % 360.0) - 180.0) < 60.0) & (el > 10) & front.in_view
    assert behind.any() and ahead.any()
    drop_behind = np.mean(front.cn0_true_dbhz[behind] - worn.cn0_true_dbhz[behind])
    drop_ahead = np.mean(front.cn0_true_dbhz[ahead] - worn.cn0_true_dbhz[ahead])
    assert 1.0 < drop_behind < 10.5 and abs(drop_ahead) < 0.5
