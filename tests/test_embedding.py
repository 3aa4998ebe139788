"""Standardise → t-SNE → DPC pipeline and the severity naming of its clusters."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

import models.embedding as emb
from models.dpc import DensityPeakClustering
from models.embedding import (ENV_CLASSES, ENV_FEATURES, SEVERITY_WEIGHTS, EnvironmentEmbedding, name_clusters,
                              severity_scores)
from tests.env_synth import CLASSES, synthetic_library

N = 600


@pytest.fixture(scope="module")
def library():
    return synthetic_library(N, seed=1)


@pytest.fixture(scope="module")
def fitted(library):
    return EnvironmentEmbedding(n_clusters=3, random_state=3).fit(library[0])


def test_feature_order_is_the_design_order():
    assert ENV_FEATURES == ("att_mean_db", "att_std_db", "fluct_per_s", "invisible_ratio", "dop_growth",
                            "mean_excess_delay_ms", "rms_delay_ms", "delay_kurtosis", "delay_skewness",
                            "rician_k_db", "gain_mean_db", "gain_rms_db", "gain_kurtosis", "gain_skewness")
    assert set(SEVERITY_WEIGHTS) <= set(ENV_FEATURES)
    assert ENV_CLASSES == CLASSES


def test_same_seed_same_result(library, fitted):
    again = EnvironmentEmbedding(n_clusters=3, random_state=3).fit(library[0])
    np.testing.assert_array_equal(again.embedding_, fitted.embedding_)
    np.testing.assert_array_equal(again.labels_, fitted.labels_)
    assert again.tsne_seed_ == fitted.tsne_seed_


def test_seed_reaches_tsne(monkeypatch, library):
    """The seed drawn once from random_state is the one t-SNE receives (stubbed: no t-SNE run)."""
    seen = []

    def fake_tsne(Z, *, backend, perplexity, random_state, n_jobs):
        seen.append(random_state)
        return np.random.default_rng(random_state).normal(size=(len(Z), 2))

    monkeypatch.setattr(emb, "tsne_2d", fake_tsne)
    X = library[0]
    a = EnvironmentEmbedding(random_state=3).fit(X)
    b = EnvironmentEmbedding(random_state=np.random.RandomState(3)).fit(X)
    c = EnvironmentEmbedding(random_state=4).fit(X)
    assert seen == [a.tsne_seed_, b.tsne_seed_, c.tsne_seed_]
    assert a.tsne_seed_ == b.tsne_seed_ != c.tsne_seed_
    assert a.tsne_seed_ == np.random.RandomState(3).randint(np.iinfo(np.int32).max)


def test_severity_naming_recovers_the_known_classes(library, fitted):
    X, y = library
    assert fitted.embedding_.shape == (N, 2)
    assert fitted.n_clusters_ == 3
    assert 0.85 <= adjusted_rand_score(y, fitted.labels_) <= 1.0
    truth = np.asarray(CLASSES)[y]
    acc = np.mean(fitted.classes_ == truth)
    assert 0.93 <= acc <= 1.0
    assert sorted(fitted.cluster_classes_) == sorted(ENV_CLASSES)
    # severity increases open -> light -> heavy
    sev = {name: s for name, s in zip(fitted.cluster_classes_, fitted.severity_)}
    assert sev["open"] < sev["light"] < sev["heavy"]


def test_automatic_cluster_count_on_the_embedding(fitted):
    """The decision-graph rule on the same embedding, with the density the embedding chose for 600 windows (the
    gaussian kernel, issue 27), finds the three classes by itself."""
    assert fitted.kernel_ == "gaussian"
    m = DensityPeakClustering(kernel=fitted.kernel_).fit(fitted.embedding_)
    assert m.n_clusters_ == 3
    assert adjusted_rand_score(fitted.labels_, m.labels_) > 0.9


def test_severity_scores_signs():
    """One feature at a time: raising a 'worse' feature raises severity, raising K lowers it."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 14))
    labels = np.repeat([0, 1], 100)
    for name, w in SEVERITY_WEIGHTS.items():
        Xs = X.copy()
        Xs[labels == 1, ENV_FEATURES.index(name)] += 5.0
        s = severity_scores(Xs, labels)
        assert np.sign(s[1] - s[0]) == np.sign(w)
    # shape features do not count
    Xs = X.copy()
    Xs[labels == 1, ENV_FEATURES.index("gain_skewness")] += 5.0
    np.testing.assert_allclose(severity_scores(Xs, labels), severity_scores(X, labels), atol=1e-12)


def test_severity_scores_ignore_a_missing_modality():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(100, 14))
    labels = np.repeat([0, 1], 50)
    X[labels == 1, ENV_FEATURES.index("att_mean_db")] += 4
    X[labels == 1, 5:] = np.nan                          # no beacon heard in cluster 1
    s = severity_scores(X, labels)
    assert np.all(np.isfinite(s)) and s[1] > s[0] + 2


@pytest.mark.parametrize("severity,expected", [
    ([0.3, -1.2, 2.5], ["light", "open", "heavy"]),
    ([5.0, 1.0, 4.0, 0.0, 3.0, 2.0], ["heavy", "open", "heavy", "open", "light", "light"]),
    ([0.0, 1.0, 2.0, 3.0], ["open", "open", "light", "heavy"]),
    ([1.0, -1.0], ["heavy", "open"]),
    ([7.0], ["open"]),
    ([1.0, 1.0, 0.0], ["light", "heavy", "open"]),          # tie: lower index ranks first
])
def test_name_clusters(severity, expected):
    assert name_clusters(np.array(severity)) == expected


@pytest.mark.parametrize("params,match", [
    ({"tsne": "umap"}, r"'tsne' parameter .* Got 'umap'"),
    ({"perplexity": -3}, r"'perplexity' parameter .* Got -3"),
    ({"feature_names": ["a", "b"]}, "feature_names has 2 names for X with 14 columns"),
    ({"perplexity": 50.0}, r"perplexity=50.0 must be below the number of samples 20"),
])
def test_validation(params, match):
    X = np.random.default_rng(0).normal(size=(20, 14))
    with pytest.raises(ValueError, match=match):
        EnvironmentEmbedding(**params).fit(X)


def test_nan_rows_are_refused():
    X = np.random.default_rng(0).normal(size=(50, 14))
    X[3, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        EnvironmentEmbedding(random_state=0).fit(X)


# Which way each feature moves when the sky and the beacons are blocked, from the physics (docs/design.md §5),
# written here, not read from SEVERITY_WEIGHTS: attenuation, invisible ratio, DOP growth and the delay
# spread grow; the Rician K (first path over the rest) falls; the others do not enter the score.
_DIRECTION = {"att_mean_db": 1, "invisible_ratio": 1, "dop_growth": 1, "rms_delay_ms": 1, "rician_k_db": -1}


@pytest.mark.parametrize("name", ENV_FEATURES)
def test_severity_direction_is_hard_coded_per_feature(name):
    """Issue 20: two clusters of two windows, one feature 0, 0 | 2, 2 (z = −1, −1 | +1, +1), every other
    feature constant (z = 0): cluster 1's severity is +2, −2 or 0 relative to cluster 0 by hand."""
    X = np.ones((4, len(ENV_FEATURES)))
    X[:, ENV_FEATURES.index(name)] = [0.0, 0.0, 2.0, 2.0]
    s = severity_scores(X, np.array([0, 0, 1, 1]))
    d = _DIRECTION.get(name, 0)
    np.testing.assert_allclose(s, [-d, d], atol=1e-12)


def test_severity_of_a_blocked_cluster_by_hand():
    """Attenuation 2 → 8 dB, invisible ratio 0 → 0.5, Rician K 12 → 4 dB between two clusters of two windows:
    z = ∓1 on each, so severity = (−1 − 1 − (+1)) = −3 for the open cluster and +3 for the blocked one,
    which is named heavy (the other open) — whatever the cluster index."""
    X = np.zeros((4, len(ENV_FEATURES)))
    X[:, ENV_FEATURES.index("att_mean_db")] = [8.0, 8.0, 2.0, 2.0]
    X[:, ENV_FEATURES.index("invisible_ratio")] = [0.5, 0.5, 0.0, 0.0]
    X[:, ENV_FEATURES.index("rician_k_db")] = [4.0, 4.0, 12.0, 12.0]
    s = severity_scores(X, np.array([0, 0, 1, 1]))
    np.testing.assert_allclose(s, [3.0, -3.0], atol=1e-12)
    assert name_clusters(s) == ["heavy", "open"]
