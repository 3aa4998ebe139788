"""Environment-model study (issue 13): every mode, leave-site-out, per window and per cell; prints tables.

Builds (or reuses) the surveys of a benchmark split, ingests them into one
fingerprint library, and scores against the cells' map labels:

- ``paper``      the site's own windows, t-SNE + DPC, severity-named clusters taken as the classes;
- ``kmeans``     the same with K-means (k = 3) on the standardised 14-D windows;
- ``survey``     the online classifier fitted on the site's own clusters, classifying the site's windows;
- ``transfer``   clusters of the training sites' library → classifier → each test site;
- ``supervised`` classifier on the training sites' map labels → each test site;
- ``same-site``  supervised on half of a test site's *cells* (cells, not windows, are the unit), scored on
                 the other half — marked as such: the published figures are probably of this kind.

Per test site and mode: recall per class (open / light / heavy) and macro-F1, over all cells and over
cells at least ``--margin`` points of blocked-sky share from a class boundary (10 % and 40 %); windows and
cells (a cell takes the class of its windows' combined probabilities, or their majority for the
clustering modes). Then mean ± SD over test sites, clusters found, the continuous estimate's residual SD
(points), missing-modality accuracy, and the OOD share on held-out windows vs shifted windows.

``--sky both`` (the default) scores every mode twice on the same surveys and windows: once against the
label of the satellites' sky (the definition since issue 13) and once against the uniform (solid-angle)
sky the project started with, recomputed from the same cells' capture points, so the effect of the
definition shows apart from the model. ``--cell-size-m`` / ``--capture-s`` override the split's survey
(the split's 10 m cells give 6–12 heavy cells a site; 5 m cells give 22–36).

Usage: ``python bench/env_study.py --split standard --cell-size-m 5 --capture-s 4 --out /tmp/env_study``
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from features.schema import GNSS_FEATURES  # noqa: E402

BOUNDS = (0.10, 0.40)


def class_scores(y_true, y_pred):
    from sklearn.metrics import f1_score

    rec = [float(np.mean(y_pred[y_true == k] == k)) if np.any(y_true == k) else np.nan for k in range(3)]
    f1 = float(f1_score(y_true, y_pred, labels=[0, 1, 2], average="macro", zero_division=0))
    return rec + [f1]


def cell_predictions(ts, pred_w, proba_w=None):
    """Cell-level prediction: combined probabilities when given, else the windows' majority."""
    from models.environment import combine_windows

    keys = list(zip(ts.site.tolist(), ts.cell.tolist()))
    out = {}
    for i, k in enumerate(keys):
        out.setdefault(k, []).append(i)
    cell_pred, cell_true, cell_share = [], [], []
    for k, idx in out.items():
        idx = np.array(idx)
        if proba_w is not None:
            cell_pred.append(int(np.argmax(combine_windows(proba_w[idx]))))
        else:
            v = pred_w[idx]
            v = v[v >= 0]
            cell_pred.append(int(np.bincount(v, minlength=3).argmax()) if v.size else -1)
        cell_true.append(int(ts.label[idx[0]]))
        cell_share.append(float(ts.share[idx[0]]))
    return np.array(cell_pred), np.array(cell_true), np.array(cell_share)


def far_from_boundary(share, margin):
    return np.min(np.abs(share[:, None] - np.array(BOUNDS)[None, :]), axis=1) >= margin


def main() -> None:
    from fingerprints.survey import build_library
    from models.environment import EnvironmentClassifier
    from simulation.split import SPLITS, build_split
    from training.clustering import cluster_windows
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="quick", choices=sorted(SPLITS))
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--margin", type=float, default=0.03, help="distance from a class boundary, share (0.03)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sky", default="both", choices=("both", "satellites", "uniform"),
                    help="label definition(s) to score against (both: the same windows twice)")
    ap.add_argument("--cell-size-m", type=float, default=None, help="survey cell size (default: the split's)")
    ap.add_argument("--capture-s", type=float, default=None, help="capture per cell (default: the split's)")
    ap.add_argument("--workers", type=int, default=2, help="simulation processes (default 2)")
    args = ap.parse_args()
    split = SPLITS[args.split]
    if args.cell_size_m or args.capture_s:
        split = replace(split, name=f"{split.name}-c{args.cell_size_m or split.cell_size_m:g}",
                        cell_size_m=args.cell_size_m or split.cell_size_m, capture_s=args.capture_s or split.capture_s)
    layout = build_split(split, args.out / "data", progress=lambda s: print("  simulated", s, flush=True),
                         walks=False, workers=args.workers)
    sp = layout.split
    # its own library: it holds the test sites too, which the fusion study's and the benchmark's
    # libraries (training sites only, fingerprints.sqlite beside it) must never see
    lib = args.out / "fingerprints_env_study.sqlite"
    for site in sp.train_sites + sp.test_sites:
        build_library(layout.survey_dir(site), lib, progress=False)
    all_ts = training_set(lib)
    site_names = sorted(set(all_ts.site.tolist()))              # generated sites are named sim-<seed>
    train_names = [n for n in site_names if int(n.split("-")[-1]) in sp.train_sites]
    test_names = [n for n in site_names if int(n.split("-")[-1]) in sp.test_sites]
    print(f"library: {len(all_ts)} windows; training sites {train_names}; test sites {test_names}")
    skies = ("satellites", "uniform") if args.sky == "both" else (args.sky,)
    for sky in skies:
        ts = relabel(all_ts, layout, sky)
        n_heavy = [len(set(ts.cell[(ts.site == n) & (ts.label == 2)].tolist())) for n in test_names]
        print(f"\n=== label: {sky} sky; heavy cells per test site {n_heavy} ===")
        study(ts, train_names, test_names, args)


def relabel(all_ts, layout, sky: str):
    """The same windows with map label and share recomputed under the ``sky`` weighting, from each cell's
    capture point (cell.toml) and the site's layout (simulated sites only)."""
    from dataclasses import replace as dc_replace

    from features.fileio import read_toml
    from features.site import load_site
    from simulation.site.environment import blocked_share, classify_share

    label, share = all_ts.label.copy(), all_ts.share.copy()
    for seed in layout.split.train_sites + layout.split.test_sites:
        d = layout.survey_dir(seed)
        site = load_site(d / "site.toml")
        sel = all_ts.site == site.name
        cells = sorted(set(all_ts.cell[sel].tolist()))
        pts = [read_toml(d / "cells" / c / "cell.toml") for c in cells]
        sh = blocked_share(site, [p["east_m"] for p in pts], [p["north_m"] for p in pts], sky=sky)
        by_cell = dict(zip(cells, zip(classify_share(sh), sh)))
        for i in np.flatnonzero(sel):
            label[i], share[i] = by_cell[all_ts.cell[i]]
    return dc_replace(all_ts, label=label, share=share)


def study(all_ts, train_names, test_names, args) -> None:
    """Every mode on ``test_names`` (models fitted on ``train_names`` or the site itself); prints the tables."""
    from models.environment import EnvironmentClassifier
    from training.clustering import cluster_windows

    train = all_ts.subset(np.isin(all_ts.site, train_names))
    rows = {}   # (mode, unit, subset) -> list of per-site [r_open, r_light, r_heavy, f1]
    nclust = {"paper": [], "kmeans": [], "transfer": []}

    def add(mode, ts, pred_w, proba_w=None):
        ok = ts.label >= 0
        far_w = far_from_boundary(ts.share, args.margin)
        for subset, sel in (("all", ok), ("far", ok & far_w)):
            rows.setdefault((mode, "window", subset), []).append(class_scores(ts.label[sel], pred_w[sel]))
        cp, ct, cs = cell_predictions(ts, pred_w, proba_w)
        okc = ct >= 0
        for subset, sel in (("all", okc), ("far", okc & far_from_boundary(cs, args.margin))):
            rows.setdefault((mode, "cell", subset), []).append(class_scores(ct[sel], cp[sel]))

    sup = EnvironmentClassifier().fit(train.X[train.label >= 0], train.label[train.label >= 0],
                                      share=train.share[train.label >= 0])
    tr_cl = cluster_windows(train.X, random_state=args.seed)
    nclust["transfer"].append(tr_cl.n_clusters)
    okt = tr_cl.labels >= 0
    transfer = EnvironmentClassifier().fit(train.X[okt], tr_cl.labels[okt])
    resid, miss, ood_in, ood_shift = [], {"gnss": [], "acoustic": []}, [], []
    for name in test_names:
        ts = all_ts.subset(all_ts.site == name)
        for mode, method in (("paper", "dpc"), ("kmeans", "kmeans")):
            cl = cluster_windows(ts.X, method=method, random_state=args.seed)
            nclust[mode].append(cl.n_clusters)
            add(mode, ts, cl.labels)
            if mode == "paper":
                ok = cl.labels >= 0
                own = EnvironmentClassifier().fit(ts.X[ok], cl.labels[ok])
                p = own.predict_proba(ts.X)
                add("survey", ts, p.argmax(1), p)
        p = transfer.predict_proba(ts.X)
        add("transfer", ts, p.argmax(1), p)
        p = sup.predict_proba(ts.X)
        add("supervised", ts, p.argmax(1), p)
        resid.append(float(np.nanstd(sup.occlusion(ts.X) - ts.share)) * 100)
        for mod, cols in (("gnss", slice(len(GNSS_FEATURES), None)), ("acoustic", slice(0, len(GNSS_FEATURES)))):
            Xm = ts.X.copy()
            Xm[:, cols] = np.nan
            pm = sup.predict(Xm)
            ok = ts.label >= 0
            miss[mod].append(float(np.mean(pm[ok] == ts.label[ok])))
        ood_in.append(float(sup.is_ood(ts.X).mean()))
        ood_shift.append(float(sup.is_ood(ts.X + 3.0 * np.nanstd(train.X, axis=0)).mean()))
        # same-site: half of the cells (by a seeded draw) train, the other half test
        cells = sorted(set(ts.cell.tolist()))
        rng = np.random.default_rng(args.seed)
        half = set(rng.permutation(cells)[: len(cells) // 2].tolist())
        tr_m = np.isin(ts.cell, list(half)) & (ts.label >= 0)
        te = ts.subset(~np.isin(ts.cell, list(half)))
        if tr_m.sum() >= 30 and len(np.unique(ts.label[tr_m])) >= 2:
            ss = EnvironmentClassifier().fit(ts.X[tr_m], ts.label[tr_m])
            p = ss.predict_proba(te.X)
            add("same-site", te, p.argmax(1), p)

    print(f"\nrecall open / light / heavy and macro-F1 against map labels, mean ± SD over {len(test_names)} "
          f"held-out sites; 'far' = cells at least {100 * args.margin:.0f} points from a class boundary")
    print(f"{'mode':11s} {'unit':6s} {'cells':5s}  {'open':>11s} {'light':>11s} {'heavy':>11s} {'macro-F1':>11s}")
    for mode in ("paper", "kmeans", "survey", "transfer", "supervised", "same-site"):
        for unit in ("window", "cell"):
            for subset in ("all", "far"):
                v = np.array(rows.get((mode, unit, subset), []), float)
                if v.size == 0:
                    continue
                m, s = np.nanmean(v, axis=0), np.nanstd(v, axis=0)
                print(f"{mode:11s} {unit:6s} {subset:5s}  " + " ".join(f"{100 * a:5.1f}±{100 * b:4.1f}"
                                                                       for a, b in zip(m, s)))
    for k, v in nclust.items():
        print(f"clusters found ({k}): {v}")
    print(f"continuous blocked-share estimate (supervised), residual SD: {np.mean(resid):.1f} ± {np.std(resid):.1f} "
          "points")
    print(f"missing modality (supervised, window accuracy): GNSS only {100 * np.mean(miss['gnss']):.1f} %, "
          f"acoustic only {100 * np.mean(miss['acoustic']):.1f} %")
    print(f"OOD flagged: held-out windows {100 * np.mean(ood_in):.1f} %, windows shifted by 3 SD "
          f"{100 * np.mean(ood_shift):.1f} %")


if __name__ == "__main__":
    main()
