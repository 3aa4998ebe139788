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
import itertools
import math
import statistics
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from features.errors import ConfigError
from features.site import Site

__all__ = ["BeaconRange", "AcousticFix", "PositionConfig", "solve_position", "toa_range_sigma_m",
           "RANGE_SIGMA_FLOOR_M", "POSITION_COLUMNS"]

_STEP_TOL_M = 1e-4
"""Gauss-Newton stops once a step moves the position and c·δ by less than this, m (0.1 mm)."""

_SCALAR_SUBSETS = 16
"""Up to this many subsets of one size are solved one by one (scalar, each stopping on its own);
more are solved together (:func:`_gauss_newton_subsets`)."""

_MAX_SUBSETS = 256
"""Most beacon subsets tried when excluding NLOS-biased beacons (C(8, 4) = 70, C(10, 5) = 252)."""

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
    exceed :data:`_MAX_SUBSETS` (see :func:`_exclude`). 0 keeps ``max_excluded`` alone.

    The air. The receiver turns times into ranges with c from the crew's thermometer, dry air:
    the reading is off by ±1–2 K (0.17–0.35 % of c; c ∝ √T, Cramer 1993), humidity adds
    0.2–0.3 %, a wind w along the path c_eff = c + w·n̂ (Ostashev & Wilson 2015), and warm
    air over transformers differs path by path. ``path_rel_sigma`` is the per-path part (each
    range's variance takes (ε·ρ)², :func:`features.acoustic.frame_fix.frame_ranges`);
    ``air_rel_sigma`` (a common scale error of c) and ``wind_sigma_m_s`` (per horizontal axis)
    are common to every beacon of a fix, which a diagonal weight cannot describe: they enter the
    fix's covariance as *consider parameters* (Tapley, Schutz & Born, "Statistical Orbit
    Determination", 2004, §6.3: P_c = P + K·G·Σ·Gᵀ·Kᵀ, K = (JᵀWJ)⁻¹JᵀW, G = ∂ρ/∂(w_e, w_n, k)),
    without moving the estimate (:func:`_consider_covariance`). Without them a fix on 10–15
    beacons claimed 3 cm while it stood 0.2–0.4 m off for tens of seconds in a steady wind
    (NEES 40–200 on the coverage deployment's walks). Set all three to 0 for an exactly known
    sound speed (Monte Carlo tests of the solver).

    ``estimate_air``: the tracker estimates the wind and the sound-speed scale from its fixes
    (:mod:`features.acoustic.air`), corrects each frame's ranges by them and takes the estimate's σ, not
    ``wind_sigma_m_s`` / ``air_rel_sigma``, as the consider parameters (those are then the priors; either
    at 0 switches the estimate off too).

    ``exclusion_screen``: when > 0, the exclusion search (:func:`_exclude`) first scores every subset
    of a size in closed form, by the deletion formula of linear least squares at the all-beacon fix
    (:func:`_deletion_chi2`), and solves only those whose linearised chi² is at most this multiple of
    the test's limit. Off by default (0: every subset solved), because it does not pay on held-out
    walks (the 15 test walks of the standard split, sites 201–205): at 3× the receiver took 24–31 %
    less CPU, but the linearisation at an NLOS-dragged fix screened out the right subset often
    enough to change the track on 5 walks, and the acoustic error in light grew from 0.592 to
    0.640 m mean (p95 2.26 → 3.19 m); at 30× the fixes were the same as the full search's, and
    the saving (about 10 %) within this machine's run-to-run scatter.
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
    exclusion_screen: float = 0.0
    estimate_air: bool = True

    def __post_init__(self):
        if not (math.isfinite(self.exclusion_screen) and self.exclusion_screen >= 0):
            raise ConfigError(f"exclusion_screen must be a finite number >= 0, got {self.exclusion_screen}")
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
def _chi2_limit(dof: int, alpha: float) -> float:
    """Upper ``alpha`` quantile of the chi-square law with ``dof`` degrees of freedom (cached).

    ``scipy.special.chdtri`` (the inverse survival function, equal to
    ``scipy.stats.chi2.ppf(1 − alpha, dof)``), imported here: ``scipy.stats``
    would cost about a second of start-up.

    >>> round(_chi2_limit(1, 1e-3), 3)
    10.828
    """
    import scipy.special

    return float(scipy.special.chdtri(dof, alpha))


def _inverse3_sym(a: float, b: float, c: float, e: float, f: float, i: float) -> tuple | None:
    """Upper triangle (00, 01, 02, 11, 12, 22) of the inverse of the symmetric matrix
    [[a, b, c], [b, e, f], [c, f, i]] by its adjugate, or None when nearly singular.

    Scalar Python: on a 3×3 system numpy's call overhead exceeds the arithmetic many
    times over, and the receiver solves one or more per TDMA frame.

    >>> u = _inverse3_sym(4.0, 1.0, 0.5, 3.0, 0.2, 2.0)
    >>> m = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    >>> bool(np.allclose(np.array(_sym_rows(u)) @ m, np.eye(3))), _inverse3_sym(1.0, 1.0, 0.0, 1.0, 0.0, 1.0)
    (True, None)
    """
    c00, c01, c02 = e * i - f * f, c * f - b * i, b * f - c * e
    det = a * c00 + b * c01 + c * c02
    scale = abs(a) + abs(e) + abs(i)
    if not math.isfinite(det) or abs(det) <= 1e-14 * scale ** 3:
        return None
    return c00 / det, c01 / det, c02 / det, (a * i - c * c) / det, (b * c - a * f) / det, (a * e - b * b) / det


def _sym_rows(u: tuple) -> list:
    """Rows of the symmetric 3×3 matrix whose upper triangle is ``u`` (00, 01, 02, 11, 12, 22)."""
    return [[u[0], u[1], u[2]], [u[1], u[3], u[4]], [u[2], u[4], u[5]]]


def _gauss_newton(ranges: list[BeaconRange], height_m: float, c: float, iterations: int,
                  start: np.ndarray | None = None, clock_prior: tuple[float, float] | None = None):
    """(x = [e, n, δ], covariance (3, 3), residuals (n,), sigmas (n,), chi²) or None if singular.

    Starts from ``start`` (e.g. the previous fix) or from the weighted centroid
    of the beacons with the median clock offset. ``clock_prior`` = (δ₀, σ_δ)
    adds the pseudo-measurement δ = δ₀ ± σ_δ (a tracked clock), which enters
    the normal equations and chi² like one more range. Iterates until a step
    moves less than :data:`_STEP_TOL_M` (the comment at that test says what is
    returned then) or ``iterations`` steps are taken.

    Scalar Python over the ranges (a frame has a few to a few tens): with three
    unknowns the normal equations are six sums, and numpy's per-call overhead
    would cost several times the arithmetic. :func:`_gauss_newton_subsets` is the
    vectorised form for many subsets at once.
    """
    if not all(r.sigma_m > 0 for r in ranges):
        return None
    rows = [(r.east_m, r.north_m, (height_m - r.up_m) ** 2, r.pseudorange_m, 1.0 / (r.sigma_m * r.sigma_m))
            for r in ranges]
    if start is None:
        w_sum = sum(q[4] for q in rows)
        e = sum(q[4] * q[0] for q in rows) / w_sum
        n = sum(q[4] * q[1] for q in rows) / w_sum
        d = statistics.median([q[3] - math.sqrt((q[0] - e) ** 2 + (q[1] - n) ** 2 + q[2]) for q in rows]) / c
    else:
        e, n, d = (float(v) for v in (start.tolist() if isinstance(start, np.ndarray) else start))
    prior_w = 0.0 if clock_prior is None else 1.0 / (clock_prior[1] * clock_prior[1])
    # The clock column of J is c for every range: its sums need only Σw, Σw·j and Σw·v.
    a22 = c * c * sum(q[4] for q in rows) + prior_w
    cov = None
    chi2_shift = 0.0
    for it in range(iterations + 1):
        # f(x) = ‖p − sᵢ‖ + c·δ;  J = [∂f/∂e, ∂f/∂n, ∂f/∂δ];  normal = JᵀWJ, gradient = JᵀW(ρ − f)
        a00 = a01 = a11 = s0 = s1 = g0 = g1 = gv = 0.0
        cd = c * d
        res = []
        for se, sn, du2, rho, w in rows:
            de, dn = e - se, n - sn
            r = math.sqrt(de * de + dn * dn + du2)
            if r == 0.0:                     # on a beacon at the device's height: no direction, no fix
                return None
            v = rho - r - cd
            res.append(v)
            j0, j1 = de / r, dn / r
            wj0, wj1 = w * j0, w * j1
            a00 += wj0 * j0
            a01 += wj0 * j1
            a11 += wj1 * j1
            s0 += wj0
            s1 += wj1
            g0 += wj0 * v
            g1 += wj1 * v
            gv += w * v
        a02, a12, g2 = c * s0, c * s1, c * gv
        if clock_prior is not None:
            # Prior row: δ₀ − δ with weight 1/σ_δ² (J row [0, 0, 1]).
            g2 += (clock_prior[0] - d) * prior_w
        if it == iterations:
            break
        inv = _inverse3_sym(a00, a01, a02, a11, a12, a22)
        if inv is None:
            return None
        s_e = inv[0] * g0 + inv[1] * g1 + inv[2] * g2
        s_n = inv[1] * g0 + inv[3] * g1 + inv[4] * g2
        s_d = inv[2] * g0 + inv[4] * g1 + inv[5] * g2
        e, n, d = e + s_e, n + s_n, d + s_d
        if s_e * s_e + s_n * s_n < _STEP_TOL_M ** 2 and abs(s_d) * c < _STEP_TOL_M:
            # Converged. Residuals and covariance stay those of the last linearisation point (less
            # than _STEP_TOL_M away); χ² moves along the linear model: ‖v − J·s‖²_W − ‖v‖²_W
            # = −2·sᵀg + sᵀN·s = −sᵀg, since the step solves N·s = g.
            cov = inv
            chi2_shift = -(s_e * g0 + s_n * g1 + s_d * g2)
            d_prior = d - s_d
            break
    if cov is None:
        d_prior = d
        # Covariance of the weighted LS estimate: (JᵀWJ)⁻¹ (refused when nearly singular).
        cov = _inverse3_sym(a00, a01, a02, a11, a12, a22)
    if cov is None or not all(math.isfinite(v) for v in cov) or min(cov[0], cov[3], cov[5]) <= 0 \
            or cov[0] + cov[3] > 1e8:
        return None
    sig = [r.sigma_m for r in ranges]
    chi2 = sum(w * v * v for (_, _, _, _, w), v in zip(rows, res)) + chi2_shift
    if clock_prior is not None:
        chi2 += (clock_prior[0] - d_prior) ** 2 * prior_w
    return np.array([e, n, d]), np.array(_sym_rows(cov)), np.array(res), np.array(sig), chi2


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
    sol = _gauss_newton(ranges, h, speed_m_s, config.max_iterations, start, clock_prior)
    if sol is None and start is None:
        sol = _multistart(ranges, site, speed_m_s, config, clock_prior)
    if sol is None:
        return None
    x, cov, res, sig, chi2 = sol
    dof = len(ranges) + n_prior - 3
    rejected: list[int] = []
    if dof > 0 and chi2 > _chi2_limit(dof, config.chi2_alpha):
        found = _exclude(ranges, h, speed_m_s, config, x, clock_prior, position_prior)
        if found is None:
            return None
        keep, (x, cov, res, sig, _) = found
        rejected = [r.beacon_id for i, r in enumerate(ranges) if i not in keep]
        ranges = [ranges[i] for i in keep]
    if not _plausible(x, site, config):
        return None
    if config.air_rel_sigma > 0 or config.wind_sigma_m_s > 0:
        cov = _consider_covariance(ranges, x, cov, h, speed_m_s, config)
    east, north, clock = x.tolist()
    t_stated = sum(r.arrival_s for r in ranges) / len(ranges) if t_ref_s is None else t_ref_s
    t_true = t_stated - clock
    return AcousticFix(t_s=t_true, east_m=east, north_m=north, clock_offset_s=clock,
                       n_beacons=len(ranges), covariance=cov,
                       rms_residual_m=math.sqrt(float(res @ res) / len(res)),
                       used_ids=tuple(r.beacon_id for r in ranges), rejected_ids=tuple(rejected),
                       ranges=tuple(ranges))


def _consider_covariance(ranges: list[BeaconRange], x: np.ndarray, cov: np.ndarray, h: float, c: float,
                         config: PositionConfig) -> np.ndarray:
    """The fix covariance with the air's common errors as consider parameters (see :class:`PositionConfig`).

    ρᵢ = rᵢ·(1 − w·n̂ᵢ/c − k) + c·δ, so ∂ρᵢ/∂w = −(p − sᵢ)_h/c and ∂ρᵢ/∂k = −rᵢ; the estimator's gain
    K = P·JᵀW (the clock prior's row has no air term) maps them onto (e, n, δ):

        # P_c = P + K·G·Σ·Gᵀ·Kᵀ,  Σ = diag(σ_w², σ_w², σ_k²)
    """
    # K·G = P·Σᵢ wᵢ·jᵢ·gᵢᵀ: one 3×3 sum over the ranges (scalar Python: a frame has a few to a few
    # tens, and numpy's per-call overhead would cost the receiver several % of its time).
    e, n = float(x[0]), float(x[1])
    sw, sk = config.wind_sigma_m_s / c, config.air_rel_sigma
    m00 = m01 = m02 = m10 = m11 = m12 = m20 = m21 = m22 = 0.0
    for r in ranges:
        de, dn, du = e - r.east_m, n - r.north_m, h - r.up_m
        dist = math.sqrt(de * de + dn * dn + du * du)
        w = 1.0 / (r.sigma_m * r.sigma_m)
        j0, j1, j2 = w * de / dist, w * dn / dist, w * c          # wᵢ·jᵢ
        g0, g1, g2 = -de * sw, -dn * sw, -dist * sk               # gᵢ·Σ^½
        m00 += j0 * g0
        m01 += j0 * g1
        m02 += j0 * g2
        m10 += j1 * g0
        m11 += j1 * g1
        m12 += j1 * g2
        m20 += j2 * g0
        m21 += j2 * g1
        m22 += j2 * g2
    p = cov.tolist()
    kg = [(q[0] * m00 + q[1] * m10 + q[2] * m20, q[0] * m01 + q[1] * m11 + q[2] * m21,
           q[0] * m02 + q[1] * m12 + q[2] * m22) for q in p]
    # P_c = P + (KG)(KG)ᵀ, symmetric by construction
    return np.array([[p[a][b] + kg[a][0] * kg[b][0] + kg[a][1] * kg[b][1] + kg[a][2] * kg[b][2]
                      for b in range(3)] for a in range(3)])


def _inverse3_batch(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverses of symmetric 3×3 matrices (k, 3, 3) by their adjugates, and which are regular (k,).

    The batched form of :func:`_inverse3_sym` (same singularity test); singular ones get zeros.

    >>> a = np.array([[[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]], np.zeros((3, 3))])
    >>> inv, ok = _inverse3_batch(a)
    >>> ok.tolist(), bool(np.allclose(inv[0] @ a[0], np.eye(3)))
    ([True, False], True)
    """
    a, b, c = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    d, e, f = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
    g, h, i = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
    c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
    det = a * c00 + d * c01 + g * c02
    scale = np.abs(a) + np.abs(e) + np.abs(i)
    ok = np.isfinite(det) & (np.abs(det) > 1e-14 * scale ** 3)
    adj = np.empty(m.shape)
    adj[:, 0, 0], adj[:, 0, 1], adj[:, 0, 2] = c00, c01, c02
    adj[:, 1, 0], adj[:, 1, 1], adj[:, 1, 2] = f * g - d * i, a * i - c * g, c * d - a * f
    adj[:, 2, 0], adj[:, 2, 1], adj[:, 2, 2] = d * h - e * g, b * g - a * h, a * e - b * d
    adj /= np.where(ok, det, 1.0)[:, None, None]
    adj[~ok] = 0.0
    inv = adj
    return inv, ok


def _gauss_newton_subsets(ranges: list[BeaconRange], masks: np.ndarray, h: float, c: float, iterations: int,
                          start: np.ndarray, clock_prior: tuple[float, float] | None = None):
    """:func:`_gauss_newton` for many subsets of ``ranges`` at once (the exclusion search).

    ``masks`` (k, n) bool selects each subset's ranges (a range left out gets weight 0).
    Returns x (k, 3), covariance (k, 3, 3), residuals (k, n), chi² (k,) and which
    subsets gave a valid solution (k,) — the same validity tests as :func:`_gauss_newton`, but
    iterated until every subset's step is below 1 µm and evaluated at the final point.
    """
    s = np.array([[r.east_m, r.north_m, r.up_m] for r in ranges])
    rho = np.array([r.pseudorange_m for r in ranges])
    sig = np.array([r.sigma_m for r in ranges])
    w = masks / sig[None, :] ** 2                                   # (k, n)
    du2 = (h - s[:, 2]) ** 2
    k = masks.shape[0]
    x = np.repeat(np.asarray(start, dtype=float)[None, :], k, axis=0)
    ok = np.ones(k, dtype=bool)
    prior_w = 0.0 if clock_prior is None else 1.0 / clock_prior[1] ** 2

    jac = np.empty((k, len(ranges), 3))                            # (k, n, 3): ∂f/∂e, ∂f/∂n, ∂f/∂δ
    jac[:, :, 2] = c

    def normal_equations(x):
        # Jᵀ W J and Jᵀ W r of every subset as two batched (3, n) @ (n, ·) products.
        de, dn = x[:, :1] - s[None, :, 0], x[:, 1:2] - s[None, :, 1]
        r = np.sqrt(de * de + dn * dn + du2[None, :])
        jac[:, :, 0] = de / r
        jac[:, :, 1] = dn / r
        res = rho[None, :] - (r + c * x[:, 2:3])
        jw = np.transpose(jac * w[:, :, None], (0, 2, 1))          # (k, 3, n)
        normal = jw @ jac
        normal[:, 2, 2] += prior_w
        gradient = (jw @ res[:, :, None])[:, :, 0]
        if clock_prior is not None:
            gradient[:, 2] += (clock_prior[0] - x[:, 2]) * prior_w
        return normal, gradient, res

    for _ in range(iterations):
        normal, gradient, _ = normal_equations(x)
        inv, regular = _inverse3_batch(normal)
        ok &= regular
        step = np.einsum("kij,kj->ki", inv, gradient)
        step[~ok] = 0.0
        x = x + step
        if np.all((step[:, 0] ** 2 + step[:, 1] ** 2 < 1e-12) & (np.abs(step[:, 2]) * c < 1e-6)):
            break
    normal, _, res = normal_equations(x)
    cov, regular = _inverse3_batch(normal)
    diag = np.diagonal(cov, axis1=1, axis2=2)
    ok &= regular & np.all(np.isfinite(cov), axis=(1, 2)) & np.all(diag > 0, axis=1) & (diag[:, 0] + diag[:, 1] <= 1e8)
    chi2 = np.sum(w * res ** 2, axis=1)
    if clock_prior is not None:
        chi2 += (clock_prior[0] - x[:, 2]) ** 2 * prior_w
    return x, 0.5 * (cov + np.transpose(cov, (0, 2, 1))), res, chi2, ok


def _linearised(ranges: list[BeaconRange], h: float, c: float, x, clock_prior=None):
    """Whitened Jacobian A = W^½·J, residuals b = W^½·(ρ − f(x)), P = (AᵀA + prior)⁻¹, the hat matrix
    H = A·P·Aᵀ and chi² at ``x`` (a converged fix of every range), or None when singular."""
    s = np.array([[r.east_m, r.north_m, r.up_m] for r in ranges])
    rho = np.array([r.pseudorange_m for r in ranges])
    sw = 1.0 / np.array([r.sigma_m for r in ranges])
    e, n, d = (float(v) for v in np.asarray(x, dtype=float))
    de, dn = e - s[:, 0], n - s[:, 1]
    r = np.sqrt(de * de + dn * dn + (h - s[:, 2]) ** 2)
    if not np.all(r > 0):
        return None
    a = np.column_stack([de / r, dn / r, np.full(len(r), c)]) * sw[:, None]
    b = (rho - r - c * d) * sw
    normal = a.T @ a
    chi2 = float(b @ b)
    if clock_prior is not None:
        prior_w = 1.0 / clock_prior[1] ** 2
        normal[2, 2] += prior_w
        chi2 += (clock_prior[0] - d) ** 2 * prior_w
    inv, regular = _inverse3_batch(normal[None])
    if not regular[0]:
        return None
    return a, b, inv[0], a @ inv[0] @ a.T, chi2


def _deletion_chi2(linear, removed: np.ndarray) -> np.ndarray:
    """Chi² of the least-squares fit without the ranges ``removed`` (k, m), for each of the k subsets.

    Deleting the rows S of a linear least-squares problem lowers its residual sum of squares by
    b_Sᵀ(I − H_SS)⁻¹b_S (Cook & Weisberg, "Residuals and Influence in Regression", 1982, §3.6,
    the multiple-case deletion formula; here whitened by W^½). At the all-range fix of
    :func:`_gauss_newton` the problem is that fix's linearisation, so this is the subset's chi²
    to first order: exact for a linear model, off by the curvature of the ranges over the move
    the deletion makes (up to 2× for one beacon left out on held-out walks, more for three when
    the all-range fix stands metres off; what that costs a screen built on it:
    ``PositionConfig.exclusion_screen``). Subsets with a singular I − H_SS get +inf.
    """
    _, b, _, hat, chi2 = linear
    k, m = removed.shape
    h_ss = hat[removed[:, :, None], removed[:, None, :]]
    b_s = b[removed]
    lhs = np.eye(m)[None] - h_ss
    out = np.full(k, np.inf)
    if m == 1:
        den = lhs[:, 0, 0]
        ok = den > 1e-12
        out[ok] = chi2 - b_s[ok, 0] ** 2 / den[ok]
        return out
    det = np.linalg.det(lhs)
    ok = det > 1e-12
    if np.any(ok):
        sol = np.linalg.solve(lhs[ok], b_s[ok][:, :, None])[:, :, 0]
        out[ok] = chi2 - np.einsum("km,km->k", b_s[ok], sol)
    return out


def _prior_share(east, north, position_prior):
    """‖p − p̂‖²/σ² of fixes (scalars or arrays) against the track's prediction ``(east_m, north_m, sigma_m)``:
    the innovation's share of a subset's score in the exclusion search."""
    pe, pn, ps = position_prior
    return ((east - pe) ** 2 + (north - pn) ** 2) / ps ** 2


def _exclude(ranges: list[BeaconRange], h: float, c: float, config: PositionConfig, start, clock_prior=None,
             position_prior=None):
    """Largest subset (of four or more) whose residuals pass the chi-square test; ties: smallest chi².

    Subsets are tried by decreasing size, at most ``config.max_excluded``
    beacons left out and :data:`_MAX_SUBSETS` subsets tried in all; the subsets
    of one size are solved one by one when few, else together
    (:func:`_gauss_newton_subsets`).
    Returns (kept indices, Gauss-Newton solution) or None. With n − k beacons
    kept, k NLOS-biased beacons can be excluded, which the classic one-at-a-time
    leave-one-out cannot do reliably once two are biased. Where the budget runs out
    (before, a frame of 13 or more beacons with one NLOS among them got no fix at all) or
    ``max_excluded_share`` allows more exclusions, :func:`_backward_elimination` goes on.
    """
    n = len(ranges)
    n_prior = 0 if clock_prior is None else 1
    smallest = 4 - n_prior            # one degree of freedom left for the test
    sig = np.array([r.sigma_m for r in ranges])
    tried = 0
    truncated = False
    linear = _linearised(ranges, h, c, start, clock_prior) if config.exclusion_screen > 0 else None
    for size in range(n - 1, max(smallest - 1, n - 1 - config.max_excluded), -1):
        combos = list(itertools.islice(itertools.combinations(range(n), size), _MAX_SUBSETS - tried + 1))
        truncated = tried + len(combos) > _MAX_SUBSETS
        combos = combos[: _MAX_SUBSETS - tried]
        tried += len(combos)
        if linear is not None and combos:
            # Solve only the subsets whose linearised chi² could pass the test (see PositionConfig).
            kept = np.zeros((len(combos), n), dtype=bool)
            kept[np.repeat(np.arange(len(combos)), size), np.array(combos).ravel()] = True
            removed = np.nonzero(~kept)[1].reshape(len(combos), n - size)
            approx = _deletion_chi2(linear, removed)
            limit = _chi2_limit(size + n_prior - 3, config.chi2_alpha)
            combos = [combos[i] for i in np.flatnonzero(approx <= config.exclusion_screen * limit)]
        if combos and len(combos) <= _SCALAR_SUBSETS:
            # A few subsets: one scalar Gauss-Newton each, every one stopping when it converges.
            best_score, best = math.inf, None
            limit = _chi2_limit(size + n_prior - 3, config.chi2_alpha)
            for keep in combos:
                sol = _gauss_newton([ranges[i] for i in keep], h, c, config.max_iterations, start, clock_prior)
                if sol is None or not sol[4] <= limit:
                    continue
                score = sol[4]
                if position_prior is not None:
                    score += _prior_share(sol[0][0], sol[0][1], position_prior)
                if score < best_score:
                    best_score, best = score, (keep, sol)
            if best is not None:
                return best
        elif combos:
            masks = np.zeros((len(combos), n), dtype=bool)
            for row, keep in enumerate(combos):
                masks[row, list(keep)] = True
            x, cov, res, chi2, ok = _gauss_newton_subsets(ranges, masks, h, c, config.max_iterations, start,
                                                          clock_prior)
            score = np.where(ok & (chi2 <= _chi2_limit(size + n_prior - 3, config.chi2_alpha)), chi2, np.inf)
            if position_prior is not None:
                score = score + _prior_share(x[:, 0], x[:, 1], position_prior)
            best = int(np.argmin(score))
            if np.isfinite(score[best]):
                keep = combos[best]
                m = masks[best]
                return keep, (x[best], cov[best], res[best][m], sig[m], float(chi2[best]))
        if truncated:
            break
    if not truncated and math.floor(config.max_excluded_share * n) <= config.max_excluded:
        return None
    # Beyond the exhaustive search: its budget ran out (13 or more beacons), or more may be left out.
    return _backward_elimination(ranges, h, c, config, start, clock_prior, position_prior, smallest)


def _backward_elimination(ranges, h, c, config, start, clock_prior, position_prior, smallest):
    """Iterative exclusion (RAIM FDE's one-at-a-time form; Brown 1992, "A baseline GPS RAIM scheme",
    Navigation 39(3)): leave each remaining beacon out in turn (one batched solve), drop the one
    whose removal leaves the smallest score (chi² plus the position prior's share), until the test
    passes. Used beyond the exhaustive search's budget: at most ``max(max_excluded,
    ⌊max_excluded_share·n⌋)`` beacons are dropped and at least ``smallest`` kept.
    """
    n = len(ranges)
    n_prior = 0 if clock_prior is None else 1
    most = max(config.max_excluded, math.floor(config.max_excluded_share * n))
    sig = np.array([r.sigma_m for r in ranges])
    keep = list(range(n))
    x0 = start
    while len(keep) - 1 >= smallest and n - len(keep) < most:
        size = len(keep) - 1
        masks = np.zeros((len(keep), n), dtype=bool)
        masks[:, keep] = True
        masks[np.arange(len(keep)), keep] = False
        x, cov, res, chi2, ok = _gauss_newton_subsets(ranges, masks, h, c, config.max_iterations, x0, clock_prior)
        score = np.where(ok, chi2, np.inf)
        if position_prior is not None:
            score = score + _prior_share(x[:, 0], x[:, 1], position_prior)
        best = int(np.argmin(score))
        if not np.isfinite(score[best]):
            return None
        keep = [i for i in keep if i != keep[best]]
        x0 = x[best]
        if chi2[best] <= _chi2_limit(size + n_prior - 3, config.chi2_alpha):
            m = masks[best]
            return tuple(keep), (x[best], cov[best], res[best][m], sig[m], float(chi2[best]))
    return None


def _multistart(ranges: list[BeaconRange], site: Site, c: float, config: PositionConfig, clock_prior=None):
    """Gauss-Newton from the centres of the site grid's quarters; the solution of least chi².

    From the beacons' centroid Gauss-Newton can diverge when few beacons are heard
    from one side (pseudorange problems have a second, spurious solution; Abel &
    Chaffee 1991, IEEE Trans. AES 27(6)); these starts cover the site.
    """
    g = site.grid
    clock0 = statistics.median([r.pseudorange_m for r in ranges]) / c
    best = None
    for fe in (0.25, 0.75):
        for fn in (0.25, 0.75):
            x0 = np.array([g.east_min_m + fe * (g.east_max_m - g.east_min_m),
                           g.north_min_m + fn * (g.north_max_m - g.north_min_m), 0.0])
            geo = statistics.median([math.dist((x0[0], x0[1], site.device_height_m), (r.east_m, r.north_m, r.up_m))
                                     for r in ranges])
            x0[2] = clock0 - geo / c
            sol = _gauss_newton(ranges, site.device_height_m, c, config.max_iterations, x0, clock_prior)
            if sol is not None and (best is None or sol[4] < best[4]):
                best = sol
    return best


def _plausible(x: np.ndarray, site: Site, config: PositionConfig) -> bool:
    e, n, d = x.tolist()
    g, m = site.grid, config.bounds_margin_m
    inside = (g.east_min_m - m <= e <= g.east_max_m + m) and (g.north_min_m - m <= n <= g.north_max_m + m)
    clock_ok = config.max_clock_offset_s is None or abs(d) <= config.max_clock_offset_s
    return inside and clock_ok and math.isfinite(e + n + d)
