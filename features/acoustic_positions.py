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
degrees of freedom, each beacon is left out in turn and the subset with the
smallest normalised residual sum is kept (with four beacons, where a subset
cannot be tested, the beacon whose left-out residual is most positive, since
a blocked path is always longer than the direct one). This repeats while at
least four beacons remain.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

from .errors import ConfigError
from .site import Site

__all__ = ["BeaconRange", "AcousticFix", "PositionConfig", "solve_position", "toa_range_sigma_m",
           "RANGE_SIGMA_FLOOR_M", "POSITION_COLUMNS"]

RANGE_SIGMA_FLOOR_M = 0.01
"""Smallest range standard deviation assumed, m (sub-sample interpolation and beacon survey errors)."""

POSITION_COLUMNS = ("t_s", "east_m", "north_m", "clock_offset_s", "n_beacons", "var_east_m2", "cov_en_m2",
                    "var_north_m2", "clock_offset_std_s", "rms_residual_m", "n_rejected")
"""Columns of an acoustic positions CSV, one row per frame."""


@dataclass(frozen=True)
class PositionConfig:
    """Solver settings: chi-square test level, iteration limit, plausibility bounds."""

    chi2_alpha: float = 1e-3
    max_iterations: int = 20
    max_clock_offset_s: float | None = None
    bounds_margin_m: float = 20.0

    def __post_init__(self):
        if not 0 < self.chi2_alpha < 1:
            raise ConfigError(f"chi2_alpha must lie in (0, 1), got {self.chi2_alpha}")
        if self.max_iterations < 1:
            raise ConfigError(f"max_iterations must be >= 1, got {self.max_iterations}")


@dataclass(frozen=True)
class BeaconRange:
    """One pseudorange: beacon position (ENU m), ``pseudorange_m`` = c·(arrival − emission), σ in m."""

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
    0.01
    >>> round(toa_range_sigma_m(0.0, 6000.0, 343.0), 4)
    0.0223
    """
    snr = 10.0 ** (snr_db / 10.0)
    beta = bandwidth_hz / math.sqrt(12.0)
    sigma_s = 1.0 / (2.0 * math.pi * beta * math.sqrt(2.0 * max(snr, 1e-12)))
    return max(RANGE_SIGMA_FLOOR_M, speed_m_s * sigma_s)


@functools.lru_cache(maxsize=64)
def _chi2_limit(dof: int, alpha: float) -> float:
    """Upper ``alpha`` quantile of the chi-square law with ``dof`` degrees of freedom (cached)."""
    return float(scipy.stats.chi2.ppf(1.0 - alpha, dof))


def _gauss_newton(ranges: list[BeaconRange], height_m: float, c: float, iterations: int,
                  start: np.ndarray | None = None):
    """(x = [e, n, δ], covariance (3, 3), residuals (n,), sigmas (n,)) or None if singular.

    Starts from ``start`` (e.g. the previous fix) or from the weighted centroid
    of the beacons with the median clock offset.
    """
    s = np.array([[r.east_m, r.north_m, r.up_m] for r in ranges])
    rho = np.array([r.pseudorange_m for r in ranges])
    sig = np.array([r.sigma_m for r in ranges])
    w = 1.0 / sig ** 2
    du = height_m - s[:, 2]
    if start is None:
        e0, n0 = float(w @ s[:, 0] / w.sum()), float(w @ s[:, 1] / w.sum())
        geo = np.sqrt((s[:, 0] - e0) ** 2 + (s[:, 1] - n0) ** 2 + du ** 2)
        x = np.array([e0, n0, float(np.median(rho - geo)) / c])
    else:
        x = np.array(start, dtype=float)
    jac = np.empty((len(ranges), 3))
    jac[:, 2] = c
    for it in range(iterations + 1):
        de, dn = x[0] - s[:, 0], x[1] - s[:, 1]
        r = np.sqrt(de * de + dn * dn + du * du)
        # f(x) = ‖p − sᵢ‖ + c·δ;  J = [∂f/∂e, ∂f/∂n, ∂f/∂δ]
        jac[:, 0], jac[:, 1] = de / r, dn / r
        res = rho - (r + c * x[2])
        normal = jac.T @ (w[:, None] * jac)
        if it == iterations:
            break
        try:
            step = np.linalg.solve(normal, jac.T @ (w * res))
        except np.linalg.LinAlgError:
            return None
        x = x + step
        if step[0] * step[0] + step[1] * step[1] < 1e-12 and abs(step[2]) * c < 1e-6:
            iterations = it + 1
    # Covariance of the weighted LS estimate: (JᵀWJ)⁻¹ (refused when nearly singular).
    try:
        cov = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) <= 0) or cov[0, 0] + cov[1, 1] > 1e8:
        return None
    return x, 0.5 * (cov + cov.T), res, sig


def solve_position(ranges: list[BeaconRange], site: Site, speed_m_s: float,
                   config: PositionConfig = PositionConfig(), start: np.ndarray | None = None) -> AcousticFix | None:
    """Gauss-Newton fix with NLOS exclusion; None when fewer than 3 beacons or no plausible solution.

    ``start``: optional initial (east_m, north_m, clock_offset_s), e.g. the previous fix.
    """
    ranges = list(ranges)
    rejected: list[int] = []
    h = site.device_height_m
    while len(ranges) >= 3:
        sol = _gauss_newton(ranges, h, speed_m_s, config.max_iterations, start)
        if sol is None:
            return None
        x, cov, res, sig = sol
        dof = len(ranges) - 3
        chi2 = float(np.sum((res / sig) ** 2))
        if dof == 0 or chi2 <= _chi2_limit(dof, config.chi2_alpha):
            break
        drop = _exclusion_candidate(ranges, h, speed_m_s, config.max_iterations)
        if drop is None:
            return None
        rejected.append(ranges[drop].beacon_id)
        del ranges[drop]
    else:
        return None
    if not _plausible(x, site, config):
        return None
    t_true = float(np.mean([r.arrival_s for r in ranges])) - x[2]
    return AcousticFix(t_s=t_true, east_m=float(x[0]), north_m=float(x[1]), clock_offset_s=float(x[2]),
                       n_beacons=len(ranges), covariance=cov,
                       rms_residual_m=float(np.sqrt(np.mean(res ** 2))),
                       used_ids=tuple(r.beacon_id for r in ranges), rejected_ids=tuple(rejected))


def _exclusion_candidate(ranges: list[BeaconRange], h: float, c: float, iterations: int) -> int | None:
    """Index of the beacon to exclude (leave-one-out; see module docstring)."""
    best, best_score = None, math.inf
    for i in range(len(ranges)):
        subset = ranges[:i] + ranges[i + 1:]
        sol = _gauss_newton(subset, h, c, iterations)
        if sol is None:
            continue
        x, _, res, sig = sol
        if len(subset) > 3:
            score = float(np.sum((res / sig) ** 2)) / (len(subset) - 3)
        else:
            left = ranges[i]
            pred = math.dist((x[0], x[1], h), (left.east_m, left.north_m, left.up_m)) + c * x[2]
            score = -(left.pseudorange_m - pred) / left.sigma_m
        if score < best_score:
            best, best_score = i, score
    return best


def _plausible(x: np.ndarray, site: Site, config: PositionConfig) -> bool:
    g, m = site.grid, config.bounds_margin_m
    inside = (g.east_min_m - m <= x[0] <= g.east_max_m + m) and (g.north_min_m - m <= x[1] <= g.north_max_m + m)
    clock_ok = config.max_clock_offset_s is None or abs(x[2]) <= config.max_clock_offset_s
    return bool(inside and clock_ok and np.all(np.isfinite(x)))
