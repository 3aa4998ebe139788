"""Fusion study (issue 14): every method on the held-out sites of a split, over several model seeds.

For each model seed: the environment model (``--env-mode``, default supervised: the best held-out mode of
``bench/env_study.py``) is fitted on the *training* sites' fingerprint library, the fusion model (noise
per class, BP ensemble) on the training walks, and every method is evaluated on the *test* sites' walks,
which nothing was fitted or tuned on. The split's data (sites, surveys, walks) is built once and shared
by the seeds (``envfuse benchmark`` on the same ``--out`` reuses it too).

Prints, in Markdown:

1. per method and class: mean / median / p95 / max horizontal error (every epoch of every test walk pooled),
   mean ± SD over the seeds;
2. per method: the mean error per test site (spread over sites, seed 0), so a gain can be told from one
   lucky site;
3. the claim: ``adaptive`` mean error relative to ``kf``, ``kf_map``, ``kf_quality``, ``aekf``, ``imm``
   per seed, and its p95;
4. BP: ``adaptive`` vs ``adaptive_nobp`` vs ``adaptive_closed``, and the share of epochs the guards withheld
   the correction;
5. consistency: the share of epochs whose NEES lies inside the two-sided 95 % χ²₂ bounds, per method.

Usage: ``python bench/fusion_study.py --split standard --out /tmp/std --seeds 0 1 2``; a replicate on other
layouts: ``--train-sites 111 112 113 114 115 116 --test-sites 211 212 213 214 215``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLASSES = ("all", "open", "light", "heavy")
RIVALS = ("kf", "kf_map", "kf_quality", "aekf", "imm")


def run_seed(layout, library: Path, out: Path, seed: int, env_mode: str, workers: int | None) -> dict:
    """Fit both models with ``seed`` and evaluate the test walks (:func:`pipeline.benchmark.fit_and_evaluate`)."""
    from pipeline.benchmark import fit_and_evaluate

    return fit_and_evaluate(layout, library, out, env_mode=env_mode, seed=seed, workers=workers,
                            say=lambda line: print(f"  seed {seed}: {line}", flush=True), progress=True,
                            plots=seed == 0, meta={"seed": seed})


def _by(rows):
    return {(r["method"], r["env_class"]): r for r in rows}


def _site_means(result) -> dict:
    """{method: {site: mean error over the site's walks' epochs}} from the per-walk rows (n-weighted)."""
    acc: dict = {}
    for res in result["results"]:
        for r in res["rows"]:
            if r["env_class"] != "all":
                continue
            d = acc.setdefault(r["method"], {}).setdefault(res["site"], [0.0, 0])
            d[0] += r["mean_m"] * r["n"]
            d[1] += r["n"]
    return {m: {s: v[0] / v[1] for s, v in sites.items()} for m, sites in acc.items()}


def main() -> None:
    from fingerprints.survey import build_library
    from pipeline.evaluate import method_order
    from simulation.split import SPLITS, build_split

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="standard", choices=sorted(SPLITS))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--env-mode", default="supervised")
    ap.add_argument("--workers", type=int, default=None, help="simulation and evaluation workers (default: cores)")
    ap.add_argument("--train-sites", type=int, nargs="+", default=None,
                    help="site seeds to train on instead of the split's (a replicate with other layouts)")
    ap.add_argument("--test-sites", type=int, nargs="+", default=None, help="site seeds to test on instead")
    args = ap.parse_args()
    t0 = time.perf_counter()
    split = SPLITS[args.split]
    if args.train_sites or args.test_sites:
        train, test = tuple(args.train_sites or split.train_sites), tuple(args.test_sites or split.test_sites)
        if set(train) & set(test):
            ap.error(f"train and test sites overlap: {sorted(set(train) & set(test))}")
        split = dataclasses.replace(split, name=f"{split.name}-sites", train_sites=train, test_sites=test)
    layout = build_split(split, args.out / "data", workers=args.workers or 2,
                         progress=lambda s: print(f"[{time.perf_counter() - t0:6.0f} s] simulated {s}", flush=True))
    library = args.out / "fingerprints.sqlite"
    for site in layout.split.train_sites:
        build_library(layout.survey_dir(site), library, progress=False)
    results = {}
    for seed in args.seeds:
        results[seed] = run_seed(layout, library, args.out / f"seed{seed}", seed, args.env_mode, args.workers)
        print(f"[{time.perf_counter() - t0:6.0f} s] seed {seed}: evaluated {len(results[seed]['results'])} walks",
              flush=True)
    pooled = {s: _by(r["pooled"]) for s, r in results.items()}
    methods = method_order({m for p in pooled.values() for (m, _) in p})
    sp = layout.split
    print(f"\n## {sp.name}: train sites {list(sp.train_sites)}, test sites {list(sp.test_sites)}, "
          f"{sp.walks_per_site} walks × {sp.walk_s:.0f} s per site; model seeds {args.seeds}; "
          f"env mode {args.env_mode}\n")
    print("Horizontal error, m: mean / median / p95 / max, each mean ± SD over seeds\n")
    print("| method | class | mean | median | p95 | max | NEES in 95 % bounds |")
    print("|---|---|---|---|---|---|---|")
    for m in methods:
        for c in CLASSES:
            rs = [pooled[s].get((m, c)) for s in args.seeds]
            if any(r is None for r in rs):
                continue

            def ms(key, rs=rs):
                v = np.array([r[key] for r in rs], float)
                return f"{v.mean():.3f} ± {v.std():.3f}"
            print(f"| {m} | {c} | {ms('mean_m')} | {ms('median_m')} | {ms('p95_m')} | {ms('max_m')} | "
                  f"{ms('nees_in_bounds')} |")
    first = args.seeds[0]
    sites = _site_means(results[first])
    names = sorted({s for v in sites.values() for s in v})
    print(f"\nMean error per test site, m (seed {first}):\n")
    print("| method | " + " | ".join(names) + " | mean ± SD over sites |")
    print("|---|" + "---|" * (len(names) + 1))
    for m in methods:
        v = [sites.get(m, {}).get(n, np.nan) for n in names]
        print(f"| {m} | " + " | ".join(f"{x:.3f}" for x in v) + f" | {np.nanmean(v):.3f} ± {np.nanstd(v):.3f} |")
    print("\nThe claim: adaptive's mean error relative to each rival (negative = adaptive better), per seed\n")
    print("| rival | " + " | ".join(f"seed {s}" for s in args.seeds) + " |")
    print("|---|" + "---|" * len(args.seeds))
    for rival in RIVALS:
        cells = []
        for s in args.seeds:
            a, b = pooled[s].get(("adaptive", "all")), pooled[s].get((rival, "all"))
            cells.append(f"{100 * (a['mean_m'] / b['mean_m'] - 1):+.0f} %" if a and b else "–")
        print(f"| {rival} | " + " | ".join(cells) + " |")
    for c in CLASSES[1:]:
        cells = []
        for s in args.seeds:
            a, b = pooled[s].get(("adaptive", c)), pooled[s].get(("kf_quality", c))
            cells.append(f"{100 * (a['mean_m'] / b['mean_m'] - 1):+.0f} %" if a and b else "–")
        print(f"| kf_quality, {c} only | " + " | ".join(cells) + " |")
    p95 = [pooled[s][("adaptive", "all")]["p95_m"] for s in args.seeds if ("adaptive", "all") in pooled[s]]
    print(f"\nadaptive p95: {', '.join(f'{v:.2f}' for v in p95)} m (target < 1.0 m)")
    for s in args.seeds:
        shares = [r["bp_disabled_share"] for r in results[s]["results"] if r["bp_disabled_share"] is not None]
        if shares:
            print(f"seed {s}: BP correction withheld by its guards on {100 * np.mean(shares):.1f} % of epochs")
    print(f"\nwall time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
