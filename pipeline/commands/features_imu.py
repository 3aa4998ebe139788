"""``envfuse features imu``: IMU CSV → one row per step (time, length, heading, PDR position)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

from features.errors import ConfigError, DataError
from pipeline.args import bounded, check_outputs, finite, positive
from pipeline.tables import csv_text, with_geodetic, with_time_utc

GROUP = "features"


def register(sub) -> None:
    p = sub.add_parser(
        "imu", help="steps, step lengths, heading and PDR track from an IMU CSV",
        description="Read imu.csv (t_s, ax, ay, az [, gx, gy, gz] [, mx, my, mz]), repair gaps, duplicates, "
                    "NaN and clipped samples (counts on stderr; t_s must be seconds, 10-2000 Hz), detect steps, estimate step length (Weinberg) "
                    "and heading (gyro + magnetometer complementary filter), and dead-reckon from the start "
                    "point. Accelerometer-only files give steps and lengths with empty heading/position.",
        epilog="Example: envfuse features imu walk7/imu.csv --start-east-m 12.5 --start-north-m 3.0 --k 0.48 "
               "--out steps.csv")
    p.add_argument("imu", type=Path, help="IMU CSV file")
    p.add_argument("--out", type=Path, required=True,
                   help="steps CSV: t_s (heel strike), step_length_m, heading_rad, east_m, north_m; - for stdout")
    p.add_argument("--start-east-m", "--start-east", dest="start_east", type=finite, default=0.0,
                   help="start east, m (default 0)")
    p.add_argument("--start-north-m", "--start-north", dest="start_north", type=finite, default=0.0,
                   help="start north, m (default 0)")
    p.add_argument("--k", type=bounded(0.05, 3.0), default=None,
                   help="Weinberg constant K, 0.05 to 3 (default 0.47; calibrate it)")
    p.add_argument("--accel-unit", choices=("auto", "m/s2", "g", "mg"), default="auto",
                   help="accelerometer unit (default auto: the unit in which the median |a| is gravity)")
    p.add_argument("--gyro-unit", choices=("auto", "rad/s", "deg/s"), default="auto",
                   help="gyro unit (default auto: deg/s when the 99th percentile of |w| exceeds 20, else rad/s)")
    p.add_argument("--declination-deg", type=bounded(-180.0, 180.0, "deg"), default=None,
                   help="magnetic declination, degrees east (default: [imu] declination_deg of walk.toml "
                        "beside the file, else 0)")
    p.add_argument("--calibrate-distance-m", type=positive, default=None,
                   help="the walk's known length, m: fit K to it and print it (overrides --k)")
    p.set_defaults(func=_run)


def _declination_deg(imu_path: Path, given: float | None) -> float:
    if given is not None:
        return given
    walk_toml = imu_path.parent / "walk.toml"
    if walk_toml.is_file():
        from features.fileio import read_toml

        imu_table = read_toml(walk_toml).get("imu", {})
        value = imu_table.get("declination_deg") if isinstance(imu_table, dict) else None
        if isinstance(value, (int, float)) and math.isfinite(value):
            if not -180.0 <= value <= 180.0:
                raise ConfigError(f"{walk_toml}: [imu] declination_deg must lie in [-180, 180], got {value}")
            return float(value)
    return 0.0


def _walk_beside(imu_path: Path):
    """The walk.toml beside the IMU file (its start time and site), or None."""
    if not (imu_path.parent / "walk.toml").is_file():
        return None
    from features.walk import load_walk

    return load_walk(imu_path.parent)


_STEP_FORMATS = {"t_s": ".3f", "step_length_m": ".4f", "heading_rad": ".5f", "east_m": ".3f", "north_m": ".3f"}


def _steps_table(imu_path: Path, result) -> str:
    """steps.csv: t_s, time_utc, step_length_m, heading_rad, east_m, north_m, lat_deg, lon_deg, h_ell_m
    (UTC and geodetic empty without a walk.toml beside the file naming its start and site)."""
    from features.errors import ConfigError

    walk = _walk_beside(imu_path)
    site = None
    if walk is not None and walk.site_ref is not None:
        try:
            site = walk.load_site()
        except ConfigError:
            site = None
    names = tuple(_STEP_FORMATS)
    cols = {"t_s": result.t_s, "step_length_m": result.step_length_m, "heading_rad": result.heading_rad,
            "east_m": result.east_m, "north_m": result.north_m}
    names, cols = with_time_utc(names, cols, None if walk is None else walk.start_utc)
    up = None if site is None else site.device_height_m
    names, cols = with_geodetic(names, cols, None if site is None else site.origin, up_m=up)
    return csv_text(names, cols, _STEP_FORMATS)


def _run(args) -> int:
    from features.imu.heading import HeadingConfig
    from features.imu.reader import read_imu_csv
    from features.fileio import atomic_write_text
    from features.imu.pdr import PdrConfig, run_pdr
    from features.imu.steps import StepLengthModel, calibrate_weinberg_k

    check_outputs({"IMU": args.imu, "walk.toml beside it": args.imu.parent / "walk.toml"}, {"--out": args.out})
    imu = read_imu_csv(args.imu, accel_unit=args.accel_unit, gyro_unit=args.gyro_unit)
    heading = HeadingConfig(declination_rad=math.radians(_declination_deg(args.imu, args.declination_deg)))
    length = StepLengthModel() if args.k is None else StepLengthModel(k=args.k)
    config = PdrConfig(length=length, heading=heading)
    result = run_pdr(imu, args.start_east, args.start_north, config)
    if args.calibrate_distance_m is not None:
        try:
            k = calibrate_weinberg_k(result.steps, args.calibrate_distance_m)
        except DataError as exc:
            raise DataError(f"--calibrate-distance-m: {exc}") from None
        if not 0.05 <= k <= 3.0:
            raise DataError(f"--calibrate-distance-m {args.calibrate_distance_m:g} over {len(result.steps)} "
                            f"detected steps gives K = {k:.4g}, outside the plausible 0.05-3: check the distance")
        result = run_pdr(imu, args.start_east, args.start_north,
                         PdrConfig(length=StepLengthModel(k=k), heading=heading))
        print(f"K = {k:.4f} (Weinberg, from {args.calibrate_distance_m:g} m)")
    atomic_write_text(args.out, _steps_table(args.imu, result))
    repaired = f"; repaired: {imu.report.summary()}" if imu.report.n_defects else ""
    print(f"envfuse: {args.imu}: {imu.units}{repaired}", file=sys.stderr)
    if result.heading is None:
        print(f"envfuse: {args.imu}: no gyro/magnetometer columns: heading and positions left empty",
              file=sys.stderr)
    if len(result) == 0:
        print(f"envfuse: warning: {args.imu}: no steps detected in {imu.t_s[-1] - imu.t_s[0]:.1f} s "
              f"({imu.units}); if the person walked, check --accel-unit", file=sys.stderr)
    print(f"{len(result)} steps, {result.distance_m:.1f} m -> {args.out}")
    return 0
