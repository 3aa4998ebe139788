"""Speed of the whole pipeline and of batch evaluation (issue 14): prints figures, asserts nothing.

1. **Raw files to fused track, one core**: a 10-minute simulated walk read
   (NMEA, audio, IMU), classified window by window and fused by ``adaptive``
   (environment classifier, per-class filter, BP network): × real time, and
   that rate divided by scipy's ``oaconvolve`` matched filter over the same
   audio timed in the same run (this VM's speed drifts 1.5–2× between days; the
   ratio is the figure to compare). Target: ≥ 500× real time.
2. **Fusion step alone**: events per second of each method on that walk's
   event stream (reading excluded). Target: ≥ 50,000 steps/s for ``adaptive``.
3. **evaluate over 8 walks** with 1 and 2 local workers: wall time, parallel
   efficiency T1 / (2·T2) (target ≥ 0.8) and the peak resident memory of a
   worker process.

Usage: ``python bench/bench_pipeline.py [--quick]`` (``--quick``: 2-minute walks, 4 walks).
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.signal
import soundfile as sf

os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def oaconvolve_rate(wav: Path) -> tuple[float, float]:
    """× real time of scipy's oaconvolve with the receiver's 10 ms chirp kernel over the whole file: the first
    run (the figure earlier notes quote; it also allocates and faults in its 115 MB output, and read 154–377×
    on one day) and the best of three (that memory reused: 1,900× on the same day)."""
    from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank

    x, fs = sf.read(str(wav), dtype="float32")
    h = MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], fs).kernels[0].astype(np.float32)
    walls = []
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        walls.append(time.perf_counter() - t0)
    duration = len(x) / fs
    return duration / walls[0], duration / min(walls)


def build(tmp: Path, walk_s: float, n_walks: int):
    from features.site import save_site
    from models.bp import BPConfig
    from models.fusion.model import save_fusion_model
    from models.environment import EnvironmentClassifier
    from training.filters import train_fusion
    from walks.inputs import window_features
    from walks.reader import read_walk
    from simulation.site.layout import generate_site
    from simulation.walk import simulate_walk

    site = tmp / "site"
    site.mkdir()
    save_site(generate_site(5), site / "site.toml")
    walks = [simulate_walk(site, tmp / f"w{k}", seed=40 + k, duration_s=walk_s) for k in range(n_walks)]
    train = walks[:2]
    X, y = [], []
    for w in train:
        d = read_walk(w)
        t, Xw = window_features(d)
        X.append(Xw)
        y.append(d.truth.class_at(t - 1.0))
    clf = EnvironmentClassifier(min_samples=10).fit(np.vstack(X), np.concatenate(y))
    model = train_fusion(train, clf, bp_config=BPConfig(n_members=5))
    save_fusion_model(model, tmp / "model")
    return walks, tmp / "model"


def pipeline_rate(walk: Path, model_dir: Path) -> tuple[float, float, dict]:
    from models.fusion.model import load_fusion_model
    from walks.inputs import walk_inputs
    from walks.methods import method, method_names, run_methods
    from walks.reader import read_walk

    model = load_fusion_model(model_dir)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        data = read_walk(walk)
        inputs = walk_inputs(data, model.classifier)
        tracks, _ = run_methods(model, inputs, ("adaptive",), smooth=False)
        best = min(best, time.perf_counter() - t0)
    duration = float(data.walk.duration_s)
    rates = {}
    n_events = len(inputs.events)
    r = data.pdr.result
    n_steps = int(np.sum(np.isfinite(r.heading_rad) & np.isfinite(r.step_length_m)))     # heel strikes
    for m in [n for n in method_names() if method(n).filter or n.startswith("adaptive")]:
        wall = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            run_methods(model, inputs, (m,), smooth=False)
            wall = min(wall, time.perf_counter() - t0)
        rates[m] = n_events / wall
    return duration / best, (n_events, n_steps), rates


def stage_breakdown(walk: Path, model_dir: Path, repeat: int = 5) -> dict:
    """CPU seconds (best of ``repeat``, process time) of each stage of raw files -> adaptive track.

    The stages :func:`walks.reader.read_walk` and the fusion run one after another:
    NMEA reading (and the walk's time base), GNSS sky arrays and positions (ENU, sigma), GNSS
    features, the acoustic receiver, IMU reading and PDR, the fusion inputs from the read walk
    (events, the 14 window features, the classifier) and the ``adaptive`` filter.
    """
    from features.gnss.features import gnss_features, sky_arrays
    from features.gnss.nmea import epochs_on_time_base, read_nmea
    from features.gnss.positions import fixes_to_enu
    from features.walk import load_walk
    from models.fusion.model import load_fusion_model
    from walks import reader as wd
    from walks.inputs import walk_inputs
    from walks.methods import run_methods

    model = load_fusion_model(model_dir)
    info = load_walk(walk)
    site = info.load_site()
    o = site.origin
    state: dict = {}

    def nmea():
        state["epochs"] = epochs_on_time_base(read_nmea(info.path("gnss"))[0], info.start_utc)

    def gnss_positions():
        state["sky"] = sky_arrays(state["epochs"])
        fixes_to_enu(state["epochs"], o.lat_deg, o.lon_deg, o.alt_m, sky=state["sky"])

    def gnss_feats():
        gnss_features(state["sky"])

    def audio():
        wd.read_acoustic_stream(info, site, None)

    def imu():
        wd.read_pdr_stream(info, (0.0, 0.0), None)

    state["data"] = wd.read_walk(walk)

    def inputs():
        state["inputs"] = walk_inputs(state["data"], model.classifier)

    def fusion():
        run_methods(model, state["inputs"], ("adaptive",), smooth=False)

    stages = {"NMEA read + time base": nmea, "GNSS sky arrays + positions": gnss_positions,
              "GNSS features": gnss_feats, "acoustic receiver": audio, "IMU read + PDR": imu,
              "fusion inputs (events, windows, classifier)": inputs, "adaptive filter": fusion}
    out = {}
    for name, fn in stages.items():
        best = np.inf
        for _ in range(repeat):
            gc.collect()  # each stage starts from a collected heap (the build left much garbage behind)
            t0 = time.process_time()
            fn()
            best = min(best, time.process_time() - t0)
        out[name] = best
    return out


def _peak_rss_task(walk, model_dir, methods, force):
    """:func:`pipeline.evaluate.evaluate_walk`, plus this process's peak resident memory (VmHWM, MiB).

    VmHWM is the high-water mark of this process's own address space since it started; getrusage's
    maxrss of children would also count the parent's pages at the fork before the worker's exec
    (Linux keeps the larger), which put every worker at the size of this bench process (~1 GiB).
    """
    from pipeline.evaluate import evaluate_walk

    evaluate_walk(walk, model_dir, methods, force)
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmHWM:"))


def evaluate_scaling(walks, model_dir: Path, tmp: Path, repeat: int = 2) -> dict:
    """Wall time of ``evaluate`` with 1 and 2 local workers, the runs interleaved (1, 2, 1, 2, ...) and the
    best of ``repeat`` kept: this VM's speed moves by tens of per cent within minutes, and interleaving
    lets both see the same machine. Each 2-worker run starts its own Dask cluster (worker start-up and
    imports included, as a user's ``envfuse evaluate --workers 2`` pays them)."""
    from pipeline.evaluate import evaluate

    out: dict = {1: np.inf, 2: np.inf}
    for _ in range(repeat):
        for workers in (1, 2):
            t0 = time.perf_counter()
            evaluate(walks, model_dir, tmp / f"rep{workers}", workers=workers, progress=False, plots=False)
            out[workers] = min(out[workers], time.perf_counter() - t0)
    return out


def machine_ceiling(walks, model_dir: Path) -> float:
    """Parallel efficiency of the same per-walk work in two pre-started, warmed-up plain processes (no
    Dask, imports and the first walk excluded, each taking half the walks): what these two cores give."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    times = {}
    for n in (1, 2):
        with ctx.Manager() as m:
            barrier = m.Barrier(n)
            with ctx.Pool(n) as pool:
                walls = pool.map(_ceiling_worker, [(list(map(str, walks[i::n])), str(model_dir), barrier)
                                                   for i in range(n)])
        times[n] = max(walls)
    return times[1] / (2 * times[2])


def _ceiling_worker(args) -> float:
    walks, model_dir, barrier = args
    from pipeline.evaluate import evaluate_walk
    from walks.methods import method_names

    evaluate_walk(walks[0], model_dir, method_names(), False)      # warm: imports, caches
    barrier.wait()
    t0 = time.perf_counter()
    for w in walks:
        evaluate_walk(w, model_dir, method_names(), False)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2-minute walks, 4 walks")
    ap.add_argument("--breakdown-only", action="store_true",
                    help="3 walks (2 to train, 1 timed): the per-stage breakdown, no evaluate scaling")
    args = ap.parse_args()
    walk_s, n_walks = (120.0, 4) if args.quick else (600.0, 8)
    if args.breakdown_only:
        n_walks = 3
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        t0 = time.perf_counter()
        walks, model_dir = build(tmp, walk_s, n_walks)
        print(f"built {n_walks} walks of {walk_s:.0f} s and a model in {time.perf_counter() - t0:.0f} s")
        rate, n_events, step_rates = pipeline_rate(walks[-1], model_dir)
        yard, yard_warm = oaconvolve_rate(walks[-1] / "audio.wav")
        print(f"raw files -> adaptive track, one core: {rate:,.0f}x real time (oaconvolve matched filter in the same "
              f"run: first run {yard:,.0f}x, ratio {rate / yard:.3f}; best of 3 {yard_warm:,.0f}x, ratio "
              f"{rate / yard_warm:.3f}; target 500x)")
        stages = stage_breakdown(walks[-1], model_dir)
        total = sum(stages.values())
        print(f"breakdown of one run (CPU s, best of 5; sum {total:.3f} s = {walk_s / total:,.0f}x real time, "
              f"ratio to oaconvolve {walk_s / total / yard:.3f}):")
        for name, sec in stages.items():
            print(f"  {name:36s} {sec:7.3f} s  {100 * sec / total:5.1f} %  ({walk_s / sec:,.0f}x real time)")
        n_events, n_steps = n_events
        print(f"fusion alone on a {walk_s:.0f} s walk, best of 3: filter events (a predict or an update; "
              f"{n_events:,} in all: {n_steps:,} PDR heel strikes cut at the fixes inside them, GNSS and acoustic "
              f"fixes) per second, and PDR heel strikes per second")
        for m, r in step_rates.items():
            print(f"  {m:16s} {r:12,.0f} events/s {r * n_steps / n_events:12,.0f} heel strikes/s")
        if args.breakdown_only:
            return
        times = evaluate_scaling(walks, model_dir, tmp)
        eff = times[1] / (2 * times[2])
        ceiling = machine_ceiling(walks, model_dir)
        from pipeline.parallel import map_walks
        from walks.methods import method_names

        rss = map_walks(_peak_rss_task, [str(w) for w in walks], str(model_dir), method_names(), False,
                        workers=2, progress=False)
        print(f"evaluate {n_walks} walks (best of 2, interleaved): 1 worker {times[1]:.1f} s, 2 workers "
              f"{times[2]:.1f} s, parallel efficiency {eff:.2f} (target 0.8); the same work in two warmed-up "
              f"plain processes: {ceiling:.2f}; peak RSS of a worker process {max(rss):.0f} MiB")

if __name__ == "__main__":
    main()
