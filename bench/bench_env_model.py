"""Speed and memory of the whole environment model (issue 13): prints figures, asserts nothing.

On a synthetic library of 14-feature windows (three overlapping classes, a
tenth of the windows missing one modality): the unsupervised route (standardise
→ t-SNE → DPC → severity names, :func:`training.clustering.cluster_windows`),
the online classifier's fit, and its prediction rate in windows per second
(with the OOD test), each with the process's peak resident memory after it. Target: the whole
model on 100,000 windows in under 3 minutes. A yardstick (scipy's
``oaconvolve`` of a fixed size) is timed in the same run, since this VM's
speed drifts between days.

Usage: ``python bench/bench_env_model.py [--n 100000]``
"""

from __future__ import annotations

import argparse
import sys
import resource
import time
from pathlib import Path

import numpy as np
import scipy.signal

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def library(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    y = rng.choice(3, size=n, p=[0.6, 0.28, 0.12])
    means = np.array([[2, 1, 0.5, 0.1, 0.1, 0.6, 0.8, 3, 1, 2, -10, 5, 3, -1],
                      [6, 3, 0.8, 0.2, 0.3, 1.4, 1.4, 3, 1, 0, -12, 6, 3, -1],
                      [14, 6, 1.2, 0.4, 1.5, 3.0, 2.6, 2, 0.5, -6, -15, 7, 2, -0.5]], float)
    scale = np.abs(means) * 0.35 + 0.3
    X = means[y] + rng.normal(size=(n, 14)) * scale[y]
    drop = rng.random(n)
    X[drop < 0.05, :5] = np.nan
    X[(drop >= 0.05) & (drop < 0.10), 5:] = np.nan
    return X, y


def yardstick() -> float:
    x = np.random.default_rng(1).normal(size=2_000_000).astype(np.float32)
    h = np.random.default_rng(2).normal(size=480).astype(np.float32)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        best = min(best, time.perf_counter() - t0)
    return best


def timed(f):
    """(result, wall s, peak resident MiB of the process so far). tracemalloc is not used: it slows
    openTSNE's and numpy's allocations several-fold and would distort the timing."""
    t0 = time.perf_counter()
    out = f()
    wall = time.perf_counter() - t0
    return out, wall, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    from models.environment import EnvironmentClassifier
    from training.clustering import cluster_windows

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    args = ap.parse_args()
    X, y = library(args.n)
    y0 = yardstick()
    res, t_cl, m_cl = timed(lambda: cluster_windows(X, random_state=0))
    ok = res.labels >= 0
    clf, t_fit, m_fit = timed(lambda: EnvironmentClassifier().fit(X[ok], res.labels[ok]))
    Xq, _ = library(200_000, seed=5)
    (_, _), t_pred, m_pred = timed(lambda: (clf.predict_proba(Xq), clf.is_ood(Xq)))
    y1 = yardstick()
    from sklearn.metrics import adjusted_rand_score

    print(f"{args.n:,} windows ({int(ok.sum()):,} complete):")
    print(f"  t-SNE + DPC + naming  {t_cl:7.1f} s  peak {m_cl:7.0f} MiB RSS  ({res.n_clusters} clusters, "
          f"{res.method}; ARI vs the generating classes {adjusted_rand_score(y[ok], res.labels[ok]):.2f})")
    print(f"  classifier fit        {t_fit:7.1f} s  peak {m_fit:7.0f} MiB RSS")
    print(f"  whole model           {t_cl + t_fit:7.1f} s  (target < 180 s)")
    print(f"  online classifier     {len(Xq) / t_pred:,.0f} windows/s with the OOD test, peak {m_pred:.0f} MiB "
          f"({1e6 * t_pred / len(Xq):.1f} µs per window)")
    print(f"  yardstick oaconvolve(2e6, 480) {1e3 * min(y0, y1):.1f} ms (before {1e3 * y0:.1f}, after {1e3 * y1:.1f}); "
          f"whole model = {(t_cl + t_fit) / min(y0, y1):,.0f} yardsticks")


if __name__ == "__main__":
    main()
