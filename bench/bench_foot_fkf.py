"""``foot_ins_fkf`` against ``kf_quality`` per environment class on held-out simulated walks, and its speed per
10-minute walk (issue 26, item 5 of the foot-INS work).

Training: the fusion model (the ``kf_quality`` noise, no BP) and a supervised environment classifier fitted on
``--n-train`` walks of site 3; test: ``--n-test`` walks of site 5, a site the model never saw. The foot method
uses nothing the model learnt (its settings are fixed: :class:`models.foot.ins.FootInsConfig`); ``kf_quality``
fuses GNSS and the acoustic fixes. Errors are horizontal, at each method's own epochs, per truth class
(:func:`walks.score.track_errors`); the interval is a 95 % percentile bootstrap of the mean over walks
(2 000 resamples of whole walks: epochs of one walk are not independent).

Speed: one 600 s walk (GNSS, waist IMU, UWB and foot IMU; no audio, which the foot method does not read): the
method's wall time (read ``imu_foot.csv``, read and solve ``uwb.csv``, the filter), best of 3, beside
``scipy.signal.oaconvolve`` of 60 s of 48 kHz audio with a 480-tap kernel timed in the same run (the yardstick of
bench/bench_audio.py), and the ratio.

Measured (2 training walks of site 3, 3 test walks of site 5, 120 s each; this 2-core machine):

    method        class   epochs  mean m   95% CI (walks)  median  p95 m
    kf_quality    all       3817    0.07     [0.04, 0.10]    0.02   0.36
    foot_ins_fkf  all       3600    0.20     [0.16, 0.28]    0.15   0.49
    kf_quality    open      2289    0.05     [0.04, 0.05]    0.02   0.24
    foot_ins_fkf  open      2173    0.19     [0.15, 0.24]    0.13   0.47
    kf_quality    light      952    0.10     [0.03, 0.14]    0.03   0.55
    foot_ins_fkf  light      716    0.29     [0.25, 0.31]    0.28   0.54
    kf_quality    heavy      576    0.11     [0.02, 0.18]    0.05   0.38
    foot_ins_fkf  heavy      711    0.14     [0.07, 0.30]    0.07   0.45

    speed: 6.4 s per 10-minute walk (93x real time; oaconvolve 713x in the same run, ratio 7.6)

Read with care: truth.csv is the waist device's position and foot_ins_fkf tracks the right ankle, which is
0.19-0.27 m (mean; p95 0.40-0.48 m) from the waist on these walks (simulation/imu/foot.py's motion against
the route) — about all of its error. kf_quality fuses mostly RTK-fixed GNSS here (centimetres in the open).

(The table above is the ankle track, before foot_ins_fkf gave the body's: see ``--study`` below for both.)

``--study DIR`` (both splits; 2026-12-02, this machine): the study's 15 held-out walks (standard: sites 201-205;
later_days: the ``later<k>`` walks of sites 301-305) with ``imu_foot.csv`` added to linked copies of
bench_uwb.py's walks (trajectory rebuilt from the seed, within 1 cm of truth.csv; nothing in the study
overwritten); ``kf_quality`` and ``adaptive`` run with each of the study's 3 seed models (per-walk means averaged
over seeds, :func:`pipeline.compare.walk_scores`), ``uwb_aoa_pdr``, ``foot_ins_fkf`` (body, the mid-stance rule)
and ``foot_ankle`` (the same run's ankle track) once. Mean horizontal error m (median of the walks' medians);
Δ of foot_ins_fkf against each, with the 95 % site-level bootstrap interval (:func:`pipeline.compare.compare`)::

    standard     foot_ins_fkf   foot_ankle     uwb_aoa_pdr    kf_quality     adaptive
    all          0.349 (0.102)  0.401 (0.174)  0.599 (0.113)  0.219 (0.026)  0.205 (0.025)
    open         0.166 (0.105)  0.280 (0.249)  0.448 (0.139)  0.039 (0.016)  0.061 (0.015)
    light        0.336 (0.108)  0.372 (0.109)  0.877 (0.151)  0.213 (0.028)  0.203 (0.029)
    heavy        0.582 (0.142)  0.582 (0.224)  0.337 (0.200)  0.631 (0.251)  0.530 (0.221)
    Δ vs         foot_ankle            kf_quality              adaptive               uwb_aoa_pdr
    all          -12.9 [-21.5, -8.7]   +56.2 [-14.3, +226.0]   +66.9 [+7.5, +173.1]   -43.3 [-60.5, -5.1]
    open         -40.6 [-48.4, -32.2]  +324.6 [+208.3, +627.3] +174.9 [+52.7, +592.4] -62.8 [-74.1, -43.9]
    light         -9.7 [-23.2, -3.8]   +64.5 [-24.2, +290.1]   +72.4 [-7.1, +247.6]   -61.2 [-80.3, -25.2]
    heavy         +0.0 [-4.1, +1.4]     -5.9 [-50.7, +154.5]   +12.0 [-30.2, +91.0]   +71.6 [-5.2, +136.1]

    later_days   foot_ins_fkf   foot_ankle     uwb_aoa_pdr    kf_quality     adaptive
    all          0.391 (0.094)  0.441 (0.121)  0.657 (0.110)  0.191 (0.024)  0.240 (0.025)
    open         0.162 (0.090)  0.302 (0.258)  0.491 (0.126)  0.043 (0.014)  0.105 (0.014)
    light        0.134 (0.079)  0.165 (0.071)  0.330 (0.071)  0.176 (0.018)  0.230 (0.018)
    heavy        0.874 (0.139)  0.876 (0.126)  1.466 (0.154)  0.459 (0.175)  0.479 (0.241)
    Δ vs         foot_ankle            kf_quality              adaptive               uwb_aoa_pdr
    all          -11.4 [-29.7, -4.1]   +98.4 [-22.7, +282.0]   +57.8 [-42.6, +242.4]  -45.2 [-70.5, -25.7]
    open         -46.5 [-58.0, -36.3]  +278.7 [+50.1, +736.2]  +54.2 [-20.3, +283.9]  -66.9 [-82.6, -44.8]
    light        -18.9 [-23.1, -12.7]  -22.2 [-51.9, +49.9]    -40.3 [-68.1, +45.3]   -59.2 [-68.7, -31.0]
    heavy         -0.3 [-11.0, +1.3]   +90.4 [-56.4, +244.1]   +82.2 [-58.4, +220.4]  -42.8 [-69.1, -35.4]

    foot_ins_fkf 1.3-1.4 s per 10-minute walk (uwb_aoa_pdr 0.08-0.09 s), timed inside the runs above.

(Δ in %; Δ's pooled means can differ a little from the table's: compare() keeps the walks where both have the
class.) The body rule removes the ankle's offset where the walker walks (open: −41 / −47 %); in heavy
occlusion the mean is held by a few walks where the INS itself is metres off, which no output rule mends. Before
the UWB re-acquisition (models/foot/ins.py, ``uwb_relock_n``) the same runs gave 2.26 m (standard) and 3.83 m
(later_days) means: 7 of 15 walks per split ended 4-20 m off after a long stop (UWB gate lockout).

Not done here (issue 26 item 4 for this method): the environment class setting foot_ins_fkf's UWB gate or an
NLOS prior, with its blind twin. The UWB helper's NLOS prior (fitted per class on the training walks' χ²₂ NIS)
made uwb_aoa_pdr worse in every class, env and blind alike (bench/bench_uwb.py), and here the UWB local filter
already rejects by residual and gate; the heavy-class mean is held by a few walks where the INS is metres off,
which a tighter gate would lengthen rather than mend. Left for a run with its own fit on the training walks.

Run: ``.venv/bin/python bench/bench_foot_fkf.py [--n-train 2 --n-test 3 --duration 120 --work DIR]``
(simulates its walks into ``--work``, reusing any already there; prints tables; no assertions);
``--study /work/studies/standard`` (or ``later_days``) ``--work DIR [--uwb-work /tmp/bench_uwb] [--seeds 3]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.signal

from features.schema import ENV_CLASSES

METHODS = ("kf_quality", "foot_ins_fkf")


def _site(work: Path, seed: int) -> Path:
    from features.site import save_site
    from simulation.site.layout import generate_site

    d = work / f"site{seed}"
    if not (d / "site.toml").is_file():
        d.mkdir(parents=True, exist_ok=True)
        save_site(generate_site(seed), d / "site.toml")
    return d


def _walk(work: Path, site: Path, seed: int, duration_s: float, writers=None) -> Path:
    from simulation.walk import simulate_walk

    d = work / (f"{site.name}_w{seed}_{int(duration_s)}" + ("" if writers is None else "_noaudio"))
    if (d / "walk.toml").is_file():
        return d
    kw = {} if writers is None else {"writers": writers}
    return simulate_walk(site, d, seed=seed, duration_s=duration_s, progress=False, **kw)


def _model(train_dirs):
    from models.environment import EnvironmentClassifier
    from training.filters import DEFAULT_EKF, fit_fusion_model, training_rows
    from walks.inputs import walk_inputs, window_features
    from walks.reader import read_walk

    datas = [read_walk(d) for d in train_dirs]
    feats = [window_features(d) for d in datas]
    X = np.vstack([f[1] for f in feats])
    y = np.concatenate([d.truth.class_at(f[0] - 1.0) for d, f in zip(datas, feats)])
    clf = EnvironmentClassifier(min_samples=5).fit(X, y)
    rows = [training_rows(d, walk_inputs(d, clf), f"train{i}") for i, d in enumerate(datas)]
    return fit_fusion_model(rows, clf, None, ekf=DEFAULT_EKF)


def _boot_ci(per_walk: list[float], n: int = 2000, seed: int = 0) -> tuple[float, float]:
    v = np.asarray(per_walk, float)
    if len(v) < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), size=(n, len(v)))].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def accuracy(model, test_dirs) -> None:
    from walks.inputs import walk_inputs
    from walks.methods import run_methods
    from walks.reader import read_walk
    from walks.score import track_errors

    pooled = {(m, c): [] for m in METHODS for c in ("all",) + ENV_CLASSES}
    per_walk = {(m, c): [] for m in METHODS for c in ("all",) + ENV_CLASSES}
    for d in test_dirs:
        data = read_walk(d)
        inputs = walk_inputs(data, model.classifier)
        for m in METHODS:
            t0 = time.perf_counter()
            tracks, skipped = run_methods(model, inputs, (m,), smooth=False, lag_s=None)
            dt = time.perf_counter() - t0
            if m not in tracks:
                print(f"{d.name}: {m} skipped: {skipped.get(m)}")
                continue
            te = track_errors(tracks[m], data.truth)
            note = tracks[m].info.get("note", "")
            print(f"{d.name}: {m:13s} {dt:6.2f} s  mean {te['err_m'].mean():.2f} m  {note}")
            for k, c in [(None, "all")] + list(enumerate(ENV_CLASSES)):
                sel = np.ones(len(te["err_m"]), bool) if k is None else te["cls"] == k
                if sel.any():
                    pooled[(m, c)].append(te["err_m"][sel])
                    per_walk[(m, c)].append(float(te["err_m"][sel].mean()))
    print(f"\n{'method':13s} {'class':6s} {'epochs':>7s} {'mean m':>7s} {'95% CI (walks)':>16s} {'median':>7s} "
          f"{'p95 m':>6s}")
    for c in ("all",) + ENV_CLASSES:
        for m in METHODS:
            if not pooled[(m, c)]:
                continue
            x = np.concatenate(pooled[(m, c)])
            lo, hi = _boot_ci(per_walk[(m, c)])
            print(f"{m:13s} {c:6s} {len(x):7d} {x.mean():7.2f} {f'[{lo:.2f}, {hi:.2f}]':>16s} {np.median(x):7.2f} "
                  f"{np.percentile(x, 95):6.2f}")


def speed(model, walk: Path) -> None:
    from features.imu.foot import read_foot_imu
    from walks.foot_methods import foot_ins_fkf
    from walks.inputs import walk_inputs
    from walks.methods import MethodContext
    from walks.reader import read_walk

    data = read_walk(walk)
    inputs = walk_inputs(data, model.classifier)
    dur = float(data.walk.duration_s)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        tr = foot_ins_fkf(MethodContext(model, inputs))
        best = min(best, time.perf_counter() - t0)
    imu = read_foot_imu(data.walk.path("imu_foot"))
    x = np.random.default_rng(0).standard_normal(60 * 48_000).astype(np.float32)
    h = np.random.default_rng(1).standard_normal(480).astype(np.float32)
    yard = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        yard = min(yard, time.perf_counter() - t0)
    per10 = best * 600.0 / dur
    print(f"\nspeed: foot_ins_fkf on a {dur:.0f} s walk ({len(imu.t_s)} foot samples at {imu.rate_hz:.0f} Hz, "
          f"{tr.info['note']}): {best:.2f} s best of 3 = {per10:.2f} s per 10-minute walk, {dur / best:.0f}x real "
          f"time; oaconvolve 60 s of 48 kHz audio {yard * 1000:.1f} ms ({60 / yard:.0f}x real time); "
          f"ratio method/oaconvolve per second of walk {(best / dur) / (yard / 60):.1f}")


def _rebuilt_trajectory(site, wd: Path):
    """The walk's trajectory rebuilt from its seed as :func:`simulation.walk.simulate_walk` draws it, and its
    largest horizontal distance from the walk's ``truth.csv`` (bench/bench_uwb.py's check)."""
    from features.fileio import read_toml
    from features.walk import parse_utc, read_truth
    from simulation.rng import stream_rng
    from simulation.site.route import RouteConfig, plan_route, route_trajectory
    from simulation.walk import device_height_m

    meta = read_toml(wd / "walk.toml")
    route = RouteConfig()
    dur = float(meta["duration_s"])
    poly, stops, speed = plan_route(site, stream_rng(int(meta["seed"]), "route"), dur, route)
    traj = route_trajectory(poly, stops, speed, dur, parse_utc(meta["start_utc"]),
                            device_height_m(site, int(meta["person"])), route)
    truth = read_truth(wd)
    te, tn, _ = traj.interp(truth.t_s)
    return traj, meta, float(np.max(np.hypot(te - truth.east_m, tn - truth.north_m)))


def _study_foot_walks(study: Path, out: Path, uwb_work: Path) -> tuple[list, dict]:
    """The study's held-out walks with ``uwb.csv`` (bench/bench_uwb.py's linked copies in ``uwb_work``, built there
    if absent) and ``imu_foot.csv`` added in ``out``: every file linked, ``imu_foot.csv`` simulated from the
    rebuilt trajectory (within 1 cm of ``truth.csv``, else the walk is left out) and written temp + rename,
    ``walk.toml`` written new with its ``[imu_foot]`` table; nothing is written where a file already is.
    Returns ([(site id, walk dir)], split table)."""
    import sys

    from features.fileio import write_toml
    from features.site import load_site
    from simulation.imu.foot import IMU_FOOT_FILE, write_imu_foot
    from simulation.streams import StreamContext

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_uwb import _is_test, _study_walks

    walks, split = _study_walks(study, uwb_work)
    (out / "sites").mkdir(parents=True, exist_ok=True)
    held = []
    for sid, dirs in walks.items():
        link = out / "sites" / str(sid)
        if not link.exists():
            link.symlink_to((uwb_work / "sites" / str(sid)).resolve())
        for src in dirs:
            if not _is_test(split, sid, src):
                continue
            dst = out / "walks" / str(sid) / src.name
            if not (dst / "walk.toml").is_file():
                site = load_site(link / "site.toml")
                traj, meta, dev = _rebuilt_trajectory(site, src)
                if dev > 0.01:
                    print(f"  {src}: rebuilt trajectory {dev:.2f} m off its truth.csv; left out")
                    continue
                dst.mkdir(parents=True, exist_ok=True)
                for f in src.iterdir():
                    if f.name != "walk.toml" and not (dst / f.name).exists():
                        (dst / f.name).symlink_to(f.resolve())
                if not (dst / IMU_FOOT_FILE).exists():
                    # write_imu_foot writes temp + rename (features.fileio.atomic_write_text)
                    meta.update(write_imu_foot(StreamContext(site=site, trajectory=traj, out_dir=dst,
                                                             seed=int(meta["seed"]), kind="walk",
                                                             person_seed=int(meta["person"]))))
                write_toml(dst / "walk.toml", meta)
            held.append((sid, dst))
    return held, split


STUDY_METHODS = ("kf_quality", "adaptive", "uwb_aoa_pdr", "foot_ins_fkf")


def _walk_rows(models, wd: Path, sid: int) -> tuple[list[list[dict]], dict]:
    """Metric rows of one walk per model seed (kf_quality and adaptive per seed's model; the others use no
    learnt part and run once), the foot method's ankle track as ``foot_ankle``, and seconds per method."""
    from walks.foot_methods import foot_ins_fkf
    from walks.inputs import walk_inputs
    from walks.methods import MethodContext, run_methods
    from walks.reader import read_walk
    from walks.score import score

    data = read_walk(wd)
    name = f"{sid}/{wd.name}"
    per_seed, secs, once = [], {}, []
    for s, model in enumerate(models):
        inputs = walk_inputs(data, model.classifier)
        learnt = ("kf_quality", "adaptive")
        tracks, skipped = run_methods(model, inputs, learnt, smooth=False, lag_s=None)
        rows = score(tracks, data, name)
        if s == 0:
            for m in ("uwb_aoa_pdr", "foot_ins_fkf"):
                t0 = time.perf_counter()
                tr, sk = run_methods(model, inputs, (m,), smooth=False, lag_s=None)
                secs[m] = time.perf_counter() - t0
                if m not in tr:
                    print(f"  {name}: {m} skipped: {sk.get(m)}")
                once += score(tr, data, name)
            ankle = foot_ins_fkf(MethodContext(model, inputs), body=None)
            once += score({"foot_ankle": ankle}, data, name)
            for r in once:
                r["site"] = str(sid)
        for r in rows:
            r["site"] = str(sid)
        per_seed.append(rows + [dict(r) for r in once])
    return per_seed, secs


def section_study(args) -> None:
    """``foot_ins_fkf`` (body; and its ankle track) beside ``kf_quality``, ``adaptive`` and ``uwb_aoa_pdr`` on a
    study's held-out walks, per true class, with the site-level bootstrap interval of the paired difference
    (:func:`pipeline.compare.compare`)."""
    from models.fusion.model import load_fusion_model
    from pipeline.compare import compare, walk_scores

    study = Path(args.study)
    held, split = _study_foot_walks(study, Path(args.work) / f"study_{study.name}",
                                    Path(args.uwb_work) / f"study_{study.name}")
    models = [load_fusion_model(d / "fusion_model") for d in sorted(study.glob("seed*")) if
              (d / "fusion_model").is_dir()][: args.seeds]
    by_seed = [[] for _ in models]
    per10 = {}
    for sid, wd in held:
        t0 = time.perf_counter()
        rows, secs = _walk_rows(models, wd, sid)
        for s, r in enumerate(rows):
            by_seed[s].append({"walk": f"{sid}/{wd.name}", "site": str(sid), "rows": r})
        dur = float(split.get("walk_s", 300.0))
        for m, v in secs.items():
            per10.setdefault(m, []).append(v * 600.0 / dur)
        print(f"  {sid}/{wd.name}: {time.perf_counter() - t0:.1f} s", flush=True)
    scores = walk_scores(by_seed)
    print(f"\nStudy {study.name}: {len(held)} held-out walks on {len({s for s, _ in held})} sites, {len(models)} model "
          f"seeds (kf_quality, adaptive per seed; per-walk means averaged over seeds). Mean horizontal error, m "
          f"(in brackets the median of the walks' medians, seed 0); "
          f"Δ = Σ n ē_A / Σ n ē_B − 1 with its 95 % site-level bootstrap interval (pipeline/compare.py)")
    methods = ("foot_ins_fkf", "foot_ankle", "uwb_aoa_pdr", "kf_quality", "adaptive")
    for c in ("all",) + ENV_CLASSES:
        line = [f"{c:6s}"]
        for m in methods:
            v, n = scores.mean_m.get((m, c)), scores.n.get((m, c))
            if v is None:
                continue
            ok = np.isfinite(v) & (n > 0)
            med = [r["median_m"] for res in by_seed[0] for r in res["rows"] if r["method"] == m and r["env_class"] == c]
            line.append(f"{m} {np.sum(v[ok] * n[ok]) / np.sum(n[ok]):.3f} ({np.median(med):.3f})")
        print("  ".join(line))
    print()
    for c in ("all",) + ENV_CLASSES:
        for a, b in (("foot_ins_fkf", "foot_ankle"), ("foot_ins_fkf", "kf_quality"), ("foot_ins_fkf", "adaptive"),
                     ("foot_ins_fkf", "uwb_aoa_pdr")):
            cmp = compare(scores, a, b, c)
            if cmp is not None:
                print(f"  {cmp}")
    for m, v in per10.items():
        print(f"{m}: median {np.median(v):.2f} s per 10-minute walk over {len(v)} walks")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-train", type=int, default=2)
    ap.add_argument("--n-test", type=int, default=3)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "envfuse_bench_foot")
    ap.add_argument("--study", type=Path, help="a benchmark study folder (data/, seed*/fusion_model): the held-out "
                    "walks with imu_foot.csv added, foot_ins_fkf beside kf_quality, adaptive and uwb_aoa_pdr")
    ap.add_argument("--uwb-work", type=Path, default=Path("/tmp/bench_uwb"),
                    help="bench_uwb.py --study's work folder (its walks with uwb.csv; built there if absent)")
    ap.add_argument("--seeds", type=int, default=3, help="model seeds of the study used for kf_quality/adaptive")
    args = ap.parse_args(argv)
    if args.study:
        section_study(args)
        return 0
    work = args.work
    train_site, test_site = _site(work, 3), _site(work, 5)
    train = [_walk(work, train_site, 100 + i, args.duration) for i in range(args.n_train)]
    test = [_walk(work, test_site, 200 + i, args.duration) for i in range(args.n_test)]
    model = _model(train)
    accuracy(model, test)
    long_walk = _walk(work, test_site, 300, 600.0, writers=("simulation.gnss.stream:write_gnss",
                                                            "simulation.imu.stream:write_imu",
                                                            "simulation.uwb.stream:write_uwb_stream",
                                                            "simulation.imu.foot:write_imu_foot"))
    speed(model, long_walk)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
