"""Waist-worn IMU of a walking person: steps, body motion and sensor errors.

Given the true route (:class:`simulation.streams.Trajectory`, 100 Hz) the
walker places steps, synthesises the specific force, angular rate and magnetic
field a belt-clipped device would measure, and returns the true steps.

Frames and conventions
    Navigation frame north-east-down (NED); heading ψ from true north,
    clockwise (docs/design.md §3). Device (body) frame forward-right-down (x along
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

    Vertical motion: the pelvis (≈ centre of mass) vaults over the stance
    leg as an inverted pendulum of the person's leg length l (Zijlstra & Hof
    1997, "Displacement of the pelvis during human walking", Gait & Posture
    6:249-262): a step of length S raises it by h with
    S = γ·2·sqrt(2·l·h − h²)  ⇒  h = l − sqrt(l² − (S/2γ)²),
    γ the person's correction factor of the pendulum model (Zijlstra & Hof
    2003, Gait & Posture 18:1-10, report ≈ 1.25 on average; drawn per person
    in [1.15, 1.35]). Each step's excursion varies by N(0, 10 %) (step-to-step
    variability of trunk motion), so no step-length formula is exact. The
    height follows z(t) = h_k·(1 − cos 2π·c(t))/2 over step k (c the
    continuous step count): lowest at heel strike (double support), highest
    at mid-stance, continuous with its slope at every heel strike. The
    vertical acceleration is its second derivative (numerical, at 100 Hz), so
    its amplitude h·2π²·f² follows from the pendulum *and* the instantaneous
    step frequency f; its maximum (upward) falls at heel strike. Weinberg's
    S = K·(a_max − a_min)^(1/4) is therefore only approximate (K ∝ f^(1/4)
    at fixed l, γ) and K must be calibrated, as with real walkers.
    Steps shorter than :data:`MIN_EXCURSION_STEP_M` (starting and stopping)
    take the excursion of a step of that length. The first step of a bout
    leaves quiet standing smoothly (its excursion is windowed by u², u its
    phase), so setting off makes no heel-strike-like peak; after a bout's last
    heel strike the motion runs on for one cycle windowed by (1 − v)² while
    the trailing leg is brought alongside (gait termination). Forward surge (½ of the
    vertical amplitude, step frequency), lateral sway (stride frequency,
    ~0.7 m/s²) and pelvic yaw/roll/pitch oscillation (±4°, ±2°, ±1.5°) ride
    on top (Zijlstra & Hof 2003: vertical CoM excursion 3-5 cm, lateral sway
    at stride frequency).

Sensor errors (consumer MEMS, e.g. Bosch BMI160 / AKM AK09916 data sheets)
    accelerometer: white noise 0.02 m/s² rms at 100 Hz, turn-on bias
    N(0, 0.13 m/s² ≈ 13 mg) per axis (BMI160 zero-g offset ±40 mg typ., taken
    as the 3σ bound), ±16 g clipping; gyro: white noise 0.07 °/s rms,
    turn-on bias N(0, 1.0 °/s) per axis (BMI160 zero-rate offset ±3 °/s typ.,
    as the 3σ bound; ICM-20948 states ±5 °/s) plus a random walk 0.002 °/s/√s; both biases
    drift as the device warms after power-on (:func:`warmup_kelvin`, 3–10 K
    over τ = 5 min, temperature coefficients gyro N(0, 0.05 °/s/K), accelerometer
    N(0, 1 mg/K)); the 50 Hz field of busbars overhead reaches the magnetometer
    aliased at 100 Hz (:func:`mains_field_ned_ut`);
    scale-factor error N(0, 1 %) per axis,
    ±2000 °/s clipping; magnetometer: white noise 0.4 µT rms and the residual
    of a field calibration: hard iron N(0, 1.5 µT) per axis and a symmetric
    soft-iron matrix I + E, E entries N(0, 2 %) (Renaudin, Afzal & Lachapelle
    2010, "Complete triaxis magnetometer calibration in the magnetic domain",
    J. Sensors: residuals of this order after a consumer calibration). The
    device is clipped on anew for every walk: mounting tilt N(0, 3°) roll
    and pitch and a mounting yaw offset N(0, 5°) between the device's x axis
    and the walking direction (drawn from the walk's sensor stream).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np
from scipy import ndimage

from features.constants import GRAVITY_M_S2, OMEGA_EARTH_RAD_S
from features.site import Site

from simulation.imu.magnetic import disturbance_ned_ut, earth_field_ned_ut, site_steel_dipoles
from simulation.rng import stream_rng
from simulation.streams import Trajectory

__all__ = ["Gait", "SensorErrors", "StepTruth", "ImuSamples", "person_gait", "place_steps",
           "synthesise_imu", "trajectory_from_waypoints", "REFERENCE_SPEED_M_S", "MOVING_SPEED_M_S"]

REFERENCE_SPEED_M_S = 1.25
"""Walking speed at which the person's nominal cadence applies, m/s."""

MOVING_SPEED_M_S = 0.15
"""Below this horizontal speed the person stands (no steps), m/s."""

MIN_EXCURSION_STEP_M = 0.5
"""Shorter (starting / stopping) steps get the vertical excursion of a step of this length, m.

Gait initiation and termination still raise and lower the centre of mass
about as a normal step does (the pendulum relation describes steady
walking), so their excursions do not shrink with the step's length."""


@dataclass(frozen=True)
class Gait:
    """One person's gait constants (same person → same values across walks)."""

    step_freq_hz: float
    leg_length_m: float = 0.92
    pendulum_correction: float = 1.25
    excursion_variability: float = 0.10
    lateral_sway_m_s2: float = 0.7
    yaw_sway_rad: float = math.radians(4.0)
    roll_sway_rad: float = math.radians(2.0)
    pitch_sway_rad: float = math.radians(1.5)
    timing_jitter: float = 0.03
    cadence_speed_exponent: float = 0.4

    def __post_init__(self):
        if not 1.0 <= self.step_freq_hz <= 3.0:
            raise ValueError(f"step_freq_hz must lie in [1, 3], got {self.step_freq_hz}")
        if not 0.6 <= self.leg_length_m <= 1.2:
            raise ValueError(f"leg_length_m must lie in [0.6, 1.2], got {self.leg_length_m}")
        if not 1.0 <= self.pendulum_correction <= 1.6:
            raise ValueError(f"pendulum_correction must lie in [1, 1.6], got {self.pendulum_correction}")
        if not 0.0 <= self.excursion_variability < 0.3:
            raise ValueError(f"excursion_variability must lie in [0, 0.3), got {self.excursion_variability}")
        if not 0.0 <= self.timing_jitter < 0.2:
            raise ValueError(f"timing_jitter must lie in [0, 0.2), got {self.timing_jitter}")

    def cadence_hz(self, speed_m_s: np.ndarray) -> np.ndarray:
        """Step frequency at the given speed, Hz: f_p·(v/1.25)^0.4, speed clipped to [0.5, 2] m/s."""
        v = np.clip(np.asarray(speed_m_s, dtype=float), 0.5, 2.0)
        return self.step_freq_hz * (v / REFERENCE_SPEED_M_S) ** self.cadence_speed_exponent

    def excursion_m(self, step_length_m: np.ndarray) -> np.ndarray:
        """Pelvis rise h over a step of length S: h = l − sqrt(l² − (S/2γ)²), m (Zijlstra & Hof 1997).

        >>> g = Gait(step_freq_hz=1.8, leg_length_m=0.9, pendulum_correction=1.25)
        >>> round(float(g.excursion_m(np.array([0.7]))[0]), 4)
        0.0447
        """
        half = np.minimum(np.asarray(step_length_m, float) / (2.0 * self.pendulum_correction),
                          0.95 * self.leg_length_m)
        return self.leg_length_m - np.sqrt(self.leg_length_m ** 2 - half ** 2)


def person_gait(person_seed: int) -> Gait:
    """The gait of person ``person_seed``: cadence U(1.6, 2.0) Hz, leg length U(0.85, 1.0) m,
    pendulum correction γ U(1.15, 1.35), sway amplitudes."""
    rng = stream_rng(person_seed, "person")
    return Gait(
        step_freq_hz=float(rng.uniform(1.6, 2.0)),
        leg_length_m=float(rng.uniform(0.85, 1.0)),
        pendulum_correction=float(rng.uniform(1.15, 1.35)),
        lateral_sway_m_s2=float(rng.uniform(0.5, 0.9)),
        yaw_sway_rad=math.radians(float(rng.uniform(3.0, 5.0))),
        roll_sway_rad=math.radians(float(rng.uniform(1.5, 2.5))),
        pitch_sway_rad=math.radians(float(rng.uniform(1.0, 2.0))),
    )


@dataclass(frozen=True)
class SensorErrors:
    """Error model of the device (see module docstring for sources)."""

    acc_noise_m_s2: float = 0.02
    acc_bias_m_s2: float = 0.13
    acc_tc_m_s2_per_k: float = 0.01
    acc_range_m_s2: float = 16.0 * GRAVITY_M_S2
    gyro_noise_rad_s: float = math.radians(0.07)
    gyro_bias_rad_s: float = math.radians(1.0)
    gyro_tc_rad_s_per_k: float = math.radians(0.05)
    warmup_min_k: float = 3.0
    warmup_max_k: float = 10.0
    warmup_tau_s: float = 300.0
    mains_hz: float = 50.0
    mains_sigma_hz: float = 0.02
    busbar_current_a: float = 400.0
    mag_mains_gain: float = 0.3
    gyro_bias_walk_rad_s_sqrt_s: float = math.radians(0.002)
    gyro_range_rad_s: float = math.radians(2000.0)
    gyro_scale_error: float = 0.01
    mag_noise_ut: float = 0.4
    mag_hard_iron_ut: float = 1.5
    mag_soft_iron: float = 0.02
    mount_tilt_rad: float = math.radians(3.0)
    mount_yaw_rad: float = math.radians(5.0)

    def __post_init__(self):
        for name in ("acc_noise_m_s2", "acc_bias_m_s2", "gyro_noise_rad_s", "gyro_bias_rad_s", "gyro_scale_error",
                     "gyro_bias_walk_rad_s_sqrt_s", "mag_noise_ut", "mag_hard_iron_ut", "mag_soft_iron",
                     "mount_tilt_rad", "mount_yaw_rad", "acc_tc_m_s2_per_k", "gyro_tc_rad_s_per_k", "warmup_min_k",
                     "warmup_max_k", "warmup_tau_s", "mains_hz", "mains_sigma_hz", "busbar_current_a",
                     "mag_mains_gain"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"SensorErrors.{name} must be finite and >= 0, got {value}")
        if self.warmup_max_k < self.warmup_min_k or self.warmup_tau_s <= 0:
            raise ValueError("SensorErrors needs warmup_min_k <= warmup_max_k and warmup_tau_s > 0")
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
    the device and ``mount_yaw_rad`` the device's mounting yaw offset, kept
    for scoring (not written to imu.csv).
    """

    t_s: np.ndarray
    acc_m_s2: np.ndarray
    gyro_rad_s: np.ndarray
    mag_ut: np.ndarray
    mag_disturbance_ut: np.ndarray
    mount_yaw_rad: float = 0.0


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


def _pelvis_height(count: np.ndarray, steps: StepTruth, gait: Gait, rng: np.random.Generator,
                   fs: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pelvis height above its standing height z_up (m), the step excursion h_t (m), whether walking, and 2π·c,
    each (n,) at the IMU rate, from the step count ``count`` (n,); draws each step's excursion variability."""
    n = len(count)
    dt = 1.0 / fs
    # pelvis height z = h_k·(1 − cos 2πc)/2 over step k (inverted pendulum, Zijlstra & Hof 1997)
    n_steps = len(steps.step_length_m)
    h_step = gait.excursion_m(np.maximum(steps.step_length_m, MIN_EXCURSION_STEP_M))
    h_step = h_step * (1.0 + gait.excursion_variability * rng.standard_normal(n_steps).clip(-3, 3))
    k_idx = np.clip(np.ceil(count - 1e-9).astype(int) - 1, 0, max(n_steps - 1, 0))
    walking = (np.abs(np.gradient(count)) > 1e-9)
    h_t = h_step[k_idx].copy() if n_steps else np.zeros(n)
    two_pi_c = 2.0 * np.pi * count
    # gait initiation: the first step of a bout leaves quiet standing smoothly (window u², u the phase
    # in that step: no acceleration jump, hence no peak, when the person sets off; unchanged from its
    # heel strike on)
    bout = np.cumsum(np.diff(np.r_[0, walking.astype(np.int8)]) == 1)
    c0 = np.r_[0.0, count[np.diff(np.r_[0, walking.astype(np.int8)]) == 1]][bout]
    u = count - c0
    window = np.where(u < 1.0, u * u, 1.0)
    # gait termination: after a bout's last heel strike the pelvis motion runs on for one windowed cycle
    # ((1 − v)², v its phase) while the trailing leg is brought alongside, so the last heel strike is a
    # peak with both flanks, as in real records
    ends = np.nonzero(np.diff(walking.astype(np.int8)) == -1)[0] + 1
    phase = count.copy()
    for i in ends:
        f_last = float(np.abs(np.gradient(count, dt)[max(i - 5, 0):i]).mean()) if i > 0 else 0.0
        if f_last <= 0 or n_steps == 0:
            continue
        m = min(int(round(fs / f_last)), n - i)
        v = np.arange(1, m + 1) * f_last * dt
        v = v[v < 1.0]
        sl = slice(i, i + len(v))
        if walking[sl].any():
            continue
        phase[sl] = count[i] + v
        window[sl] = (1.0 - v) ** 2
        h_t[sl] = h_t[i - 1]
    z_up = h_t * 0.5 * (1.0 - np.cos(2.0 * np.pi * phase)) * window
    return z_up, h_t, walking, two_pi_c


def _sensor_errors(f_body: np.ndarray, gyro: np.ndarray, mag: np.ndarray, t: np.ndarray, dt: float,
                   errors: SensorErrors, rng: np.random.Generator, warm_rng: np.random.Generator):
    """The sensors' errors on the true specific force, body rate and field (each (n, 3)): turn-on biases,
    warm-up drift through the temperature coefficients, the gyro's bias walk and scale error, soft and hard
    iron, noise, range clipping. Returns (f_body, gyro, mag); f_body and gyro are changed in place."""
    n = len(t)
    d_temp = warmup_kelvin(t, errors, warm_rng)
    f_body += (rng.normal(0.0, errors.acc_bias_m_s2, size=3)
               + d_temp[:, None] * rng.normal(0.0, errors.acc_tc_m_s2_per_k, size=3)
               + rng.normal(0.0, errors.acc_noise_m_s2, size=(n, 3)))
    bias_g = (rng.normal(0.0, errors.gyro_bias_rad_s, size=3)
              + d_temp[:, None] * rng.normal(0.0, errors.gyro_tc_rad_s_per_k, size=3)
              + np.cumsum(rng.normal(0.0, errors.gyro_bias_walk_rad_s_sqrt_s * math.sqrt(dt), size=(n, 3)), axis=0))
    gyro *= 1.0 + rng.normal(0.0, errors.gyro_scale_error, size=3)
    gyro += bias_g + rng.normal(0.0, errors.gyro_noise_rad_s, size=(n, 3))
    soft = rng.normal(0.0, errors.mag_soft_iron, size=(3, 3))
    mag = mag @ (np.eye(3) + 0.5 * (soft + soft.T)).T + rng.normal(0.0, errors.mag_hard_iron_ut, size=3)
    mag += rng.normal(0.0, errors.mag_noise_ut, size=(n, 3))
    np.clip(f_body, -errors.acc_range_m_s2, errors.acc_range_m_s2, out=f_body)
    np.clip(gyro, -errors.gyro_range_rad_s, errors.gyro_range_rad_s, out=gyro)
    return f_body, gyro, mag


def synthesise_imu(traj: Trajectory, site: Site, gait: Gait, steps: StepTruth, count: np.ndarray,
                   rng: np.random.Generator, errors: SensorErrors = SensorErrors()) -> ImuSamples:
    """Specific force, body rate and magnetic field of the waist device along ``traj``.

    ``steps`` and ``count`` come from :func:`place_steps`; ``rng`` draws the
    per-step excursion variability, the device's mounting tilt and yaw, and
    the sensor errors.
    """
    t = np.asarray(traj.t_s, dtype=float)
    fs = traj.rate_hz
    dt = 1.0 / fs
    z_up, h_t, walking, two_pi_c = _pelvis_height(count, steps, gait, rng, fs)
    a_up = np.gradient(np.gradient(z_up, dt), dt)
    envelope = np.clip(_smooth(walking.astype(float), 0.15 * fs), 0.0, 1.0)
    freq = np.gradient(count, dt)
    amp_smooth = _smooth(h_t * 2.0 * np.pi ** 2 * freq ** 2, 0.1 * fs)
    a_fwd = -0.5 * amp_smooth * np.sin(two_pi_c) * envelope
    a_lat = gait.lateral_sway_m_s2 * np.sin(0.5 * two_pi_c) * envelope

    # route heading: unwrap and smooth over 0.3 s (the body turns over a finite time)
    travel = _smooth(np.unwrap(np.asarray(traj.heading_rad, dtype=float)), 0.3 * fs)
    mount_roll, mount_pitch = rng.normal(0.0, errors.mount_tilt_rad, size=2)
    mount_yaw = rng.normal(0.0, errors.mount_yaw_rad)
    yaw = travel + mount_yaw + gait.yaw_sway_rad * np.sin(0.5 * two_pi_c) * envelope
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
    dipoles = site_steel_dipoles(site)
    pos_ned = np.stack([traj.north_m, traj.east_m, -np.asarray(traj.up_m, float)], axis=1)
    dist = disturbance_ned_ut(dipoles, pos_ned)
    mag = np.einsum("nji,nj->ni", c_bn, b_earth[None, :] + dist)

    # Child streams for the warm-up and mains draws (spawning does not advance ``rng``, so the other
    # sensor draws stay as they were).
    warm_rng, mains_rng = rng.spawn(2)
    # 50 Hz fields of the busbars (sampled, aliased, at the IMU rate), in the body frame
    mag = mag + np.einsum("nji,nj->ni", c_bn, mains_field_ned_ut(site, pos_ned, t, errors, mains_rng))

    f_body, gyro, mag = _sensor_errors(f_body, gyro, mag, t, dt, errors, rng, warm_rng)
    return ImuSamples(t, f_body, gyro, mag, np.linalg.norm(dist, axis=1), float(mount_yaw))


def warmup_kelvin(t_s: np.ndarray, errors: SensorErrors, rng: np.random.Generator) -> np.ndarray:
    """Sensor temperature rise after power-on, K, shape (n,): ΔT(t) = ΔT∞·(1 − exp(−t/τ)), ΔT∞ ~ U(min, max).

    A device switched on and clipped to the waist warms from ambient towards
    body and electronics heat over minutes (first-order thermal response); its
    biases follow through the data sheet's temperature coefficients (BMI160:
    gyro zero-rate offset ±0.05 °/s/K, accelerometer ±1 mg/K; Bosch BST-BMI160-DS000).
    """
    d_inf = rng.uniform(errors.warmup_min_k, errors.warmup_max_k)
    return d_inf * (1.0 - np.exp(-(np.asarray(t_s, float) - float(t_s[0])) / errors.warmup_tau_s))


def mains_field_ned_ut(site: Site, pos_ned_m: np.ndarray, t_s: np.ndarray, errors: SensorErrors,
                       rng: np.random.Generator) -> np.ndarray:
    """The 50 Hz magnetic field of the busbars at the device, sampled at ``t_s``, µT NED, shape (n, 3).

    Each gantry carries a busbar along its long axis at its top: an infinite
    straight line current, B = μ0·I/(2π·r) along l̂ × r̂ (Biot–Savart), with a
    random phase per busbar (three phases) and the mains frequency f = 50 Hz +
    N(0, σ) of the day. The magnetometer samples at 100 Hz — exactly twice
    50 Hz — so the tone aliases to a ±alternating sample pattern whose envelope
    beats at |f − 50|·… Hz; its digital filter passes ``mag_mains_gain`` of it
    (a modelling choice for a BMM150/AK09916-class sensor at 100 Hz output).
    """
    n = len(t_s)
    out = np.zeros((n, 3))
    if errors.busbar_current_a <= 0 or errors.mag_mains_gain <= 0:
        return out
    f = errors.mains_hz + rng.normal(0.0, errors.mains_sigma_hz)
    mu0_over_2pi = 2e-7
    for b in site.layout:
        if b.kind != "gantry":
            continue
        along_east = (b.east_max_m - b.east_min_m) >= (b.north_max_m - b.north_min_m)
        line_dir = np.array([0.0, 1.0, 0.0]) if along_east else np.array([1.0, 0.0, 0.0])  # NED
        point = np.array([0.5 * (b.north_min_m + b.north_max_m), 0.5 * (b.east_min_m + b.east_max_m), -b.height_m])
        r = pos_ned_m - point[None, :]
        r = r - (r @ line_dir)[:, None] * line_dir[None, :]
        dist = np.maximum(np.linalg.norm(r, axis=1), 0.5)
        direction = np.cross(line_dir[None, :], r / dist[:, None])
        amp_ut = mu0_over_2pi * errors.busbar_current_a / dist * 1e6
        phase = rng.uniform(0.0, 2.0 * np.pi)
        out += (errors.mag_mains_gain * amp_ut * np.sin(2.0 * np.pi * f * np.asarray(t_s, float) + phase))[:, None] \
            * direction
    return out


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
