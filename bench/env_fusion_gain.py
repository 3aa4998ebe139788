"""What the fusion methods gain from the class HMM's smoothed window classes (issue 27, last "Must show").

Two arms on a built split, each over the same model seeds, the same environment model and class HMM:

- ``forward`` (today's pipeline): the HMM's causal (forward) class probabilities in training (noise per class,
  tuning, BP, calibration: :func:`training.filters.train_fusion`) and in evaluation (``run``'s classes);
- ``none`` (the twin with the ingredient removed): every window on its own in training and evaluation alike,
  so the filters' tuning is fitted on the classes they then get.

Optionally (``--arms fb_rts``, once the ``forward`` arm's models exist) they are evaluated again with the
forward–backward classes (the whole walk), scored for the ``+rts`` tracks only: an RTS smoother uses the walk's
future anyway, so an offline user may hand it the smoothed classes; its tuning was fitted on forward classes
(labelled so).

Printed (Markdown) and written to ``<out>/gain.json``: per method and class the pooled mean horizontal error of
each arm and Δ = ratio of pooled means − 1 (forward against none; negative: smoothing helps) with a 95 %
interval from a bootstrap over test sites (:func:`pipeline.compare.compare`, per-walk means first averaged over
the seeds); kind ``class``: the method takes the classifier's classes, ``map``: the site map's, ``blind``: none
— the blind ones (the twins among them) are the sanity check: their inputs hold no class, so Δ = 0. Then the
per-window class accuracy along the held-out walks (each window alone / forward / forward–backward), the gain
in points with the same site bootstrap, and how often the argmax class changes.

Each arm and seed is kept in ``<out>/<arm>/seed<s>`` (models and ``report/metrics.csv``) and reused when there,
so a run can be resumed or extended by seeds; ``--tables-only`` re-reads what is there.

Result (2 December 2026, ``standard`` split: trained on sites 101–106, 15 test walks of sites 201–205; model
seeds 0, 1, 2, BP members 5; the seeds change only the BP networks — the supervised environment model, the class
HMM, the noise fits and the tuning are the same for every seed): forward against none, Δ [95 % site interval],

  adaptive          all −7.2 % [−9.6, −2.6]   open −5.5 % [−10.3, +4.2]  light +0.3 % [−3.4, +4.8]  heavy −12.4 % [−17.6, −0.1]
  adaptive_nobp     all −7.6 % [−10.4, −2.2]  open −7.9 % [−10.6, +2.0]  light −0.9 % [−3.4, +1.9]  heavy −11.9 % [−18.1, +1.7]
  adaptive+lag      all −5.2 % [−9.6, +1.9]   open +2.9 % [−1.5, +6.3]   light −3.0 % [−13.6, +4.1] heavy −7.6 % [−13.9, +1.3]
  adaptive_nobp+rts all −7.7 % [−19.6, +4.6]  open +5.6 % [+0.6, +10.4]  light +1.2 % [−3.0, +8.1]  heavy −11.8 % [−24.4, +4.7]
  imm               all −1.0 % [−3.8, +2.5]   open −8.5 % [−12.2, −5.2]  light +1.2 % [−1.0, +4.3]  heavy +0.3 % [−4.0, +6.0]
  uwb_aoa_pdr_env   all −14.9 % [−30.0, +0.8] heavy −55.1 % [−80.0, −1.9]

(adaptive 0.18 against 0.20 m overall, 0.47 against 0.53 m in heavy); all 28 class-blind and map rows exactly
+0.0 %. The forward–backward classes add little to the RTS tracks: adaptive_nobp+rts −2.0 % [−10.0, +5.2] against
forward. Per-window accuracy on the same walks: each window alone 81.8 %, forward 81.3 % (−0.5 [−1.5, +0.4]
points), forward–backward 83.2 % (+1.5 [+1.0, +1.9]): the causal HMM does not make the argmax more often right,
yet the filters gain from its steadier probabilities: the argmax class changes 2.39 times a minute against 5.04
for the windows alone (truth 2.01; forward–backward 1.65).

``later_days`` (five sites, test walks four weeks after the training walks; seeds 0, 1): adaptive all −13.8 %
[−30.8, −1.2], open −61.0 % [−78.6, −24.5] (0.06 against 0.15 m), light −1.0 % [−20.8, +12.0], heavy +3.6 %
[−1.3, +7.3]; adaptive_nobp all −8.5 % [−18.3, −0.1]; imm worse with the HMM in open (+15.5 % [+11.9, +17.7]),
better in heavy (−2.3 % [−4.0, −0.7]); 31 blind and map rows +0.0 %. Accuracy 70.0 / 70.3 / 70.6 % (window /
forward / forward–backward), changes per minute 5.63 / 3.11 / 2.35 (truth 2.15).

Usage: ``python bench/env_fusion_gain.py --data /work/studies/standard/data --out /work/studies/envgain/standard
--seeds 0 1 2 --workers 1``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

CLASSES = ("all", "open", "light", "heavy")
ARMS = ("forward", "none")
FB = "fb_rts"
"""The ``forward`` arm's models evaluated with forward–backward classes (``+rts`` tracks only)."""
CLASS_AWARE = ("imm", "adaptive_nobp", "adaptive", "adaptive_correction", "fg_env", "uwb_aoa_pdr_env")
"""Methods whose inputs hold the classifier's classes (their ``+lag`` / ``+rts`` tracks too)."""
MAP = ("kf_map",)
"""Methods that take the site map's class, not the classifier's."""
MODES = ("none", "forward", "forward_backward")


def run_arm(layout, library: Path, out: Path, arm: str, seed: int, workers: int, bp_members: int,
            methods=None) -> None:
    """Fit and evaluate one arm with one seed into ``out`` (kept when its report is already there); ``methods``:
    the ones evaluated (default: every registered one)."""
    from pipeline.benchmark import fit_and_evaluate

    if (out / "report" / "metrics.csv").is_file():
        print(f"  {arm} seed {seed}: kept ({out})", flush=True)
        return
    t0 = time.process_time()
    fit_and_evaluate(layout, library, out, seed=seed, workers=workers, bp_members=bp_members, plots=False,
                     say=lambda line: print(f"  [{time.strftime('%H:%M:%S')}, {time.process_time() - t0:5.0f} s CPU] "
                                            f"{arm} seed {seed}: {line}", flush=True), meta={"seed": seed},
                     class_smoothing=arm, methods=methods)
    print(f"  {arm} seed {seed}: done, {time.process_time() - t0:.0f} s CPU in this process", flush=True)


def run_fb(layout, out: Path, seed: int, workers: int) -> None:
    """The ``forward`` arm's model of ``seed`` on the test walks with forward–backward classes (filters only)."""
    from pipeline.evaluate import evaluate

    from features.errors import EnvfuseError

    report = out / FB / f"seed{seed}" / "report"
    if (report / "metrics.csv").is_file():
        return
    model = out / "forward" / f"seed{seed}" / "fusion_model"
    if not (model / "bundle.json").is_file():
        raise EnvfuseError(f"{model}: no forward-arm model of seed {seed} to evaluate with forward–backward classes")
    t0 = time.process_time()
    bases = ("adaptive_nobp", "adaptive", "adaptive_nobp_blind", "adaptive_blind", "imm")
    evaluate(layout.test_walks, model, report, methods=bases, workers=workers, progress=False, plots=False,
             force=True, class_smoothing="forward_backward")
    print(f"  {FB} seed {seed}: done, {time.process_time() - t0:.0f} s CPU", flush=True)


def merged_scores(out: Path, arms: list[str], seeds: list[int]):
    """:class:`pipeline.compare.WalkScores` of every arm's rows, methods named ``<method>@<arm>``."""
    from fusion_study import results_from_reports

    from pipeline.compare import walk_scores

    reports = {(arm, s): results_from_reports(out / arm, [s])[0] for arm in arms for s in seeds}
    # a method enters when every seed of its arm evaluated it (the graph methods may be left out of later seeds)
    have = {arm: set.intersection(*({r["method"] for res in reports[(arm, s)] for r in res["rows"]} for s in seeds))
            for arm in arms}
    by_seed = []
    for s in seeds:
        walks: dict = {}
        for arm in arms:
            for res in reports[(arm, s)]:
                w = walks.setdefault(res["walk"], {"walk": res["walk"], "site": res["site"], "rows": []})
                w["rows"] += [{**r, "method": f"{r['method']}@{arm}"} for r in res["rows"] if r["method"] in have[arm]]
        by_seed.append([walks[k] for k in sorted(walks)])
    return walk_scores(by_seed)


def gain_table(scores, arms: list[str]) -> list[dict]:
    """Δ of ``forward`` against ``none`` per method and class, printed as one Markdown row per method."""
    from pipeline.compare import compare
    from pipeline.evaluate import method_order

    names = {k[0].rsplit("@", 1)[0] for k in scores.mean_m if k[0].endswith("@forward")}
    rows = []
    print("\nΔ = pooled mean error (forward) / (none) − 1, 95 % interval over test sites; means in m "
          "(forward / none)\n")
    print("| method | kind | " + " | ".join(CLASSES) + " |")
    print("|---|---|" + "---|" * len(CLASSES))
    for m in method_order(names):
        base = m.split("+")[0]
        kind = "class" if base in CLASS_AWARE else "map" if base in MAP else "blind"
        cells = []
        for c in CLASSES:
            cmp = compare(scores, f"{m}@forward", f"{m}@none", c)
            if cmp is None:
                cells.append("")
                continue
            rows.append({"method": m, "kind": kind, "env_class": c, "delta": cmp.delta, "lo": cmp.lo, "hi": cmp.hi,
                         "mean_forward_m": cmp.mean_a_m, "mean_none_m": cmp.mean_b_m, "walks": cmp.n_walks,
                         "sites": cmp.n_sites})
            star = "**" if cmp.excludes_zero else ""
            cells.append(f"{star}{100 * cmp.delta:+.1f} %{star} [{100 * cmp.lo:+.1f}, {100 * cmp.hi:+.1f}] "
                         f"({cmp.mean_a_m:.2f} / {cmp.mean_b_m:.2f})")
        print(f"| {m} | {kind} | " + " | ".join(cells) + " |")
    if FB in arms:
        print("\nOffline: the forward arm's models with forward–backward classes, RTS tracks (tuned on forward "
              "classes)\n")
        for m in sorted({k[0].rsplit("@", 1)[0] for k in scores.mean_m if k[0].endswith(f"@{FB}")}):
            if not m.endswith("+rts"):
                continue
            for ref in ("forward", "none"):
                for c in CLASSES:
                    cmp = compare(scores, f"{m}@{FB}", f"{m}@{ref}", c)
                    if cmp is not None:
                        rows.append({"method": m, "kind": FB, "against": ref, "env_class": c, "delta": cmp.delta,
                                     "lo": cmp.lo, "hi": cmp.hi, "mean_fb_m": cmp.mean_a_m, "mean_ref_m": cmp.mean_b_m})
                        print(f"- {m} fb vs {ref} ({c}): {100 * cmp.delta:+.1f} % [{100 * cmp.lo:+.1f}, "
                              f"{100 * cmp.hi:+.1f}] ({cmp.mean_a_m:.3f} vs {cmp.mean_b_m:.3f} m)")
    return rows


def class_accuracy(layout, out: Path, seeds: list[int]) -> dict:
    """Per-window class accuracy on the test walks with the ``forward`` arm's classifier and class HMM of each
    seed, in each of :data:`MODES` (the classes :func:`walks.inputs.smooth_classes` hands the filters, argmax),
    pooled over seeds; the gain over ``none`` in points with a site-bootstrap interval."""
    from env_along_walk import walk_windows

    from models.fusion.model import load_fusion_model
    from pipeline.compare import cluster_bootstrap
    from walks.inputs import smooth_classes

    walks = [walk_windows(w, out / "windows") for w in layout.test_walks]
    sites = np.array([w["site"] for w in walks])
    # correct[mode][walk], n[walk], per class too: counts summed over seeds
    correct = {m: np.zeros((len(walks), 4)) for m in MODES}
    count = np.zeros((len(walks), 4))
    changes = {m: 0 for m in MODES}               # argmax class changes between consecutive windows, over seeds
    for s in seeds:
        model = load_fusion_model(out / "forward" / f"seed{s}" / "fusion_model")
        clf, hmm = model.classifier, model.temporal
        for i, w in enumerate(walks):
            p = clf.predict_proba(w["X"])
            y = w["label"]
            ok = y >= 0
            for mode in MODES:
                yp = smooth_classes(p, w["t_end"], clf.answers(w["X"]), clf, hmm, mode).argmax(1)
                changes[mode] += int(np.sum(np.diff(yp) != 0))
                hit = (yp == y) & ok
                correct[mode][i, 0] += hit.sum()
                for k in range(3):
                    correct[mode][i, k + 1] += (hit & (y == k)).sum()
            count[i, 0] += ok.sum()
            for k in range(3):
                count[i, k + 1] += (y == k).sum()
    res = {"seeds": seeds, "windows": int(count[:, 0].sum() / len(seeds)), "accuracy": {}, "gain": {}}
    print(f"\nPer-window class accuracy along the {len(walks)} test walks ({res['windows']} labelled windows, "
          f"seeds {seeds} pooled), percent; gain over each window alone in points, 95 % interval over sites\n")
    minutes = len(seeds) * sum(len(w["label"]) for w in walks) / 60.0         # one window per hop of 1 s
    truth = sum(int(np.sum(np.diff(w["label"]) != 0)) for w in walks) * len(seeds) / minutes
    res["changes_per_min"] = {m: changes[m] / minutes for m in MODES} | {"truth": truth}
    print("| classes | " + " | ".join(CLASSES) + " | class changes / min |")
    print("|---|" + "---|" * (len(CLASSES) + 1))
    for mode in MODES:
        acc = correct[mode].sum(0) / count.sum(0)
        res["accuracy"][mode] = dict(zip(CLASSES, acc.tolist()))
        cells = [f"{100 * a:.1f}" for a in acc]
        if mode != "none":
            gains = {}
            for j, c in enumerate(CLASSES):
                def stat(rows, j=j, mode=mode):
                    n = count[rows, j].sum()
                    return float((correct[mode][rows, j].sum() - correct["none"][rows, j].sum()) / n) if n else np.nan
                lo, hi = cluster_bootstrap(stat, sites)
                g = stat(np.arange(len(walks)))
                gains[c] = {"gain": g, "lo": lo, "hi": hi}
                cells[j] += f" ({100 * g:+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}])"
            res["gain"][mode] = gains
        print(f"| {mode} | " + " | ".join(cells) + f" | {changes[mode] / minutes:.2f} |")
    print(f"| truth | | | | | {truth:.2f} |")
    return res


def main() -> None:
    from fingerprints.survey import build_library
    from simulation.split import split_layout

    from features.errors import EnvfuseError

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a built split (read only)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--bp-members", type=int, default=5, help="BP ensemble members (the study's 5)")
    ap.add_argument("--arms", nargs="+", default=list(ARMS), choices=ARMS + (FB,),
                    help="the arms to run here (processes may share --out, one arm each); fb_rts: the forward "
                         "arm's models (fitted already) with forward–backward classes, RTS tracks only")
    ap.add_argument("--methods", nargs="+", default=None,
                    help="the methods evaluated in both arms (default: every one; the tables keep those every seed has)")
    ap.add_argument("--tables-only", action="store_true", help="print the tables from what is in --out")
    args = ap.parse_args()
    try:
        if not (args.data / "split.toml").is_file():
            raise EnvfuseError(f"--data {args.data}: no split.toml (build the split first)")
        layout = split_layout(args.data)
        args.out.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        if not args.tables_only:
            library = args.out / "fingerprints.sqlite"
            if not library.is_file():
                tmp = library.with_suffix(".tmp.sqlite")
                tmp.unlink(missing_ok=True)
                for site in layout.split.train_sites:
                    build_library(layout.survey_dir(site), tmp, progress=False)
                tmp.rename(library)
            for seed in args.seeds:          # seed by seed, both arms: a cut-short run still has paired seeds
                for arm in args.arms:
                    if arm == FB:
                        run_fb(layout, args.out, seed, args.workers)
                    else:
                        run_arm(layout, library, args.out / arm / f"seed{seed}", arm, seed, args.workers,
                                args.bp_members, args.methods)
                print(f"[{time.perf_counter() - t0:6.0f} s wall] seed {seed} done", flush=True)
        seeds = [s for s in args.seeds if all((args.out / a / f"seed{s}" / "report" / "metrics.csv").is_file()
                                              for a in ARMS)]
        if not seeds and not args.tables_only:
            from env_along_walk import walk_windows

            for w in layout.test_walks:              # the class-accuracy table's windows, read once for later
                walk_windows(w, args.out / "windows")
            print(f"no seed with both arms evaluated yet in {args.out}: tables later (--tables-only)")
            return
        if not seeds:
            raise EnvfuseError(f"{args.out}: no seed with both arms evaluated")
        arms = list(ARMS) + ([FB] if all((args.out / FB / f"seed{s}" / "report" / "metrics.csv").is_file()
                                         for s in seeds) else [])
        sp = layout.split
        print(f"\n## {sp.name}: train sites {list(sp.train_sites)}, test sites {list(sp.test_sites)}, model seeds "
              f"{seeds}, BP members {args.bp_members}")
        doc = {"split": sp.name, "seeds": seeds, "bp_members": args.bp_members,
               "gain": gain_table(merged_scores(args.out, arms, seeds), arms),
               "class_accuracy": class_accuracy(layout, args.out, seeds)}
        tmp = args.out / "gain.json.tmp"
        tmp.write_text(json.dumps(doc, indent=1, allow_nan=True))
        tmp.rename(args.out / "gain.json")
    except EnvfuseError as exc:
        sys.exit(f"env_fusion_gain: {exc}")


if __name__ == "__main__":
    main()
