"""Pseudorange and carrier errors, weighted least squares with RAIM, and the receiver's fix quality.

Errors per epoch and satellite (shape (n_epochs, k), metres):

* **Code noise**: SIGMA-ε model, σ² = a² + b²·10^(−C/N0/10) (Hartinger &
  Brunner 1999, "Variances of GPS phase observations: the SIGMA-ε model",
  GPS Solutions 2(4)), first-order Gauss–Markov in time with the ≈ 1 s
  correlation of carrier smoothing.
* **Atmosphere, orbit and clock residuals**: slowly varying Gauss–Markov
  processes (τ ≈ 30 min) per satellite, the ionospheric part scaled by the
  Klobuchar obliquity factor F = 1 + 16·(0.53 − E)³ (IS-GPS-200 §20.3.3.5.2.5,
  E in semicircles), the tropospheric part by 1/sin(el). Differential
  corrections from a nearby base remove all but a small fraction (DGNSS) or
  all of it (RTK double differences).
* **Multipath**: Gauss–Markov, σ growing at low elevation and near clutter;
  the correlation time shortens as the walker moves (the multipath geometry
  changes over about a metre).
* **NLOS bias**: positive, the reflected path's extra length, ≈ 2·d·cos(el)
  off a structure d metres away plus an exponential part (from
  :mod:`simulation.gnss.signal`).
* **Carrier phase** (for RTK): SIGMA-ε carrier noise (C = 0.00224 m²Hz for L1,
  Hartinger & Brunner 1999), millimetre-to-centimetre carrier multipath, and
  for NLOS satellites the fractional-cycle part of the extra path.

The receiver weights satellites by reported C/N0 only (it cannot know which
are NLOS), with the SIGMA-ε variance plus a floor for the unmodelled errors of
its mode. Weighted least squares is linearised about the true position with
one clock column per system: the pseudorange errors are metres while ranges are
2·10⁷ m, so the linearisation error is |δx|²/ρ < 10⁻³ m — far below every
modelled error — and iterating Gauss–Newton on ECEF would return the same
solution. A RAIM-style test compares the weighted sum of squared residuals
with the χ² quantile for the degrees of freedom and, when it fails, excludes
the satellite with the largest standardised residual (Brown 1992, "A baseline
GPS RAIM scheme", Navigation 39(3)), up to ``raim_max_exclusions`` times.

Fix quality (GGA field 6): RTK fixed (4) and float (5) come from the RTK
engine of :mod:`simulation.gnss.rtk` — float ambiguities from the
code-minus-carrier since lock, integer search (LAMBDA), ratio test and
bootstrapping success rate, fix-and-hold and its validation — which reads the
receiver's observables only. Its fixes are wrong when the float ambiguities
are biased beyond what the receiver's white-noise model allows: code multipath
and NLOS delays held while a carrier stays locked, and NLOS carriers, which
measure the reflected path (:func:`pseudorange_errors`). RTK float (5) needs
≥ ``float_min_sats`` satellites in phase lock, one more than the unknowns, with
PDOP ≤ ``float_pdop_mask``; the float filter runs beneath
the fixed output (not restarted when a fix is declared or lost). DGNSS (2)
otherwise; autonomous (1) when corrections are off; no fix (0) when the
geometry cannot be solved (fewer than 4 satellites, or fewer than 3 + the
number of systems). Every solution carries the receiver's GST: σ from its own
least-squares covariance scaled by its a-posteriori variance factor
(:func:`_gst_sigma`), which is too small wherever the solution has absorbed a
bias.

The truth NLOS flags enter only physics the receiver cannot choose: reflected
carriers slip more often, and their code and carrier carry the reflected path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.signal import lfilter
from scipy.stats import chi2

from features.errors import ConfigError
from simulation.gnss.gst import gst_fields
from simulation.gnss.rtk import RtkConfig, carrier_model_var_m2, float_solution, rtk_engine
from simulation.gnss.signal import open_sky_cn0_dbhz

__all__ = ["FixConfig", "FixResult", "code_sigma_m", "carrier_sigma_m", "klobuchar_obliquity",
           "gauss_markov", "pseudorange_errors", "slip_probability", "cycle_slips", "hatch_smooth", "float_ambiguity_bias", "distance_gm_phi",
           "solve_fixes", "QUALITY_NONE", "QUALITY_AUTONOMOUS",
           "QUALITY_DGNSS", "QUALITY_RTK_FIXED", "QUALITY_RTK_FLOAT"]

QUALITY_NONE, QUALITY_AUTONOMOUS, QUALITY_DGNSS, QUALITY_RTK_FIXED, QUALITY_RTK_FLOAT = 0, 1, 2, 4, 5


@dataclass(frozen=True)
class FixConfig:
    """Error and receiver parameters (metres, seconds, degrees as named)."""

    code_a_m: float = 0.2
    code_b_m_sqrt_hz: float = 47.4
    code_tau_s: float = 1.0
    carrier_c_m2_hz: float = 0.00224
    carrier_mp_sigma_m: float = 0.004
    carrier_mp_tau_s: float = 30.0
    mp_sigma_m: float = 0.3
    mp_low_el_m: float = 1.2
    mp_el_scale_deg: float = 15.0
    mp_clutter_gain: float = 1.5
    mp_tau_s: float = 120.0
    mp_corr_dist_m: float = 5.0
    nlos_var_share: float = 0.5
    nlos_tau_s: float = 60.0
    nlos_corr_dist_m: float = 10.0
    hatch_window_s: float = 20.0
    nlos_mp_sigma_m: float = 1.5
    orbit_clock_sigma_m: float = 0.8
    iono_zenith_sigma_m: float = 2.0
    tropo_zenith_sigma_m: float = 0.2
    atm_tau_s: float = 1800.0
    dgnss_residual_fraction: float = 0.05
    fix_mask_deg: float = 10.0
    raim_pfa: float = 1e-3
    raim_max_exclusions: int = 2
    rx_floor_autonomous_m: float = 3.0
    rx_floor_differential_m: float = 0.6
    rtk_cold_start: bool = True
    float_min_sats: int = 5
    float_pdop_mask: float = 25.0
    float_filter_tau_s: float = 8.0
    warm_start_lock_s: float = 60.0
    slip_nlos_prob: float = 0.05
    slip_weak_prob: float = 0.5
    slip_weak_scale_db: float = 3.0
    rtk_atm_fraction: float = 0.003

    def __post_init__(self):
        for name, value in vars(self).items():
            if not np.isfinite(value) or value < 0:
                raise ConfigError(f"FixConfig.{name} must be finite and non-negative, got {value!r}")
        if self.nlos_var_share > 1.0:
            raise ConfigError(f"FixConfig.nlos_var_share must lie in [0, 1], got {self.nlos_var_share}")
        if not 0.0 < self.raim_pfa < 1.0:
            raise ConfigError(f"FixConfig.raim_pfa must lie in (0, 1), got {self.raim_pfa}")
        if self.float_min_sats < 4:
            raise ConfigError("FixConfig.float_min_sats must be >= 4")


def code_sigma_m(cn0_dbhz, a_m: float = 0.2, b_m_sqrt_hz: float = 47.4) -> np.ndarray:
    """Code (pseudorange) noise σ, m: SIGMA-ε σ² = a² + b²·10^(−C/N0/10) (Hartinger & Brunner 1999).

    >>> [round(float(code_sigma_m(c)), 2) for c in (45.0, 30.0)]
    [0.33, 1.51]
    """
    c = np.asarray(cn0_dbhz, float)
    return np.sqrt(a_m ** 2 + b_m_sqrt_hz ** 2 * 10.0 ** (-c / 10.0))


def carrier_sigma_m(cn0_dbhz, c_m2_hz: float = 0.00224) -> np.ndarray:
    """Carrier-phase noise σ, m: SIGMA-ε σ² = C·10^(−C/N0/10), C = 0.00224 m²Hz for L1 (Hartinger & Brunner 1999)."""
    return np.sqrt(c_m2_hz * 10.0 ** (-np.asarray(cn0_dbhz, float) / 10.0))


def klobuchar_obliquity(el_rad) -> np.ndarray:
    """Ionospheric obliquity factor F = 1 + 16·(0.53 − E)³, E in semicircles (IS-GPS-200 §20.3.3.5.2.5).

    >>> round(float(klobuchar_obliquity(np.pi / 2)), 3), round(float(klobuchar_obliquity(np.radians(10.0))), 2)
    (1.0, 2.71)
    """
    e = np.clip(np.asarray(el_rad, float), 0.0, np.pi / 2) / np.pi
    return 1.0 + 16.0 * (0.53 - e) ** 3


def gauss_markov(rng: np.random.Generator, phi: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Unit-variance first-order Gauss–Markov processes, shape (n, k), started in steady state.

    x_i = φ_i·x_{i−1} + sqrt(1 − φ_i²)·w_i, w ~ N(0, 1); ``phi`` has shape (n,)
    (φ_i = exp(−Δt/τ_i)) or is a scalar.
    """
    n, k = shape
    w = rng.standard_normal((n, k))
    phi = np.broadcast_to(np.asarray(phi, float), (n,))
    if n > 1 and np.all(phi[1:] == phi[1]):
        # Constant φ: the same recursion as a first-order IIR filter, run in C.
        p = float(phi[1])
        x = np.empty((n, k))
        x[0] = w[0]
        if n > 1:
            x[1:], _ = lfilter([np.sqrt(1.0 - p * p)], [1.0, -p], w[1:], axis=0, zi=(p * w[0])[None])
        return x
    out = np.empty((n, k))
    x = w[0]
    out[0] = x
    q = np.sqrt(1.0 - phi ** 2)
    for i in range(1, n):
        x = phi[i] * x + q[i] * w[i]
        out[i] = x
    return out


def hatch_smooth(err_m: np.ndarray, reset: np.ndarray, window: int) -> np.ndarray:
    """Carrier smoothing of the code-only error (Hatch 1982), shape (n, k).

    The Hatch filter ρ̂ₖ = ρₖ/Nₖ + (Nₖ − 1)/Nₖ·(ρ̂ₖ₋₁ + Δφₖ) with a growing
    window Nₖ = min(k − k_reset + 1, N) (Hatch 1982, "The synergism of GPS
    code and carrier measurements", 3rd Int. Geodetic Symp. on Satellite
    Doppler Positioning; RTCA DO-229 §2.1.4.1.1 for the 100 s form). What code
    and carrier share (geometry, the reflected path's extra length) passes
    through unchanged; what only the code carries — its thermal noise and code
    multipath — is averaged: êₖ = eₖ/Nₖ + (Nₖ − 1)/Nₖ·êₖ₋₁. ``reset`` (n, k)
    restarts the window (cycle slip or loss of lock); ``window`` N in epochs.

    >>> e = np.array([[1.0], [0.0], [0.0], [3.0]]); r = np.array([[True], [False], [False], [True]])
    >>> hatch_smooth(e, r, 100)[:, 0].tolist()
    [1.0, 0.5, 0.3333333333333333, 3.0]
    """
    return _hatch(np.ascontiguousarray(err_m, float), np.ascontiguousarray(reset, bool), float(window))


@njit(cache=True)
def _hatch(err_m: np.ndarray, reset: np.ndarray, window: float) -> np.ndarray:
    """:func:`hatch_smooth`'s recursion, compiled (epoch by epoch, each satellite alone)."""
    n, k = err_m.shape
    out = np.empty((n, k))
    count = np.zeros(k)
    prev = np.zeros(k)
    for i in range(n):
        for j in range(k):
            if reset[i, j]:
                count[j] = 1.0
                prev[j] = err_m[i, j]
            else:
                count[j] = min(count[j] + 1.0, window)
                prev[j] = err_m[i, j] / count[j] + (count[j] - 1.0) / count[j] * prev[j]
            out[i, j] = prev[j]
    return out


def distance_gm_phi(speed_m_s: np.ndarray, dt_s: float, tau_s: float, corr_dist_m: float) -> np.ndarray:
    """Per-epoch φ of a Gauss–Markov process in distance travelled with a time floor, shape (n,).

    φᵢ = exp(−Δt/τ − vᵢ·Δt/d): the correlation falls with the metres walked
    (the reflection geometry changes over about ``corr_dist_m``) and, standing
    still, with the time constant ``tau_s`` (satellite motion changes static
    multipath over minutes; Braasch 1996, "Multipath effects", in Parkinson &
    Spilker, *GPS: Theory and Applications* I, ch. 14).

    >>> round(float(distance_gm_phi(np.array([1.0]), 1.0, 10.0, 10.0)[0]), 4)
    0.8187
    """
    v = np.asarray(speed_m_s, float)
    return np.exp(-dt_s * (1.0 / tau_s + v / corr_dist_m))


def pseudorange_errors(rng: np.random.Generator, el_rad: np.ndarray, cn0_dbhz: np.ndarray, nlos: np.ndarray,
                       nlos_extra_m: np.ndarray, clutter: np.ndarray, speed_m_s: np.ndarray, dt_s: float,
                       wavelength_m: float, cfg: FixConfig = FixConfig(),
                       reset: np.ndarray | None = None, specular: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Error components, each of shape (n, k), metres.

    Returns a dict with ``noise`` (code noise, carrier-smoothed), ``multipath``
    (carrier-smoothed), ``nlos_bias``, ``atmosphere`` (orbit, clock, ionosphere
    and troposphere residuals before any differential correction) and
    ``carrier`` (carrier-phase error for RTK).

    Code multipath and the NLOS extra path are Gauss–Markov processes in
    distance travelled with a time floor (:func:`distance_gm_phi`), so a walker
    passing a fire wall keeps a bias over metres and a standing one keeps it
    over minutes; the NLOS extra path, geometric (≈ 2·d·cos el off the
    reflector) plus an exponential part per satellite–reflector pair, is
    modulated by (1 + s·u) with u such a process (s = ``nlos_var_share``),
    since a diffusely scattering face is no mirror; a specular reflection
    (``specular`` (n, k), True) keeps the extra path its geometry gives — it
    changes as the walker or the satellite moves, not at random. The code-only parts (noise,
    multipath) are carrier smoothed (:func:`hatch_smooth`), restarted where
    ``reset`` (n, k) is True (cycle slips, loss of lock; default: where
    ``cn0_dbhz`` is NaN, i.e. untracked, and the epoch after).

    Parameters
    ----------
    el_rad, cn0_dbhz : (n, k) elevation and the C/N0 seen by the tracking loops
    nlos, nlos_extra_m : (n, k) NLOS flags and extra path
    clutter : (n,) nearness of structures in [0, 1]; speed_m_s : (n,)
    """
    n, k = el_rad.shape
    el = np.clip(el_rad, np.radians(1.0), np.pi / 2)
    untracked = ~np.isfinite(cn0_dbhz)
    cn0 = np.nan_to_num(cn0_dbhz, nan=20.0)
    v = np.asarray(speed_m_s, float)
    noise = code_sigma_m(cn0, cfg.code_a_m, cfg.code_b_m_sqrt_hz) * gauss_markov(
        rng, np.exp(-dt_s / cfg.code_tau_s), (n, k))
    sigma_mp = ((cfg.mp_sigma_m + cfg.mp_low_el_m * np.exp(-np.degrees(el) / cfg.mp_el_scale_deg))
                * (1.0 + cfg.mp_clutter_gain * clutter[:, None]))
    sigma_mp = np.where(nlos, np.hypot(sigma_mp, cfg.nlos_mp_sigma_m), sigma_mp)
    phi_mp = distance_gm_phi(v, dt_s, cfg.mp_tau_s, cfg.mp_corr_dist_m)
    multipath = sigma_mp * gauss_markov(rng, phi_mp, (n, k))
    sigma_atm = np.sqrt(cfg.orbit_clock_sigma_m ** 2 + (cfg.iono_zenith_sigma_m * klobuchar_obliquity(el)) ** 2
                        + (cfg.tropo_zenith_sigma_m / np.sin(el)) ** 2)
    atmosphere = sigma_atm * gauss_markov(rng, np.exp(-dt_s / cfg.atm_tau_s), (n, k))
    phi_cmp = np.exp(-dt_s * (1.0 / cfg.carrier_mp_tau_s + v / wavelength_m))
    sigma_cmp = cfg.carrier_mp_sigma_m * (1.0 + 2.0 * clutter[:, None]) * (1.0 + np.exp(-np.degrees(el) / 15.0))
    carrier = (carrier_sigma_m(cn0, cfg.carrier_c_m2_hz) * rng.standard_normal((n, k))
               + sigma_cmp * gauss_markov(rng, phi_cmp, (n, k)))
    u = gauss_markov(rng, distance_gm_phi(v, dt_s, cfg.nlos_tau_s, cfg.nlos_corr_dist_m), (n, k))
    share = cfg.nlos_var_share if specular is None else np.where(specular, 0.0, cfg.nlos_var_share)
    extra = np.where(nlos, np.maximum(nlos_extra_m * (1.0 + share * u), 0.0), 0.0)
    # A reflected carrier measures the reflected path: its error is the whole extra path (Groves 2013 §10.4.2),
    # as the code's; code-minus-carrier (the float ambiguity) therefore does not see it, the float position does.
    carrier = np.where(nlos, carrier + extra, carrier)
    if reset is None:
        reset = untracked | np.vstack([np.ones((1, k), bool), untracked[:-1]])
    window = max(1, int(round(cfg.hatch_window_s / dt_s)))
    if cfg.hatch_window_s > 0:
        noise = hatch_smooth(noise, reset, window)
        multipath = hatch_smooth(multipath, reset, window)
    return {"noise": noise, "multipath": multipath, "nlos_bias": extra,
            "atmosphere": atmosphere, "carrier": carrier}


@dataclass(frozen=True, eq=False)
class FixResult:
    """Receiver solution per epoch.

    error_enu_m : (n, 3) fix minus truth, m (NaN without a fix)
    quality : (n,) int, GGA fix quality 0/1/2/4/5
    used : (n, k) bool, satellites in the solution (after RAIM)
    hdop, vdop, pdop : (n,) from the used satellites (NaN without a fix)
    gst : (n, 7) the receiver's own error statistics of the solution it reports, NMEA GST fields 2–8
        (:func:`gst_fields`: rms, semi-major, semi-minor, orientation, σ lat, σ lon, σ alt), NaN without a fix
    code_error_m : (n, k) pseudorange errors after the differential corrections (simulator truth, for reports)
    """

    error_enu_m: np.ndarray
    quality: np.ndarray
    used: np.ndarray
    hdop: np.ndarray
    vdop: np.ndarray
    pdop: np.ndarray
    gst: np.ndarray = None
    code_error_m: np.ndarray = None

    @property
    def n_used(self) -> np.ndarray:
        return self.used.sum(axis=1)


def _design(az_rad: np.ndarray, el_rad: np.ndarray, sys_idx: np.ndarray) -> np.ndarray:
    """Design matrix rows [−u_E, −u_N, −u_U, 1_GPS, 1_BDS], shape (n, k, 5); u points to the satellite."""
    ce = np.cos(el_rad)
    n, k = el_rad.shape
    g = np.zeros((n, k, 5))
    g[..., 0] = -ce * np.sin(az_rad)
    g[..., 1] = -ce * np.cos(az_rad)
    g[..., 2] = -np.sin(el_rad)
    g[..., 3] = (sys_idx == 0)[None, :]
    g[..., 4] = (sys_idx == 1)[None, :]
    return g


def _solvable(used: np.ndarray, sys_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop satellites alone in their system (they only fix their own clock) and test the rank.

    Returns (used, ok) with ok (n,) = at least 3 + n_systems satellites remain.
    """
    used = used.copy()
    n_sys = np.zeros(used.shape[0], int)
    for s in (0, 1):
        cols = sys_idx == s
        cnt = used[:, cols].sum(axis=1)
        lone = cnt == 1
        used[np.ix_(lone, cols)] = False
        n_sys += cnt >= 2
    ok = used.sum(axis=1) >= np.maximum(4, 3 + n_sys)
    return used, ok


def _wls(g: np.ndarray, w: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched WLS θ = (GᵀWG)⁻¹GᵀWy; returns (θ (n, 5), (GᵀWG)⁻¹ (n, 5, 5)).

    A clock column with no used satellite is pinned (its diagonal set to 1),
    which is the same as removing that unknown.
    """
    gw = g * w[..., None]
    nmat = np.matmul(gw.transpose(0, 2, 1), g)
    for c in (3, 4):
        empty = nmat[:, c, c] <= 0.0
        nmat[empty, c, c] = 1.0
    nmat = nmat + 1e-12 * np.eye(5)[None]
    ninv = np.linalg.inv(nmat)
    theta = np.matmul(ninv, np.matmul(gw.transpose(0, 2, 1), y[..., None]))[..., 0]
    return theta, ninv


def _dops(g: np.ndarray, used: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    _, q = _wls(g, used.astype(float), np.zeros(used.shape))
    hdop = np.sqrt(q[:, 0, 0] + q[:, 1, 1])
    vdop = np.sqrt(np.abs(q[:, 2, 2]))
    pdop = np.sqrt(q[:, 0, 0] + q[:, 1, 1] + q[:, 2, 2])
    return hdop, vdop, pdop


def _lock_age_s(tracked: np.ndarray, slip: np.ndarray, dt_s: float, warm_s: float) -> np.ndarray:
    """Seconds of continuous carrier-phase lock up to each epoch, (n, k).

    Lock restarts at 0 after a loss of track or a cycle slip (``slip``, bool
    (n, k)); satellites tracked at epoch 0 without a slip start at ``warm_s``.
    """
    n, k = tracked.shape
    age = np.empty((n, k))
    a = np.where(tracked[0] & ~slip[0], warm_s, 0.0)
    age[0] = a
    for i in range(1, n):
        a = np.where(tracked[i] & ~slip[i], a + dt_s, 0.0)
        age[i] = a
    return age


def slip_probability(cn0_dbhz: np.ndarray, nlos: np.ndarray, cfg: FixConfig = FixConfig()) -> np.ndarray:
    """Per-epoch probability of a cycle slip, (n, k).

    Weak signals slip more, p = p_w·exp(−(C/N0 − 25)/s), and reflected (NLOS)
    carriers, whose phase follows the moving reflection geometry, slip often
    (a behavioural model; cf. Groves 2013, *Principles of GNSS, Inertial, and
    Multisensor Integrated Navigation Systems*, 2nd ed., §9.2.4 and §10.4).

    >>> [round(float(x), 3) for x in slip_probability(np.array([25.0, 40.0]), np.array([False, True]))]
    [0.5, 0.053]
    """
    c = np.nan_to_num(np.asarray(cn0_dbhz, float), nan=0.0)
    p = cfg.slip_weak_prob * np.exp(-np.maximum(c - 25.0, 0.0) / cfg.slip_weak_scale_db)
    return np.clip(p + np.where(nlos, cfg.slip_nlos_prob, 0.0), 0.0, 1.0)


def _smooth_runs(x: np.ndarray, mask: np.ndarray, dt_s: float, tau_s: float) -> np.ndarray:
    """First-order smoothing of ``x`` (n, d) within each run of ``mask``, restarted at every run's start.

    The float and code solutions come out of the receiver's Kalman filter (ambiguity states, a pedestrian
    dynamic model) whose states carry the past: a slip or a change of the satellite set moves the position by
    a fraction of the new error per epoch, not all at once — x̂ᵢ = x̂ᵢ₋₁ + α·(xᵢ − x̂ᵢ₋₁), α = 1 − exp(−Δt/τ), the steady-state gain of a
    random-walk state observed in white noise (Brown & Hwang 2012, *Introduction to Random Signals and
    Applied Kalman Filtering*, 4th ed., §4.6, scalar steady-state filter).
    """
    if tau_s <= 0:
        return x
    alpha = 1.0 - np.exp(-dt_s / tau_s)
    out = x.copy()
    prev = None
    for i in range(len(x)):
        if not mask[i]:
            prev = None
            continue
        prev = x[i] if prev is None else prev + alpha * (x[i] - prev)
        out[i] = prev
    return out


def float_ambiguity_bias(code_err_m: np.ndarray, lock_age_s: np.ndarray, dt_s: float,
                         window_s: float = np.inf) -> np.ndarray:
    """Range error a float ambiguity carries, (n, k) m: the mean of the code error since the lock began.

    An ambiguity held constant in the RTK filter (no process noise) is estimated from code minus
    carrier; its least-squares estimate after N epochs of lock is the mean of the N code errors
    (the growing-window Hatch filter, Hatch 1982; Misra & Enge 2011, *Global Positioning System*,
    2nd ed., §6.2 on carrier smoothing as ambiguity estimation). White noise averages down as 1/√N,
    a bias the code held while the carrier stayed locked (an NLOS delay, slow multipath) stays in the
    float solution until a slip restarts the lock. Lock present at the first epoch (warm start, age
    > 0) starts from the first code error with the weight of its age. With ``window_s`` the weight
    1/N stops falling at N = window_s/dt_s (an exponentially fading mean): the filter's ambiguity
    process noise forgets data older than about the window, as the receiver's own variance
    s² = σ²/N_eff assumes (:mod:`simulation.gnss.rtk`).

    >>> e = np.array([[1.0], [3.0], [5.0], [7.0]]); age = np.array([[0.0], [1.0], [2.0], [0.0]])
    >>> float_ambiguity_bias(e, age, 1.0)[:, 0].tolist()
    [1.0, 2.0, 3.0, 7.0]
    """
    n, k = code_err_m.shape
    out = np.empty((n, k))
    count = np.minimum(np.rint(lock_age_s / dt_s) + 1.0, max(window_s / dt_s, 1.0))
    restart = np.zeros((n, k), bool)
    restart[0] = True
    restart[1:] = lock_age_s[1:] <= lock_age_s[:-1]
    prev = code_err_m[0].copy()
    out[0] = prev
    for i in range(1, n):
        prev = np.where(restart[i], code_err_m[i], prev + (code_err_m[i] - prev) / count[i])
        out[i] = prev
    return out


def cycle_slips(rng: np.random.Generator, cn0_dbhz: np.ndarray, nlos: np.ndarray,
                cfg: FixConfig = FixConfig()) -> np.ndarray:
    """Cycle-slip events, bool (n, k), drawn with :func:`slip_probability`."""
    return rng.random(np.shape(cn0_dbhz)) < slip_probability(cn0_dbhz, nlos, cfg)


def solve_fixes(rng: np.random.Generator, az_rad: np.ndarray, el_rad: np.ndarray, sys_idx: np.ndarray,
                tracked: np.ndarray, cn0_reported_dbhz: np.ndarray, errors: dict[str, np.ndarray],
                nlos: np.ndarray, dt_s: float, corrections: bool = True,
                cfg: FixConfig = FixConfig(), slip: np.ndarray | None = None,
                wavelength_m: float = 0.1903, receiver_offset_db: float = 0.0,
                rtk_cfg: RtkConfig = RtkConfig()) -> FixResult:
    """Weighted least squares with RAIM and the fix-quality state machine (module docstring).

    Parameters
    ----------
    az_rad, el_rad : (n, k); sys_idx : (k,) 0 = GPS, 1 = BeiDou
    tracked, cn0_reported_dbhz : (n, k) receiver tracking state and reported C/N0
    errors : from :func:`pseudorange_errors`
    nlos : (n, k) truth NLOS flags — physics only: they raise the slip rate; the receiver's decisions (used set,
        RAIM, float, ambiguities, fixed/float) never read them
    corrections : differential corrections (DGNSS/RTK) available
    slip : (n, k) cycle slips (default: drawn here with :func:`cycle_slips`)
    receiver_offset_db : the receiver's own C/N0 offset from the nominal open-sky curve, dB — its maker
        tunes the SNR mask to its antenna, so the mask moves with it
    rtk_cfg : the RTK engine's parameters (:mod:`simulation.gnss.rtk`)
    """
    n, k = el_rad.shape
    g = _design(az_rad, el_rad, sys_idx)
    cand = tracked & (el_rad >= np.radians(cfg.fix_mask_deg))
    used, ok = _solvable(cand, sys_idx)
    atm_scale = cfg.dgnss_residual_fraction if corrections else 1.0
    code_err = errors["noise"] + errors["multipath"] + errors["nlos_bias"] + atm_scale * errors["atmosphere"]
    floor = cfg.rx_floor_differential_m if corrections else cfg.rx_floor_autonomous_m
    sig2 = floor ** 2 + code_sigma_m(np.nan_to_num(cn0_reported_dbhz, nan=0.0),
                                     cfg.code_a_m, cfg.code_b_m_sqrt_hz) ** 2
    used, ok, theta_code, cov_code, w = _raim(g, used, ok, code_err, 1.0 / sig2, sys_idx, cfg)
    hdop, vdop, pdop = _dops(g, used)
    gst = _gst_sigma(g, w, code_err, theta_code, cov_code, used, sys_idx)

    quality = np.zeros(n, int)
    err = np.full((n, 3), np.nan)
    if not corrections:
        quality[ok] = QUALITY_AUTONOMOUS
        err[ok] = _smooth_runs(theta_code[:, :3], ok, dt_s, cfg.float_filter_tau_s)[ok]
    else:
        if slip is None:
            slip = cycle_slips(rng, cn0_reported_dbhz, nlos, cfg)
        lock = _lock_age_s(tracked, slip, dt_s, 0.0 if cfg.rtk_cold_start else cfg.warm_start_lock_s)
        locked = used & (lock >= rtk_cfg.phase_lock_s)
        # The float solution needs a redundant, well-shaped set of locked carriers: one more than the unknowns and
        # PDOP within the receiver's mask (u-blox's navigation PDOP mask defaults to 25, UBX-CFG-NAV5 pDop); five
        # high satellites of two systems solve exactly and can throw the float position hundreds of metres.
        lock_pdop = _dops(g, locked)[2]
        lock_dof = locked.sum(axis=1) - 3 - _n_systems(locked, sys_idx)
        float_ok = (ok & (locked.sum(axis=1) >= cfg.float_min_sats) & (lock_dof >= 1)
                    & (lock_pdop <= cfg.float_pdop_mask))
        # Double-differenced carrier: the base a few km away leaves ≈ 1 ppm of the atmosphere (rtk_atm_fraction).
        carrier_err = errors["carrier"] + cfg.rtk_atm_fraction * errors["atmosphere"]
        # Float ambiguity prior λÑ = mean(Φ − P) since lock: its error a = mean(e_Φ − e_P); the receiver's variance
        # s² = σ²_code/N_eff, its filter counting float_indep_rate_hz independent code samples a second.
        amb = float_ambiguity_bias(carrier_err - code_err, lock, dt_s, rtk_cfg.float_weight_window_s)
        n_eff = np.minimum(lock * rtk_cfg.float_indep_rate_hz + 1.0,
                           max(rtk_cfg.float_weight_window_s * rtk_cfg.float_indep_rate_hz, 1.0))
        s2 = sig2 / n_eff
        sig_phi2 = carrier_model_var_m2(el_rad, rtk_cfg)
        theta_f, cov_f, w_f = float_solution(g, locked, carrier_err, amb, s2, sig_phi2)
        # Partial ambiguity resolution: carriers above an elevation-dependent SNR mask, the nominal open-sky C/N0
        # less a margin (RTKLIB's pos1-snrmask; Takasu, RTKLIB 2.4.2 manual).
        mask = open_sky_cn0_dbhz(el_rad) + receiver_offset_db - rtk_cfg.snr_margin_db
        cn0_ok = np.nan_to_num(cn0_reported_dbhz, nan=0.0) >= mask
        res = rtk_engine(g, used, lock, cn0_ok, el_rad, sys_idx, carrier_err, amb, s2, theta_f, cov_f, float_ok,
                         wavelength_m, theta_code, cov_code, dt_s, rtk_cfg)
        fixed = res.fixed & ok
        quality[ok] = QUALITY_DGNSS
        quality[float_ok] = QUALITY_RTK_FLOAT
        quality[fixed] = QUALITY_RTK_FIXED
        raw = np.where(float_ok[:, None], theta_f[:, :3], theta_code[:, :3])
        # The float (or code) filter runs beneath the fixed output and is not restarted when a fix is
        # declared or lost: a lost fix falls back to the float state it had all along.
        free = ok & ~fixed
        err[free] = _smooth_runs(raw, ok, dt_s, cfg.float_filter_tau_s)[free]
        err[fixed] = res.fixed_error_enu_m[fixed]
        gst_f = _gst_sigma(g, w_f, carrier_err - amb, theta_f, cov_f, locked, sys_idx)
        gst = np.where(float_ok[:, None], gst_f, gst)
        gst[fixed] = res.gst[fixed]
    hdop = np.where(ok, hdop, np.nan)
    vdop = np.where(ok, vdop, np.nan)
    pdop = np.where(ok, pdop, np.nan)
    gst[~ok] = np.nan
    return FixResult(err, quality, used, hdop, vdop, pdop, gst, code_err)


def _raim(g, used, ok, code_err, w_all, sys_idx, cfg):
    """Code WLS with RAIM exclusions (module docstring); returns (used, ok, θ (n, 5), (GᵀWG)⁻¹, weights (n, k))."""
    for n_excluded in range(cfg.raim_max_exclusions + 1):
        w = np.where(used & ok[:, None], w_all, 0.0)
        theta, ninv = _wls(g, w, code_err)
        resid = code_err - np.matmul(g, theta[..., None])[..., 0]
        dof = used.sum(axis=1) - 3 - _n_systems(used, sys_idx)
        test = (w * resid ** 2).sum(axis=1)
        thresh = chi2.ppf(1.0 - cfg.raim_pfa, np.maximum(dof, 1))
        fail = ok & (dof >= 2) & (test > thresh)
        if not fail.any() or n_excluded == cfg.raim_max_exclusions:
            break
        # Standardised residual w·r²/(1 − h), h = w·gᵀ(GᵀWG)⁻¹g (hat-matrix diagonal).
        h = w * (np.matmul(g, ninv) * g).sum(axis=-1)
        std = np.where(used, w * resid ** 2 / np.maximum(1.0 - h, 1e-6), -1.0)
        worst = std.argmax(axis=1)
        rows = np.flatnonzero(fail)
        used[rows, worst[rows]] = False
        used, ok = _solvable(used, sys_idx)
    used &= ok[:, None]
    w = np.where(used, w_all, 0.0)
    theta, ninv = _wls(g, w, code_err)
    return used, ok, theta, ninv, w


def _n_systems(used: np.ndarray, sys_idx: np.ndarray) -> np.ndarray:
    return used[:, sys_idx == 0].any(axis=1).astype(int) + used[:, sys_idx == 1].any(axis=1)


def _gst_sigma(g, w, y_err, theta, cov, used, sys_idx) -> np.ndarray:
    """The receiver's GST of a solution (:func:`gst_fields`, shape (n, 7)): its covariance (GᵀWG)⁻¹ scaled by the
    a-posteriori variance factor of its own residuals r = y − Gθ, σ̂₀² = rᵀWr/(m − p) (the receiver scales its
    covariance by how well its residuals fit, so biases the solution absorbs make σ too small), and the RMS of
    the residuals. NaN where fewer observations than unknowns + 1."""
    r = np.where(used, y_err - np.matmul(g, theta[..., None])[..., 0], 0.0)
    m = used.sum(axis=1)
    dof = m - 3 - _n_systems(used, sys_idx)
    v = np.where(dof >= 1, (w * r * r).sum(axis=1) / np.maximum(dof, 1), np.nan)
    rms = np.where(m > 0, np.sqrt((r * r).sum(axis=1) / np.maximum(m, 1)), np.nan)
    return gst_fields(cov[:, :3, :3], v, rms)
