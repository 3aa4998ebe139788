"""Density-peak clustering: Rodriguez & Laio, "Clustering by fast search and find of density
peaks", Science 344:1492 (2014), with KD-tree neighbour queries.

For every point the paper computes

* the local density ρ_i, Eq. (1): ρ_i = Σ_j χ(d_ij − d_c), χ(x) = 1 if x < 0 else 0 (the
  *cutoff* kernel), or its smooth variant used in the paper's supplement and code,
  ρ_i = Σ_j exp(−(d_ij / d_c)²) (the *gaussian* kernel);
* δ_i, Eq. (2): the distance to the nearest point of higher density, and for the densest
  point δ = max_j d_ij;

cluster centres are the points where both are large (the decision graph; γ = ρ·δ, the paper's
Fig. 4), every other point joins the cluster of its nearest higher-density neighbour, visited in
order of decreasing density, and the *halo* (points fit to be called noise) is found by the
paper's border-density rule.

Definitions made here, each stated where it is computed:

* ties in ρ are broken by index (lower index = higher density), so the order, δ, the upslope
  neighbour and the labels are deterministic; ties in distance go to the higher-density point;
* d_c from the paper's rule of thumb ("the average number of neighbours is around 1 to 2 % of
  the total number of points"): k = percent·(n − 1)/100 neighbours, at most ``max_neighbors``
  (so the cost stays near n log n on large sets), and d_c = the median over points of the
  distance to their k-th nearest neighbour, so that the typical point has k neighbours within
  d_c (the median, not the mean, of an evenly strided subset of at most 5,000 points, trimmed
  to an even count so that d_c is the midpoint of two distances rather than a pair distance);
* the gaussian sum runs over each point's ``n_neighbors`` nearest neighbours (default 3k,
  reaching about √3·d_c in 2-D, where the kernel is e⁻³ ≈ 5 %); pass ``n - 1`` for the full sum;
* automatic centres: the largest ratio between consecutive values of γ sorted in decreasing
  order, among the ``max_clusters + 1`` largest (the knee of the decision graph, the paper's
  Fig. 4 / S1), with the densest point's conventional δ replaced by the largest other δ so that
  it does not make a gap of its own.

Every distance that decides anything is recomputed from the coordinates by :func:`_dist`, the
same arithmetic as the dense reference in ``tests/dpc_reference.py``; the KD-tree
(``scipy.spatial.cKDTree``) only proposes candidates.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> X = np.concatenate([rng.normal(0, 0.3, (50, 2)), rng.normal(5, 0.3, (50, 2))])
>>> m = DensityPeakClustering(n_clusters=2).fit(X)
>>> m.n_clusters_, np.bincount(m.labels_).tolist()
(2, [50, 50])
"""

from __future__ import annotations

from numbers import Integral, Real

import numpy as np
from scipy.spatial import cKDTree
from sklearn.base import BaseEstimator, ClusterMixin, _fit_context
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import validate_data

__all__ = ["DensityPeakClustering", "fit_dpc", "select_centers"]

_DC_QUERIES = 5_000
"""At most this many points (an even stride through the data) estimate d_c (their median
k-th neighbour distance moves by well under 1 % between 5,000 and 20,000 such points)."""

_CHUNK = 32_768
"""Points per block of neighbour queries (bounds the (block, k) candidate arrays)."""

_BRUTE = 1024
"""Rank blocks at most this long are searched by brute force in the exact δ phase."""

_KNN_STEPS = (16, 64, 256, 1024)
"""Neighbour counts of the growing k-NN phase of the δ search."""

_REL = 1e-12
"""Relative margin between the tree's distances and the recomputed ones."""


def _dist(X: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Euclidean distances between rows ``X[i]`` and ``X[j]`` (broadcast index arrays).

    Squares summed dimension by dimension, in order, then one square root: the arithmetic
    every decision in this module uses, so that a dense implementation doing the same is
    bit-for-bit comparable.
    """
    s = np.zeros(np.broadcast_shapes(np.shape(i), np.shape(j)))
    for k in range(X.shape[1]):
        diff = X[i, k] - X[j, k]
        s += diff * diff
    return np.sqrt(s)


def _rule_neighbors(n: int, percent: float, max_neighbors: int) -> int:
    """k of the neighbour-percentage rule: round(percent/100 · (n − 1)), within [1, max_neighbors]."""
    return int(min(max(1, round(percent / 100.0 * (n - 1))), max_neighbors, n - 1))


def _rule_queries(n: int) -> np.ndarray:
    """Indices of the points whose k-th neighbour distance sets d_c (an even stride)."""
    q = np.arange(0, n, -(-n // _DC_QUERIES))
    return q[:len(q) - len(q) % 2] if len(q) > 1 else q


def _knn(tree: cKDTree, X: np.ndarray, rows: np.ndarray, k: int, n_jobs: int):
    """Indices of the k nearest points (self included) of ``X[rows]`` and their recomputed distances."""
    _, idx = tree.query(X[rows], k=k, workers=n_jobs)
    idx = idx.reshape(len(rows), k)
    return idx, _dist(X, rows[:, None], idx)


def _cutoff_dc(tree, X, inv, k, n_jobs) -> float:
    """d_c = median distance to the k-th nearest other point over the :func:`_rule_queries` points
    (caller's indices, mapped through ``inv`` into the tree's order)."""
    q = inv[_rule_queries(len(X))]
    kth = np.concatenate([_knn(tree, X, q[s:s + _CHUNK], k + 1, n_jobs)[1].max(axis=1)
                          for s in range(0, len(q), _CHUNK)])
    return float(np.median(kth))


def _knn_all(tree, X, k, n_jobs):
    """(indices, recomputed distances) of the k nearest points (self included) of every point."""
    n = len(X)
    idx = np.empty((n, k), dtype=np.int64)
    d = np.empty((n, k))
    for s in range(0, n, _CHUNK):
        rows = np.arange(s, min(n, s + _CHUNK))
        idx[rows], d[rows] = _knn(tree, X, rows, k, n_jobs)
    return idx, d


def _density(tree, X, dc, kernel, m, n_jobs) -> np.ndarray:
    """ρ by Eq. (1) (cutoff: others strictly within d_c) or the truncated gaussian sum."""
    n = len(X)
    if kernel == "cutoff":
        # the tree counts d <= r, self included. A dual-tree count of the pairs in a thin shell
        # round d_c tells whether any pair sits on d_c (a given d_c on gridded data, or a float
        # coincidence among 10^8 pairs); only then are the points concerned recounted with the
        # exact distances and the strict inequality of Eq. (1)
        lo_r, hi_r = dc * (1 - _REL), dc * (1 + _REL)
        shell = tree.count_neighbors(tree, np.array([lo_r, hi_r]))
        hi = tree.query_ball_point(X, hi_r, return_length=True, workers=n_jobs)
        if shell[0] != shell[1]:
            lo = tree.query_ball_point(X, lo_r, return_length=True, workers=n_jobs)
            amb = np.flatnonzero(lo != hi)
            near = tree.query_ball_point(X[amb], hi_r, workers=n_jobs)
            for t, lst in zip(amb, near):
                hi[t] = int(np.count_nonzero(_dist(X, t, np.asarray(lst)) < dc))
        return hi.astype(float) - 1.0
    rho = np.empty(n)
    for s in range(0, n, _CHUNK):
        rows = np.arange(s, min(n, s + _CHUNK))
        idx, d = _knn(tree, X, rows, m + 1, n_jobs)
        # the m nearest others: drop self where listed, else the farthest listed point
        d = np.where(idx == rows[:, None], np.inf, d)
        d = np.sort(d, axis=1)[:, :m]
        rho[rows] = np.exp(-(d / dc) ** 2).sum(axis=1)
    return rho


def _pick(d: np.ndarray, r: np.ndarray, ok: np.ndarray):
    """Per row, the column of least distance among ``ok``, ties to the least rank ``r``."""
    dm = np.where(ok, d, np.inf).min(axis=1)
    tie = ok & (d == dm[:, None])
    col = np.where(tie, r, np.iinfo(np.int64).max).argmin(axis=1)
    return dm, col


def _nearest_higher(tree, X, rank, order, knn, n_jobs):
    """δ_i and the upslope neighbour of every point but the densest, Eq. (2).

    Growing k-NN lists (the shared 16-NN list, then 64 and 256 neighbours) settle every point
    whose nearest listed higher-ranked point is strictly closer than the farthest listed one;
    the rest (local density maxima) are searched exactly over the rank prefix
    ``order[:rank_i]``, split into aligned power-of-two blocks (the logarithmic method of
    Bentley & Saxe, J. Algorithms 1:301, 1980), each block a cached KD-tree or, when short,
    brute force.
    """
    n = len(X)
    delta = np.full(n, np.inf)
    nh = np.full(n, -1, dtype=np.int64)
    pending = np.sort(order[1:])                       # tree (spatial) order: cache-friendly
    for step, k in enumerate(_KNN_STEPS):
        if not pending.size:
            break
        kk = min(n, k + 1)
        left = []
        for s in range(0, len(pending), _CHUNK):
            rows = pending[s:s + _CHUNK]
            if step == 0 and knn is not None and knn[0].shape[1] == kk:
                idx, d = knn[0][rows], knn[1][rows]
            else:
                idx, d = _knn(tree, X, rows, kk, n_jobs)
            r = rank[idx]
            dm, col = _pick(d, r, r < rank[rows][:, None])
            bound = np.inf if kk >= n else d.max(axis=1) * (1 - _REL)
            done = dm < bound
            sel = rows[done]
            delta[sel] = dm[done]
            nh[sel] = idx[done, col[done]]
            left.append(rows[~done])
        pending = np.concatenate(left)
    if pending.size:
        _exact_prefix_search(X, rank, order, pending, delta, nh)
    top = order[0]
    delta[top] = _dist(X, top, np.arange(n)).max()
    return delta, nh


def _exact_prefix_search(X, rank, order, pending, delta, nh) -> None:
    """Nearest point among ranks < rank_i for each pending i, by aligned dyadic rank blocks."""
    blocks: dict[tuple[int, int], list[int]] = {}
    for p in pending.tolist():
        r, s = int(rank[p]), 0
        for b in range(r.bit_length() - 1, -1, -1):
            if r >> b & 1:
                blocks.setdefault((s, b), []).append(p)
                s += 1 << b
    best_d = {p: np.inf for p in pending.tolist()}
    best_r = {p: -1 for p in pending.tolist()}
    for (s, b), pts in blocks.items():
        q = np.asarray(pts)
        members = order[s:s + (1 << b)]
        if len(members) <= _BRUTE:
            d = _dist(X, q[:, None], members[None, :])
            dm, col = _pick(d, np.broadcast_to(np.arange(len(members)), d.shape), np.ones(d.shape, bool))
            cand = [(float(dm[t]), s + int(col[t])) for t in range(len(q))]
        else:
            sub = cKDTree(X[members])
            td, _ = sub.query(X[q], k=1)
            near = sub.query_ball_point(X[q], td * (1 + _REL) + 1e-300)
            cand = []
            for t, lst in enumerate(near):
                loc = np.sort(np.asarray(lst, dtype=np.int64))        # rank order within the block
                d = _dist(X, q[t], members[loc])
                j = int(np.argmin(d))                                  # first minimum: least rank
                cand.append((float(d[j]), s + int(loc[j])))
        for p, (d, rr) in zip(pts, cand):
            if d < best_d[p] or (d == best_d[p] and rr < best_r[p]):
                best_d[p], best_r[p] = d, rr
    for p in pending.tolist():
        delta[p] = best_d[p]
        nh[p] = order[best_r[p]]


def select_centers(rho: np.ndarray, delta: np.ndarray, order: np.ndarray,
                   n_clusters: int | None = None, max_clusters: int = 10) -> np.ndarray:
    """Centre indices from the decision graph, in decreasing γ = ρ·δ (ties: higher density first).

    Given ``n_clusters``: the n_clusters largest γ (the densest point always comes first, since
    its ρ and δ are both the largest). Otherwise the largest ratio γ_(c)/γ_(c+1) between
    consecutive values of γ in decreasing order, c = 1 … max_clusters, among positive γ, with the
    densest point's δ replaced by the largest other δ for this rule (its conventional
    δ = max_j d_ij would otherwise make the first gap) — the knee of the sorted decision graph,
    Rodriguez & Laio (2014) Fig. 4.

    >>> select_centers(np.array([5., 4, 1, 1]), np.array([9., 3, .1, .2]), np.array([0, 1, 2, 3]))
    array([0, 1])
    """
    n = len(rho)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    gamma = rho * delta
    if n_clusters is not None:
        return np.lexsort((rank, -gamma))[:n_clusters]
    d = delta.copy()
    if n > 1:
        d[order[0]] = np.max(np.delete(delta, order[0]))
    g_rule = rho * d
    by = np.lexsort((rank, -g_rule))
    g = g_rule[by[:max_clusters + 1]]
    g = g[g > 0]
    if len(g) < 2:
        return by[:1]
    c = int(np.argmax(np.log(g[:-1]) - np.log(g[1:]))) + 1
    return by[:c]


def _assign(nh: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """Label of every point: that of the centre reached by following upslope neighbours.

    Equivalent to the paper's assignment in decreasing density; done by pointer doubling.
    """
    parent = nh.copy()
    parent[centers] = centers
    while True:
        nxt = parent[parent]
        if np.array_equal(nxt, parent):
            break
        parent = nxt
    lab = np.full(len(nh), -1, dtype=np.int64)
    lab[centers] = np.arange(len(centers))
    return lab[parent]


def _border(X, labels, dc, knn, n_clusters) -> np.ndarray:
    """Points with a point of another cluster strictly within d_c (the paper's border region).

    The shared 16-NN list settles most points (a cross-cluster neighbour inside d_c, or a list
    reaching beyond d_c); the rest query a KD-tree of each other cluster whose box, grown by
    d_c, holds them.
    """
    n = len(X)
    border = np.zeros(n, bool)
    if n_clusters < 2:
        return border
    idx, d = knn
    cross = (labels[idx] != labels[:, None]) & (d < dc)
    border[:] = cross.any(axis=1)
    reach = np.inf if idx.shape[1] >= n else d.max(axis=1) * (1 - _REL)
    und = np.flatnonzero(~border & ~(reach > dc * (1 + _REL)))
    for c in range(n_clusters):
        members = np.flatnonzero(labels == c)
        lo, hi = X[members].min(axis=0) - dc, X[members].max(axis=0) + dc
        q = und[(labels[und] != c) & ~border[und] & np.all((X[und] >= lo) & (X[und] <= hi), axis=1)]
        if not q.size:
            continue
        sub = cKDTree(X[members])
        dq, _ = sub.query(X[q], k=1, distance_upper_bound=dc * (1 + _REL))
        q = q[np.isfinite(dq)]
        for t, lst in zip(q, sub.query_ball_point(X[q], dc * (1 + _REL))):
            if np.any(_dist(X, t, members[np.asarray(lst)]) < dc):
                border[t] = True
    return border


def _halo(rho, labels, border, n_clusters) -> np.ndarray:
    """Halo by the border-density rule: ρ_b(c) = highest ρ in cluster c's border region (paper,
    text); points of c with ρ < ρ_b(c) are halo (as in the authors' code, ties stay core)."""
    rho_b = np.full(n_clusters, -np.inf)
    np.maximum.at(rho_b, labels[border], rho[border])
    return rho < rho_b[labels]


class DensityPeakClustering(ClusterMixin, BaseEstimator):
    """Density-peak clustering (Rodriguez & Laio, Science 2014), KD-tree accelerated.

    Parameters
    ----------
    kernel : {"cutoff", "gaussian"}, default "cutoff"
        Density estimate: Eq. (1) count within d_c, or the gaussian sum over the nearest
        ``n_neighbors`` points.
    dc : float or None, default None
        Cutoff distance; None applies the neighbour-percentage rule (module docstring).
    percent : float in (0, 100], default 2.0
        Target neighbours within d_c as a percentage of n (the paper's 1–2 %).
    max_neighbors : int, default 100
        Cap on the rule's neighbour count (keeps large n near n log n).
    n_neighbors : int or None, default None
        Neighbours in the gaussian sum; None: 3 × the rule's k (or 3 × ``max_neighbors`` when
        ``dc`` is given); capped at n − 1.
    n_clusters : int or None, default None
        Number of centres; None chooses them from the decision graph (:func:`select_centers`).
    max_clusters : int, default 10
        Largest number of centres the automatic rule considers.
    n_jobs : int or None, default None
        Workers for the KD-tree queries (None: 1, −1: all cores).

    Attributes
    ----------
    dc_ : float
    rho_ : ndarray of shape (n_samples,)
    delta_ : ndarray of shape (n_samples,)
    nearest_higher_ : ndarray of shape (n_samples,), −1 for the densest point
    gamma_ : ndarray of shape (n_samples,), ρ·δ
    order_ : ndarray of shape (n_samples,), indices by decreasing density (ties: lower index)
    centers_ : ndarray of shape (n_clusters_,), indices, centre c has label c
    labels_ : ndarray of shape (n_samples,)
    halo_ : ndarray of bool, shape (n_samples,)
    n_clusters_ : int
    """

    _parameter_constraints: dict = {
        "kernel": [StrOptions({"cutoff", "gaussian"})],
        "dc": [Interval(Real, 0, None, closed="neither"), None],
        "percent": [Interval(Real, 0, 100, closed="right")],
        "max_neighbors": [Interval(Integral, 1, None, closed="left")],
        "n_neighbors": [Interval(Integral, 1, None, closed="left"), None],
        "n_clusters": [Interval(Integral, 1, None, closed="left"), None],
        "max_clusters": [Interval(Integral, 1, None, closed="left")],
        "n_jobs": [Integral, None],
    }

    def __init__(self, *, kernel="cutoff", dc=None, percent=2.0, max_neighbors=100, n_neighbors=None,
                 n_clusters=None, max_clusters=10, n_jobs=None):
        self.kernel = kernel
        self.dc = dc
        self.percent = percent
        self.max_neighbors = max_neighbors
        self.n_neighbors = n_neighbors
        self.n_clusters = n_clusters
        self.max_clusters = max_clusters
        self.n_jobs = n_jobs

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Cluster ``X`` of shape (n_samples, n_features); returns ``self``."""
        X = validate_data(self, X, dtype=np.float64, ensure_min_samples=2)
        n = len(X)
        if self.n_clusters is not None and self.n_clusters > n:
            raise ValueError(f"n_clusters={self.n_clusters} exceeds the number of samples {n}")
        jobs = 1 if self.n_jobs is None else int(self.n_jobs)
        # work in the KD-tree's leaf order: neighbour queries in spatial order run about twice
        # as fast (cache locality); ties are still broken by the caller's index, ``key``
        perm = cKDTree(X).indices.astype(np.int64)
        inv = np.empty(n, dtype=np.int64)
        inv[perm] = np.arange(n)
        Xp = X[perm]
        tree = cKDTree(Xp)
        k = _rule_neighbors(n, self.percent, self.max_neighbors)
        dc = float(self.dc) if self.dc is not None else _cutoff_dc(tree, Xp, inv, k, jobs)
        if not dc > 0:
            raise ValueError(f"d_c from percent={self.percent} is {dc}: more than k={k} duplicate points; "
                             "pass dc explicitly")
        m = min(n - 1, self.n_neighbors if self.n_neighbors is not None
                else 3 * (k if self.dc is None else self.max_neighbors))
        rho_p = _density(tree, Xp, dc, self.kernel, m, jobs)
        # decreasing density, ties to the lower (caller's) index
        order_p = np.lexsort((perm, -rho_p))
        rank_p = np.empty(n, dtype=np.int64)
        rank_p[order_p] = np.arange(n)
        knn = _knn_all(tree, Xp, min(n, _KNN_STEPS[0] + 1), jobs)
        delta_p, nh_p = _nearest_higher(tree, Xp, rank_p, order_p, knn, jobs)
        rho, delta = rho_p[inv], delta_p[inv]
        order = perm[order_p]
        nh = np.where(nh_p[inv] >= 0, perm[nh_p[inv]], -1)
        centers = select_centers(rho, delta, order, self.n_clusters, self.max_clusters)
        labels = _assign(nh, centers)
        border = _border(Xp, labels[perm], dc, knn, len(centers))[inv]
        self.dc_ = dc
        self.rho_, self.delta_, self.nearest_higher_ = rho, delta, nh
        self.gamma_ = rho * delta
        self.order_ = order
        self.centers_, self.labels_ = centers, labels
        self.n_clusters_ = len(centers)
        self.halo_ = _halo(rho, labels, border, len(centers))
        return self


def fit_dpc(X, **params) -> DensityPeakClustering:
    """``DensityPeakClustering(**params).fit(X)``, for one-line use."""
    return DensityPeakClustering(**params).fit(X)
