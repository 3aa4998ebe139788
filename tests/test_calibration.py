"""Realism cannot quietly regress (issue 10 item 8): the calibration report's figures inside their bands.

Runs ``bench/calibrate_sim.py``'s GNSS part on two sites nobody tuned on (seeds 31, 32), one 240 s walk
each and a 15 m survey. The bands are the real figures where one exists (DESIGN.md §6: smartLoc C/N0,
the gpsd logs' untracked share) and otherwise the measured value of this simulator with room for
seed-to-seed spread (measured 2026-12-01, in comments) — the point is that a change that makes RTK an
oracle again, whitens the errors or leaks truth into RMC lands outside them.
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
        g = cs.gnss_walk_figures([31, 32], [1], 240.0)
        sv = cs.survey_figures([31, 32], cell_size_m=15.0, capture_s=15.0)
    return g, sv


def test_rtk_is_not_an_oracle(figures):
    g, _ = figures
    fixed = g["fixed"]
    # measured 0.69 / 0.46 / 0.30 (the old oracle: 0.99 / 0.75 / 0.13, never wrong)
    assert 0.5 <= fixed[0] <= 1.0 and 0.2 <= fixed[1] <= 0.85 and 0.0 <= fixed[2] <= 0.6
    assert fixed[0] > fixed[1] > fixed[2]
    assert g["wrong"][0] <= 0.02 and g["wrong"][1] <= 0.1          # wrong fixes: rare, never in the open
    assert 3.0 <= g["refix_median_s"] <= 40.0                      # measured 18 s; F9P data sheet: < 10 s in clear sky


def test_gnss_errors_are_correlated_in_time(figures):
    g, _ = figures
    ac = g["autocorr"]
    # measured lag 1 / 5 / 20 s: open +0.91 / +0.53 / +0.04, light +0.93 / +0.48 / -0.12, heavy +0.89 / +0.20 / -0.22
    # (the old simulator: +0.25 / +0.10 / +0.06, +0.55 / +0.14 / +0.03, +0.53 / +0.19 / +0.05). At 20 s the class
    # mean removed over short visits to a class makes the figure swing; issue 10's target (>= 0.2) is not met.
    for c in (0, 1, 2):
        assert 0.6 <= ac[c][0] <= 1.0, ac
        assert -0.45 <= ac[c][2] <= 0.6, ac
    assert ac[0][1] >= 0.3 and ac[1][1] >= 0.3 and ac[2][1] >= 0.1, ac


def test_rmc_speed_error_comes_from_the_doppler_solution(figures):
    g, _ = figures
    # measured median |error| 0.014 / 0.014 / 0.021 m/s, p95 0.046 / 0.049 / 0.129: it grows with NLOS
    for c in (0, 1, 2):
        assert 0.005 <= g["speed_err_med"][c] <= 0.05
    assert g["speed_err_p95"][2] > 1.5 * g["speed_err_p95"][0]


def test_cn0_and_features_beside_real_receivers(figures):
    g, _ = figures
    los, nlos = g["cn0_los"], g["cn0_nlos"]
    # smartLoc: LOS 43.8 ± 4.5, NLOS 31.4 ± 7.9 dB-Hz; a waist-worn receiver sits a few dB lower (measured 40.5 / 32.8)
    assert 38.0 <= los[0] <= 47.0 and 3.0 <= los[1] <= 7.0
    assert 27.0 <= nlos[0] <= 36.0 and los[0] - nlos[0] >= 5.0
    f = g["features"]
    # ζ (untracked share): measured 0.09 / 0.17 / 0.39; real gpsd logs 0.12-0.67 (12 of 13), the old open sky 0.01
    assert 0.03 <= f[0][2] <= 0.67 and f[2][2] > f[0][2]
    # μ attenuation: measured 4.9 / 5.1 / 4.7 dB; real gpsd logs 3.6-24.6 dB (the old open sky: 1.8-2.2)
    assert 3.0 <= f[0][0] <= 25.0


def test_survey_fix_error_per_class(figures):
    _, sv = figures
    for s, row in sv.items():
        assert row[0][1] < 0.03, (s, row)                         # open cells: centimetres (measured 0.007-0.012)
    heavy = [row[2][1] for row in sv.values() if row[2][0] > 0]
    assert np.nanmedian(heavy) > 0.1                              # heavy cells: decimetres to metres (0.95, 1.14)
