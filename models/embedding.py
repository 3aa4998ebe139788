"""Environment classes from the 14 window features: standardise → t-SNE to 2-D → density peaks,
then clusters named ``open`` / ``light`` / ``heavy`` by a severity order.

The route of the method this package implements (docs/design.md §5, issue 13 item 4): t-SNE (van der
Maaten & Hinton, JMLR 9:2579, 2008) maps the standardised windows to a plane where
density-peak clustering (Rodriguez & Laio, Science 2014; :mod:`models.dpc`) finds the
environment clusters without labels; t-SNE cannot place new points, so classifying new windows
is left to a classifier trained on these labels.

t-SNE backend: openTSNE (Poličar et al., J. Stat. Softw. 109(3), 2024; FFT-accelerated
interpolation, Linderman et al., Nat. Methods 16:243, 2019) or scikit-learn's Barnes–Hut TSNE.
Measured in one run of ``bench/bench_dpc.py`` (20,000 synthetic 14-feature windows, one core
each on a shared 2-core VM, perplexity 30, PCA initialisation, each at its default iterations):
t-SNE + DPC with openTSNE 245 s, scikit-learn 482 s (2.0x, also when each is divided by the
``oaconvolve`` yardstick timed in its own process; an earlier run on a busier machine gave
571 s and 848 s); trustworthiness (k = 10, on a fixed 5,000-window subset) 0.9607 and 0.9646;
both give 3 clusters, named with ARI 0.997 against the synthetic classes. openTSNE is the
faster at trustworthiness equal to 0.004, so ``tsne="auto"`` means openTSNE when it is
installed, scikit-learn otherwise.
"""

from __future__ import annotations

from numbers import Integral, Real

import numpy as np
from sklearn.base import BaseEstimator, ClusterMixin, _fit_context
from sklearn.preprocessing import StandardScaler
from sklearn.utils import check_random_state
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import validate_data

from features.acoustic.cir import FEATURE_NAMES as _CIR_FEATURES
from features.gnss.features import FEATURE_COLUMNS as _GNSS_FEATURES
from models.dpc import DensityPeakClustering

__all__ = ["ENV_FEATURES", "ENV_CLASSES", "SEVERITY_WEIGHTS", "EnvironmentEmbedding", "tsne_2d", "tsne_backend",
           "severity_scores", "name_clusters", "canonical_order", "density_kernel", "GAUSSIAN_BELOW_NEIGHBOURS"]

ENV_FEATURES: tuple[str, ...] = tuple(_GNSS_FEATURES) + tuple(_CIR_FEATURES)
"""The 14 window features in library order (docs/design.md §5): 5 GNSS, then 9 acoustic CIR."""

ENV_CLASSES: tuple[str, ...] = ("open", "light", "heavy")
"""Environment class names, least to most severe (docs/design.md §4)."""

SEVERITY_WEIGHTS: dict[str, float] = {
    "att_mean_db": 1.0, "invisible_ratio": 1.0, "dop_growth": 1.0, "rms_delay_ms": 1.0, "rician_k_db": -1.0,
}
"""Sign (and weight) of each standardised feature in the severity score: GNSS attenuation,
invisible ratio and DOP growth rise under blocking (docs/design.md §5 items 1, 4, 5), so does the
acoustic delay spread τ_rms (item 7), and the Rician K (first path over the rest, item 10) falls."""


GAUSSIAN_BELOW_NEIGHBOURS = 50
"""With ``kernel="auto"``, density-peak clustering uses the gaussian kernel when the neighbour rule expects fewer
than this many points within d_c (percent·(n − 1)/100: below 2,500 windows at the default 2 %). A cutoff count
of a few tens has many ties among the densest points, which decide the centres."""


def density_kernel(kernel: str, n: int, percent: float) -> str:
    """The DPC kernel ``kernel`` means for ``n`` points ("auto": gaussian below :data:`GAUSSIAN_BELOW_NEIGHBOURS`
    expected neighbours, cutoff above).

    >>> density_kernel("auto", 900, 2.0), density_kernel("auto", 20_000, 2.0), density_kernel("cutoff", 90, 2.0)
    ('gaussian', 'cutoff', 'cutoff')
    """
    if kernel != "auto":
        return kernel
    return "gaussian" if percent * (n - 1) / 100.0 < GAUSSIAN_BELOW_NEIGHBOURS else "cutoff"


def canonical_order(X: np.ndarray) -> np.ndarray:
    """Row indices of ``X`` (n, d) in lexicographic order of the rows (first column first; equal rows keep
    their relative order, and are interchangeable), shape (n,): the same rows in any order give the same
    sorted array.

    >>> canonical_order(np.array([[2.0, 1.0], [1.0, 5.0], [1.0, 3.0]])).tolist()
    [2, 1, 0]
    """
    X = np.asarray(X, float)
    return np.lexsort(X.T[::-1]).astype(np.int64)


def _opentsne_available() -> bool:
    try:
        import openTSNE  # noqa: F401
    except ImportError:
        return False
    return True


def tsne_backend(backend: str = "auto") -> str:
    """The t-SNE implementation ``backend`` means: "opentsne" or "sklearn" ("auto": openTSNE when installed)."""
    if backend == "auto":
        return "opentsne" if _opentsne_available() else "sklearn"
    return backend


def tsne_2d(Z: np.ndarray, *, backend: str = "auto", perplexity: float = 30.0, random_state: int = 0,
            n_jobs: int = 1) -> np.ndarray:
    """2-D t-SNE of ``Z`` (n_samples, n_features), shape (n_samples, 2).

    ``backend``: "opentsne", "sklearn" or "auto" (openTSNE when installed; module docstring).
    Both start from the PCA initialisation, with the learning rate of each library's "auto"
    rule (growing with n, after Belkina et al., Nat. Commun. 10:5415, 2019) and its default
    iterations (openTSNE 250 + 500, scikit-learn 1000 in all).
    """
    backend = tsne_backend(backend)
    if backend == "opentsne":
        from openTSNE import TSNE as OpenTSNE
        emb = OpenTSNE(n_components=2, perplexity=perplexity, initialization="pca", random_state=random_state,
                       n_jobs=n_jobs, verbose=False).fit(Z)
        return np.asarray(emb, dtype=float)
    from sklearn.manifold import TSNE
    return TSNE(n_components=2, perplexity=perplexity, init="pca", learning_rate="auto",
                random_state=random_state, n_jobs=n_jobs).fit_transform(Z).astype(float)


def severity_scores(X: np.ndarray, labels: np.ndarray, feature_names=ENV_FEATURES,
                    weights: dict[str, float] | None = None) -> np.ndarray:
    """Severity of every cluster 0 … max(labels), shape (n_clusters,).

    ``X`` (n_samples, n_features) is standardised here (z-scores over all rows, NaN ignored);
    a cluster's severity is Σ_f w_f · mean z_f over its members for the features of
    :data:`SEVERITY_WEIGHTS` (features missing from ``feature_names``, or all-NaN in a cluster,
    drop out of that sum). Larger means more obstructed.
    """
    weights = SEVERITY_WEIGHTS if weights is None else weights
    X = np.asarray(X, dtype=float)
    labels = np.asarray(labels)
    names = list(feature_names)
    cols = [(names.index(f), w) for f, w in weights.items() if f in names]
    if not cols:
        raise ValueError(f"none of the severity features {sorted(weights)} is among feature_names")
    mu = np.nanmean(X, axis=0)
    sd = np.nanstd(X, axis=0)
    Z = (X - mu) / np.where(sd > 0, sd, 1.0)
    k = int(labels.max()) + 1
    out = np.zeros(k)
    for c in range(k):
        rows = Z[labels == c]
        for j, w in cols:
            v = rows[:, j]
            v = v[np.isfinite(v)]
            if v.size:
                out[c] += w * v.mean()
    return out


def name_clusters(severity: np.ndarray, classes=ENV_CLASSES) -> list[str]:
    """Class name of every cluster from its severity (:func:`severity_scores`).

    Clusters are ranked by severity (ties: lower cluster index first), r = 0 … k−1, and with C
    classes: k = C maps rank to class; k > C merges by severity quantiles, class ⌊r·C/k⌋ (each
    class takes ⌊k/C⌋ or ⌈k/C⌉ consecutive clusters, the most severe going to the last class);
    1 < k < C spreads the clusters over the classes, class round(r·(C−1)/(k−1)) (two clusters:
    the first and last class); k = 1 gives the first class (nothing to compare with).

    >>> name_clusters(np.array([0.3, -1.2, 2.5]))
    ['light', 'open', 'heavy']
    >>> name_clusters(np.array([0.0, 1.0, 2.0, 3.0, 4.0]))
    ['open', 'open', 'light', 'light', 'heavy']
    """
    severity = np.asarray(severity, dtype=float)
    k, C = len(severity), len(classes)
    rank = np.empty(k, dtype=np.int64)
    rank[np.lexsort((np.arange(k), severity))] = np.arange(k)
    if k >= C:
        idx = rank * C // k
    elif k > 1:
        idx = np.rint(rank * (C - 1) / (k - 1)).astype(np.int64)
    else:
        idx = np.zeros(k, dtype=np.int64)
    return [classes[i] for i in idx]


class EnvironmentEmbedding(ClusterMixin, BaseEstimator):
    """Standardise → 2-D t-SNE → density-peak clustering → severity-named classes.

    Parameters
    ----------
    tsne : {"auto", "opentsne", "sklearn"}, default "auto"
    perplexity : float, default 30
    kernel : {"auto", "cutoff", "gaussian"}, default "auto"
        Density of :class:`models.dpc.DensityPeakClustering`. ``"auto"``: the gaussian kernel when the
        neighbour rule expects fewer than :data:`GAUSSIAN_BELOW_NEIGHBOURS` points within d_c (a small
        library: the cutoff count ρ is then a small integer, 0, 1, 2 on a 25-cell survey, and the decision
        graph is mostly ties; Rodriguez & Laio 2014 estimate ρ with a Gaussian kernel on their small sets),
        the cutoff count otherwise.
    percent, n_clusters, max_clusters :
        Passed to :class:`models.dpc.DensityPeakClustering` (run on the 2-D embedding).
    feature_names : sequence of str or None, default None
        Column names of X, for the severity naming; None means :data:`ENV_FEATURES`.
    random_state : int, numpy Generator/RandomState or None
        Normalised once in ``fit``; the seed drawn from it goes to t-SNE.
    n_jobs : int, default 1

    Attributes
    ----------
    scaler_ : StandardScaler
    embedding_ : ndarray of shape (n_samples, 2)
    dpc_ : DensityPeakClustering (fitted on ``embedding_``)
    labels_ : ndarray of shape (n_samples,)
    n_clusters_ : int
    severity_ : ndarray of shape (n_clusters_,)
    cluster_classes_ : list of str, class name of each cluster
    classes_ : ndarray of str, shape (n_samples,), class name of each sample
    rho_, delta_ : ndarray of shape (n_samples,), the decision graph (DPC's ρ and δ) per sample
    centers_ : ndarray of shape (n_clusters_,), sample indices of the cluster centres
    tsne_seed_ : int
    kernel_ : str, the density kernel used ("cutoff" or "gaussian")

    The result does not depend on the order of the rows: they are embedded and clustered in a canonical
    (lexicographic) order and the results put back in the caller's order, so a shuffled library gives the
    same classes row for row (t-SNE's neighbour search and optimisation, and DPC's tie-breaking by index,
    all depend on the order in which they meet the points).
    """

    _parameter_constraints: dict = {
        "tsne": [StrOptions({"auto", "opentsne", "sklearn"})],
        "perplexity": [Interval(Real, 0, None, closed="neither")],
        "kernel": [StrOptions({"auto", "cutoff", "gaussian"})],
        "percent": [Interval(Real, 0, 100, closed="right")],
        "n_clusters": [Interval(Integral, 1, None, closed="left"), None],
        "max_clusters": [Interval(Integral, 1, None, closed="left")],
        "feature_names": ["array-like", None],
        "random_state": ["random_state"],
        "n_jobs": [Integral],
    }

    def __init__(self, *, tsne="auto", perplexity=30.0, kernel="auto", percent=2.0, n_clusters=None,
                 max_clusters=10, feature_names=None, random_state=None, n_jobs=1):
        self.tsne = tsne
        self.perplexity = perplexity
        self.kernel = kernel
        self.percent = percent
        self.n_clusters = n_clusters
        self.max_clusters = max_clusters
        self.feature_names = feature_names
        self.random_state = random_state
        self.n_jobs = n_jobs

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Embed and cluster ``X`` of shape (n_samples, n_features) (complete rows: windows with a
        missing modality must be imputed or left out before this step); returns ``self``."""
        X = validate_data(self, X, dtype=np.float64, ensure_min_samples=4)
        names = ENV_FEATURES if self.feature_names is None else tuple(self.feature_names)
        if len(names) != X.shape[1]:
            raise ValueError(f"feature_names has {len(names)} names for X with {X.shape[1]} columns")
        if self.perplexity >= len(X):
            raise ValueError(f"perplexity={self.perplexity} must be below the number of samples {len(X)}")
        rng = check_random_state(self.random_state)
        self.tsne_seed_ = int(rng.randint(np.iinfo(np.int32).max))
        order = canonical_order(X)
        Xs = X[order]
        self.scaler_ = StandardScaler().fit(Xs)
        Z = self.scaler_.transform(Xs)
        emb = tsne_2d(Z, backend=self.tsne, perplexity=self.perplexity, random_state=self.tsne_seed_,
                      n_jobs=self.n_jobs)
        self.kernel_ = density_kernel(self.kernel, len(X), self.percent)
        self.dpc_ = DensityPeakClustering(kernel=self.kernel_, percent=self.percent, n_clusters=self.n_clusters,
                                          max_clusters=self.max_clusters).fit(emb)
        inv = np.empty_like(order)
        inv[order] = np.arange(len(order))
        self.embedding_ = emb[inv]
        self.labels_ = self.dpc_.labels_[inv]         # dpc_'s own attributes stay in the canonical order
        self.rho_, self.delta_ = self.dpc_.rho_[inv], self.dpc_.delta_[inv]
        self.centers_ = order[np.asarray(self.dpc_.centers_, np.int64)]
        self.n_clusters_ = self.dpc_.n_clusters_
        self.severity_ = severity_scores(X, self.labels_, names)
        self.cluster_classes_ = name_clusters(self.severity_)
        self.classes_ = np.asarray(self.cluster_classes_)[self.labels_]
        return self
