"""Fusion study (issue 22): every method on held-out walks, over model seeds, with site-level intervals.

For each model seed: the environment model (``--env-mode``, default supervised) is fitted on the training
sites' fingerprint library, the fusion model on the training walks (noise policies, the context error model
and its blind twin, every filter method's knobs tuned by its own training error, the BP network), and every
method is evaluated on the test walks, which nothing was fitted or tuned on; the oracle ceilings
(``bench/fusion_oracle.py``) run on the same walks. The split's data is built once and shared by the seeds.

Two honest splits (``--split``): ``standard`` (leave-site-out: six training sites, five held-out sites × 3
walks) and ``later_days`` (five sites, three training walks each, three test walks four weeks later).

Prints, in Markdown, and writes ``<out>/study.json``:

1. per method and class: mean / median / p95 / max horizontal error and the share of epochs whose NEES lies
   inside the two-sided 95 % χ²₂ bounds (every epoch of every test walk pooled; mean over seeds);
2. the claim as intervals: Δ = ratio of pooled mean errors − 1 of the environment-aware methods against
   ``kf``, ``kf_quality``, their own environment-blind twin and the best single input, per class, with a
   95 % interval from a bootstrap over test sites (:mod:`pipeline.compare`), per-walk means first averaged
   over the seeds;
3. sanity: ``run``'s default method (``kf_quality+lag``, :data:`pipeline.commands.fuse.DEFAULT_METHOD`; until
   2026-12-03 ``adaptive_blind+lag``), the blind and class-aware context models at the same lag and the zero-latency
   ``adaptive`` against the best single input, per class;
4. BP: ``adaptive`` vs ``adaptive_nobp`` vs ``adaptive_correction``, and the guards' share;
5. the oracle ceilings against ``adaptive_nobp``; 6. what tuning did on the training walks (seed 0).

Usage: ``python bench/fusion_study.py --split standard --out /tmp/std --seeds 0 1 2``; a replicate on other
layouts: ``--train-sites 111 112 113 114 115 116 --test-sites 211 212 213 214 215``. ``--reports-only`` re-reads a
finished study's per-walk ``seed*/report/metrics.csv`` and prints the claim and sanity tables again (no fitting,
no oracles). ``--class-smoothing none`` trains and evaluates on the windows' classes one by one instead of the
class HMM's causal ones (the twin ``bench/env_fusion_gain.py`` compares). ``study.json`` keeps every walk's rows
(``walks``), so any other pair can be compared later.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

CLASSES = ("all", "open", "light", "heavy")
AWARE = ("adaptive_nobp", "adaptive", "adaptive_nobp+lag", "adaptive_nobp+rts")
TWIN = {"adaptive_nobp": "adaptive_nobp_blind", "adaptive": "adaptive_blind",
        "adaptive_nobp+lag": "adaptive_nobp_blind+lag", "adaptive_nobp+rts": "adaptive_nobp_blind+rts"}
RIVALS = ("kf", "kf_quality", "best input")
SANITY = ("kf_quality+lag", "adaptive_blind+lag", "adaptive+lag", "adaptive")
"""The methods held to 'never worse than the best single input': run's default
(:data:`pipeline.commands.fuse.DEFAULT_METHOD`; the study fails with one message if it is not listed here), the
context model with and without the class at the same lag, and the zero-latency one."""


def run_seed(layout, library: Path, out: Path, seed: int, env_mode: str, workers: int | None,
             class_smoothing: str = "forward") -> dict:
    """Fit both models with ``seed``, evaluate the test walks and add the oracles' rows per walk
    (``class_smoothing``: the class HMM's, in training and evaluation, :func:`pipeline.benchmark.fit_and_evaluate`)."""
    from fusion_oracle import oracle_results

    from pipeline.benchmark import fit_and_evaluate
    from pipeline.evaluate import load_model

    res = fit_and_evaluate(layout, library, out, env_mode=env_mode, seed=seed, workers=workers,
                           say=lambda line: print(f"  seed {seed}: {line}", flush=True), progress=True,
                           plots=seed == 0, meta={"seed": seed}, class_smoothing=class_smoothing)
    model = load_model(out / "fusion_model")
    oracles = {o["walk"]: o for o in oracle_results(model, layout.train_walks, layout.test_walks)}
    for r in res["results"]:
        r["rows"] = r["rows"] + oracles[r["walk"]]["rows"]
    res["tuning_report"] = model.meta.get("tuning_report", {})
    return res


def _pooled(results: list[dict]) -> dict:
    """{(method, class): {mean, median, p95, max, nees}} pooled over walks by epochs (medians, p95 and max:
    the epoch-weighted mean of the walks' values, max the largest)."""
    acc: dict = {}
    for res in results:
        for r in res["rows"]:
            acc.setdefault((r["method"], r["env_class"]), []).append(r)
    out = {}
    for key, rows in acc.items():
        n = np.array([r["n"] for r in rows], float)
        w = n / n.sum()
        nees = np.array([r["nees_in_bounds"] for r in rows], float)
        ok = np.isfinite(nees)
        out[key] = {"mean_m": float(w @ [r["mean_m"] for r in rows]), "median_m": float(w @ [r["median_m"] for r in rows]),
                    "p95_m": float(w @ [r["p95_m"] for r in rows]), "max_m": float(max(r["max_m"] for r in rows)),
                    "nees_in_bounds": float(n[ok] @ nees[ok] / n[ok].sum()) if ok.any() else float("nan"),
                    "n": int(n.sum())}
    return out


def _best_input(scores, env_class: str) -> str:
    """gnss or acoustic, whichever has the lower pooled mean error on ``env_class``."""
    best, name = np.inf, "acoustic"
    for m in ("gnss", "acoustic"):
        k = (m, env_class)
        if k in scores.mean_m:
            v, n = scores.mean_m[k], scores.n[k]
            ok = np.isfinite(v)
            if ok.any() and float(np.sum(v[ok] * n[ok]) / n[ok].sum()) < best:
                best, name = float(np.sum(v[ok] * n[ok]) / n[ok].sum()), m
    return name


def sanity(scores) -> list[dict]:
    """Print and return run's default method and the zero-latency one against the best single input per class."""
    from pipeline.commands.fuse import DEFAULT_METHOD
    from pipeline.compare import compare

    print(f"\nSanity: run's default ({DEFAULT_METHOD}), the context models at the same lag and the zero-latency "
          "adaptive against the best single input (must not be worse)\n")
    out = []
    for m in SANITY:
        for c in CLASSES:
            b = _best_input(scores, c)
            cmp = compare(scores, m, b, c)
            if cmp is not None:
                out.append({"method": m, "env_class": c, "input": b, "delta": cmp.delta, "lo": cmp.lo, "hi": cmp.hi,
                            "mean_a_m": cmp.mean_a_m, "mean_b_m": cmp.mean_b_m})
                print(f"- {cmp}")
    return out


def claims(scores) -> list[dict]:
    """Print and return the environment-aware methods against kf, kf_quality, the best input and their twin."""
    from pipeline.compare import compare

    print("\nThe claim: Δ = pooled mean error ratio − 1 (negative: the first method better), 95 % interval over "
          "test sites (bootstrap)\n")
    print("| method | against | class | Δ | 95 % interval | means (m) | walks / sites |")
    print("|---|---|---|---|---|---|---|")
    out = []
    for a in AWARE:
        for rival in RIVALS + (TWIN[a],):
            for c in CLASSES:
                b = _best_input(scores, c) if rival == "best input" else rival
                cmp = compare(scores, a, b, c)
                if cmp is None:
                    continue
                out.append({"a": a, "b": b, "env_class": c, "delta": cmp.delta, "lo": cmp.lo, "hi": cmp.hi,
                            "mean_a_m": cmp.mean_a_m, "mean_b_m": cmp.mean_b_m})
                print(f"| {a} | {b} | {c} | {100 * cmp.delta:+.1f} % | [{100 * cmp.lo:+.1f}, {100 * cmp.hi:+.1f}] | "
                      f"{cmp.mean_a_m:.3f} / {cmp.mean_b_m:.3f} | {cmp.n_walks} / {cmp.n_sites} |")
    return out


def results_from_reports(out: Path, seeds: list[int]) -> list[list[dict]]:
    """Each seed's per-walk rows as :func:`pipeline.compare.walk_scores` takes them, from
    ``out/seed<s>/report/metrics.csv`` (a walk's site is the first part of its name, ``201/w0``; the pooled
    ``all`` rows are left out)."""
    import csv

    by_seed = []
    for s in seeds:
        walks: dict = {}
        with open(out / f"seed{s}" / "report" / "metrics.csv", newline="") as fh:
            for r in csv.DictReader(fh):
                if r["walk"] == "all":          # evaluate's pooled rows, not a walk
                    continue
                row = {"method": r["method"], "env_class": r["env_class"], "n": int(r["n"]),
                       "mean_m": float(r["mean_m"])}
                walks.setdefault(r["walk"], []).append(row)
        by_seed.append([{"walk": w, "site": w.split("/")[0], "rows": rows} for w, rows in walks.items()])
    return by_seed


def main() -> None:
    from fingerprints.survey import build_library
    from pipeline.compare import compare, walk_scores
    from pipeline.evaluate import method_order
    from simulation.split import SPLITS, build_split
    from walks.inputs import CLASS_SMOOTHING

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="standard", choices=sorted(SPLITS))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--env-mode", default="supervised")
    ap.add_argument("--workers", type=int, default=None, help="simulation and evaluation workers (default: cores)")
    ap.add_argument("--train-sites", type=int, nargs="+", default=None,
                    help="site seeds to train on instead of the split's (a replicate with other layouts)")
    ap.add_argument("--test-sites", type=int, nargs="+", default=None, help="site seeds to test on instead")
    ap.add_argument("--class-smoothing", default="forward", choices=CLASS_SMOOTHING,
                    help="the class HMM's smoothing of the window classes in training and evaluation (default: "
                         "forward, what run does; none: each window on its own)")
    ap.add_argument("--reports-only", action="store_true",
                    help="re-read a finished study's seed*/report/metrics.csv: the claim and sanity tables again")
    args = ap.parse_args()
    from pipeline.commands.fuse import DEFAULT_METHOD
    if DEFAULT_METHOD not in SANITY:        # checked before the study's half hour, not after it
        raise SystemExit(f"fusion_study: run's default {DEFAULT_METHOD} is not among the methods held to the best "
                         f"single input ({', '.join(SANITY)}): add it to SANITY")
    if args.reports_only:
        scores = walk_scores(results_from_reports(args.out, args.seeds))
        claims(scores)
        sanity(scores)
        return
    t0 = time.perf_counter()
    split = SPLITS[args.split]
    if args.train_sites or args.test_sites:
        train, test = tuple(args.train_sites or split.train_sites), tuple(args.test_sites or split.test_sites)
        split = dataclasses.replace(split, name=f"{split.name}-sites", train_sites=train,
                                    test_sites=train if split.later_days else test)
    layout = build_split(split, args.out / "data", workers=args.workers or 2,
                         progress=lambda s: print(f"[{time.perf_counter() - t0:6.0f} s] simulated {s}", flush=True))
    library = args.out / "fingerprints.sqlite"
    for site in layout.split.train_sites:
        build_library(layout.survey_dir(site), library, progress=False)
    results = {}
    for seed in args.seeds:
        results[seed] = run_seed(layout, library, args.out / f"seed{seed}", seed, args.env_mode, args.workers,
                                 args.class_smoothing)
        print(f"[{time.perf_counter() - t0:6.0f} s] seed {seed}: evaluated {len(results[seed]['results'])} walks",
              flush=True)
    pooled = {s: _pooled(r["results"]) for s, r in results.items()}
    scores = walk_scores([results[s]["results"] for s in args.seeds])
    methods = method_order({m for p in pooled.values() for (m, _) in p})
    sp = layout.split
    doc = {"split": sp.name, "class_smoothing": args.class_smoothing, "train_sites": list(sp.train_sites),
           "test_sites": list(sp.test_sites),
           "walks_per_site": sp.walks_per_site, "walk_s": sp.walk_s, "seeds": args.seeds, "table": [],
           "claims": [], "sanity": [], "bp": {}, "tuning": results[args.seeds[0]]["tuning_report"]}
    print(f"\n## {sp.name}: train sites {list(sp.train_sites)}, test sites {list(sp.test_sites)}"
          f"{' (test walks four weeks later)' if sp.later_days else ''}, {sp.walks_per_site} walks × "
          f"{sp.walk_s:.0f} s per site; model seeds {args.seeds}; env mode {args.env_mode}; class smoothing "
          f"{args.class_smoothing}\n")
    print("Horizontal error, m: mean / median / p95 / max (mean over seeds), NEES share in the 95 % bounds\n")
    print("| method | class | n | mean | median | p95 | max | NEES in bounds |")
    print("|---|---|---|---|---|---|---|---|")
    for m in methods:
        for c in CLASSES:
            rs = [pooled[s].get((m, c)) for s in args.seeds]
            if any(r is None for r in rs):
                continue
            row = {k: float(np.mean([r[k] for r in rs])) for k in ("mean_m", "median_m", "p95_m", "max_m",
                                                                  "nees_in_bounds")}
            doc["table"].append({"method": m, "env_class": c, "n": rs[0]["n"], **row})
            print(f"| {m} | {c} | {rs[0]['n']} | {row['mean_m']:.3f} | {row['median_m']:.3f} | {row['p95_m']:.3f} | "
                  f"{row['max_m']:.2f} | {row['nees_in_bounds']:.2f} |")
    doc["claims"] = claims(scores)
    doc["sanity"] = sanity(scores)
    print("\nOracle ceilings against adaptive_nobp\n")
    for o in ("oracle_class", "oracle_variance", "oracle_debias"):
        cmp = compare(scores, o, "adaptive_nobp")
        if cmp is not None:
            doc["claims"].append({"a": o, "b": "adaptive_nobp", "env_class": "all", "delta": cmp.delta, "lo": cmp.lo,
                                  "hi": cmp.hi, "mean_a_m": cmp.mean_a_m, "mean_b_m": cmp.mean_b_m})
            print(f"- {cmp}")
    print("\nBP\n")
    for a, b in (("adaptive", "adaptive_nobp"), ("adaptive", "adaptive_blind"),
                 ("adaptive", "adaptive_correction"), ("adaptive_correction", "adaptive_nobp")):
        cmp = compare(scores, a, b)
        if cmp is not None:
            print(f"- {cmp}")
    for s in args.seeds:
        for key in ("bp_disabled_share", "bp_guard_share"):
            shares = [r.get(key) for r in results[s]["results"] if r.get(key) is not None]
            if shares:
                doc["bp"][f"seed{s}.{key}"] = float(np.mean(shares))
                print(f"seed {s}: {key} {100 * np.mean(shares):.1f} % of epochs")
    print("\nTuning on the training walks (seed 0): mean error before -> after\n")
    for m, r in doc["tuning"].items():
        print(f"- {m}: {r['error_before_m']:.3f} -> {r['error_after_m']:.3f} m")
    doc["walks"] = {f"seed{s}": [{"walk": r["walk"], "site": r["site"], "rows": r["rows"]} for r in results[s]["results"]]
                    for s in args.seeds}
    (args.out / "study.json").write_text(json.dumps(doc, indent=1, allow_nan=True, default=float))
    print(f"\nwall time {time.perf_counter() - t0:.0f} s; tables in {args.out / 'study.json'}")


if __name__ == "__main__":
    main()
