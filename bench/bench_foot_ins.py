"""Foot-mounted INS on the x-io Gait-Tracking walks: loop-closure error and stride count beside the published
figures (issue 26, "Must show").

The two walks (../shared/data/imu/xio_gait_tracking, NGIMU at the foot, 400 Hz) are closed loops: the foot
ends where it started, so the final position's distance from the first is the error. x-io's own method
(their Fusion AHRS, a threshold on the Earth-frame acceleration for "moving", and — offline — a linear
velocity-drift removal over every moving period) reaches 82 mm (short, ~25 m) and 421 mm (long, ~60 m),
the 3-D final displacement. Ours is causal: the 15-state ZUPT error-state filter of
:func:`models.foot.ins.run_foot_ins`, with no look-ahead.

Strides by hand: the gyro magnitude of each walk plotted in three panels (0.5 s grid) and the swing
bursts counted by eye — a swing is one burst of |ω| from ≈ 0.3 to 8–11 rad/s and back below 1 rad/s;
the double peaks of a last step bringing the foot alongside count once: short walk 5 + 6 + 5 = 16 strides
(15.7 s to 33.5 s), long walk 12 + 13 + 12 = 37 (12.4 s to 55.8 s). The detector's count must agree.

The stance threshold: γ = 1·10⁵ for the NGIMU (:data:`XIO_STANCE`); OpenShoe's 3·10⁴ was set for its
820 Hz MIMU22BT and misses some stances here (35 of 37 strides on the long walk) — printed beside it.

Run: ``.venv/bin/python bench/bench_foot_ins.py`` (prints a table; no assertions).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from features.imu.foot import read_xio_gait_csv
from models.foot.ins import FootInsConfig, run_foot_ins
from models.foot.stance import StanceConfig

_REPO = Path(__file__).resolve().parents[1]
_ROOTS = [Path(os.environ["ENVFUSE_SHARED_DATA"])] if os.environ.get("ENVFUSE_SHARED_DATA") else []
_ROOTS += [_REPO.parent / "shared" / "data", _REPO.parent.parent / "shared" / "data"]   # beside the repo / a worktree
DATA = next((r for r in _ROOTS if r.is_dir()), _ROOTS[0]) / "imu" / "xio_gait_tracking"
PUBLISHED_MM = {"short_walk": 82.0, "long_walk": 421.0}
HAND_STRIDES = {"short_walk": 16, "long_walk": 37}
XIO_STANCE = StanceConfig(gamma=1e5)
"""The SHOE threshold for the NGIMU (module docstring); σ's and window are OpenShoe's."""


def loop_closure(name: str, cfg: FootInsConfig, root: Path = DATA) -> dict:
    """Run one walk: {'error_mm' (3-D), 'horizontal_mm', 'vertical_mm', 'strides', 'path_m', 'seconds'}."""
    imu = read_xio_gait_csv(root / f"{name}.csv")
    t0 = time.perf_counter()
    run = run_foot_ins(imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, None, cfg)
    dt = time.perf_counter() - t0
    d = run.pos_m[-1] - run.pos_m[0]
    step = np.linalg.norm(np.diff(run.pos_m[:, :2], axis=0), axis=1)
    return {"error_mm": 1000 * float(np.linalg.norm(d)), "horizontal_mm": 1000 * float(np.linalg.norm(d[:2])),
            "vertical_mm": 1000 * float(d[2]), "strides": run.strides, "path_m": float(step.sum()),
            "seconds": dt, "record_s": float(imu.t_s[-1] - imu.t_s[0])}


def main(root: Path = DATA) -> int:
    if not root.is_dir():
        print(f"x-io data not found at {root}", file=sys.stderr)
        return 1
    # compile once (numba caches to disk; the first call in a fresh environment compiles)
    loop_closure("short_walk", FootInsConfig(stance=XIO_STANCE), root)
    print(f"{'walk':11s} {'gamma':>7s} {'3-D mm':>7s} {'horiz mm':>8s} {'vert mm':>8s} {'published':>9s} "
          f"{'ratio':>6s} {'strides':>7s} {'by hand':>7s} {'path m':>7s} {'x real time':>11s}")
    for name in ("short_walk", "long_walk"):
        for gamma in (XIO_STANCE.gamma, StanceConfig().gamma):
            r = loop_closure(name, FootInsConfig(stance=StanceConfig(gamma=gamma)), root)
            print(f"{name:11s} {gamma:7.0e} {r['error_mm']:7.0f} {r['horizontal_mm']:8.0f} {r['vertical_mm']:8.0f} "
                  f"{PUBLISHED_MM[name]:9.0f} {r['error_mm'] / PUBLISHED_MM[name]:6.1f} {r['strides']:7d} "
                  f"{HAND_STRIDES[name]:7d} {r['path_m']:7.1f} {r['record_s'] / r['seconds']:11.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
