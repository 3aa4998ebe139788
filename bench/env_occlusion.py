"""Continuous occlusion estimate on sites nobody tuned on (issue 27 item 5): residual SD in and out of the band.

The environment classifier's blocked-sky share estimate (:meth:`models.environment.EnvironmentClassifier.occlusion`)
is fitted on the map shares of ``n`` of a built split's *training* sites' surveys (the seed draws which:
``numpy.random.default_rng(seed).permutation``) and scored on every window of the split's *test* sites' surveys —
sites no choice of this study looked at (the estimator's form and its penalty were chosen by leave-one-site-out
over the training sites alone). Residual = estimate − the cell's map share (the satellite-weighted blocked-sky share
at the capture point, :func:`simulation.site.environment.blocked_share`), in points of share; ``band`` = windows whose
true share lies within ±``--margin`` of a class threshold (10 % and 40 %), ``out`` = the rest. Per window, and per
cell (the mean of its capture's window estimates). Pooled over the test sites per seed; mean ± SD over seeds, and a
90 % bootstrap interval over the test sites (seeds pooled; 2,000 resamples of the five sites).

Estimators:

- ``ridge`` — what shipped before: ridge (α = 1) on the standardised features and their pairwise products, clipped
  to [0, 1] (recomputed here from the fitted sub-model's own standardisation);
- ``new`` — :class:`models.occlusion.OcclusionRegressor` as the classifier fits it: fractional logit through one
  tanh layer, averaged over initialisations.

Bounds (what the features can hold, not estimators a user could run):

- ``ceiling`` — gradient boosting fitted on the test sites themselves, 5-fold cross-validation grouped by cell:
  no site shift, a flexible model, every test site seen — an optimistic ceiling of the 14 features;
- ``ceiling+`` — the same fitted on every site of the split (training and test sites, 5 folds grouped by cell),
  scored on the test sites' windows: more data, still no site shift;
- ``sky floor`` — the share of the satellites actually in view during the capture (from the cell's NMEA sky,
  elevation ≥ the mask) that the site's solid structures hide (the site's skyline from
  :func:`simulation.site.geometry.horizon_elevation`), mapped to the share by isotonic regression, cell-grouped
  5-fold: what a receiver that knew exactly which of its ~21 satellites are blocked could say. The label weighs the
  whole day's satellite passes; a 10 s capture sees one instant of them, so this gap no feature of the capture
  can close.

Measured (the standard split as built for the fusion study: training sites 101-106, test sites 201-205, 10 m
cells / 10 s captures, 4,536 test windows in 504 cells, 684 windows in the band; seeds 0-4; 97 s of CPU, one
BLAS thread); residual SD, points of share, mean ± SD over seeds [90 % bootstrap interval over test sites]::

    estimator  sites  window band         window out          cell band           cell out
    ridge      2      7.5±0.4 [6.1, 8.7]  6.2±0.3 [5.7, 6.7]  7.0±0.5 [5.5, 8.2]  5.7±0.3 [5.2, 6.2]
    new        2      7.5±0.9 [5.9, 8.7]  5.3±0.3 [4.8, 6.0]  7.1±0.8 [5.5, 8.4]  5.0±0.2 [4.5, 5.8]
    ridge      6      7.4     [5.1, 8.8]  5.5     [4.8, 6.0]  6.9     [4.6, 8.3]  5.1     [4.4, 5.6]
    new        6      7.5     [5.3, 8.9]  4.8     [4.2, 5.7]  7.1     [4.8, 8.4]  4.6     [3.8, 5.5]
    ceiling    -      7.0     [6.2, 7.9]  5.1     [4.7, 5.5]  6.6     [5.6, 7.5]  4.8     [4.3, 5.3]
    ceiling+   -      6.7     [5.7, 7.5]  4.7     [4.4, 5.1]  6.3     [5.2, 7.0]  4.4     [3.9, 4.9]
    sky floor  -      5.6     [4.6, 6.5]  4.3     [3.7, 4.9]  5.6     [4.6, 6.5]  4.3     [3.7, 4.9]

    test walks (``--walks``; moving, truth share at the window centre; 4,485 windows with both modalities,
    710 in the band), per window, band / out:  2 sites ridge 11.9±1.1 / 9.2±0.4, new 10.9±0.8 / 8.6±0.7;
                                               6 sites ridge 10.8 / 8.2, new 10.8 / 7.6
    later_days split (the five walked sites' own surveys 28 days earlier train the model; walks only):
                                               ridge 8.4 / 10.3, new 6.9 / 9.9

Reading. The ≤ 3-point target is out of reach, and not for want of a model: even a receiver that knew exactly
which of its satellites the structures hide (``sky floor``) misses the label by 5.6 points in the band and 4.3
out of it, because the label weighs a whole day of satellite passes and a capture sees ~21 satellites at one
instant. The 14 features see less than that (flexible boosting on the test sites' own cells, ``ceiling``, 7.0 /
5.1; with every site's cells, ``ceiling+``, 6.7 / 4.7), and the estimate on sites nobody tuned on comes within
0.5-0.8 points of it in the band and reaches it out of the band. Averaging a cell's windows gains only 0.2-0.4:
the error is the cell's, not the window's (leave-one-site-out on the training sites: 2.0 points between the
windows of one capture, 5.3 between cells of a site, 3.4 between sites in the band). The fractional-logit net
replaced the ridge for what it gains out of the band (0.7-0.9 points on surveys, 0.6 along walks) and for an
estimate that stays in (0, 1) unclipped; in the band it is level with the ridge within the seeds' spread on
surveys, and level or a point better along walks.
A target a capture can meet would be the blocked share of the satellites in view (the sky floor's own
quantity), not the day-weighted one.

Usage: ``python bench/env_occlusion.py --data /work/studies/standard/data --library LIB --out /tmp/occ
--seeds 0 1 2 3 4 --walks --plot /tmp/occ/occlusion.png`` (``--library``: a library of the split's sites, built
into ``--out`` when not given); a later-days split (its test sites are its training sites): ``--data
/work/studies/later_days/data --n-sites 5 --seeds 0 --walks``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BOUNDS = (0.10, 0.40)


def in_band(share: np.ndarray, margin: float) -> np.ndarray:
    """True where the share lies within ``margin`` of a class threshold."""
    return np.min(np.abs(np.asarray(share)[:, None] - np.array(BOUNDS)[None, :]), axis=1) < margin


def cell_means(keys: np.ndarray, *values: np.ndarray):
    """Per distinct key: the mean of each of ``values``."""
    _, inv = np.unique(keys, return_inverse=True)
    n = np.bincount(inv)
    return [np.bincount(inv, v) / n for v in values]


def ridge_old(clf, ts_train, ts_test) -> np.ndarray:
    """The estimate bundles held before: Ridge(α = 1) on the 'both' sub-model's expanded standardised inputs."""
    from sklearn.linear_model import Ridge

    from models.environment import _expand

    m = clf.submodels_["both"]
    z_tr = (ts_train.X - m["mean"]) / m["scale"]
    z_te = (ts_test.X - m["mean"]) / m["scale"]
    r = Ridge(alpha=1.0).fit(_expand(z_tr, clf.degree), ts_train.share)
    return np.clip(r.predict(_expand(z_te, clf.degree)), 0.0, 1.0)


def sky_share(survey_dir: Path) -> dict:
    """{cell id: share of the in-view satellites (over the capture's epochs) below the site's solid skyline}."""
    from features.constants import ELEVATION_MASK_DEG
    from features.gnss.nmea import read_nmea
    from features.site import load_site
    from simulation.site.environment import solid_boxes
    from simulation.site.geometry import horizon_elevation

    site = load_site(survey_dir / "site.toml")
    boxes = solid_boxes(site)
    out = {}
    for cdir in sorted((survey_dir / "cells").iterdir()):
        cell = tomllib.loads((cdir / "cell.toml").read_text())
        epochs, _ = read_nmea(cdir / cell["gnss"]["file"])
        az_el = np.array([(s.az_deg, s.el_deg) for ep in epochs for s in ep.primary_satellites
                          if s.el_deg is not None and s.az_deg is not None and s.el_deg >= ELEVATION_MASK_DEG])
        if len(az_el) == 0:
            out[cell["id"]] = np.nan
            continue
        hor = horizon_elevation(np.array([[cell["east_m"], cell["north_m"]]]), np.radians(az_el[None, :, 0]), boxes,
                                site.device_height_m)[0]
        out[cell["id"]] = float(np.mean(np.radians(az_el[:, 1]) < hor))
    return out


def grouped_cv(X: np.ndarray, y: np.ndarray, groups: np.ndarray, make) -> np.ndarray:
    """Out-of-fold predictions of ``make()`` models, 5 folds grouped by ``groups``."""
    from sklearn.model_selection import GroupKFold

    out = np.empty(len(y))
    for tr, te in GroupKFold(5).split(X, y, groups):
        out[te] = make().fit(X[tr], y[tr]).predict(X[te])
    return out


def scores(resid: np.ndarray, share: np.ndarray, keys: np.ndarray, margin: float) -> list[float]:
    """[window band SD, window out SD, cell band SD, cell out SD], share units."""
    b = in_band(share, margin)
    cr, cs = cell_means(keys, resid, share)
    cb = in_band(cs, margin)
    return [float(np.std(resid[b])), float(np.std(resid[~b])), float(np.std(cr[cb])), float(np.std(cr[~cb]))]


def bootstrap(parts: list, n_sites: int, margin: float, n_boot: int = 2000, seed: int = 0) -> np.ndarray:
    """90 % interval (4, 2) of :func:`scores` over resamples of the test sites.

    ``parts``: [(resid, share, cell keys)] seed-major, ``n_sites`` entries a seed; a resampled site brings its
    windows of every seed (seeds are not independent sites)."""
    per_site = []
    for j in range(n_sites):
        mine = parts[j::n_sites]
        per_site.append(tuple(np.concatenate(c) for c in zip(*[
            (r, s, np.char.add(f"{i}/", k)) for i, (r, s, k) in enumerate(mine)])))
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(n_boot):
        pick = rng.integers(0, n_sites, n_sites)
        r, s, k = (np.concatenate([per_site[i][j] for i in pick]) for j in range(3))
        draw = np.repeat(np.arange(len(pick)).astype(str), [len(per_site[i][0]) for i in pick])
        k = np.char.add(np.char.add(draw, "/"), k)              # a site drawn twice keeps two sets of cells
        draws.append(scores(r, s, k, margin))
    return np.quantile(np.array(draws), [0.05, 0.95], axis=0).T


def plot(path: Path, panels: list, margin: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(5.0 * len(panels), 5.0), sharey=True)
    for ax, (title, share, est, stats) in zip(np.atleast_1d(axes), panels):
        for b in BOUNDS:
            ax.axvspan(100 * (b - margin), 100 * (b + margin), color="orange", alpha=0.15, lw=0)
            ax.axvline(100 * b, color="orange", lw=1)
            ax.axhline(100 * b, color="orange", lw=1, ls=":")
        ax.plot([0, 100], [0, 100], color="grey", lw=1)
        ax.text(98, 2, "each cell's windows share one true share: vertical stripes", fontsize=7, ha="right",
                color="grey")
        band = in_band(share, margin)
        ax.scatter(100 * share[~band], 100 * est[~band], s=4, alpha=0.25, color="tab:blue", label="out of band")
        ax.scatter(100 * share[band], 100 * est[band], s=5, alpha=0.5, color="tab:red", label="in ±3-point band")
        ax.set_xlim(-2, 100)
        ax.set_ylim(-2, 100)
        ax.set_title(f"{title}\nresidual SD in / out of band: {stats[0]:.1f} / {stats[1]:.1f} points", fontsize=10)
        ax.set_xlabel("true blocked-sky share, % (cell's map share)")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("estimate, %")
    np.atleast_1d(axes)[0].legend(fontsize=8, loc="upper left")
    fig.suptitle("Blocked-sky share on held-out sites (class thresholds 10 % and 40 %, band shaded)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    from fingerprints.survey import build_library
    from simulation.split import split_layout
    from training.env import training_set

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a built split (its surveys)")
    ap.add_argument("--library", type=Path, default=None, help="a library holding the split's sites")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--n-sites", type=int, nargs="+", default=[2, 6])
    ap.add_argument("--margin", type=float, default=0.03)
    ap.add_argument("--plot", type=Path, default=None)
    ap.add_argument("--walks", action="store_true",
                    help="also score the test sites' walks' windows that have both modalities (moving, share varies)")
    args = ap.parse_args()
    if not (args.data / "split.toml").is_file():
        raise SystemExit(f"{args.data}: not a built split (no split.toml)")
    t0 = time.process_time()
    layout = split_layout(args.data)
    sp = layout.split
    if max(args.n_sites) > len(sp.train_sites):
        raise SystemExit(f"the split has {len(sp.train_sites)} training sites, --n-sites asks for {max(args.n_sites)}")
    args.out.mkdir(parents=True, exist_ok=True)
    lib = args.library
    if lib is None:
        lib = args.out / "fingerprints.sqlite"
        for s in sp.train_sites + sp.test_sites:
            build_library(layout.survey_dir(s), lib, progress=False)
    ts = training_set(lib)
    name_of = {}
    for s in sp.train_sites + sp.test_sites:
        name_of[s] = tomllib.loads((layout.survey_dir(s) / "site.toml").read_text())["name"]
    test = ts.subset(np.isin(ts.site, [name_of[s] for s in sp.test_sites]))
    held_out = not set(sp.train_sites) & set(sp.test_sites)
    if not held_out and not args.walks:
        raise SystemExit(f"split {sp.name}: its test sites were surveyed for training (a later-days split); "
                         "only its test walks are held out: pass --walks")
    keys = np.char.add(np.char.add(test.site.astype(str), "/"), test.cell.astype(str))
    from threadpoolctl import threadpool_limits

    from models.environment import EnvironmentClassifier

    res, parts, scatter, walk_res = {}, {}, {}, {}
    walks = None
    if args.walks:
        from training.env import walk_training_set

        walks = walk_training_set(layout.walks(sp.test_sites, test=True))
        walks = walks.subset(np.isfinite(walks.share) & np.all(np.isfinite(walks.X), axis=1))
        if len(walks) == 0:
            raise SystemExit("the test walks hold no window with both modalities and a true share")
    with threadpool_limits(1):
        for n in args.n_sites:
            # every seed draws the same sites when all train, and the fit is deterministic: one fit
            for seed in (args.seeds if n < len(sp.train_sites) else args.seeds[:1]):
                order = np.random.default_rng(seed).permutation(len(sp.train_sites))
                chosen = [name_of[sp.train_sites[j]] for j in order[:n]]
                tr = ts.subset(np.isin(ts.site, chosen) & (ts.label >= 0))
                clf = EnvironmentClassifier().fit(tr.X, tr.label, share=tr.share)
                est = {"ridge": ridge_old(clf, tr, test), "new": clf.occlusion(test.X)} if held_out else {}
                for name, e in est.items():
                    r = e - test.share
                    res.setdefault((n, name), []).append(scores(r, test.share, keys, args.margin))
                    parts.setdefault((n, name), []).extend(
                        [(r[test.site == s], test.share[test.site == s], keys[test.site == s])
                         for s in sorted(set(test.site.tolist()))])
                    if seed == args.seeds[0]:
                        scatter[(n, name)] = e
                if walks is not None:
                    for name, e in (("ridge", ridge_old(clf, tr, walks)), ("new", clf.occlusion(walks.X))):
                        wb = in_band(walks.share, args.margin)
                        r = e - walks.share
                        walk_res.setdefault((n, name), []).append([float(np.std(r[wb])), float(np.std(r[~wb]))])
    if held_out:
        table = surveys_table(args, sp, layout, name_of, ts, test, keys, res, parts, scatter)
    else:
        table = {}
        print(f"split {sp.name}: the test sites' surveys trained the model; only the test walks are held out")
    if walk_res:
        print(f"test walks, per window ({len(walks)} windows with both modalities; "
              f"{int(in_band(walks.share, args.margin).sum())} in the band): residual SD band / out, points")
        for (n, name), v in sorted(walk_res.items(), key=lambda kv: (kv[0][0], kv[0][1] != "ridge")):
            v = 100 * np.array(v)
            table[f"walks/{name}/{n}"] = {"mean": v.mean(0).tolist(), "sd": v.std(0).tolist()}
            print(f"{name:>12s} {n:>5}  " + "  ".join(f"{a:4.1f}±{b:3.1f}" for a, b in zip(v.mean(0), v.std(0))))
    tmp = args.out / ".occlusion_table.json.partial"
    tmp.write_text(json.dumps(table, indent=1))
    tmp.replace(args.out / "occlusion_table.json")
    print(f"cpu time {time.process_time() - t0:.0f} s")


def surveys_table(args, sp, layout, name_of, ts, test, keys, res, parts, scatter) -> dict:
    """Add the bounds to ``res``/``parts``, print the held-out survey table, draw the plot; the table as a dict."""
    from sklearn.ensemble import HistGradientBoostingRegressor
    from sklearn.isotonic import IsotonicRegression
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        def boost():
            return HistGradientBoostingRegressor(max_iter=300, learning_rate=0.05, random_state=0)

        ceil = np.clip(grouped_cv(test.X, test.share, keys, boost), 0, 1)
        # the same over every site of the split (training sites too), cell-grouped; its test-site windows kept
        all_keys = np.char.add(np.char.add(ts.site.astype(str), "/"), ts.cell.astype(str))
        pooled = np.clip(grouped_cv(ts.X, ts.share, all_keys, boost), 0, 1)
        ceil_all = pooled[np.isin(ts.site, [name_of[s] for s in sp.test_sites])]    # test's rows, in its order
        sky = {}
        for s in sp.test_sites:
            sky.update({f"{name_of[s]}/{c}": v for c, v in sky_share(layout.survey_dir(s)).items()})
        inst = np.array([sky[k] for k in keys])
        ok = np.isfinite(inst)
        floor = np.full(len(inst), np.nan)
        floor[ok] = grouped_cv(inst[ok, None], test.share[ok], keys[ok],
                               lambda: _Iso(IsotonicRegression(out_of_bounds="clip")))
    bounds = {"ceiling": ceil, "ceiling+": ceil_all, "sky floor": floor}
    for name, e in bounds.items():
        ok = np.isfinite(e)
        r = e[ok] - test.share[ok]
        res[(0, name)] = [scores(r, test.share[ok], keys[ok], args.margin)]
        parts[(0, name)] = [(r[test.site[ok] == s], test.share[ok][test.site[ok] == s], keys[ok][test.site[ok] == s])
                            for s in sorted(set(test.site.tolist()))]
    nb = in_band(test.share, args.margin)
    print(f"split {sp.name}: trained on n of {len(sp.train_sites)} training sites (seeds {args.seeds} draw which), "
          f"scored on the {len(sp.test_sites)} test sites' {len(test)} windows / {len(set(keys.tolist()))} cells "
          f"({int(nb.sum())} windows in the ±{100 * args.margin:.0f}-point band)")
    print("residual SD, points of share: mean ± SD over seeds [90 % bootstrap interval over test sites]; "
          f"with all {len(sp.train_sites)} training sites one fit (the same sites whatever the seed; a seeded fit)")
    print(f"{'estimator':>12s} {'sites':>5s}  {'window band':>22s} {'window out':>22s} {'cell band':>22s} "
          f"{'cell out':>22s}")
    table = {}
    for key in sorted(res, key=lambda k: (k[0] == 0, k[0], k[1] != "ridge")):
        n, name = key
        v = 100 * np.array(res[key])
        ci = 100 * bootstrap(parts[key], len(sp.test_sites), args.margin)
        table[f"{name}/{n}"] = {"mean": v.mean(0).tolist(), "sd": v.std(0).tolist(), "ci90": ci.tolist()}
        cols = " ".join(f"{m:4.1f}±{s:3.1f} [{lo:4.1f},{hi:4.1f}]" for m, s, (lo, hi) in zip(v.mean(0), v.std(0), ci))
        print(f"{name:>12s} {n if n else '-':>5}  {cols}")
    if args.plot is not None:
        n = max(args.n_sites)
        panels = []
        for name, title in (("ridge", f"ridge (before), {n} training sites"),
                            ("new", f"fractional-logit net, {n} sites")):
            panels.append((title, test.share, scatter[(n, name)], 100 * np.array(res[(n, name)][0])))
        fok = np.isfinite(floor)
        panels.append(("sky floor: blocked share of the satellites in view", test.share[fok], floor[fok],
                       100 * np.array(res[(0, "sky floor")][0])))
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        plot(args.plot, panels, args.margin)
    return table


class _Iso:
    """IsotonicRegression with the (n, 1) input of the other estimators."""

    def __init__(self, iso):
        self.iso = iso

    def fit(self, X, y):
        self.iso.fit(X[:, 0], y)
        return self

    def predict(self, X):
        return self.iso.predict(X[:, 0])


if __name__ == "__main__":
    main()
