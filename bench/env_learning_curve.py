"""Learning curve of the environment model (issue 27 item 1): how many surveyed sites, how dense a survey.

The table a user reads to plan a survey campaign. Every site of a built split (training and test sites alike:
the pool) is held out in turn; the supervised online classifier (``train env``'s default) is fitted on the map
labels of ``n`` other sites' surveys (1, 2, 4, 8) and scored on the held-out site's cells, each cell taking the
class of its windows' combined probabilities (:func:`models.environment.combine_windows`). The held-out site is
always scored on its full survey; the training surveys are thinned to the survey density under study:

- ``cell size``: the split's grid (10 m on ``standard``) thinned to every 2nd / 3rd cell in east and north
  (20 m / 30 m cells) — the cells a coarser survey would have captured at those points;
- ``capture``: each cell's first windows only (a 4 s capture holds the 2 s windows centred at 1, 2 and 3 s) — the
  windows a shorter capture would have given, as every window is computed from its own 2 s of data.

Seeds: seed ``s`` draws, per held-out site, one order of the other sites (``numpy.random.default_rng([s, i])``)
and takes its first ``n`` — so the 2 sites are among the 4, the 4 among the 8, and a curve is not a new draw
at every point. Scores are pooled over the held-out sites of one seed (a site has 2–12 heavy cells: per-site
recall would be mostly 0, 50 or 100 %), then mean ± SD over seeds. ``far`` = cells at least ``--margin`` of
blocked-sky share from a class boundary (10 % and 40 %); ``all`` = every labelled cell. Beside them (issue 27
item 5, measured only): the residual SD of the classifier's continuous blocked-sky estimate
(:meth:`models.environment.EnvironmentClassifier.occlusion`) on the held-out windows inside the ±``--margin``
band around the class thresholds and outside it, in points of share.

Measured (the standard split's 11 sites as built for the fusion study, 10 m cells / 10 s captures, 723 / 167 / 71
far cells open / light / heavy pooled over the held-out sites; seeds 0-4; 389 s on 2 shared cores, one BLAS
thread); recall on far cells and macro-F1 on all cells, percent, mean ± SD over seeds::

    cells capture sites   open       light      heavy      macro-F1 (all)  occlusion SD in / out of band, points
    10 m  10 s    1       93.4±1.8   68.7±2.6   67.0±7.4   73.2±1.1        9.6 / 7.7
    10 m  10 s    2       92.0±0.9   74.4±5.3   80.0±3.5   77.1±0.7        8.4 / 6.8
    10 m  10 s    4       92.4±1.1   80.7±0.7   84.2±2.9   79.7±1.2        7.2 / 5.8
    10 m  10 s    8       93.6±0.3   86.1±1.0   90.1±1.3   82.8±0.6        6.8 / 5.3
    20 m  10 s    2       93.8±0.6   62.4±0.6   64.8±12.4  71.6±1.9        10.9 / 9.3
    20 m  10 s    8       93.4±0.5   76.6±2.2   80.6±4.5   78.8±1.2        7.6 / 7.3
    10 m   4 s    2       93.0±2.0   72.6±4.4   74.4±6.9   75.7±0.7        8.9 / 7.6
    10 m   4 s    8       94.3±0.6   84.4±2.0   87.6±2.3   82.1±0.5        7.0 / 5.5
    20 m   4 s    2       94.5±1.6   61.4±1.2   55.5±9.7   69.9±2.2        12.9 / 10.5
    20 m   4 s    8       94.7±0.2   75.1±2.7   82.5±4.0   80.3±1.1        8.3 / 8.5

What a campaign planner reads from it: every added site helps light and heavy (+12 and +10 points from two
sites to eight at 10 m), and open stays near 93 % whatever is done; the cell spacing matters far more than the
capture length (20 m cells cost 12-15 points of light and heavy at two sites, 4 s captures 2-6); the issue's
target, 97 % per class on far cells with at most two sites, is not met (92.0 / 74.4 / 80.0 %), nor with eight.
The continuous blocked-sky estimate misses its ≤ 3-point target everywhere (5-14 points), worst in the band
around the class thresholds where it matters. (Those occlusion figures are of the ridge estimate the classifier
had then; its fractional-logit replacement, and why 3 points is out of reach of a 10 s capture — the blocked
share of the satellites actually in view already misses the day-weighted share by 5-6 points in the band — are
in ``bench/env_occlusion.py``.)

Usage: ``python bench/env_learning_curve.py --data /work/studies/standard/data --out /tmp/lc --seeds 0 1 2
--plot /tmp/lc/learning_curve.png`` (``--library`` reuses a library holding every site of the split).
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.env_study import cell_predictions, class_scores, far_from_boundary  # noqa: E402

CELL_ID = re.compile(r"^E(\d+)N(\d+)$")


def thin(ts, base_cell_m: float, cell_m: float, capture_s: float):
    """The windows of ``ts`` a survey of ``cell_m`` cells and ``capture_s`` captures would hold (see the module
    docstring); ``cell_m`` must be a whole multiple of the survey's own ``base_cell_m``."""
    step = cell_m / base_cell_m
    if abs(step - round(step)) > 1e-9 or step < 1:
        raise SystemExit(f"cell size {cell_m:g} m is not a whole multiple of the survey's {base_cell_m:g} m")
    step = int(round(step))
    idx = [CELL_ID.match(c) for c in ts.cell.tolist()]
    if any(m is None for m in idx):
        raise SystemExit("cell ids are not the simulator's grid ids (E000N000): cannot thin the grid")
    e = np.array([int(m.group(1)) for m in idx])
    n = np.array([int(m.group(2)) for m in idx])
    keep = (e % step == 0) & (n % step == 0) & (ts.t_s + ts.window_s / 2.0 <= capture_s + 1e-9)
    return ts.subset(keep)


def evaluate(ts, sites: list[str], seeds, n_sites, densities, base, margin: float):
    """{(density, n, seed): (cell true, cell predicted, far mask, fitted?)} pooled over held-out sites."""
    from models.environment import EnvironmentClassifier

    out = {}
    by_site = {s: ts.subset(ts.site == s) for s in sites}
    for seed in seeds:
        for i, held in enumerate(sites):
            others = [s for s in sites if s != held]
            order = np.random.default_rng([seed, i]).permutation(len(others))
            test = by_site[held]
            for dens in densities:
                thinned = {s: thin(by_site[s], base[0], *dens) for s in others}
                for n in n_sites:
                    chosen = [others[j] for j in order[:n]]
                    X = np.vstack([thinned[s].X for s in chosen])
                    y = np.concatenate([thinned[s].label for s in chosen])
                    share = np.concatenate([thinned[s].share for s in chosen])
                    ok = y >= 0
                    key = (dens, n, seed)
                    try:
                        clf = EnvironmentClassifier().fit(X[ok], y[ok], share=share[ok])
                    except ValueError:              # too few windows or one class: no model from this survey
                        out.setdefault(key, []).append(None)
                        continue
                    p = clf.predict_proba(test.X)
                    cp, ct, cs = cell_predictions(test, p.argmax(1), p)
                    resid = clf.occlusion(test.X) - test.share           # per window, share units
                    out.setdefault(key, []).append((ct, cp, far_from_boundary(cs, margin), resid,
                                                    ~far_from_boundary(test.share, margin)))
    return out


def summarise(out, seeds, n_sites, densities):
    """{(density, n): (mean (10,), sd (10,), failed fits)}: recall open / light / heavy and macro-F1 on far cells,
    then on all cells, then the continuous estimate's residual SD on windows inside and outside the boundary
    band; pooled over held-out sites per seed, mean and SD over seeds."""
    table = {}
    for dens in densities:
        for n in n_sites:
            per_seed, failed = [], 0
            for seed in seeds:
                parts = out[(dens, n, seed)]
                failed += sum(p is None for p in parts)
                parts = [p for p in parts if p is not None]
                if not parts:
                    continue
                ct, cp, far, resid, band = (np.concatenate(c) for c in zip(*parts))
                ok = ct >= 0
                per_seed.append(class_scores(ct[ok & far], cp[ok & far]) + class_scores(ct[ok], cp[ok])
                                + [float(np.nanstd(resid[band])), float(np.nanstd(resid[~band]))])
            v = np.array(per_seed, float)
            table[(dens, n)] = (np.nanmean(v, axis=0), np.nanstd(v, axis=0), failed)
    return table


def plot(path: Path, table, n_sites, densities, target: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5), sharex=True)
    panels = [(0, "far cells: open recall"), (1, "far cells: light recall"), (2, "far cells: heavy recall"),
              (7, "all cells: macro-F1")]
    for ax, (col, title) in zip(axes.ravel(), panels):
        for k, dens in enumerate(densities):
            m = np.array([table[(dens, n)][0][col] for n in n_sites]) * 100
            s = np.array([table[(dens, n)][1][col] for n in n_sites]) * 100
            x = np.array(n_sites) * (1 + 0.03 * (k - (len(densities) - 1) / 2))     # dodge the error bars
            ax.errorbar(x, m, yerr=s, marker="o", capsize=3, label=f"{dens[0]:g} m cells, {dens[1]:g} s capture")
        if col < 3:
            ax.axhline(100 * target, color="grey", ls="--", lw=1, label=f"target {100 * target:.0f} %")
        ax.set_xscale("log", base=2)
        ax.set_xticks(n_sites, [str(n) for n in n_sites])
        ax.set_ylim(30, 101)
        ax.set_title(title)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("surveyed training sites")
    for ax in axes[:, 0]:
        ax.set_ylabel("percent (mean ± SD over seeds)")
    axes[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle("Environment model on a site nobody surveyed for it: recall against survey effort", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    from fingerprints.survey import build_library
    from simulation.split import SPLITS, build_split, split_layout
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a built split (its surveys built there when missing)")
    ap.add_argument("--split", default="standard", choices=sorted(SPLITS))
    ap.add_argument("--library", type=Path, default=None, help="a library of every site of the split")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--n-sites", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--densities", nargs="+", default=["10:10", "20:10", "10:4", "20:4"],
                    help="training survey densities as CELL_M:CAPTURE_S (multiples of the split's cell size)")
    ap.add_argument("--margin", type=float, default=0.03)
    ap.add_argument("--target", type=float, default=0.97, help="recall target drawn on the plot")
    ap.add_argument("--plot", type=Path, default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    layout = (split_layout(args.data) if (args.data / "split.toml").is_file()
              else build_split(args.split, args.data, walks=False, workers=2))
    sp = layout.split
    lib = args.library
    if lib is None:
        lib = args.out / "fingerprints_all_sites.sqlite"
        for s in sp.train_sites + sp.test_sites:
            build_library(layout.survey_dir(s), lib, progress=False)
    ts = training_set(lib)
    sites = sorted(set(ts.site.tolist()))
    if max(args.n_sites) > len(sites) - 1:
        raise SystemExit(f"{len(sites)} sites in the library: at most {len(sites) - 1} can train for a held-out one")
    densities = [tuple(float(v) for v in d.split(":")) for d in args.densities]
    base = (sp.cell_size_m, sp.capture_s)
    t_fit = time.perf_counter()
    # one BLAS thread: the Newton solver's X'WX products on 2 cores shared with other jobs ran 8x slower
    # threaded (20 s against 2.6 s for one eight-site fit, measured while the machine's load was 8)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        out = evaluate(ts, sites, args.seeds, args.n_sites, densities, base, args.margin)
    table = summarise(out, args.seeds, args.n_sites, densities)
    print(f"{len(sites)} sites, each held out in turn; training surveys thinned from {base[0]:g} m / {base[1]:g} s; "
          f"{len(args.seeds)} seeds; cells pooled over held-out sites per seed, mean ± SD over seeds (percent)")
    n_far = {c: int(sum(np.sum((p[0] == c) & p[2]) for p in out[(densities[0], args.n_sites[0], args.seeds[0])]
                        if p is not None)) for c in range(3)}
    print(f"held-out far cells open / light / heavy: {n_far[0]} / {n_far[1]} / {n_far[2]} (margin "
          f"{100 * args.margin:.0f} points)")
    hdr = " ".join(f"{h:>11s}" for h in ("open", "light", "heavy", "macro-F1"))
    print(f"{'cells':>6s} {'capture':>7s} {'sites':>5s}   far: {hdr}   all: {hdr}  occlusion SD band / out, "
          "points  failed")
    for dens in densities:
        for n in args.n_sites:
            m, s, failed = table[(dens, n)]
            cells = " ".join(f"{100 * a:5.1f}±{100 * b:4.1f}" for a, b in zip(m[:4], s[:4]))
            alls = " ".join(f"{100 * a:5.1f}±{100 * b:4.1f}" for a, b in zip(m[4:8], s[4:8]))
            occ = " / ".join(f"{100 * a:4.1f}±{100 * b:3.1f}" for a, b in zip(m[8:], s[8:]))
            print(f"{dens[0]:5g}m {dens[1]:6g}s {n:5d}   far: {cells}   all: {alls}  {occ}  {failed}")
    full = densities[0]
    best = max((n for n in args.n_sites if n <= 2), default=None)
    if best is not None:
        m = table[(full, best)][0]
        print(f"target >= {100 * args.target:.0f} % per class on far cells with at most two surveyed sites: "
              f"{'met' if np.all(m[:3] >= args.target) else 'not met'} ({best} sites, {full[0]:g} m / {full[1]:g} s: "
              + " / ".join(f"{100 * v:.1f}" for v in m[:3]) + " %)")
    if args.plot is not None:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(args.plot, table, args.n_sites, densities, args.target)
    print(f"run time {time.perf_counter() - t0:.0f} s (fits and scoring {time.perf_counter() - t_fit:.0f} s)")


if __name__ == "__main__":
    main()
