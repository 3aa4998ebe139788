"""Per-epoch position from pseudoranges: weighted least squares, one clock per system, Sagnac, RAIM.

**Model** (Kaplan & Hegarty, *Understanding GPS*, 2nd ed. 2006, §2.4.2; Misra & Enge 2011 §6.1):
for satellite i of system s(i) at one epoch,

    ρᵢ = |R_z(ω_E τᵢ)·sᵢ − r| + b_s(i) + εᵢ,      εᵢ ~ N(0, σᵢ²),

r the receiver's ECEF position, b_s the receiver clock of system s in metres (one per constellation:
GPS and GLONASS time differ, and so do the receiver's inter-system biases), sᵢ the satellite at
emission, τᵢ the signal's travel time and R_z(ω_E τ) the rotation of the Earth-fixed frame during
it (the Sagnac or Earth-rotation correction, IS-GPS-200 §20.3.3.4.3.3.2 and Table 20-IV note:
x' = x cos θ + y sin θ, y' = −x sin θ + y cos θ, θ = ω_E·τ; up to ≈ 30 m of range at mid latitudes,
:func:`sagnac_rotate`). It is applied unless the table's ``corrections`` list ``earth_rotation``.

**Solution**: Gauss–Newton from the Earth's centre (the standard pseudorange iteration; it converges
in 5–7 steps from there, which makes every epoch independent and lets all epochs iterate at once as
one batch): H = [−uᵢᵀ, 1_s(i)], W = diag(1/σᵢ²), Δx = (HᵀWH)⁻¹HᵀWΔρ, until |Δx| < ``tolerance_m``.
A system with no satellite at an epoch keeps its clock at 0 (unit diagonal, decoupled), so an epoch
needs 3 + (systems present) satellites. σᵢ² comes from a model of :mod:`features.gnss.weights`
(default the RTKLIB elevation + C/N0 model).

**RAIM, fault detection and exclusion**: the weighted sum of squared residuals
SSE = rᵀWr is χ²(n − p) distributed for consistent Gaussian errors (Brown 1992, "A baseline GPS RAIM
scheme and a note on the equivalence of three RAIM methods", Navigation 39(3); with weights, Walter
& Enge 1995, "Weighted RAIM for precision approach", ION GPS-95). A fix fails the test when SSE
exceeds the χ²(n − p) quantile of 1 − ``p_false_alarm`` (default 10⁻³, RTKLIB's ``chisqr`` table).
Then the satellite with the largest normalised residual |rᵢ|/sqrt((Σ − H Q Hᵀ)ᵢᵢ), Q = (HᵀWH)⁻¹
(Baarda's w-test, Baarda 1968; Kelly 1998, "The linear model, RNP, and the near-optimum fault
detection and exclusion algorithm"), is excluded and the epoch solved again, while the test fails,
the redundancy n − p is at least 2 (so the new fix can still be tested) and fewer than
``max_exclusions`` were excluded. Single-fault FDE assumes few faults; in a street canyon most
satellites may be reflections, the test then fails nearly always and exclusion need not find the
worst ones — the smartLoc figures show it (tests, ``bench/bench_smartloc.py``).

**Covariance**: Q's position block, in m², from the model's absolute σ (the a-priori covariance),
times the a-posteriori variance factor σ̂₀² = SSE/(n − p) where it exceeds 1 (Koch 1999,
*Parameter Estimation and Hypothesis Testing in Linear Models*, §3.2.3; the usual practice when the
global test rejects the a-priori model): an inconsistent epoch then reports its own scatter
instead of the model's optimism, a consistent one never shrinks below the model. After two or
more RAIM exclusions the factor is that of the epoch *before* exclusion (or after, if larger): FDE's
test vouches for one fault (Brown 1992; Walter & Enge 1995), and a subset that passes because the
largest residuals were removed until it did has a factor biased low by that selection, while the
epoch's full set shows how far the model was off; after a single exclusion the kept subset's own
factor stands (a lone fault removed, the rest is what the model says). On the smartLoc drive (RTKLIB
model with RAIM) the rule brings the horizontal NEES from a mean of 202 to 7.3 (2 is consistent);
without RAIM it is 10.6 — still 3–5× optimistic, because NLOS biases common to many satellites
move the fix without showing in the residuals (``bench/bench_smartloc.py``).

:func:`wls_positions` turns a solution into the NMEA path's fix table
(:class:`~features.gnss.positions.GnssPositions`, GGA quality 1, σ per axis and the full
east/north covariance, ``quality_text`` "SPS, WLS (rtklib), 14 satellites, excluded 2").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pymap3d
from scipy.stats import chi2

from features.constants import OMEGA_EARTH_RAD_S, SPEED_OF_LIGHT_M_S
from features.errors import ConfigError
from features.gnss.positions import GnssPositions
from features.gnss.pseudorange import PseudorangeTable
from features.gnss.weights import RtklibVariance

__all__ = ["WlsConfig", "WlsSolution", "INTEGRITY", "solve_epochs", "sagnac_rotate", "wls_positions",
           "enu_rotation"]

INTEGRITY = ("consistent", "alarm", "untested")
"""Integrity codes of a fix: 0 the χ² test passed (after any exclusions), 1 it still fails (RAIM alarm: the
fix is not trustworthy at the model's σ), 2 no redundancy to test (n = p)."""


@dataclass(frozen=True)
class WlsConfig:
    """Solver settings: the variance model, RAIM and the iteration (module docstring)."""

    weights: object = field(default_factory=RtklibVariance)
    raim: bool = True
    p_false_alarm: float = 1e-3
    max_exclusions: int | None = None
    elevation_mask_deg: float = 0.0
    scale_covariance: bool = True
    max_iterations: int = 15
    tolerance_m: float = 1e-4

    def __post_init__(self):
        if not callable(getattr(self.weights, "variance_m2", None)):
            raise ConfigError(f"WlsConfig.weights needs a variance_m2 method, got {self.weights!r}")
        if not 0.0 < self.p_false_alarm < 0.5:
            raise ConfigError(f"WlsConfig.p_false_alarm must lie in (0, 0.5), got {self.p_false_alarm}")
        if self.max_exclusions is not None and (not isinstance(self.max_exclusions, int) or self.max_exclusions < 0):
            raise ConfigError(f"WlsConfig.max_exclusions must be None or an integer >= 0, got {self.max_exclusions!r}")
        if not -90.0 <= self.elevation_mask_deg < 90.0:
            raise ConfigError(f"WlsConfig.elevation_mask_deg must lie in [-90, 90), got {self.elevation_mask_deg}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ConfigError(f"WlsConfig.max_iterations must be an integer >= 1, got {self.max_iterations!r}")
        if not (math.isfinite(self.tolerance_m) and self.tolerance_m > 0):
            raise ConfigError(f"WlsConfig.tolerance_m must be > 0, got {self.tolerance_m}")


@dataclass(frozen=True)
class WlsSolution:
    """One row per epoch of the table (E epochs), plus per-observation flags (n rows of the table).

    t_s (E,); has_fix (E,) bool; ecef_m (E, 3) NaN without a fix; clock_m (E, K) per system of
    ``systems`` (K letters), NaN when absent; cov_ecef_m2 (E, 3, 3) position covariance (scaled,
    module docstring); variance_factor (E,) SSE/(n − p) (NaN when n = p); test_statistic (E,) SSE;
    dof (E,) n − p; threshold (E,) the χ² quantile; integrity (E,) codes into :data:`INTEGRITY`;
    n_used, n_excluded (E,); hdop (E,) of the used satellites, unweighted, one clock per system;
    used (n,) bool; residual_m (n,) every observation against its epoch's final fix (NaN where the
    satellite's system has no clock); azimuth_deg, elevation_deg (n,) of every observation seen
    from its epoch's fix (NaN without one); weight_model the variance model's name.
    """

    t_s: np.ndarray
    has_fix: np.ndarray
    ecef_m: np.ndarray
    clock_m: np.ndarray
    systems: tuple
    cov_ecef_m2: np.ndarray
    variance_factor: np.ndarray
    test_statistic: np.ndarray
    dof: np.ndarray
    threshold: np.ndarray
    integrity: np.ndarray
    n_used: np.ndarray
    n_excluded: np.ndarray
    hdop: np.ndarray
    used: np.ndarray
    residual_m: np.ndarray
    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    weight_model: str

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def quality_text(self) -> np.ndarray:
        """Per epoch, e.g. ``SPS, WLS (rtklib), 14 satellites, excluded 2`` (+ ``, RAIM alarm`` / ``, untested``)."""
        tail = {0: "", 1: ", RAIM alarm", 2: ", untested"}
        return np.array([f"SPS, WLS ({self.weight_model}), {n} satellites, excluded {k}{tail[int(c)]}"
                         for n, k, c in zip(self.n_used.tolist(), self.n_excluded.tolist(), self.integrity.tolist())],
                        dtype=object)


def sagnac_rotate(sat_ecef_m: np.ndarray, travel_time_s) -> np.ndarray:
    """Satellite positions rotated into the ECEF frame of reception: R_z(ω_E τ)·s, shape (..., 3).

    IS-GPS-200 §20.3.3.4.3.3.2 (Earth rotation during the travel time τ):
    x' = x cos θ + y sin θ, y' = −x sin θ + y cos θ, z' = z, θ = ω_E·τ.

    >>> s = np.array([26_000e3, 0.0, 0.0])
    >>> [round(float(v), 1) for v in sagnac_rotate(s, 0.07)]
    [26000000.0, -132.7, 0.0]
    """
    s = np.asarray(sat_ecef_m, dtype=float)
    theta = OMEGA_EARTH_RAD_S * np.asarray(travel_time_s, dtype=float)
    c, sn = np.cos(theta), np.sin(theta)
    return np.stack([c * s[..., 0] + sn * s[..., 1], -sn * s[..., 0] + c * s[..., 1], s[..., 2]], axis=-1)


def enu_rotation(lat_deg, lon_deg) -> np.ndarray:
    """ECEF → ENU rotation matrices (rows east, north, up), shape (..., 3, 3) (Kaplan & Hegarty 2006 eq. 2.26)."""
    la, lo = np.radians(np.asarray(lat_deg, float)), np.radians(np.asarray(lon_deg, float))
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    z = np.zeros_like(sl)
    return np.stack([np.stack([-so, co, z], -1), np.stack([-sl * co, -sl * so, cl], -1),
                     np.stack([cl * co, cl * so, sl], -1)], -2)


@dataclass
class _Batch:
    """Padded (epoch, slot) arrays of the observations; slot −1 rows are padding."""

    rows: np.ndarray        # (E, M) table row or −1
    sat: np.ndarray         # (E, M, 3)
    pr: np.ndarray          # (E, M)
    var: np.ndarray         # (E, M)
    onehot: np.ndarray      # (E, M, K) system indicator
    active: np.ndarray      # (E, M) bool: used in the solution


def _pack(table: PseudorangeTable, config: WlsConfig, systems: tuple, elevation_deg: np.ndarray) -> _Batch:
    """Pad the table's epochs into (epoch, slot) arrays; σ² from the model at ``elevation_deg`` (n,)."""
    t, start, stop = table.epochs()
    count = stop - start
    m_n = int(count.max()) if len(t) else 0
    slot = np.arange(m_n)
    rows = np.where(slot[None, :] < count[:, None], start[:, None] + slot[None, :], -1)
    valid = rows >= 0
    r = np.maximum(rows, 0)
    var = np.asarray(config.weights.variance_m2(table.cn0_dbhz, elevation_deg, table.system,
                                                table.pseudorange_var_m2), dtype=float)
    sys_index = np.searchsorted(np.array(systems), table.system)
    onehot = (sys_index[r][..., None] == np.arange(len(systems))) & valid[..., None]
    with np.errstate(invalid="ignore"):
        above = ~(elevation_deg[r] < config.elevation_mask_deg)   # NaN elevation: kept
    active = valid & np.isfinite(var[r]) & (var[r] > 0) & above
    return _Batch(rows, table.sat_ecef_m[r], table.pseudorange_m[r], np.where(active, var[r], 1.0),
                  onehot.astype(float), active)


def _look_angles(table: PseudorangeTable, x: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (deg, (n,)) of every observation seen from its epoch's fix; NaN without a fix."""
    _, start, stop = table.epochs()
    k = np.repeat(np.arange(len(start)), stop - start)
    rx = np.where(ok[:, None], x[:, :3], np.nan)[k]
    lat, lon, alt = pymap3d.ecef2geodetic(rx[:, 0], rx[:, 1], rx[:, 2])
    s = table.sat_ecef_m
    az, el, _ = pymap3d.ecef2aer(s[:, 0], s[:, 1], s[:, 2], lat, lon, alt)
    return np.asarray(az, float), np.asarray(el, float)


def _predict(b: _Batch, x: np.ndarray, sagnac: bool):
    """Unit line-of-sight vectors (E, M, 3), geometric ranges (E, M) and predicted pseudoranges at states x."""
    sat = b.sat
    if sagnac:
        tau = np.linalg.norm(sat - x[:, None, :3], axis=-1) / SPEED_OF_LIGHT_M_S
        sat = sagnac_rotate(sat, tau)
    d = sat - x[:, None, :3]
    rng = np.linalg.norm(d, axis=-1)
    u = d / np.where(rng > 0, rng, 1.0)[..., None]
    return u, rng, rng + np.matmul(b.onehot, x[:, 3:, None])[..., 0]


def _normal(b: _Batch, u: np.ndarray, weighted: bool = True):
    """H (E, M, p) masked by ``active``, N = HᵀWH (E, p, p) with a unit diagonal for absent clocks, and W."""
    h = np.concatenate([-u, b.onehot], axis=-1) * b.active[..., None]
    w = np.where(b.active, 1.0 / b.var, 0.0) if weighted else b.active.astype(float)
    n = np.matmul(h.transpose(0, 2, 1), h * w[..., None])
    present = (b.onehot * b.active[..., None]).sum(axis=1) > 0
    k = 3 + np.arange(b.onehot.shape[-1])
    n[:, k, k] += ~present
    return h, n, w, present


def _solvable(b: _Batch, n: np.ndarray, present: np.ndarray) -> np.ndarray:
    """Epochs with 3 + (systems present) satellites and a well-conditioned normal matrix."""
    enough = b.active.sum(axis=1) >= 3 + present.sum(axis=1)
    ev = np.linalg.eigvalsh(n)
    return enough & (ev[:, 0] > 1e-12 * np.maximum(ev[:, -1], 1e-300))


def _gauss_newton(b: _Batch, x: np.ndarray, config: WlsConfig, sagnac: bool):
    """Iterate every epoch of the batch to convergence; returns (x, converged (E,) bool)."""
    ok = np.ones(len(x), dtype=bool)
    step = np.full(len(x), np.inf)
    for _ in range(config.max_iterations):
        u, _, pred = _predict(b, x, sagnac)
        h, n, w, present = _normal(b, u)
        ok = _solvable(b, n, present)
        dz = np.where(b.active, b.pr - pred, 0.0)
        rhs = np.matmul(h.transpose(0, 2, 1), (w * dz)[..., None])[..., 0]
        # Δx = (HᵀWH)⁻¹ HᵀWΔρ, the normal equations of weighted least squares
        n_safe = np.where(ok[:, None, None], n, np.eye(n.shape[-1]))
        dx = np.linalg.solve(n_safe, np.where(ok[:, None], rhs, 0.0)[..., None])[..., 0]
        x = x + dx
        step = np.linalg.norm(dx, axis=1)
        if np.all(step[ok] < config.tolerance_m):
            break
    return x, ok & (step < max(config.tolerance_m, 1e-3))


def _statistics(b: _Batch, x: np.ndarray, sagnac: bool):
    """Residuals (E, M), SSE (E,), dof (E,), covariance Q = (HᵀWH)⁻¹ (E, p, p), H, W at the fix."""
    u, _, pred = _predict(b, x, sagnac)
    h, n, w, present = _normal(b, u)
    resid = np.where(b.rows >= 0, b.pr - pred, np.nan)
    sse = np.sum(np.where(b.active, w * resid ** 2, 0.0), axis=1)
    dof = b.active.sum(axis=1) - 3 - present.sum(axis=1)
    ok = _solvable(b, n, present)
    q = np.linalg.inv(np.where(ok[:, None, None], n, np.eye(n.shape[-1])))
    return resid, sse, dof, q, h, ok, present


def _normalised_residuals(b: _Batch, resid, q, h) -> np.ndarray:
    """|rᵢ| / sqrt(σᵢ² − (H Q Hᵀ)ᵢᵢ), Baarda's w-test statistic; 0 where untestable (E, M)."""
    hqh = np.einsum("emi,eij,emj->em", h, q, h)
    s2 = np.where(b.active, b.var - hqh, 0.0)
    testable = b.active & (s2 > 1e-9 * b.var)
    return np.where(testable, np.abs(np.nan_to_num(resid)) / np.sqrt(np.where(testable, s2, 1.0)), 0.0)


def _raim(b: _Batch, x: np.ndarray, converged: np.ndarray, config: WlsConfig, sagnac: bool):
    """Fault detection and exclusion over all epochs at once (module docstring); returns (x, converged, n_excl).

    Each round tests only the epochs still open (those that just lost a satellite), so an epoch that
    passes is never solved again.
    """
    n_excl = np.zeros(len(x), dtype=int)
    cap = np.inf if config.max_exclusions is None else config.max_exclusions
    open_ = np.flatnonzero(converged)
    while open_.size:
        sub = _subset(b, open_)
        resid, sse, dof, q, h, ok, _ = _statistics(sub, x[open_], sagnac)
        with np.errstate(invalid="ignore"):
            limit = chi2.isf(config.p_false_alarm, np.maximum(dof, 1))
        fail = ok & (dof >= 2) & (sse > limit) & (n_excl[open_] < cap)
        wn = _normalised_residuals(_subset(sub, np.flatnonzero(fail)), resid[fail], q[fail], h[fail])
        j = np.argmax(wn, axis=1) if wn.size else np.zeros(0, dtype=int)
        testable = wn[np.arange(len(j)), j] > 0 if wn.size else np.zeros(0, dtype=bool)
        e, j = open_[fail][testable], j[testable]
        b.active[e, j] = False
        n_excl[e] += 1
        if e.size:
            x[e], converged[e] = _gauss_newton(_subset(b, e), x[e], config, sagnac)
        open_ = e[converged[e]]
    return x, converged, n_excl


def _subset(b: _Batch, e: np.ndarray) -> _Batch:
    return _Batch(b.rows[e], b.sat[e], b.pr[e], b.var[e], b.onehot[e], b.active[e])


def solve_epochs(table: PseudorangeTable, config: WlsConfig = WlsConfig()) -> WlsSolution:
    """Solve every epoch of ``table`` (module docstring); epochs that cannot be solved get ``has_fix`` False.

    Elevations for the weights and the mask are the solver's own, seen from its fix (RTKLIB does
    the same): a first solve weights with the table's elevations (45° where it has none), then
    every epoch is solved again with the elevations from that fix. The table's elevations thus only
    start the iteration (smartLoc's were computed at the reference position; the fixes do not
    depend on them, a test).
    """
    systems = tuple(sorted(set(table.system.tolist())))
    sagnac = "earth_rotation" not in table.corrections
    el0 = np.where(np.isfinite(table.elevation_deg), table.elevation_deg, 45.0)
    b = _pack(table, config, systems, el0)
    x, converged = _gauss_newton(b, np.zeros((len(b.rows), 3 + len(systems))), config, sagnac)
    az, el = _look_angles(table, x, converged)
    b = _pack(table, config, systems, np.where(np.isfinite(el), el, el0))
    x, converged = _gauss_newton(b, x, config, sagnac)
    n_excl = np.zeros(len(b.rows), dtype=int)
    _, sse0, dof0, *_ = _statistics(b, x, sagnac)
    with np.errstate(invalid="ignore", divide="ignore"):
        factor0 = np.where(dof0 >= 1, sse0 / np.maximum(dof0, 1), np.nan)
    if config.raim:
        x, converged, n_excl = _raim(b, x, converged, config, sagnac)
    return _solution(table, b, x, converged, n_excl, factor0, systems, config, sagnac)


def _solution(table, b: _Batch, x, converged, n_excl, factor0, systems, config: WlsConfig,
              sagnac: bool) -> WlsSolution:
    resid, sse, dof, q, h, ok, present = _statistics(b, x, sagnac)
    has_fix = converged & ok
    with np.errstate(invalid="ignore", divide="ignore"):
        limit = np.where(dof >= 1, chi2.isf(config.p_false_alarm, np.maximum(dof, 1)), np.nan)
        factor = np.where(dof >= 1, sse / np.maximum(dof, 1), np.nan)
    integrity = np.where(dof < 1, 2, np.where(sse > limit, 1, 0))
    # beyond one exclusion (single-fault FDE's reach) σ̂₀² of the epoch before exclusion: the kept
    # subset's own is biased low by the selection (module docstring)
    after = np.nan_to_num(factor, nan=1.0)
    worst = np.where(n_excl >= 2, np.fmax(after, np.nan_to_num(factor0, nan=1.0)), after)
    scale = np.where(config.scale_covariance, np.maximum(worst, 1.0), 1.0)
    cov = q[:, :3, :3] * scale[:, None, None]
    valid = b.rows >= 0
    used = np.zeros(len(table), dtype=bool)
    used[b.rows[valid]] = b.active[valid]
    clock_known = (b.onehot * present[:, None, :]).sum(axis=-1) > 0
    residual = np.full(len(table), np.nan)
    residual[b.rows[valid]] = np.where(clock_known, resid, np.nan)[valid]
    az, el = _look_angles(table, x, has_fix)
    return WlsSolution(
        t_s=table.epochs()[0], has_fix=has_fix, ecef_m=np.where(has_fix[:, None], x[:, :3], np.nan),
        clock_m=np.where(has_fix[:, None] & present, x[:, 3:], np.nan), systems=systems,
        cov_ecef_m2=np.where(has_fix[:, None, None], cov, np.nan), variance_factor=factor, test_statistic=sse,
        dof=dof, threshold=limit, integrity=integrity, n_used=b.active.sum(axis=1), n_excluded=n_excl,
        hdop=np.where(has_fix, _hdop(b, h, x), np.nan), used=used, residual_m=residual, azimuth_deg=az,
        elevation_deg=el, weight_model=str(getattr(config.weights, "name", type(config.weights).__name__)))


def _hdop(b: _Batch, h: np.ndarray, x: np.ndarray) -> np.ndarray:
    """HDOP of the used satellites: unweighted (HᵀH)⁻¹ rotated to the fix's local ENU (Kaplan & Hegarty ch. 7)."""
    _, n, _, present = _normal(b, -h[..., :3], weighted=False)
    ok = _solvable(b, n, present)
    q = np.linalg.inv(np.where(ok[:, None, None], n, np.eye(n.shape[-1])))[:, :3, :3]
    lat, lon, _ = pymap3d.ecef2geodetic(x[:, 0], x[:, 1], x[:, 2])
    r = enu_rotation(lat, lon)
    q_enu = r @ q @ r.transpose(0, 2, 1)
    with np.errstate(invalid="ignore"):
        return np.where(ok, np.sqrt(q_enu[:, 0, 0] + q_enu[:, 1, 1]), np.nan)


def wls_positions(solution: WlsSolution, lat0_deg: float, lon0_deg: float, alt0_m: float, *,
                  table: PseudorangeTable | None = None, cn0_reference=None,
                  invisible_ratio: np.ndarray | None = None) -> GnssPositions:
    """The fixes as the NMEA path's :class:`~features.gnss.positions.GnssPositions` about the site origin.

    One row per epoch with a fix: ENU position, σ per axis and ``cov_en_m2`` (n, 2, 2) from the
    solution's covariance rotated into the site's ENU axes (over a site of a few km the local
    axes turn by < 0.1°), GGA quality 1 (autonomous SPS), ``sigma_source`` "wls",
    ``quality_text``. With ``table`` (the solved one) ``attenuation_db`` is the used satellites' mean
    attenuation under ``cn0_reference`` (:class:`~features.gnss.features.Cn0Reference`, default
    built-in) as in the NMEA path; ``invisible_ratio`` (per epoch of the solution) is carried over.
    """
    from features.gnss.features import Cn0Reference

    k = np.flatnonzero(solution.has_fix)
    xyz = solution.ecef_m[k]
    e, n, u = pymap3d.ecef2enu(xyz[:, 0], xyz[:, 1], xyz[:, 2], lat0_deg, lon0_deg, alt0_m)
    r = enu_rotation(lat0_deg, lon0_deg)
    cov = r @ solution.cov_ecef_m2[k] @ r.T
    att = np.zeros(len(k))
    if table is not None:
        ref = cn0_reference or Cn0Reference()
        a = np.maximum(0.0, ref.cref_dbhz(solution.elevation_deg) - table.cn0_dbhz)
        _, start, stop = table.epochs()
        use = solution.used & np.isfinite(a)
        sums = np.add.reduceat(np.where(use, a, 0.0), start) if len(table) else np.zeros(0)
        counts = np.add.reduceat(use.astype(float), start) if len(table) else np.zeros(0)
        att = np.where(counts > 0, sums / np.maximum(counts, 1), 0.0)[k]
    zeta = np.full(len(k), np.nan) if invisible_ratio is None else np.asarray(invisible_ratio, float)[k]
    s_e, s_n = np.sqrt(cov[:, 0, 0]), np.sqrt(cov[:, 1, 1])
    return GnssPositions(
        t_s=solution.t_s[k], east_m=np.asarray(e, float), north_m=np.asarray(n, float), up_m=np.asarray(u, float),
        sigma_en_m=np.maximum(s_e, s_n), sigma_up_m=np.sqrt(cov[:, 2, 2]), quality=np.ones(len(k), dtype=int),
        n_used=solution.n_used[k].astype(int), hdop=solution.hdop[k], hdop_assumed=np.zeros(len(k), dtype=bool),
        sigma_east_m=s_e, sigma_north_m=s_n, attenuation_db=att, sigma_source=np.full(len(k), "wls", dtype="<U6"),
        invisible_ratio=zeta, cov_en_m2=cov[:, :2, :2], quality_text=solution.quality_text()[k])
