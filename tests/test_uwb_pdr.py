"""models.uwb_pdr (Zhou et al. 2025 UWB AOA + PDR): a hand-worked update, filterpy as the reference, the gain's
sign, and the method on a simulated walk (better than PDR alone; skipped without uwb.csv)."""

import math
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from features.uwb.position import UwbFixes
from models.fusion.events import STEP
from models.uwb_pdr import UWB_FIX, UwbPdrConfig, UwbPdrFilter, pdr_track_at


def _fixes(t, e, n, var):
    k = len(t)
    return UwbFixes(t_s=np.asarray(t, float), east_m=np.asarray(e, float), north_m=np.asarray(n, float),
                    cov_en=np.eye(2)[None] * np.asarray(var, float)[:, None, None], n_anchors=np.full(k, 3),
                    used_aoa=np.zeros(k, bool), rms_residual=np.full(k, np.nan), n_rounds=k)


def _steps(t, L, psi, start=(0.0, 0.0)):
    t, L, psi = (np.asarray(v, float) for v in (t, L, psi))
    e = start[0] + np.cumsum(L * np.sin(psi))
    n = start[1] + np.cumsum(L * np.cos(psi))
    return SimpleNamespace(t_s=t, step_length_m=L, heading_rad=psi, east_m=e, north_m=n)


def test_one_update_by_hand():
    # PDR stands at (0, 0); UWB fix 0 at (0, 0) (R = I) starts the filter: δx = 0, P = I. Fix 1 at (2, 0), R = I,
    # q = 0: z = p_PDR − p_UWB = (−2, 0), S = 2I, K = I/2, δx = (−1, 0), p̂ = p_PDR − δx = (1, 0), P = I/2.
    run = UwbPdrFilter(UwbPdrConfig(q_m2_s=0.0, outlier="none")).run(
        _steps([], [], []), (0.0, 0.0), _fixes([0.0, 1.0], [0.0, 2.0], [0.0, 0.0], [1.0, 1.0]))
    assert list(run.kind) == [UWB_FIX, UWB_FIX]
    np.testing.assert_allclose(run.x[-1], [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(run.P[-1], 0.5 * np.eye(2), atol=1e-12)
    np.testing.assert_allclose(run.nu[-1], [2.0, 0.0], atol=1e-12)     # the position's innovation p_UWB − p̂⁻
    np.testing.assert_allclose(run.K[-1], 0.5 * np.eye(2), atol=1e-12)


def test_step_noise_is_along_and_across_track():
    # one step east (ψ = 90°), L = 1: P⁻ = P + σ_L²·g g' + (L σ_ψ)²·h h', g = (1, 0), h = (0, −1); the step
    # (a first step lasts models.uwb_pdr.STEP_S = 0.55 s) ends at 0.6 s, so it starts after fix 0
    cfg = UwbPdrConfig(sigma_step_length_m=0.1, sigma_heading_rad=0.2, q_m2_s=0.0, outlier="none")
    run = UwbPdrFilter(cfg).run(_steps([0.6], [1.0], [math.pi / 2]), (0.0, 0.0),
                                _fixes([0.0, 1.0], [0.0, 1.0], [0.0, 0.0], [1.0, 1.0]))
    assert list(run.kind) == [UWB_FIX, STEP, UWB_FIX]
    np.testing.assert_allclose(run.P_prior[1], np.diag([1.0 + 0.01, 1.0 + 0.04]), atol=1e-12)
    np.testing.assert_allclose(run.x_prior[1], [1.0, 0.0], atol=1e-12)    # the PDR moved the estimate 1 m east


def _drifting_walk(seed=0, n_steps=400, bias_deg=2.0, uwb_sigma=0.3):
    rng = np.random.default_rng(seed)
    t = 0.5 * np.arange(1, n_steps + 1)
    psi_true = np.radians(30.0) + 0.3 * np.sin(t / 20.0)
    L = np.full(n_steps, 0.7)
    truth = _steps(t, L, psi_true)
    pdr = _steps(t, L * 1.04, psi_true + np.radians(bias_deg) + rng.normal(0, 0.01, n_steps))
    tf = np.arange(0.0, t[-1], 0.25)
    te, tn = pdr_track_at(tf, t, truth.east_m, truth.north_m, (0.0, 0.0))
    fixes = _fixes(tf, te + rng.normal(0, uwb_sigma, tf.size), tn + rng.normal(0, uwb_sigma, tf.size),
                   np.full(tf.size, uwb_sigma ** 2))
    return truth, pdr, fixes


def test_fused_beats_pdr_and_uwb_and_matches_filterpy():
    truth, pdr, fixes = _drifting_walk()
    cfg = UwbPdrConfig(outlier="none")
    run = UwbPdrFilter(cfg).run(pdr, (0.0, 0.0), fixes)
    te, tn = pdr_track_at(run.t_s, truth.t_s, truth.east_m, truth.north_m, (0.0, 0.0))
    fused = np.sqrt(np.mean((run.x[:, 0] - te) ** 2 + (run.x[:, 1] - tn) ** 2))
    pe, pn = pdr_track_at(run.t_s, pdr.t_s, pdr.east_m, pdr.north_m, (0.0, 0.0))
    pdr_rms = np.sqrt(np.mean((pe - te) ** 2 + (pn - tn) ** 2))
    uwb_rms = 0.3 * math.sqrt(2.0)
    assert pdr_rms > 5.0 and fused < 0.8 * uwb_rms
    # a gain of the wrong sign (p̂ = p_PDR + δx) would land ≈ 2·|δx| ≈ 2× the PDR error away
    flipped = np.sqrt(np.mean((2 * pe - run.x[:, 0] - te) ** 2 + (2 * pn - run.x[:, 1] - tn) ** 2))
    assert flipped > pdr_rms
    # filterpy: the same error-state model (F = I, Q per step and per second, H = I, z = p_PDR − p_UWB)
    kf = KalmanFilter(dim_x=2, dim_z=2)
    kf.x = np.array([pe[0] - fixes.east_m[0], pn[0] - fixes.north_m[0]])
    kf.P = fixes.cov_en[0].copy()
    kf.F, kf.H = np.eye(2), np.eye(2)
    t_prev, out = run.t_s[0], []
    for k in range(len(run.t_s)):
        Q = np.eye(2) * cfg.q_m2_s * (run.t_s[k] - t_prev)
        t_prev = run.t_s[k]
        if run.kind[k] == STEP:
            i = int(np.searchsorted(pdr.t_s, run.t_s[k]))
            psi, L = pdr.heading_rad[i], pdr.step_length_m[i]
            g, h = np.array([math.sin(psi), math.cos(psi)]), np.array([math.cos(psi), -math.sin(psi)])
            Q = Q + cfg.sigma_step_length_m ** 2 * np.outer(g, g) + (L * cfg.sigma_heading_rad) ** 2 * np.outer(h, h)
        kf.predict(Q=Q)
        if run.kind[k] == UWB_FIX and k > 0:
            j = int(np.searchsorted(fixes.t_s, run.t_s[k]))
            kf.update(np.array([pe[k] - fixes.east_m[j], pn[k] - fixes.north_m[j]]), R=fixes.cov_en[j])
        out.append(np.array([pe[k], pn[k]]) - kf.x)
    np.testing.assert_allclose(run.x, np.array(out), atol=1e-9)


def test_gate_restarts_after_a_run_of_rejections():
    truth, pdr, fixes = _drifting_walk(bias_deg=15.0, uwb_sigma=0.05)
    tight = UwbPdrConfig(sigma_heading_rad=math.radians(0.1), sigma_step_length_m=0.005, q_m2_s=0.0)
    locked = UwbPdrFilter(UwbPdrConfig(**{**tight.__dict__, "reset_after": 0})).run(pdr, (0.0, 0.0), fixes)
    kept = UwbPdrFilter(tight).run(pdr, (0.0, 0.0), fixes)
    err = []
    for run in (locked, kept):
        te, tn = pdr_track_at(run.t_s, truth.t_s, truth.east_m, truth.north_m, (0.0, 0.0))
        err.append(np.median(np.hypot(run.x[:, 0] - te, run.x[:, 1] - tn)))
    assert kept.info["n_resets"] > 0 and err[1] < 1.0 and err[0] > 5.0 * err[1], err


def test_method_on_a_simulated_walk_and_skipped_without_uwb(walk_dir, tmp_path):
    from walks.methods import MethodContext, MethodSkipped, method
    from walks.reader import read_walk

    data = read_walk(walk_dir)
    assert data.uwb is not None and len(data.uwb.fixes) > 100
    ctx = MethodContext(model=None, inputs=SimpleNamespace(data=data))
    run = method("uwb_aoa_pdr").build(ctx)
    te, tn = data.truth.at(run.t_s)
    fused = np.median(np.hypot(run.x[:, 0] - te, run.x[:, 1] - tn))
    r = data.pdr.result
    pe, pn = data.truth.at(r.t_s)
    pdr = np.median(np.hypot(r.east_m - pe, r.north_m - pn))
    assert fused < 1.0 and fused < 0.25 * pdr
    # the same walk without uwb.csv: read as before, the method skipped with its reason
    bare = tmp_path / "bare"
    shutil.copytree(walk_dir, bare)
    (bare / "uwb.csv").unlink()
    old = read_walk(bare)
    assert old.uwb is None and old.pdr is not None and any("uwb" in n for n in old.notes)
    with pytest.raises(MethodSkipped, match="no UWB"):
        method("uwb_aoa_pdr").build(MethodContext(model=None, inputs=SimpleNamespace(data=old)))


def test_noise_prior_by_hand_and_its_twin():
    from models.uwb_pdr import UwbNoisePrior, uwb_nees

    # eᵀC⁻¹e by hand: e = (1, 2), C = diag(1, 4) → 1 + 1 = 2
    assert uwb_nees([[1.0, 2.0]], [np.diag([1.0, 4.0])])[0] == pytest.approx(2.0)
    # class 0: NEES 2 (χ²₂ mean 2: scale 1), class 1: NEES 10 (scale 5), class 2: 5 fixes only → the pooled
    # scale (30·2 + 30·10 + 5·40) / 65 / 2 = 560 / 130 = 4.3077
    nees = np.r_[np.full(30, 2.0), np.full(30, 10.0), np.full(5, 40.0)]
    cls = np.r_[np.zeros(30, int), np.ones(30, int), np.full(5, 2)]
    prior = UwbNoisePrior(3).fit(nees, cls)
    np.testing.assert_allclose(prior.scale_, [1.0, 5.0, 560.0 / 130.0])
    np.testing.assert_allclose(prior.r_scale([[0.5, 0.5, 0.0], [0.0, 0.0, 1.0]]), [3.0, 560.0 / 130.0])
    blind = UwbNoisePrior(1).fit(nees, cls)
    np.testing.assert_allclose(blind.r_scale(np.ones((2, 1))), [560.0 / 130.0] * 2)
    assert UwbNoisePrior(3).fit(np.full(40, 0.5), np.zeros(40, int)).scale_[0] == 1.0     # floored at 1
    back = UwbNoisePrior.from_state(prior.get_state())
    np.testing.assert_array_equal(back.scale_, prior.scale_)
    with pytest.raises(ValueError, match=">= 1"):
        UwbNoisePrior.from_state({"n_classes": 3, "estimator": "mean", "scale": [1.0, 0.2, 2.0]})


def test_prior_scales_each_fix_covariance_in_the_filter():
    truth, pdr, fixes = _drifting_walk()
    plain = UwbPdrFilter(UwbPdrConfig(outlier="none")).run(pdr, (0.0, 0.0), fixes)
    scaled = UwbPdrFilter(UwbPdrConfig(outlier="none")).run(pdr, (0.0, 0.0), fixes, r_scale=np.full(len(fixes), 4.0))
    u = scaled.updated
    np.testing.assert_allclose(scaled.R[u], 4.0 * plain.R[u])
    assert np.trace(scaled.P[-1]) > np.trace(plain.P[-1])


@pytest.mark.parametrize("gap_s", [0.0, 6.0])
def test_a_resumed_run_fuses_the_cuts_first_fix_and_the_steps_before_it(gap_s):
    """A long walk's cut resumed at t_s = 50 s from the whole run's state there (a segment's hand-over). Its
    first UWB fix lies ``gap_s`` after t_s (6 s: the cut's warm-up held no fix, a UWB gap). From t_s on the
    cut's run must be the whole run's, event for event, to round-off; before, the cut's first fix was taken as
    a fresh start (never fused) and the steps before it were dropped (0.055 m on a simulated walk)."""
    truth, pdr, fixes = _drifting_walk(seed=3)
    t_cut = 50.0
    far = (fixes.t_s < t_cut) | (fixes.t_s >= t_cut + gap_s)        # the whole walk's UWB gap after t_cut
    whole_fixes = _fixes(fixes.t_s[far], fixes.east_m[far], fixes.north_m[far], fixes.cov_en[far, 0, 0])
    cfg = UwbPdrConfig()
    whole = UwbPdrFilter(cfg).run(pdr, (0.0, 0.0), whole_fixes)
    resume = whole.state_before(t_cut)
    # the cut: its PDR track starts elsewhere (only increments enter), its fixes from 40 s or the gap's end
    lo = t_cut - 10.0 if gap_s == 0 else t_cut
    keep = whole_fixes.t_s >= lo
    cut_fixes = _fixes(whole_fixes.t_s[keep], whole_fixes.east_m[keep], whole_fixes.north_m[keep],
                       whole_fixes.cov_en[keep, 0, 0])
    s = pdr.t_s > lo - 5.0
    cut_steps = _steps(pdr.t_s[s], pdr.step_length_m[s], pdr.heading_rad[s], start=(3.0, -2.0))
    cut = UwbPdrFilter(cfg).run(cut_steps, (3.0, -2.0), cut_fixes, resume=resume)
    a = whole.t_s >= t_cut
    b = cut.t_s >= t_cut
    assert gap_s == 0 or cut_fixes.t_s[0] > t_cut
    np.testing.assert_array_equal(cut.t_s[b], whole.t_s[a])
    np.testing.assert_array_equal(cut.kind[b], whole.kind[a])
    # positions: the cut's PDR track is offset by a constant, which δx absorbs
    np.testing.assert_allclose(cut.x[b], whole.x[a], atol=1e-9)
    np.testing.assert_allclose(cut.P[b], whole.P[a], atol=1e-12)
    assert int(cut.updated[b].sum()) == int(whole.updated[a].sum())
