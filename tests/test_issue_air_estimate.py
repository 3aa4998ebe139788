"""Issue 21, item 6: the wind, two thirds of the open-area acoustic error, estimated from the track's fixes.

``bench/acoustic_error_causes.py`` on five held-out walks (sites 201–205, walk 0, 300 s): the open-area
median error fell from 0.200 m to 0.070 m with the simulator's wind switched off, more than any other
source; the receiver carried the wind only as a consider parameter. It now estimates the wind and the
sound-speed scale (:mod:`features.acoustic.air`; a scale error alone looks like a wind along the beacons'
mean direction, and estimating the wind without it wandered by metres per second on the training walks).
These tests check the estimator against closed forms and a Monte Carlo truth, independent of the simulator.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from features.acoustic.positions import BeaconRange, PositionConfig, solve_position
from features.acoustic.air import AirState, air_range_corrections_m
from tests.acoustic_synth import C_20C_M_S, square_site

C = C_20C_M_S
SITE = square_site(8)
H = SITE.device_height_m


def _ranges(p, wind, clock_s, rng, sigma=0.05, scale=0.0):
    """Pseudoranges a receiver at ``p`` reads through ``wind`` in air (1 + ``scale``) times faster than it
    thinks (travel time r / (c(1 + k) + w·n̂), converted with c)."""
    out = []
    for b in SITE.beacons:
        d = np.array([p[0] - b.east_m, p[1] - b.north_m, H - b.up_m])
        r = float(np.linalg.norm(d))
        c_eff = C * (1.0 + scale) + float(np.dot(wind, d[:2])) / r
        rho = C * r / c_eff + C * clock_s + rng.normal(0.0, sigma)
        out.append(BeaconRange(b.id, b.east_m, b.north_m, b.up_m, rho, sigma, 0.0))
    return out


def test_range_correction_is_the_first_order_effective_sound_speed():
    """c·r/(c(1 + k) + w·n̂) = r − (p − s)_h·w/c − k·r to first order: at 20 m, 3 m/s and k = 0.3 % the two
    agree to 0.2 mm."""
    p, s, w, k = np.array([17.0, 9.0]), np.array([[3.0, -4.0, 3.0]]), np.array([2.0, -2.2]), 0.003
    d = np.array([p[0] - 3.0, p[1] + 4.0, H - 3.0])
    r = float(np.linalg.norm(d))
    exact = r - C * r / (C * (1 + k) + float(w @ d[:2]) / r)
    assert air_range_corrections_m(w, k, p, s, H, C)[0] == pytest.approx(exact, abs=2e-4)


def _walk(wind, rng, n_fixes=60, estimate=True, scale=0.0):
    """A receiver walking a loop inside the 8-beacon square; each fix solved with the clock free, its
    ranges corrected by the estimate, then the estimate updated. Returns (state, errors of the fixes)."""
    prior = AirState.prior(0.0, 2.0, 0.003)
    state = prior
    cfg = PositionConfig(air_rel_sigma=0.0, wind_sigma_m_s=0.0, path_rel_sigma=0.0)
    errors = []
    for k in range(n_fixes):
        a = 2 * math.pi * k / 30
        p = (30.0 + 18.0 * math.cos(a), 30.0 + 12.0 * math.sin(a))
        clock = 0.004 + 1e-6 * k
        ranges = _ranges(p, wind, clock, rng, scale=scale)
        state = state.predict(float(k), prior)
        if estimate:
            corr = air_range_corrections_m(state.x[:2], state.x[2], p,
                                           [(r.east_m, r.north_m, r.up_m) for r in ranges], H, C)
            ranges = [r._replace(pseudorange_m=r.pseudorange_m + c_) for r, c_ in zip(ranges, corr)]
        fix = solve_position(ranges, SITE, C, cfg, np.array([p[0], p[1], clock]))
        x = np.array([fix.east_m, fix.north_m, fix.clock_offset_s])
        if estimate:
            state, dx = state.update(fix.ranges, x, H, C, None)
            x = x + np.array(dx)
        errors.append(math.hypot(x[0] - p[0], x[1] - p[1]))
    return state, np.array(errors)


def test_a_steady_wind_and_a_thermometer_error_are_estimated_and_their_bias_removed():
    """A 3 m/s wind from the south-west in air 0.4 % faster than the thermometer says (−2.3 K): after 60
    fixes round a loop the wind is within 0.3 m/s per axis, the scale within 0.05 %, both within 3σ of
    their own covariance; the last 30 fixes stand a median under 4 cm off — the ranging noise's own floor
    (HDOP ~0.8 × 5 cm) — against 8+ cm with the air ignored (the wind shifts every fix downwind by about
    the mean range × w/c)."""
    wind, scale = np.array([2.1, 2.1]), 0.004
    state, err = _walk(wind, np.random.default_rng(1), scale=scale)
    truth = np.array([*wind, scale])
    e = state.x - truth
    assert np.abs(e[:2]).max() < 0.3 and abs(e[2]) < 5e-4
    assert float(e @ np.linalg.solve(state.p, e)) < 14.2                            # χ²₃ 0.997
    _, err_off = _walk(wind, np.random.default_rng(1), estimate=False, scale=scale)
    assert np.median(err[30:]) < 0.04
    assert np.median(err_off[30:]) > 0.08


def test_the_estimate_is_consistent_and_unbiased_over_many_airs(monkeypatch):
    """Monte Carlo: 40 random steady winds (|w| ≤ 4 m/s) and scales (σ 0.3 %), the random walks' growth set to
    0 (the truth has none) and each fix's information counted whole (``UPDATE_WEIGHT`` 1: these range errors
    are white, not persistent as on a walk): the estimate's NEES after 40 fixes has mean 3 ± 1 (3 degrees of
    freedom) and its mean error is within 0.1 m/s and 0.01 % of zero."""
    import features.acoustic.air as air_module

    monkeypatch.setattr(air_module, "UPDATE_WEIGHT", 1.0)
    monkeypatch.setattr(air_module, "WIND_RANDOM_WALK_M2_S3", 0.0)
    monkeypatch.setattr(air_module, "SCALE_RANDOM_WALK_PER_S", 0.0)
    rng = np.random.default_rng(7)
    nees, errs = [], []
    for _ in range(40):
        speed, direction = rng.uniform(0, 4), rng.uniform(0, 2 * math.pi)
        wind = speed * np.array([math.sin(direction), math.cos(direction)])
        scale = rng.normal(0.0, 0.003)
        state, _ = _walk(wind, rng, n_fixes=40, scale=scale)
        e = state.x - np.array([*wind, scale])
        nees.append(float(e @ np.linalg.solve(state.p, e)))
        errs.append(e)
    assert 2.0 < np.mean(nees) < 4.0
    m = np.mean(errs, axis=0)
    assert np.all(np.abs(m[:2]) < 0.1) and abs(m[2]) < 1e-4


def test_a_fix_that_contradicts_the_estimate_is_gated():
    """Once the wind is known to ±0.2 m/s, a fix whose 1 cm ranges imply 10 m/s more leaves it unchanged (the
    fix solved with its residual test switched off, as an NLOS range that passed it would have been), while
    the same fix through the true wind updates it."""
    state = AirState(0.0, np.array([1.0, 0.0, 0.0]), np.diag([0.04, 0.04, 1e-6]))
    p = (20.0, 35.0)
    cfg = PositionConfig(air_rel_sigma=0.0, wind_sigma_m_s=0.0, path_rel_sigma=0.0, chi2_alpha=1e-300)
    ranges = _ranges(p, np.array([1.0, 0.0]), 0.0, np.random.default_rng(3), sigma=0.01)
    fix = solve_position(ranges, SITE, C, cfg, np.array([p[0], p[1], 0.0]))
    new, _ = state.update(fix.ranges, np.array([fix.east_m, fix.north_m, fix.clock_offset_s]), H, C, None)
    assert new.p[0, 0] < state.p[0, 0]
    ranges = _ranges(p, np.array([11.0, 0.0]), 0.0, np.random.default_rng(3), sigma=0.01)
    fix = solve_position(ranges, SITE, C, cfg, np.array([p[0], p[1], 0.0]))
    new, dx = state.update(fix.ranges, np.array([fix.east_m, fix.north_m, fix.clock_offset_s]), H, C, None)
    assert new is state and dx == (0.0, 0.0, 0.0)
