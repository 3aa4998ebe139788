"""Realism cannot quietly regress (issues 10 and 21): the calibration report's figures inside two-sided bands.

Runs ``bench/calibrate_sim.py``'s GNSS part on three sites nobody tuned on (seeds 31–33: the GNSS world of
issue 21 was tuned on site seeds 1–4, its routes on 1–6, and 31–33 were first simulated for these bands), two
300 s default walks each, and a 15 m survey of sites 31 and 32. The bands are the real figures where one exists
(smartLoc's LOS/NLOS C/N0, computed from the file by bench/smartloc.py; the public low-cost RTK log's wrong fixes)
and otherwise the measured value of this simulator (2026-12-02, in comments) with room for seed-to-seed spread —
the point is that a change that makes RTK an oracle again, stops tracking NLOS, whitens the errors, trusts GST or
leaks truth into RMC lands outside them. Every band is two-sided.
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


def test_rtk_fixes_from_the_ambiguities_are_not_an_oracle(figures):
    g, _ = figures
    fixed, wrong = g["fixed"], g["wrong"]
    # Quality-4 share of the epochs, measured 0.960 / 0.904 / 0.065 (issue 21: from the ambiguity search; before,
    # 0.70 / 0.45 / 0.20 from a 20 s convergence gate and a time-to-fix draw)
    assert 0.85 <= fixed[0] <= 1.0 and 0.6 <= fixed[1] <= 0.97 and 0.02 <= fixed[2] <= 0.3
    assert fixed[0] > fixed[2] and fixed[1] > fixed[2]
    # Quality-4 epochs more than 0.2 m wrong, measured 0.0 / 1.5 / 0.0 % of 2416 / 3332 / 182: open near 0,
    # under occlusion what biased float ambiguities and a confident search give — it varies by site (tuning
    # sites 1-4: heavy 12 %; report sites 21-25: see bench/calibrate_sim.py; the public low-cost RTK log had all
    # 23 of its occluded fixed epochs 0.85 m off; before issue 21: 0 / 6.1 / 4.2 %, drawn from the true NLOS
    # flags). The mechanism is pinned on a heavy stand point in tests/test_gnss_sim.py.
    assert 0.0 <= wrong[0] <= 0.01 and 0.0 <= wrong[1] <= 0.1 and 0.0 <= wrong[2] <= 0.6
    assert wrong[1] + wrong[2] > wrong[0]
    # Time to first fix after a cold start, measured median 5.8 s (max 11.4): a GPS + BeiDou sky is strong
    assert 3.0 <= g["first_fix_s"][0] <= 30.0
    # Re-fix after a loss by the class where the fix was lost: light median 4.2 s (5 losses), heavy 74 s (6)
    n_h, med_h, _ = g["refix_by_class"][2]
    assert n_h >= 1 and 10.0 <= med_h <= 300.0


def test_gst_is_the_receivers_overconfident_belief(figures):
    """GST NEES (east² / σ_lon² + north² / σ_lat², 2 = consistent), σ read back from the written GST. Medians,
    measured: DGNSS 1.3 / 1.8 / 0.5, float 1.8 / 1.6 / 2.5, fixed 5.9 / 5.1 / 7.0 (means 8.8 / 597 / 11.6: a
    wrong fix is metres off with a σ of millimetres)."""
    g, _ = figures
    nees = g["nees"]
    for c in (0, 1, 2):
        n, mean, med = nees[c][4]
        assert n >= 50 and 2.5 <= med <= 30.0 and mean >= med   # fixed: carrier σ × variance factor, too small
    for c in (1, 2):
        n, mean, med = nees[c][5]
        assert n >= 20 and 1.0 <= med <= 8.0                    # float: closer to consistent
    assert max(nees[1][4][1], nees[2][4][1]) > 10 * nees[0][4][1]   # the mean blows up where wrong fixes live


def test_nlos_is_tracked_and_used(figures):
    """Share of NLOS among tracked / used satellites above 10°, measured open 0.7 / 0.3 %, light 4.1 / 3.0 %,
    heavy 23.0 / 20.1 % (before issue 21: 2.1 % of tracked overall, heavy 8.9 % of used); smartLoc's Berlin
    canyon, where every low satellite is behind a building: 48.5 % of tracked."""
    g, _ = figures
    sh = g["nlos_share"]
    assert 0.0 <= sh[0][0] <= 0.03 and 0.01 <= sh[1][0] <= 0.12 and 0.12 <= sh[2][0] <= 0.45
    assert 0.08 <= sh[2][1] <= 0.45 and sh[2][1] > sh[1][1] > sh[0][1]


def test_cn0_beside_smartloc_and_the_residual_beside_berlin(figures):
    g, _ = figures
    from bench.smartloc import los_nlos_cn0

    real = los_nlos_cn0()
    assert real["los"][:2] == pytest.approx((43.76, 4.53), abs=0.01)        # computed from the file
    assert real["nlos"][:2] == pytest.approx((31.42, 7.86), abs=0.01)
    los, nlos = g["cn0_all"]["los"], g["cn0_all"]["nlos"]
    # NLOS measured 31.3 ± 5.3 dB-Hz: within 1 dB-Hz of smartLoc's mean; narrower (no glass façades at grazing
    # incidence in a yard). LOS 40.6 ± 6.3: a body-worn antenna (receiver offset 0 to −5 dB, the wearer's body)
    # against a car roof's 43.8 ± 4.5.
    assert abs(nlos[0] - real["nlos"][0]) <= 1.0 and 4.0 <= nlos[1] <= 9.0
    assert 38.0 <= los[0] <= 45.0 and 4.0 <= los[1] <= 8.0 and 6.0 <= los[0] - nlos[0] <= 14.0
    for c in (1, 2):                                                     # light 30.7, heavy 31.6
        assert 27.0 <= g["cn0"][c]["nlos"][0] <= 35.0
    # Per-satellite residual by C/N0 (<30, 30-35, 35-40, 40-45, >=45 dB-Hz): measured 1.73 / 0.83 / 0.46 / 0.30 /
    # 0.23 m; Berlin 36.1 / 18.7 / 10.2 / 6.7 / 6.4 m. It falls with C/N0 as Berlin's does (ratio of the ends 7.5
    # vs 5.6); its scale is the yard's: delays of 2·d·cos θ off reflectors 5-30 m away, most weak satellites here
    # direct but body-masked.
    r = [m for _, m in g["residual_by_cn0"]]
    assert all(a >= b for a, b in zip(r, r[1:])) and 3.0 <= r[0] / r[-1] <= 20.0 and 0.5 <= r[0] <= 15.0


def test_default_walks_time_share(figures):
    g, _ = figures
    # measured 28 / 41 / 31 % open / light / heavy on these walks (issue 21: >= 20 % heavy, >= 30 % light)
    ts = g["time_share"]
    assert 0.2 <= ts[2] <= 0.5 and 0.3 <= ts[1] <= 0.6 and 0.1 <= ts[0] <= 0.5


def test_gnss_errors_are_correlated_in_time(figures):
    g, _ = figures
    ac, pairs = g["autocorr"], g["autocorr_pairs"]
    # Pooled (class mean removed over the walk, pairs across visits; issue 21 item 5), lags 1 / 5 / 20 / 60 s,
    # measured open +0.83 / +0.31 / -0.00 / -0.04, light +0.94 / +0.63 / -0.16 / -0.03, heavy +0.99 / +0.88 /
    # +0.25 / -0.17 (per visit, the old figure: heavy +0.99 / +0.88 / +0.25 / -0.66). Heavy errors are float and
    # wrong-fix biases held for tens of seconds at inspection stops; open and light are mostly RTK fixed, their
    # errors centimetres of carrier noise plus short float spells.
    for c in (0, 1, 2):
        assert 0.6 <= ac[c][0] <= 1.0 and pairs[c][1] >= 500, (ac, pairs)
    assert 0.6 <= ac[2][1] <= 0.99 and 0.05 <= ac[2][2] <= 0.9, ac
    assert 0.1 <= ac[1][1] <= 0.9 and -0.6 <= ac[0][3] <= 0.5, ac
    assert ac[2][1] > ac[0][1]


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
    # measured median |error| 0.012 / 0.023 / 0.059 m/s, p95 0.039 / 0.068 / 0.26 (before issue 21: 0.012 / 0.014 /
    # 0.033, p95 0.039 / 0.056 / 0.37): it grows with NLOS
    for c in (0, 1, 2):
        assert 0.005 <= g["speed_err_med"][c] <= 0.06
    assert g["speed_err_p95"][2] > 1.5 * g["speed_err_p95"][0]


def test_features_beside_real_receivers(figures):
    g, _ = figures
    f = g["features"]
    # ζ (untracked share): measured 0.040 / 0.104 / 0.400 (issue 21: tracking down to 20-23 dB-Hz, as the smartLoc
    # u-blox log shows; before, 0.056 / 0.167 / 0.352); real gpsd logs 0.12-0.67 (12 of 13), but those are not
    # open-sky captures (see bench/calibrate_sim.py: weak or indoor C/N0, whole constellations listed untracked)
    assert 0.0 <= f[0][2] <= 0.2 and 0.03 <= f[1][2] <= 0.4 and 0.2 <= f[2][2] <= 0.8
    assert f[2][2] > f[1][2] > f[0][2]
    # μ attenuation of tracked satellites: measured 4.0 / 5.9 / 8.4 dB (before 2.6 / 4.0 / 6.1: NLOS tracked now);
    # real gpsd logs 3.6-24.6 dB
    assert 1.5 <= f[0][0] <= 25.0 and 3.0 <= f[2][0] <= 25.0 and f[2][0] > f[0][0]
    # all in-view satellites above 10°, tracked or not: measured 4.0 / 6.6 / 16.1 dB (paper: light 5-10, heavy
    # 18-23 dB)
    att = g["att_all_mean"]
    assert 1.0 <= att[0] <= 8.0 and 10.0 <= att[2] <= 25.0 and att[2] > att[1] > att[0]


def test_survey_fix_error_per_class(figures):
    _, sv = figures
    for s, row in sv.items():
        assert 0.002 <= row[0][1] < 0.03, (s, row)               # open cells: centimetres (measured 0.012-0.013)
    heavy = [row[2][1] for row in sv.values() if row[2][0] > 0]
    assert 0.1 < np.nanmedian(heavy) < 10.0                       # heavy cells: decimetres to metres (0.98, 2.97)
