"""Waist-worn IMU of a walking person: steps, body motion and sensor errors.

Given the true route (:class:`simulation.streams.Trajectory`, 100 Hz) the
walker places steps, synthesises the specific force, angular rate and magnetic
field a belt-clipped device would measure, and returns the true steps.

Frames and conventions
    Navigation frame north-east-down (NED); heading ψ from true north,
    clockwise (DESIGN.md §3). Device (body) frame forward-right-down (x along
    the direction of travel, z down). The accelerometer measures specific
    force f = a − g, so a device at rest reads az ≈ −9.81 m/s². Body → NED
    rotation C = Rz(ψ)·Ry(θ)·Rx(φ) (Titterton & Weston, *Strapdown Inertial
    Navigation Technology*, 2nd ed., eq. 3.47); body rates from Euler rates by
    their eq. 3.52. Earth rotation is added to the gyro.

Gait (per person, from ``stream_rng(person_seed, "person")``)
    Cadence f = f_p·(v / 1.25 m/s)^0.4 with f_p ∈ [1.6, 2.0] Hz (cadence and
    step length both grow with speed; exponent after Grieve & Gear 1966's
    step-length ∝ speed^0.6 relation). Steps are placed by integrating the
    cadence while moving (v > 0.15 m/s), with ±3 % per-step timing jitter; a
    final step closes a walking bout when more than 30 % of a nominal step's
    path is left (else the last step absorbs the rest).
    The true step length is the path length between consecutive steps.

    Vertical acceleration per step k is a_up = A_k·sin(2π·c(t)) with c the
    continuous step count, so (a_max − a_min) over the step is 2A_k, and A_k
    is chosen so that Weinberg's relation holds exactly:
    S_k = K·(a_max − a_min)^(1/4) ⇒ A_k = ½·(S_k / K)^4
    (Weinberg 2002, Analog Devices AN-602, eq. 1), except that steps shorter
    than :data:`MIN_EXCURSION_STEP_M` (starting and stopping) keep that
    step's amplitude. The vertical peak of step k falls a quarter step after
    heel strike k−1 (weight acceptance). Forward surge
    (½A, step frequency), lateral sway (stride frequency, ~0.7 m/s²) and
    pelvic yaw/roll/pitch oscillation (±4°, ±2°, ±1.5°) ride on top; the
    magnitudes follow waist-accelerometry studies (Zijlstra & Hof 2003,
    Gait & Posture 18:1-10: vertical CoM excursion 3-5 cm, lateral sway at
    stride frequency).

Sensor errors (consumer MEMS, e.g. Bosch BMI160 / AKM AK09916 data sheets)
    accelerometer: white noise 0.02 m/s² rms at 100 Hz, constant bias
    N(0, 0.05 m/s²) per axis, ±16 g clipping; gyro: white noise 0.07 °/s rms,
    turn-on bias N(0, 0.3 °/s) per axis plus a random walk 0.002 °/s/√s,
    scale-factor error N(0, 1 %) per axis,
    ±2000 °/s clipping; magnetometer: white noise 0.4 µT rms (hard/soft iron
    assumed calibrated). The device is clipped with a small mounting tilt
    (N(0, 3°) roll and pitch, no yaw offset).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np
from scipy import ndimage

from features.constants import GRAVITY_M_S2, OMEGA_EARTH_RAD_S
from features.site import Site

from .magnetic import disturbance_ned_ut, earth_field_ned_ut, steel_dipoles
from .rng import stream_rng
from .streams import Trajectory

__all__ = ["Gait", "SensorErrors", "StepTruth", "ImuSamples", "person_gait", "place_steps",
           "synthesise_imu", "trajectory_from_waypoints", "REFERENCE_SPEED_M_S", "MOVING_SPEED_M_S"]

REFERENCE_SPEED_M_S = 1.25
"""Walking speed at which the person's nominal cadence applies, m/s."""

MOVING_SPEED_M_S = 0.15
"""Below this horizontal speed the person stands (no steps), m/s."""

MIN_EXCURSION_STEP_M = 0.5
"""Shorter (starting / stopping) steps get the vertical excursion of a step of this length, m.

Weinberg's relation is fitted to steady walking; gait initiation and
termination still raise and lower the centre of mass about as a normal step
does, so their accelerations do not shrink with the fourth power of length."""


@dataclass(frozen=True)
class Gait:
    """One person's gait constants (same person → same values across walks)."""

    step_freq_hz: float
    weinberg_k: float
    lateral_sway_m_s2: float = 0.7
    yaw_sway_rad: float = math.radians(4.0)
    roll_sway_rad: float = math.radians(2.0)
    pitch_sway_rad: float = math.radians(1.5)
    timing_jitter: float = 0.03
    cadence_speed_exponent: float = 0.4

    def __post_init__(self):
        if not 1.0 <= self.step_freq_hz <= 3.0:
            raise ValueError(f"step_freq_hz must lie in [1, 3], got {self.step_freq_hz}")
        if not 0.2 <= self.weinberg_k <= 1.0:
            raise ValueError(f"weinberg_k must lie in [0.2, 1], got {self.weinberg_k}")
        if not 0.0 <= self.timing_jitter < 0.2:
            raise ValueError(f"timing_jitter must lie in [0, 0.2), got {self.timing_jitter}")

    def cadence_hz(self, speed_m_s: np.ndarray) -> np.ndarray:
        """Step frequency at the given speed, Hz: f_p·(v/1.25)^0.4, speed clipped to [0.5, 2] m/s."""
        v = np.clip(np.asarray(speed_m_s, dtype=float), 0.5, 2.0)
        return self.step_freq_hz * (v / REFERENCE_SPEED_M_S) ** self.cadence_speed_exponent


def person_gait(person_seed: int) -> Gait:
    """The gait of person ``person_seed``: cadence U(1.6, 2.0) Hz, Weinberg K U(0.42, 0.52), sway amplitudes."""
    rng = stream_rng(person_seed, "person")
    return Gait(
        step_freq_hz=float(rng.uniform(1.6, 2.0)),
        weinberg_k=float(rng.uniform(0.42, 0.52)),
        lateral_sway_m_s2=float(rng.uniform(0.5, 0.9)),
        yaw_sway_rad=math.radians(float(rng.uniform(3.0, 5.0))),
        roll_sway_rad=math.radians(float(rng.uniform(1.5, 2.5))),
        pitch_sway_rad=math.radians(float(rng.uniform(1.0, 2.0))),
    )


@dataclass(frozen=True)
class SensorErrors:
    """Error model of the device (see module docstring for sources)."""

    acc_noise_m_s2: float = 0.02
    acc_bias_m_s2: float = 0.05
    acc_range_m_s2: float = 16.0 * GRAVITY_M_S2
    gyro_noise_rad_s: float = math.radians(0.07)
    gyro_bias_rad_s: float = math.radians(0.3)
    gyro_bias_walk_rad_s_sqrt_s: float = math.radians(0.002)
    gyro_range_rad_s: float = math.radians(2000.0)
    gyro_scale_error: float = 0.01
    mag_noise_ut: float = 0.4
    mount_tilt_rad: float = math.radians(3.0)

    def __post_init__(self):
        for name in ("acc_noise_m_s2", "acc_bias_m_s2", "gyro_noise_rad_s", "gyro_bias_rad_s", "gyro_scale_error",
                     "gyro_bias_walk_rad_s_sqrt_s", "mag_noise_ut", "mount_tilt_rad"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"SensorErrors.{name} must be finite and >= 0, got {value}")
        if self.acc_range_m_s2 <= 2 * GRAVITY_M_S2 or self.gyro_range_rad_s <= 1.0:
            raise ValueError("sensor ranges too small for walking")


@dataclass(frozen=True)
class StepTruth:
    """True steps: ``t_s`` (n,) heel-strike times, ``step_length_m`` (n,), ``heading_rad`` (n,) of the displacement."""

    t_s: np.ndarray
    step_length_m: np.ndarray
    heading_rad: np.ndarray


@dataclass(frozen=True)
class ImuSamples:
    """Device output: ``t_s`` (n,), ``acc_m_s2``, ``gyro_rad_s``, ``mag_ut`` (n, 3) in the body frame.

    ``mag_disturbance_ut`` (n,) is the magnitude of the steel disturbance at
    the device, kept for scoring (not written to imu.csv).
    """

    t_s: np.ndarray
    acc_m_s2: np.ndarray
    gyro_rad_s: np.ndarray
    mag_ut: np.ndarray
    mag_disturbance_ut: np.ndarray


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [start, stop) of the True runs of ``mask``."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]))


def place_steps(traj: Trajectory, gait: Gait, rng: np.random.Generator) -> tuple[StepTruth, np.ndarray]:
    """Heel-strike times of the walk and the continuous step count c(t).

    Returns
    -------
    steps : StepTruth
    count : ndarray of shape (n,)
        Continuous step count at every trajectory sample (integer at heel
        strikes, constant while standing): the gait phase.
    """
    t = np.asarray(traj.t_s, dtype=float)
    dt = 1.0 / traj.rate_hz
    v = np.asarray(traj.speed_m_s, dtype=float)
    dist_m = np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))]
    anchors_t: list[float] = [float(t[0])]
    anchors_c: list[float] = [0.0]
    step_t: list[np.ndarray] = []
    total = 0
    for i0, i1 in _segments(v > MOVING_SPEED_M_S):
        phase = np.cumsum(gait.cadence_hz(v[i0:i1]) * dt)
        phase = np.r_[0.0, phase[:-1]]
        n_full = int(math.floor(phase[-1]))
        targets = np.arange(1, n_full + 1, dtype=float)
        targets += gait.timing_jitter * rng.standard_normal(n_full).clip(-3, 3)
        targets = targets[(targets > 0.5) & (targets < phase[-1])]
        times = np.interp(targets, phase, t[i0:i1])
        # close the bout: a last short step if enough path is left, else the last step absorbs the rest
        step_nominal_m = REFERENCE_SPEED_M_S / gait.step_freq_hz
        t_end = t[i1 - 1]
        left_m = dist_m[i1 - 1] - (np.interp(times[-1], t, dist_m) if len(times) else dist_m[i0])
        if len(times) == 0 or (left_m > 0.3 * step_nominal_m and t_end - times[-1] > 0.35):
            times = np.r_[times, t_end]
        else:
            times[-1] = t_end
        anchors_t += [float(t[i0])] + list(times)
        anchors_c += [float(total)] + list(total + np.arange(1, len(times) + 1, dtype=float))
        total += len(times)
        step_t.append(times)
    times = np.concatenate(step_t) if step_t else np.zeros(0)
    # a standing spell keeps the count constant: anchor its start too
    order = np.argsort(anchors_t, kind="stable")
    at = np.asarray(anchors_t)[order]
    ac = np.asarray(anchors_c)[order]
    count = np.interp(t, at, ac)
    # path length and displacement direction between consecutive steps (or the bout start)
    j = np.searchsorted(at, times, side="left")
    prev_t = at[np.maximum(j - 1, 0)]
    east0, north0, _ = traj.interp(prev_t)
    east1, north1, _ = traj.interp(times)
    length = np.interp(times, t, dist_m) - np.interp(prev_t, t, dist_m)
    heading = np.arctan2(east1 - east0, north1 - north0)
    return StepTruth(times, length, heading), count


def _smooth(x: np.ndarray, sigma_samples: float) -> np.ndarray:
    return ndimage.gaussian_filter1d(x, sigma_samples, mode="nearest") if sigma_samples > 0 else x


def _rot_body_to_ned(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """C = Rz(ψ)Ry(θ)Rx(φ), shape (n, 3, 3) (Titterton & Weston eq. 3.47)."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    c = np.empty((len(yaw), 3, 3))
    c[:, 0, 0] = cp * cy
    c[:, 0, 1] = -cr * sy + sr * sp * cy
    c[:, 0, 2] = sr * sy + cr * sp * cy
    c[:, 1, 0] = cp * sy
    c[:, 1, 1] = cr * cy + sr * sp * sy
    c[:, 1, 2] = -sr * cy + cr * sp * sy
    c[:, 2, 0] = -sp
    c[:, 2, 1] = sr * cp
    c[:, 2, 2] = cr * cp
    return c


def synthesise_imu(traj: Trajectory, site: Site, gait: Gait, steps: StepTruth, count: np.ndarray,
                   rng: np.random.Generator, errors: SensorErrors = SensorErrors()) -> ImuSamples:
    """Specific force, body rate and magnetic field of the waist device along ``traj``.

    ``steps`` and ``count`` come from :func:`place_steps`; ``rng`` draws the
    device's mounting tilt and sensor errors.
    """
    t = np.asarray(traj.t_s, dtype=float)
    n = len(t)
    fs = traj.rate_hz
    dt = 1.0 / fs
    # per-step vertical amplitude A_k = ½(S_k/K)^4 (Weinberg inverted), held over the step
    amp_step = 0.5 * (np.maximum(steps.step_length_m, MIN_EXCURSION_STEP_M) / gait.weinberg_k) ** 4
    k_idx = np.clip(np.ceil(count - 1e-9).astype(int) - 1, 0, max(len(amp_step) - 1, 0))
    walking = (np.abs(np.gradient(count)) > 1e-9)
    amp = np.where(walking, amp_step[k_idx], 0.0) if len(amp_step) else np.zeros(n)
    envelope = np.clip(_smooth(walking.astype(float), 0.15 * fs), 0.0, 1.0)
    amp_smooth = _smooth(amp, 0.1 * fs)
    two_pi_c = 2.0 * np.pi * count
    a_up = amp * np.sin(two_pi_c)
    a_fwd = -0.5 * amp_smooth * np.cos(two_pi_c) * envelope
    a_lat = gait.lateral_sway_m_s2 * np.sin(0.5 * two_pi_c) * envelope

    # route heading: unwrap and smooth over 0.3 s (the body turns over a finite time)
    travel = _smooth(np.unwrap(np.asarray(traj.heading_rad, dtype=float)), 0.3 * fs)
    mount_roll, mount_pitch = rng.normal(0.0, errors.mount_tilt_rad, size=2)
    yaw = travel + gait.yaw_sway_rad * np.sin(0.5 * two_pi_c) * envelope
    roll = mount_roll + gait.roll_sway_rad * np.sin(0.5 * two_pi_c + 0.5 * np.pi) * envelope
    pitch = mount_pitch + gait.pitch_sway_rad * np.sin(two_pi_c) * envelope

    # trajectory acceleration in NED from positions, smoothed over 50 ms
    acc_n = _smooth(np.gradient(np.gradient(np.asarray(traj.north_m, float), dt), dt), 0.05 * fs)
    acc_e = _smooth(np.gradient(np.gradient(np.asarray(traj.east_m, float), dt), dt), 0.05 * fs)
    acc_d = -_smooth(np.gradient(np.gradient(np.asarray(traj.up_m, float), dt), dt), 0.05 * fs)
    ct, st = np.cos(travel), np.sin(travel)
    a_ned = np.stack([acc_n + a_fwd * ct - a_lat * st, acc_e + a_fwd * st + a_lat * ct, acc_d - a_up], axis=1)
    f_ned = a_ned - np.array([0.0, 0.0, GRAVITY_M_S2])
    c_bn = _rot_body_to_ned(yaw, pitch, roll)
    f_body = np.einsum("nji,nj->ni", c_bn, f_ned)

    # body rates from Euler rates (Titterton & Weston eq. 3.52) plus Earth rotation
    d_roll, d_pitch, d_yaw = np.gradient(roll, dt), np.gradient(pitch, dt), np.gradient(yaw, dt)
    gyro = np.stack([
        d_roll - d_yaw * np.sin(pitch),
        d_pitch * np.cos(roll) + d_yaw * np.sin(roll) * np.cos(pitch),
        -d_pitch * np.sin(roll) + d_yaw * np.cos(roll) * np.cos(pitch)], axis=1)
    lat = math.radians(site.origin.lat_deg)
    omega_ie_n = OMEGA_EARTH_RAD_S * np.array([math.cos(lat), 0.0, -math.sin(lat)])
    gyro += np.einsum("nji,j->ni", c_bn, omega_ie_n)

    # magnetic field: Earth dipole + steel dipoles at the device position
    b_earth = earth_field_ned_ut(site.origin.lat_deg, site.origin.lon_deg)
    dipoles = steel_dipoles(site, b_earth, stream_rng(site.seed or 0, "steel-remanence"))
    pos_ned = np.stack([traj.north_m, traj.east_m, -np.asarray(traj.up_m, float)], axis=1)
    dist = disturbance_ned_ut(dipoles, pos_ned)
    mag = np.einsum("nji,nj->ni", c_bn, b_earth[None, :] + dist)

    # sensor errors
    f_body += rng.normal(0.0, errors.acc_bias_m_s2, size=3) + rng.normal(0.0, errors.acc_noise_m_s2, size=(n, 3))
    bias_g = rng.normal(0.0, errors.gyro_bias_rad_s, size=3) + np.cumsum(
        rng.normal(0.0, errors.gyro_bias_walk_rad_s_sqrt_s * math.sqrt(dt), size=(n, 3)), axis=0)
    gyro *= 1.0 + rng.normal(0.0, errors.gyro_scale_error, size=3)
    gyro += bias_g + rng.normal(0.0, errors.gyro_noise_rad_s, size=(n, 3))
    mag += rng.normal(0.0, errors.mag_noise_ut, size=(n, 3))
    np.clip(f_body, -errors.acc_range_m_s2, errors.acc_range_m_s2, out=f_body)
    np.clip(gyro, -errors.gyro_range_rad_s, errors.gyro_range_rad_s, out=gyro)
    return ImuSamples(t, f_body, gyro, mag, np.linalg.norm(dist, axis=1))


def trajectory_from_waypoints(waypoints_en: np.ndarray, speed_m_s: float = 1.25, rate_hz: float = 100.0,
                              stops_s: dict[int, float] | None = None, start_stand_s: float = 2.0,
                              end_stand_s: float = 2.0, ramp_s: float = 1.0, origin_en: tuple = (0.0, 0.0),
                              up_m: float = 1.0) -> Trajectory:
    """A simple walk along straight legs, for tests and benchmarks when no route generator is at hand.

    ``waypoints_en`` (k, 2) east/north metres; the walker stands
    ``start_stand_s``, walks leg by leg at ``speed_m_s`` (speed ramps of
    ``ramp_s`` into and out of every stop), stands ``stops_s[i]`` seconds at
    waypoint ``i``, and stands ``end_stand_s`` at the end. Turns are rounded by
    smoothing the heading over 0.4 s; positions integrate speed along heading,
    so position, heading and speed are mutually consistent.
    """
    wp = np.asarray(waypoints_en, dtype=float)
    stops_s = dict(stops_s or {})
    dt = 1.0 / rate_hz
    speed_parts, head_parts = [np.zeros(int(round(start_stand_s * rate_hz)))], []
    first_heading = math.atan2(wp[1, 0] - wp[0, 0], wp[1, 1] - wp[0, 1])
    head_parts.append(np.full(len(speed_parts[0]), first_heading))
    for i in range(len(wp) - 1):
        d = wp[i + 1] - wp[i]
        length = float(np.hypot(*d))
        heading = math.atan2(d[0], d[1])
        stop_before = i == 0 or i in stops_s
        stop_after = i + 1 == len(wp) - 1 or (i + 1) in stops_s
        n_ramp = int(round(ramp_s * rate_hz))
        ramp_len = 0.5 * speed_m_s * ramp_s
        cruise = max(length - ramp_len * (stop_before + stop_after), 0.0)
        v = np.full(int(round(cruise / speed_m_s * rate_hz)), speed_m_s)
        if stop_before:
            v = np.r_[np.linspace(0.0, speed_m_s, n_ramp, endpoint=False), v]
        if stop_after:
            v = np.r_[v, np.linspace(speed_m_s, 0.0, n_ramp)]
        speed_parts.append(v)
        head_parts.append(np.full(len(v), heading))
        if (i + 1) in stops_s:
            n_stop = int(round(stops_s[i + 1] * rate_hz))
            speed_parts.append(np.zeros(n_stop))
            head_parts.append(np.full(n_stop, heading))
    n_end = int(round(end_stand_s * rate_hz))
    speed_parts.append(np.zeros(n_end))
    head_parts.append(np.full(n_end, head_parts[-1][-1] if len(head_parts[-1]) else first_heading))
    speed = np.concatenate(speed_parts)
    heading = _smooth(np.unwrap(np.concatenate(head_parts)), 0.4 * rate_hz)
    east = origin_en[0] + wp[0, 0] + np.r_[0.0, np.cumsum(speed[:-1] * np.sin(heading[:-1]) * dt)]
    north = origin_en[1] + wp[0, 1] + np.r_[0.0, np.cumsum(speed[:-1] * np.cos(heading[:-1]) * dt)]
    t = np.arange(len(speed)) * dt
    return Trajectory(t_s=t, east_m=east, north_m=north, up_m=np.full(len(t), up_m),
                      heading_rad=np.mod(heading, 2 * np.pi), speed_m_s=speed,
                      start_utc=datetime(2026, 1, 1, tzinfo=timezone.utc), rate_hz=rate_hz)
