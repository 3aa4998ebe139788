"""Speed and accuracy of the PDR path (issue 5), on one core.

Speed: a simulated 30-min waist walk (100 Hz, accelerometer + gyro +
magnetometer) written as ``imu.csv``, then

* ``read``: :func:`features.imu.reader.read_imu_csv` (parse + repair + resample),
* ``pdr``: :func:`features.imu.pdr.run_pdr` (step detection, step length,
  heading filter, track) on the repaired samples,
* ``whole``: both, the path ``envfuse features imu`` runs,

as IMU samples per second and multiples of real time (target ≥ 2,000×), plus
the per-sample cost of the heading filters: ours (linear Mahony yaw filter as
IIR), imufusion (compiled C, one Python call per sample) and ahrs' Mahony
(pure Python loop).

Accuracy (the issue's Must-show figures):

* Oxford step-counter walks: our count, the truth, the published algorithm's count;
* simulated walks of one person on site 3, each written as imu.csv /
  truth_steps.csv and read back: step count error, median |Δt| to the true
  heel strikes, distance error with K calibrated on a different walk
  (Weinberg and the improved model, the latter fitted on 30-s segments of
  the calibration walk as GNSS would give), PDR-only horizontal error (mean
  and final, % of distance walked; mounting yaw offset uncorrected);
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

from features.imu.heading import HeadingConfig, estimate_heading, imufusion_heading, wrap_pi  # noqa: E402
from features.imu.reader import read_imu_csv, repair_imu  # noqa: E402
from features.imu.pdr import PdrConfig, run_pdr  # noqa: E402
from features.imu.steps import StepLengthModel, calibrate_weinberg_k, detect_steps, fit_improved_model  # noqa: E402
from simulation.imu.stream import imu_csv_text, simulate_imu  # noqa: E402
from simulation.site.layout import generate_site  # noqa: E402
from simulation.imu.magnetic import earth_field_ned_ut, field_elements  # noqa: E402
from simulation.rng import stream_rng  # noqa: E402
from simulation.site.route import plan_route, route_trajectory  # noqa: E402
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


def _file_walk(site, seed, duration_s, root: Path):
    """Simulate a walk, write imu.csv / truth_steps.csv, read them back as a user would."""
    from simulation.imu.stream import write_imu

    out = root / f"w{seed}_{int(duration_s)}"
    out.mkdir(parents=True, exist_ok=True)
    poly, stops, speed_m_s = plan_route(site, stream_rng(seed, "route"), duration_s)
    traj = route_trajectory(poly, stops, speed_m_s, duration_s, datetime(2026, 6, 1, tzinfo=timezone.utc),
                            site.device_height_m)
    ctx = StreamContext(site=site, trajectory=traj, out_dir=out, seed=seed, kind="walk", person_seed=PERSON)
    meta = write_imu(ctx)
    data = read_imu_csv(out / "imu.csv")
    truth = np.loadtxt(out / "truth_steps.csv", delimiter=",", skiprows=1, ndmin=2)
    hcfg = HeadingConfig(declination_rad=math.radians(meta["imu"]["declination_deg"]))
    return traj, data, truth, hcfg, speed_m_s


def simulated(quick: bool) -> None:
    from simulation.imu.magnetic import disturbance_ned_ut, site_steel_dipoles

    site = generate_site(3)
    tmp = tempfile.TemporaryDirectory()
    root = Path(tmp.name)
    # calibration walk (seed 21): Weinberg K from its length; improved (K, β) from its 30-s segments
    traj_c, data_c, truth_c, hcfg, speed_c = _file_walk(site, 21, 300.0, root)
    cal = run_pdr(data_c, config=PdrConfig(heading=hcfg))
    k = calibrate_weinberg_k(cal.steps, float(truth_c[:, 1].sum()))
    seg = np.floor(cal.t_s / 30.0).astype(int)
    cum = np.r_[0.0, np.cumsum(truth_c[:, 1])]
    edges = np.arange(0, seg.max() + 2) * 30.0
    seg_dist = np.diff(np.interp(edges, np.r_[0.0, truth_c[:, 0]], cum))
    improved = fit_improved_model(cal.steps, seg, seg_dist)
    forced = fit_improved_model(cal.steps, seg, seg_dist, select=False)
    print(f"simulated (through imu.csv), person {PERSON}, site 3: K calibrated on walk 21 ({speed_c:.2f} m/s) = "
          f"{k:.4f}; improved model fitted on 30-s segments K = {forced.k:.4f}, β = {forced.beta:.5f}; "
          f"after leave-one-segment-out selection: K = {improved.k:.4f}, β = {improved.beta:.5f}")
    seeds = (22, 23) if quick else (22, 23, 24, 25, 26)
    print("  walk  speed  steps true/det  count %  med|Δt| s  dist % (Weinberg / improved)  "
          "PDR error mean / final (% of distance)")
    for seed in seeds:
        traj, data, truth, hcfg, speed_m_s = _file_walk(site, seed, 300.0, root)
        res = run_pdr(data, traj.east_m[0], traj.north_m[0], PdrConfig(length=StepLengthModel(k=k), heading=hcfg))
        dist = float(truth[:, 1].sum())
        d_imp = float(forced.predict(res.steps).sum())
        err = np.hypot(res.east_m - np.interp(res.t_s, traj.t_s, traj.east_m),
                       res.north_m - np.interp(res.t_s, traj.t_s, traj.north_m))
        t_true = truth[:, 0]
        j = np.clip(np.searchsorted(t_true, res.t_s), 1, len(t_true) - 1)
        dt = np.minimum(np.abs(t_true[j] - res.t_s), np.abs(t_true[j - 1] - res.t_s))
        print(f"  {seed:4d}  {speed_m_s:5.2f}  {len(t_true):5d}/{len(res):5d}  "
              f"{100 * (len(res) - len(t_true)) / len(t_true):+6.2f}   {np.median(dt):7.3f}"
              f"   {100 * (res.distance_m - dist) / dist:+6.2f} / {100 * (d_imp - dist) / dist:+6.2f}"
              f"              {100 * err.mean() / dist:5.2f} / {100 * err[-1] / dist:5.2f}"
              f"   (final {err[-1]:.1f} m of {dist:.0f} m)")
    print("  heading RMS near steel (> 2 µT) vs walking direction, 15-min walks, deg: "
          "complementary / gyro-only / magnetometer-only / imufusion")
    dipoles = site_steel_dipoles(site)
    for seed in ((21,) if quick else (21, 22)):
        traj, data, _, hcfg, _ = _file_walk(site, seed, 900.0, root)
        h = estimate_heading(data.acc_m_s2, data.gyro_rad_s, data.mag_ut, data.rate_hz, hcfg)
        pos = np.stack([traj.north_m, traj.east_m, -np.asarray(traj.up_m)], axis=1)
        near_traj = np.linalg.norm(disturbance_ned_ut(dipoles, pos), axis=1) > 2.0
        near = np.interp(data.t_s, traj.t_s, near_traj.astype(float)) > 0.5
        truth_h = np.interp(data.t_s, traj.t_s, np.unwrap(traj.heading_rad))
        fusion = imufusion_heading(data.acc_m_s2, data.gyro_rad_s, data.mag_ut, data.rate_hz, hcfg.declination_rad)

        def rms(x, mask=near):
            return math.degrees(float(np.sqrt(np.mean(wrap_pi(x - truth_h)[mask] ** 2))))

        every = np.ones(len(near), bool)
        print(f"  walk {seed}: {rms(h.fused):.2f} / {rms(h.gyro_only):.2f} / {rms(h.mag_only):.2f} / {rms(fusion):.2f}"
              f"   (near steel {100 * near.mean():.0f} % of samples; over the whole walk "
              f"{rms(h.fused, every):.2f} / {rms(h.gyro_only, every):.2f} / {rms(h.mag_only, every):.2f})")
    tmp.cleanup()


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
