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

Measured (the standard split's 11 sites, 10 m cells, 10 s captures, 864-1,053 windows each, seed 0; mean ± SD
over sites, all cells; before = the code before issue 27, after = canonical row order and the gaussian density
on these small libraries; 95-143 s)::

                            open        light       heavy       macro-F1   same class after shuffling
    before, t-SNE + DPC     65.7±21.9   15.9±23.6   98.7±4.1    45.2±12.9  75.8 % (worst site 34.7 %)
    before, rows shuffled   56.2±23.9   23.1±25.9  100.0±0.0    42.9±14.9
    after,  t-SNE + DPC     71.3±25.2    8.5±11.6  100.0±0.0    42.9±11.8  100.0 % (every site)
    K-means, after          59.4±11.8   53.2±16.2   99.0±3.2    59.5±12.1  (before 59.2 / 53.2 / 99.0 / 59.4)

The order no longer matters; the light class is still not found (the clusterings found 2-7 clusters, 2 on six
sites). ``--plot`` shows why: counted per window, light has no density peak of its own — it is a flat bridge
under the tail of the open mode towards heavy, also along the best linear direction fitted with the labels — and
density-peak clustering finds peaks. An honest bound of the unsupervised route, not a tuning problem.

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


def overlap_plot(path: Path, ts_all, sites) -> str:
    """Why light is hard to find without labels: per window, (left) the severity score the clusters are named by
    (:func:`models.embedding.severity_scores`' weighted z-sum, per site) and (right) the one direction that
    separates the labelled classes best (Fisher's linear discriminant on the standardised windows of every site,
    fitted WITH the labels: a supervised upper bound for any linear cut), histograms of window counts per
    map-label class: density-peak clustering looks for peaks of density, and light has none of its own.
    Returns a one-line summary (the overlap of light with its neighbours on the discriminant)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

    from features.schema import ENV_CLASSES, FEATURES
    from models.embedding import SEVERITY_WEIGHTS

    ok = (ts_all.label >= 0) & np.isfinite(ts_all.X).all(axis=1) & np.isin(ts_all.site, sites)
    X, y, site = ts_all.X[ok], ts_all.label[ok], ts_all.site[ok]
    Z = np.empty_like(X)
    for s in np.unique(site):                           # standardised within each site, as the clustering does
        m = site == s
        Z[m] = (X[m] - X[m].mean(0)) / np.where(X[m].std(0) > 0, X[m].std(0), 1.0)
    sev = sum(w * Z[:, FEATURES.index(f)] for f, w in SEVERITY_WEIGHTS.items())
    lda = LinearDiscriminantAnalysis(n_components=1).fit(Z, y)
    proj = lda.transform(Z)[:, 0]
    if np.mean(proj[y == 2]) < np.mean(proj[y == 0]):
        proj = -proj
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    colours = ("#4daf4a", "#ff7f00", "#6a3d9a")
    for ax, v, title in ((axes[0], sev, "severity score (names the clusters)"),
                         (axes[1], proj, "best linear direction, fitted with the labels (LDA)")):
        bins = np.linspace(np.percentile(v, 0.5), np.percentile(v, 99.5), 60)
        for c in range(3):
            ax.hist(v[y == c], bins=bins, alpha=0.5, color=colours[c],
                    label=f"{ENV_CLASSES[c]} ({np.sum(y == c)} windows)")
        ax.set_title(title, fontsize=10)
        ax.set_ylabel("windows per bin")
        ax.legend(fontsize=8)
    axes[0].set_xlabel("Σ w·z over the severity features (z within each site)")
    axes[1].set_xlabel("LDA projection (z within each site)")
    fig.suptitle(f"Map-label classes of {len(np.unique(site))} sites' survey windows (counts): light is a bridge "
                 "between open and heavy, with no density peak of its own", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    # the share of light windows a 1-D cut at the midpoints between class medians would call light
    med = [np.median(proj[y == c]) for c in range(3)]
    lo, hi = (med[0] + med[1]) / 2, (med[1] + med[2]) / 2
    inside = float(np.mean((proj[y == 1] > lo) & (proj[y == 1] < hi)))
    return (f"on the LDA direction (fitted with the labels), {100 * inside:.0f} % of light windows lie between the "
            "midpoints to the open and heavy medians; a window's nearest class median is its label for "
            f"{100 * np.mean(np.argmin(np.abs(proj[:, None] - np.array(med)[None]), axis=1) == y):.0f} % of windows")


def main() -> None:
    from training.clustering import cluster_windows
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library", type=Path, required=True)
    ap.add_argument("--sites", nargs="*", default=None, help="site names (default: every site of the library)")
    ap.add_argument("--seed", type=int, default=0, help="t-SNE / K-means seed and the shuffle's")
    ap.add_argument("--margin", type=float, default=0.03)
    ap.add_argument("--plot", type=Path, default=None, help="PNG of the classes' overlap (why light is hard)")
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
    if args.plot is not None:
        print(overlap_plot(args.plot, ts_all, sites))
    print(f"run time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
