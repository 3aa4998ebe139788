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


def _wrap(x):
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


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


def _initial(anc: np.ndarray, r_h: np.ndarray, az_world: np.ndarray, use_az: np.ndarray) -> np.ndarray | None:
    """Starting point: the mean polar point of the anchors with an angle, else the linearised ranges."""
    if use_az.any():
        pts = anc[use_az, :2] + r_h[use_az, None] * np.column_stack([np.sin(az_world[use_az]),
                                                                    np.cos(az_world[use_az])])
        return pts.mean(axis=0)
    if len(anc) < 3:
        return None
    # Caffery (2000): |p − a_i|² − |p − a_k|² = r_i² − r_k²  →  2(a_k − a_i)·p = r_i² − r_k² − |a_i|² + |a_k|²
    a, k = anc[:, :2], anc[-1, :2]
    A = 2.0 * (k - a[:-1])
    b = r_h[:-1] ** 2 - r_h[-1] ** 2 - np.sum(a[:-1] ** 2, axis=1) + np.sum(k ** 2)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return sol


def solve_round(anc: np.ndarray, boresight_rad: np.ndarray, range_m: np.ndarray, azimuth_rad: np.ndarray,
                range_sigma_m: np.ndarray, azimuth_sigma_rad: np.ndarray, tag_up_m: float,
                max_iter: int = 15, tol_m: float = 1e-4):
    """One round's horizontal position by weighted Gauss–Newton (module docstring).

    anc : array of shape (k, 3), anchors' (east, north, up), m. ``azimuth_rad`` NaN where a row's angle is
    not used. Returns ``(p (2,), cov (2, 2), rms)`` or ``None`` when the round cannot be solved
    (too few equations, no convergence, singular geometry).
    """
    use_az = np.isfinite(azimuth_rad)
    n_eq = len(range_m) + int(use_az.sum())
    if n_eq < 2 or (not use_az.any() and len(range_m) < 3):
        return None
    dz = tag_up_m - anc[:, 2]
    r_h = np.sqrt(np.maximum(range_m ** 2 - dz ** 2, 0.0))
    az_world = boresight_rad + np.where(use_az, azimuth_rad, 0.0)
    p = _initial(anc, r_h, az_world, use_az)
    if p is None or not np.all(np.isfinite(p)):
        return None
    w = np.concatenate([1.0 / range_sigma_m ** 2, 1.0 / azimuth_sigma_rad[use_az] ** 2])
    for _ in range(max_iter):
        de, dn = p[0] - anc[:, 0], p[1] - anc[:, 1]
        d3 = np.sqrt(de ** 2 + dn ** 2 + dz ** 2)
        d2h = np.maximum(de ** 2 + dn ** 2, 1e-6)
        # residuals z − h(p) and Jacobian ∂h/∂p of the range and bearing models
        res = np.concatenate([range_m - d3, _wrap(az_world - np.arctan2(de, dn))[use_az]])
        J = np.vstack([np.column_stack([de / np.maximum(d3, 1e-6), dn / np.maximum(d3, 1e-6)]),
                       np.column_stack([dn / d2h, -de / d2h])[use_az]])
        JtW = J.T * w
        N = JtW @ J
        if np.linalg.cond(N) > 1e12:
            return None
        step = np.linalg.solve(N, JtW @ res)
        p = p + step
        if np.hypot(*step) < tol_m:
            break
    else:
        return None
    de, dn = p[0] - anc[:, 0], p[1] - anc[:, 1]
    res = np.concatenate([range_m - np.sqrt(de ** 2 + dn ** 2 + dz ** 2),
                          _wrap(az_world - np.arctan2(de, dn))[use_az]])
    chi2 = float(np.sum(w * res ** 2))
    dof = n_eq - 2
    cov = np.linalg.inv(N)
    rms = math.sqrt(chi2 / dof) if dof > 0 else math.nan
    if dof > 0 and chi2 / dof > 1.0:
        cov = cov * (chi2 / dof)
    return p, 0.5 * (cov + cov.T), rms


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
    out = []
    for idx in rounds:
        k = len(idx)
        if config.use_aoa == "never" or (config.use_aoa == "fallback" and k >= config.min_range_anchors):
            if k < config.min_range_anchors:
                continue
            az = np.full(k, np.nan)
        else:
            az = az_rad[idx]
        anc = table[row_anchor[idx]]
        sol = solve_round(anc[:, :3], anc[:, 3], log.range_m[idx], az, config.range_sigma_m * scale[idx],
                          az_sigma[idx], tag_up_m, config.max_iter, config.tol_m)
        if sol is not None:
            out.append((float(np.mean(log.t_s[idx])), sol, k, bool(np.isfinite(az).any())))
    n = len(out)
    return UwbFixes(t_s=np.array([o[0] for o in out]), east_m=np.array([o[1][0][0] for o in out]),
                    north_m=np.array([o[1][0][1] for o in out]),
                    cov_en=np.array([o[1][1] for o in out]).reshape(n, 2, 2),
                    n_anchors=np.array([o[2] for o in out], dtype=int), used_aoa=np.array([o[3] for o in out], bool),
                    rms_residual=np.array([o[1][2] for o in out]), n_rounds=len(rounds))
