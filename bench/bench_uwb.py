"""UWB: the simulator's range errors by line of sight beside measured UWB data, PDoA errors, and the methods.

Section ``nlos`` (default). Measured: ../shared/data/cir_uwb (Kolakowski & Modelski, MIKON 2018; DecaWave
EVK1000 / DW1000, channel 2, in a furnished apartment): 22 logs, each one static anchor–tag pair labelled
LOS / NLOS (direct path attenuated) / NDP NLOS (no direct path), true distances from ``anchors.csv`` /
``tags.csv`` (the README's "true distances are given"); range error = DecaRanging's ``Dist`` − true
distance, and its first-path/received level ``FSL − RSL`` (what ``uwb.csv`` calls ``quality``).
Simulated: :func:`simulation.uwb.stream.simulate_uwb` on ``--walks`` walks of ``--walk-s`` seconds over
generated sites (seeds ``--site-seeds``), each row's error against the distance to the anchor's true
position, grouped by the first path the receiver took (clear direct = LOS; through walls = NLOS; bent round
or off a structure = no direct path), and the PDoA angle error (tags in front of the array).

Section ``methods`` (``--methods``): ``pdr``, ``uwb``, ``uwb_aoa_pdr`` on simulated walks with GNSS, IMU and
UWB (no audio: the acoustic receiver dominates the cost and ``uwb_aoa_pdr`` does not use it), error per
true environment class, and the time of ``uwb_aoa_pdr`` (UWB solve + filter, best of 3) scaled to a
10-minute walk, beside ``scipy.signal.oaconvolve`` (480,000 × 480 taps, float32) timed in the same run.

Section ``study`` (``--study /work/studies/standard``): a benchmark study's walks (both splits are studies:
``standard``, ``later``) with ``uwb.csv`` added — UWB anchors placed on the study sites' beacon poles, each
walk's trajectory rebuilt from its seed and checked against its ``truth.csv`` — then ``uwb``,
``uwb_aoa_pdr``, ``uwb_aoa_pdr_env`` and ``uwb_aoa_pdr_blind`` (the NLOS prior fitted on the study's
training walks, classes from the study's seed-0 classifier) on its held-out walks, per true class with a
95 % bootstrap interval over walks, beside the study's own rows for ``kf_quality`` and Fusion II.

Run: ``.venv/bin/python bench/bench_uwb.py`` (``--methods`` / ``--study DIR`` for the others; prints tables).

Measured (this machine, 2026-12-02; defaults: 3 walks of 300 s on sites 3, 7, 11)::

    Range error, m            n   median     mean      sd  p95|e|   FP-RX dB (median)
    measured LOS            858   +0.226   +0.261   0.102   0.476     -3.2  (6 logs, medians +0.18..+0.47)
    measured NLOS          1096   +0.295   +0.325   0.135   0.539     -5.8  (7 logs, +0.13..+0.53)
    measured NDP NLOS      1392   +0.910   +1.133   0.738   3.121    -11.2  (9 logs, +0.61..+3.10)
      NLOS − LOS offset    1096   +0.069   +0.099   0.135   0.313
      NDP NLOS − LOS       1392   +0.684   +0.907   0.738   2.896
    simulated LOS (clear) 31741   -0.005   -0.005   0.097   0.191     -3.4  (95.5 % of rows)
    simulated no direct    1495   +1.069   +8.116  10.742  31.902     -3.1  (4.5 %; none through walls:
                                                                            the yard's concrete is too thick)
    PDoA error, deg (front): simulated LOS median -0.3, sd 5.7, p95|e| 11.3; NLOS median -4.7, sd 32.5
    FP−RX < −6 dB flags 0.28 of simulated NLOS rows (0.11 of LOS) against 0.74 of measured NLOS packets (0.00)

The simulated no-direct-path median (+1.07 m) is of the measured one's order (+0.68 m over LOS), its tail
much longer: in a steel yard the first path the receiver finds is often a strong specular reflection off
a tank metres away, which also reads as line of sight to the chip's FP/RX indicator — unlike the
apartment's furniture and walls. ``--methods`` (3 walks of 300 s, GNSS + IMU + UWB; median / p95 m)::

    method        open          light          heavy
    pdr           1.87  7.61    6.25 11.26     8.29 13.51
    uwb           0.09  0.38    0.30 10.66     0.24  7.25
    uwb_aoa_pdr   0.05  0.19    0.10  9.65     0.07  0.70
    uwb_aoa_pdr per 10-minute walk 4.8 s (399x the oaconvolve yardstick; 0.13-0.23 s since the round
    solver is compiled, the --study runs below)

``--study /work/studies/standard`` (15 held-out walks of 300 s on sites 201-205; median [95 % CI over
walks] / p95, m; the study's kf_quality and adaptive rows pooled over its 3 seeds)::

                        open                         light                        heavy
    uwb                 0.106 [0.099, 0.115]  4.05   0.212 [0.154, 0.470] 10.99   0.301 [0.226, 0.420]  4.86
    uwb_aoa_pdr         0.131 [0.107, 0.186]  1.47   0.106 [0.070, 0.185]  2.32   0.114 [0.061, 0.190]  1.67
    uwb_aoa_pdr_env     0.642 [0.514, 0.815]  3.98   0.634 [0.377, 0.975]  4.20   0.730 [0.585, 1.081] 14.02
    uwb_aoa_pdr_blind   0.854 [0.728, 1.026]  3.99   0.739 [0.440, 1.067]  4.26   0.565 [0.431, 1.048] 11.87
    kf_quality          0.017                 0.30   0.051                 1.36   0.481                 2.39
    adaptive            0.016                 0.51   0.045                 1.08   0.492                 1.77
    pdr                10.071                15.42   9.876                15.52  13.273                14.29

``--study /work/studies/later_days`` (the same 5 sites 28 days later: 15 held-out ``later<k>`` walks, the
prior fitted on the 15 first-day walks)::

    uwb                 0.118 [0.108, 0.131]  5.29   0.141 [0.118, 0.182]  6.62   0.850 [0.247, 2.025]  7.68
    uwb_aoa_pdr         0.129 [0.108, 0.188]  2.06   0.078 [0.049, 0.125]  1.63   0.189 [0.096, 0.877]  7.36
    uwb_aoa_pdr_env     0.701 [0.547, 0.919]  4.96   0.406 [0.204, 0.854]  5.19   0.992 [0.417, 2.229]  4.91
    uwb_aoa_pdr_blind   0.821 [0.641, 1.122]  5.54   0.344 [0.192, 0.752]  5.62   0.904 [0.376, 1.636]  4.63
    kf_quality          0.015                 0.19   0.025                 1.13   0.428                 1.49
    adaptive            0.014                 0.59   0.038                 1.27   0.420                 1.61

The NLOS prior (mean estimator) fitted 38.8 / 79.3 / 184.3 (blind 94.7): the class does carry UWB's tail,
but scaling every fix's R by it makes the filter lean on a drifting PDR — worse than no prior, with or
without the class. With ``--prior-estimator median`` every class's scale is 1 (floored: the solver's
covariance already covers the core), so both methods equal ``uwb_aoa_pdr``. An honest negative result.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import csv
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

CIR_UWB = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cir_uwb"
if not CIR_UWB.is_dir():  # a git worktree (wt/<name>): the shared folder beside the main checkout
    CIR_UWB = Path("/work/shared/data/cir_uwb")


def measured_rows(root: Path = CIR_UWB) -> list[tuple]:
    """(file id, label, true distance m, range errors (n,), FSL − RSL (m,)) per log of the real data."""
    from features.uwb.decaranging import read_decaranging

    def table(name, key):
        with open(root / name, newline="") as fh:
            return {int(r[key]): r for r in csv.DictReader(fh)}

    labels, pairs = table("labels.csv", "file_id"), table("pairs.csv", "file_number")
    anchors, tags = table("anchors.csv", "location"), table("tags.csv", "location")
    out = []
    for path in sorted(root.glob("*.log.gz"), key=lambda p: int(p.name.split(".")[0])):
        i = int(path.name.split(".")[0])
        a, t = anchors[int(pairs[i]["anchor_location"])], tags[int(pairs[i]["tag_location"])]
        d = float(np.hypot(float(a["x"]) - float(t["x"]), float(a["y"]) - float(t["y"])))
        log = read_decaranging(path)
        out.append((i, labels[i]["label"], d, log.dist_m - d, log.fp_minus_rx_db))
    return out


def _stats(e: np.ndarray) -> str:
    return (f"{e.size:6d} {np.median(e):+8.3f} {np.mean(e):+8.3f} {np.std(e):7.3f} "
            f"{np.percentile(np.abs(e), 95):7.3f}")


def simulated_rows(site_seeds, n_walks: int, walk_s: float):
    """Simulated UWB logs with their truth: list of (UwbLog, UwbTruth)."""
    from simulation.rng import stream_rng
    from simulation.site.layout import generate_site
    from simulation.site.route import RouteConfig, plan_route, route_trajectory
    from simulation.streams import StreamContext
    from simulation.uwb.stream import simulate_uwb
    from simulation.walk import default_start_utc, device_height_m

    out = []
    for w in range(n_walks):
        site = generate_site(site_seeds[w % len(site_seeds)])
        seed = 100 + w
        poly, stops, speed = plan_route(site, stream_rng(seed, "route"), walk_s, RouteConfig())
        traj = route_trajectory(poly, stops, speed, walk_s, default_start_utc(seed), device_height_m(site, seed))
        out.append(simulate_uwb(StreamContext(site=site, trajectory=traj, out_dir=Path("."), seed=seed, kind="walk")))
    return out


def section_nlos(args) -> None:
    from simulation.uwb.channel import PATH_BENT, PATH_DIRECT, PATH_THROUGH

    head = f"{'':28s} {'n':>6s} {'median':>8s} {'mean':>8s} {'sd':>7s} {'p95|e|':>7s}   FP-RX dB (median)"
    print("Range error, m (measured − true)")
    print(head)
    if CIR_UWB.is_dir():
        rows = measured_rows()
        for label in ("LOS", "NLOS", "NDP NLOS"):
            sel = [r for r in rows if r[1] == label]
            e = np.concatenate([r[3] for r in sel])
            q = np.concatenate([r[4] for r in sel])
            per_log = np.array([np.median(r[3]) for r in sel])
            print(f"{'measured ' + label:28s} {_stats(e)}   {np.median(q):6.1f}   "
                  f"(logs: {len(sel)}, per-log medians {per_log.min():+.2f}..{per_log.max():+.2f})")
        los = np.median(np.concatenate([r[3] for r in rows if r[1] == "LOS"]))
        print(f"  measured LOS median offset {los:+.3f} m (uncalibrated antenna delay of the EVK1000 pair);"
              f" NLOS and NDP relative to it:")
        for label in ("NLOS", "NDP NLOS"):
            e = np.concatenate([r[3] for r in rows if r[1] == label]) - los
            print(f"{'  measured ' + label + ' − LOS':28s} {_stats(e)}")
    else:
        print(f"(measured data absent: {CIR_UWB})")
    t0 = time.perf_counter()
    sims = simulated_rows(args.site_seeds, args.walks, args.walk_s)
    el = time.perf_counter() - t0
    err = np.concatenate([log.range_m - tr.true_range_m for log, tr in sims])
    kind = np.concatenate([tr.first_kind for _, tr in sims])
    q = np.concatenate([log.quality for log, _ in sims])
    az_err = np.concatenate([(log.azimuth_deg - tr.true_azimuth_deg) for log, tr in sims])
    front = np.concatenate([np.abs(tr.true_azimuth_deg) <= 90.0 for _, tr in sims])
    for name, k in (("simulated LOS (clear)", PATH_DIRECT), ("simulated NLOS (through)", PATH_THROUGH),
                    ("simulated no direct path", PATH_BENT)):
        sel = kind == k
        if sel.any():
            print(f"{name:28s} {_stats(err[sel])}   {np.median(q[sel]):6.1f}   (share {sel.mean():.3f})")
    print(f"  ({args.walks} walks of {args.walk_s:g} s on sites {args.site_seeds}, {err.size} ranges, {el:.1f} s)")
    print("\nPDoA angle error, deg (tags in front of the array; simulated only: the measured data has no angles)")
    print(f"{'':28s} {'n':>6s} {'median':>8s} {'mean':>8s} {'sd':>7s} {'p95|e|':>7s}")
    for name, sel in (("simulated LOS", (kind == PATH_DIRECT) & front), ("simulated NLOS (any)", (kind != PATH_DIRECT) & front)):
        if sel.any():
            print(f"{name:28s} {_stats(az_err[sel])}")
    # the device's own indicator: how well does FP−RX < −6 dB flag the rows whose first path is not clear?
    flag = q < -6.0
    nlos = kind != PATH_DIRECT
    print(f"\nFP−RX < −6 dB as an NLOS flag (simulated): flags {flag[nlos].mean():.2f} of NLOS rows, "
          f"{flag[~nlos].mean():.2f} of LOS rows")
    if CIR_UWB.is_dir():
        lab = np.concatenate([np.full(r[4].size, r[1] != "LOS") for r in rows])
        qq = np.concatenate([r[4] for r in rows])
        print(f"FP−RX < −6 dB as an NLOS flag (measured):  flags {(qq[lab] < -6).mean():.2f} of NLOS packets, "
              f"{(qq[~lab] < -6).mean():.2f} of LOS packets")


def _yardstick_s() -> float:
    import scipy.signal

    rng = np.random.default_rng(0)
    x = rng.standard_normal(480_000).astype(np.float32)
    h = rng.standard_normal(480).astype(np.float32)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        best = min(best, time.perf_counter() - t0)
    return best


def section_methods(args) -> None:
    from features.site import ENV_CLASSES, save_site
    from models.uwb_pdr import UwbPdrFilter
    from simulation.site.layout import generate_site
    from simulation.walk import simulate_walk
    from walks.reader import read_walk
    from walks.uwb_methods import AOA_SOLVE

    work = Path(args.workdir)
    work.mkdir(parents=True, exist_ok=True)
    writers = ("simulation.gnss.stream:write_gnss", "simulation.imu.stream:write_imu",
               "simulation.uwb.stream:write_uwb_stream")
    errs = {m: {c: [] for c in ENV_CLASSES} for m in ("pdr", "uwb", "uwb_aoa_pdr")}
    times, durations = [], []
    for w in range(args.walks):
        s = args.site_seeds[w % len(args.site_seeds)]
        site_dir = work / f"site{s}"
        if not (site_dir / "site.toml").is_file():
            site_dir.mkdir(exist_ok=True)
            save_site(generate_site(s), site_dir / "site.toml")
        wd = work / f"walk{w}_{int(args.walk_s)}"
        if not wd.is_dir():
            simulate_walk(site_dir, wd, seed=200 + w, duration_s=args.walk_s, writers=writers, progress=False)
        data = read_walk(wd)
        tr = data.truth
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            fixes = data.uwb.positions(AOA_SOLVE)
            run = UwbPdrFilter().run(data.pdr.result, data.pdr.start_en_m, fixes)
            best = min(best, time.perf_counter() - t0)
        times.append(best)
        durations.append(args.walk_s)
        r = data.pdr.result
        for name, t, e, n in (("pdr", r.t_s, r.east_m, r.north_m), ("uwb", fixes.t_s, fixes.east_m, fixes.north_m),
                              ("uwb_aoa_pdr", run.t_s, run.x[:, 0], run.x[:, 1])):
            te, tn = tr.at(t)
            cls = tr.class_at(t)
            d = np.hypot(e - te, n - tn)
            for c, cname in enumerate(ENV_CLASSES):
                errs[name][cname].append(d[cls == c])
    print(f"Horizontal error, m, by true class ({args.walks} walks of {args.walk_s:g} s; median / p95 / n)")
    print(f"{'method':14s} " + " ".join(f"{c:>24s}" for c in ENV_CLASSES))
    for name, per in errs.items():
        cells = []
        for c in ENV_CLASSES:
            d = np.concatenate(per[c]) if per[c] else np.zeros(0)
            cells.append(f"{np.median(d):7.2f} {np.percentile(d, 95):7.2f} {d.size:7d}" if d.size else f"{'—':>24s}")
        print(f"{name:14s} " + " ".join(f"{c:>24s}" for c in cells))
    per10 = np.array(times) / np.array(durations) * 600.0
    y = _yardstick_s()
    print(f"\nuwb_aoa_pdr (UWB solve + filter) per 10-minute walk: {np.median(per10):.2f} s (walks: "
          f"{', '.join(f'{v:.2f}' for v in per10)}); oaconvolve yardstick {y * 1e3:.1f} ms; "
          f"ratio {np.median(per10) / y:.0f}x")


def _study_walks(study: Path, out: Path):
    """The study's walks with ``uwb.csv`` added: the sites copied with UWB anchors placed on their beacon poles
    (:func:`simulation.uwb.placement.place_uwb_anchors`), each walk's trajectory rebuilt from its seed (as
    :func:`simulation.walk.simulate_walk` draws it; checked against its ``truth.csv`` to 1 cm) and its UWB
    simulated; the other files linked. Returns ({site id: [walk dirs]}, split table)."""
    from dataclasses import replace

    from features.fileio import read_toml, write_toml
    from features.site import load_site, save_site
    from features.uwb.reader import write_uwb
    from features.walk import parse_utc, read_truth
    from simulation.rng import stream_rng
    from simulation.site.route import RouteConfig, plan_route, route_trajectory
    from simulation.streams import StreamContext
    from simulation.uwb.placement import place_uwb_anchors
    from simulation.uwb.stream import UwbSimConfig, simulate_uwb
    from simulation.walk import device_height_m

    data = study / "data"
    split = read_toml(data / "split.toml")
    walks = {}
    for sid in dict.fromkeys(list(split["train_sites"]) + list(split["test_sites"])):
        site = load_site(data / "sites" / str(sid) / "site.toml")
        sdir = out / "sites" / str(sid)
        sdir.mkdir(parents=True, exist_ok=True)
        if not (sdir / "site.toml").is_file():
            save_site(replace(site, uwb_anchors=place_uwb_anchors(site)), sdir / "site.toml")
        site_u = load_site(sdir / "site.toml")
        walks[sid] = []
        for wd in sorted((data / "walks" / str(sid)).iterdir()):
            dst = out / "walks" / str(sid) / wd.name
            if not (dst / "uwb.csv").is_file():
                dst.mkdir(parents=True, exist_ok=True)
                for f in wd.iterdir():
                    if f.name != "walk.toml" and not (dst / f.name).exists():
                        (dst / f.name).symlink_to(f.resolve())
                meta = read_toml(wd / "walk.toml")
                route = RouteConfig()
                dur = float(meta["duration_s"])
                poly, stops, speed = plan_route(site, stream_rng(int(meta["seed"]), "route"), dur, route)
                traj = route_trajectory(poly, stops, speed, dur, parse_utc(meta["start_utc"]),
                                        device_height_m(site, int(meta["person"])), route)
                truth = read_truth(wd)
                te, tn, _ = traj.interp(truth.t_s)
                dev = float(np.max(np.hypot(te - truth.east_m, tn - truth.north_m)))
                if dev > 0.01:
                    print(f"  {wd}: rebuilt trajectory {dev:.2f} m off its truth.csv; left out")
                    continue
                log, _ = simulate_uwb(StreamContext(site=site_u, trajectory=traj, out_dir=dst, seed=int(meta["seed"]),
                                                    kind="walk", person_seed=int(meta["person"])))
                write_uwb(dst / "uwb.csv", log)
                meta["uwb"] = {"file": "uwb.csv", "rate_hz": UwbSimConfig().rate_hz}
                write_toml(dst / "walk.toml", meta)
            walks[sid].append(dst)
    return walks, split


def _ci(per_walk: list, stat, rng, n_boot: int = 1000) -> tuple[float, float]:
    """95 % bootstrap interval of ``stat`` over the pooled errors, resampling whole walks."""
    vals = []
    for _ in range(n_boot):
        pick = rng.integers(0, len(per_walk), len(per_walk))
        d = np.concatenate([per_walk[i] for i in pick])
        if d.size:
            vals.append(stat(d))
    return float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))


def _is_test(split: dict, sid: int, walk_dir: Path) -> bool:
    """Whether a study walk is held out: on a later-days split the ``later<k>`` walks of the same sites
    (:meth:`simulation.split.SplitLayout.walk_dir`), else every walk of a test site."""
    if split.get("later_days"):
        return walk_dir.name.startswith("later")
    return sid in split["test_sites"]


def section_study(args) -> None:
    """``uwb``, ``uwb_aoa_pdr`` and the prior's two methods on a benchmark study's held-out walks, by class,
    beside the study's own ``kf_quality`` and Fusion II rows (``study.json``)."""
    import json

    from features.site import ENV_CLASSES
    from models.fusion.model import load_fusion_model
    from models.uwb_pdr import UwbNoisePrior, UwbPdrFilter, uwb_nees
    from walks.inputs import walk_inputs
    from walks.reader import read_walk
    from walks.uwb_methods import AOA_SOLVE

    study = Path(args.study)
    walks, split = _study_walks(study, Path(args.workdir) / f"study_{study.name}")
    model = load_fusion_model(study / "seed0" / "fusion_model")
    read = {}
    for sid, dirs in walks.items():
        for wd in dirs:
            t0 = time.perf_counter()
            d = read_walk(wd)
            inputs = walk_inputs(d, model.classifier)
            read[wd] = (sid, d, inputs, d.uwb.positions(AOA_SOLVE))
            print(f"  read {wd.parent.name}/{wd.name} in {time.perf_counter() - t0:.1f} s", flush=True)
    nees, cls = [], []
    for wd, (sid, d, inputs, f) in read.items():
        if not _is_test(split, sid, wd):
            te, tn = d.truth.at(f.t_s)
            nees.append(uwb_nees(np.column_stack([f.east_m - te, f.north_m - tn]), f.cov_en))
            cls.append(np.argmax(inputs.classes.at(f.t_s), axis=1))
    prior = UwbNoisePrior(model.classifier.n_classes_, args.prior_estimator).fit(np.concatenate(nees), np.concatenate(cls))
    blind = UwbNoisePrior(1, args.prior_estimator).fit(np.concatenate(nees), np.concatenate(cls))
    print(f"NLOS prior ({args.prior_estimator}) fitted on {len(nees)} training walks: per class {np.round(prior.scale_, 2).tolist()}, "
          f"blind {blind.scale_[0]:.2f}")
    errs = {m: {c: [] for c in ENV_CLASSES} for m in ("uwb", "uwb_aoa_pdr", "uwb_aoa_pdr_env", "uwb_aoa_pdr_blind")}
    per10 = []
    for wd, (sid, d, inputs, f) in read.items():
        if not _is_test(split, sid, wd):
            continue
        t0 = time.perf_counter()
        f = d.uwb.positions(AOA_SOLVE)
        run = UwbPdrFilter().run(d.pdr.result, d.pdr.start_en_m, f)
        per10.append((time.perf_counter() - t0) / float(d.walk.duration_s) * 600.0)
        tracks = {"uwb": (f.t_s, f.east_m, f.north_m), "uwb_aoa_pdr": (run.t_s, run.x[:, 0], run.x[:, 1])}
        for name, pr in (("uwb_aoa_pdr_env", prior), ("uwb_aoa_pdr_blind", blind)):
            scale = pr.r_scale(np.ones((len(f), 1)) if pr.n_classes == 1 else inputs.classes.at(f.t_s))
            r = UwbPdrFilter(method=name).run(d.pdr.result, d.pdr.start_en_m, f, r_scale=scale)
            tracks[name] = (r.t_s, r.x[:, 0], r.x[:, 1])
        for name, (t, e, n) in tracks.items():
            te, tn = d.truth.at(t)
            c = d.truth.class_at(t)
            err = np.hypot(e - te, n - tn)
            for k, cname in enumerate(ENV_CLASSES):
                errs[name][cname].append(err[c == k])
    rng = np.random.default_rng(0)
    n_test = sum(_is_test(split, s, w) for s, dirs in walks.items() for w in dirs)
    print(f"\nStudy {study.name}: {n_test} held-out walks on sites {split['test_sites']}; horizontal error, m: "
          f"median [95 % CI over walks] / p95 / mean")
    for name, per in errs.items():
        for cname in ENV_CLASSES:
            d = np.concatenate(per[cname])
            if not d.size:
                continue
            lo, hi = _ci(per[cname], np.median, rng)
            print(f"{name:20s} {cname:6s} n {d.size:6d}  median {np.median(d):6.3f} [{lo:.3f}, {hi:.3f}]  "
                  f"p95 {np.percentile(d, 95):6.2f}  mean {np.mean(d):6.3f}")
    table = json.loads((study / "study.json").read_text())["table"]
    print("\nThe study's own rows (study.json, its seeds pooled):")
    for r in table:
        if r["method"] in args.compare and r["env_class"] in ENV_CLASSES:
            print(f"{r['method']:20s} {r['env_class']:6s} n {r['n']:6d}  median {r['median_m']:6.3f}"
                  f"{'':18s}  p95 {r['p95_m']:6.2f}  mean {r['mean_m']:6.3f}")
    print(f"\nuwb_aoa_pdr (solve + filter) per 10-minute walk: median {np.median(per10):.3f} s over {len(per10)} walks")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--methods", action="store_true", help="run the methods section instead of the NLOS one")
    p.add_argument("--walks", type=int, default=3)
    p.add_argument("--walk-s", type=float, default=300.0)
    p.add_argument("--site-seeds", type=int, nargs="+", default=[3, 7, 11])
    p.add_argument("--workdir", default="/tmp/bench_uwb")
    p.add_argument("--study", help="a benchmark study folder (data/, seed0/fusion_model, study.json): the UWB "
                                   "methods on its held-out walks beside its own rows")
    p.add_argument("--prior-estimator", default="mean", choices=("mean", "median"),
                   help="the NLOS prior's chi2_2 estimator (models.fusion.noise.chi2_2_mean)")
    p.add_argument("--compare", nargs="+", default=["kf_quality", "adaptive", "fg_env", "pdr"],
                   help="the study's methods printed beside (default: kf_quality adaptive fg_env pdr)")
    args = p.parse_args(argv)
    if args.study:
        section_study(args)
    elif args.methods:
        section_methods(args)
    else:
        section_nlos(args)


if __name__ == "__main__":
    main()
