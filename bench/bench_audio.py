"""Acoustic receiver speed and memory: audio seconds processed per wall second, one core.

Generates synthetic recordings (8 beacons round a 30 m square, a static receiver
10–25 m from all of them, two echoes per arrival, white noise; written block by
block so generation stays flat too), then times

* the streaming matched filter alone (decimated batched overlap-save), against
  ``scipy.signal.correlate(method="fft")`` and ``scipy.signal.oaconvolve`` of
  the same kernel over the same samples (full rate, whole file in memory);
* the whole receiver, ``features.acoustic.features.analyse_audio``: reading,
  matched filter, detection, CIR features per window and positions per frame;

and, on a simulated 300 s walk (``envfuse simulate site --seed 3`` and
``simulate walk --seed 7``, run through the CLI: the receiver itself never
imports the simulator), the whole receiver with acquisition and tracking of a
moving receiver (best of 3, beside ``oaconvolve`` of the same kernel over the same
audio, and CPU per stage), its fix count and its error against truth.csv
(``--walk-only``: this part alone);

and the receiver on files of 1, 5 and 10 minutes, each in its own process:
the first run there (imports, FFT plans), the best of six, the peak resident set (``resource.getrusage(RUSAGE_SELF).ru_maxrss``,
dominated by the interpreter and imported libraries) and the peak of memory
allocated while processing (``tracemalloc``, which numpy reports its buffers to).

Speeds are best-of-several because this 2-core virtual machine's speed drifts by
up to 40 % from minute to minute (a Python loop is timed first, as a gauge). For
the same reason the receiver is also measured against the yardsticks the issue
quotes its 1,000x target with (scipy ``correlate(method="fft")`` ~600x and
``oaconvolve`` ~2,400x on this machine), timed between the receiver's own runs.

Run: ``.venv/bin/python bench/bench_audio.py`` (prints a table; no assertions).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"          # one core, set before numpy loads

import json
import math
import resource
import tracemalloc
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import scipy.signal
import soundfile as sf

from features.acoustic.features import analyse_audio
from features.acoustic.detection import AudioTiming, DetectorConfig
from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank, StreamingMatchedFilter, chirp_template
from features.site import AcousticConfig, Beacon, Grid, Origin, Site

FS = 48_000
C = 331.3 * math.sqrt(1 + 20 / 273.15)


def ring_site() -> Site:
    pts = [(0, 0), (15, 0), (30, 0), (30, 15), (30, 30), (15, 30), (0, 30), (0, 15)]
    beacons = tuple(Beacon(id=i + 1, east_m=float(e), north_m=float(n), up_m=3.0, slot=i)
                    for i, (e, n) in enumerate(pts))
    return Site(name="bench", origin=Origin(31.0, 118.0), grid=Grid(5.0, -5.0, 35.0, -5.0, 35.0),
                acoustic=AcousticConfig(n_slots=8), beacons=beacons)


def write_recording(path: Path, minutes: float, seed: int = 0) -> None:
    """A static receiver at (13, 17): one 8 s pattern of chirps repeated, fresh noise per block."""
    site = ring_site()
    rng = np.random.default_rng(seed)
    block_n = int(10 * site.acoustic.frame_s * FS)
    pattern = np.zeros(block_n + FS)
    spec = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
    s = chirp_template(spec, FS)
    for k in range(10):
        for b in site.beacons:
            d = math.dist((13.0, 17.0, 1.0), (b.east_m, b.north_m, b.up_m))
            for extra_s, g in ((0.0, 1.0), (0.004, 0.35), (0.012, 0.2)):
                t = k * site.acoustic.frame_s + b.slot * site.acoustic.slot_s + d / C + 0.007 + extra_s
                n0 = int(round(t * FS))
                pattern[n0: n0 + len(s)] += g * 2.0 / d * s
    pattern[:FS] += pattern[block_n:]          # chirps spilling past the block wrap round (periodic)
    pattern = pattern[:block_n]
    total = int(minutes * 60 * FS)
    with sf.SoundFile(str(path), "w", FS, 1, subtype="PCM_16") as fh:
        done = 0
        while done < total:
            n = min(block_n, total - done)
            x = pattern[:n] + rng.normal(0, 0.003, n)
            fh.write(np.clip(x, -1, 0.9999))
            done += n


def receiver(path: Path) -> tuple[float, float, int, int]:
    """(audio s, wall s, windows, fixes) of one full receiver run."""
    site = ring_site()
    t0 = time.perf_counter()
    res = analyse_audio(path, site, AudioTiming(0.0, 0.02, 0.0), DetectorConfig())
    return res.duration_s, time.perf_counter() - t0, len(res.rows), len(res.fixes)


def reference_rates(path: Path, seconds: float = 60.0) -> tuple[float, float]:
    """x real time of scipy correlate(method="fft") and oaconvolve of the receiver's kernel over
    the first ``seconds`` of ``path`` (the yardsticks the issue's 1,000x target is quoted against)."""
    x, _ = sf.read(str(path), dtype="int16", frames=int(seconds * FS))
    x = x.astype(np.float32) / 32768
    h = MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], FS).kernels[0].astype(np.float32)
    t0 = time.perf_counter()
    scipy.signal.correlate(x, h[::-1], method="fft")
    t1 = time.perf_counter()
    scipy.signal.oaconvolve(x, h)
    t2 = time.perf_counter()
    return len(x) / FS / (t1 - t0), len(x) / FS / (t2 - t1)


def child(path: str, repeats: int = 3) -> None:
    """Receiver runs on ``path`` in a fresh process: the first, the best of ``repeats``, memory
    (before anything else allocates), then ``repeats`` more runs each followed by the two
    references, so that their ratio comes from the same minute."""
    walls = []
    for _ in range(repeats):                                             # timed without tracing
        dur, wall, n_rows, n_fix = receiver(Path(path))
        walls.append(wall)
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()                                                  # numpy reports its buffers here
    receiver(Path(path))
    traced_peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    paired, correlate, oaconvolve = [], [], []
    for _ in range(repeats):
        paired.append(receiver(Path(path))[1])
        c, o = reference_rates(Path(path))
        correlate.append(c)
        oaconvolve.append(o)
    print(json.dumps({"audio_s": dur, "wall_s": min(walls + paired), "first_wall_s": walls[0], "rows": n_rows,
                      "fixes": n_fix, "peak_mib": peak_kib / 1024, "traced_mib": traced_peak / 2 ** 20,
                      "paired_x": dur / min(paired), "correlate_x": max(correlate), "oaconvolve_x": max(oaconvolve)}))


def python_loop_us() -> float:
    """Best of 5: microseconds for 1,000 iterations of a float loop (how fast this machine is today)."""
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        x = 0.0
        for i in range(1000):
            x += i * 0.5
        best = min(best, time.perf_counter() - t0)
    return best * 1e6


def matched_filter_rates(path: Path) -> dict:
    """x real time of the streaming matched filter and of the two scipy yardsticks over ``path``."""
    x, _ = sf.read(str(path), dtype="int16")
    x = x.astype(np.float32) / 32768
    mf = StreamingMatchedFilter(MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], FS))
    t0 = time.perf_counter()
    for i in range(0, len(x), 4 * FS):
        mf.process(x[i: i + 4 * FS])
    streaming = len(x) / FS / (time.perf_counter() - t0)
    correlate, oaconvolve = reference_rates(path, len(x) / FS)
    return {"streaming decimated overlap-save (envelope)": streaming,
            "scipy oaconvolve (real output only)": oaconvolve,
            "scipy correlate fft (real output only)": correlate}


STAGES = {
    "read + sample stats": ("features.acoustic.detection", "_Stream", "ensure"),
    "impulse removal": ("features.acoustic.impulses", "ImpulseBlanker", ("process", "flush")),
    "matched filter": ("features.acoustic.matched_filter", "StreamingMatchedFilter", ("process", "flush")),
    "detection, association, timing": ("features.acoustic.detection", "_FrameDetector", "detect_frame"),
    "acquisition vote": ("features.acoustic.detection", "_FrameDetector", "acquire"),
    "fix: ranges, exclusion, lock, air": ("features.acoustic.tracking", "ClockPositionTracker", "frame_done"),
    "CIR features": ("features.acoustic.detection", "_FrameDetector", "flush_features"),
}
"""Receiver stages timed by :func:`stage_breakdown` (module, class, method(s)); time is exclusive of the stages
nested in them (``detect_frame`` reads audio through ``ensure``, which runs the blanker and the filter)."""


def stage_breakdown(run) -> dict:
    """CPU seconds per stage of one call of ``run()`` (exclusive, see :data:`STAGES`), plus ``other``."""
    import importlib

    spent: dict = {name: 0.0 for name in STAGES}
    stack: list = []
    saved = []

    def wrap(name, fn):
        def timed(*a, **k):
            t0 = time.process_time()
            stack.append(0.0)
            try:
                return fn(*a, **k)
            finally:
                inner = stack.pop()
                dt = time.process_time() - t0
                spent[name] += dt - inner
                if stack:
                    stack[-1] += dt
        return timed

    for name, (mod, cls, methods) in STAGES.items():
        klass = getattr(importlib.import_module(mod), cls)
        for m in (methods if isinstance(methods, tuple) else (methods,)):
            saved.append((klass, m, getattr(klass, m)))
            setattr(klass, m, wrap(name, getattr(klass, m)))
    try:
        t0 = time.process_time()
        run()
        total = time.process_time() - t0
    finally:
        for klass, m, fn in saved:
            setattr(klass, m, fn)
    spent["other (features, windows, Python glue)"] = total - sum(spent.values())
    spent["total"] = total
    return spent


def walk_rate(tmp: Path, seconds: int = 300) -> dict:
    """The receiver on a simulated walk (site seed 3, walk seed 7, ``seconds`` long, made with the CLI): best of 3
    wall and × real time, scipy's ``oaconvolve`` with the same 10 ms kernel over the same audio (best of 3, timed
    between the receiver's runs), the ratio of the two, the per-stage breakdown, fixes and their error."""
    from features.acoustic.positions import PositionConfig
    from features.site import load_site
    from pipeline.cli import main as cli_main
    from features.acoustic.timing import timing_from_walk
    from features.walk import load_walk

    site_dir, walk = tmp / "site3", tmp / "walk7"
    quiet = open(os.devnull, "w")
    old = sys.stdout
    sys.stdout = quiet
    try:
        cli_main(["simulate", "site", "--seed", "3", "--out", str(site_dir)])
        cli_main(["simulate", "walk", str(site_dir), "--seed", "7", "--duration", str(seconds), "--out", str(walk)])
    finally:
        sys.stdout = old
        quiet.close()
    site = load_site(site_dir)
    timing = timing_from_walk(load_walk(walk), site)
    positions = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05, motion_speed_m_s=1.4)

    def run():
        return analyse_audio(walk / "audio.wav", site, timing, DetectorConfig(), positions=positions)

    res = run()                                            # first run: compiled kernels loaded, caches warm
    walls, yard, cpus, yard_cpu = [], [], [], []
    x, _ = sf.read(str(walk / "audio.wav"), dtype="float32")
    h = MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], FS).kernels[0].astype(np.float32)
    for _ in range(3):
        t0, c0 = time.perf_counter(), time.process_time()
        res = run()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        t0, c0 = time.perf_counter(), time.process_time()
        scipy.signal.oaconvolve(x, h)
        yard.append(time.perf_counter() - t0)
        yard_cpu.append(time.process_time() - c0)
    stages = stage_breakdown(run)
    truth = np.genfromtxt(walk / "truth.csv", delimiter=",", names=True, dtype=None, encoding=None)
    t = np.array([f.t_s for f in res.fixes])
    err = np.hypot(np.array([f.east_m for f in res.fixes]) - np.interp(t, truth["t_s"], truth["east_m"]),
                   np.array([f.north_m for f in res.fixes]) - np.interp(t, truth["t_s"], truth["north_m"]))
    n_frames = int(round(res.duration_s / site.acoustic.frame_s))
    return {"audio_s": res.duration_s, "wall_s": min(walls), "oaconvolve_s": min(yard), "cpu_s": min(cpus),
            "oaconvolve_cpu_s": min(yard_cpu), "stages": stages,
            "fixes": len(res.fixes), "frames": n_frames, "median_m": float(np.median(err)),
            "p95_m": float(np.percentile(err, 95)), "max_m": float(err.max())}


def print_walk(w: dict) -> None:
    """Print :func:`walk_rate`'s figures."""
    rx, yard = w["audio_s"] / w["wall_s"], w["audio_s"] / w["oaconvolve_s"]
    print(f"\nsimulated walk (site 3, walk 7), best of 3: {w['audio_s']:.0f} s audio in {w['wall_s']:.2f} s = "
          f"{rx:,.0f}x real time; oaconvolve with the same 10 ms kernel over the same audio, best of 3: "
          f"{yard:,.0f}x; receiver / yardstick = {rx / yard:.3f}")
    rx_cpu, yard_cpu = w["audio_s"] / w["cpu_s"], w["audio_s"] / w["oaconvolve_cpu_s"]
    print(f"  by CPU time (process_time, best of 3; the fairer clock on a shared machine): receiver {rx_cpu:,.0f}x, "
          f"oaconvolve {yard_cpu:,.0f}x, receiver / yardstick = {rx_cpu / yard_cpu:.3f}")
    print(f"  {w['fixes']} fixes of {w['frames']} frames, error median {w['median_m']:.2f} m, p95 {w['p95_m']:.2f} m, "
          f"max {w['max_m']:.2f} m")
    st = w["stages"]
    print(f"  per stage (CPU s of one run, exclusive; total {st['total']:.2f} s):")
    for name, sec in st.items():
        if name != "total":
            print(f"    {name:40s} {sec:7.3f} s {100 * sec / st['total']:5.1f} %  "
                  f"({w['audio_s'] / max(sec, 1e-9):,.0f}x real time)")


def main() -> None:
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        child(sys.argv[2])
        return
    print(f"machine check: 1,000 iterations of a Python float loop take {python_loop_us():.0f} us "
          "(63-86 us seen on the 2-core test machine; timings there vary by up to 40 % from minute to minute)\n")
    walk_only = "--walk-only" in sys.argv[1:]         # the simulated walk's figures alone (issue 25 before/after)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if walk_only:
            print_walk(walk_rate(tmp))
            return
        files = {}
        for minutes in (1, 5, 10):
            files[minutes] = tmp / f"rec_{minutes}min.wav"
            write_recording(files[minutes], minutes)
        print("matched filter alone, 1-min file, one core (x real time):")
        mf_rates = matched_filter_rates(files[1])
        for name, rate in mf_rates.items():
            print(f"  {name:48s} {rate:8.0f}x")
        print_walk(walk_rate(tmp))
        print("\nfull receiver (read, matched filter, detection, CIR features, positions), one core, "
              "static receiver, 8 beacons;\neach file in a fresh process: the first run, then the best of 6:")
        print(f"  {'file':>8s} {'audio s':>8s} {'first x':>8s} {'best s':>8s} {'best x':>8s} {'windows':>8s} "
              f"{'fixes':>6s} {'peak RSS MiB':>13s} {'peak allocated MiB':>19s}")
        refs = {}
        for minutes, path in files.items():
            run = subprocess.run([sys.executable, __file__, "--child", str(path)], capture_output=True, text=True,
                                 check=True)
            r = json.loads(run.stdout.strip().splitlines()[-1])
            refs[minutes] = (r["paired_x"], r["correlate_x"], r["oaconvolve_x"])
            print(f"  {minutes:>5d}min {r['audio_s']:8.0f} {r['audio_s'] / r['first_wall_s']:8.0f} {r['wall_s']:8.2f} "
                  f"{r['audio_s'] / r['wall_s']:8.0f} {r['rows']:8d} {r['fixes']:6d} {r['peak_mib']:13.1f} "
                  f"{r['traced_mib']:19.1f}")
        # The target (issue 4) is 1,000x on the day scipy's correlate(method="fft") ran at ~600x and
        # oaconvolve at ~2,400x: against them, timed in the same process between the receiver's
        # runs, the comparison holds whatever the machine's speed that minute.
        print("\nagainst the yardsticks the issue quotes, timed between the receiver's runs (first 60 s of each file):")
        print(f"  {'file':>8s} {'receiver x':>11s} {'correlate x':>12s} {'oaconvolve x':>13s} "
              f"{'scaled to correlate 600x':>25s} {'scaled to oaconvolve 2400x':>27s}")
        for minutes, (rx, corr, oac) in refs.items():
            print(f"  {minutes:>5d}min {rx:11.0f} {corr:12.0f} {oac:13.0f} {rx * 600 / corr:25.0f} "
                  f"{rx * 2400 / oac:27.0f}")

if __name__ == "__main__":
    main()
