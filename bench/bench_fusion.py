"""Fusion filter speed: PDR steps (and events) per wall second for each method on a 10-minute walk, one core.

The walk is synthetic (``tests/fusion_synth.py``, seed 1: 1.8 steps/s, GNSS
at 5 Hz, acoustic fixes every 0.8 s frame — the device rates of docs/design.md §4
— so about 3.5 fixes per step: 1,080 steps and ~4,800 events in all), and the
same walk again with GNSS at 1 Hz to show how the rate of fixes, not of
steps, sets the cost. Each method is timed best-of-``REPEATS`` because this
shared 2-core machine's speed drifts from minute to minute; a Python float
loop is timed first as a gauge, and a fixed ``scipy.signal.oaconvolve``
(480,000 samples × 480 taps, float32) is timed between the methods'
runs so that the ratio method/yardstick is comparable across days and
machines (the pattern of bench/bench_audio.py).

Methods (walks.methods names), all on the one compiled core of
models/fusion/core.py: ``kf``, ``kf_quality``, ``kf_map`` (a gridded site
map looked up at every fix), ``adaptive_nobp`` (per-class noise from a class
track; also with the short covariance update ``joseph=False``), ``huber``,
``aekf`` (VB-AKF with 3 variational iterations), the 6-state filter with the
GNSS bias, ``imm`` (3 modes) and the RTS smoother of a ``kf`` run. The first
call of each compiled function pays numba's compilation (or its cache load);
the best-of-N timing excludes it.

Run: ``.venv/bin/python bench/bench_fusion.py`` (prints a table; no assertions).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"          # one core, set before numpy loads

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import scipy.signal

from models.fusion import (ClassMap, ClassTrack, ContextNoise, EkfConfig, EventEKF, FixedNoise, IMMFilter,
                           PerClassNoise, QualityNoise, VBAdaptiveNoise, fixed_lag_smooth, rts_smooth)
from models.fusion.context import ErrorSeries
from tests.fusion_synth import synth_walk

REPEATS = 9


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


_RNG = np.random.default_rng(0)
_X = _RNG.standard_normal(480_000).astype(np.float32)
_H = _RNG.standard_normal(480).astype(np.float32)


def yardstick_s() -> float:
    """Wall seconds of one fixed oaconvolve (480,000 × 480, float32)."""
    t0 = time.perf_counter()
    scipy.signal.oaconvolve(_X, _H)
    return time.perf_counter() - t0


def context_model(n_classes: int) -> ContextNoise:
    """A context error model fitted on another synthetic walk (float fixes with a correlated bias)."""
    s = synth_walk(2, duration_s=600.0, gnss_hz=5.0, acoustic_hz=1.25, bias_sigma_m=0.4, bias_tau_s=30.0,
                   gnss_quality=lambda t: np.where((np.asarray(t) // 60) % 2 == 0, 5, 4))
    ev = s.stream
    out = []
    for code in (1, 2):
        sel = ev.kind == code
        q = s.gnss.quality[ev.index[sel]] if code == 1 else np.zeros(sel.sum(), int)
        out.append([ErrorSeries(ev.t_s[sel], ev.z_m[sel] - s.truth[sel, :2], ev.cov_m2[sel], q,
                                (ev.t_s[sel] // 100).astype(int) % n_classes)])
    return ContextNoise(n_classes=n_classes, min_samples=50).fit(*out)


def methods(stream):
    pc = PerClassNoise(3, 1.5, 0.3).fit()
    pc.R_gnss_ = np.array([np.eye(2) * 1.5 ** 2, np.eye(2) * 3.0 ** 2, np.eye(2) * 6.0 ** 2])
    t = np.arange(0.0, stream.t_s[-1] + 1.0, 1.0)
    proba = np.stack([0.6 + 0.3 * np.sin(t / 50), 0.3 - 0.2 * np.sin(t / 50), np.full(t.size, 0.1)], axis=1)
    classes = ClassTrack(t, proba)
    # a site map: class 1 west of east = 0, class 0 east of it, on a 2 m grid
    east = np.arange(-400.0, 400.0, 2.0)
    class_at = ClassMap.from_axes(east, np.arange(-400.0, 400.0, 2.0), np.tile((east > 0).astype(int) ^ 1, (400, 1)))
    ctx3, ctx1 = CONTEXT[3], CONTEXT[1]
    return [
        ("kf", lambda: EventEKF(noise=FixedNoise(1.5, 0.3)).run(stream)),
        ("kf_quality", lambda: EventEKF(noise=QualityNoise()).run(stream)),
        ("kf_map", lambda: EventEKF(noise=pc).run(stream, class_at=class_at)),
        ("adaptive_nobp (per class)", lambda: EventEKF(noise=pc).run(stream, classes=classes)),
        ("adaptive_nobp, short form", lambda: EventEKF(EkfConfig(joseph=False), pc).run(stream, classes=classes)),
        ("huber", lambda: EventEKF(EkfConfig(outlier="huber"), FixedNoise(1.5, 0.3)).run(stream)),
        ("aekf VB-AKF", lambda: EventEKF(noise=VBAdaptiveNoise(1.5, 0.3)).run(stream)),
        ("kf + GNSS bias (6 states)", lambda: EventEKF(EkfConfig(gnss_bias=True), FixedNoise(1.5, 0.3)).run(stream)),
        ("imm (3 modes)", lambda: IMMFilter(pc).run(stream, classes=classes)),
        ("adaptive_nobp (context)", lambda: EventEKF(EkfConfig(outlier="mixture"), ctx3).run(stream, classes=classes)),
        ("adaptive_nobp_blind", lambda: EventEKF(EkfConfig(outlier="mixture"), ctx1).run(stream)),
    ]


def time_best(fn, repeats: int) -> tuple[float, float]:
    """(best wall s of ``fn``, best yardstick s timed between its runs)."""
    walls, yards = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        walls.append(time.perf_counter() - t0)
        yards.append(yardstick_s())
    time_best.last = out
    return min(walls), min(yards)


def bench(label: str, gnss_hz: float) -> None:
    s = synth_walk(1, duration_s=600.0, gnss_hz=gnss_hz, acoustic_hz=1.25)
    ev = s.stream
    n_steps, n_ev = ev.n_steps, len(ev)
    print(f"\n{label}: {ev.t_s[-1]:.0f} s walk, {n_steps} steps, {n_ev} events "
          f"({n_ev - n_steps} fixes, {(n_ev - n_steps) / n_steps:.1f} per step)")
    print(f"{'method':<28}{'wall ms':>9}{'steps/s':>10}{'events/s':>10}{'x real time':>12}{'/ yardstick':>12}")
    kf_run = None
    for name, fn in methods(ev):
        reps = REPEATS
        wall, yard = time_best(fn, reps)
        if name == "kf":
            kf_run = time_best.last
        print(f"{name:<28}{wall * 1e3:9.1f}{n_steps / wall:10.0f}{n_ev / wall:10.0f}{ev.t_s[-1] / wall:12.0f}"
              f"{wall / yard:12.2f}")
    for label2, fn in (("rts_smooth (of kf)", lambda: rts_smooth(kf_run)),
                       ("fixed-lag 3 s (of kf)", lambda: fixed_lag_smooth(kf_run, 3.0))):
        wall, yard = time_best(fn, REPEATS)
        print(f"{label2:<28}{wall * 1e3:9.1f}{n_steps / wall:10.0f}{n_ev / wall:10.0f}"
              f"{ev.t_s[-1] / wall:12.0f}{wall / yard:12.2f}")


CONTEXT: dict = {}


def main() -> None:
    CONTEXT.update({3: context_model(3), 1: context_model(1)})
    print(f"python float loop: {python_loop_us():.1f} µs per 1,000 iterations (machine gauge)")
    best_ms = min(yardstick_s() for _ in range(5)) * 1e3
    print(f"yardstick: scipy.signal.oaconvolve 480,000 x 480 float32, best {best_ms:.2f} ms")
    print("'/ yardstick' = method wall time over the yardstick's, both best-of-N from the same minutes")
    bench("GNSS 5 Hz + acoustic 1.25 Hz", 5.0)
    bench("GNSS 1 Hz + acoustic 1.25 Hz", 1.0)


if __name__ == "__main__":
    main()
