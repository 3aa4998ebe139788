"""Unsupervised classes of library windows: DPC and K-means, complete rows only, subsample then classify."""

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

from features.errors import DataError
from training.clustering import cluster_windows


def _windows(n=900, seed=0):
    """Three well-separated classes whose severity grows with attenuation and delay spread, falling K."""
    rng = np.random.default_rng(seed)
    y = rng.choice(3, size=n, p=[0.5, 0.3, 0.2])
    base = np.array([[2, 1, 0.5, 0.05, 0.1, 0.5, 0.7, 3, 1, 3, -10, 5, 3, -1]], float)
    step = np.array([[6, 2, 0.3, 0.2, 0.8, 1.2, 1.0, 0, 0, -4, -2, 1, 0, 0]], float)
    X = base + y[:, None] * step + rng.normal(size=(n, 14)) * 0.25 * (np.abs(step) + 0.2)
    X[:30, :5] = np.nan                      # a few windows without GNSS
    return X, y


@pytest.mark.parametrize("method", ["dpc", "kmeans"])
def test_classes_found_and_named_by_severity(method):
    X, y = _windows()
    res = cluster_windows(X, method=method, random_state=1)
    ok = res.labels >= 0
    assert not ok[:30].any() and ok[30:].all()             # incomplete windows are not clustered
    assert adjusted_rand_score(y[ok], res.labels[ok]) > 0.9
    assert np.mean(res.labels[ok] == y[ok]) > 0.95         # named open < light < heavy by severity


def test_large_library_is_subsampled_then_classified():
    X, y = _windows(n=1500, seed=3)
    full = cluster_windows(X, method="kmeans", random_state=2)
    sub = cluster_windows(X, method="kmeans", random_state=2, max_windows=300)
    ok = full.labels >= 0
    assert np.array_equal(ok, sub.labels >= 0)             # every complete window still gets a class
    assert sub.clustered.sum() == 300
    assert np.mean(sub.labels[ok] == full.labels[ok]) > 0.95
    assert np.array_equal(sub.labels, cluster_windows(X, method="kmeans", random_state=2, max_windows=300).labels)


def test_too_few_complete_windows():
    X, _ = _windows(n=60)
    X[:, 5:] = np.nan
    with pytest.raises(DataError, match="both GNSS and acoustic"):
        cluster_windows(X)
