"""The unsupervised mode on each site's own survey (issue 27 item 4): recall, macro-F1, and row-order dependence.

For every site of a fingerprint library, the site's own windows are clustered without labels, as ``train env
--mode survey`` does (:func:`training.clustering.cluster_windows`: standardise → t-SNE → density peaks →
clusters named by severity; K-means beside it), and scored against the cells' map labels: recall per class and
macro-F1 over all cells and over cells at least ``--margin`` from a class boundary (a cell takes its windows'
majority, as in ``bench/env_study.py``). The same windows are then clustered again in a shuffled row order
(a seeded permutation): the share of windows that get the same class both times measures how much the result
depends on the order the library happens to list its rows in.

Run it on a checkout before and after a change to compare (``cp bench/env_unsupervised.py OLD/bench/`` and run
it there: it imports the code beside it).

Usage: ``python bench/env_unsupervised.py --library /tmp/lib_all.sqlite --seed 0``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.env_study import cell_predictions, class_scores, far_from_boundary  # noqa: E402


def site_scores(ts, labels, margin: float) -> list[float]:
    """[recall open, light, heavy, macro-F1] on far cells, then on all cells, of window classes ``labels``."""
    cp, ct, cs = cell_predictions(ts, labels)
    ok = (ct >= 0) & (cp >= 0)
    far = far_from_boundary(cs, margin)
    return class_scores(ct[ok & far], cp[ok & far]) + class_scores(ct[ok], cp[ok])


def main() -> None:
    from training.clustering import cluster_windows
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library", type=Path, required=True)
    ap.add_argument("--sites", nargs="*", default=None, help="site names (default: every site of the library)")
    ap.add_argument("--seed", type=int, default=0, help="t-SNE / K-means seed and the shuffle's")
    ap.add_argument("--margin", type=float, default=0.03)
    args = ap.parse_args()
    t0 = time.perf_counter()
    ts_all = training_set(args.library)
    sites = args.sites or sorted(set(ts_all.site.tolist()))
    rows = {"dpc": [], "dpc shuffled": [], "kmeans": []}
    agree, found = [], []
    from threadpoolctl import threadpool_limits

    for name in sites:
        ts = ts_all.subset(ts_all.site == name)
        perm = np.random.default_rng(args.seed).permutation(len(ts))
        inv = np.argsort(perm)
        with threadpool_limits(1):
            a = cluster_windows(ts.X, random_state=args.seed)
            b = cluster_windows(ts.X[perm], random_state=args.seed)
            k = cluster_windows(ts.X, method="kmeans", random_state=args.seed)
        b_labels = b.labels[inv]
        rows["dpc"].append(site_scores(ts, a.labels, args.margin))
        rows["dpc shuffled"].append(site_scores(ts, b_labels, args.margin))
        rows["kmeans"].append(site_scores(ts, k.labels, args.margin))
        ok = (a.labels >= 0) & (b_labels >= 0)
        agree.append(float(np.mean(a.labels[ok] == b_labels[ok])))
        found.append((a.n_clusters, b.n_clusters))
        r = rows["dpc"][-1]
        print(f"  {name}: {len(ts)} windows, {a.n_clusters} clusters ({b.n_clusters} shuffled), same class "
              f"after shuffling {100 * agree[-1]:.1f} %; all cells recall {100 * r[4]:.0f} / {100 * r[5]:.0f} / "
              f"{100 * r[6]:.0f} %, macro-F1 {100 * r[7]:.0f} %", flush=True)
    print(f"\n{len(sites)} sites, each clustered on its own survey; mean ± SD over sites, percent (cells; far = at "
          f"least {100 * args.margin:.0f} points from a class boundary)")
    hdr = " ".join(f"{h:>11s}" for h in ("open", "light", "heavy", "macro-F1"))
    print(f"{'route':13s} far: {hdr}   all: {hdr}")
    for route, v in rows.items():
        v = np.array(v, float)
        m, s = np.nanmean(v, axis=0), np.nanstd(v, axis=0)
        print(f"{route:13s} far: " + " ".join(f"{100 * a:5.1f}±{100 * b:4.1f}" for a, b in zip(m[:4], s[:4]))
              + "   all: " + " ".join(f"{100 * a:5.1f}±{100 * b:4.1f}" for a, b in zip(m[4:], s[4:])))
    print(f"windows with the same class after shuffling the rows: mean {100 * np.mean(agree):.1f} %, worst "
          f"{100 * np.min(agree):.1f} %; clusters found (original, shuffled): {found}")
    print(f"run time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
