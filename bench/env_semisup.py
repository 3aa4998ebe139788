"""The semi-supervised survey mode on each site's own survey (issue 27 item 4): k labelled cells name and shape
the clusters.

For every site of a library (the standard split's 11 surveys), ``k`` (5, 10, 20) labelled cells of the site are
drawn at random per seed (not stratified: a draw may miss a class, as a user's might; the same draw as
``bench/env_default.py``: ``numpy.random.default_rng([seed, i, 7])`` permutes the site's cells, the first ``k``),
and every method is scored on the site's *other* cells:

``survey c.o. k``
    on the cells the ``k``-cell draw leaves: the unsupervised survey mode (t-SNE + density peaks, clusters named by severity; no label), its classifier;
``named k``
    the same clusters named by the labelled windows inside them (:func:`training.semisup.name_by_seeds`; severity
    only where a cluster holds none), its classifier;
``spread-f k`` / ``spread-e k``
    ``train env --mode survey --cell ...``: label spreading from the labelled windows (:mod:`training.semisup`,
    Zhou et al. 2004, kNN k = 7, α = 0.2) on the standardised features (``-f``) or on the t-SNE plane (``-e``),
    the classifier fitted on the spread labels;
``scratch k``
    the supervised classifier fitted on the ``k`` cells alone (one class or under 30 windows: their majority);
``tuned k``
    the shipped default model fine-tuned on the ``k`` cells (``--mode finetune``, σ = 0.03, the CLI default).

Each site is clustered once (seed 0) and the clustering reused for every draw — the same computation as
``fit_env_model(..., seeds=...)`` (deterministic for a given seed) without repeating t-SNE. Scores: recall per
class on far cells (at least ``--margin`` of blocked-sky share from a class boundary) and macro-F1 on all the
scored cells, cells pooled over sites; mean ± SD over seeds and the 95 % bootstrap interval over sites
(:func:`bench.env_default.summarise`).

Measured: see the table below (filled from a run).

Usage: ``python bench/env_semisup.py --library /work/wt/semisup_data/lib_standard.sqlite --seeds 0 1 2``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.env_default import _Constant, _score_cells, summarise  # noqa: E402
from bench.env_study import cell_predictions, far_from_boundary  # noqa: E402


def _fit(X, labels):
    """The survey mode's classifier on the windows with a class (one class: its constant)."""
    from models.environment import EnvironmentClassifier

    ok = labels >= 0
    if np.unique(labels[ok]).size < 2 or ok.sum() < 30:
        return _Constant(labels[ok] if ok.any() else np.zeros(1, int))
    try:
        return EnvironmentClassifier().fit(X[ok], labels[ok])
    except ValueError:
        return _Constant(labels[ok])


def evaluate(ts, sites, default, seeds, ks, sigma, say=print):
    """{method: {seed: [(site, cell true, cell pred, cell share), ...]}}."""
    from models.finetune import finetune
    from training.clustering import cluster_windows
    from training.semisup import seeded_labels

    res: dict = {}

    def add(method, seed, site, ct, cp, cs):
        res.setdefault(method, {}).setdefault(seed, []).append((site, ct, cp, cs))

    for i, held in enumerate(sites):
        t0 = time.process_time()
        test = ts.subset((ts.site == held) & (ts.label >= 0))
        clusters = cluster_windows(test.X, random_state=0)
        survey = _fit(test.X, clusters.labels)
        cells = np.array(sorted(set(test.cell.tolist())))
        for seed in seeds:
            draw = np.random.default_rng([seed, i, 7]).permutation(len(cells))
            for k in ks:
                if k >= len(cells):
                    continue
                mine = np.isin(test.cell, cells[draw[:k]])
                rest = test.subset(~mine)
                X, y = test.X[mine], test.label[mine]
                add(f"survey c.o. {k}", seed, held, *_score_cells(survey, rest))
                seed_label = np.where(mine, test.label, -1)
                if np.unique(y).size < 2:
                    # one class among the labelled cells: the CLI refuses; scored as the constant a user cannot get
                    for m in ("named", "spread-f", "spread-e"):
                        add(f"{m} {k}", seed, held, *_score_cells(_Constant(y), rest))
                else:
                    for space, m in (("features", "spread-f"), ("embedding", "spread-e")):
                        spread, named, _ = seeded_labels(test.X, seed_label, clusters, space=space)
                        add(f"{m} {k}", seed, held, *_score_cells(_fit(test.X, spread), rest))
                        if space == "features":
                            add(f"named {k}", seed, held, *_score_cells(_fit(test.X, named), rest))
                            cp, ct, cs = cell_predictions(rest, spread[~mine])
                            add(f"spread-f labels {k}", seed, held, ct, cp, cs)
                add(f"scratch {k}", seed, held, *_score_cells(_fit(X, y), rest))
                add(f"tuned {k}", seed, held, *_score_cells(finetune(default, X, y, sigma), rest))
        say(f"{held}: {len(test)} windows, {clusters.n_clusters} clusters; {time.process_time() - t0:.0f} s CPU")
    return res


def main() -> None:
    from training.default_env import DEFAULT_SIGMA, load_default_model
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--library", type=Path, required=True, help="a library of the sites' surveys")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--cells", type=int, nargs="+", default=[5, 10, 20])
    ap.add_argument("--margin", type=float, default=0.03)
    ap.add_argument("--sites", nargs="+", default=None, help="site names (default: every site)")
    args = ap.parse_args()
    t0 = time.process_time()
    default, meta = load_default_model()
    ts = training_set(args.library)
    sites = args.sites or sorted(set(ts.site.tolist()))
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        res = evaluate(ts, sites, default, args.seeds, args.cells, DEFAULT_SIGMA,
                       say=lambda line: print(line, flush=True))
    table = summarise(res, args.margin)
    n_far = np.zeros(3, int)
    for p in res[f"survey c.o. {args.cells[0]}"][args.seeds[0]]:
        far = far_from_boundary(p[3], args.margin)
        n_far += [int(np.sum((p[1] == c) & far)) for c in range(3)]
    print(f"{len(sites)} sites ({', '.join(sites)}); seeds {args.seeds}; far cells scored (k = {args.cells[0]}, seed "
          f"{args.seeds[0]}) open / light / heavy {n_far[0]} / {n_far[1]} / {n_far[2]}")
    print("percent: mean ± SD over seeds [95 % bootstrap over sites]")
    print(f"{'method':<20s} " + " ".join(f"{h:>24s}" for h in ("far open", "far light", "far heavy", "macro-F1 all")))
    for method in sorted(table, key=lambda m: (int(m.split()[-1]), m)):
        m, s, lo, hi = table[method]
        print(f"{method:<20s} " + " ".join(f"{100 * a:5.1f}±{100 * b:4.1f} [{100 * c:5.1f},{100 * d:5.1f}]"
                                          for a, b, c, d in zip(m, s, lo, hi)))
    print(f"run time {time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
