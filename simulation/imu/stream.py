"""The IMU stream of a walk: ``imu.csv`` (100 Hz) and ``truth_steps.csv``.

Writer for :data:`simulation.streams.STREAM_WRITERS`. Survey cells (static
GNSS + audio captures) get no IMU: the writer returns ``{}`` for them.

Random draws: the person's gait from ``stream_rng(person_seed, "person")``
(:func:`simulation.imu.walker.person_gait`), step timing from
``stream_rng(seed, "imu", "steps")``, per-step pelvis-excursion variability,
the device's mounting (tilt, yaw offset) and sensor errors from
``stream_rng(seed, "imu", "sensor")``. ``truth_steps.csv`` lists heel strikes,
the event the step detector reports.

``walk.toml`` gets ``[imu] file, rate_hz, body_frame = "FRD", declination_deg``:
the declination is stated as a logger would state the WMM value for the
site — off the simulated local field by ±0.5–1° (:func:`stated_declination_error_deg`),
so PDR turns magnetic into true heading as well as a real crew could, without peeking at the
simulator.
"""

from __future__ import annotations

import math

import numpy as np

from features.fileio import atomic_write_text

from simulation.imu.walker import ImuSamples, SensorErrors, StepTruth, person_gait, place_steps, synthesise_imu
from simulation.imu.magnetic import earth_field_ned_ut, field_elements
from simulation.rng import stream_rng
from simulation.streams import StreamContext, Trajectory

__all__ = ["write_imu", "simulate_imu", "imu_csv_text", "truth_steps_csv_text", "IMU_FILE", "TRUTH_STEPS_FILE",
           "IMU_RATE_HZ"]

IMU_FILE = "imu.csv"
TRUTH_STEPS_FILE = "truth_steps.csv"
IMU_RATE_HZ = 100.0


def _resample(traj: Trajectory, rate_hz: float) -> Trajectory:
    """The trajectory at ``rate_hz`` (linear interpolation; heading unwrapped first)."""
    if abs(traj.rate_hz - rate_hz) < 1e-9:
        return traj
    t = np.arange(traj.t_s[0], traj.t_s[-1] + 1e-9, 1.0 / rate_hz)
    e, n, u = traj.interp(t)
    h = np.mod(np.interp(t, traj.t_s, np.unwrap(traj.heading_rad)), 2 * np.pi)
    v = np.interp(t, traj.t_s, traj.speed_m_s)
    return Trajectory(t, e, n, u, h, v, traj.start_utc, rate_hz)


def simulate_imu(ctx: StreamContext, errors: SensorErrors = SensorErrors()) -> tuple[ImuSamples, StepTruth]:
    """IMU samples and true steps for the context's walk (no files)."""
    traj = _resample(ctx.trajectory, IMU_RATE_HZ)
    gait = person_gait(ctx.person_seed)
    steps, count = place_steps(traj, gait, stream_rng(ctx.seed, "imu", "steps"))
    imu = synthesise_imu(traj, ctx.site, gait, steps, count, stream_rng(ctx.seed, "imu", "sensor"), errors)
    return imu, steps


def csv_rows(data: np.ndarray, fmt: list[str], block_rows: int = 4096) -> str:
    """The rows of ``data`` (n, k) as ``numpy.savetxt(buf, data, delimiter=",", fmt=fmt)`` writes them (each
    value %-formatted, a newline after each row), formatted a block of rows per ``%`` operation instead of one
    Python call per row; a block's text and its values as Python floats are what memory holds at once."""
    if data.ndim != 2 or data.shape[1] != len(fmt):
        raise ValueError(f"csv_rows: {len(fmt)} formats for data of shape {data.shape}")
    line = ",".join(fmt) + "\n"
    out = []
    for i in range(0, data.shape[0], block_rows):
        block = data[i:i + block_rows]
        out.append((line * block.shape[0]) % tuple(block.ravel().tolist()))
    return "".join(out)


def imu_csv_text(imu: ImuSamples) -> str:
    """``t_s,ax,ay,az,gx,gy,gz,mx,my,mz`` rows (m/s², rad/s, µT)."""
    data = np.column_stack([imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut])
    return "t_s,ax,ay,az,gx,gy,gz,mx,my,mz\n" + csv_rows(data, ["%.2f"] + ["%.5f"] * 3 + ["%.6f"] * 3 + ["%.3f"] * 3)


def truth_steps_csv_text(steps: StepTruth) -> str:
    """``t_s,step_length_m,heading_rad`` rows (heel strikes; heading of the step's displacement)."""
    return "t_s,step_length_m,heading_rad\n" + csv_rows(
        np.column_stack([steps.t_s, steps.step_length_m, steps.heading_rad]), ["%.3f", "%.4f", "%.5f"])


def write_imu(ctx: StreamContext) -> dict:
    """Write ``imu.csv`` and ``truth_steps.csv`` for a walk; nothing for a survey cell."""
    if ctx.kind == "survey":
        return {}
    imu, steps = simulate_imu(ctx)
    atomic_write_text(ctx.out_dir / IMU_FILE, imu_csv_text(imu))
    atomic_write_text(ctx.out_dir / TRUTH_STEPS_FILE, truth_steps_csv_text(steps))
    declination_rad, _, _ = field_elements(earth_field_ned_ut(ctx.site.origin.lat_deg, ctx.site.origin.lon_deg))
    return {"imu": {"file": IMU_FILE, "rate_hz": IMU_RATE_HZ, "body_frame": "FRD",
                    "declination_deg": round(math.degrees(declination_rad) + stated_declination_error_deg(ctx.seed),
                                             3)}}


def stated_declination_error_deg(seed: int, low_deg: float = 0.5, high_deg: float = 1.0) -> float:
    """Error of the declination a logger states, degrees: ±U(0.5, 1.0)°.

    The logger takes the declination from a global model (WMM/IGRF) for the
    site's coordinates; the local field of a substation's soil, rebar and
    buried steel departs from it by crustal anomalies of the order of a
    degree (the WMM's stated declination uncertainty is about 0.4° globally,
    larger at crustal anomalies; Chulliat et al. 2020, *The US/UK World
    Magnetic Model for 2020–2025*, NOAA technical report, Table 18).
    """
    rng = stream_rng(seed, "imu", "declination")
    return float(rng.choice([-1.0, 1.0]) * rng.uniform(low_deg, high_deg))
