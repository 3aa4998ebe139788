"""Speed and accuracy of the PDR path (issue 5), on one core.

Speed: a simulated 30-min waist walk (100 Hz, accelerometer + gyro +
magnetometer) written as ``imu.csv``, then

* ``read``: :func:`features.imu.read_imu_csv` (parse + repair + resample),
* ``pdr``: :func:`features.pdr.run_pdr` (step detection, step length,
  heading filter, track) on the repaired samples,
* ``whole``: both, the path ``envfuse features imu`` runs,

as IMU samples per second and multiples of real time (target ≥ 2,000×), plus
the per-sample cost of the heading filters: ours (linear Mahony yaw filter as
IIR), imufusion (compiled C, one Python call per sample) and ahrs' Mahony
(pure Python loop).

Accuracy (the issue's Must-show figures):

* Oxford step-counter walks: our count, the truth, the published algorithm's count;
* simulated walks of one person on site 3: step count error, distance error
  with K calibrated on a different walk (Weinberg and the improved model,
  the latter fitted on 30-s segments of the calibration walk as GNSS would
  give), PDR-only horizontal error (mean and final, % of distance walked);
* heading RMS near steel (disturbance > 2 µT) on 15-min walks: complementary,
  gyro-only, magnetometer-only, imufusion.

Usage: ``.venv/bin/python bench/bench_pdr.py [--repeat 3] [--quick]``
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from features.heading import HeadingConfig, estimate_heading, imufusion_heading, wrap_pi  # noqa: E402
from features.imu import read_imu_csv, repair_imu  # noqa: E402
from features.pdr import PdrConfig, run_pdr  # noqa: E402
from features.steps import StepLengthModel, calibrate_weinberg_k, detect_steps, fit_improved_model  # noqa: E402
from simulation.imu_stream import imu_csv_text, simulate_imu  # noqa: E402
from simulation.layout import generate_site  # noqa: E402
from simulation.magnetic import earth_field_ned_ut, field_elements  # noqa: E402
from simulation.rng import stream_rng  # noqa: E402
from simulation.route import plan_route, route_trajectory  # noqa: E402
from simulation.streams import StreamContext  # noqa: E402

OXFORD = ROOT.parent / "shared" / "data" / "imu" / "oxford_step_counter"
PERSON = 5


def _best_of(repeat: int, fn) -> float:
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _walk(site, seed, duration_s):
    poly, stops, speed = plan_route(site, stream_rng(seed, "route"), duration_s)
    traj = route_trajectory(poly, stops, speed, duration_s, datetime(2026, 6, 1, tzinfo=timezone.utc),
                            site.device_height_m)
    ctx = StreamContext(site=site, trajectory=traj, out_dir=Path("."), seed=seed, kind="walk", person_seed=PERSON)
    imu, truth = simulate_imu(ctx)
    return traj, imu, truth


def _heading_config(site):
    decl, _, _ = field_elements(earth_field_ned_ut(site.origin.lat_deg, site.origin.lon_deg))
    return HeadingConfig(declination_rad=decl)


def speed(repeat: int, minutes: float) -> None:
    site = generate_site(1)
    traj, imu, _ = _walk(site, 101, minutes * 60.0)
    n = len(imu.t_s)
    config = PdrConfig(heading=_heading_config(site))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "imu.csv"
        path.write_text(imu_csv_text(imu))
        data = read_imu_csv(path)
        t_read = _best_of(repeat, lambda: read_imu_csv(path))
        t_pdr = _best_of(repeat, lambda: run_pdr(data, config=config))
        t_whole = _best_of(repeat, lambda: run_pdr(read_imu_csv(path), config=config))
    print(f"speed ({minutes:g}-min walk, {n} samples at 100 Hz, one thread, best of {repeat}):")
    for name, t in (("read+repair", t_read), ("pdr (steps, length, heading, track)", t_pdr), ("whole path", t_whole)):
        print(f"  {name:38s} {t * 1e3:8.1f} ms  {n / t:12,.0f} samples/s  {n / t / 100.0:8,.0f}x real time")
    m = 3000
    cfg = _heading_config(site)
    t_ours = _best_of(repeat, lambda: estimate_heading(imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut, 100.0, cfg))
    t_fusion = _best_of(1, lambda: imufusion_heading(imu.acc_m_s2[:m], imu.gyro_rad_s[:m], imu.mag_ut[:m], 100.0))
    print(f"  heading per sample: ours {t_ours / n * 1e6:.3f} µs (whole heading path incl. tilt, gates), "
          f"imufusion {t_fusion / m * 1e6:.2f} µs", end="")
    try:
        from ahrs.filters import Mahony

        t_ahrs = _best_of(1, lambda: Mahony(gyr=imu.gyro_rad_s[:m], acc=-imu.acc_m_s2[:m], mag=imu.mag_ut[:m],
                                            frequency=100.0))
        print(f", ahrs.Mahony {t_ahrs / m * 1e6:.1f} µs")
    except ImportError:
        print()


def oxford() -> None:
    if not OXFORD.is_dir():
        print(f"oxford: {OXFORD} absent, skipped")
        return
    print("Oxford step counter (user 1): ours / truth / published algorithm (error %)")
    for f in sorted(OXFORD.glob("user1_*.csv")):
        raw = np.loadtxt(f, delimiter=",")
        imu = repair_imu(raw[:, 0] * 1e-9, raw[:, 1:4])
        ours = len(detect_steps(imu.acc_m_s2, imu.rate_hz, imu.t_s, imu.valid))
        truth, pub = int(raw[-1, 5]), int(raw[-1, 4])
        print(f"  {f.name.split('_')[1]:12s} {ours:4d} / {truth:4d} / {pub:4d}   "
              f"ours {100 * (ours - truth) / truth:+5.1f} %   published {100 * (pub - truth) / truth:+5.1f} %")


def simulated(quick: bool) -> None:
    site = generate_site(3)
    hcfg = _heading_config(site)
    # calibration walk (seed 21): Weinberg K from its length; improved (K, β) from 30-s segments
    _, imu_c, truth_c = _walk(site, 21, 300.0)
    cal = run_pdr(repair_imu(imu_c.t_s, imu_c.acc_m_s2, imu_c.gyro_rad_s, imu_c.mag_ut),
                  config=PdrConfig(heading=hcfg))
    k = calibrate_weinberg_k(cal.steps, float(truth_c.step_length_m.sum()))
    seg = np.floor(cal.t_s / 30.0).astype(int)
    cum = np.r_[0.0, np.cumsum(truth_c.step_length_m)]
    edges = np.arange(0, seg.max() + 2) * 30.0
    seg_dist = np.diff(np.interp(edges, truth_c.t_s, cum[1:]))
    improved = fit_improved_model(cal.steps, seg, seg_dist)
    forced = fit_improved_model(cal.steps, seg, seg_dist, select=False)
    print(f"simulated, person {PERSON}, site 3: K calibrated on walk 21 = {k:.4f} (true "
          f"{__import__('simulation.imu_walker', fromlist=['person_gait']).person_gait(PERSON).weinberg_k:.4f}); "
          f"improved model fitted on 30-s segments K = {forced.k:.4f}, β = {forced.beta:.5f}; "
          f"kept after leave-one-segment-out selection: K = {improved.k:.4f}, β = {improved.beta:.5f}")
    seeds = (22, 23) if quick else (22, 23, 24, 25, 26)
    print("  walk  steps true/det  count %  dist % (Weinberg / improved forced / selected)  PDR error mean / final (% of distance)")
    for seed in seeds:
        traj, imu, truth = _walk(site, seed, 300.0)
        data = repair_imu(imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut)
        res = run_pdr(data, traj.east_m[0], traj.north_m[0], PdrConfig(length=StepLengthModel(k=k), heading=hcfg))
        res_i = run_pdr(data, traj.east_m[0], traj.north_m[0], PdrConfig(length=forced, heading=hcfg))
        res_s = run_pdr(data, traj.east_m[0], traj.north_m[0], PdrConfig(length=improved, heading=hcfg))
        dist = float(truth.step_length_m.sum())
        err = np.hypot(res.east_m - np.interp(res.t_s, traj.t_s, traj.east_m),
                       res.north_m - np.interp(res.t_s, traj.t_s, traj.north_m))
        walked = np.interp(res.t_s, truth.t_s, np.cumsum(truth.step_length_m))
        print(f"  {seed:4d}  {len(truth.t_s):5d}/{len(res):5d}  {100 * (len(res) - len(truth.t_s)) / len(truth.t_s):+6.2f}"
              f"   {100 * (res.distance_m - dist) / dist:+6.2f} / {100 * (res_i.distance_m - dist) / dist:+6.2f}"
              f" / {100 * (res_s.distance_m - dist) / dist:+6.2f}"
              f"              {100 * err.mean() / dist:5.2f} / {100 * err[-1] / dist:5.2f}"
              f"   (final {err[-1]:.1f} m of {dist:.0f} m; max ratio err/walked after 50 m "
              f"{100 * np.max(err[walked > 50] / walked[walked > 50]):.1f} %)")
    print("  heading RMS near steel (> 2 µT), 15-min walks, deg: complementary / gyro-only / magnetometer-only / imufusion")
    for seed in ((21,) if quick else (21, 22)):
        traj, imu, _ = _walk(site, seed, 900.0)
        h = estimate_heading(imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut, 100.0, hcfg)
        near = imu.mag_disturbance_ut > 2.0
        fusion = imufusion_heading(imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut, 100.0, hcfg.declination_rad)

        def rms(x):
            return math.degrees(float(np.sqrt(np.mean(wrap_pi(x - traj.heading_rad)[near] ** 2))))

        print(f"  walk {seed}: {rms(h.fused):.2f} / {rms(h.gyro_only):.2f} / {rms(h.mag_only):.2f} / {rms(fusion):.2f}"
              f"   (near steel {100 * near.mean():.0f} % of samples; over the whole walk "
              f"{rms_all(h.fused, traj):.2f} / {rms_all(h.gyro_only, traj):.2f} / {rms_all(h.mag_only, traj):.2f})")


def rms_all(x, traj) -> float:
    return math.degrees(float(np.sqrt(np.mean(wrap_pi(x - traj.heading_rad) ** 2))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--quick", action="store_true", help="fewer simulated walks")
    ap.add_argument("--speed-only", action="store_true", help="only the speed figures")
    args = ap.parse_args()
    speed(args.repeat, args.minutes)
    if not args.speed_only:
        oxford()
        simulated(args.quick)


if __name__ == "__main__":
    main()
