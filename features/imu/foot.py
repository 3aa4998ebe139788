"""Foot-mounted IMU records: ``imu_foot.csv`` of a walk, and the x-io Gait-Tracking CSV.

``imu_foot.csv`` has the columns of ``imu.csv`` (docs/design.md §4: ``t_s, ax, ay, az`` m/s², ``gx, gy, gz``
rad/s, ``mx, my, mz`` µT, body frame, gravity included) at the foot IMU's own rate (100–400 Hz); a foot INS
needs the gyro, so a file without it is refused. It goes through the same reader and repair as the waist
IMU (:func:`features.imu.reader.read_imu_csv`: one uniform time base, defects counted).

The x-io Gait-Tracking recordings (NGIMU, 400 Hz; ../shared/data/imu/xio_gait_tracking) have the columns
``Time (s), Gyroscope X/Y/Z (deg/s), Accelerometer X/Y/Z (g)``; :func:`read_xio_gait_csv` converts them to
SI and repairs them the same way (they hold repeated timestamps).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from features.errors import ImuError
from features.imu.reader import ACCEL_UNITS, ImuData, RepairConfig, read_imu_csv, repair_imu

__all__ = ["read_foot_imu", "read_xio_gait_csv", "FOOT_RATE_RANGE_HZ", "XIO_COLUMNS"]

FOOT_RATE_RANGE_HZ = (50.0, 2000.0)
"""Sample rates a foot INS accepts, Hz: below ~50 Hz a heel strike's shock and the swing's rotation are
aliased (foot-mounted systems run at 100–1000 Hz: OpenShoe 820 Hz, the seed paper's SBG Ellipse2-A 100 Hz)."""

XIO_COLUMNS = ("Time (s)", "Gyroscope X (deg/s)", "Gyroscope Y (deg/s)", "Gyroscope Z (deg/s)",
               "Accelerometer X (g)", "Accelerometer Y (g)", "Accelerometer Z (g)")
"""Header of an x-io Gait-Tracking CSV (NGIMU export)."""


def _check_foot(imu: ImuData, path: Path) -> ImuData:
    if imu.gyro_rad_s is None:
        raise ImuError(f"{path}: a foot-mounted IMU record needs the gyro columns gx, gy, gz")
    lo, hi = FOOT_RATE_RANGE_HZ
    if not lo <= imu.rate_hz <= hi:
        raise ImuError(f"{path}: sample rate {imu.rate_hz:.1f} Hz is outside the {lo:.0f}-{hi:.0f} Hz a foot INS "
                       "needs")
    return imu


def read_foot_imu(path: str | os.PathLike, config: RepairConfig = RepairConfig()) -> ImuData:
    """Read ``imu_foot.csv`` (SI units, as written by the simulator or a logger) into :class:`ImuData`."""
    return _check_foot(read_imu_csv(path, config, accel_unit="m/s2", gyro_unit="rad/s"), Path(path))


def read_xio_gait_csv(path: str | os.PathLike, config: RepairConfig = RepairConfig()) -> ImuData:
    """Read an x-io Gait-Tracking CSV (columns :data:`XIO_COLUMNS`; g and deg/s) into :class:`ImuData` (SI)."""
    path = Path(path)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            header = [h.strip() for h in fh.readline().split(",")]
            data = np.loadtxt(fh, delimiter=",", ndmin=2)
    except FileNotFoundError:
        raise ImuError(f"{path}: file not found") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ImuError(f"{path}: not a numeric x-io CSV ({exc})") from None
    if tuple(header[:7]) != XIO_COLUMNS:
        raise ImuError(f"{path}: expected the x-io header {', '.join(XIO_COLUMNS)}, got {', '.join(header[:7])}")
    if len(data) < 2 or data.shape[1] < 7:
        raise ImuError(f"{path}: fewer than 2 data rows of 7 columns")
    imu = repair_imu(data[:, 0], data[:, 4:7] * ACCEL_UNITS["g"], data[:, 1:4] * math.pi / 180.0, None, config=config)
    return _check_foot(imu, path)
