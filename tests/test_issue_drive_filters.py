"""Issue 24: what a drive exposed in the filters — a GGA quality the context model never saw, and steps with their
own noise."""

from __future__ import annotations

import numpy as np
import pytest

from models.fusion import EventEKF, GnssEvents, StepEvents, merge_events, rts_smooth
from models.fusion.context import ContextNoise, ErrorSeries
from models.fusion.ekf import EkfConfig


def _stream(quality: int, step_sigma=None):
    t_step = np.arange(1, 41) * 0.3
    steps = StepEvents(t_step, np.full(40, 2.0), np.full(40, 0.3),
                       *(() if step_sigma is None else (np.full(40, step_sigma[0]), np.full(40, step_sigma[1]))))
    tg = np.arange(0, 41) * 0.3
    rng = np.random.default_rng(0)
    e = 2.0 * np.sin(0.3) * np.arange(41) + rng.normal(0, 3, 41)
    n = 2.0 * np.cos(0.3) * np.arange(41) + rng.normal(0, 3, 41)
    return merge_events(steps=steps, gnss=GnssEvents.from_sigma(tg, e, n, np.full(41, 3.0),
                                                                quality=np.full(41, quality)))


def test_a_quality_unseen_in_training_keeps_the_covariance_positive_definite():
    """A model trained on RTK walks (quality 4) meets a drive's autonomous fixes (quality 1): its bias states were
    reset to zero variance, P became singular and the RTS smoother's gain solve raised LinAlgError (an internal
    error of ``envfuse evaluate``). With the floor the bias variance is 1e-8 m² and the run smooths."""
    rng = np.random.default_rng(1)
    t = np.arange(300) * 0.2
    series = ErrorSeries(t, rng.normal(0, 0.02, (300, 2)), np.tile(np.eye(2) * 4e-4, (300, 1, 1)),
                         np.full(300, 4), np.zeros(300, int))
    ctx = ContextNoise(n_classes=1).fit([series], [])
    assert (0, 1) not in ctx.gnss_
    ev = _stream(quality=1)
    run = EventEKF(EkfConfig(outlier="mixture"), ctx, "adaptive_nobp_blind").run(ev)
    assert run.P.shape[1] == 6
    assert np.all(np.linalg.eigvalsh(run.P_prior)[:, 0] > 0)
    assert run.P_prior[-1, 4, 4] == pytest.approx(1e-8, rel=0.05)
    sm = rts_smooth(run)
    assert np.all(np.isfinite(sm.x))


def test_steps_with_their_own_sigma_drive_the_step_noise():
    """A stream whose steps state σ_L, σ_ψ runs exactly as the configured filter with those σ (the core takes one
    value per run: their mean square), and not as the walker's defaults."""
    from models.fusion.noise import FixedNoise

    noise = FixedNoise(3.0, 1.0)
    own = EventEKF(EkfConfig(), noise).run(_stream(1, (0.01, 0.002)))
    cfg = EventEKF(EkfConfig(sigma_step_length_m=0.01, sigma_heading_rad=0.002), noise).run(_stream(1))
    default = EventEKF(EkfConfig(), noise).run(_stream(1))
    np.testing.assert_allclose(own.P_prior, cfg.P_prior, rtol=1e-12, atol=0)
    assert not np.allclose(own.P_prior, default.P_prior)
    # one step's added noise by hand at the first step (state heading offset 0, scale 0, θ = 0.3):
    # Q = G diag(σ_L², σ_ψ²) G',  G = [[sin θ, L cos θ], [cos θ, −L sin θ]]
    k = int(np.flatnonzero(own.kind == 0)[0])
    prev_P = own.P[k - 1]
    F = own.F[k]
    th, L = 0.3, 2.0
    G = np.array([[np.sin(th), L * np.cos(th)], [np.cos(th), -L * np.sin(th)]])
    Q = G @ np.diag([0.01 ** 2, 0.002 ** 2]) @ G.T
    dt = own.t_s[k] - own.t_s[k - 1]
    expect = F @ (prev_P + np.diag([1e-3 * dt, 1e-3 * dt, 1e-6 * dt, 1e-7 * dt])) @ F.T
    expect[:2, :2] += Q
    np.testing.assert_allclose(own.P_prior[k], expect, rtol=1e-9, atol=1e-15)
