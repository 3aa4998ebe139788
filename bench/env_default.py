"""The shipped default environment model, and fine-tuning it, on held-out sites (issue 27 item 2).

Every site of a built split (the ``standard`` split's 11 sites: none of them among the default's training
seeds 1001-...) is held out in turn and scored per cell, each cell taking the class of its windows' combined
probabilities (:func:`models.environment.combine_windows`), as ``bench/env_learning_curve.py`` does:

``default``
    the shipped model (:func:`training.default_env.load_default_model`) alone — what a user without a
    labelled survey gets;
``scratch n``
    the supervised classifier fitted on the map labels of ``n`` (1, 2) other sites' surveys (the learning
    curve's draw: seed ``s`` orders the other sites by ``numpy.random.default_rng([s, i])``, first ``n``);
``tuned n``
    the default MAP-adapted (:mod:`models.finetune`) to the same ``n`` sites' windows;
``cells k``, ``scratch k cells``
    the default fine-tuned on ``k`` (5, 10, 20) labelled cells of the held-out site itself, drawn at random
    (seed ``s``), against the supervised classifier fitted on those ``k`` cells alone (when they hold one
    class, or under 30 windows, it answers their majority class); both scored on the site's *other* cells.

σ: by cell-grouped cross-validation on the user's cells (:func:`models.finetune.choose_sigma`) unless
``--sigma`` fixes it. Scores: recall per class on far cells (at least ``--margin`` of blocked-sky share from a
class boundary) and macro-F1 on all labelled cells, cells pooled over the held-out sites; ``mean ± SD over
seeds`` and, in brackets, the 95 % bootstrap interval over held-out sites (sites resampled with replacement,
their cells pooled over seeds; 1000 resamples).

Measured (the shipped default: 24 simulated sites, seeds 1001-1024; held out: the standard split's 11 sites as
built for the fusion study, 10 m cells / 10 s captures, 723 / 167 / 71 far cells open / light / heavy; seeds
0-2; one BLAS thread; 327 s CPU with σ by cross-validation, 70 s with σ fixed). Percent: mean ± SD over seeds
[95 % bootstrap over held-out sites]; ``c.o.`` = the default alone on the cells the ``k``-cell runs score::

    method            far open            far light           far heavy           macro-F1 (all cells)
    default           95.6 [93.5, 97.3]   82.6 [76.4, 89.4]   91.5 [85.5, 97.1]   82.1 [79.0, 84.8]
    scratch 1 site    91.8±0.4            67.7±1.8            70.9±5.4            72.3±0.8
    scratch 2 sites   91.7±0.6 [88.9,94.6] 73.9±5.7 [66.9,81.1] 79.8±3.5 [74.2,85.5] 76.9±0.3 [75.3,78.5]
    σ by cross-validation on the user's cells:
    tuned 1 site      94.7±0.4            79.8±2.4            88.3±2.4            79.8±0.9
    tuned 2 sites     95.6±0.1 [93.6,97.5] 81.8±0.7 [76.0,87.6] 88.7±2.3 [83.6,93.8] 81.1±0.3 [78.2,83.6]
    tuned 5 cells     97.1±0.5            63.2±7.9            92.1±0.6            78.4±2.4
    tuned 10 cells    96.3±0.2            77.0±1.8            90.0±5.7            81.4±0.8
    tuned 20 cells    95.0±0.6            80.0±4.3            83.2±6.6            79.6±0.3
    σ = 0.03 fixed (training.default_env.DEFAULT_SIGMA, the CLI's default):
    tuned 1 site      95.1±0.3            81.0±1.0            86.4±2.4            79.8±0.2
    tuned 2 sites     95.1±0.3 [92.8,97.1] 80.6±0.6 [73.6,87.1] 88.7±2.0 [83.1,94.8] 80.1±0.8 [77.5,82.6]
    default 5 c.o.    95.4±0.1            82.8±0.9            91.6±0.8            82.2±0.3
    scratch 5 cells   90.9±2.1            35.1±3.8            23.4±5.2            50.9±2.9
    tuned 5 cells     95.4±0.1 [93.2,97.3] 83.0±1.7 [76.3,88.8] 91.6±1.8 [85.0,97.0] 82.0±0.5 [78.7,85.1]
    default 10 c.o.   95.5±0.1            82.8±0.6            91.5±0.8            82.4±0.2
    scratch 10 cells  93.9±0.8            49.4±2.6            36.4±13.7           60.6±2.8
    tuned 10 cells    95.4±0.1            83.0±1.4            91.0±2.4            82.2±0.7
    default 20 c.o.   95.5±0.1            82.5±1.5            91.3±0.8            82.4±0.6
    scratch 20 cells  95.3±0.2            54.5±1.3            44.1±7.7            65.4±2.2
    tuned 20 cells    95.1±0.4 [93.0,97.2] 84.5±2.7 [79.0,90.2] 86.4±4.0 [80.2,93.4] 81.6±0.2 [78.7,84.9]

What it says. The shipped default, which has never seen any of these sites, beats what a user gets from their
own one or two surveyed sites by 4 / 9 / 12 points (far open / light / heavy against two sites) and 5 points of
macro-F1 — about what the learning curve's eight surveyed sites give (93.6 / 86.1 / 90.1 %, macro-F1 82.8 %) —
and a handful of labelled cells alone is useless from scratch (light 35-55 %, heavy 23-44 %). Fine-tuning the
default, however, shows **no held-out gain** on these simulated sites: on one or two other sites' surveys it
costs 3-5 points of heavy, on 5-20 labelled cells of the site itself it is within the intervals of the default on
the same cells (σ = 0.03: light +0.2 to +2.0, heavy 0 to −4.9 points). The held-out sites come from the same
simulator as the default's 24, so there is no site-specific shift for the adaptation to correct: what the default
gets wrong is cells whose features overlap another class's, which a few labels of the same site do not
separate. The adaptation does correct a shifted site (tests/test_finetune.py: a synthetic site moved by 0.8 of a
class step, accuracy from < 60 % to > 90 %) — the case of a real receiver or yard unlike the simulation, which
this bench cannot show. σ by cross-validation over 5-10 cells is harmful (it often picks a loose prior: light
63 % at 5 cells), hence the fixed default σ. The issue's target, 97 % per class on far cells with at most two
surveyed sites, is not met: open 95.6 %, light 82.6 %, heavy 91.5 % with no survey at all (the default), and no
fine-tuned variant is better than that within the intervals.

Usage: ``python bench/env_default.py --data /work/studies/standard/data --out /tmp/envdef --seeds 0 1 2
[--sigma 0.03]`` (``--library`` reuses a library of the split's 11 surveys).
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


def _score_cells(clf, ts):
    p = clf.predict_proba(ts.X)
    cp, ct, cs = cell_predictions(ts, p.argmax(1), p)
    return ct, cp, cs


class _Constant:
    """The classifier a one-class (or too small) labelled set gives: always its majority class."""

    def __init__(self, y):
        self.c = int(np.bincount(y, minlength=3).argmax())

    def predict_proba(self, X):
        p = np.full((len(X), 3), 1e-3)
        p[:, self.c] = 1.0
        return p / p.sum(1, keepdims=True)


def _scratch(X, y):
    from models.environment import EnvironmentClassifier

    try:
        return EnvironmentClassifier().fit(X, y)
    except ValueError:
        return _Constant(y)


def _tune(default, X, y, groups, sigma):
    from models.finetune import choose_sigma, finetune

    s = sigma if sigma is not None else choose_sigma(default, X, y, groups)[0]
    return finetune(default, X, y, s), s


def labelled_draws(test, seed: int, site_index: int, ks):
    """(k, mine, rest) for each ``k`` of ``ks`` below the site's cell count: the windows of the first ``k`` cells of
    one random order of the site's cells (``numpy.random.default_rng([seed, site_index, 7])``, so the 5 cells are
    among the 10 and the 10 among the 20), as a mask over ``test``, and the site's other windows. The one draw
    every bench of "a handful of labelled cells" scores (this one, ``bench/env_semisup.py``)."""
    cells = np.array(sorted(set(test.cell.tolist())))
    draw = np.random.default_rng([seed, site_index, 7]).permutation(len(cells))
    for k in ks:
        if k < len(cells):
            mine = np.isin(test.cell, cells[draw[:k]])
            yield k, mine, test.subset(~mine)


def evaluate(ts, sites, default, seeds, n_sites, ks, sigma, say=print):
    """{method: {seed: [(site, cell true, cell pred, cell share), ...]}} and the σ chosen per method."""
    res: dict = {}
    sigmas: dict = {}
    by_site = {s: ts.subset((ts.site == s) & (ts.label >= 0)) for s in sites}

    def add(method, seed, site, ct, cp, cs):
        res.setdefault(method, {}).setdefault(seed, []).append((site, ct, cp, cs))

    for i, held in enumerate(sites):
        test = by_site[held]
        ct, cp, cs = _score_cells(default, test)
        for seed in seeds:
            add("default", seed, held, ct, cp, cs)
        others = [s for s in sites if s != held]
        for seed in seeds:
            t0 = time.process_time()
            order = np.random.default_rng([seed, i]).permutation(len(others))
            for n in n_sites:
                chosen = [others[j] for j in order[:n]]
                keep = np.isin(ts.site, chosen) & (ts.label >= 0)
                X, y = ts.X[keep], ts.label[keep]
                groups = np.array([f"{a}/{b}" for a, b in zip(ts.site[keep], ts.cell[keep])])
                add(f"scratch {n} site{'s' * (n > 1)}", seed, held, *_score_cells(_scratch(X, y), test))
                tuned, s = _tune(default, X, y, groups, sigma)
                sigmas.setdefault(f"tuned {n} site{'s' * (n > 1)}", []).append(s)
                add(f"tuned {n} site{'s' * (n > 1)}", seed, held, *_score_cells(tuned, test))
            for k, mine, rest in labelled_draws(test, seed, i, ks):
                X, y, g = test.X[mine], test.label[mine], test.cell[mine]
                add(f"default {k} c.o.", seed, held, *_score_cells(default, rest))   # the same cells, untuned
                add(f"scratch {k} cells", seed, held, *_score_cells(_scratch(X, y), rest))
                tuned, s = _tune(default, X, y, g, sigma)
                sigmas.setdefault(f"tuned {k} cells", []).append(s)
                add(f"tuned {k} cells", seed, held, *_score_cells(tuned, rest))
            say(f"held out {held} seed {seed}: {time.process_time() - t0:.0f} s CPU")
    return res, sigmas


def _scores(parts, margin):
    ct, cp, cs = (np.concatenate(c) for c in zip(*[p[1:] for p in parts]))
    far = far_from_boundary(cs, margin)
    return np.array(class_scores(ct[far], cp[far])[:3] + [class_scores(ct, cp)[3]])


def summarise(res, margin, n_boot=1000, boot_seed=0):
    """{method: (mean over seeds (4,), SD over seeds (4,), bootstrap 2.5 % (4,), 97.5 % (4,))}: far recall open /
    light / heavy and macro-F1 on all cells."""
    out = {}
    rng = np.random.default_rng(boot_seed)
    for method, per_seed in res.items():
        v = np.array([_scores(parts, margin) for parts in per_seed.values()])
        by_site: dict = {}
        for parts in per_seed.values():
            for p in parts:
                by_site.setdefault(p[0], []).append(p)
        names = sorted(by_site)
        boots = []
        for _ in range(n_boot):
            pick = rng.integers(0, len(names), len(names))
            boots.append(_scores([p for j in pick for p in by_site[names[j]]], margin))
        boots = np.array(boots)
        out[method] = (np.nanmean(v, 0), np.nanstd(v, 0), np.nanpercentile(boots, 2.5, 0),
                       np.nanpercentile(boots, 97.5, 0))
    return out


def main() -> None:
    from fingerprints.survey import build_library
    from simulation.split import split_layout
    from training.default_env import load_default_model, resolve_env_model
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a built split (sites and surveys)")
    ap.add_argument("--library", type=Path, default=None, help="a library of every site of the split")
    ap.add_argument("--model", default="default", help="the default model (directory, or 'default': the shipped)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--n-sites", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cells", type=int, nargs="+", default=[5, 10, 20])
    ap.add_argument("--sigma", type=float, default=None, help="fix σ (default: cell-grouped cross-validation)")
    ap.add_argument("--margin", type=float, default=0.03)
    ap.add_argument("--sites", nargs="+", default=None, help="held-out site names (default: every site)")
    args = ap.parse_args()
    t0 = time.process_time()
    layout = split_layout(args.data)
    sp = layout.split
    lib = args.library
    args.out.mkdir(parents=True, exist_ok=True)
    if lib is None:
        lib = args.out / "fingerprints_all_sites.sqlite"
        for s in dict.fromkeys(sp.train_sites + sp.test_sites):
            build_library(layout.survey_dir(s), lib, progress=False)
    default, meta = load_default_model() if args.model == "default" else resolve_env_model(args.model)
    seen = set(meta.get("site_seeds", []))
    ts = training_set(lib)
    sites = args.sites or sorted(set(ts.site.tolist()))
    clash = [s for s in sites if int("".join(ch for ch in s if ch.isdigit()) or -1) in seen]
    if clash:
        raise SystemExit(f"held-out sites {clash} are among the default model's training seeds")
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        res, sigmas = evaluate(ts, sites, default, args.seeds, args.n_sites, args.cells, args.sigma,
                               say=lambda line: print(line, flush=True))
    table = summarise(res, args.margin)
    n_far = {}
    for p in res["default"][args.seeds[0]]:
        far = far_from_boundary(p[3], args.margin)
        for c in range(3):
            n_far[c] = n_far.get(c, 0) + int(np.sum((p[1] == c) & far))
    print(f"default model: {meta.get('n_sites')} simulated sites (seeds {min(seen, default=0)}-{max(seen, default=0)}); "
          f"held out: {len(sites)} sites ({', '.join(sites)}), far cells open / light / heavy {n_far[0]} / {n_far[1]} / "
          f"{n_far[2]} (margin {100 * args.margin:.0f} points); seeds {args.seeds}; "
          f"sigma {'CV' if args.sigma is None else args.sigma}")
    print("percent: mean ± SD over seeds [95 % bootstrap over held-out sites]")
    print(f"{'method':<16s} " + " ".join(f"{h:>24s}" for h in ("far open", "far light", "far heavy", "macro-F1 all")))
    for method, (m, s, lo, hi) in table.items():
        print(f"{method:<16s} " + " ".join(f"{100 * a:5.1f}±{100 * b:4.1f} [{100 * c:5.1f},{100 * d:5.1f}]"
                                          for a, b, c, d in zip(m, s, lo, hi)))
    for method, v in sigmas.items():
        vals, counts = np.unique(v, return_counts=True)
        print(f"sigma chosen, {method}: " + ", ".join(f"{a:g} ×{c}" for a, c in zip(vals, counts)))
    print(f"run time {time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
