"""A foot-mounted IMU at the right ankle: stance phases from the walker's gait, ``imu_foot.csv``.

Writer for :data:`simulation.streams.STREAM_WRITERS` (survey cells get nothing). The heel strikes are the
walker's own (:func:`simulation.imu.walker.place_steps` with the waist stream's seed, so both IMUs see the
same steps); every other one is the right foot's.

Foot motion (a rigid foot with heel, ankle and toe; Perry & Burnfield 2010, *Gait Analysis: Normal and
Pathological Function*, 2nd ed., ch. 1–2: stance ≈ 60 % of the gait cycle, swing ≈ 40 %; the heel, ankle
and forefoot rockers):

* footfall j lands where the pelvis passes over it at mid-stance (the waist path 30 % of a stride after
  the heel strike), ``lateral_m`` to the right of the path, its yaw the walking direction plus the
  person's toe-out angle;
* heel rocker: from the heel strike the foot rotates about the heel from +``heel_strike_pitch`` (toes up)
  to flat over 10 % of a stride; foot flat (the ZUPT's stance) until the forefoot rocker, in which it
  rotates about the toe to ``toe_off_pitch`` over 15 % of a stride; the swing (≤ 40 % of a nominal stride)
  carries the ankle to the next footfall on a minimum-jerk profile s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ (Flash &
  Hogan 1985, J. Neurosci. 5(7)) with a clearance bump and the yaw turning; every phase starts and ends
  at rest, so position and velocity are continuous (the heel strike's impact shock is left out);
* standing stops and the ends of the walk keep the foot flat and still.

The motion is built at an internal rate of at least 400 Hz (twice the output), differentiated (specific
force f_b = Cᵀ(a_n − g_n), body rate from C_kᵀ Ċ), and block-averaged to the output rate as an IMU's
decimation filter does, each sample stamped at the end of its interval. Earth rate is added to the gyro; the magnetometer reads the site's Earth field
(:func:`simulation.imu.magnetic.earth_field_ned_ut`) plus the steel disturbances at the foot.

Sensor errors of an SBG Ellipse2-A class MEMS IMU (the seed paper's sensor; SBG Systems, *Ellipse 2 Series
leaflet / datasheet*, 2017, as quoted there: gyro in-run bias instability 8 °/h, angular random walk
0.18 °/√h, range ±450 °/s; accelerometer in-run bias instability 14 µg, velocity random walk
0.03 m/s/√h, range ±16 g; magnetometer noise 1 mG): white noise of those densities (σ = N·√f_s), in-run
biases as first-order Gauss–Markov processes of those σ with τ = 100 s, turn-on bias residuals after the
factory calibration (0.05 °/s gyro, 2 mg accelerometer: assumptions, the datasheet states no repeatability
figure), scale errors 0.1 %, clipping at the ranges, magnetometer hard-iron residual 0.5 µT and
soft-iron 1 %, and a strap misalignment N(0, 3°) per axis.

Random draws: footfall placement from ``stream_rng(seed, "imu_foot", "gait")``, sensor errors from
``stream_rng(seed, "imu_foot", "sensor")``; the person's toe-out from ``stream_rng(person_seed,
"foot")``. ``walk.toml`` gets ``[imu_foot] file, rate_hz, body_frame = "FLU", placement = "right ankle",
declination_deg`` (the waist IMU's stated declination).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from features.constants import GRAVITY_M_S2, OMEGA_EARTH_RAD_S
from features.errors import ConfigError
from features.fileio import atomic_write_text
from features.site import Site

from simulation.imu.magnetic import disturbance_ned_ut, earth_field_ned_ut, field_elements, site_steel_dipoles
from simulation.imu.stream import IMU_RATE_HZ, csv_rows, stated_declination_error_deg
from simulation.imu.walker import ImuSamples, person_gait, place_steps
from simulation.rng import stream_rng
from simulation.streams import StreamContext, Trajectory

__all__ = ["FootGait", "FootErrors", "FootMotion", "foot_motion", "synthesise_foot_imu", "simulate_foot_imu",
           "foot_csv_text", "write_imu_foot", "IMU_FOOT_FILE", "FOOT_RATE_HZ", "FOOT_RATES_HZ"]

IMU_FOOT_FILE = "imu_foot.csv"
FOOT_RATE_HZ = 100.0
"""Default output rate, Hz (the seed paper's Ellipse2-A at 100 Hz); ``options['foot_imu_rate_hz']`` sets it."""
FOOT_RATES_HZ = (100.0, 400.0)
"""Rates the writer accepts, Hz."""


@dataclass(frozen=True)
class FootGait:
    """Foot geometry and rocker angles (Perry & Burnfield 2010; module docstring). Lengths m, angles rad;
    ``r_heel`` and ``r_toe`` are the ankle's (forward, up) offsets from the heel and toe contact points."""

    r_heel: tuple = (0.06, 0.08)
    r_toe: tuple = (-0.14, 0.08)
    heel_strike_pitch_rad: float = math.radians(15.0)
    toe_off_pitch_rad: float = math.radians(-30.0)
    clearance_m: float = 0.10
    lateral_m: float = 0.10
    heel_rocker: float = 0.10
    toe_rocker: float = 0.15
    swing: float = 0.40
    toe_out_rad: float = math.radians(7.0)


@dataclass(frozen=True)
class FootErrors:
    """SBG Ellipse2-A class sensor errors (module docstring). Densities per √Hz, biases σ."""

    acc_vrw_m_s2_sqrt_hz: float = 0.03 / 60.0
    acc_bias_instability_m_s2: float = 14e-6 * GRAVITY_M_S2
    acc_turn_on_m_s2: float = 2e-3 * GRAVITY_M_S2
    acc_range_m_s2: float = 16.0 * GRAVITY_M_S2
    gyro_arw_rad_s_sqrt_hz: float = math.radians(0.18) / 60.0
    gyro_bias_instability_rad_s: float = math.radians(8.0 / 3600.0)
    gyro_turn_on_rad_s: float = math.radians(0.05)
    gyro_range_rad_s: float = math.radians(450.0)
    bias_tau_s: float = 100.0
    scale_error: float = 1e-3
    mag_noise_ut: float = 0.1
    mag_hard_iron_ut: float = 0.5
    mag_soft_iron: float = 0.01
    misalignment_rad: float = math.radians(3.0)

    def __post_init__(self):
        for name, v in vars(self).items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"FootErrors.{name} must be finite and >= 0, got {v}")


@dataclass(frozen=True)
class FootMotion:
    """True motion of the foot IMU at ``rate_hz``: ``t_s`` (n,), ``pos_enu_m`` (n, 3), ``C_bn`` (n, 3, 3)
    (body FLU → ENU), ``flat`` (n,) bool (foot flat and still), ``heel_strikes_s`` (m,) of the right foot."""

    t_s: np.ndarray
    pos_enu_m: np.ndarray
    C_bn: np.ndarray
    flat: np.ndarray
    heel_strikes_s: np.ndarray
    rate_hz: float


def _minjerk(u):
    """s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on τ ∈ [0, 1] (Flash & Hogan 1985), clipped outside."""
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)


def _rotate(r, pitch):
    """(forward, up) offset ``r`` of a foot pitched by ``pitch`` (toes up positive)."""
    c, s = np.cos(pitch), np.sin(pitch)
    return r[0] * c - r[1] * s, r[0] * s + r[1] * c


def _footfalls(traj: Trajectory, strikes: np.ndarray, stride_s: float, fg: FootGait, toe_out: float):
    """Positions (m, 2) and yaws (m,) of the footfalls: the initial stance, then one per right heel strike."""
    t_mid = np.r_[traj.t_s[0], strikes + 0.3 * stride_s]
    e, n, _ = traj.interp(t_mid)
    psi = np.interp(t_mid, traj.t_s, np.unwrap(traj.heading_rad))
    right = np.column_stack([np.cos(psi), -np.sin(psi)])             # unit vector to the walker's right (E, N)
    pos = np.column_stack([e, n]) + fg.lateral_m * right
    return pos, psi + toe_out


def foot_motion(traj: Trajectory, strikes: np.ndarray, stride_s: float, rate_hz: float, fg: FootGait = FootGait(),
                toe_out_rad: float | None = None) -> FootMotion:
    """The right foot's true motion (module docstring) along ``traj`` with heel strikes ``strikes`` (s) and a
    nominal stride of ``stride_s``, sampled at ``rate_hz``."""
    toe_out = fg.toe_out_rad if toe_out_rad is None else toe_out_rad
    t = np.arange(traj.t_s[0], traj.t_s[-1] + 1e-9, 1.0 / rate_hz)
    n = len(t)
    pos_fl, yaw_fl = _footfalls(traj, strikes, stride_s, fg, toe_out)
    fwd = np.zeros(n)       # along-foot offset of the ankle from the footfall point
    up = np.full(n, fg.r_heel[1])
    pitch = np.zeros(n)
    E = np.full(n, pos_fl[0, 0])
    N = np.full(n, pos_fl[0, 1])
    yaw = np.full(n, yaw_fl[0])
    flat = np.ones(n, bool)
    r_h, r_t = np.asarray(fg.r_heel), np.asarray(fg.r_toe)
    # Footfall j's phases cover [t_to0, ∞) and footfall j + 1's start after its heel strike (t_to0 of j + 1 >
    # hs_prev + 0.3·(t_hs − hs_prev)), so footfall j's stance is written only up to where footfall j + 1's
    # phases write it again (its toe-off rocker; its swing for E, N, yaw, which the rocker keeps): index
    # ranges of the sorted grid (the first sample at or after a time) instead of masks over the whole walk.
    hs_prev = [max(h, t[0] - 1.0) for h in np.r_[-np.inf, strikes[:-1]]]   # the previous heel strike (or t0 − 1 s)
    d_sw_all = [min(fg.swing * stride_s, 0.4 * (t_hs - p)) for t_hs, p in zip(strikes, hs_prev)]
    d_to_all = [min(fg.toe_rocker * stride_s, 0.3 * (t_hs - p)) for t_hs, p in zip(strikes, hs_prev)]
    t_sw0_all = [t_hs - d_sw for t_hs, d_sw in zip(strikes, d_sw_all)]
    t_to0_all = [t_sw0 - d_to for t_sw0, d_to in zip(t_sw0_all, d_to_all)]

    def at(x: float) -> int:
        """Index of the first sample at or after time ``x`` (t is sorted)."""
        return int(np.searchsorted(t, x, side="left"))

    for j, t_hs in enumerate(strikes):
        # swing into footfall j + 1 (footfall 0 is the initial stance)
        d_sw, d_to, t_sw0, t_to0 = d_sw_all[j], d_to_all[j], t_sw0_all[j], t_to0_all[j]
        stop = at(t_to0_all[j + 1]) if j + 1 < len(strikes) else n     # the next footfall's phases from here
        stop_en = at(t_sw0_all[j + 1]) if j + 1 < len(strikes) else n   # ... its swing
        a, b = pos_fl[j], pos_fl[j + 1]
        ya, yb = yaw_fl[j], yaw_fl[j + 1]
        # forefoot rocker about the toe of footfall j
        m = slice(at(t_to0), at(t_sw0))
        th = fg.toe_off_pitch_rad * _minjerk((t[m] - t_to0) / d_to)
        f0, u0 = _rotate(r_t, th)
        # the ankle's forward offset from its flat position, its height
        pitch[m], fwd[m], up[m], flat[m] = th, f0 - r_t[0], u0, False
        # swing: ankle from the toe-off pose to the heel-strike pose of footfall j + 1
        m = slice(at(t_sw0), at(t_hs))
        s = _minjerk((t[m] - t_sw0) / d_sw)
        f_to, u_to = _rotate(r_t, fg.toe_off_pitch_rad)
        f_hs, u_hs = _rotate(r_h, fg.heel_strike_pitch_rad)
        pitch[m] = fg.toe_off_pitch_rad + (fg.heel_strike_pitch_rad - fg.toe_off_pitch_rad) * s
        yaw[m] = ya + (yb - ya) * s
        dir_a = np.array([math.sin(ya), math.cos(ya)])
        dir_b = np.array([math.sin(yb), math.cos(yb)])
        start = a + dir_a * (f_to - r_t[0])
        end = b + dir_b * (f_hs - r_h[0])
        E[m] = start[0] + (end[0] - start[0]) * s
        N[m] = start[1] + (end[1] - start[1]) * s
        fwd[m] = 0.0
        up[m] = u_to + (u_hs - u_to) * s + fg.clearance_m * 16.0 * s * s * (1 - s) ** 2
        flat[m] = False
        # heel rocker of footfall j + 1, then flat on it (until the next footfall's toe-off rocker)
        d_hr = fg.heel_rocker * stride_s
        i_hs = at(t_hs)
        m = slice(i_hs, max(stop_en, i_hs))
        E[m], N[m], yaw[m] = b[0], b[1], yb
        m = slice(i_hs, max(stop, i_hs))
        up[m], fwd[m], pitch[m], flat[m] = r_h[1], 0.0, 0.0, True
        m = slice(i_hs, max(min(at(t_hs + d_hr), stop), i_hs))
        th = fg.heel_strike_pitch_rad * (1.0 - _minjerk((t[m] - t_hs) / d_hr))
        f0, u0 = _rotate(r_h, th)
        pitch[m], fwd[m], up[m], flat[m] = th, f0 - r_h[0], u0, False
    dir_e, dir_n = np.sin(yaw), np.cos(yaw)
    pos = np.column_stack([E + fwd * dir_e, N + fwd * dir_n, up])
    # body FLU in ENU: x = forward pitched, y = left, z = x × y
    cp, sp = np.cos(pitch), np.sin(pitch)
    x_b = np.column_stack([cp * dir_e, cp * dir_n, sp])
    y_b = np.column_stack([-dir_n, dir_e, np.zeros(n)])
    C = np.stack([x_b, y_b, np.cross(x_b, y_b)], axis=2)
    return FootMotion(t, pos, C, flat, np.asarray(strikes, float), rate_hz)


def _body_rate(C: np.ndarray, dt: float) -> np.ndarray:
    """ω_b (n, 3) from body → ENU matrices C (n, 3, 3): [ω×] = Cᵀ Ċ (central differences, antisymmetric part)."""
    dC = np.gradient(C, dt, axis=0)
    W = np.einsum("nji,njk->nik", C, dC)
    W = 0.5 * (W - np.transpose(W, (0, 2, 1)))
    return np.column_stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]])


def _block_mean(x: np.ndarray, k: int) -> np.ndarray:
    """Means of consecutive blocks of ``k`` rows (an IMU's decimation filter); a partial last block dropped."""
    m = len(x) // k
    return x[: m * k].reshape(m, k, *x.shape[1:]).mean(axis=1)


def _gauss_markov(rng: np.random.Generator, n: int, dt: float, sigma: float, tau_s: float) -> np.ndarray:
    """(n, 3) first-order Gauss–Markov process of stationary σ and correlation time τ (Gelb 1974, ch. 3)."""
    phi = math.exp(-dt / tau_s)
    w = rng.normal(0.0, sigma * math.sqrt(1.0 - phi * phi), size=(n, 3))
    return _ar1(phi, rng.normal(0.0, sigma, size=3), w)


@njit(cache=True)
def _ar1(phi: float, x0: np.ndarray, w: np.ndarray) -> np.ndarray:
    """x[0] = x0, x[k] = φ·x[k−1] + w[k] (k ≥ 1), per column of ``w`` (n, 3)."""
    x = np.empty_like(w)
    if len(w):
        x[0] = x0
    for k in range(1, len(w)):
        for c in range(w.shape[1]):
            x[k, c] = phi * x[k - 1, c] + w[k, c]
    return x


def synthesise_foot_imu(motion: FootMotion, site: Site, out_rate_hz: float, rng: np.random.Generator,
                        errors: FootErrors = FootErrors()) -> ImuSamples:
    """The foot IMU's output at ``out_rate_hz`` from its true ``motion`` (internal rate an integer multiple)."""
    k = int(round(motion.rate_hz / out_rate_hz))
    if k < 1 or abs(k * out_rate_hz - motion.rate_hz) > 1e-6:
        raise ValueError(f"internal rate {motion.rate_hz} Hz must be a multiple of the output rate {out_rate_hz} Hz")
    dt = 1.0 / motion.rate_hz
    # the body → ENU matrix with the strap's misalignment (a constant rotation of the IMU in the foot)
    ang = rng.normal(0.0, errors.misalignment_rad, size=3)
    c, s = np.cos(ang), np.sin(ang)
    Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    C = motion.C_bn @ (Rz @ Ry @ Rx)
    pos = ndimage.gaussian_filter1d(motion.pos_enu_m, 0.002 * motion.rate_hz, axis=0, mode="nearest")
    acc_n = np.gradient(np.gradient(pos, dt, axis=0), dt, axis=0)
    # f_b = Cᵀ (a_n − g_n), g_n = (0, 0, −g)
    f_b = np.einsum("nji,nj->ni", C, acc_n + np.array([0.0, 0.0, GRAVITY_M_S2]))
    lat = math.radians(site.origin.lat_deg)
    w_ie = OMEGA_EARTH_RAD_S * np.array([0.0, math.cos(lat), math.sin(lat)])
    w_b = _body_rate(C, dt) + np.einsum("nji,j->ni", C, w_ie)
    b_ned = earth_field_ned_ut(site.origin.lat_deg, site.origin.lon_deg)
    pos_ned = np.column_stack([motion.pos_enu_m[:, 1], motion.pos_enu_m[:, 0], -motion.pos_enu_m[:, 2]])
    d_ned = disturbance_ned_ut(site_steel_dipoles(site), pos_ned)
    b_enu = np.column_stack([b_ned[1] + d_ned[:, 1], b_ned[0] + d_ned[:, 0], -(b_ned[2] + d_ned[:, 2])])
    m_b = np.einsum("nji,nj->ni", C, b_enu)
    f_b, w_b, m_b = _block_mean(f_b, k), _block_mean(w_b, k), _block_mean(m_b, k)
    # a sample is the mean over its interval, stamped at the interval's end (the strapdown's convention)
    t = _block_mean(motion.t_s, k) + 0.5 * (k + 1) * dt
    n, fs, odt = len(t), out_rate_hz, 1.0 / out_rate_hz
    # sensor errors: turn-on bias, in-run bias (Gauss–Markov), scale, white noise σ = N·√f_s, clipping
    f_b = (f_b * (1.0 + rng.normal(0.0, errors.scale_error, size=3)) + rng.normal(0.0, errors.acc_turn_on_m_s2, 3)
           + _gauss_markov(rng, n, odt, errors.acc_bias_instability_m_s2, errors.bias_tau_s)
           + rng.normal(0.0, errors.acc_vrw_m_s2_sqrt_hz * math.sqrt(fs), size=(n, 3)))
    w_b = (w_b * (1.0 + rng.normal(0.0, errors.scale_error, size=3)) + rng.normal(0.0, errors.gyro_turn_on_rad_s, 3)
           + _gauss_markov(rng, n, odt, errors.gyro_bias_instability_rad_s, errors.bias_tau_s)
           + rng.normal(0.0, errors.gyro_arw_rad_s_sqrt_hz * math.sqrt(fs), size=(n, 3)))
    soft = rng.normal(0.0, errors.mag_soft_iron, size=(3, 3))
    m_b = (m_b @ (np.eye(3) + 0.5 * (soft + soft.T)).T + rng.normal(0.0, errors.mag_hard_iron_ut, 3)
           + rng.normal(0.0, errors.mag_noise_ut, size=(n, 3)))
    np.clip(f_b, -errors.acc_range_m_s2, errors.acc_range_m_s2, out=f_b)
    np.clip(w_b, -errors.gyro_range_rad_s, errors.gyro_range_rad_s, out=w_b)
    return ImuSamples(t, f_b, w_b, m_b, np.linalg.norm(_block_mean(d_ned, k), axis=1), float(ang[2]))


def _traj_at(traj: Trajectory, rate_hz: float) -> Trajectory:
    """The trajectory at ``rate_hz`` (linear interpolation, heading unwrapped) — the waist stream's grid."""
    if abs(traj.rate_hz - rate_hz) < 1e-9:
        return traj
    t = np.arange(traj.t_s[0], traj.t_s[-1] + 1e-9, 1.0 / rate_hz)
    e, n, u = traj.interp(t)
    h = np.mod(np.interp(t, traj.t_s, np.unwrap(traj.heading_rad)), 2 * np.pi)
    return Trajectory(t, e, n, u, h, np.interp(t, traj.t_s, traj.speed_m_s), traj.start_utc, rate_hz)


def simulate_foot_imu(ctx: StreamContext, rate_hz: float = FOOT_RATE_HZ, fg: FootGait = FootGait(),
                      errors: FootErrors = FootErrors()) -> tuple[ImuSamples, FootMotion]:
    """The foot IMU's samples and its true motion for the context's walk (no files)."""
    traj = _traj_at(ctx.trajectory, IMU_RATE_HZ)
    gait = person_gait(ctx.person_seed)
    steps, _ = place_steps(traj, gait, stream_rng(ctx.seed, "imu", "steps"))   # the waist stream's steps
    strikes = steps.t_s[0::2]
    stride_s = 2.0 / gait.step_freq_hz
    toe_out = fg.toe_out_rad + math.radians(float(stream_rng(ctx.person_seed, "foot").normal(0.0, 3.0)))
    internal = rate_hz * max(2, int(math.ceil(400.0 / rate_hz)))
    motion = foot_motion(traj, strikes, stride_s, internal, fg, toe_out)
    imu = synthesise_foot_imu(motion, ctx.site, rate_hz, stream_rng(ctx.seed, "imu_foot", "sensor"), errors)
    return imu, motion


def foot_csv_text(imu: ImuSamples) -> str:
    """``t_s,ax,ay,az,gx,gy,gz,mx,my,mz`` rows (m/s², rad/s, µT), the columns of ``imu.csv``."""
    return "t_s,ax,ay,az,gx,gy,gz,mx,my,mz\n" + csv_rows(
        np.column_stack([imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut]),
        ["%.4f"] + ["%.5f"] * 3 + ["%.6f"] * 3 + ["%.3f"] * 3)


def write_imu_foot(ctx: StreamContext) -> dict:
    """Write ``imu_foot.csv`` for a walk (``options['foot_imu_rate_hz']``, 100 or 400 Hz); nothing for a survey."""
    if ctx.kind == "survey":
        return {}
    rate = float(ctx.options.get("foot_imu_rate_hz", FOOT_RATE_HZ))
    if rate not in FOOT_RATES_HZ:
        raise ConfigError(f"foot_imu_rate_hz must be one of {FOOT_RATES_HZ}, got {rate}")
    imu, _ = simulate_foot_imu(ctx, rate)
    atomic_write_text(ctx.out_dir / IMU_FOOT_FILE, foot_csv_text(imu))
    decl, _, _ = field_elements(earth_field_ned_ut(ctx.site.origin.lat_deg, ctx.site.origin.lon_deg))
    return {"imu_foot": {"file": IMU_FOOT_FILE, "rate_hz": rate, "body_frame": "FLU", "placement": "right ankle",
                         "declination_deg": round(math.degrees(decl) + stated_declination_error_deg(ctx.seed), 3)}}
