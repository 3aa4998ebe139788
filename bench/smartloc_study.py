"""Every fusion method on the shared smartLoc drive, the environment model along it, and what transfers from the simulator.

Data: ../shared/data/gnss_urban_smartloc (the first 170 s of smartLoc's Berlin Potsdamer Platz drive, TU
Chemnitz, CC BY-SA 4.0; ``ENVFUSE_SHARED_DATA`` overrides the folder). Nothing here reads the reference
except to score (and, in the honest variant, to train on the first half only).

1. ``envfuse convert smartloc`` of the whole drive and of its two halves (split at 85 s; one site name).
2. Environment models: **sim** — the ``demo`` benchmark split's model (supervised on simulated
   substations' surveys; ``--demo DIR``, built with :func:`pipeline.benchmark.run_benchmark` when missing,
   a few minutes); **drive** — the unsupervised ``survey`` mode (standardise → t-SNE → DPC → severity
   names, :func:`training.env.fit_env_model`) on the drive's own GNSS windows, no label, no truth
   (**drive-h1**: on the first half's windows only).
3. Fusion models and what each is tuned on:
   - ``transfer``: the demo split's fusion model (noise, knobs and BP networks fitted and tuned on the
     simulator's training walks), with the sim environment model — applied to the drive as it is;
   - ``transfer, drive env``: the same with the drive-clustered classifier in place of the sim one;
   - ``drive h1 → h2``: ``train fusion`` on the first half (noise, knobs, BP, with the drive-h1
     environment model), evaluated on the second half only — the honest variant;
   - ``drive h1 → h2, sim env``: the same with the sim environment model.
4. Every method: mean / median / p95 / max horizontal error against the reference beside the per-epoch
   solver (``gnss``: WLS, RTKLIB weights, Sagnac, RAIM); the environment-aware methods against their blind
   twins, Δ = Σe_A/Σe_B − 1 over paired epochs with a block-bootstrap 95 % interval over 20 s (and 10 s)
   blocks (:func:`pipeline.compare.block_compare`).
5. The classes along the drive (PNG) and Spearman's ρ of each model's occlusion scores — and of the raw
   GNSS features — against the solver's error per window, with block-bootstrap intervals
   (:mod:`pipeline.env_error`).

Run: ``.venv/bin/python bench/smartloc_study.py [--demo demo_out] [--out build/smartloc_study]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from features.schema import ENV_CLASSES, GNSS_FEATURES  # noqa: E402
from models.fusion.model import load_fusion_model  # noqa: E402
from pipeline.compare import block_compare  # noqa: E402
from pipeline.env_error import occlusion_scores, rank_correlation, window_error  # noqa: E402
from pipeline.env_plots import plot_class_track  # noqa: E402
from training.env import fit_env_model, load_env_model, walk_training_set  # noqa: E402
from training.filters import train_fusion  # noqa: E402
from walks.convert import convert_smartloc  # noqa: E402
from walks.fuse import fuse_walk  # noqa: E402
from walks.inputs import WINDOW_S  # noqa: E402
from walks.methods import method_names  # noqa: E402
from walks.score import track_errors  # noqa: E402

SPLIT_S = 85.0
TWINS = (("adaptive_nobp", "adaptive_nobp_blind"), ("adaptive", "adaptive_blind"),
         ("adaptive_nobp+rts", "adaptive_nobp_blind+rts"), ("adaptive+rts", "adaptive_blind+rts"))


def _folder() -> Path:
    env = os.environ.get("ENVFUSE_SHARED_DATA")
    for c in ([Path(env)] if env else []) + [ROOT.parent / "shared" / "data", ROOT.parents[1] / "shared" / "data"]:
        if (c / "gnss_urban_smartloc").is_dir():
            return c / "gnss_urban_smartloc"
    sys.exit("smartloc_study: ../shared/data/gnss_urban_smartloc not found (set ENVFUSE_SHARED_DATA)")


def _convert(folder: Path, out: Path) -> dict:
    src = (folder / "Berlin_Potsdamer_Platz_Input.txt", folder / "Berlin_Potsdamer_Platz_GT.txt")
    spans = {"drive": (None, None), "h1": (None, SPLIT_S), "h2": (SPLIT_S, None)}
    walks = {}
    for name, (a, b) in spans.items():
        d = out / "walks" / name
        convert_smartloc(*src, d, start_s=a, end_s=b, site_name="Berlin_Potsdamer_Platz", overwrite=True)
        walks[name] = d
    return walks


def _demo(demo: Path):
    if not (demo / "fusion_model" / "bundle.json").is_file():
        from pipeline.benchmark import run_benchmark

        print(f"building the demo split's models in {demo} (a few minutes) ...")
        run_benchmark("demo", demo, workers=1, say=lambda s: None)
    return load_fusion_model(demo / "fusion_model"), load_env_model(demo / "env_model")[0]


def _survey_env(walk: Path):
    clf, info = fit_env_model(walk_training_set([walk]), "survey", random_state=0)
    return clf, info


def _run(walk: Path, model) -> dict:
    fused = fuse_walk(walk, model, None, force=True)
    errs = {m: track_errors(tr, fused.data.truth) for m, tr in fused.tracks.items()}
    return {"fused": fused, "errors": errs}


def _table(results: dict) -> None:
    names = [m for m in method_names(smoothed=True) if not m.endswith("+lag")]
    variants = list(results)
    print("\nhorizontal error against the reference, m: mean / median / p95 / max (every event of a filter, every "
          "fix of a source)")
    head = f"{'method':24s}" + "".join(f"{v:>34s}" for v in variants)
    print(head)
    print("-" * len(head))
    for m in names:
        cells = []
        for v in variants:
            e = results[v]["errors"].get(m)
            if e is None or not len(e["err_m"]):
                cells.append(f"{'-':>34s}")
                continue
            x = e["err_m"]
            cells.append(f"{x.mean():8.2f}{np.median(x):8.2f}{np.percentile(x, 95):9.2f}{x.max():9.2f}")
        if any(c.strip() != "-" for c in cells):
            print(f"{m:24s}" + "".join(cells))
    print("NEES inside the two-sided 95 % chi2_2 region (share of epochs):")
    from models.fusion.consistency import chi2_bounds

    lo, hi = chi2_bounds(2)
    for m in ("gnss", "kf", "kf_quality", "aekf", "imm", "adaptive_nobp", "adaptive_nobp_blind", "adaptive",
              "adaptive_blind"):
        vals = []
        for v in variants:
            e = results[v]["errors"].get(m)
            n = e["nees"][np.isfinite(e["nees"])] if e is not None else np.zeros(0)
            vals.append(f"{np.mean((n >= lo) & (n <= hi)):.2f}" if n.size else "-")
        print(f"  {m:22s} " + "  ".join(f"{v}: {x}" for v, x in zip(variants, vals)))


def _twins(results: dict) -> None:
    print("\nenvironment-aware methods against their blind twins: delta = sum e_A / sum e_B - 1, paired epochs, "
          "95 % block bootstrap")
    for v, res in results.items():
        print(f"  [{v}]")
        for a, b in TWINS:
            ea, eb = res["errors"].get(a), res["errors"].get(b)
            if ea is None or eb is None:
                print(f"    {a} vs {b}: not both run")
                continue
            for block in (20.0, 10.0):
                c = block_compare(ea["t_s"], ea["err_m"], eb["t_s"], eb["err_m"], a, b, block_s=block)
                print(f"    {c}")


def _env_along(drive_res: dict, clfs: dict, out: Path) -> None:
    fused = drive_res["fused"]
    inputs, data = fused.inputs, fused.data
    t_end, X = inputs.window_t_s, inputs.window_X
    t_mid = t_end - WINDOW_S / 2.0
    g = drive_res["errors"]["gnss"]
    err = window_error(t_end, g["t_s"], g["err_m"])
    proba = {name: clf.predict_proba(X) for name, clf in clfs.items()}
    print(f"\nenvironment classes over the drive's {len(t_end)} windows (open / light / heavy):")
    for name, p in proba.items():
        counts = np.bincount(np.argmax(p, axis=1), minlength=3)
        by = [np.nanmedian(err[np.argmax(p, axis=1) == k]) if (np.argmax(p, axis=1) == k).any() else np.nan
              for k in range(3)]
        print(f"  {name:42s} {counts[0]:4d} / {counts[1]:4d} / {counts[2]:4d}   solver's median window error "
              f"per class {by[0]:.1f} / {by[1]:.1f} / {by[2]:.1f} m")
    tr = data.truth
    png = plot_class_track({"t_s": tr.t_s, "east_m": tr.east_m, "north_m": tr.north_m}, t_mid, proba,
                           out / "classes_along_drive.png",
                           {"t_s": t_mid, "err_m": err, "label": "per-epoch solver (WLS, RAIM): mean error per window"},
                           "smartLoc Berlin Potsdamer Platz: environment classes along the reference track")
    print(f"  plot -> {png}")
    print("\nSpearman rank correlation with the solver's mean error per window (95 % block bootstrap, 20 s blocks):")
    for name, clf in clfs.items():
        for score, s in occlusion_scores(proba[name], clf, X).items():
            print(f"  {name:42s} {rank_correlation(s, err, t_mid, name=score)}")
    for j, f in enumerate(GNSS_FEATURES):
        print(f"  {'raw feature':42s} {rank_correlation(X[:, j], err, t_mid, name=f)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--demo", type=Path, default=ROOT / "demo_out", help="demo split output (models)")
    parser.add_argument("--out", type=Path, default=ROOT / "build" / "smartloc_study", help="working directory")
    args = parser.parse_args()
    t0 = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    walks = _convert(_folder(), args.out)
    sim_fusion, sim_env = _demo(args.demo)
    drive_env, info = _survey_env(walks["drive"])
    h1_env, info_h1 = _survey_env(walks["h1"])
    print(f"drive-clustered environment model: {info['n_clusters']} clusters -> open/light/heavy "
          f"{info['class_counts']} windows; first half: {info_h1['n_clusters']} clusters -> {info_h1['class_counts']}")
    say = (lambda line: None)
    h1_model = train_fusion([walks["h1"]], h1_env, meta={"study": "drive h1"}, progress=say)
    h1_model_sim = train_fusion([walks["h1"]], sim_env, meta={"study": "drive h1, sim env"}, progress=say)
    print("tuning on the first half: " + "; ".join(f"{m} {r['error_before_m']:.1f} -> {r['error_after_m']:.1f} m"
                                                  for m, r in h1_model.meta.get("tuning_report", {}).items()))
    results = {
        "transfer (full drive)": _run(walks["drive"], sim_fusion),
        "transfer, drive env (full)": _run(walks["drive"], replace(sim_fusion, classifier=drive_env)),
        "transfer (h2)": _run(walks["h2"], sim_fusion),
        "drive h1 -> h2": _run(walks["h2"], h1_model),
        "drive h1 -> h2, sim env": _run(walks["h2"], h1_model_sim),
    }
    _table(results)
    _twins(results)
    _env_along(results["transfer (full drive)"], {"sim (demo split, supervised)": sim_env,
                                                  "drive (survey mode)": drive_env}, args.out)
    print(f"\nstudy took {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
