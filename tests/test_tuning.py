"""Issue 22 item 3: fair tuning — each method's knobs fitted by its own error on training walks."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def untuned(walk_dir):
    from models.environment import EnvironmentClassifier
    from training.filters import train_fusion
    from walks.inputs import walk_inputs, window_features
    from walks.reader import read_walk

    data = read_walk(walk_dir)
    t, X = window_features(data)
    clf = EnvironmentClassifier(min_samples=5).fit(X, data.truth.class_at(t - 1.0))
    model = train_fusion([walk_dir], clf, bp=False, tune=False)
    return model, walk_inputs(data, clf)


def test_tuning_undoes_a_sabotaged_noise_fit(untuned):
    """GNSS R fitted 100× too large: the tuned gnss knob comes back well below 1 (a knob applied as R/k
    instead of R·k would climb instead) and the training error falls."""
    from dataclasses import replace

    from training.tuning import KNOB_RANGE, TuningWalk, tune_method
    from walks.methods import MethodContext, method

    model, inputs = untuned
    from models.fusion import FixedNoise

    fixed = FixedNoise()
    fixed.R_gnss_ = model.fixed.R_gnss_ * 100.0
    fixed.R_acoustic_ = model.fixed.R_acoustic_
    bad = replace(model, fixed=fixed, tuning={})
    walk = TuningWalk.of(inputs)
    knobs, before, after = tune_method(bad, "kf", [walk], max_evals=40)
    assert knobs["gnss"] < 0.3 and KNOB_RANGE[0] <= min(knobs.values()) <= max(knobs.values()) <= KNOB_RANGE[1]
    assert after < 0.9 * before
    # the knobs reach the method through the model, as at evaluation
    run = method("kf").build(MethodContext(replace(bad, tuning={"kf": knobs}), inputs))
    g = run.updated & (run.kind == 1)
    np.testing.assert_allclose(run.R[g][0], fixed.R_gnss_ * knobs["gnss"], rtol=1e-12)


def test_every_filter_method_has_knobs_and_untunable_names_are_refused(untuned):
    from training.tuning import KNOBS, TuningWalk, tune_method
    from walks.methods import method, method_names

    filters = {n for n in method_names() if method(n).filter}
    # the BP's second passes run on their first pass's tuned knobs (adaptive_nobp's, its twin's); the seed
    # paper's RTK/PDR EKF keeps the paper's published noise, its step model and heading tau fitted by graph_fit;
    # the uwb_aoa_pdr methods take R from the UWB solver's covariance (scaled by the fitted NLOS prior) and the
    # PDR noise of models.uwb_pdr
    assert filters - {"adaptive", "adaptive_blind", "ekf_rtk_pdr", "uwb_aoa_pdr", "uwb_aoa_pdr_env",
                      "uwb_aoa_pdr_blind"} <= set(KNOBS)
    model, inputs = untuned
    with pytest.raises(KeyError):
        tune_method(model, "gnss", [TuningWalk.of(inputs)])


def test_a_method_that_runs_on_no_walk_is_not_searched(monkeypatch):
    """kf_map without a site map is skipped on every training walk, so its objective is inf everywhere: the
    knobs stay at 1 after the one evaluation that finds it, with no Nelder–Mead passes (there were up to
    ``max_evals`` of them, ending in scipy's RuntimeWarning of inf − inf in its convergence test)."""
    import math
    import warnings

    from training import tuning

    calls = []

    def objective(model, name, knobs, walks):
        def f(log_k):
            calls.append(np.array(log_k))
            return math.inf
        return f

    monkeypatch.setattr(tuning, "_objective", objective)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        knobs, before, after = tuning.tune_method(None, "kf_map", [], max_evals=60)
    assert knobs == {"gnss": 1.0, "acoustic": 1.0, "q_walk": 1.0}
    assert math.isinf(before) and math.isinf(after)
    assert len(calls) == 1 and not calls[0].any()
