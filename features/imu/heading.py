"""Heading of a body-fixed IMU: gyro, tilt-compensated magnetometer, and their complementary filter.

Conventions: body frame forward-right-down (x = the device's forward axis);
heading ψ of the x axis from true north, clockwise, radians (docs/design.md §3);
accelerometer reads specific force (≈ −g·down at rest).

- Tilt: the down direction in the body frame is minus the normalised
  low-passed specific force (0.3 Hz zero-phase Butterworth: walking
  accelerations at ≥ 0.8 Hz average out).
- Gyro heading rate: ψ̇ = d_b · ω_b (the component of the body rate about the
  vertical); integrated from the initial heading, with the turn-on bias
  removed when the record starts with ≥ 1 s standing still.
- Magnetometer heading (tilt-compensated): horizontal field
  h = m − (m·d)d; with n = h/|h| and e = d × n, ψ_m = atan2(x·e, x·n) + D,
  D the declination (Caruso 1997, "Applications of magnetoresistive sensors
  in navigation systems", SAE 970602, eqs. 1-3, in vector form).
- Complementary filter: Mahony, Hamel & Pflimlin (2008, IEEE TAC 53(5),
  "Nonlinear complementary filters on the special orthogonal group", passive
  filter with bias estimation, eqs. 32-33) restricted to the vertical axis:
      e_k = ψ_m,k − ψ_{k−1}
      ψ_k = ψ_{k−1} + Δt·(r_k − b_{k−1} + kP·e_k)
      b_k = b_{k−1} − Δt·kI·e_k
  Restricted to yaw with an unwrapped ψ_m this is a linear time-invariant
  system, so it runs as two IIR filters (``scipy.signal.lfilter``, compiled)
  instead of a per-sample loop.
- Magnetic disturbance gate: where the field's intensity departs from its
  median over the record's first :data:`GATE_REFERENCE_S` by more than 5 % or its
  dip by more than 3° (steel,
  transformers), the magnetometer heading is replaced by the gyro-propagated
  heading from the last undisturbed sample, so the filter coasts on the gyro
  there (the idea of imufusion's magnetic rejection, Madgwick 2020). A second
  gate flags spells where the magnetometer heading turns while the gyro does
  not (quasi-static field test, see :func:`_inconsistent_with_gyro`).
- Resuming: every quantity above is either local in time (the low-pass filters'
  transients last seconds) or a state (ψ, b, the gyro heading, the gate's
  offset) or a statistic of the record's start (the turn-on bias, the gate's
  reference field), so a record cut into pieces is run piece by piece from
  the :class:`HeadingState` the previous piece reached (:meth:`HeadingResult.state_at`)
  and gives the headings of the whole record (a long walk's segments,
  ``walks/segments.py``), up to the low-pass transients at the piece's start.

Why not a library: ``ahrs.filters.Mahony`` runs a Python loop (≈ 20 µs per
sample here, 500× real time at 100 Hz); ``imufusion.Ahrs`` is compiled C but
called once per sample from Python (≈ 3 µs); this linear form runs at
≈ 0.1 µs per sample, which the 2,000× real-time target for the whole PDR path
needs. :func:`imufusion_heading` runs imufusion's AHRS for comparison.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, signal

from features.errors import ConfigError

__all__ = ["HeadingConfig", "HeadingResult", "HeadingState", "GATE_REFERENCE_S", "down_in_body", "yaw_rate", "magnetic_heading",
           "complementary_heading", "estimate_heading", "imufusion_heading", "wrap_pi"]


def wrap_pi(angle_rad):
    """Wrap to (−π, π].

    >>> round(float(wrap_pi(3 * math.pi / 2)), 6)
    -1.570796
    """
    return np.angle(np.exp(1j * np.asarray(angle_rad, dtype=float)))


@dataclass(frozen=True)
class HeadingConfig:
    """Heading estimation parameters.

    ``kp_per_s`` / ``ki_per_s2``: Mahony gains. Time constant 1/kP = 50 s,
    longer than a walker spends passing one transformer, so residual
    (ungated) disturbances average out while gyro drift over minutes is
    corrected; kI = kP²/4 makes the yaw loop critically damped.
    """

    declination_rad: float = 0.0
    gravity_lowpass_hz: float = 0.3
    mag_lowpass_hz: float = 1.0
    kp_per_s: float = 0.02
    ki_per_s2: float = 0.0001
    gate_intensity_frac: float = 0.05
    gate_dip_rad: float = math.radians(3.0)
    static_start_s: float = 1.0
    initial_heading_rad: float = 0.0
    consistency_window_s: float = 1.0
    consistency_rad: float = math.radians(2.0)

    def __post_init__(self):
        for name in ("gravity_lowpass_hz", "mag_lowpass_hz", "kp_per_s", "gate_intensity_frac", "gate_dip_rad",
                     "static_start_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"HeadingConfig.{name} must be positive, got {value}")
        if not (math.isfinite(self.ki_per_s2) and self.ki_per_s2 >= 0):
            raise ConfigError(f"HeadingConfig.ki_per_s2 must be >= 0, got {self.ki_per_s2}")
        if not math.isfinite(self.declination_rad) or not math.isfinite(self.initial_heading_rad):
            raise ConfigError("declination_rad and initial_heading_rad must be finite")


GATE_REFERENCE_S = 300.0
"""Span of the record's start whose median intensity and dip are the gate's undisturbed field, s: a statistic of
the walk's first minutes rather than of the whole record, so that a long walk read in pieces has the same gate
(the field of a site varies by far less than the gate's 5 % and 3° between its start and later)."""


@dataclass(frozen=True)
class HeadingState:
    """Where a heading run stood after one sample (:meth:`HeadingResult.state_at`), what a run over the samples
    that follow resumes from (:func:`estimate_heading`'s ``start``): the complementary filter's heading
    ``fused_rad`` and bias ``bias_rad_s``, the gyro-only heading ``gyro_rad``, the gate's magnetometer − gyro
    heading at the last undisturbed sample ``gate_offset_rad`` (NaN without magnetometer), and the record's
    start statistics: the turn-on bias ``static_bias_rad_s`` and the gate's reference ``intensity_ref`` (the
    field's intensity, the magnetometer's unit) and ``dip_ref_rad``."""

    fused_rad: float
    bias_rad_s: float
    gyro_rad: float
    gate_offset_rad: float
    static_bias_rad_s: float
    intensity_ref: float
    dip_ref_rad: float
    t_s: float = math.nan
    """Time of the sample the state follows (the record's time base; NaN: not stated)."""
    mag_rad: float = math.nan
    """The magnetometer heading at that sample (wrapped; NaN without magnetometer)."""
    mag_minus_gyro_rad: float = math.nan
    mag_minus_fused_rad: float = math.nan
    """The magnetometer heading less the gyro-only and the complementary heading there, unwrapped (each heading
    followed continuously from the run's start): what puts the resumed run's headings on the branch of its own
    unwrapped magnetometer heading as the whole run's stood, however far apart they drifted in a long disturbed
    spell (:func:`_integrate`). With them ``gate_offset_rad`` is unwrapped too."""


@dataclass(frozen=True)
class HeadingResult:
    """Per-sample headings, rad from true north clockwise, shape (n,) each (NaN where unavailable).

    ``fused`` (complementary), ``gyro_only``, ``mag_only``; ``mag_disturbed``
    bool (n,); ``gyro_bias_rad_s`` (n,) the filter's yaw-rate bias estimate; the record's start statistics the
    run used: ``static_bias_rad_s`` (the turn-on bias removed), the gate's ``intensity_ref`` and ``dip_ref_rad``.
    """

    fused: np.ndarray
    gyro_only: np.ndarray
    mag_only: np.ndarray
    mag_disturbed: np.ndarray
    gyro_bias_rad_s: np.ndarray
    static_bias_rad_s: float = 0.0
    intensity_ref: float = math.nan
    dip_ref_rad: float = math.nan
    start_gate_offset_rad: float = math.nan
    """The gate offset the run resumed from (:class:`HeadingState`), NaN for a run from the record's start."""
    mag_minus_gyro: np.ndarray | None = field(default=None, repr=False)
    mag_minus_fused: np.ndarray | None = field(default=None, repr=False)
    """(n,) the magnetometer heading less the gyro-only and the complementary heading, unwrapped (NaN where
    there is none; None without magnetometer): what :meth:`state_at` hands a resumed run."""

    def state_at(self, i: int, t_s: float = math.nan) -> HeadingState:
        """The run's state after sample ``i`` (at time ``t_s``); the gate's offset from the last undisturbed
        sample at or before it with a heading (else the offset this run resumed from, else the first sample's)."""
        good = np.flatnonzero(~self.mag_disturbed[:i + 1] & np.isfinite(self.gyro_only[:i + 1]))
        unwrapped = self.mag_minus_gyro is not None and self.mag_minus_fused is not None
        if good.size:
            offset = float(self.mag_minus_gyro[good[-1]]) if unwrapped else \
                float(wrap_pi(self.mag_only[good[-1]] - self.gyro_only[good[-1]]))
        elif math.isfinite(self.start_gate_offset_rad):
            offset = self.start_gate_offset_rad
        else:
            offset = float(self.mag_minus_gyro[0]) if unwrapped else float(wrap_pi(self.mag_only[0] - self.gyro_only[0]))
        extra = (float(self.mag_only[i]), float(self.mag_minus_gyro[i]), float(self.mag_minus_fused[i])) \
            if unwrapped else ()
        return HeadingState(float(self.fused[i]), float(self.gyro_bias_rad_s[i]), float(self.gyro_only[i]), offset,
                            self.static_bias_rad_s, self.intensity_ref, self.dip_ref_rad, float(t_s), *extra)


def _lowpass(x: np.ndarray, cutoff_hz: float, rate_hz: float) -> np.ndarray:
    sos = signal.butter(2, min(cutoff_hz, 0.45 * rate_hz), fs=rate_hz, output="sos")
    if len(x) <= 15:
        return np.array(x, dtype=float)
    return signal.sosfiltfilt(sos, x, axis=0)


def down_in_body(acc_m_s2: np.ndarray, rate_hz: float, cutoff_hz: float = 0.3) -> np.ndarray:
    """Unit down vector in the body frame from low-passed specific force, shape (n, 3)."""
    g = -_lowpass(np.asarray(acc_m_s2, float), cutoff_hz, rate_hz)
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)


def yaw_rate(gyro_rad_s: np.ndarray, down: np.ndarray) -> np.ndarray:
    """Rate of heading change ψ̇ = d·ω, rad/s, shape (n,) (clockwise seen from above is positive)."""
    return np.einsum("ij,ij->i", np.asarray(gyro_rad_s, float), down)


def magnetic_heading(mag_ut: np.ndarray, down: np.ndarray, declination_rad: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tilt-compensated heading of the body x axis (rad, wrapped), field intensity (µT), dip (rad).

    >>> d = np.array([[0.0, 0.0, 1.0]]); m = np.array([[20.0, 20.0, 30.0]])   # field 45° right of x
    >>> [round(float(v[0]), 4) for v in magnetic_heading(m, d)]
    [-0.7854, 41.2311, 0.8148]
    """
    m = np.asarray(mag_ut, float)
    md = np.einsum("ij,ij->i", m, down)
    h = m - md[:, None] * down
    north = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    east = np.cross(down, north)
    # body x = (1, 0, 0): its components along magnetic north and east
    psi = np.arctan2(east[:, 0], north[:, 0]) + declination_rad
    intensity = np.linalg.norm(m, axis=1)
    dip = np.arcsin(np.clip(md / np.maximum(intensity, 1e-12), -1.0, 1.0))
    return wrap_pi(psi), intensity, dip


def _mahony_yaw_tf(kp: float, ki: float, dt: float):
    """Transfer functions (num_r, num_m, den) of the yaw PI complementary filter above."""
    a = np.array([[1.0 - kp * dt, -dt], [ki * dt, 1.0]])
    b = np.array([[dt, kp * dt], [0.0, -ki * dt]])
    # output y_k = x_k = A x_{k-1} + B u_k  ->  state s_k = x_{k-1}: s_{k+1} = A s_k + B u_k, y = A s + B u
    num_r, den = signal.ss2tf(a, b, a[:1], b[:1], input=0)
    num_m, _ = signal.ss2tf(a, b, a[:1], b[:1], input=1)
    num_rb, _ = signal.ss2tf(a, b, a[1:], b[1:], input=0)
    num_mb, _ = signal.ss2tf(a, b, a[1:], b[1:], input=1)
    return num_r[0], num_m[0], num_rb[0], num_mb[0], den


def complementary_heading(rate_rad_s: np.ndarray, mag_heading_unwrapped: np.ndarray, rate_hz: float,
                          kp_per_s: float, ki_per_s2: float, initial_bias_rad_s: float = 0.0,
                          initial_heading_rad: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Run the yaw Mahony filter; returns (heading unwrapped, bias), each shape (n,).

    Starts at ψ₀ = ``initial_heading_rad`` (default ψ_m,0) and b₀ = ``initial_bias_rad_s`` before the first
    sample; the linear system is fed deviations from that fixed point, so zero initial filter state is exact.
    """
    dt = 1.0 / rate_hz
    nr, nm, nrb, nmb, den = _mahony_yaw_tf(kp_per_s, ki_per_s2, dt)
    r = np.asarray(rate_rad_s, float) - initial_bias_rad_s
    m = np.asarray(mag_heading_unwrapped, float)
    m0 = m[0] if initial_heading_rad is None else float(initial_heading_rad)
    psi = signal.lfilter(nr, den, r) + signal.lfilter(nm, den, m - m0) + m0
    bias = signal.lfilter(nrb, den, r) + signal.lfilter(nmb, den, m - m0) + initial_bias_rad_s
    return psi, bias


STATIC_RATE_DEVIATION_RAD_S = math.radians(3.0)
"""A standing device's angular rate stays within this of its own start value (the turn-on bias), rad/s."""

MAX_TURN_ON_BIAS_RAD_S = math.radians(8.0)
"""Largest start rate read as a gyro bias rather than a turn: consumer MEMS datasheets state a zero-rate
offset of ±3 °/s typical (BMI160; ICM-20948 ±5 °/s), so 8 °/s covers them with margin."""


def _static_start(acc: np.ndarray, gyro: np.ndarray, rate_hz: float, seconds: float) -> int:
    """Number of leading samples (≥ ``seconds``) during which the device stands still, else 0.

    Still means the accelerometer magnitude and the angular rate both stay at their start values: the rate
    is compared with its own median over the first ``seconds``, not with zero, because a turn-on bias of a
    few °/s (:data:`MAX_TURN_ON_BIAS_RAD_S`) is exactly what this interval is used to measure.
    """
    n = int(round(seconds * rate_hz))
    if len(acc) < 2 * n or n < 2:
        return 0
    a = np.linalg.norm(acc, axis=1)
    w0 = np.median(gyro[:n], axis=0)
    if np.linalg.norm(w0) > MAX_TURN_ON_BIAS_RAD_S:
        return 0                                    # turning from the start, not a biased gyro at rest
    w = np.linalg.norm(gyro - w0, axis=1)
    still = (np.abs(a - np.median(a[:n])) < 0.3) & (w < STATIC_RATE_DEVIATION_RAD_S)
    moving = np.nonzero(~still)[0]
    m = int(moving[0]) if len(moving) else len(acc)
    return m if m >= n else 0


def _inconsistent_with_gyro(mag_unwrapped: np.ndarray, gyro_heading: np.ndarray, rate_hz: float,
                           config: HeadingConfig) -> np.ndarray:
    """Samples whose magnetometer heading change over ``consistency_window_s`` disagrees with the gyro's.

    A quasi-static field turns only when the device turns (Afzal et al. 2011,
    "Magnetic field based heading estimation for pedestrian navigation
    environments", IPIN): a walker passing steel sees the field swing while the
    gyro says straight. Every sample of a window whose two heading changes
    differ by more than ``consistency_rad`` is flagged, shape (n,) bool.
    """
    w = max(int(round(config.consistency_window_s * rate_hz)), 1)
    n = len(mag_unwrapped)
    if n <= w:
        return np.zeros(n, bool)
    diff = (mag_unwrapped[w:] - mag_unwrapped[:-w]) - (gyro_heading[w:] - gyro_heading[:-w])
    bad_start = np.abs(wrap_pi(diff)) > config.consistency_rad
    # window k covers samples k..k+w: flag them all (running maximum over w+1 starts)
    flag = np.zeros(n, bool)
    flag[:n - w] = bad_start
    return ndimage.maximum_filter1d(flag, w + 1, origin=-(w // 2)) | flag


def estimate_heading(acc_m_s2: np.ndarray, gyro_rad_s: np.ndarray | None, mag_ut: np.ndarray | None,
                     rate_hz: float, config: HeadingConfig = HeadingConfig(),
                     start: HeadingState | None = None, start_index: int = 0) -> HeadingResult | None:
    """Gyro-only, magnetometer-only and complementary heading, per sample (see module docstring).

    Without gyro and magnetometer there is no heading (returns None); with only
    one of them, ``fused`` is that one (gyro from ``config.initial_heading_rad``). ``start``: the state a run
    over the record's preceding samples reached after the sample before ``start_index`` (the record's start
    statistics come from it too); the headings resume from it there, and the samples before it, where the
    low-pass filters settle, have none (NaN).
    """
    if gyro_rad_s is None and mag_ut is None:
        return None
    acc = np.asarray(acc_m_s2, float)
    n = len(acc)
    nan = np.full(n, np.nan)
    down = down_in_body(acc, rate_hz, config.gravity_lowpass_hz)
    mag_psi = nan
    disturbed = np.zeros(n, bool)
    if mag_ut is not None:
        mag_f = _lowpass(np.asarray(mag_ut, float), config.mag_lowpass_hz, rate_hz)
        mag_psi, intensity, dip = magnetic_heading(mag_f, down, config.declination_rad)
        if start is None:
            n_ref = max(int(round(GATE_REFERENCE_S * rate_hz)), 1)
            ref = (float(np.median(intensity[:n_ref])), float(np.median(dip[:n_ref])))
        else:
            ref = (start.intensity_ref, start.dip_ref_rad)
        disturbed = ((np.abs(intensity / ref[0] - 1.0) > config.gate_intensity_frac)
                     | (np.abs(dip - ref[1]) > config.gate_dip_rad))
    else:
        ref = (math.nan, math.nan)
    if gyro_rad_s is None:
        return HeadingResult(mag_psi, nan, mag_psi, disturbed, nan, 0.0, *ref)
    gyro = np.asarray(gyro_rad_s, float)
    r = yaw_rate(gyro, down)
    if start is None:
        n_static = _static_start(acc, gyro, rate_hz, config.static_start_s)
        bias0 = float(np.mean(r[:n_static])) if n_static else 0.0
        *out, diffs = _integrate(r, None if mag_ut is None else mag_psi, disturbed, rate_hz, config, bias0, None)
        return HeadingResult(*out, bias0, *ref, math.nan, *diffs)
    j = int(start_index)
    *out, diffs = _integrate(r[j:], None if mag_ut is None else mag_psi[j:], disturbed[j:], rate_hz, config,
                             start.static_bias_rad_s, start)

    def padded(x):
        return None if x is None else np.concatenate([np.full(j, np.nan if x.dtype != bool else False), x])

    fused, gyro_only, _, flags, bias = (padded(x) for x in out)
    return HeadingResult(fused, gyro_only, mag_psi, disturbed | flags, bias, start.static_bias_rad_s, *ref,
                         start.gate_offset_rad, *(padded(x) for x in diffs))


def _integrate(r: np.ndarray, mag_psi: np.ndarray | None, disturbed: np.ndarray, rate_hz: float,
               config: HeadingConfig, bias0: float, start: HeadingState | None) -> tuple:
    """(fused, gyro_only, mag_only, disturbed, bias, (mag − gyro, mag − fused)) from the yaw rate ``r`` and the
    magnetometer heading ``mag_psi`` (None without one), gated by ``disturbed``: the gyro heading, the gate and
    the complementary filter, from the record's start (``start`` None) or from the state ``start``; the last two
    unwrapped (None, None without magnetometer).

    Resumed from a state that states its unwrapped differences (:class:`HeadingState`), the run's headings are
    put where they stood against the magnetometer's: its unwrapped heading before the first sample is the
    first one's less the wrapped change from the state's, and the gyro, complementary and gate headings stand
    the state's differences from it. (Before, the gate's offset and the complementary heading were each put on
    the branch nearest the first sample's magnetometer heading, which is another branch when a disturbed
    spell across the resumption lets gyro and magnetometer drift more than π apart: a 48 s hole in a walk's
    IMU log across a long walk's seam turned the segment's headings by π.)"""
    n = len(r)
    dt = 1.0 / rate_hz
    if start is None:
        # ψ_g relative to the first sample
        psi_rel = np.r_[0.0, np.cumsum((r[1:] - bias0) * dt)]
    else:
        # ψ_g relative to the sample before the first (the state's)
        psi_rel = np.cumsum((r - bias0) * dt)
    if mag_psi is None:
        psi_g = (config.initial_heading_rad if start is None else start.gyro_rad) + psi_rel
        return wrap_pi(psi_g), wrap_pi(psi_g), np.full(n, np.nan), disturbed, np.full(n, bias0), (None, None)
    m_unw = np.unwrap(mag_psi)
    # the state's branch: its magnetometer heading on this run's unwrapped one, and its headings from it
    placed = start is not None and all(math.isfinite(v) for v in (start.mag_rad, start.mag_minus_gyro_rad,
                                                                    start.mag_minus_fused_rad))
    m_before = m_unw[0] - float(wrap_pi(mag_psi[0] - start.mag_rad)) if placed else math.nan
    disturbed = disturbed | _inconsistent_with_gyro(m_unw, psi_rel, rate_hz, config)
    if start is None:
        n0 = max(int(round(config.static_start_s * rate_hz)), 1)
        good0 = ~disturbed[:n0]
        psi0 = float(np.mean(m_unw[:n0][good0])) if good0.any() else float(m_unw[0])
    else:
        psi0 = m_before - start.mag_minus_gyro_rad if placed else start.gyro_rad
    psi_g = psi0 + psi_rel
    # gate: inside disturbed spells follow the gyro from the last good magnetometer heading
    m_gated = m_unw.copy()
    if start is None:
        m_gated[0] = psi0
    if disturbed.any():
        idx = np.arange(n)
        last_good = np.maximum.accumulate(np.where(~disturbed, idx, -1 if start is not None else 0))
        before = last_good < 0          # a spell that began before this piece: the state's offset, on m_unw's branch
        lg = np.maximum(last_good, 0)
        gated = m_unw[lg] + (psi_g - psi_g[lg])
        if before.any():
            if placed:
                offset = start.gate_offset_rad
            else:
                offset = start.gate_offset_rad if math.isfinite(start.gate_offset_rad) else m_unw[0] - psi_g[0]
                offset += _branch(m_unw[0] - psi_g[0] - offset)
            gated = np.where(before, offset + psi_g, gated)
        m_gated = np.where(disturbed, gated, m_unw)
        if start is None:
            m_gated[0] = psi0
    if start is None:
        psi, bias = complementary_heading(r, m_gated, rate_hz, config.kp_per_s, config.ki_per_s2, bias0)
    else:
        psi_start = m_before - start.mag_minus_fused_rad if placed else \
            start.fused_rad + _branch(m_gated[0] - start.fused_rad)
        psi, bias = complementary_heading(r, m_gated, rate_hz, config.kp_per_s, config.ki_per_s2, start.bias_rad_s,
                                          psi_start)
    return wrap_pi(psi), wrap_pi(psi_g), mag_psi, disturbed, bias, (m_unw - psi_g, m_unw - psi)


def _branch(delta_rad: float) -> float:
    """The multiple of 2π nearest ``delta_rad``: what puts an angle on another's unwrapped branch."""
    return 2.0 * math.pi * round(float(delta_rad) / (2.0 * math.pi))


def imufusion_heading(acc_m_s2: np.ndarray, gyro_rad_s: np.ndarray, mag_ut: np.ndarray, rate_hz: float,
                      declination_rad: float = 0.0, gain: float = 0.5, rejection_deg: float = 10.0) -> np.ndarray:
    """Heading from imufusion's AHRS (Madgwick's revised complementary filter, compiled C), for comparison.

    Our body frame is forward-right-down, so imufusion's NED convention applies
    with the specific force as measured (in g) and the gyro in °/s; the
    magnetic-rejection threshold ``rejection_deg`` is imufusion's own gate.
    One Python call per sample (≈ 3 µs). Returns rad from true north, clockwise, shape (n,).

    Needs the optional extra ``compare`` (``pip install -e ".[compare]"``); without it a
    :class:`~features.errors.ConfigError` says so.
    """
    try:
        import imufusion
    except ImportError:
        raise ConfigError('imufusion_heading needs imufusion, the optional extra "compare": '
                          'pip install -e ".[compare]"') from None

    settings = imufusion.AhrsSettings()
    settings.convention = imufusion.CONVENTION_NED
    settings.gain = gain
    settings.gyroscope_range = 2000.0
    settings.acceleration_rejection = rejection_deg
    settings.magnetic_rejection = rejection_deg
    settings.rejection_timeout = int(5 * rate_hz)
    settings.sample_rate = int(round(rate_hz))
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(settings)
    acc_g = np.asarray(acc_m_s2, float) / 9.80665
    gyr_dps = np.degrees(np.asarray(gyro_rad_s, float))
    mag = np.asarray(mag_ut, float)
    quat = np.empty((len(acc_g), 4))
    for i in range(len(acc_g)):
        ahrs.update(gyr_dps[i], acc_g[i], mag[i])
        quat[i] = ahrs.get_quaternion()
    w, x, y, z = quat.T
    return wrap_pi(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)) + declination_rad)
