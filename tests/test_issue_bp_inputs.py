"""Issue 20: what the BP network is trained on and what its guard is fed, against hand-made runs.

- The training target of :func:`training.filters.train_fusion` is truth − filter position (the correction
  that moves the filter onto the truth), NaN outside the truth's time span. The filter run is replaced by
  one whose positions are the truth moved 1 m east and 2 m south, so every target is (−1, +2) by hand.
- The guard of the open-loop ``adaptive_correction`` method compares each fix against the filter's *prior* (what the
  next fix is independent evidence about); a stub network records what the method hands it.
"""

from __future__ import annotations

import csv
import types

import numpy as np
import pytest

from models.bp import N_INPUTS, Correction
from tests.bad_inputs import _trim_walk


@pytest.fixture(scope="module")
def short_walk(walk_dir, site_dir, tmp_path_factory):
    """The first 20 s of the session's walk, without audio (fast to read)."""
    root = tmp_path_factory.mktemp("bp_inputs")
    (root / "site").mkdir()
    (root / "site" / "site.toml").write_bytes((site_dir / "site.toml").read_bytes())
    _trim_walk(walk_dir, root / "walks" / "w", 20.0, "../../site/site.toml", audio=False)
    return root / "walks" / "w"


def _truth(walk):
    rows = list(csv.DictReader(open(walk / "truth.csv")))
    return (np.array([float(r["t_s"]) for r in rows]), np.array([float(r["east_m"]) for r in rows]),
            np.array([float(r["north_m"]) for r in rows]))


def test_bp_targets_are_truth_minus_the_filter(short_walk, monkeypatch):
    import training.filters as tf
    from models.environment import EnvironmentClassifier

    t_truth, e_truth, n_truth = _truth(short_walk)
    t = np.array([t_truth[0] - 1.0, 0.5, 3.3, 10.1, t_truth[-1] - 0.1, t_truth[-1] + 5.0])
    x = np.zeros((len(t), 4))
    x[:, 0] = np.interp(t, t_truth, e_truth) + 1.0          # the filter 1 m east of the truth
    x[:, 1] = np.interp(t, t_truth, n_truth) - 2.0          # and 2 m south
    fake_run = types.SimpleNamespace(t_s=t, x=x)
    seen = {}

    class Recorder:
        def __init__(self, config):
            self.config = config

        def fit(self, X, Y, progress=None):
            seen["X"], seen["Y"] = X, Y
            return self

    monkeypatch.setattr(tf, "adaptive_run", lambda model, inputs, *a, **k: fake_run)
    monkeypatch.setattr(tf, "bp_features", lambda run, inputs: np.zeros((len(run.t_s), N_INPUTS)))
    monkeypatch.setattr(tf, "BPCorrector", Recorder)
    monkeypatch.setattr(tf, "fit_param_net", lambda *a, **k: types.SimpleNamespace(validation_error_m_=0.0))   # the parameter nets train on other targets
    rng = np.random.default_rng(0)
    clf = EnvironmentClassifier(min_samples=5).fit(rng.normal(size=(60, 14)), np.repeat([0, 1, 2], 20))
    tf.train_fusion([short_walk], clf, calibrate=False)    # the calibrators would run adaptive on the stub nets
    (y,) = seen["Y"]
    assert np.all(np.isnan(y[[0, -1]]))                      # outside the truth's span: no target
    np.testing.assert_allclose(y[1:-1], np.tile([-1.0, 2.0], (4, 1)), atol=1e-9)


def test_the_adaptive_guard_is_fed_the_prior(trained_small):
    from walks.methods import run_methods

    model, inputs = trained_small
    seen = {}

    class StubBP:
        def correct(self, X, prior_en, z_en, S, updated):
            seen["prior"], seen["updated"] = np.array(prior_en), np.array(updated)
            m = len(X)
            zeros, off = np.zeros((m, 2)), np.zeros(m, bool)
            return Correction(zeros, zeros, zeros, off, off, off)

    model.bp = StubBP()
    tracks, _ = run_methods(model, inputs, ("adaptive_correction",), smooth=False)
    run = tracks["adaptive_correction"].info["run"]
    upd = seen["updated"]
    # the fixes moved the state: prior and posterior differ where the filter updated
    assert np.max(np.abs(run.x[upd, :2] - run.x_prior[upd, :2])) > 1e-3
    np.testing.assert_array_equal(seen["prior"], run.x_prior[:, :2])


@pytest.fixture(scope="module")
def trained_small(short_walk):
    from models.bp import BPConfig
    from models.environment import EnvironmentClassifier
    from training.filters import train_fusion
    from walks.inputs import walk_inputs, window_features
    from walks.reader import read_walk

    data = read_walk(short_walk)
    t, X = window_features(data)
    y = np.arange(len(t)) % 3
    clf = EnvironmentClassifier(min_samples=3).fit(X, y)
    model = train_fusion([short_walk], clf, bp=False, bp_config=BPConfig(n_members=1))
    return model, walk_inputs(data, clf)
