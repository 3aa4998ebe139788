"""Continuous occlusion estimate (issue 27 item 5): fractional-logit regressor and its place in the classifier.

References: the generating curve itself (a known logistic or non-monotone mean), scikit-learn's logistic
regression on the same objective written as weighted rows, and scikit-learn's ridge for the old bundles' form.
"""

import json

import numpy as np
import pytest

from features.schema import FEATURES
from models.environment import EnvironmentClassifier, _expand
from models.occlusion import OcclusionRegressor


def _logistic_data(rng, n=4000, coef=(1.0, -2.0, 0.5), intercept=-1.0, noise=0.0):
    X = rng.normal(size=(n, len(coef)))
    mean = 1.0 / (1.0 + np.exp(-(intercept + X @ np.asarray(coef))))
    return X, mean, np.clip(mean + rng.normal(0.0, noise, n), 0.0, 1.0)


def _raw_coefficients(reg: OcclusionRegressor) -> tuple[np.ndarray, float]:
    """A linear model's coefficients on the unstandardised inputs."""
    w, b = reg.weights_[0][0, 0], float(reg.weights_[1][0, 0])
    return w / reg.scale_, b - float(np.sum(w * reg.mean_ / reg.scale_))


def test_linear_form_recovers_a_known_logistic_curve():
    X, mean, share = _logistic_data(np.random.default_rng(0))
    reg = OcclusionRegressor(hidden=(), alpha=1e-6).fit(X, share)        # noiseless: the curve itself
    coef, intercept = _raw_coefficients(reg)
    assert np.allclose(coef, [1.0, -2.0, 0.5], atol=2e-3) and abs(intercept + 1.0) < 2e-3
    assert np.max(np.abs(reg.predict(X) - mean)) < 1e-3


def test_linear_form_is_sklearn_logistic_regression_on_weighted_rows():
    from sklearn.linear_model import LogisticRegression

    rng = np.random.default_rng(1)
    X, _, share = _logistic_data(rng, n=1500, noise=0.08)              # noisy, with exact 0s and 1s
    assert np.any(share == 0.0) and np.any(share == 1.0)
    reg = OcclusionRegressor(hidden=(), alpha=3.0).fit(X, share)
    z = (X - reg.mean_) / reg.scale_
    n = len(z)
    ref = LogisticRegression(C=1 / 3.0, tol=1e-10, max_iter=10_000)
    ref.fit(np.vstack([z, z]), np.r_[np.ones(n), np.zeros(n)], sample_weight=np.r_[share, 1.0 - share])
    assert reg.weights_[0].shape == (1, 1, 3)                          # convex: one member whatever n_members
    assert np.allclose(reg.weights_[0][0, 0], ref.coef_[0], atol=1e-4)
    assert abs(float(reg.weights_[1][0, 0]) - ref.intercept_[0]) < 1e-4
    assert np.max(np.abs(reg.predict(X) - ref.predict_proba(z)[:, 1])) < 1e-5


def test_hidden_layer_follows_a_non_monotone_mean_the_linear_form_cannot():
    rng = np.random.default_rng(2)
    x = rng.uniform(-3, 3, size=(1500, 1))
    mean = 1.0 / (1.0 + np.exp(-(2.5 * np.sin(1.5 * x[:, 0]) - 1.0)))
    share = np.clip(mean + rng.normal(0, 0.05, len(x)), 0, 1)
    xt = np.linspace(-2.8, 2.8, 200)[:, None]
    mt = 1.0 / (1.0 + np.exp(-(2.5 * np.sin(1.5 * xt[:, 0]) - 1.0)))
    net = OcclusionRegressor(hidden=(8,), alpha=0.1, n_members=1, max_iter=1000).fit(x, share)
    lin = OcclusionRegressor(hidden=(), alpha=0.1).fit(x, share)
    # the mean swings between σ(−3.5) = 0.03 and σ(1.5) = 0.82: a monotone curve misses it by ~0.3 RMS
    assert np.sqrt(np.mean((net.predict(xt) - mt) ** 2)) < 0.03
    assert np.sqrt(np.mean((lin.predict(xt) - mt) ** 2)) > 0.2


def test_output_stays_inside_the_unit_interval():
    X, _, share = _logistic_data(np.random.default_rng(3), n=800, noise=0.1)
    reg = OcclusionRegressor(hidden=(8,), alpha=1.0, n_members=2, max_iter=200).fit(X, share)
    far = np.array([[1e3, -1e3, 1e3], [-1e3, 1e3, -1e3], [0.0, 0.0, 0.0]])
    est = reg.predict(far)
    assert np.all(np.isfinite(est)) and np.all((est >= 0.0) & (est <= 1.0))
    assert est[0] > 0.9 and est[1] < 0.1 and est[1] < est[2] < est[0]    # tanh units saturate: not 0 / 1


def test_state_round_trip_without_pickle_and_seed_determinism():
    X, _, share = _logistic_data(np.random.default_rng(4), n=600, noise=0.05)
    kw = dict(hidden=(6, 4), alpha=1.0, n_members=2, max_iter=100)
    a = OcclusionRegressor(**kw, random_state=7).fit(X, share)
    b = OcclusionRegressor(**kw, random_state=7).fit(X, share)
    c = OcclusionRegressor(**kw, random_state=8).fit(X, share)
    assert not np.array_equal(a.weights_[0][0], a.weights_[0][1])      # members start from different weights
    assert all(np.array_equal(u, v) for u, v in zip(a.weights_, b.weights_))
    assert not np.array_equal(a.weights_[0], c.weights_[0])           # the seed reaches the initial weights
    params, arrays = a.get_state()
    params = json.loads(json.dumps(params))                              # JSON, not pickle
    assert all(isinstance(v, np.ndarray) and v.dtype.kind == "f" for v in arrays.values())
    again = OcclusionRegressor.from_state(params, arrays)
    bare = OcclusionRegressor.from_arrays(arrays)                        # widths read from the shapes
    assert bare.hidden == (6, 4) and bare.weights_[0].shape == (2, 6, 3)
    assert np.array_equal(again.predict(X), a.predict(X)) and np.array_equal(bare.predict(X), a.predict(X))
    with pytest.raises(ValueError, match="do not match"):
        OcclusionRegressor.from_state(params, dict(arrays, w1=arrays["w1"][:, :3]))
    with pytest.raises(ValueError, match="non-finite"):
        OcclusionRegressor.from_state(params, dict(arrays, b0=np.full_like(arrays["b0"], np.nan)))


def test_bad_input_is_named():
    X, _, share = _logistic_data(np.random.default_rng(5), n=50)
    with pytest.raises(ValueError, match=r"share must lie in \[0, 1\]"):
        OcclusionRegressor().fit(X, share + 1.0)
    with pytest.raises(ValueError, match="hidden must be"):
        OcclusionRegressor(hidden=(0,)).fit(X, share)
    with pytest.raises(ValueError, match="alpha must be"):
        OcclusionRegressor(alpha=-1.0).fit(X, share)
    with pytest.raises(ValueError, match="finite"):
        OcclusionRegressor().fit(np.where(X > 1, np.nan, X), share)
    with pytest.raises(ValueError, match="columns"):
        OcclusionRegressor(hidden=()).fit(X, share).predict(X[:, :2])


def _classifier_data(rng, n_per_class=200):
    X, y, share = [], [], []
    for c in range(3):
        X.append(rng.normal(1.5 * c, 1.0, size=(n_per_class, len(FEATURES))))
        y.append(np.full(n_per_class, c))
        share.append(np.clip(0.05 + 0.2 * c + 0.05 * X[-1][:, 0] / 1.5, 0, 1))
    return np.vstack(X), np.concatenate(y), np.concatenate(share)


def test_classifier_state_round_trip_keeps_the_share_estimate():
    X, y, share = _classifier_data(np.random.default_rng(6))
    clf = EnvironmentClassifier().fit(X, y, share=share)
    params, arrays = clf.get_state()
    assert "both.share.w0" in arrays and not any(k.endswith("share_coef") for k in arrays)
    again = EnvironmentClassifier.from_state(json.loads(json.dumps(params)), arrays)
    Xt, _, st = _classifier_data(np.random.default_rng(7), 50)
    Xt[::4, :5] = np.nan                                                 # some windows answered by "acoustic"
    assert np.array_equal(clf.occlusion(Xt), again.occlusion(Xt))
    est = clf.occlusion(Xt)
    assert np.all((est > 0) & (est < 1)) and np.std(est - st) < 0.05


def test_old_bundle_with_ridge_share_keys_still_answers():
    """A bundle saved before the fractional-logit estimate holds ``share_coef``/``share_intercept`` of a ridge on
    the expanded standardised inputs; it must answer with that ridge (clipped to [0, 1]), as before."""
    from sklearn.linear_model import Ridge

    from models.checks import check_classifier

    X, y, share = _classifier_data(np.random.default_rng(8))
    params, arrays = EnvironmentClassifier().fit(X, y, share=share).get_state()
    old = {k: v for k, v in arrays.items() if ".share." not in k}
    refs = {}
    for name in params["submodels"]:
        cols = {"both": slice(None), "gnss": slice(0, 5), "acoustic": slice(5, 14)}[name]
        z = (X[:, cols] - arrays[f"{name}.mean"]) / arrays[f"{name}.scale"]
        r = Ridge(alpha=1.0).fit(_expand(z, params["degree"]), share)
        old[f"{name}.share_coef"], old[f"{name}.share_intercept"] = r.coef_, np.array([r.intercept_])
        refs[name] = r
    clf = EnvironmentClassifier.from_state(params, old)
    check_classifier(clf)
    Xt, _, _ = _classifier_data(np.random.default_rng(9), 40)
    zt = (Xt - arrays["both.mean"]) / arrays["both.scale"]
    expected = np.clip(refs["both"].predict(_expand(zt, params["degree"])), 0, 1)
    assert np.allclose(clf.occlusion(Xt), expected, atol=1e-12)
    bad = dict(arrays, **{"both.share.w0": arrays["both.share.w0"][:, :3]})
    with pytest.raises(ValueError, match="share estimator"):
        check_classifier(EnvironmentClassifier.from_state(params, bad))
