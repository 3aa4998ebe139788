"""What ``train fusion`` says of the covariance calibration it fitted: no 'nan' where a figure cannot exist."""

import numpy as np

import training.calibration as tc


def _fake_data(groups):
    rng = np.random.default_rng(0)
    n = 400
    X = rng.normal(size=(n, 3))
    nees = rng.chisquare(2, n) * 1.7          # a filter that under-reports its covariance by 1.7
    return {"adaptive": (X, nees, np.array(groups * (n // len(groups))))}


def test_one_training_walk_says_there_is_no_out_of_fold_figure(monkeypatch):
    lines = []
    monkeypatch.setattr(tc, "calibration_data", lambda model, walks: _fake_data(["w0"]))
    cals = tc.fit_calibration(None, [], progress=lines.append)
    assert cals["adaptive"].multiplier_ == 1.0
    assert len(lines) == 1 and "nan" not in lines[0]
    assert "no out-of-fold figure" in lines[0] and "two or more training walks" in lines[0]


def test_two_walks_report_the_out_of_fold_share(monkeypatch):
    lines = []
    monkeypatch.setattr(tc, "calibration_data", lambda model, walks: _fake_data(["w0", "w1"]))
    cals = tc.fit_calibration(None, [], progress=lines.append)
    c = cals["adaptive"]
    # the two-sided 95 % region of chi-square(2) is [-2 ln 0.975, -2 ln 0.025] = [0.0506, 7.378]; for 1.7 chi2(2)
    # (CDF 1 - exp(-x / 3.4)) by hand exp(-0.0506 / 3.4) - exp(-7.378 / 3.4) = 0.9852 - 0.1142 = 0.871 (SE 0.017)
    assert abs(c.oof_share_raw_ - 0.871) < 0.04
    assert np.isfinite(c.oof_share_) and f"-> {c.oof_share_:.2f} (out of fold" in lines[0]
