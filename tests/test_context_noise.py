"""Issue 22: the error model in context — Gauss–Markov bias states, ε-contamination, consider states.

References are closed forms (an AR(1) process's autocovariance, a two-exponential mixture's parameters) and
computations written here from the equations (a two-component Gaussian sum collapsed by moments).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from models.fusion import ClassTrack, EkfConfig, EventEKF, FixedNoise, GnssEvents, merge_events, nees
from models.fusion.context import BIASED_QUALITIES, ContextNoise, ErrorSeries, fit_contamination, fit_gauss_markov
from models.fusion.core import MIXTURE, MIXTURE_DROP, kalman_update, mixture_update
from tests.fusion_synth import synth_walk


def _gm_series(rng, n, dt, sigma_b, tau, sigma_w, quality=5):
    """e = b + w at a fixed rate: b an exact discrete AR(1) of stationary σ_b and time constant τ."""
    phi = math.exp(-dt / tau)
    b = np.zeros((n, 2))
    b[0] = rng.normal(0, sigma_b, 2)
    for k in range(1, n):
        b[k] = phi * b[k - 1] + rng.normal(0, sigma_b * math.sqrt(1 - phi * phi), 2)
    e = b + rng.normal(0, sigma_w, (n, 2))
    t = np.arange(n) * dt
    return ErrorSeries(t, e, np.broadcast_to(np.eye(2) * sigma_w ** 2, (n, 2, 2)), np.full(n, quality),
                       np.zeros(n, int))


def test_gauss_markov_fit_recovers_sigma_and_tau():
    """C(τ) = σ_b² e^(−τ/T) for τ > 0 (Gelb 1974 §3.8): 10 walks of 20 min at 5 Hz, σ_b 0.4 m, T 20 s, white
    0.15 m. A white series (σ_b = 0) gives no bias."""
    rng = np.random.default_rng(1)
    series = [_gm_series(rng, 6000, 0.2, 0.4, 20.0, 0.15) for _ in range(10)]
    sb2, tau, c0, n = fit_gauss_markov(series, lambda s: np.ones(len(s.t_s), bool))
    assert n == 60000
    assert abs(c0 / (0.4 ** 2 + 0.15 ** 2) - 1) < 0.1
    assert abs(sb2 / 0.16 - 1) < 0.15                         # measured 1.00
    assert abs(tau / 20.0 - 1) < 0.2
    white = [ErrorSeries(s.t_s, rng.normal(0, 0.3, s.err_m.shape), s.cov_m2, s.quality, s.cls) for s in series]
    sb2w, _, c0w, _ = fit_gauss_markov(white, lambda s: np.ones(len(s.t_s), bool))
    assert sb2w < 0.01 * c0w
    # pairs never cross a quality change: two halves of a series of different qualities, each its own bias
    s = series[0]
    halves = ErrorSeries(s.t_s, s.err_m, s.cov_m2, np.where(np.arange(len(s.t_s)) < 3000, 5, 2), s.cls)
    assert fit_gauss_markov([halves], lambda x: x.quality == 2)[3] == 3000


def test_contamination_em_recovers_the_mixture():
    rng = np.random.default_rng(2)
    u = np.concatenate([rng.exponential(0.7, 19000), rng.exponential(0.7 * 40, 1000)])
    s2, eps, kappa = fit_contamination(u)
    assert abs(s2 / 0.7 - 1) < 0.05 and abs(eps / 0.05 - 1) < 0.15 and abs(kappa / 40 - 1) < 0.15
    s2, eps, kappa = fit_contamination(rng.exponential(1.0, 20000))
    assert abs(s2 - 1) < 0.05 and eps < 0.01


def test_mixture_update_is_the_collapsed_gaussian_sum():
    """β and the moments by hand: two Kalman updates (R and κR), their evidences N(ν; 0, S_i) from scipy."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(4, 4))
    P = 0.05 * (A @ A.T + np.eye(4))
    x = rng.normal(size=4)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    R = np.array([[0.5, 0.1], [0.1, 0.3]])
    eps, kappa = 0.1, 30.0
    for z in (x[:2] + [0.3, -0.2], x[:2] + [6.0, 4.0]):            # an inlier-looking and an outlier-looking fix
        xn, Pn, nu, S, K, Ru, nis, w, ok = mixture_update(x, P, z, R, H, eps, kappa, True)
        parts = []
        for r, prior in ((R, 1 - eps), (kappa * R, eps)):
            S_i = H @ P @ H.T + r
            K_i = P @ H.T @ np.linalg.inv(S_i)
            A_i = np.eye(4) - K_i @ H
            parts.append((prior * multivariate_normal(np.zeros(2), S_i).pdf(z - H @ x), x + K_i @ (z - H @ x),
                          A_i @ P @ A_i.T + K_i @ r @ K_i.T))
        beta = parts[1][0] / (parts[0][0] + parts[1][0])
        mean = (1 - beta) * parts[0][1] + beta * parts[1][1]
        cov = sum(wt * (Pi + np.outer(xi - mean, xi - mean)) for wt, (_, xi, Pi) in zip((1 - beta, beta), parts))
        # a component of weight below MIXTURE_DROP (1e-6) is dropped: the moments then agree to that fraction
        assert w == pytest.approx(1 - beta, rel=1e-9, abs=MIXTURE_DROP)
        scale = np.abs(parts[0][1] - parts[1][1]).max() ** 2 + np.abs(parts[0][2] - parts[1][2]).max()
        np.testing.assert_allclose(xn, mean, atol=1e-10 + MIXTURE_DROP * np.sqrt(scale))
        np.testing.assert_allclose(Pn, cov, atol=1e-10 + MIXTURE_DROP * scale)
    assert w < 0.01                                                  # the 7 m fix is judged an outlier


def test_consider_states_are_never_estimated_but_counted():
    """Schmidt–Kalman: the consider rows of K are zero and P is the Joseph form with that gain."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(6, 6))
    P = A @ A.T + np.eye(6)
    x = rng.normal(size=6)
    H = np.zeros((2, 6))
    H[0, 0] = H[1, 1] = H[0, 4] = H[1, 5] = 1.0
    R = np.eye(2) * 0.2
    z = np.array([1.0, -1.0])
    consider = np.array([False] * 4 + [True] * 2)
    xn, Pn, nu, S, K, *_ = kalman_update(x, P, z, R, H, 2, 0.0, 1.0, True, consider)
    K_opt = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    K_s = K_opt.copy()
    K_s[4:] = 0.0                                                    # the optimal gain with the consider rows cut
    A_s = np.eye(6) - K_s @ H
    np.testing.assert_allclose(K, K_s, atol=1e-12)
    np.testing.assert_allclose(xn, x + K_s @ (z - H @ x), atol=1e-12)
    np.testing.assert_allclose(Pn, A_s @ P @ A_s.T + K_s @ R @ K_s.T, atol=1e-10)
    np.testing.assert_allclose(xn[4:], x[4:])


def _context_fit(stream_synth, n_classes=1, **kw):
    s = stream_synth
    g = s.stream.kind == 1
    e = s.stream.z_m[g] - s.truth[g, :2]
    series = [ErrorSeries(s.stream.t_s[g], e, s.stream.cov_m2[g], s.gnss.quality[s.stream.index[g]],
                          np.zeros(g.sum(), int))]
    a = s.stream.kind == 2
    ac = [ErrorSeries(s.stream.t_s[a], s.stream.z_m[a] - s.truth[a, :2], s.stream.cov_m2[a],
                      np.zeros(a.sum(), int), np.zeros(a.sum(), int))]
    return ContextNoise(n_classes=n_classes, **kw).fit(series, ac)


def test_bias_states_reset_on_quality_change_and_gap():
    t = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 12.0, 13.0, 14.0])
    q = np.array([5, 5, 4, 4, 5, 5, 2, 2])
    g = GnssEvents.from_sigma(t, np.zeros(8), np.zeros(8), np.ones(8), quality=q)
    ev = merge_events(gnss=g)
    cn = ContextNoise(n_classes=1, reset_gap_s=5.0, biased_qualities=(2, 4, 5))
    cn.gnss_ = {(0, 5): {"s2": 1.0, "eps": 0.0, "kappa": 1.0, "sb2": 0.25, "tau_s": 10.0},
                (0, 2): {"s2": 1.0, "eps": 0.0, "kappa": 1.0, "sb2": 1.0, "tau_s": 40.0},
                (0, 4): {"s2": 1.0, "eps": 0.0, "kappa": 1.0, "sb2": 0.0, "tau_s": 1.0}}
    cn.acoustic_ = {-1: {"s2": 1.0, "eps": 0.0, "kappa": 1.0}}
    spec = cn.measurement_noise(ev)
    assert spec.bias_shared.tolist() == [True] * 8
    # resets: the first fix, fixed after float (t = 2), float after fixed (t = 4), after the 8 s gap (t = 12),
    # DGNSS after float (t = 13): each run of one quality has its own bias, of that quality's prior variance
    assert np.flatnonzero(spec.bias_phi == 0).tolist() == [0, 2, 4, 5, 6]
    # (σ_b² = 0 of the fixed run is floored at 1e-8 m², so P stays positive definite: issue 24)
    np.testing.assert_allclose(spec.bias_q[[0, 2, 4, 5, 6]], [0.25, 1e-8, 0.25, 0.25, 1.0])
    # between: φ = e^(−Δt/τ) of the regime in force, Q = σ_b²(1 − φ²)
    assert spec.bias_phi[1] == pytest.approx(math.exp(-0.1)) and spec.bias_phi[7] == pytest.approx(math.exp(-1 / 40))
    assert spec.bias_q[7] == pytest.approx(1.0 * (1 - math.exp(-2 / 40)))
    assert spec.bias_phi[3] == pytest.approx(math.exp(-1.0))
    assert spec.bias_q[3] == pytest.approx(1e-8 * (1 - math.exp(-2.0)), rel=1e-9)     # the floored σ_b²


def test_bias_states_win_on_correlated_float_errors():
    """Float fixes with a 0.5 m bias of τ 40 s over 0.1 m white noise, acoustic fixes 0.3 m every 2 s: the
    fitted bias model keeps the filter on the acoustic fixes and consistent; one white R does neither."""
    train = synth_walk(31, duration_s=900, gnss_sigma_m=0.1, bias_sigma_m=0.5, bias_tau_s=40.0, acoustic_hz=0.5,
                       gnss_quality=lambda t: np.full(np.shape(t), 5))
    cn = _context_fit(train, mixture=False)
    fitted = cn.gnss_[(0, 5)]
    assert abs(math.sqrt(fitted["sb2"]) / 0.5 - 1) < 0.25 and 20 < fitted["tau_s"] < 80
    test = synth_walk(32, duration_s=600, gnss_sigma_m=0.1, bias_sigma_m=0.5, bias_tau_s=40.0, acoustic_hz=0.5,
                      gnss_quality=lambda t: np.full(np.shape(t), 5))
    kw = dict(x0=test.x0, P0=test.P0)
    white = EventEKF(EkfConfig(outlier="none"), FixedNoise(math.sqrt(0.01 + 0.25), 0.3)).run(test.stream, **kw)
    x6, P6 = np.concatenate([test.x0, [0, 0]]), np.diag(np.concatenate([np.diag(test.P0), [0.25, 0.25]]))
    biased = EventEKF(EkfConfig(outlier="none"), cn).run(test.stream, x0=x6, P0=P6)
    err = lambda r: np.sqrt(np.mean(np.sum((r.x[:, :2] - test.truth[:, :2]) ** 2, axis=1)))   # noqa: E731
    assert biased.x.shape[1] == 6
    assert err(biased) < 0.75 * err(white)                            # measured 0.18 vs 0.31 m
    inb = lambda r: np.mean((nees(r.x, r.P, test.truth) > 0.0506) & (nees(r.x, r.P, test.truth) < 7.378))  # noqa
    assert inb(biased) > 0.85 and inb(biased) > inb(white) + 0.1
    considered = EventEKF(EkfConfig(outlier="none", consider_bias=True), cn).run(test.stream, x0=x6, P0=P6)
    assert np.all(considered.x[:, 4:] == 0.0)                         # never estimated
    assert err(considered) < err(white)


def test_class_contamination_distrusts_fixes_where_the_class_says_so():
    """RTK-fixed fixes 1 cm good in the open; under occlusion (alternate minutes) half of each minute's 10 s
    blocks hold a wrong fix, a constant 1.2 m offset per block (a wrong integer stays wrong until lock is lost).
    Fitted per class, the filter distrusts fixed fixes under occlusion and keeps to the 0.2 m acoustic fixes;
    the blind twin (the same machinery, one class) trusts every fixed fix alike."""
    rng = np.random.default_rng(7)
    heavy = lambda t: (np.asarray(t) // 60) % 2 == 1                          # noqa: E731 (alternate minutes)

    def walk(seed):
        s = synth_walk(seed, duration_s=600, gnss_sigma_m=0.01, acoustic_hz=1.25, acoustic_sigma_m=0.2,
                       gnss_quality=lambda t: np.full(np.shape(t), 4))
        g = np.flatnonzero(s.stream.kind == 1)
        block = (s.stream.t_s[g] // 10).astype(int)
        offsets = rng.normal(0, 1.2 / math.sqrt(2), (block.max() + 1, 2)) * (rng.random(block.max() + 1) < 0.5)[:, None]
        s.stream.z_m[g] += np.where(heavy(s.stream.t_s[g])[:, None], offsets[block], 0.0)
        cls = heavy(s.stream.t_s).astype(int) * 2
        return s, ClassTrack(s.stream.t_s, np.eye(3)[cls])
    def series(s, track):
        out = []
        for code, quality in ((1, 4), (2, 0)):
            sel = s.stream.kind == code
            out.append([ErrorSeries(s.stream.t_s[sel], s.stream.z_m[sel] - s.truth[sel, :2],
                                    s.stream.cov_m2[sel], np.full(sel.sum(), quality),
                                    track.at(s.stream.t_s[sel]).argmax(1))])
        return out

    train, tr_cls = walk(41)
    g, a = series(train, tr_cls)
    # wrong fixes here are frequent and long: the fixed runs get a bias state too
    aware = ContextNoise(n_classes=3, min_samples=50, biased_qualities=BIASED_QUALITIES + (4,)).fit(g, a)
    blind = ContextNoise(n_classes=1, biased_qualities=BIASED_QUALITIES + (4,)).fit(g, a)
    test, te_cls = walk(42)
    cfg = EkfConfig(outlier="mixture")
    ra = EventEKF(cfg, aware).run(test.stream, classes=te_cls, x0_en=test.x0[:2])
    rb = EventEKF(cfg, blind).run(test.stream, x0_en=test.x0[:2])
    late = test.stream.t_s > 30
    occluded = heavy(test.stream.t_s)

    def err(r, sel):
        return float(np.sqrt(np.mean(np.sum((r.x[sel, :2] - test.truth[sel, :2]) ** 2, axis=1))))
    # measured: open minutes 0.033 vs 0.133 m (the blind twin distrusts good fixes everywhere, as it must for
    # the bad ones); occluded minutes 0.160 vs 0.175 m
    assert err(ra, late & ~occluded) < 0.5 * err(rb, late & ~occluded)
    assert err(ra, late & occluded) < err(rb, late & occluded)
    assert aware.gnss_[(0, 4)]["sb2"] < 1e-4 < 0.1 < aware.gnss_[(2, 4)]["sb2"]
    assert MIXTURE == 3 and set(BIASED_QUALITIES) == {1, 2, 5, 6}
