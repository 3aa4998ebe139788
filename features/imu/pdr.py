"""Pedestrian dead reckoning: steps × length × heading → track, and the steps CSV.

Each detected step (:mod:`features.imu.steps`) gets a length from a
:class:`~features.imu.steps.StepLengthModel` and the heading averaged over the
step (circular mean of the complementary-filter heading, :mod:`features.imu.heading`,
over the step's samples, which cancels the pelvis's yaw sway); the track is
    east_k = east_{k−1} + S_k·sin ψ_k,   north_k = north_{k−1} + S_k·cos ψ_k
(heading from north, clockwise), from a given start point.

A step's ``t_s`` is its heel strike: the peak of the filtered acceleration
norm, where the pelvis is lowest in double support (see :mod:`features.imu.steps`);
``truth_steps.csv`` of the simulator lists the same event. Samples flagged not
``valid`` by the reader (gaps, clipped samples) never carry a step.

The heading is that of the device's forward axis: a mounting yaw offset
between device and walking direction (a few degrees for a belt clip) is not
observable from the IMU alone and rotates the track about its start; fusion
with GNSS or acoustic positions removes it.

Without gyro and magnetometer the steps still get times and lengths; heading
and positions are NaN (written as empty CSV fields).
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass, field

import numpy as np

from features.fileio import atomic_write_text
from features.imu.heading import HeadingConfig, HeadingResult, HeadingState, estimate_heading
from features.imu.reader import ImuData
from features.imu.steps import StepDetectorConfig, StepLengthModel, Steps, detect_steps

__all__ = ["PdrConfig", "PdrResult", "run_pdr", "dead_reckon", "step_heading", "steps_csv_text", "write_steps_csv"]


@dataclass(frozen=True)
class PdrConfig:
    """Detector, step-length and heading settings of one PDR run."""

    detector: StepDetectorConfig = field(default_factory=StepDetectorConfig)
    length: StepLengthModel = field(default_factory=StepLengthModel)
    heading: HeadingConfig = field(default_factory=HeadingConfig)


@dataclass(frozen=True)
class PdrResult:
    """Per-step output, each ndarray of shape (n_steps,): ``t_s``, ``step_length_m``,
    ``heading_rad`` (from north, clockwise; NaN without heading sensors), ``east_m``,
    ``north_m`` (position after the step; NaN without heading). ``steps`` holds the
    detector's details, ``heading`` the per-sample headings (None without gyro/mag)."""

    t_s: np.ndarray
    step_length_m: np.ndarray
    heading_rad: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    steps: Steps
    heading: HeadingResult | None

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def distance_m(self) -> float:
        """Total walked distance, m."""
        return float(self.step_length_m.sum())


def step_heading(heading_rad: np.ndarray, steps: Steps) -> np.ndarray:
    """Circular mean of the per-sample heading over each step's samples, rad, shape (n_steps,); NaN for a step
    with a sample without heading (a resumed heading's first samples, :func:`run_pdr`)."""
    if len(steps) == 0:
        return np.zeros(0)
    h = np.asarray(heading_rad, float)
    bad = ~np.isfinite(h)
    z = np.r_[0.0, np.cumsum(np.where(bad, 0.0, np.exp(1j * np.where(bad, 0.0, h))))]
    psi = np.angle(z[steps.window_end] - z[steps.window_start])
    if bad.any():
        nbad = np.r_[0, np.cumsum(bad)]
        psi[nbad[steps.window_end] > nbad[steps.window_start]] = np.nan
    return psi


def dead_reckon(step_length_m: np.ndarray, heading_rad: np.ndarray, start_east_m: float = 0.0,
                start_north_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Positions after each step, (east_m, north_m), each shape (n_steps,).

    >>> e, n = dead_reckon(np.array([1.0, 1.0]), np.array([0.0, math.pi / 2]))
    >>> [round(float(v), 6) for v in (*e, *n)]
    [0.0, 1.0, 1.0, 1.0]
    """
    s = np.asarray(step_length_m, float)
    h = np.asarray(heading_rad, float)
    return start_east_m + np.cumsum(s * np.sin(h)), start_north_m + np.cumsum(s * np.cos(h))


def run_pdr(imu: ImuData, start_east_m: float = 0.0, start_north_m: float = 0.0,
            config: PdrConfig = PdrConfig(), heading_start: HeadingState | None = None) -> PdrResult:
    """The whole PDR path on repaired IMU data (see module docstring); ``heading_start``: the heading filter's
    state after the sample at its ``t_s``, from a run over the record up to there
    (:meth:`~features.imu.heading.HeadingResult.state_at`): the headings resume from it at the next sample
    (the steps before have none)."""
    steps = detect_steps(imu.acc_m_s2, imu.rate_hz, imu.t_s, imu.valid, config.detector)
    length = config.length.predict(steps)
    j = 0 if heading_start is None else int(np.searchsorted(imu.t_s, heading_start.t_s + 0.5 / imu.rate_hz))
    heading = estimate_heading(imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut, imu.rate_hz, config.heading, heading_start, j)
    if heading is None:
        nan = np.full(len(steps), np.nan)
        return PdrResult(steps.t_s, length, nan, nan.copy(), nan.copy(), steps, None)
    psi = step_heading(heading.fused, steps)
    east, north = dead_reckon(length, psi, start_east_m, start_north_m)
    return PdrResult(steps.t_s, length, psi, east, north, steps, heading)


def steps_csv_text(result: PdrResult) -> str:
    """CSV text: header ``t_s,step_length_m,heading_rad,east_m,north_m``, one row per step, NaN → empty."""
    out = io.StringIO()
    out.write("t_s,step_length_m,heading_rad,east_m,north_m\n")
    cols = np.stack([result.t_s, result.step_length_m, result.heading_rad, result.east_m, result.north_m], axis=1)
    fmt = ("{:.3f}", "{:.4f}", "{:.5f}", "{:.3f}", "{:.3f}")
    for row in cols:
        out.write(",".join("" if not math.isfinite(v) else f.format(v) for f, v in zip(fmt, row)) + "\n")
    return out.getvalue()


def write_steps_csv(path: str | os.PathLike, result: PdrResult) -> None:
    """Write the steps CSV atomically."""
    atomic_write_text(path, steps_csv_text(result))
