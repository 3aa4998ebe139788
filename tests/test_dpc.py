"""Density-peak clustering: the KD-tree estimator against the dense oracle, and its contract."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

import models.dpc as dpc
from models.dpc import DensityPeakClustering, fit_dpc, select_centers
from tests.dpc_reference import dense_dpc


def _blobs(seed: int, n: int, dim: int = 2, spread: float = 1.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = np.array([[0.0] * dim, [4.0] * dim, [0.0] + [6.0] * (dim - 1)])
    return np.concatenate([rng.normal(c, spread * (1 + i / 2), (n // 3 + (i < n % 3), dim))
                           for i, c in enumerate(centres)])


def _assert_same(m: DensityPeakClustering, ref: dict) -> None:
    assert m.dc_ == ref["dc"]
    np.testing.assert_allclose(m.rho_, ref["rho"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(m.delta_, ref["delta"], rtol=1e-12, atol=0)
    np.testing.assert_array_equal(m.order_, ref["order"])
    np.testing.assert_array_equal(m.nearest_higher_, ref["nearest_higher"])
    np.testing.assert_array_equal(m.centers_, ref["centers"])
    np.testing.assert_array_equal(m.labels_, ref["labels"])
    np.testing.assert_array_equal(m.halo_, ref["halo"])


@pytest.mark.parametrize("kernel", ["cutoff", "gaussian"])
@pytest.mark.parametrize("seed,n,dim,k", [(0, 400, 2, 3), (1, 1500, 2, None), (2, 900, 3, None), (3, 2000, 5, 4)])
def test_matches_dense_oracle(kernel, seed, n, dim, k):
    X = _blobs(seed, n, dim)
    m = DensityPeakClustering(kernel=kernel, n_clusters=k).fit(X)
    _assert_same(m, dense_dpc(X, kernel=kernel, n_clusters=k))


@pytest.mark.parametrize("kernel", ["cutoff", "gaussian"])
def test_matches_oracle_through_the_exact_prefix_search(monkeypatch, kernel):
    """With a 2-NN list only and tiny brute-force blocks, nearly every δ comes from the dyadic
    KD-tree search, which must give the same answer."""
    monkeypatch.setattr(dpc, "_KNN_STEPS", (2,))
    monkeypatch.setattr(dpc, "_BRUTE", 8)
    X = np.random.default_rng(7).uniform(size=(1200, 2))
    _assert_same(DensityPeakClustering(kernel=kernel).fit(X), dense_dpc(X, kernel=kernel))


@pytest.mark.parametrize("kernel,dc", [("cutoff", None), ("cutoff", 1.0), ("cutoff", 2.0), ("gaussian", 1.0)])
def test_ties_on_a_grid_with_duplicates(kernel, dc):
    """Integer grid: many equal densities and equal distances, pairs exactly at d_c, duplicates."""
    g = np.stack(np.meshgrid(np.arange(25), np.arange(20)), -1).reshape(-1, 2).astype(float)
    X = np.concatenate([g, g[::7]])
    m = DensityPeakClustering(kernel=kernel, dc=dc).fit(X)
    _assert_same(m, dense_dpc(X, kernel=kernel, dc=dc))
    # ties in density go to the lower index
    r = m.rho_[m.order_]
    assert np.all(np.diff(r) <= 0)
    same = np.diff(r) == 0
    assert np.all(np.diff(m.order_)[same] > 0)


def test_deterministic_and_permutation_consistent():
    X = _blobs(4, 900)
    a, b = fit_dpc(X, kernel="gaussian"), fit_dpc(X, kernel="gaussian")
    np.testing.assert_array_equal(a.labels_, b.labels_)
    np.testing.assert_array_equal(a.rho_, b.rho_)
    # the same points in another order give the same partition (continuous data: no ties)
    p = np.random.default_rng(0).permutation(len(X))
    c = fit_dpc(X[p], kernel="gaussian")
    assert adjusted_rand_score(a.labels_[p], c.labels_) == 1.0
    np.testing.assert_allclose(c.rho_, a.rho_[p], rtol=1e-12)


@pytest.mark.parametrize("kernel", ["cutoff", "gaussian"])
def test_separated_blobs_recovered_automatically(kernel):
    rng = np.random.default_rng(5)
    centres = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], float)
    y = np.repeat(np.arange(4), 250)
    X = centres[y] + rng.normal(0, 0.7, (1000, 2))
    m = DensityPeakClustering(kernel=kernel).fit(X)
    assert m.n_clusters_ == 4
    assert adjusted_rand_score(y, m.labels_) == 1.0
    assert adjusted_rand_score(y, m.fit_predict(X)) == 1.0
    # one centre per blob, each at the cluster's densest point, labelled by its position
    np.testing.assert_array_equal(m.labels_[m.centers_], np.arange(4))
    for c, i in enumerate(m.centers_):
        members = m.labels_ == c
        assert m.rho_[i] == m.rho_[members].max()
    np.testing.assert_array_equal(m.gamma_, m.rho_ * m.delta_)


def test_given_n_clusters_takes_the_largest_gamma():
    X = _blobs(6, 600)
    m = DensityPeakClustering(n_clusters=5).fit(X)
    assert m.n_clusters_ == 5 and len(np.unique(m.labels_)) == 5
    top = np.sort(m.gamma_)[::-1][:5]
    np.testing.assert_allclose(np.sort(m.gamma_[m.centers_])[::-1], top)
    assert m.centers_[0] == m.order_[0]                 # the densest point is always a centre
    assert m.nearest_higher_[m.order_[0]] == -1
    assert m.delta_[m.order_[0]] == pytest.approx(np.linalg.norm(X - X[m.order_[0]], axis=1).max())


def test_halo_lies_between_clusters_and_keeps_cores():
    """Two touching blobs: halo points are less dense than every core point of their cluster;
    the saddle between the blobs is mostly halo, the blob centres none."""
    rng = np.random.default_rng(8)
    X = np.concatenate([rng.normal(0, 1, (500, 2)), rng.normal([3.5, 0], 1, (500, 2))])
    m = DensityPeakClustering(n_clusters=2).fit(X)
    assert 0 < m.halo_.sum() < 0.8 * len(X)
    for c in range(2):
        core, halo = (m.labels_ == c) & ~m.halo_, (m.labels_ == c) & m.halo_
        assert core.sum() > 100
        assert m.rho_[halo].max() < m.rho_[core].min()
    saddle = np.abs(X[:, 0] - 1.75) < 0.3
    assert 0.8 < m.halo_[saddle].mean() <= 1.0
    for cx in (0.0, 3.5):
        assert not m.halo_[np.hypot(X[:, 0] - cx, X[:, 1]) < 0.5].any()
    far = DensityPeakClustering(n_clusters=2).fit(np.concatenate([X[:500], X[:500] + [50, 0]]))
    assert not far.halo_.any()                            # no border region, no halo


def test_select_centers_gap_rule():
    rho = np.array([10.0, 9, 8, 2, 2, 1])
    delta = np.array([99.0, 5, 4, 0.5, 0.4, 0.3])
    order = np.arange(6)
    # gamma (densest with delta capped at 5): 50, 45, 32, 1, 0.8, 0.3: the gap is after 3
    np.testing.assert_array_equal(select_centers(rho, delta, order), [0, 1, 2])
    np.testing.assert_array_equal(select_centers(rho, delta, order, n_clusters=2), [0, 1])
    # only the 3 largest considered: 50, 45, 32, the larger ratio is 45/32
    np.testing.assert_array_equal(select_centers(rho, delta, order, max_clusters=2), [0, 1])
    np.testing.assert_array_equal(select_centers(rho, delta, order, max_clusters=1), [0])


@pytest.mark.parametrize("params,match", [
    ({"kernel": "tophat"}, r"'kernel' parameter .* Got 'tophat'"),
    ({"percent": 0}, r"'percent' parameter .* Got 0"),
    ({"percent": 150.0}, r"'percent' parameter .* Got 150.0"),
    ({"dc": -1.0}, r"'dc' parameter .* Got -1.0"),
    ({"n_clusters": 0}, r"'n_clusters' parameter .* Got 0"),
    ({"max_neighbors": 2.5}, r"'max_neighbors' parameter .* Got 2.5"),
    ({"n_clusters": 50}, r"n_clusters=50 exceeds the number of samples 10"),
])
def test_parameter_validation_names_parameter_and_value(params, match):
    X = np.random.default_rng(0).normal(size=(10, 2))
    with pytest.raises(ValueError, match=match):
        DensityPeakClustering(**params).fit(X)


@pytest.mark.parametrize("X,match", [
    (np.array([[0.0, np.nan], [1, 1], [2, 2]]), "NaN"),
    (np.zeros((1, 2)), "minimum of 2"),
    (np.zeros((50, 2)), "d_c from percent"),
])
def test_bad_input(X, match):
    with pytest.raises(ValueError, match=match):
        DensityPeakClustering().fit(X)


def test_sklearn_clone_and_params():
    from sklearn.base import clone
    m = DensityPeakClustering(kernel="gaussian", percent=1.0)
    c = clone(m)
    assert c.get_params() == m.get_params()
    assert not hasattr(c, "labels_")


def test_centre_rule_is_rho_times_delta_where_rho_plus_delta_disagrees():
    """Issue 20: a case worked by hand where the paper's γ = ρ·δ and a mistaken ρ + δ pick other centres.

    1-D points, cutoff kernel, d_c = 0.1 (no distance lies near it): A = 0.00 … 0.05 (6 points, 0.01
    apart: ρ = 5 each), B = 0.30 … 0.34 (5 points: ρ = 4), C = 2.00, 2.01 (ρ = 1). Ties in ρ go to
    the lower index, so the order is A, B, C in index order. δ: the densest point (index 0) takes
    its largest distance, 2.01; each other point of A, B, C is 0.01 from the one before it; B's
    first point is 0.30 − 0.05 = 0.25 from A, C's first 2.00 − 0.34 = 1.66 from B.
    γ = ρ·δ: 10.05 (index 0), 1.66 (index 11, C), 1.00 (index 6, B), then 0.05, 0.04, 0.01.
    ρ + δ would rank A's other points (5.01) and B's first (4.25) above C's first (2.66).
    """
    X = np.r_[0.00, 0.01, 0.02, 0.03, 0.04, 0.05, 0.30, 0.31, 0.32, 0.33, 0.34, 2.00, 2.01][:, None]
    rho = [5.0] * 6 + [4.0] * 5 + [1.0] * 2
    delta = [2.01] + [0.01] * 5 + [0.25] + [0.01] * 4 + [1.66, 0.01]
    m = DensityPeakClustering(kernel="cutoff", dc=0.1, n_clusters=2).fit(X)
    np.testing.assert_array_equal(m.rho_, rho)
    np.testing.assert_allclose(m.delta_, delta, rtol=1e-9)
    np.testing.assert_allclose(m.gamma_, np.multiply(rho, delta), rtol=1e-9)
    np.testing.assert_array_equal(m.centers_, [0, 11])                 # ρ + δ: [0, 1]
    np.testing.assert_array_equal(m.labels_, [0] * 11 + [1] * 2)       # B follows its upslope into A
    # automatic: the knee. δ of the densest point replaced by the largest other (1.66): γ = 8.3, 1.66,
    # 1.0, 0.05 …; ratios 5.0, 1.66, 20 -> cut after the third: A, C, B
    auto = DensityPeakClustering(kernel="cutoff", dc=0.1).fit(X)
    np.testing.assert_array_equal(auto.centers_, [0, 11, 6])
    np.testing.assert_array_equal(auto.labels_, [0] * 6 + [2] * 5 + [1] * 2)
    # the decision-graph function alone, on the hand values
    order = np.arange(13)
    np.testing.assert_array_equal(select_centers(np.array(rho), np.array(delta), order, n_clusters=2), [0, 11])
    np.testing.assert_array_equal(select_centers(np.array(rho), np.array(delta), order), [0, 11, 6])
    # and the dense oracle, which now imports nothing from models.dpc, says the same
    ref = dense_dpc(X, kernel="cutoff", dc=0.1, n_clusters=2)
    np.testing.assert_array_equal(ref["centers"], [0, 11])
    _assert_same(m, ref)
