"""Acoustic positions: east, north and receiver clock offset from beacon times of arrival.

Measurement model (one TDMA frame, beacons i heard; device height h known):

    ρᵢ = c·(aᵢ − txᵢ) = ‖(e, n, h) − sᵢ‖ + c·δ + vᵢ

with ``aᵢ`` the first arrival on the receiver's stated clock, ``txᵢ`` the
beacon's emission time (both walk time), ``sᵢ`` the beacon position, δ the
receiver clock offset (stated − true) and vᵢ noise. This is the
pseudorange problem of GNSS in two dimensions plus clock (Kaplan & Hegarty,
"Understanding GPS/GNSS", 3rd ed., §11.2.1), solved by Gauss-Newton least
squares (Björck 1996, §9.2):

    # x ← x + (JᵀWJ)⁻¹ JᵀW (ρ − f(x)),   J = [∂f/∂e, ∂f/∂n, c],   W = diag(1/σᵢ²)

and the covariance of (e, n, δ) is (JᵀWJ)⁻¹ at convergence. Hand-written
rather than ``scipy.optimize.least_squares`` because the problem has three
unknowns and a closed-form Jacobian, and the covariance and per-beacon
residuals are needed for fault exclusion anyway.

σᵢ is the Cramér–Rao bound of a time-of-arrival estimate for a band of width
B, σ_τ = 1/(2π·β·sqrt(2·SNR)) with rms bandwidth β = B/√12 (Kay, "Fundamentals
of Statistical Signal Processing, Vol. I", 1993, §3.11, eq. 3.38), times c,
with a floor (:data:`RANGE_SIGMA_FLOOR_M`) for the errors the bound ignores
(sampling, interpolation, beacon survey).

NLOS rejection (receiver autonomous fault detection and exclusion in the
manner of RAIM; Parkinson & Axelrad 1988, Navigation 35(2)): when the
weighted residual sum of squares exceeds the chi-square quantile with n − 3
degrees of freedom, subsets are tried by decreasing size and the largest one
that passes the test (smallest chi² among equals) is kept; no subset below
four beacons is accepted, since three beacons leave nothing to test.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from features.acoustic import lsq
from features.errors import ConfigError
from features.site import Site

__all__ = ["BeaconRange", "AcousticFix", "PositionConfig", "solve_position", "toa_range_sigma_m",
           "RANGE_SIGMA_FLOOR_M", "POSITION_COLUMNS", "least_squares_fix", "chi2_limit"]

RANGE_SIGMA_FLOOR_M = 0.05
"""Smallest range standard deviation assumed, m (sub-sample interpolation, beacon survey, grazing paths).

On simulated walks correctly associated LOS ranges scatter by 3–6 cm about the
truth (the leading edge of a path grazing an equipment edge, interpolation),
so a 1 cm floor failed the chi-square test of most correct five-beacon fixes;
wrong associations are off by metres and still fail it at 5 cm."""

POSITION_COLUMNS = ("t_s", "east_m", "north_m", "clock_offset_s", "n_beacons", "var_east_m2", "cov_en_m2",
                    "var_north_m2", "clock_offset_std_s", "rms_residual_m", "n_rejected")
"""Columns of an acoustic positions CSV, one row per frame."""


@dataclass(frozen=True)
class PositionConfig:
    """Solver settings: chi-square test level, iteration limit, plausibility bounds, motion prior.

    ``motion_speed_m_s``: the beacons of one frame are heard up to a frame
    apart while the receiver walks, which a static model sees as range error of
    about v·(tᵢ − t̄)·cos θ. Each range variance gets ½·(v·(tᵢ − t̄))² added
    (cos² θ averages ½ over directions). Default 0 (static model): on simulated
    walks a 1.4 m/s prior let wrong associations pass the residual test and
    gave more but worse fixes (metres instead of decimetres); the fusion
    filter, which knows the motion, is the better place to weigh them.

    ``max_excluded_share``: with many beacons heard (a coverage deployment hears 8–18) more
    than ``max_excluded`` of them can be NLOS or wrongly associated; up to this share of the
    frame's beacons may then be left out, by backward elimination once the subsets of a size
    exceed :data:`features.acoustic.lsq.MAX_SUBSETS` (see :func:`features.acoustic.lsq.exclude`). 0 keeps ``max_excluded`` alone.

    The air. The receiver turns times into ranges with c from the crew's thermometer, dry air:
    the reading is off by ±1–2 K (0.17–0.35 % of c; c ∝ √T, Cramer 1993), humidity adds
    0.2–0.3 %, a wind w along the path c_eff = c + w·n̂ (Ostashev & Wilson 2015), and warm
    air over transformers differs path by path. ``path_rel_sigma`` is the per-path part (each
    range's variance takes (ε·ρ)², :func:`features.acoustic.frame_fix.frame_ranges`);
    ``air_rel_sigma`` (a common scale error of c) and ``wind_sigma_m_s`` (per horizontal axis)
    are common to every beacon of a fix, which a diagonal weight cannot describe: they enter the
    fix's covariance as *consider parameters* (Tapley, Schutz & Born, "Statistical Orbit
    Determination", 2004, §6.3: P_c = P + K·G·Σ·Gᵀ·Kᵀ, K = (JᵀWJ)⁻¹JᵀW, G = ∂ρ/∂(w_e, w_n, k)),
    without moving the estimate (:func:`features.acoustic.lsq.consider_covariance`). Without them a fix on 10–15
    beacons claimed 3 cm while it stood 0.2–0.4 m off for tens of seconds in a steady wind
    (NEES 40–200 on the coverage deployment's walks). Set all three to 0 for an exactly known
    sound speed (Monte Carlo tests of the solver).

    ``estimate_air``: the tracker estimates the wind and the sound-speed scale from its fixes
    (:mod:`features.acoustic.air`), corrects each frame's ranges by them and takes the estimate's σ, not
    ``wind_sigma_m_s`` / ``air_rel_sigma``, as the consider parameters (those are then the priors; either
    at 0 switches the estimate off too).

    A screen of the exclusion search was tried and left out (issue 25): scoring every subset first by
    the deletion formula of linear least squares at the all-beacon fix (Cook & Weisberg 1982, §3.6)
    and solving only those within 3× the test's limit took 24–31 % less CPU, but the linearisation at
    an NLOS-dragged fix screened out the right subset often enough to change the track on 5 of the 15
    held-out walks (light-area error 0.592 → 0.640 m mean); at 30× it saved about 10 %, within
    run-to-run scatter. The compiled search (:mod:`features.acoustic.lsq`) made the question moot.
    """

    chi2_alpha: float = 1e-3
    max_iterations: int = 20
    max_clock_offset_s: float | None = None
    bounds_margin_m: float = 20.0
    motion_speed_m_s: float = 0.0
    max_excluded: int = 3
    max_excluded_share: float = 0.0
    path_rel_sigma: float = 0.002
    air_rel_sigma: float = 0.003
    wind_sigma_m_s: float = 2.0
    estimate_air: bool = True

    def __post_init__(self):
        for name, most in (("path_rel_sigma", 0.1), ("air_rel_sigma", 0.1), ("wind_sigma_m_s", 20.0)):
            if not 0 <= getattr(self, name) < most:
                raise ConfigError(f"{name} must lie in [0, {most:g}), got {getattr(self, name)}")
        if self.max_clock_offset_s is not None and not self.max_clock_offset_s > 0:
            raise ConfigError(f"max_clock_offset_s must be positive, got {self.max_clock_offset_s}")
        if not self.bounds_margin_m >= 0:
            raise ConfigError(f"bounds_margin_m must be >= 0, got {self.bounds_margin_m}")
        if not isinstance(self.max_excluded, int) or self.max_excluded < 0:
            raise ConfigError(f"max_excluded must be an integer >= 0, got {self.max_excluded!r}")
        if not 0 <= self.max_excluded_share < 0.5:
            raise ConfigError(f"max_excluded_share must lie in [0, 0.5), got {self.max_excluded_share}")
        if not 0 <= self.motion_speed_m_s < 10:
            raise ConfigError(f"motion_speed_m_s must lie in [0, 10), got {self.motion_speed_m_s}")
        if not 0 < self.chi2_alpha < 1:
            raise ConfigError(f"chi2_alpha must lie in (0, 1), got {self.chi2_alpha}")
        if self.max_iterations < 1:
            raise ConfigError(f"max_iterations must be >= 1, got {self.max_iterations}")


class BeaconRange(NamedTuple):
    """One pseudorange: beacon position (ENU m), ``pseudorange_m`` = c·(arrival − emission), σ in m;
    ``arrival_s`` the stated time the range refers to (the arrival plus the chirp's range–Doppler
    lag, see :func:`features.acoustic.frame_fix.frame_fix`), used for the fix's time tag."""

    beacon_id: int
    east_m: float
    north_m: float
    up_m: float
    pseudorange_m: float
    sigma_m: float
    arrival_s: float


@dataclass(frozen=True)
class AcousticFix:
    """A position fix. ``covariance`` of (east_m, north_m, clock_offset_s), shape (3, 3)."""

    t_s: float
    east_m: float
    north_m: float
    clock_offset_s: float
    n_beacons: int
    covariance: np.ndarray
    rms_residual_m: float
    used_ids: tuple[int, ...]
    rejected_ids: tuple[int, ...]
    ranges: tuple = field(default=(), repr=False, compare=False)
    """The :class:`BeaconRange` s the fix kept (for the air estimate, :mod:`features.acoustic.air`)."""

    def as_row(self) -> dict:
        """A row of the positions CSV (:data:`POSITION_COLUMNS`)."""
        cov = self.covariance
        return {"t_s": self.t_s, "east_m": self.east_m, "north_m": self.north_m,
                "clock_offset_s": self.clock_offset_s, "n_beacons": self.n_beacons,
                "var_east_m2": cov[0, 0], "cov_en_m2": cov[0, 1], "var_north_m2": cov[1, 1],
                "clock_offset_std_s": math.sqrt(max(cov[2, 2], 0.0)),
                "rms_residual_m": self.rms_residual_m, "n_rejected": len(self.rejected_ids)}


def toa_range_sigma_m(snr_db: float, bandwidth_hz: float, speed_m_s: float) -> float:
    """Range standard deviation from the TOA Cramér–Rao bound (see module docstring), floored.

    >>> round(toa_range_sigma_m(30.0, 6000.0, 343.0), 4)
    0.05
    >>> round(toa_range_sigma_m(-10.0, 6000.0, 343.0), 4)
    0.0705
    """
    snr = 10.0 ** (snr_db / 10.0)
    beta = bandwidth_hz / math.sqrt(12.0)
    sigma_m = speed_m_s / (2.0 * math.pi * beta * math.sqrt(2.0 * (snr if snr > 1e-12 else 1e-12)))
    return sigma_m if sigma_m > RANGE_SIGMA_FLOOR_M else RANGE_SIGMA_FLOOR_M


@functools.lru_cache(maxsize=64)
def chi2_limit(dof: int, alpha: float) -> float:
    """Upper ``alpha`` quantile of the chi-square law with ``dof`` degrees of freedom (cached).

    ``scipy.special.chdtri`` (the inverse survival function, equal to
    ``scipy.stats.chi2.ppf(1 − alpha, dof)``), imported here: ``scipy.stats``
    would cost about a second of start-up.

    >>> round(chi2_limit(1, 1e-3), 3)
    10.828
    """
    import scipy.special

    return float(scipy.special.chdtri(dof, alpha))


def _arrays(ranges: list[BeaconRange]) -> tuple[np.ndarray, ...]:
    """Beacon east, north, up (m), pseudorange (m) and σ (m) of ``ranges``: five contiguous float arrays (n,).
    (The named tuples read whole, their fields by position: a third of the time of a tuple built per range.)"""
    a = np.array(ranges, dtype=float).reshape(-1, len(BeaconRange._fields))
    return tuple(np.ascontiguousarray(a[:, 1:6].T))


@functools.lru_cache(maxsize=64)
def _chi2_limits(n: int, alpha: float) -> np.ndarray:
    """:func:`chi2_limit` of 0 … ``n`` degrees of freedom (∞ for 0): the exclusion's tests. Cached and shared:
    read it, never write it (left writeable: numba would compile a second, read-only specialisation).

    The 0.999 quantiles of 1, 2, 3 degrees of freedom (tables: 10.828, 13.816, 16.266):

    >>> _chi2_limits(3, 1e-3).round(3).tolist()
    [inf, 10.828, 13.816, 16.266]
    """
    return np.array([chi2_limit(dof, alpha) if dof > 0 else math.inf for dof in range(n + 1)])


def _clock_prior(clock_prior: tuple[float, float] | None) -> tuple[float, float]:
    """(δ₀, 1/σ_δ²) of a clock prior (δ₀, σ_δ); (0, 0) for none."""
    if clock_prior is None:
        return 0.0, 0.0
    return float(clock_prior[0]), 1.0 / (float(clock_prior[1]) * float(clock_prior[1]))


def least_squares_fix(ranges: list[BeaconRange], height_m: float, c: float, iterations: int,
                      start: np.ndarray | None = None, clock_prior: tuple[float, float] | None = None):
    """(x = [e, n, δ], covariance (3, 3), residuals (n,), sigmas (n,), chi²) or None if singular.

    One Gauss–Newton solve of all ``ranges`` (:func:`features.acoustic.lsq.gauss_newton`, which states
    the stopping rule): from ``start`` (e.g. the previous fix) or from the weighted centroid of the
    beacons with the median clock offset. ``clock_prior`` = (δ₀, σ_δ) adds the pseudo-measurement
    δ = δ₀ ± σ_δ (a tracked clock), which enters the normal equations and chi² like one more range.
    """
    se, sn, su, rho, sig = _arrays(ranges)
    prior_d, prior_w = _clock_prior(clock_prior)
    x0 = np.zeros(3) if start is None else np.array(start, dtype=float).reshape(3)
    ok, x, cov, res, chi2 = lsq.gauss_newton(se, sn, su, rho, sig, float(height_m), float(c), int(iterations), x0,
                                             start is not None, prior_d, prior_w)
    return (x, cov, res, sig, float(chi2)) if ok else None


def solve_position(ranges: list[BeaconRange], site: Site, speed_m_s: float,
                   config: PositionConfig = PositionConfig(), start: np.ndarray | None = None,
                   clock_prior: tuple[float, float] | None = None,
                   position_prior: tuple[float, float, float] | None = None,
                   t_ref_s: float | None = None) -> AcousticFix | None:
    """Gauss-Newton fix with NLOS exclusion; None when too few beacons or no plausible solution.

    ``start``: optional initial (east_m, north_m, clock_offset_s), e.g. the previous fix.
    ``clock_prior``: optional (clock_offset_s, sigma_s) from a tracked clock; with it
    three beacons leave one degree of freedom for the residual test.
    ``position_prior``: optional (east_m, north_m, sigma_m) predicted by a track; it does
    not enter the fix, only the choice among subsets of equal size that pass the test
    (smallest chi² + ‖p − p̂‖²/σ², the innovation's share): under poor geometry a subset
    keeping an NLOS-biased beacon can fit as well as the right one, but lies metres off.
    ``t_ref_s``: the stated time the ranges were motion-compensated to (see
    :func:`features.acoustic.frame_fix.frame_fix`); the fix's ``t_s`` is then that time less
    the clock offset, whichever beacons the exclusion keeps. Without it, ``t_s`` is the
    mean arrival of the kept beacons less the clock offset (the static model: the fix is
    where the receiver stood while they were heard).
    """
    ranges = list(ranges)
    h = site.device_height_m
    n_prior = 0 if clock_prior is None else 1
    if len(ranges) < 3:
        return None
    sol = least_squares_fix(ranges, h, speed_m_s, config.max_iterations, start, clock_prior)
    if sol is None and start is None:
        sol = _multistart(ranges, site, speed_m_s, config, clock_prior)
    if sol is None:
        return None
    x, cov, res, sig, chi2 = sol
    dof = len(ranges) + n_prior - 3
    rejected: list[int] = []
    if dof > 0 and chi2 > chi2_limit(dof, config.chi2_alpha):
        found = _exclude(ranges, h, speed_m_s, config, x, clock_prior, position_prior)
        if found is None:
            return None
        keep, x, cov, res = found
        rejected = [r.beacon_id for i, r in enumerate(ranges) if i not in keep]
        ranges = [ranges[i] for i in keep]
    if not _plausible(x, site, config):
        return None
    if config.air_rel_sigma > 0 or config.wind_sigma_m_s > 0:
        se, sn, su, _, sig = _arrays(ranges)
        cov = lsq.consider_covariance(se, sn, su, sig, x, cov, float(h), float(speed_m_s),
                                      float(config.wind_sigma_m_s), float(config.air_rel_sigma))
    east, north, clock = x.tolist()
    t_stated = sum(r.arrival_s for r in ranges) / len(ranges) if t_ref_s is None else t_ref_s
    t_true = t_stated - clock
    return AcousticFix(t_s=t_true, east_m=east, north_m=north, clock_offset_s=clock,
                       n_beacons=len(ranges), covariance=cov,
                       rms_residual_m=math.sqrt(float(res @ res) / len(res)),
                       used_ids=tuple(r.beacon_id for r in ranges), rejected_ids=tuple(rejected),
                       ranges=tuple(ranges))


def _exclude(ranges: list[BeaconRange], h: float, c: float, config: PositionConfig, start, clock_prior=None,
             position_prior=None):
    """(kept indices, x, covariance, residuals of the kept) of the exclusion search, or None.

    The largest subset (of four or more, three with a clock prior) whose residuals pass the
    chi-square test, the smallest score among equals, beyond the exhaustive search's budget by
    backward elimination: :func:`features.acoustic.lsq.exclude`. With n − k beacons kept, k
    NLOS-biased beacons can be excluded, which the classic one-at-a-time leave-one-out cannot do
    reliably once two are biased.
    """
    se, sn, su, rho, sig = _arrays(ranges)
    n = len(ranges)
    prior_d, prior_w = _clock_prior(clock_prior)
    limits = _chi2_limits(n, config.chi2_alpha)
    pos_prior = np.zeros(3) if position_prior is None else np.array(position_prior, dtype=float)
    found, keep, x, cov, res, _ = lsq.exclude(se, sn, su, rho, sig, float(h), float(c), int(config.max_iterations),
                                              np.array(start, dtype=float).reshape(3), prior_d, prior_w, pos_prior,
                                              limits, int(config.max_excluded),
                                              int(math.floor(config.max_excluded_share * n)))
    if not found:
        return None
    return tuple(int(i) for i in np.flatnonzero(keep)), x, cov, res[keep]


def _multistart(ranges: list[BeaconRange], site: Site, c: float, config: PositionConfig, clock_prior=None):
    """Gauss-Newton from the centres of the site grid's quarters (:func:`features.acoustic.lsq.multistart`);
    the solution of least chi², as :func:`least_squares_fix` returns it, or None."""
    g = site.grid
    starts = np.array([(g.east_min_m + fe * (g.east_max_m - g.east_min_m), g.north_min_m + fn * (g.north_max_m - g.north_min_m))
                       for fe in (0.25, 0.75) for fn in (0.25, 0.75)])
    se, sn, su, rho, sig = _arrays(ranges)
    prior_d, prior_w = _clock_prior(clock_prior)
    ok, x, cov, res, chi2 = lsq.multistart(se, sn, su, rho, sig, float(site.device_height_m), float(c),
                                           int(config.max_iterations), starts, prior_d, prior_w)
    return (x, cov, res, sig, float(chi2)) if ok else None


def _plausible(x: np.ndarray, site: Site, config: PositionConfig) -> bool:
    e, n, d = x.tolist()
    g, m = site.grid, config.bounds_margin_m
    inside = (g.east_min_m - m <= e <= g.east_max_m + m) and (g.north_min_m - m <= n <= g.north_max_m + m)
    clock_ok = config.max_clock_offset_s is None or abs(d) <= config.max_clock_offset_s
    return inside and clock_ok and math.isfinite(e + n + d)
