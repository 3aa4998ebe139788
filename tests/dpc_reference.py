"""Dense O(n²) density-peak clustering: the oracle ``models.dpc`` must match.

Written straight from Rodriguez & Laio, Science 344:1492 (2014), Eqs. (1)–(2), with the
conventions of ``models.dpc`` (its module docstring): the full distance matrix, densities by
the cutoff count or the gaussian sum over the m nearest others, δ as the least distance to a
point earlier in the density order (ties to the earlier point), the border region as every
pair closer than d_c across clusters. Distances are summed dimension by dimension like
``models.dpc._dist`` so equal inputs give equal bits; nothing here uses a tree.

It imports nothing from ``models.dpc``: the neighbour-count rule, the d_c query points and the
centre rule (γ = ρ·δ, Rodriguez & Laio 2014 Fig. 4; the knee of the sorted γ) are written out
again below from the module docstring's definitions, so a bug in the estimator's copy of them
(say γ = ρ + δ) makes the two disagree instead of hiding in both.
"""

from __future__ import annotations

import math

import numpy as np

DC_QUERIES = 5_000
"""The documented number of evenly strided points whose k-th neighbour distance sets d_c."""


def neighbours_rule(n: int, percent: float, max_neighbors: int) -> int:
    """k = percent % of the n − 1 others, rounded, at least 1, at most max_neighbors and n − 1."""
    k = round(percent / 100.0 * (n - 1))
    return int(min(max(1, k), max_neighbors, n - 1))


def dc_query_points(n: int) -> np.ndarray:
    """Every ceil(n / 5000)-th point, trimmed to an even count (d_c is then a midpoint of two distances)."""
    stride = math.ceil(n / DC_QUERIES)
    q = list(range(0, n, stride))
    if len(q) > 1 and len(q) % 2:
        q = q[:-1]
    return np.array(q, dtype=np.int64)


def centres(rho, delta, order, n_clusters=None, max_clusters=10) -> np.ndarray:
    """Centres by γ_i = ρ_i·δ_i, largest first, equal γ to the denser point (earlier in ``order``).

    Given ``n_clusters``: the first n_clusters. Otherwise the knee: with the densest point's δ
    replaced by the largest other δ, among the max_clusters + 1 largest positive γ, cut after the
    position c (1-based) where γ_c / γ_(c+1) is largest (the first such c); one centre when fewer
    than two are positive.
    """
    n = len(rho)
    place = {int(i): r for r, i in enumerate(order)}
    if n_clusters is not None:
        ranked = sorted(range(n), key=lambda i: (-(rho[i] * delta[i]), place[i]))
        return np.array(ranked[:n_clusters], dtype=np.int64)
    top = int(order[0])
    d = [float(x) for x in delta]
    if n > 1:
        d[top] = max(d[i] for i in range(n) if i != top)
    gam = [rho[i] * d[i] for i in range(n)]
    ranked = sorted(range(n), key=lambda i: (-gam[i], place[i]))
    head = [i for i in ranked[:max_clusters + 1] if gam[i] > 0]
    if len(head) < 2:
        return np.array(ranked[:1], dtype=np.int64)
    ratios = [gam[a] / gam[b] for a, b in zip(head, head[1:])]
    cut = ratios.index(max(ratios)) + 1
    return np.array(ranked[:cut], dtype=np.int64)


def distance_matrix(X: np.ndarray) -> np.ndarray:
    """(n, n) Euclidean distances, row blocks to bound the temporaries."""
    n, dim = X.shape
    D = np.empty((n, n))
    for s in range(0, n, 1024):
        e = min(n, s + 1024)
        acc = np.zeros((e - s, n))
        for k in range(dim):
            diff = X[s:e, None, k] - X[None, :, k]
            acc += diff * diff
        D[s:e] = np.sqrt(acc)
    return D


def dense_dpc(X, *, kernel="cutoff", dc=None, percent=2.0, max_neighbors=100, n_neighbors=None,
              n_clusters=None, max_clusters=10) -> dict:
    """Everything ``DensityPeakClustering`` learns, by brute force. Returns a dict of arrays."""
    X = np.asarray(X, dtype=float)
    n = len(X)
    D = distance_matrix(X)
    k = neighbours_rule(n, percent, max_neighbors)
    dc_given = dc is not None
    blocks = [np.arange(s, min(n, s + 1024)) for s in range(0, n, 1024)]    # bound the temporaries
    if not dc_given:
        q = dc_query_points(n)
        kth = np.concatenate([np.partition(D[q[s:s + 1024]], k, axis=1)[:, k].copy()  # k-th other (self: 0th)
                              for s in range(0, len(q), 1024)])
        dc = float(np.median(kth))
    if kernel == "cutoff":
        rho = np.concatenate([(D[b] < dc).sum(axis=1) for b in blocks]).astype(float) - 1.0
    else:
        m = min(n - 1, n_neighbors if n_neighbors is not None else 3 * (max_neighbors if dc_given else k))
        rho = np.empty(n)
        for b in blocks:
            Do = D[b].copy()
            Do[np.arange(len(b)), b] = np.inf                                      # others only
            near = np.sort(np.partition(Do, m - 1, axis=1)[:, :m], axis=1)
            rho[b] = np.exp(-(near / dc) ** 2).sum(axis=1)
    order = np.lexsort((np.arange(n), -rho))
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    delta = np.empty(n)
    nh = np.full(n, -1, dtype=np.int64)
    for s in range(0, n, 1024):
        rows = np.arange(s, min(n, s + 1024))
        higher = rank[None, :] < rank[rows, None]
        dm = np.where(higher, D[rows], np.inf)
        best = dm.min(axis=1)
        tie = higher & (D[rows] == best[:, None])
        pick = np.where(tie, rank[None, :], n).argmin(axis=1)
        delta[rows], nh[rows] = best, pick
    top = order[0]
    delta[top], nh[top] = D[top].max(), -1
    centers = centres(rho, delta, order, n_clusters, max_clusters)
    labels = np.full(n, -1, dtype=np.int64)
    labels[centers] = np.arange(len(centers))
    for i in order:                                    # the paper's assignment, densest first
        if labels[i] < 0:
            labels[i] = labels[nh[i]]
    border = np.zeros(n, bool)
    rho_b = np.full(len(centers), -np.inf)
    for s in range(0, n, 1024):
        rows = np.arange(s, min(n, s + 1024))
        border[rows] = ((D[rows] < dc) & (labels[None, :] != labels[rows, None])).any(axis=1)
    for i in np.flatnonzero(border):
        rho_b[labels[i]] = max(rho_b[labels[i]], rho[i])
    halo = rho < rho_b[labels]
    return {"dc": dc, "rho": rho, "delta": delta, "nearest_higher": nh, "order": order,
            "centers": centers, "labels": labels, "halo": halo, "gamma": rho * delta}
