"""Odometry dead reckoning: speed × yaw rate → displacement events, and the initial heading from GNSS.

**Integration** (a planar kinematic model, the car's odometry of Groves 2013, *Principles of GNSS,
Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed., §6.3): between odometry samples
k and k+1 (Δt apart) the trapezoidal rule gives

    Δψₖ = −½(ωₖ + ωₖ₊₁)·Δt,    Lₖ = ½(vₖ + vₖ₊₁)·Δt,    heading of the segment ψₖ + ½Δψₖ,

v the forward speed (body x), ω the yaw rate about body z (up, counter-clockwise positive, as
:class:`~features.gnss.pseudorange.OdometryTable` states), the minus sign turning it into the
navigation heading (0 = north, clockwise positive); the segment's heading at its mid-turn makes the
chord of a constant-rate arc exact to second order. Each segment whose length exceeds
``min_speed_m_s``·Δt becomes one event at t_{k+1}, like a step at its heel strike
(:class:`features.imu.pdr.PdrResult`): standing still gives no event, which the fusion reads as a
stand. Position: eₖ = eₖ₋₁ + Lₖ sin ψ, nₖ = nₖ₋₁ + Lₖ cos ψ (:func:`features.imu.pdr.dead_reckon`).

**Noise from the file's variances**, samples taken as independent: σ_L = ½Δt·sqrt(σ²_vₖ + σ²_vₖ₊₁)
per event (``sigma_step_length_m``) and σ_Δψ = ½Δt·sqrt(σ²_ωₖ + σ²_ωₖ₊₁) per heading increment
(``sigma_heading_increment_rad``); the heading is their running sum, a random walk of intensity
``heading_rw_rad2_s`` = median(σ²_Δψ/Δt) rad²/s — the figure a filter with a heading-offset state
(models' δψ random walk) takes as its process noise. Odometry's real errors are mostly a speed
scale (tyre radius) and a yaw-rate bias, not white noise: the filter's step-scale and heading-offset
states are where those belong.

**Initial heading** (never from the reference): the odometry fixes only the shape of the track; its
rotation and start come from the first GNSS fixes. The track dead-reckoned with heading 0 is fitted
to the fixes of a window from the first odometry sample as a rigid 2-D motion, p ≈ c + R(ψ₀)·d:
the closed-form least-squares rotation (Umeyama 1991, IEEE TPAMI 13(4), in 2-D:
ψ₀ = arg Σ conj(d̃ⱼ)·p̃ⱼ with points as complex north + i·east, centred), refined by scipy's
``least_squares`` with the Cauchy loss (scale 2.385, its 95 %-efficiency constant, Holland & Welsch
1977) on residuals in units of a robust scale (median residual norm / 1.1774, the Rayleigh median):
urban fixes carry NLOS outliers of 100 m, and their own σ is no guide to them. σ(ψ₀) is the fit's
Jacobian σ, scaled by the variance factor when above 1 and by the residuals' integrated
autocorrelation time τ (NLOS errors persist for tens of seconds, so n fixes are worth about n/τ
independent ones; Geyer 1992). The window starts at ``align_min_path_m`` of track (and at least
``align_window_s``) and grows by half until σ(ψ₀) ≤ ``target_sigma_deg`` or ``align_max_path_m``:
in open sky a short stretch settles the heading, in a canyon it takes hundreds of metres (on the
smartLoc drive, 340–510 m for |ψ₀ error| < 4°, where 30 s of fixes were 20–40° off). The fit
looks ahead to the window's end, so it serves offline evaluation; a real-time filter would start
with the heading unknown (a wide σ on its heading-offset state) and let the fixes settle it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from features.errors import ConfigError, DataError
from features.gnss.pseudorange import OdometryTable
from features.imu.pdr import dead_reckon

__all__ = ["OdometryConfig", "DeadReckoning", "HeadingAlignment", "integrate_odometry", "align_heading",
           "odometry_dead_reckoning"]


@dataclass(frozen=True)
class OdometryConfig:
    """Integration and heading-alignment settings (module docstring)."""

    min_speed_m_s: float = 0.05
    align_window_s: float = 30.0
    align_min_path_m: float = 100.0
    align_max_path_m: float = 1000.0
    target_sigma_deg: float = 5.0
    loss: str = "cauchy"
    loss_scale: float = 2.3849

    def __post_init__(self):
        if not (math.isfinite(self.min_speed_m_s) and self.min_speed_m_s >= 0):
            raise ConfigError(f"OdometryConfig.min_speed_m_s must be >= 0, got {self.min_speed_m_s}")
        if self.loss not in ("linear", "huber", "soft_l1", "cauchy", "arctan"):
            raise ConfigError(f"OdometryConfig.loss must be one of scipy's least_squares losses, got {self.loss!r}")
        for name in ("align_window_s", "align_min_path_m", "align_max_path_m", "target_sigma_deg", "loss_scale"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"OdometryConfig.{name} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class DeadReckoning:
    """Displacement events, each ndarray of shape (n,), with PDR's names: ``t_s`` (end of the segment),
    ``step_length_m``, ``heading_rad`` (from north, clockwise), ``east_m``, ``north_m`` (position after
    the event), and their noise ``sigma_step_length_m``, ``sigma_heading_increment_rad``;
    ``heading_rw_rad2_s`` the heading's random-walk intensity; ``initial_heading_rad`` and
    ``start_en_m`` the heading and position at the first odometry sample, ``start_t_s`` its time;
    ``segment_s`` (n,) each event's duration (its segment runs from ``t_s − segment_s`` to ``t_s``)."""

    t_s: np.ndarray
    step_length_m: np.ndarray
    heading_rad: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    sigma_step_length_m: np.ndarray
    sigma_heading_increment_rad: np.ndarray
    heading_rw_rad2_s: float
    initial_heading_rad: float
    start_en_m: tuple[float, float]
    start_t_s: float
    segment_s: np.ndarray

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def distance_m(self) -> float:
        """Total distance, m."""
        return float(self.step_length_m.sum())

    def position_at(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """(east_m, north_m) at times ``t_s``: linear along each event's segment, held while standing."""
        e = np.r_[self.start_en_m[0], self.east_m]
        n = np.r_[self.start_en_m[1], self.north_m]
        # knots: the start, then each segment's beginning (previous position) and end (its position)
        knots_t = np.r_[self.start_t_s, np.column_stack([self.t_s - self.segment_s, self.t_s]).ravel()]
        knots_e = np.r_[e[0], np.column_stack([e[:-1], e[1:]]).ravel()]
        knots_n = np.r_[n[0], np.column_stack([n[:-1], n[1:]]).ravel()]
        return np.interp(t_s, knots_t, knots_e), np.interp(t_s, knots_t, knots_n)


@dataclass(frozen=True)
class HeadingAlignment:
    """The fitted initial heading ψ₀ (rad, from north, clockwise) and its σ, the start (east, north) at
    the first odometry sample, the number of fixes used and their time span."""

    heading_rad: float
    sigma_heading_rad: float
    start_en_m: tuple[float, float]
    n_fixes: int
    span_s: tuple[float, float]


def integrate_odometry(odometry: OdometryTable, initial_heading_rad: float = 0.0,
                       start_en_m: tuple[float, float] = (0.0, 0.0),
                       config: OdometryConfig = OdometryConfig()) -> DeadReckoning:
    """Displacement events from odometry (module docstring), heading starting at ``initial_heading_rad``."""
    t = odometry.t_s
    if len(t) < 2:
        raise DataError(f"odometry needs at least 2 samples, got {len(t)}")
    v, w = odometry.speed_m_s, odometry.yaw_rate_rad_s
    var_v, var_w = odometry.velocity_var_m2_s2[:, 0], odometry.rate_var_rad2_s2[:, 2]
    dt = np.diff(t)
    # Δψ = −½(ωₖ + ωₖ₊₁)Δt (yaw rate counter-clockwise → heading clockwise), L = ½(vₖ + vₖ₊₁)Δt
    d_psi = -0.5 * (w[:-1] + w[1:]) * dt
    length = 0.5 * (v[:-1] + v[1:]) * dt
    psi = initial_heading_rad + np.r_[0.0, np.cumsum(d_psi)]
    seg_heading = psi[:-1] + 0.5 * d_psi
    s_len = 0.5 * dt * np.sqrt(var_v[:-1] + var_v[1:])
    s_dpsi = 0.5 * dt * np.sqrt(var_w[:-1] + var_w[1:])
    move = length > config.min_speed_m_s * dt
    east, north = dead_reckon(length[move], seg_heading[move], *start_en_m)
    heading = np.mod(seg_heading[move] + math.pi, 2 * math.pi) - math.pi
    return DeadReckoning(t_s=t[1:][move], step_length_m=length[move], heading_rad=heading, east_m=east,
                         north_m=north, sigma_step_length_m=s_len[move], sigma_heading_increment_rad=s_dpsi[move],
                         heading_rw_rad2_s=float(np.median(s_dpsi ** 2 / dt)), initial_heading_rad=initial_heading_rad,
                         start_en_m=(float(start_en_m[0]), float(start_en_m[1])), start_t_s=float(t[0]),
                         segment_s=dt[move])


def align_heading(track: DeadReckoning, fix_t_s, fix_east_m, fix_north_m,
                  config: OdometryConfig = OdometryConfig()) -> HeadingAlignment:
    """Fit ψ₀ and the start of a track dead-reckoned with heading 0 from (0, 0) to the first GNSS fixes.

    fix_* : arrays of shape (n,), the fixes' time (the track's time base) and ENU position. The window
    grows (by half its path each time) from ``align_min_path_m`` until σ(ψ₀) ≤ ``target_sigma_deg``
    or ``align_max_path_m`` (module docstring). Raises DataError when the fixes cover no motion.
    """
    ft, fe, fn = (np.asarray(a, float) for a in (fix_t_s, fix_east_m, fix_north_m))
    ok = np.isfinite(ft) & np.isfinite(fe) & np.isfinite(fn) & (ft >= track.start_t_s)
    ft, fe, fn = ft[ok], fe[ok], fn[ok]
    if len(track) == 0 or len(ft) < 3:
        raise DataError(f"heading alignment needs motion and >= 3 fixes; got {len(track)} odometry events, "
                        f"{len(ft)} fixes")
    cum = np.cumsum(track.step_length_m)
    path, fit = config.align_min_path_m, None
    while True:
        t_path = track.t_s[min(int(np.searchsorted(cum, path)), len(track) - 1)]
        sel = ft <= max(track.start_t_s + config.align_window_s, t_path)
        if sel.sum() >= 3:
            de, dn = track.position_at(ft[sel])
            if np.hypot(de - de.mean(), dn - dn.mean()).max() >= 0.25 * config.align_min_path_m:
                fit = _rigid_fit(dn + 1j * de, fn[sel] + 1j * fe[sel], config) + (int(sel.sum()), ft[sel])
        done = fit is not None and fit[1] <= math.radians(config.target_sigma_deg)
        if done or path >= min(config.align_max_path_m, cum[-1]):
            break
        path *= 1.5
    if fit is None:
        raise DataError(f"heading alignment: the fixes over the odometry's {cum[-1]:.1f} m show no motion of "
                        f">= {0.25 * config.align_min_path_m:g} m")
    psi, sigma, start, n, t_used = fit
    return HeadingAlignment(float(np.mod(psi + math.pi, 2 * math.pi) - math.pi), sigma, start, n,
                            (float(t_used[0]), float(t_used[-1])))


def _rigid_fit(d: np.ndarray, p: np.ndarray, config: OdometryConfig) -> tuple[float, float, tuple[float, float]]:
    """p ≈ c + e^{iψ}·d for complex points (north + i·east): (ψ, σ(ψ), (east, north) of c) (module docstring)."""
    # closed-form rigid rotation (Umeyama 1991, 2-D): ψ₀ = arg Σ conj(d̃) p̃
    psi0 = float(np.angle(np.sum(np.conj(d - d.mean()) * (p - p.mean()))))
    c0 = p.mean() - np.exp(1j * psi0) * d.mean()
    # robust scale per axis from the closed-form residuals: the median of a 2-D Gaussian's norm is 1.1774 σ
    scale = max(float(np.median(np.abs(p - c0 - np.exp(1j * psi0) * d))) / 1.1774, 1e-3)

    def residuals(theta):
        r = (p - theta[1] - 1j * theta[2] - np.exp(1j * theta[0]) * d) / scale
        return np.concatenate([r.real, r.imag])

    fit = least_squares(residuals, [psi0, c0.real, c0.imag], loss=config.loss, f_scale=config.loss_scale)
    factor = max(1.0, 2.0 * fit.cost / max(2 * len(p) - 3, 1))
    try:
        var = float(np.linalg.inv(fit.jac.T @ fit.jac)[0, 0]) * factor
    except np.linalg.LinAlgError:
        var = math.inf
    r = residuals(fit.x).reshape(2, -1)
    tau = 0.5 * (_integrated_autocorrelation(np.clip(r[0], -3, 3)) + _integrated_autocorrelation(np.clip(r[1], -3, 3)))
    return float(fit.x[0]), math.sqrt(var * tau), (float(fit.x[2]), float(fit.x[1]))


def _integrated_autocorrelation(x: np.ndarray) -> float:
    """τ = 1 + 2 Σ ρₖ over the initial positive sequence of autocorrelations (Geyer 1992, Stat. Sci. 7(4)).

    The variance of a mean of n correlated samples is τ times that of n independent ones.

    >>> round(_integrated_autocorrelation(np.r_[np.ones(50), -np.ones(50)]), 1) > 20
    True
    """
    x = np.asarray(x, float) - np.mean(x)
    n = len(x)
    if n < 3 or not np.any(x):
        return 1.0
    acf = np.correlate(x, x, mode="full")[n - 1:] / (np.dot(x, x))
    stop = np.flatnonzero(acf[1:] <= 0)
    k = int(stop[0]) if stop.size else n - 1
    return float(min(max(1.0 + 2.0 * acf[1:k + 1].sum(), 1.0), n))


def odometry_dead_reckoning(odometry: OdometryTable, fix_t_s, fix_east_m, fix_north_m,
                            config: OdometryConfig = OdometryConfig()) -> tuple[DeadReckoning, HeadingAlignment]:
    """Integrate, align the heading and start to the first GNSS fixes, integrate again from there."""
    relative = integrate_odometry(odometry, 0.0, (0.0, 0.0), config)
    align = align_heading(relative, fix_t_s, fix_east_m, fix_north_m, config)
    return integrate_odometry(odometry, align.heading_rad, align.start_en_m, config), align
