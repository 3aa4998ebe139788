"""Unsupervised environment classes of library windows: the paper's route, and K-means beside it.

``method="dpc"`` (default): standardise → t-SNE to 2-D → density-peak
clustering → clusters named open / light / heavy by severity
(:class:`models.embedding.EnvironmentEmbedding`). ``method="kmeans"``: k = 3
K-means on the standardised 14-D windows (scikit-learn, ``n_init=10``), named
by the same severity rule — the baseline a data scientist would try first.

Large libraries: t-SNE and the density-peak search run on a seeded random
subsample of at most ``max_windows`` complete windows (default 20,000, about
a minute on one core); an :class:`models.environment.EnvironmentClassifier`
fitted on the subsample's clusters then labels the other windows — the same
classifier that classifies new windows online, so the library and a new
window are treated alike. This keeps the whole model on 100,000 windows
within minutes (``bench/bench_env_model.py``).

Only windows with every feature (both modalities) are clustered: t-SNE and
K-means need complete rows, and imputing a modality would invent the
statistics the classes are told apart by. The others get label −1 (the
online classifier still answers for them, from its single-modality
sub-models trained on the clustered windows' features). Data with fewer than
40 complete windows but a single modality throughout — a vehicle's drive has
GNSS and no beacons — are clustered on that modality's features alone
(:func:`cluster_columns`), and the clusters are named by the severity features
among them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from features.errors import DataError
from features.schema import ENV_CLASSES, FEATURES

__all__ = ["ClusterResult", "cluster_windows", "cluster_columns"]

_MIN_WINDOWS = 40
"""Fewest complete windows the clustering accepts."""


@dataclass(frozen=True)
class ClusterResult:
    """``labels`` (n,) class codes (−1: not clustered), ``n_clusters`` found before naming, ``method``,
    ``embedding`` (n, 2) for DPC (NaN rows where not clustered) or None, ``rho``/``delta``/``centers`` of
    the DPC decision graph (over the clustered rows) or None, ``clusters`` (n,) the cluster index of each
    window before naming (−1: not clustered, or labelled by the classifier beyond ``max_windows``)."""

    labels: np.ndarray
    n_clusters: int
    method: str
    embedding: np.ndarray | None = None
    rho: np.ndarray | None = None
    delta: np.ndarray | None = None
    centers: np.ndarray | None = None
    clustered: np.ndarray | None = None
    clusters: np.ndarray | None = None


def cluster_columns(X: np.ndarray) -> tuple[int, ...]:
    """The feature columns the windows of ``X`` (n, 14) are clustered on: all 14 when at least 40 windows have
    both modalities; else, when one modality has at least 40 complete windows and the other none at all, that
    modality's columns; else all 14 (and :func:`cluster_windows` refuses).

    >>> X = np.full((50, 14), np.nan); X[:, :5] = 1.0
    >>> cluster_columns(X)
    (0, 1, 2, 3, 4)
    """
    from features.schema import MODALITIES, modality_columns

    X = np.asarray(X, float)
    every = tuple(range(len(FEATURES)))
    if np.isfinite(X).all(axis=1).sum() >= _MIN_WINDOWS:
        return every
    for m, other in zip(MODALITIES, MODALITIES[::-1]):
        cols, rest = list(modality_columns(m)), list(modality_columns(other))
        if np.isfinite(X[:, cols]).all(axis=1).sum() >= _MIN_WINDOWS and not np.isfinite(X[:, rest]).any():
            return tuple(cols)
    return every


def cluster_windows(X: np.ndarray, *, method: str = "dpc", random_state: int = 0,
                    n_clusters: int | None = None, max_windows: int = 20_000) -> ClusterResult:
    """Cluster the complete windows of ``X`` (n, 14) on :func:`cluster_columns` and name the clusters by
    severity."""
    from models.embedding import EnvironmentEmbedding, canonical_order, name_clusters, severity_scores, tsne_backend

    X = np.asarray(X, float)
    if X.ndim != 2 or X.shape[1] != len(FEATURES):
        raise DataError(f"windows must have shape (n, {len(FEATURES)}), got {X.shape}")
    cols = list(cluster_columns(X))
    names = [FEATURES[c] for c in cols]
    complete = np.isfinite(X[:, cols]).all(axis=1)
    if complete.sum() < _MIN_WINDOWS:
        raise DataError(f"only {int(complete.sum())} windows have both GNSS and acoustic features (and not one "
                        f"modality throughout); clustering needs at least {_MIN_WINDOWS}")
    rows = np.flatnonzero(complete)
    if rows.size > max_windows:
        # drawn from the rows in canonical order: the same library in another row order gives the same subsample
        rows = rows[canonical_order(X[rows][:, cols])]
        rows = np.sort(np.random.default_rng(random_state).choice(rows, size=max_windows, replace=False))
    sub = np.zeros(len(X), bool)
    sub[rows] = True
    Xc = X[sub][:, cols]
    labels = np.full(len(X), -1)
    if method == "dpc":
        emb = EnvironmentEmbedding(random_state=random_state, n_clusters=n_clusters, feature_names=names).fit(Xc)
        labels[sub] = [ENV_CLASSES.index(c) for c in emb.classes_]
        clusters = np.full(len(X), -1)
        clusters[sub] = emb.labels_
        embedding = np.full((len(X), 2), np.nan)
        embedding[sub] = emb.embedding_
        _label_rest(X, labels, complete & ~sub)
        backend = {"opentsne": "openTSNE", "sklearn": "scikit-learn"}[tsne_backend(emb.tsne)]
        return ClusterResult(labels, int(emb.n_clusters_), f"t-SNE + DPC ({backend})", embedding,
                             emb.rho_, emb.delta_, emb.centers_, sub, clusters)
    if method == "kmeans":
        from sklearn.cluster import KMeans
        from sklearn.preprocessing import StandardScaler

        order = canonical_order(Xc)                  # k-means++ draws by row index: canonical order
        Z = StandardScaler().fit_transform(Xc[order])
        km = KMeans(n_clusters=n_clusters or 3, n_init=10, random_state=random_state).fit(Z)
        km_labels = np.empty(len(order), np.int64)
        km_labels[order] = km.labels_
        named = name_clusters(severity_scores(Xc, km_labels, names))
        labels[sub] = [ENV_CLASSES.index(named[k]) for k in km_labels]
        clusters = np.full(len(X), -1)
        clusters[sub] = km_labels
        _label_rest(X, labels, complete & ~sub)
        return ClusterResult(labels, int(km.n_clusters), "K-means (k = 3)", clustered=sub, clusters=clusters)
    raise DataError(f"clustering method must be 'dpc' or 'kmeans', got {method!r}")


def _label_rest(X: np.ndarray, labels: np.ndarray, rest: np.ndarray) -> None:
    """Label the complete windows left out of the subsample with a classifier of the subsample's clusters."""
    if not rest.any():
        return
    from models.environment import EnvironmentClassifier

    from models.embedding import canonical_order

    done = np.flatnonzero(labels >= 0)
    if len(np.unique(labels[done])) < 2:
        labels[rest] = int(np.bincount(labels[done]).argmax())
        return
    done = done[canonical_order(X[done])]            # fitted in canonical order: independent of the row order
    labels[rest] = EnvironmentClassifier().fit(X[done], labels[done]).predict(X[rest])
