"""Density-peak clustering on the labelled SIPU benchmark sets (../shared/data/clustering).

For each set: our ARI (``sklearn.metrics.adjusted_rand_score`` against ``labels0``, which has
no noise points in these sets) with the true number of clusters given, pinned as a change
detector (±0.002); the published density-peak figure, ADPclust (Wang & Xu 2017, FCPS 1.3.4,
column ``FCPS_AdaptiveDensityPeak`` of ``adpclust_results/<name>.result<K>.gz``, also given the
true K), recomputed here from its result file; and ours >= published.

The kernel and percent per set are the better of {cutoff, gaussian} × {1, 2} % (everything
else at its default) — chosen on the labels, so these are best-of-four figures, stated as such;
``cutoff_2`` is the all-defaults figure. ADPclust tunes its own bandwidth by silhouette.

Six sets stay below ADPclust with every one of the four settings (``SHORTFALL``); their
``>=`` test is a strict xfail, so an improvement shows up as XPASS and must be recorded.
"""

from __future__ import annotations

import csv
import gzip

import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

from models.dpc import DensityPeakClustering
from tests.conftest import shared_data

# name: (K, published ADPclust ARI, our ARI all defaults (cutoff, 2 %), kernel, percent, our ARI)
BENCH = {
    "a1": (20, 0.9134, 0.9576, "cutoff", 2.0, 0.9576),
    "a2": (35, 0.9570, 0.9575, "cutoff", 1.0, 0.9654),
    "a3": (50, 0.9708, 0.9622, "gaussian", 1.0, 0.9627),
    "aggregation": (7, 0.8799, 0.9978, "cutoff", 2.0, 0.9978),
    "compound": (6, 0.7611, 0.5094, "cutoff", 1.0, 0.6116),
    "d31": (31, 0.9523, 0.9378, "cutoff", 1.0, 0.9378),
    "flame": (2, 0.3773, 0.5117, "gaussian", 1.0, 0.5861),
    "jain": (2, 0.5818, 0.5146, "gaussian", 1.0, 0.6438),
    "pathbased": (3, 0.4757, 0.3591, "gaussian", 1.0, 0.4679),
    "r15": (15, 0.9891, 0.9821, "gaussian", 2.0, 0.9928),
    "s1": (15, 0.9855, 0.9897, "gaussian", 2.0, 0.9897),
    "s2": (15, 0.9384, 0.9370, "cutoff", 2.0, 0.9370),
    "s3": (15, 0.7297, 0.7181, "gaussian", 2.0, 0.7267),
    "s4": (15, 0.6384, 0.6250, "cutoff", 1.0, 0.6405),
    "spiral": (3, -0.0059, 0.1168, "gaussian", 2.0, 1.0000),
    "unbalance": (8, 0.7329, 0.7847, "gaussian", 1.0, 1.0000),
}

SHORTFALL = {"a3", "compound", "d31", "pathbased", "s2", "s3"}
"""Sets where plain DPC (either kernel, 1 or 2 %) stays below ADPclust's ARI."""

PIN_TOL = 0.002


def _load(name: str):
    base = shared_data("clustering")
    X = np.loadtxt(base / "sipu" / f"{name}.data.gz")
    y = np.loadtxt(base / "sipu" / f"{name}.labels0.gz", dtype=int)
    return base, X, y


def _published(base, name: str, k: int) -> np.ndarray:
    with gzip.open(base / "adpclust_results" / f"{name}.result{k}.gz", "rt") as fh:
        rows = list(csv.reader(fh))
    col = rows[0].index("FCPS_AdaptiveDensityPeak")
    return np.array([int(r[col]) for r in rows[1:]])


def _ours(X, kernel, percent, k):
    return DensityPeakClustering(kernel=kernel, percent=percent, n_clusters=k).fit(X).labels_


@pytest.fixture(scope="module")
def results():
    """name -> (published ARI, defaults ARI, best-of-four ARI), computed once per module."""
    out = {}
    for name, (k, _, _, kernel, percent, _) in BENCH.items():
        base, X, y = _load(name)
        pub = adjusted_rand_score(y, _published(base, name, k))
        default = adjusted_rand_score(y, _ours(X, "cutoff", 2.0, k))
        best = default if (kernel, percent) == ("cutoff", 2.0) else adjusted_rand_score(y, _ours(X, kernel, percent, k))
        out[name] = (pub, default, best)
    return out


@pytest.mark.parametrize("name", sorted(BENCH))
def test_published_figure_recomputed(results, name):
    assert results[name][0] == pytest.approx(BENCH[name][1], abs=5e-4)


@pytest.mark.parametrize("name", sorted(BENCH))
def test_ari_pinned(results, name):
    _, default, best = results[name]
    assert default == pytest.approx(BENCH[name][2], abs=PIN_TOL)
    assert best == pytest.approx(BENCH[name][5], abs=PIN_TOL)


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason="plain DPC below ADPclust here (see SHORTFALL)"))
    if n in SHORTFALL else n for n in sorted(BENCH)])
def test_at_least_published(results, name):
    pub, _, best = results[name]
    assert best >= pub


def test_shortfalls_are_small_on_the_gaussian_blob_sets(results):
    """Where DPC falls short on sets of overlapping gaussian blobs, it is by under 0.02 ARI."""
    for name in ("a3", "d31", "s2", "s3"):
        pub, _, best = results[name]
        assert 0 < pub - best < 0.02
