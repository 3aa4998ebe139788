"""Per-epoch pseudorange solver on the shared smartLoc drive: accuracy by weighting and RAIM, and speed.

Data: ../shared/data/gnss_urban_smartloc (the first 170 s of smartLoc's Berlin Potsdamer Platz drive,
TU Chemnitz, CC BY-SA 4.0; ``ENVFUSE_SHARED_DATA`` overrides the folder).

Prints, horizontal error against the NovAtel reference at the same epochs:

* median / p95 / mean / max for unweighted (σ = 4 m), C/N0-weighted (SIGMA-ε, 10^(C/N0/10)), the file's
  own variance and the RTKLIB elevation + C/N0 model (the default), each without and with RAIM FDE
  (χ² test, P_fa 1e-3, exclusion of the largest normalised residual while the test fails), with the
  mean number excluded, the share of fixes left in RAIM alarm, and the consistency of the reported
  covariance (NEES of the horizontal error: 2 on average for a consistent 2-D covariance);
* RAIM capped at 1 and 2 exclusions (single-fault FDE) for the default model;
* the odometry track aligned to the fixes (initial heading error, median error over the drive);
* time per epoch of the solver (batched over all epochs; with and without RAIM) beside two
  yardsticks timed in the same run: ``numpy.linalg.lstsq`` on the same final weighted design
  matrices, one call per epoch (one Gauss–Newton step of a per-epoch loop), and
  ``scipy.signal.oaconvolve`` of 48,000 samples with a 480-tap kernel (the other benches' gauge);
  best of ``--repeat``, CPU time, one thread;
* time per drive of the whole path, stage by stage: ``convert smartloc`` (read the text, solve for the
  site origin, write the walk folder), ``read_walk`` (read the CSVs, solve every epoch with RAIM, the five
  features, integrate and align the odometry), ``walk_inputs`` (events, the classifier on every window),
  every registered method with its RTS and fixed-lag tracks (``fuse_walk``), and the scores — with the
  demo split's fusion model (``--model``, default ``demo_out/fusion_model``; without it one is fitted on
  the drive with no tuning and no BP, for timing only), against the same oaconvolve yardstick.

Run: ``.venv/bin/python bench/bench_smartloc.py`` (no assertions; the figures are pinned in tests).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import pymap3d  # noqa: E402
import scipy.signal  # noqa: E402

from features.gnss.pseudorange import read_smartloc  # noqa: E402
from features.gnss.sat_features import pseudorange_features  # noqa: E402
from features.gnss.weights import Cn0Variance, EqualVariance, RtklibVariance, StatedVariance  # noqa: E402
from features.gnss.wls import WlsConfig, enu_rotation, solve_epochs, wls_positions  # noqa: E402
from features.vehicle.odometry import odometry_dead_reckoning  # noqa: E402


def _folder() -> Path:
    env = os.environ.get("ENVFUSE_SHARED_DATA")
    # ../shared/data beside the clone, or beside a worktree two or three levels down (however shallow the path)
    candidates = ([Path(env)] if env else []) + [p / "shared" / "data" for p in list(ROOT.parents)[:3]]
    for c in candidates:
        if (c / "gnss_urban_smartloc").is_dir():
            return c / "gnss_urban_smartloc"
    sys.exit("bench_smartloc: ../shared/data/gnss_urban_smartloc not found (set ENVFUSE_SHARED_DATA)")


def _errors(sol, ref):
    lat, lon, h = pymap3d.ecef2geodetic(*ref.ecef_m.T)
    e, n, _ = pymap3d.ecef2enu(*sol.ecef_m.T, lat, lon, h)
    r = enu_rotation(lat, lon)
    cov = (r @ sol.cov_ecef_m2 @ r.transpose(0, 2, 1))[:, :2, :2]
    v = np.stack([e, n], axis=1)
    nees = np.einsum("ni,nij,nj->n", v, np.linalg.inv(cov), v)
    return np.hypot(e, n), nees


def _accuracy(table, ref):
    print("horizontal error against the reference, 823 epochs (m); NEES of the reported covariance (2 = consistent)")
    print(f"{'weights':28s} {'RAIM':9s} {'median':>7s} {'p95':>6s} {'mean':>6s} {'max':>6s} {'excl':>5s} "
          f"{'alarm':>6s} {'NEES mean':>9s} {'median':>7s}")
    models = (("unweighted (sigma 4 m)", EqualVariance()), ("C/N0 (SIGMA-eps)", Cn0Variance()),
              ("file variance", StatedVariance()), ("RTKLIB el + C/N0 (default)", RtklibVariance()))
    rows = [(name, m, raim, None) for name, m in models for raim in (False, True)]
    rows += [("RTKLIB el + C/N0 (default)", RtklibVariance(), True, cap) for cap in (1, 2)]
    for name, model, raim, cap in rows:
        sol = solve_epochs(table, WlsConfig(weights=model, raim=raim, max_exclusions=cap))
        err, nees = _errors(sol, ref)
        label = ("on" if raim else "off") + (f", <={cap}" if cap else "")
        print(f"{name:28s} {label:9s} {np.median(err):7.2f} {np.percentile(err, 95):6.1f} {err.mean():6.1f} "
              f"{err.max():6.1f} {sol.n_excluded.mean():5.2f} {np.mean(sol.integrity == 1):6.2f} "
              f"{nees.mean():9.1f} {np.median(nees):7.2f}")
    print("README (per-epoch WLS, Sagnac): median 24.4 / 20.1 / 26.0 m, p95 69 / 51 / 65 m "
          "(unweighted / C/N0 / file variance)")


def _odometry(log, table, ref):
    lat, lon, h = pymap3d.ecef2geodetic(*ref.ecef_m[0])
    sol = solve_epochs(table)
    pos = wls_positions(sol, lat, lon, h, table=table)
    dr, align = odometry_dead_reckoning(log.odometry, pos.t_s, pos.east_m, pos.north_m)
    re, rn, _ = pymap3d.ecef2enu(*ref.ecef_m.T, lat, lon, h)
    k = np.searchsorted(np.cumsum(np.r_[0.0, np.hypot(np.diff(re), np.diff(rn))]), 10.0)
    ref_heading = math.degrees(math.atan2(re[k] - re[0], rn[k] - rn[0]))
    e, n = dr.position_at(ref.t_s)
    d = np.hypot(e - re, n - rn)
    print(f"\nodometry: initial heading {math.degrees(align.heading_rad):.1f} +- "
          f"{math.degrees(align.sigma_heading_rad):.1f} deg from {align.n_fixes} fixes over "
          f"{align.span_s[1] - align.span_s[0]:.0f} s (reference {ref_heading:.1f} deg); aligned track "
          f"median {np.median(d):.1f} m, p95 {np.percentile(d, 95):.1f} m, end {d[-1]:.1f} m "
          f"(the fixes: median {np.median(np.hypot(pos.east_m - re, pos.north_m - rn)):.1f} m); "
          f"{len(dr)} events, {dr.distance_m:.1f} m")


def _best(fn, repeat):
    best = math.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def _speed(table, repeat):
    n_ep = len(table.epochs()[0])
    cfg_raim, cfg_plain = WlsConfig(), WlsConfig(raim=False)
    sol = solve_epochs(table, cfg_plain)
    # the same final weighted design matrices, for numpy.linalg.lstsq one epoch at a time
    _, start, stop = table.epochs()
    var = RtklibVariance().variance_m2(table.cn0_dbhz, sol.elevation_deg, table.system, None)
    mats = []
    systems = list(sol.systems)
    for k, (a, b) in enumerate(zip(start, stop)):
        d = table.sat_ecef_m[a:b] - sol.ecef_m[k]
        u = d / np.linalg.norm(d, axis=1)[:, None]
        clk = (np.array([systems.index(s) for s in table.system[a:b]])[:, None] == np.arange(len(systems)))
        w = 1.0 / np.sqrt(var[a:b])
        mats.append((np.column_stack([-u, clk]) * w[:, None], np.nan_to_num(sol.residual_m[a:b]) * w))

    def lstsq_all():
        for h, y in mats:
            np.linalg.lstsq(h, y, rcond=None)

    sig = np.random.default_rng(0).standard_normal(48_000)
    ker = np.random.default_rng(1).standard_normal(480)
    times = {"solver, RAIM on": _best(lambda: solve_epochs(table, cfg_raim), repeat),
             "solver, RAIM off": _best(lambda: solve_epochs(table, cfg_plain), repeat),
             "numpy.linalg.lstsq, same matrices, 1 call/epoch": _best(lstsq_all, repeat),
             "five features (sky + windows)": _best(lambda: pseudorange_features(table, sol), repeat)}
    oa = _best(lambda: scipy.signal.oaconvolve(sig, ker), repeat)
    print(f"\nspeed, {n_ep} epochs (best of {repeat}, CPU time, one thread):")
    ref = times["numpy.linalg.lstsq, same matrices, 1 call/epoch"]
    for name, t in times.items():
        print(f"  {name:48s} {1e6 * t / n_ep:7.1f} us/epoch, {1e3 * t:6.1f} ms/drive "
              f"({t / ref:5.2f} x the lstsq yardstick, {t / oa:5.1f} oaconvolve calls)")
    print(f"  {'yardstick: scipy.signal.oaconvolve 48000 x 480':48s} {1e3 * oa:7.3f} ms per call")


def _whole_path(folder: Path, model_dir: Path, repeat: int) -> None:
    import tempfile

    from models.fusion.model import load_fusion_model
    from walks.convert import convert_smartloc
    from walks.fuse import fuse_walk
    from walks.inputs import walk_inputs
    from walks.methods import run_methods
    from walks.reader import read_walk
    from walks.score import score

    src = (folder / "Berlin_Potsdamer_Platz_Input.txt", folder / "Berlin_Potsdamer_Platz_GT.txt")
    with tempfile.TemporaryDirectory() as tmp:
        walk = Path(tmp) / "drive"
        convert_smartloc(*src, walk)
        data = read_walk(walk)
        if (model_dir / "bundle.json").is_file():
            model, which = load_fusion_model(model_dir), f"{model_dir}"
        else:
            from training.env import fit_env_model, walk_training_set
            from training.filters import train_fusion

            clf, _ = fit_env_model(walk_training_set([walk]), "survey")
            model, which = train_fusion([walk], clf, bp=False, tune=False), "fitted on the drive (no tuning, no BP)"
        inputs = walk_inputs(data, model.classifier)
        fuse_walk(walk, model, None, force=True)          # compile (numba caches) and warm up
        n_ep = len(data.gnss.solution)
        stages = {
            "convert smartloc (read text, origin, write)": lambda: convert_smartloc(*src, walk, overwrite=True),
            "read_walk (CSV, WLS + RAIM, features, odometry)": lambda: read_walk(walk),
            "walk_inputs (events, classifier)": lambda: walk_inputs(data, model.classifier),
            "every method + RTS + fixed-lag (run_methods)": lambda: run_methods(model, inputs),
            "score": None,
        }
        tracks, _ = run_methods(model, inputs)
        stages["score"] = lambda: score(tracks, data, "drive")
        times = {name: _best(fn, repeat) for name, fn in stages.items()}
        times["whole path: fuse_walk of the folder + score"] = _best(
            lambda: score(fuse_walk(walk, model, None, force=True).tracks, data, "drive"), repeat)
    sig = np.random.default_rng(0).standard_normal(48_000)
    ker = np.random.default_rng(1).standard_normal(480)
    oa = _best(lambda: scipy.signal.oaconvolve(sig, ker), repeat)
    print(f"\nwhole path per drive ({n_ep} epochs, {data.walk.duration_s:.0f} s; model: {which}; "
          f"{len(tracks)} tracks; best of {repeat}, CPU time):")
    for name, t in times.items():
        print(f"  {name:52s} {1e3 * t:8.1f} ms/drive {1e6 * t / n_ep:8.1f} us/epoch ({t / oa:6.1f} oaconvolve calls)")
    print(f"  {'yardstick: scipy.signal.oaconvolve 48000 x 480':52s} {1e3 * oa:8.3f} ms per call")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--model", type=Path, default=ROOT / "demo_out" / "fusion_model",
                        help="fusion model for the whole path (default: the demo split's)")
    args = parser.parse_args()
    folder = _folder()
    log = read_smartloc(folder / "Berlin_Potsdamer_Platz_Input.txt")
    ref = read_smartloc(folder / "Berlin_Potsdamer_Platz_GT.txt").reference
    _accuracy(log.pseudoranges, ref)
    _odometry(log, log.pseudoranges, ref)
    _speed(log.pseudoranges, args.repeat)
    _whole_path(folder, args.model, max(1, min(args.repeat, 3)))


if __name__ == "__main__":
    main()
