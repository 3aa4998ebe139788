"""UWB tag positions per ranging round: multilateration from ranges, with PDoA angles where needed.

One epoch is one ranging round: consecutive rows of :class:`~features.uwb.reader.UwbLog` within
``epoch_s`` of the round's first row, each anchor at most once. The tag's height is known (the device's
height on the site, ``site.device_height_m``), so the unknown is the horizontal position ``p = (e, n)``.

Measurement models (anchor ``a`` surveyed at ``(a_e, a_n, a_u)``, boresight ``β``)::

    range    r = ‖(e − a_e, n − a_n, h − a_u)‖                       (two-way ranging, slant distance)
    azimuth  φ = atan2(e − a_e, n − a_n) − β     (clockwise from boresight; features.uwb.reader)

solved by weighted Gauss–Newton (nonlinear least squares; Foy, "Position-location solutions by
Taylor-series estimation", IEEE Trans. AES 12(2), 1976), started from the linearised closed form for
ranges (subtract the last anchor's squared-range equation from the others: Caffery, "A new approach
to the geometry of TOA location", IEEE VTC 2000) or from the polar point ``a + r_h·(sin(β+φ), cos(β+φ))``
of one anchor's range and angle (the single-anchor AOA+range fix of Zhou et al. 2025). The covariance is
``(JᵀWJ)⁻¹``, scaled by the reduced χ² when the round is redundant and fits worse than its σ say.
Written by hand rather than with ``scipy.optimize.least_squares``: a two-unknown problem per round,
thousands of rounds per walk, where SciPy's per-call overhead (~1 ms) would dominate.

Modes (``UwbSolveConfig.use_aoa``): ``"never"`` — ranges only, rounds with fewer than
``min_range_anchors`` (3) anchors dropped, as the foot-INS seed paper (Chen et al.) drops UWB with fewer
than three anchors; ``"fallback"`` — ranges only where three or more anchors answered, ranges and angles
where one or two did; ``"always"`` — ranges and angles in every round.

Rows whose ``quality`` (first-path minus received power, dB) is below ``nlos_quality_db`` are taken as
NLOS by the device's own indicator and weighted down by ``nlos_sigma_scale``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numba import njit

from features.errors import ConfigError, UwbError
from features.site import UwbAnchor
from features.uwb.reader import UwbLog

__all__ = ["UwbSolveConfig", "UwbFixes", "uwb_epochs", "uwb_positions", "solve_round", "bearing_rad",
           "AOA_MODES"]

AOA_MODES = ("never", "fallback", "always")


@dataclass(frozen=True)
class UwbSolveConfig:
    """How ranging rounds become positions (module docstring).

    ``range_sigma_m``: LOS two-way-ranging σ (DW3000 datasheet: ±10 cm ranging accuracy);
    ``azimuth_sigma_deg``: PDoA angle σ at boresight (Qorvo DW3000 PDoA: ±5° typical within ±60°);
    grown by 1/cos(φ) off boresight, as the phase-to-angle slope ``dφ/dθ ∝ cos θ`` shrinks (floor
    ``max_cos_floor``). ``epoch_s``: a ranging round's span (8 anchors × a ≈ 3 ms DS-TWR exchange ≈ 25 ms;
    shorter than the 100 ms between rounds at 10 Hz).
    """

    range_sigma_m: float = 0.10
    azimuth_sigma_deg: float = 5.0
    nlos_quality_db: float = -6.0
    nlos_sigma_scale: float = 5.0
    epoch_s: float = 0.05
    min_range_anchors: int = 3
    use_aoa: str = "fallback"
    max_iter: int = 15
    tol_m: float = 1e-4
    max_cos_floor: float = 0.26

    def __post_init__(self):
        for name in ("range_sigma_m", "azimuth_sigma_deg", "nlos_sigma_scale", "epoch_s", "tol_m", "max_cos_floor"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"uwb {name} must be a positive number, got {v!r}")
        if not math.isfinite(self.nlos_quality_db):
            raise ConfigError(f"uwb nlos_quality_db must be finite, got {self.nlos_quality_db!r}")
        if self.use_aoa not in AOA_MODES:
            raise ConfigError(f"uwb use_aoa must be one of {AOA_MODES}, got {self.use_aoa!r}")
        if not isinstance(self.min_range_anchors, int) or self.min_range_anchors < 3:
            raise ConfigError(f"uwb min_range_anchors must be an integer >= 3, got {self.min_range_anchors!r}")
        if not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise ConfigError(f"uwb max_iter must be a positive integer, got {self.max_iter!r}")


@dataclass(frozen=True)
class UwbFixes:
    """UWB positions, one per solved round: arrays of shape (n,), ``cov_en`` of shape (n, 2, 2) (m²).

    ``n_anchors``: anchors used; ``used_aoa``: whether angles entered the fix; ``rms_residual``: the
    round's weighted residual RMS (dimensionless, ≈ 1 when the σ are right; NaN without redundancy).
    """

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    cov_en: np.ndarray
    n_anchors: np.ndarray
    used_aoa: np.ndarray
    rms_residual: np.ndarray
    n_rounds: int = 0

    def __len__(self) -> int:
        return int(self.t_s.size)


def bearing_rad(from_e, from_n, to_e, to_n):
    """Bearing from one point to another, radians clockwise from north: ``atan2(Δe, Δn)``.

    >>> round(math.degrees(bearing_rad(0.0, 0.0, 1.0, 1.0)), 6)     # north-east
    45.0
    """
    return np.arctan2(np.subtract(to_e, from_e), np.subtract(to_n, from_n))


def uwb_epochs(log: UwbLog, epoch_s: float) -> list[np.ndarray]:
    """Row indices of each ranging round: consecutive rows within ``epoch_s`` of the round's first row,
    a round closed early when an anchor repeats. List of int arrays."""
    out, start, seen = [], 0, set()
    t, a = log.t_s, log.anchor
    for i in range(len(t)):
        if i > start and (t[i] - t[start] > epoch_s or int(a[i]) in seen):
            out.append(np.arange(start, i))
            start, seen = i, set()
        seen.add(int(a[i]))
    if len(t):
        out.append(np.arange(start, len(t)))
    return out


@njit(cache=True)
def _wrap1(x: float) -> float:
    return (x + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _solve_one(anc, bore, rng, az, sr, saz, tag_up, max_iter, tol):
    """One round (k rows; ``az`` NaN where unused) → (ok, e, n, P00, P01, P11, rms). Compiled: a round is a
    two-unknown problem, solved thousands of times per walk."""
    k = rng.shape[0]
    n_az = 0
    for i in range(k):
        if np.isfinite(az[i]):
            n_az += 1
    n_eq = k + n_az
    fail = (False, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan)
    if n_eq < 2 or (n_az == 0 and k < 3):
        return fail
    dz = np.empty(k)
    r_h = np.empty(k)
    for i in range(k):
        dz[i] = tag_up - anc[i, 2]
        r_h[i] = math.sqrt(max(rng[i] * rng[i] - dz[i] * dz[i], 0.0))
    # start: the mean polar point a + r_h·(sin φ, cos φ) of the anchors with an angle, else Caffery (2000):
    # |p − a_i|² − |p − a_k|² = r_i² − r_k²  →  2(a_k − a_i)·p = r_i² − r_k² − |a_i|² + |a_k|², least squares
    pe, pn = 0.0, 0.0
    if n_az > 0:
        for i in range(k):
            if np.isfinite(az[i]):
                phi = bore[i] + az[i]
                pe += anc[i, 0] + r_h[i] * math.sin(phi)
                pn += anc[i, 1] + r_h[i] * math.cos(phi)
        pe /= n_az
        pn /= n_az
    else:
        a00 = a01 = a11 = b0 = b1 = 0.0
        ke, kn = anc[k - 1, 0], anc[k - 1, 1]
        for i in range(k - 1):
            x0, x1 = 2.0 * (ke - anc[i, 0]), 2.0 * (kn - anc[i, 1])
            b = r_h[i] ** 2 - r_h[k - 1] ** 2 - anc[i, 0] ** 2 - anc[i, 1] ** 2 + ke ** 2 + kn ** 2
            a00 += x0 * x0
            a01 += x0 * x1
            a11 += x1 * x1
            b0 += x0 * b
            b1 += x1 * b
        det = a00 * a11 - a01 * a01
        if abs(det) <= 1e-12 * max(a00 * a11, 1e-300):
            return fail
        pe, pn = (a11 * b0 - a01 * b1) / det, (a00 * b1 - a01 * b0) / det
    n00 = n01 = n11 = 0.0
    converged = False
    for _ in range(max_iter):
        # normal equations N = J'WJ, g = J'W(z − h(p)) of the range and bearing models
        n00 = n01 = n11 = g0 = g1 = 0.0
        for i in range(k):
            de, dn = pe - anc[i, 0], pn - anc[i, 1]
            d3 = max(math.sqrt(de * de + dn * dn + dz[i] * dz[i]), 1e-6)
            w = 1.0 / (sr[i] * sr[i])
            j0, j1, res = de / d3, dn / d3, rng[i] - d3
            n00 += w * j0 * j0
            n01 += w * j0 * j1
            n11 += w * j1 * j1
            g0 += w * j0 * res
            g1 += w * j1 * res
            if np.isfinite(az[i]):
                d2h = max(de * de + dn * dn, 1e-6)
                w = 1.0 / (saz[i] * saz[i])
                j0, j1 = dn / d2h, -de / d2h
                res = _wrap1(bore[i] + az[i] - math.atan2(de, dn))
                n00 += w * j0 * j0
                n01 += w * j0 * j1
                n11 += w * j1 * j1
                g0 += w * j0 * res
                g1 += w * j1 * res
        det = n00 * n11 - n01 * n01
        # a near-singular N: the geometry does not fix the position (the cond(N) > 1e12 test for a 2×2)
        if det <= 1e-12 * (n00 + n11) ** 2:
            return fail
        s0, s1 = (n11 * g0 - n01 * g1) / det, (n00 * g1 - n01 * g0) / det
        pe += s0
        pn += s1
        if math.hypot(s0, s1) < tol:
            converged = True
            break
    if not converged:
        return fail
    chi2 = 0.0
    for i in range(k):
        de, dn = pe - anc[i, 0], pn - anc[i, 1]
        r = rng[i] - math.sqrt(de * de + dn * dn + dz[i] * dz[i])
        chi2 += r * r / (sr[i] * sr[i])
        if np.isfinite(az[i]):
            r = _wrap1(bore[i] + az[i] - math.atan2(de, dn))
            chi2 += r * r / (saz[i] * saz[i])
    det = n00 * n11 - n01 * n01
    dof = n_eq - 2
    f = chi2 / dof if dof > 0 and chi2 / dof > 1.0 else 1.0
    rms = math.sqrt(chi2 / dof) if dof > 0 else np.nan
    return True, pe, pn, f * n11 / det, -f * n01 / det, f * n00 / det, rms


@njit(cache=True)
def _solve_rounds(starts, ends, use_az, anc, bore, rng, az, sr, saz, tag_up, max_iter, tol):
    """Every round [starts[r], ends[r]) of the rows → (ok (n,), out (n, 6): e, n, P00, P01, P11, rms)."""
    n = starts.shape[0]
    ok = np.zeros(n, np.bool_)
    out = np.full((n, 6), np.nan)
    nan_az = np.full(az.shape[0], np.nan)
    for r in range(n):
        s, e = starts[r], ends[r]
        a = az[s:e] if use_az[r] else nan_az[s:e]
        res = _solve_one(anc[s:e], bore[s:e], rng[s:e], a, sr[s:e], saz[s:e], tag_up, max_iter, tol)
        if res[0]:
            ok[r] = True
            out[r, 0], out[r, 1], out[r, 2], out[r, 3], out[r, 4], out[r, 5] = res[1:]
    return ok, out


def solve_round(anc: np.ndarray, boresight_rad: np.ndarray, range_m: np.ndarray, azimuth_rad: np.ndarray,
                range_sigma_m: np.ndarray, azimuth_sigma_rad: np.ndarray, tag_up_m: float,
                max_iter: int = 15, tol_m: float = 1e-4):
    """One round's horizontal position by weighted Gauss–Newton (module docstring).

    anc : array of shape (k, 3), anchors' (east, north, up), m; the other arrays of shape (k,), ``azimuth_rad``
    NaN where a row's angle is not used. Returns ``(p (2,), cov (2, 2), rms)`` or ``None`` when the round
    cannot be solved (too few equations, no convergence, singular geometry).
    """
    f = np.ascontiguousarray
    res = _solve_one(f(anc, float), f(boresight_rad, float), f(range_m, float), f(azimuth_rad, float),
                     f(range_sigma_m, float), f(azimuth_sigma_rad, float), float(tag_up_m), int(max_iter), float(tol_m))
    if not res[0]:
        return None
    return np.array(res[1:3]), np.array([[res[3], res[4]], [res[4], res[5]]]), res[6]


def uwb_positions(log: UwbLog, anchors: Sequence[UwbAnchor], tag_up_m: float,
                  config: UwbSolveConfig = UwbSolveConfig()) -> UwbFixes:
    """Positions of every solvable round of ``log`` (module docstring), with their covariance.

    Rows from an anchor ``site.toml`` does not list raise :class:`~features.errors.UwbError` (the log and
    the site disagree: a wrong site, or an anchor not surveyed).
    """
    by_id = {a.id: a for a in anchors}
    unknown = sorted(set(int(a) for a in np.unique(log.anchor)) - set(by_id))
    if unknown:
        raise UwbError(f"uwb.csv names anchor(s) {unknown} that the site's [[uwb_anchors]] does not list "
                       f"(it lists {sorted(by_id) or 'none'})")
    ids = np.array(sorted(by_id))
    table = np.array([[by_id[i].east_m, by_id[i].north_m, by_id[i].up_m, math.radians(by_id[i].boresight_deg)]
                      for i in ids]).reshape(-1, 4)
    row_anchor = np.searchsorted(ids, log.anchor)
    nlos = np.isfinite(log.quality) & (log.quality < config.nlos_quality_db)
    scale = np.where(nlos, config.nlos_sigma_scale, 1.0)
    az_rad = np.radians(log.azimuth_deg)
    az_sigma = (math.radians(config.azimuth_sigma_deg) * scale
                / np.maximum(np.cos(np.where(np.isfinite(az_rad), az_rad, 0.0)), config.max_cos_floor))
    rounds = uwb_epochs(log, config.epoch_s)
    size = np.array([len(r) for r in rounds], int)
    starts = np.array([r[0] for r in rounds], np.int64) if rounds else np.zeros(0, np.int64)
    if config.use_aoa == "never":
        use_az, keep = np.zeros(len(rounds), bool), size >= config.min_range_anchors
    elif config.use_aoa == "fallback":
        use_az, keep = size < config.min_range_anchors, np.ones(len(rounds), bool)
    else:
        use_az, keep = np.ones(len(rounds), bool), np.ones(len(rounds), bool)
    anc = table[row_anchor]
    ok, out = _solve_rounds(starts[keep], starts[keep] + size[keep], use_az[keep], np.ascontiguousarray(anc[:, :3]),
                            np.ascontiguousarray(anc[:, 3]), np.ascontiguousarray(log.range_m, float),
                            np.ascontiguousarray(az_rad, float), np.ascontiguousarray(config.range_sigma_m * scale),
                            np.ascontiguousarray(az_sigma, float), float(tag_up_m), int(config.max_iter),
                            float(config.tol_m))
    kept = np.flatnonzero(keep)[ok]
    out = out[ok]
    if len(rounds):
        t_mid = (np.add.reduceat(log.t_s, starts) / size)[kept]
        has_az = (use_az & (np.add.reduceat(np.isfinite(az_rad).astype(int), starts) > 0))[kept]
    else:
        t_mid, has_az = np.zeros(0), np.zeros(0, bool)
    cov = np.stack([np.column_stack([out[:, 2], out[:, 3]]), np.column_stack([out[:, 3], out[:, 4]])], axis=1)
    return UwbFixes(t_s=t_mid.reshape(-1), east_m=out[:, 0].copy(), north_m=out[:, 1].copy(), cov_en=cov.reshape(-1, 2, 2),
                    n_anchors=size[kept].astype(int), used_aoa=has_az.reshape(-1), rms_residual=out[:, 5].copy(),
                    n_rounds=len(rounds))
