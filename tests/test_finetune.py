"""MAP fine-tuning of the environment classifier (models/finetune.py): gradient, limits, adaptation."""

import numpy as np
import pytest
from scipy.optimize import approx_fprime

from models.environment import EnvironmentClassifier
from models.finetune import balanced_weights, choose_sigma, finetune, fit_map, map_objective
from tests.env_synth import synthetic_library


def _problem(seed=0, n=60, d=4, K=3):
    rng = np.random.default_rng(seed)
    Phi = rng.normal(size=(n, d))
    y = rng.integers(0, K, n)
    theta0 = rng.normal(size=K * d + K)
    theta = rng.normal(size=K * d + K)
    return Phi, y, balanced_weights(y), theta0, theta


def test_balanced_weights_match_scikit_learn():
    from sklearn.utils.class_weight import compute_sample_weight

    y = np.array([0, 0, 0, 1, 2, 2, 0, 1])
    np.testing.assert_allclose(balanced_weights(y), compute_sample_weight("balanced", y))


@pytest.mark.parametrize("sigma", [0.5, np.inf])
def test_gradient_matches_finite_differences(sigma):
    Phi, y, w, theta0, theta = _problem()
    _, grad = map_objective(theta, Phi, y, w, theta0, sigma)
    numeric = approx_fprime(theta, lambda t: map_objective(t, Phi, y, w, theta0, sigma)[0], 1e-6)
    np.testing.assert_allclose(grad, numeric, rtol=1e-4, atol=1e-5)


def test_objective_by_hand():
    # one window, two classes, one input: s = (w0 x + b0, w1 x + b1) = (0, 1·2 + 0) = (0, 2); y = 0
    Phi, y, w = np.array([[2.0]]), np.array([0]), np.array([1.0])
    theta = np.array([0.0, 1.0, 0.0, 0.0])              # W = [[0], [1]], b = [0, 0]
    theta0 = np.array([0.0, 0.0, 0.0, 0.0])
    J, _ = map_objective(theta, Phi, y, w, theta0, sigma=2.0)
    # −log(e^0 / (e^0 + e^2)) + 1² / (2 · 2²)
    assert J == pytest.approx(np.log(1 + np.exp(2.0)) + 1 / 8, rel=1e-12)


def test_sigma_infinite_is_the_unpenalised_maximum_likelihood_fit():
    from sklearn.linear_model import LogisticRegression

    rng = np.random.default_rng(3)
    n, d = 400, 3
    Phi = rng.normal(size=(n, d))
    true = np.array([[1.0, -0.5, 0.2], [-0.3, 0.8, 0.0], [0.0, 0.0, -1.0]])
    p = np.exp(Phi @ true.T)
    y = np.array([rng.choice(3, p=r / r.sum()) for r in p])           # overlapping classes: a finite optimum
    w = balanced_weights(y)
    ref = LogisticRegression(C=np.inf, class_weight="balanced", max_iter=5000, tol=1e-10).fit(Phi, y)
    W0, b0 = rng.normal(size=(3, d)) * 3, rng.normal(size=3) * 3      # a far-away prior mean: ignored
    W, b = fit_map(Phi, y, w, W0, b0, np.inf)
    s = Phi @ W.T + b
    ours = np.exp(s - s.max(1, keepdims=True))
    ours /= ours.sum(1, keepdims=True)
    np.testing.assert_allclose(ours, ref.predict_proba(Phi), atol=2e-4)


def test_sigma_zero_and_tiny_return_the_default_weights():
    Phi, y, w, theta0, _ = _problem(seed=5)
    K, d = 3, Phi.shape[1]
    W0, b0 = theta0[:K * d].reshape(K, d), theta0[K * d:]
    W, b = fit_map(Phi, y, w, W0, b0, 0.0)
    np.testing.assert_array_equal(W, W0)
    W, b = fit_map(Phi, y, w, W0, b0, 1e-4)
    # the data's pull is at most Σω|φ| ≈ 60 · 1 per weight; times σ² = 1e-8 it moves a weight < 1e-5
    np.testing.assert_allclose(W, W0, atol=1e-5)
    np.testing.assert_allclose(b, b0, atol=1e-5)


def _shifted(n, seed, steps):
    """The synthetic library with every feature moved by ``steps`` class steps (another receiver / site: open
    looks like the default's light)."""
    from tests.env_synth import _MODEL
    from models.embedding import ENV_FEATURES

    X, y = synthetic_library(n, seed)
    return X + steps * np.array([_MODEL[f][1] for f in ENV_FEATURES]), y


def test_finetuning_recovers_a_shifted_site_that_the_default_misreads():
    default = EnvironmentClassifier(degree=1).fit(*synthetic_library(1500, 1))
    Xs, ys = _shifted(600, 2, 0.8)
    Xt, yt = _shifted(1500, 3, 0.8)
    before = np.mean(default.predict(Xt) == yt)
    tuned = finetune(default, Xs, ys, sigma=1.0)
    after = np.mean(tuned.predict(Xt) == yt)
    assert before < 0.6 and after > 0.9, (before, after)
    # the standardisation, OOD statistics and prior are the default's: only the weights moved
    for name, m in tuned.submodels_.items():
        np.testing.assert_array_equal(m["mean"], default.submodels_[name]["mean"])
        np.testing.assert_array_equal(m["precision"], default.submodels_[name]["precision"])
    assert not np.allclose(tuned.submodels_["both"]["coef"], default.submodels_["both"]["coef"])


def test_a_handful_of_one_class_cells_does_not_erase_the_other_classes():
    default = EnvironmentClassifier(degree=1).fit(*synthetic_library(1500, 1))
    X, y = synthetic_library(300, 4)
    only_open = y == 0
    tuned = finetune(default, X[only_open][:40], y[only_open][:40], sigma=0.3)
    Xt, yt = synthetic_library(1500, 5)
    recall_heavy = np.mean(tuned.predict(Xt[yt == 2]) == 2)
    assert recall_heavy > 0.8                    # the prior keeps heavy though no heavy window was seen
    # without the prior (σ = ∞) the same 40 open windows teach the model that nothing is heavy (measured 9 %)
    alone = finetune(default, X[only_open][:40], y[only_open][:40], sigma=np.inf)
    assert np.mean(alone.predict(Xt[yt == 2]) == 2) < 0.5


def test_choose_sigma_prefers_a_loose_prior_when_the_site_differs():
    default = EnvironmentClassifier(degree=1).fit(*synthetic_library(1500, 1))
    X, y = _shifted(400, 6, 0.8)
    groups = np.arange(len(y)) // 10                 # 40 "cells" of 10 windows
    sigma, losses = choose_sigma(default, X, y, groups, grid=(0.01, 1.0, 10.0))
    assert set(losses) == {0.01, 1.0, 10.0}
    assert sigma >= 1.0 and losses[0.01] > losses[sigma]


def test_finetune_refuses_bad_input():
    default = EnvironmentClassifier(degree=1).fit(*synthetic_library(300, 1))
    X, y = synthetic_library(50, 2)
    with pytest.raises(ValueError, match="shape"):
        finetune(default, X[:, :13], y, 1.0)
    with pytest.raises(ValueError, match="sigma"):
        finetune(default, X, y, -1.0)
    with pytest.raises(ValueError, match="rows"):
        finetune(default, X, y[:10], 1.0)
