"""Covariance calibration (models/fusion/calibration.py, walks/calibrate.py): its constant, inputs and fit
checked against hand computations and synthetic NEES whose true scale is known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from features.errors import DataError
from models.fusion.calibration import (E_LOG_CHI2_2, CalibrationConfig, CovarianceCalibrator, calibration_inputs,
                                       in_region_share, running_mean)
from walks.calibrate import calibrate_tracks
from walks.track import Track


def test_mean_log_chi2_2_is_ln2_minus_euler_gamma():
    # E[ln χ²₂] = ψ(1) + ln 2 = ln 2 − γ (γ = 0.5772156649, Euler–Mascheroni), and a Monte Carlo check
    assert E_LOG_CHI2_2 == pytest.approx(math.log(2.0) - 0.5772156649, abs=1e-9)
    x = np.random.default_rng(0).chisquare(2, 2_000_000)
    assert np.log(x).mean() == pytest.approx(E_LOG_CHI2_2, abs=0.003)


def test_region_share_of_exact_chi2_is_095_and_punishes_overconfidence():
    rng = np.random.default_rng(1)
    x = rng.chisquare(2, 400_000)
    assert in_region_share(x) == pytest.approx(0.95, abs=0.002)
    # NEES = c·χ²₂ with c = 2: P(0.0506/2 ≤ χ²₂ ≤ 7.378/2) = exp(−0.0127) − exp(−1.844) = 0.8290 by hand
    assert in_region_share(2.0 * x) == pytest.approx(0.8290, abs=0.003)


def test_running_mean_by_hand():
    t_nis = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    nis = np.array([1.0, np.nan, 3.0, 5.0, 7.0])
    # windows (t − 2, t]: at 3 → {2: 3, 3: 5} → 4; at 1 → {0: 1} (the NaN at 1 does not count) → 1;
    # at 8 → nothing → NaN; at 10 → 7
    got = running_mean(np.array([3.0, 1.0, 8.0, 10.0]), t_nis, nis, 2.0)
    assert got[:2].tolist() == [4.0, 1.0] and np.isnan(got[2]) and got[3] == 7.0


def test_inputs_columns_by_hand():
    t = np.array([1.0, 4.0])
    cov = np.array([np.diag([0.01, 0.03]), np.diag([1.0, 1.0])])
    X = calibration_inputs(t, cov, np.array([0.5, 1.0]), np.array([2.0, 6.0]), np.array([0.9]), np.array([4]),
                           class_proba=np.array([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0]]))
    assert X.shape == (2, 13)
    assert X[0, 0] == pytest.approx(math.log(0.04)) and X[1, 0] == pytest.approx(math.log(2.0))
    assert X[0, 1] == pytest.approx(math.log(4.0))          # NIS 2 and 6 in the last 2 s → mean 4
    assert X[1, 1] == pytest.approx(math.log(2.0))          # no update in (2, 4]: the consistent value
    assert X[1, 3] == pytest.approx(math.log(4.0))          # 15 s window still holds both
    # quality one-hot (1, 2, 4, 5, other, none): the RTK-fixed fix is 0.1 s old at t = 1, 3.1 s at t = 4
    assert X[0, 4:10].tolist() == [0, 0, 1, 0, 0, 0] and X[1, 4:10].tolist() == [0, 0, 0, 0, 0, 1]
    assert X[0, 10:].tolist() == [0.2, 0.3, 0.5]


def _synthetic(rng, n_groups, per_group, scale_of):
    X, y, g = [], [], []
    for k in range(n_groups):
        x = rng.uniform(-1.0, 1.0, (per_group, 3))
        X.append(x)
        y.append(scale_of(x) * rng.chisquare(2, per_group))
        g.append(np.full(per_group, f"site{k}"))
    return np.vstack(X), np.concatenate(y), np.concatenate(g)


def test_calibrator_recovers_a_constant_overconfidence():
    # NEES = 4·χ²₂ everywhere: ŝ must come out 4 (a missing E[ln χ²₂] offset would give 4·e^0.116 = 4.49)
    rng = np.random.default_rng(2)
    X, y, g = _synthetic(rng, 6, 4000, lambda x: np.full(len(x), 4.0))
    cal = CovarianceCalibrator(CalibrationConfig(epochs=15, seed=0)).fit(X, y, g)
    Xt, yt, _ = _synthetic(rng, 2, 4000, lambda x: np.full(len(x), 4.0))
    s = cal.scale(Xt)
    assert np.median(s / cal.multiplier_) == pytest.approx(4.0, rel=0.05)
    # raw: exp(−0.0506/8) − exp(−7.378/8) = 0.9937 − 0.3977 = 0.596 by hand
    assert in_region_share(yt) == pytest.approx(0.596, abs=0.01)
    assert in_region_share(yt / s) == pytest.approx(0.95, abs=0.015)
    assert 0.7 < cal.multiplier_ < 1.5


def test_calibrator_follows_a_scale_that_varies_with_the_inputs():
    # the true scale grows with the first input by e^{±3}; a static scale cannot hold the region, the fit can
    truth = lambda x: np.exp(3.0 * x[:, 0])
    rng = np.random.default_rng(3)
    X, y, g = _synthetic(rng, 6, 4000, truth)
    cal = CovarianceCalibrator(CalibrationConfig(epochs=20, seed=0)).fit(X, y, g)
    Xt, yt, _ = _synthetic(rng, 2, 5000, truth)
    best_static = max(in_region_share(yt / c) for c in np.exp(np.linspace(-2, 3, 51)))
    assert best_static < 0.86
    assert in_region_share(yt / cal.scale(Xt)) > 0.93
    assert np.corrcoef(np.log(cal.scale(Xt)), 3.0 * Xt[:, 0])[0, 1] > 0.97     # a sign error would be −1
    again = CovarianceCalibrator.from_state(*cal.get_state())
    assert np.array_equal(again.scale(Xt), cal.scale(Xt))


def test_calibrator_refuses_too_few_epochs_and_bad_shapes():
    with pytest.raises(DataError):
        CovarianceCalibrator().fit(np.zeros((10, 3)), np.ones(10), np.zeros(10))
    rng = np.random.default_rng(4)
    X, y, g = _synthetic(rng, 2, 200, lambda x: np.ones(len(x)))
    cal = CovarianceCalibrator(CalibrationConfig(epochs=3)).fit(X, y, g)
    with pytest.raises(DataError):
        cal.scale(np.zeros((4, 5)))


class _Run:
    t_s = np.array([0.0, 1.0, 2.0])
    nis = np.array([np.nan, 2.0, 2.0])


class _Inputs:
    class events:
        gnss = None

    class classes:
        @staticmethod
        def at(t):
            return np.tile([1.0, 0.0, 0.0], (len(t), 1))


class _Half:
    """A stand-in calibrator: halves every covariance."""

    def scale(self, X):
        return np.full(len(X), 0.5)


class _Model:
    calibration = {"kf_quality+lag": _Half()}


def test_calibrate_tracks_scales_only_the_named_tracks():
    cov = np.tile(np.eye(2), (3, 1, 1))
    tracks = {n: Track(n, _Run.t_s, np.zeros(3), np.zeros(3), cov.copy()) for n in ("kf_quality", "kf_quality+lag")}
    calibrate_tracks(tracks, "kf_quality", _Run(), _Model(), _Inputs())
    assert np.array_equal(tracks["kf_quality"].cov_m2, cov) and "cov_scale" not in tracks["kf_quality"].info
    assert np.allclose(tracks["kf_quality+lag"].cov_m2, 0.5 * cov)
    assert tracks["kf_quality+lag"].info["cov_scale"].tolist() == [0.5] * 3
