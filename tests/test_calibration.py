"""Realism cannot quietly regress (issue 10 item 8): the calibration report's figures inside their bands.

Runs ``bench/calibrate_sim.py``'s GNSS part on three sites nobody tuned on (seeds 31–33), two 300 s walks each,
and a 15 m survey of sites 31 and 32. The bands are the real figures where one exists (DESIGN.md §6: smartLoc
C/N0, the gpsd logs' untracked share) and otherwise the measured value of this simulator with room for
seed-to-seed spread (measured 2026-12-01, in comments) — the point is that a change that makes RTK an
oracle again, whitens the errors or leaks truth into RMC lands outside them. Every band is two-sided.
"""

import importlib.util

import numpy as np
import pytest

from tests.conftest import REPO


def _bench():
    spec = importlib.util.spec_from_file_location("calibrate_sim", REPO / "bench" / "calibrate_sim.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def figures():
    cs = _bench()
    with np.errstate(all="ignore"):
        g = cs.gnss_walk_figures([31, 32, 33], [1, 2], 300.0)
        sv = cs.survey_figures([31, 32], cell_size_m=15.0, capture_s=15.0)
    return g, sv


def test_rtk_is_not_an_oracle(figures):
    g, _ = figures
    fixed = g["fixed"]
    # measured 0.70 / 0.45 / 0.20 (issue 10 round 2: 20 s single-frequency convergence before a fix; before it, on
    # sites 31-32, 0.69 / 0.46 / 0.30; the old oracle: 0.99 / 0.75 / 0.13, never wrong)
    assert 0.45 <= fixed[0] <= 0.95 and 0.2 <= fixed[1] <= 0.7 and 0.05 <= fixed[2] <= 0.4
    assert fixed[0] > fixed[1] > fixed[2]
    # wrong fixes (q4 > 0.2 m): measured 0 / 6.1 / 4.2 % (one episode each: a few hundred fixed epochs per class
    # here, so the share moves in steps of several %); never in the open
    assert 0.0 <= g["wrong"][0] <= 0.01
    assert 0.0 <= g["wrong"][1] <= 0.12 and 0.0 <= g["wrong"][2] <= 0.15
    assert g["wrong"][1] + g["wrong"][2] > 0.0                     # wrong fixes happen where carriers reflect
    assert 5.0 <= g["refix_median_s"] <= 40.0                      # measured 16 s (was 18 s)


def test_gnss_errors_are_correlated_in_time(figures):
    g, _ = figures
    ac, pairs = g["autocorr"], g["autocorr_pairs"]
    # Pairs within one visit of the class, class mean removed per walk (bench/calibrate_sim.autocorr_sums).
    # measured lag 1 / 5 / 20 s: open +0.96 / +0.82 / +0.08, light +0.91 / +0.46 / -0.06, heavy +0.80 / +0.07 / n/a
    # (369 heavy pairs at 5 s, none at 20 s: no heavy visit of 20 s here; on 30 walks of sites 21-25 light reaches
    # +0.96 / +0.77 / +0.18). Before this round, on sites 31-32 with pairs across visits: +0.91 / +0.53 / +0.04,
    # +0.93 / +0.48 / -0.12, +0.89 / +0.20 / -0.22; the old simulator: +0.25 / +0.10 / +0.06, +0.55 / +0.14 / +0.03.
    for c in (0, 1, 2):
        assert 0.7 <= ac[c][0] <= 1.0, ac
    assert 0.55 <= ac[0][1] <= 0.95 and 0.3 <= ac[1][1] <= 0.9, ac
    assert -0.4 <= ac[2][1] <= 0.9, ac                                # a handful of heavy visits
    for c in (0, 1):
        assert pairs[c][2] >= 500 and -0.35 <= ac[c][2] <= 0.7, (ac, pairs)


def _gauss_markov_2d(rng, n, dt, tau):
    """A 2-D first-order Gauss–Markov (AR(1)) series, unit variance per axis: ρ(L) = exp(−L/τ) exactly."""
    phi = np.exp(-dt / tau)
    w = rng.standard_normal((n, 2)) * np.sqrt(1.0 - phi ** 2)
    x = np.empty((n, 2))
    x[0] = rng.standard_normal(2)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + w[i]
    return x


def test_pooled_autocorrelation_recovers_a_known_correlation_time_on_short_visits():
    """Issue 21 item 5: the pooled estimator on an AR(1) error of τ = 10 s, ρ(L) = exp(−L/τ) in closed form
    (0.905 / 0.607 / 0.135 / 0.0025 at 1 / 5 / 20 / 60 s), on 600 s walks whose class alternates every 10 s:
    pairs across visits reach every lag and the walk-mean removal costs ≈ (1 − ρ)/N_eff, N_eff = 300 s / 20 s.
    The per-visit figure of the earlier report has no pair at 20 or 60 s there and, on 25 s visits of a τ = 30 s
    error, reads far below exp(−20/30) = 0.51 — why it is reported beside the pooled one only once."""
    cs = _bench()
    rng = np.random.default_rng(5)
    dt, tau, walk_s, n_walks = 0.2, 10.0, 600.0, 12
    n = int(walk_s / dt)
    t = dt * np.arange(n)
    cls = np.where((t // 10.0) % 2 == 0, 2, 1)                   # heavy / light visits of 10 s
    pooled = np.zeros((4, 4))
    visit = np.zeros((4, 4))
    for _ in range(n_walks):
        x = _gauss_markov_2d(rng, n, dt, tau)
        pooled += cs.autocorr_sums(t, x, cls, (1.0, 5.0, 20.0, 60.0))[2]
        visit += cs.autocorr_sums(t, x, cls, (1.0, 5.0, 20.0, 60.0), per_visit=True)[2]
    rho = cs.autocorr_from_sums(pooled)
    truth = np.exp(-np.array([1.0, 5.0, 20.0, 60.0]) / tau)
    assert rho == pytest.approx(truth.tolist(), abs=0.05), (rho, truth)
    assert visit[2:, 3].sum() == 0 and np.isnan(cs.autocorr_from_sums(visit)[2:]).all()
    # A sign or lag bug (pairs at 2L, a missing mean removal) moves ρ(5 s) by > 0.1 here.
    assert abs(rho[1] - truth[1]) < 0.05
    # The old figure on one 25 s heavy visit per 200 s walk of a τ = 30 s error (the bias the issue names).
    dt, tau, n = 0.2, 30.0, 20_000
    x = _gauss_markov_2d(rng, n, dt, tau)
    t = dt * np.arange(n)
    short = np.where((t % 200.0) < 25.0, 2, 0)
    tot = np.zeros((3, 4))
    for k in range(0, n, 1000):
        tot += cs.autocorr_sums(t[k:k + 1000], x[k:k + 1000], short[k:k + 1000], (1.0, 5.0, 20.0), per_visit=True)[2]
    assert cs.autocorr_from_sums(tot)[2] < np.exp(-20 / tau) - 0.3


def test_rmc_speed_error_comes_from_the_doppler_solution(figures):
    g, _ = figures
    # measured median |error| 0.012 / 0.014 / 0.033 m/s, p95 0.039 / 0.056 / 0.37: it grows with NLOS
    for c in (0, 1, 2):
        assert 0.005 <= g["speed_err_med"][c] <= 0.06
    assert g["speed_err_p95"][2] > 1.5 * g["speed_err_p95"][0]


def test_cn0_and_features_beside_real_receivers(figures):
    g, _ = figures
    los, nlos = g["cn0_los"], g["cn0_nlos"]
    # smartLoc: LOS 43.8 ± 4.5, NLOS 31.4 ± 7.9 dB-Hz; a waist-worn receiver sits a few dB lower (measured 42.4 ± 5.1
    # / 33.0 ± 4.6)
    assert 38.0 <= los[0] <= 47.0 and 3.0 <= los[1] <= 7.0
    assert 27.0 <= nlos[0] <= 36.0 and 5.0 <= los[0] - nlos[0] <= 16.0
    f = g["features"]
    # ζ (untracked share): measured 0.056 / 0.167 / 0.352; real gpsd logs 0.12-0.67 (12 of 13), but those are not
    # open-sky captures (see bench/calibrate_sim.py: weak or indoor C/N0, whole constellations listed untracked)
    assert 0.02 <= f[0][2] <= 0.67 and 0.05 <= f[1][2] <= 0.6 and 0.15 <= f[2][2] <= 0.8
    assert f[2][2] > f[1][2] > f[0][2]
    # μ attenuation of tracked satellites: measured 2.6 / 4.0 / 6.1 dB (receiver offsets vary per walk); real gpsd
    # logs 3.6-24.6 dB
    assert 1.5 <= f[0][0] <= 25.0 and 2.0 <= f[2][0] <= 25.0
    # all in-view satellites above 10°, tracked or not: measured 3.2 / 6.3 / 13.2 dB (paper: heavy 18-23 dB; the
    # satellites that far down mostly fall below the tracking threshold and count in ζ)
    att = g["att_all_mean"]
    assert 1.0 <= att[0] <= 8.0 and 8.0 <= att[2] <= 25.0 and att[2] > att[1] > att[0]


def test_survey_fix_error_per_class(figures):
    _, sv = figures
    for s, row in sv.items():
        assert 0.002 <= row[0][1] < 0.03, (s, row)               # open cells: centimetres (measured 0.007-0.012)
    heavy = [row[2][1] for row in sv.values() if row[2][0] > 0]
    assert 0.1 < np.nanmedian(heavy) < 10.0                       # heavy cells: decimetres to metres (1.5, 6.7)
