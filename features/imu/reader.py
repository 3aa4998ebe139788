"""IMU CSV reader and repair: one uniform time base, every defect counted.

Format (docs/design.md §4): header line, columns ``t_s, ax, ay, az`` (m/s², body
frame, gravity included) required; ``gx, gy, gz`` (rad/s) and ``mx, my, mz``
(µT) optional, each triple all-or-none. Extra columns are ignored.

Repair (never an exception for a few bad samples; counts in
:class:`ImuRepairReport`):

- rows whose time is not a finite number are dropped, and so is an isolated
  time outlier: a row whose t_s departs from both file-order neighbours by
  more than ``max_gap_s`` while those neighbours agree with each other (a
  corrupted timestamp, e.g. 1e9 s inside a 100 Hz record), counted in
  ``n_bad_time``;
- the median sample interval must give a rate in [``min_rate_hz``,
  ``max_rate_hz``] (10-2000 Hz): t_s in milliseconds (100 Hz → 0.1 Hz) is
  rejected with one clear message rather than guessed at;
- a remaining gap is filled only up to ``max_fill_gap_s`` (600 s) or, if
  longer, as long as it fits ``max_fill_samples`` (360,000: an hour at 100 Hz,
  half an hour at 200 Hz); a longer one is rejected with one message naming it
  (split the file there), and so is a record whose gaps would make the uniform
  grid more than 10× the sample count (plus that allowance): the grid is never
  allocated per a corrupt time span. A filled gap (a logger paused over a
  break in a shift) is a hole on the grid, flagged not ``valid``: no step in
  it, and the walk's fusion takes it for no stop
  (:func:`walks.inputs._imu_holes`). Its samples cost memory, at most
  max(360,000, 600 s × rate) of them whatever the walk's length (the 600 s the
  reader always filled): 360,000 samples of 9 channels are 26 MB, and ``run``'s peak
  on a 1-hour walk paused 100-3,600 s was 382 MiB against 300 MiB unpaused (the
  cuts inside the hole each fill it). Until 2026-12-03 any gap past 600 s was
  rejected, and a break of eleven minutes cost a walk its PDR: on a 1,000 s
  walk of the benchmark site without IMU rows from 150 to 800 s, ``run``'s mean
  error before the hole 0.268 m without PDR, 0.046 m with it, as without the
  hole; after it 0.063 → 0.022 m (0.018 m without the hole);
- unsorted rows are sorted (stable); duplicated timestamps keep the first row;
- NaN / non-numeric channel values are interpolated from their neighbours;
- clipped samples — at or beyond the stated full scale, or in runs of ≥ 3
  equal samples at the channel's extreme — and absurd magnetometer values
  (beyond ``mag_full_scale_ut``) are treated like NaN: counted, replaced by
  interpolation from their unclipped neighbours *before* any filtering (a
  ±16 g spike would otherwise dominate the low-passed norm and the step
  amplitude) and flagged in ``saturated``; runs of clipped samples longer
  than ``max_clip_fill_s`` (40 ms) are also flagged not ``valid`` (no step
  is placed on an invented peak), while shorter ones, bridged from
  neighbours a few ms away, stay valid;
- the record is resampled onto a uniform grid at the nominal rate (the median
  sample interval unless given) by linear interpolation; gaps longer than
  ``max_gap_s`` are counted and flagged in ``valid`` (False inside them).

A file without the required columns raises one :class:`ImuError` naming them.

Units (:func:`detect_units`): the accelerometer may be in m/s², g or mg and
the gyro in rad/s or deg/s (x-io and many loggers write g and deg/s). With
``accel_unit="auto"`` the unit is the one for which the median magnitude of
the specific force is gravity: median |a| in [0.5, 2] → g, in [5, 20] →
m/s², in [500, 2000] → mg; anything else is refused with one message (name
the unit with ``--accel-unit``). With ``gyro_unit="auto"`` the 99th
percentile of |ω| decides: above 20 (1146 °/s in rad/s, beyond a walking
body, foot swing included) the gyro is in deg/s, otherwise rad/s. Both
choices are recorded in :attr:`ImuData.units`, and the command prints them.
Limitation: a deg/s record that hardly turns (99th percentile under 20 °/s,
e.g. standing still) reads as rad/s; walking at the waist turns faster than
that, and ``--gyro-unit`` settles any doubt.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from features.errors import ImuError
from features.numtext import read_csv_table

__all__ = ["ImuData", "ImuRepairReport", "RepairConfig", "read_imu_csv", "repair_imu", "REQUIRED_COLUMNS",
           "ACCEL_UNITS", "GYRO_UNITS", "detect_units"]

ACCEL_UNITS = {"m/s2": 1.0, "g": 9.80665, "mg": 9.80665e-3}
"""Accelerometer units accepted, with the factor to m/s² (standard gravity, BIPM)."""
GYRO_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180.0}
"""Gyro units accepted, with the factor to rad/s."""
_GRAVITY_MEDIAN_RANGES = (("g", 0.5, 2.0), ("m/s2", 5.0, 20.0), ("mg", 500.0, 2000.0))
_GYRO_DEG_S_ABOVE = 20.0
"""A 99th-percentile |ω| above this is taken as deg/s: 20 rad/s (1146 °/s) is beyond human motion."""

REQUIRED_COLUMNS = ("t_s", "ax", "ay", "az")
GYRO_COLUMNS = ("gx", "gy", "gz")
MAG_COLUMNS = ("mx", "my", "mz")
HEADER_SHOWN_CHARS = 120
"""At most this much of a bad header goes into the error message (repr: control bytes escaped)."""


@dataclass(frozen=True)
class RepairConfig:
    """Repair parameters.

    ``rate_hz`` None → nominal rate from the median sample interval.
    Full-scale values default to ±16 g, ±2000 °/s and ±4900 µT (common MEMS
    ranges, e.g. Bosch BMI160, AKM AK09916).
    """

    rate_hz: float | None = None
    max_gap_s: float = 0.5
    max_fill_gap_s: float = 600.0
    max_fill_samples: int = 360_000
    max_clip_fill_s: float = 0.04
    min_rate_hz: float = 10.0
    max_rate_hz: float = 2000.0
    acc_full_scale_m_s2: float = 16.0 * 9.80665
    gyro_full_scale_rad_s: float = math.radians(2000.0)
    mag_full_scale_ut: float = 4900.0
    clip_run_samples: int = 3

    def __post_init__(self):
        if self.rate_hz is not None and not (math.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 10_000.0):
            raise ImuError(f"rate_hz must lie in [1, 10000], got {self.rate_hz}")
        if not (self.max_gap_s > 0 and math.isfinite(self.max_gap_s)):
            raise ImuError(f"max_gap_s must be positive, got {self.max_gap_s}")
        if not (math.isfinite(self.max_fill_gap_s) and self.max_fill_gap_s >= self.max_gap_s):
            raise ImuError(f"max_fill_gap_s must be finite and >= max_gap_s, got {self.max_fill_gap_s}")
        if not self.max_fill_samples >= 0:
            raise ImuError(f"max_fill_samples must be >= 0, got {self.max_fill_samples}")
        if not (math.isfinite(self.max_clip_fill_s) and self.max_clip_fill_s >= 0):
            raise ImuError(f"max_clip_fill_s must be finite and >= 0, got {self.max_clip_fill_s}")
        if not (0 < self.min_rate_hz < self.max_rate_hz and math.isfinite(self.max_rate_hz)):
            raise ImuError(f"need 0 < min_rate_hz < max_rate_hz, got {self.min_rate_hz}, {self.max_rate_hz}")
        if self.clip_run_samples < 2:
            raise ImuError(f"clip_run_samples must be >= 2, got {self.clip_run_samples}")


@dataclass
class ImuRepairReport:
    """Counts of what the repair found and did."""

    n_rows: int = 0
    n_bad_time: int = 0
    n_bad_lines: int = 0
    n_unsorted: int = 0
    n_duplicate_t: int = 0
    n_nan_acc: int = 0
    n_nan_gyro: int = 0
    n_nan_mag: int = 0
    n_saturated_acc: int = 0
    n_saturated_gyro: int = 0
    n_saturated_mag: int = 0
    n_gaps: int = 0
    gap_total_s: float = 0.0
    n_output: int = 0

    @property
    def n_defects(self) -> int:
        """Number of defects found (bad times/lines, disorder, duplicates, NaN, saturation, gaps)."""
        return sum(v for k, v in vars(self).items() if k.startswith("n_") and k not in ("n_rows", "n_output"))

    def summary(self) -> str:
        """One line listing the non-zero counts.

        >>> ImuRepairReport(n_rows=10, n_gaps=1, gap_total_s=0.75).summary()
        'n_rows=10, n_gaps=1, gap_total_s=0.75'
        """
        parts = [f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in vars(self).items() if v]
        return ", ".join(parts) if parts else "clean"


@dataclass(frozen=True)
class ImuData:
    """IMU samples on a uniform time base.

    Attributes
    ----------
    t_s : ndarray of shape (n,)
        Sample times, s, uniform at ``rate_hz`` from the first valid sample.
    acc_m_s2 : ndarray of shape (n, 3)
        Specific force, body frame, m/s².
    gyro_rad_s, mag_ut : ndarray of shape (n, 3) or None
        Angular rate (rad/s) and magnetic field (µT), None when absent.
    valid : ndarray of bool, shape (n,)
        False inside gaps longer than ``max_gap_s`` and in runs of clipped
        samples longer than ``max_clip_fill_s`` (interpolated, not measured).
    saturated : ndarray of bool, shape (n,)
        True where any accelerometer, gyro or magnetometer axis was clipped
        (the value there is interpolated).
    rate_hz : float
    report : ImuRepairReport
    """

    t_s: np.ndarray
    acc_m_s2: np.ndarray
    gyro_rad_s: np.ndarray | None
    mag_ut: np.ndarray | None
    valid: np.ndarray
    saturated: np.ndarray
    rate_hz: float
    report: ImuRepairReport = field(default_factory=ImuRepairReport)
    units: str = ""
    """How the file's units were taken, e.g. ``accelerometer in g (median |a| 1.00), gyro in deg/s (...)``."""

    def __len__(self) -> int:
        return len(self.t_s)


def _fill_nan(x: np.ndarray) -> int:
    """Interpolate NaNs of every column in place (edges take the nearest value); return the count."""
    bad = ~np.isfinite(x)
    n_bad = int(bad.any(axis=1).sum())
    if n_bad == 0:
        return 0
    idx = np.arange(len(x))
    for j in range(x.shape[1]):
        ok = ~bad[:, j]
        x[:, j] = np.interp(idx, idx[ok], x[ok, j]) if ok.any() else 0.0
    return n_bad


def _time_outliers(t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Isolated corrupt timestamps in file order, bool (n,).

    Row i is an outlier when |t_i − t_{i−1}| and |t_{i+1} − t_i| both exceed
    ``max_gap_s`` while |t_{i+1} − t_{i−1}| does not (first/last row: its one
    neighbour pair, judged against the next interval).

    >>> _time_outliers(np.array([0.0, 0.01, 1e9, 0.03, 0.04]), 0.5).nonzero()[0].tolist()
    [2]
    >>> _time_outliers(np.array([0.0, 0.01, 5.0, 5.01, 5.02]), 0.5).any()   # a real gap is kept
    np.False_
    """
    n = len(t)
    out = np.zeros(n, bool)
    if n < 3:
        return out
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.abs(np.diff(t))
        skip = np.abs(t[2:] - t[:-2])
    out[1:-1] = (d[:-1] > max_gap_s) & (d[1:] > max_gap_s) & (skip <= max_gap_s)
    out[0] = d[0] > max_gap_s and d[1] <= max_gap_s and n > 3
    out[-1] = d[-1] > max_gap_s and d[-2] <= max_gap_s and n > 3
    return out


def _long_runs(mask: np.ndarray, max_samples: float) -> np.ndarray:
    """The True runs of ``mask`` longer than ``max_samples`` samples, bool (n,).

    >>> _long_runs(np.array([1, 0, 1, 1, 1, 0], bool), 2).astype(int).tolist()
    [0, 0, 1, 1, 1, 0]
    """
    out = np.zeros(len(mask), bool)
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    for s, e in zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]):
        if e - s > max_samples:
            out[s:e] = True
    return out


def _saturation(x: np.ndarray, full_scale: float, run: int) -> np.ndarray:
    """Clipped samples per axis, bool (n, 3): |x| ≥ full scale, or runs of ≥ ``run`` equal values at the
    column's (finite) extreme. NaN entries are not flagged (they are counted as NaN)."""
    with np.errstate(invalid="ignore"):
        flag = np.abs(x) >= full_scale
    for j in range(x.shape[1]):
        col = x[:, j]
        fin = np.isfinite(col) & ~flag[:, j]
        if not fin.any():
            continue
        for extreme in (col[fin].max(), col[fin].min()):
            at = col == extreme
            if at.sum() >= run:
                d = np.diff(np.r_[0, at.astype(np.int8), 0])
                for s, e in zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]):
                    if e - s >= run:
                        flag[s:e, j] = True
    return flag


def repair_imu(t_s, acc_m_s2, gyro_rad_s=None, mag_ut=None, config: RepairConfig = RepairConfig(),
               report: ImuRepairReport | None = None) -> ImuData:
    """Repair raw samples (see module docstring) and resample them to a uniform grid.

    Parameters
    ----------
    t_s : array of shape (n,)
    acc_m_s2 : array of shape (n, 3)
    gyro_rad_s, mag_ut : array of shape (n, 3) or None

    >>> d = repair_imu([0.0, 0.02, 0.01, 0.01, 0.03], [[0, 0, -9.8]] * 5, config=RepairConfig(rate_hz=100))
    >>> d.report.n_unsorted, d.report.n_duplicate_t, len(d)
    (1, 1, 4)
    """
    report = report or ImuRepairReport()
    t = np.asarray(t_s, dtype=float).ravel()
    chans = {"acc": np.array(acc_m_s2, dtype=float, ndmin=2)}
    if gyro_rad_s is not None:
        chans["gyro"] = np.array(gyro_rad_s, dtype=float, ndmin=2)
    if mag_ut is not None:
        chans["mag"] = np.array(mag_ut, dtype=float, ndmin=2)
    for name, x in chans.items():
        if x.shape != (len(t), 3):
            raise ImuError(f"{name} must have shape ({len(t)}, 3), got {x.shape}")
    report.n_rows = report.n_rows or len(t)
    ok = np.isfinite(t)
    ok[ok] &= ~_time_outliers(t[ok], config.max_gap_s)
    report.n_bad_time += int((~ok).sum())
    t = t[ok]
    chans = {k: v[ok] for k, v in chans.items()}
    if len(t) < 2:
        raise ImuError(f"fewer than 2 samples with a valid time ({len(t)})")
    if np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        report.n_unsorted += int((np.diff(t) < 0).sum())
        t = t[order]
        chans = {k: v[order] for k, v in chans.items()}
    keep = np.r_[True, np.diff(t) > 0]
    report.n_duplicate_t += int((~keep).sum())
    t = t[keep]
    chans = {k: v[keep] for k, v in chans.items()}
    if len(t) < 2:
        raise ImuError("fewer than 2 distinct sample times")
    # clipped samples become NaN first, so they are interpolated like missing ones (never filtered as data)
    full_scale = {"acc": config.acc_full_scale_m_s2, "gyro": config.gyro_full_scale_rad_s,
                  "mag": config.mag_full_scale_ut}
    sat = np.zeros(len(t), bool)
    for name, x in chans.items():
        clipped = _saturation(x, full_scale[name], config.clip_run_samples)
        rows = clipped.any(axis=1)
        setattr(report, f"n_saturated_{name}", getattr(report, f"n_saturated_{name}") + int(rows.sum()))
        sat |= rows
        n_nan = int((~np.isfinite(x) & ~clipped).any(axis=1).sum())
        x[clipped] = np.nan
        _fill_nan(x)
        setattr(report, f"n_nan_{name}", getattr(report, f"n_nan_{name}") + n_nan)

    dt_raw = np.diff(t)
    median_dt = float(np.median(dt_raw))
    if not config.min_rate_hz <= 1.0 / median_dt <= config.max_rate_hz:
        raise ImuError(f"median sample interval {median_dt:.6g} s ({1.0 / median_dt:.4g} Hz) is outside "
                       f"{config.min_rate_hz:g}-{config.max_rate_hz:g} Hz; t_s must be in seconds "
                       f"(milliseconds? divide by 1000)")
    rate = config.rate_hz or 1.0 / median_dt
    dt = 1.0 / rate
    fill_s = max(config.max_fill_gap_s, config.max_fill_samples / rate)     # the longest gap filled
    worst = int(np.argmax(dt_raw))
    if dt_raw[worst] > fill_s:
        raise ImuError(f"t_s jumps by {dt_raw[worst]:.6g} s (from {t[worst]:.6g} to {t[worst + 1]:.6g} s), "
                       f"more than the {fill_s:.6g} s filled at {rate:.4g} Hz: split the record there")
    long_clip = _long_runs(sat, config.max_clip_fill_s * rate)
    gaps = dt_raw > max(config.max_gap_s, 2.5 * dt)
    report.n_gaps += int(gaps.sum())
    report.gap_total_s += float(dt_raw[gaps].sum())
    n_out = int(math.floor((t[-1] - t[0]) * rate + 1e-6)) + 1
    n_bound = 10 * len(t) + int(rate * fill_s)
    if n_out > n_bound:
        raise ImuError(f"gaps fill {float(dt_raw[gaps].sum()):.6g} s of a {t[-1] - t[0]:.6g} s record with "
                       f"{len(t)} samples: resampling would need {n_out} samples (> {n_bound}); split the record")
    tu = t[0] + np.arange(n_out) * dt
    if n_out == len(t) and np.max(np.abs(t - tu)) <= 1e-3 * dt:
        # already uniform (the common case): keep the samples, no interpolation
        report.n_output = n_out
        return ImuData(t_s=tu, acc_m_s2=chans["acc"], gyro_rad_s=chans.get("gyro"), mag_ut=chans.get("mag"),
                       valid=~long_clip, saturated=sat, rate_hz=float(rate), report=report)
    out = {k: np.stack([np.interp(tu, t, v[:, j]) for j in range(3)], axis=1) for k, v in chans.items()}
    seg = np.searchsorted(t, tu, side="right") - 1
    seg = np.clip(seg, 0, len(dt_raw) - 1)
    tol = 1e-3 * dt
    valid = ~(gaps[seg] & (tu > t[seg] + tol) & (tu < t[seg + 1] - tol))
    nearest = np.where(tu - t[seg] <= t[np.minimum(seg + 1, len(t) - 1)] - tu, seg, np.minimum(seg + 1, len(t) - 1))
    sat_u = sat[nearest]
    report.n_output = n_out
    return ImuData(t_s=tu, acc_m_s2=out["acc"], gyro_rad_s=out.get("gyro"), mag_ut=out.get("mag"),
                   valid=valid & ~long_clip[nearest], saturated=sat_u, rate_hz=float(rate), report=report)


_ASCII_SPACE = b" \t\n\x0b\x0c\x1c\x1d\x1e\x1f"
"""The ASCII bytes ``str.strip`` removes (``\\r`` aside: a file holding one goes through :func:`_parse_table`)."""


def _plain_table(raw: bytes) -> tuple[list[str], np.ndarray, int] | None:
    """:func:`_parse_table` of a plain file, compiled: ASCII, ``\\n`` line ends, a header line, then rows
    of canonical decimals and nothing else (:func:`features.numtext.read_csv_table`: the same doubles as
    numpy's ``loadtxt``, which reads with Python's correctly rounded conversion). None for any other file."""
    data = np.frombuffer(raw, dtype=np.uint8)
    if data.size == 0 or data.max() >= 128 or (data == 13).any():
        return None
    body = raw.lstrip(_ASCII_SPACE)
    cut = body.find(b"\n")
    if cut < 0:
        return None
    header = [h.strip().lower() for h in body[:cut].decode("ascii").split(",")]
    ok, rows = read_csv_table(np.frombuffer(body, dtype=np.uint8)[cut + 1:], len(header))
    return (header, rows, 0) if ok else None


def _parse_table(text: str, path: str) -> tuple[list[str], np.ndarray, int]:
    """Header names and the numeric table; a table with bad lines is parsed line by line (bad ones counted)."""
    text = text.lstrip()
    if not text:
        raise ImuError(f"{path}: empty file; need columns {', '.join(REQUIRED_COLUMNS)}")
    cut = text.find("\n")
    head, body = (text, "") if cut < 0 else (text[:cut], text[cut + 1:])
    header = [h.strip().lower() for h in head.split(",")]
    ncol = len(header)
    try:  # fast path: numpy's C parser (blank lines and '#' comments skipped)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2, comments="#")
        if data.size == 0:
            return header, np.zeros((0, ncol)), 0
        if data.shape[1] == ncol:
            return header, data, 0
    except ValueError:
        pass
    rows, n_bad = [], 0
    for ln in body.splitlines():
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        parts = ln.split(",")
        if len(parts) != ncol:
            n_bad += 1
            continue
        row = []
        for p in parts:
            try:
                row.append(float(p))
            except ValueError:
                row.append(math.nan)
        rows.append(row)
    return header, np.asarray(rows, dtype=float).reshape(-1, ncol), n_bad


def detect_units(acc, gyro=None, accel_unit: str = "auto", gyro_unit: str = "auto",
                 where: str = "IMU data") -> tuple[float, float, str]:
    """Factors to m/s² and rad/s for raw samples, and a note saying how they were chosen.

    acc : array of shape (n, 3), gyro : array of shape (n, 3) or None.

    >>> acc = [[0.0, 0.0, 1.0]] * 10                          # at rest, in g
    >>> gyro = [[0.0, 0.0, 90.0]] * 10                        # a turn, in deg/s
    >>> fa, fg, note = detect_units(acc, gyro)
    >>> round(fa, 5), round(fg, 6), note
    (9.80665, 0.017453, 'accelerometer in g (median |a| 1, gravity), gyro in deg/s (p99 |w| 90 > 20)')
    """
    if accel_unit != "auto" and accel_unit not in ACCEL_UNITS:
        raise ImuError(f"--accel-unit must be auto, {', '.join(ACCEL_UNITS)}; got {accel_unit!r}")
    if gyro_unit != "auto" and gyro_unit not in GYRO_UNITS:
        raise ImuError(f"--gyro-unit must be auto, {', '.join(GYRO_UNITS)}; got {gyro_unit!r}")
    acc = np.asarray(acc, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        norm = np.linalg.norm(acc, axis=1)
        med = float(np.nanmedian(norm)) if np.isfinite(norm).any() else math.nan
    if accel_unit == "auto":
        unit = next((u for u, lo, hi in _GRAVITY_MEDIAN_RANGES if lo <= med <= hi), None)
        if unit is None:
            raise ImuError(f"{where}: median accelerometer magnitude {med:.4g} is gravity in none of m/s2 "
                           f"(5-20), g (0.5-2) or mg (500-2000): the file's unit is unknown; state it with "
                           f"--accel-unit (m/s2, g, mg)")
        parts = [f"accelerometer in {unit} (median |a| {med:.3g}, gravity)"]
    else:
        unit = accel_unit
        parts = [f"accelerometer in {unit} (given)"]
        g_med = med * ACCEL_UNITS[unit]
        if not 5.0 <= g_med <= 20.0:
            raise ImuError(f"{where}: with --accel-unit {unit} the median accelerometer magnitude is "
                           f"{g_med:.4g} m/s2, not gravity (9.81): check the unit")
    f_acc = ACCEL_UNITS[unit]
    f_gyro = 1.0
    if gyro is not None:
        g = np.asarray(gyro, dtype=float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            w = np.linalg.norm(g, axis=1)
            p99 = float(np.nanpercentile(w, 99)) if np.isfinite(w).any() else 0.0
        if gyro_unit == "auto":
            gunit = "deg/s" if p99 > _GYRO_DEG_S_ABOVE else "rad/s"
            rel = ">" if gunit == "deg/s" else "<="
            parts.append(f"gyro in {gunit} (p99 |w| {p99:.3g} {rel} {_GYRO_DEG_S_ABOVE:g})")
        else:
            gunit = gyro_unit
            parts.append(f"gyro in {gunit} (given)")
        f_gyro = GYRO_UNITS[gunit]
    return f_acc, f_gyro, ", ".join(parts)


def read_imu_csv(path: str | os.PathLike, config: RepairConfig = RepairConfig(), *,
                 accel_unit: str = "auto", gyro_unit: str = "auto") -> ImuData:
    """Read ``imu.csv`` (columns per module docstring), repair it, return :class:`ImuData`.

    ``accel_unit`` (``auto``, ``m/s2``, ``g``, ``mg``) and ``gyro_unit``
    (``auto``, ``rad/s``, ``deg/s``): see :func:`detect_units`.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ImuError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise ImuError(f"{path}: is a directory, expected an IMU CSV file") from None
    table = _plain_table(raw)
    if table is not None:
        header, data, n_bad = table
    else:  # as path.read_text(encoding="utf-8-sig", errors="replace") reads it (universal newlines)
        text = raw.decode("utf-8-sig", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
        header, data, n_bad = _parse_table(text, str(path))
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        have = ", ".join(header)
        have = repr(have[:HEADER_SHOWN_CHARS]) + ("…" if len(have) > HEADER_SHOWN_CHARS else "") if have else "none"
        raise ImuError(f"{path}: missing required column(s) {', '.join(missing)} "
                       f"(have: {have}; need {', '.join(REQUIRED_COLUMNS)})")
    col = {name: i for i, name in enumerate(header)}

    def triple(names):
        present = [n in col for n in names]
        if all(present):
            return data[:, [col[n] for n in names]]
        if any(present):
            raise ImuError(f"{path}: columns {', '.join(names)} must all be present or all absent")
        return None

    report = ImuRepairReport(n_rows=len(data), n_bad_lines=n_bad)
    if len(data) < 2:
        raise ImuError(f"{path}: fewer than 2 data rows")
    acc = data[:, [col["ax"], col["ay"], col["az"]]]
    gyro = triple(GYRO_COLUMNS)
    f_acc, f_gyro, note = detect_units(acc, gyro, accel_unit, gyro_unit, where=str(path))
    imu = repair_imu(data[:, col["t_s"]], acc * f_acc, None if gyro is None else gyro * f_gyro,
                     triple(MAG_COLUMNS), config=config, report=report)
    return dataclasses.replace(imu, units=note)
