"""The five GNSS features (μ, σ, β, ζ, λ) from per-satellite pseudorange data instead of GSV.

The features themselves are :func:`features.gnss.features.gnss_features`, unchanged: this module
only builds the :class:`~features.gnss.features.SkyArrays` that NMEA's GSV/GSA give, from a
:class:`~features.gnss.pseudorange.PseudorangeTable` and its solution
(:class:`~features.gnss.wls.WlsSolution`):

* **tracked** satellites are the table's rows: C/N0 from the table; azimuth and elevation seen from
  the epoch's own fix (``WlsSolution.azimuth_deg``/``elevation_deg``; smartLoc's elevation column was
  computed at the reference position, so it is not used); **used** = kept by the solver (RAIM
  exclusions are not "used", as GSA would not list them); HDOP from the solution.
* **in view but not tracked** is what this format lacks: a pseudorange file lists only tracked
  satellites, so taken as is every satellite in view is tracked and ζ = 0, λ = 0 — a silent wrong
  answer. What the data allows: a satellite tracked at some epochs of the log is *expected* at the
  others where its position, predicted from its own tracked positions, stands above the horizon.
  Its position at an untracked epoch is a cubic polynomial in time fitted to its tracked ECEF
  positions within ``horizon_s`` (default 300 s) on either side (≥ 4 of them, and one within
  ``horizon_s``): over 10 min of a GPS orbit a cubic's error is a few tens of metres, well under
  0.01° of elevation at 20,000 km (the fit uses tracked epochs after the gap too: offline, like the
  windows' features). Satellites never tracked in the log stay unknown, so ζ and λ
  are **lower bounds** of the GSV figures (a receiver's GSV lists every satellite its almanac puts
  above the horizon). With broadcast ephemerides (RINEX navigation file,
  :mod:`features.gnss.pseudorange`) the positions of every satellite would be known and the
  expected set complete; ``predict_untracked=False`` marks ζ missing instead (NaN) rather than 0.
* The features' elevation mask, window and thresholds are those of
  :class:`~features.gnss.features.GnssFeatureConfig`; C/N0 in whole dB-Hz (u-blox) as in NMEA, so
  β's 2 dB-Hz swing applies unchanged. μ and σ depend on the open-sky reference C_ref(el)
  (:class:`~features.gnss.features.Cn0Reference`): the built-in one describes the simulator's
  receiver, not a u-blox in a car; with open-sky data of the receiver,
  :func:`~features.gnss.features.fit_cn0_reference` fits one.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d

from features.errors import DataError
from features.gnss.features import Cn0Reference, GnssFeatureConfig, SkyArrays, gnss_features
from features.gnss.pseudorange import PseudorangeTable

__all__ = ["sky_from_pseudoranges", "pseudorange_features", "predict_untracked_positions"]

_MIN_FIT_SAMPLES = 4


def predict_untracked_positions(t_s: np.ndarray, sat_ecef_m: np.ndarray, tracked: np.ndarray,
                                horizon_s: float = 300.0) -> np.ndarray:
    """Satellite positions at the epochs where it was not tracked, from its tracked ones.

    t_s (E,); sat_ecef_m (E, m, 3), NaN where not tracked; tracked (E, m). For each untracked
    epoch, a cubic least-squares polynomial in time through the satellite's tracked positions
    within ± ``horizon_s`` (at least 4, the nearest within ``horizon_s``); NaN where there are
    not enough. Returns (E, m, 3), equal to ``sat_ecef_m`` where tracked.
    """
    t = np.asarray(t_s, float)
    out = np.array(sat_ecef_m, dtype=float, copy=True)
    for j in range(out.shape[1]):
        have = tracked[:, j]
        miss = np.flatnonzero(~have)
        if not have.any() or miss.size == 0:
            continue
        tt, pp = t[have], out[have, j]
        # one fit per block of untracked epochs no longer than a tenth of the horizon
        block = np.floor((t[miss] - t[miss][0]) / (0.1 * horizon_s)).astype(int)
        for b in np.unique(block):
            m = miss[block == b]
            sel = (tt >= t[m[0]] - horizon_s) & (tt <= t[m[-1]] + horizon_s)
            if sel.sum() < _MIN_FIT_SAMPLES:
                continue
            t0, scale = t[m].mean(), max(horizon_s, 1.0)
            coef = np.polynomial.polynomial.polyfit((tt[sel] - t0) / scale, pp[sel], 3)
            near = np.min(np.abs(t[m][:, None] - tt[sel][None, :]), axis=1) <= horizon_s
            pred = np.polynomial.polynomial.polyval((t[m] - t0) / scale, coef).T
            out[m[near], j] = pred[near]
    return out


def sky_from_pseudoranges(table: PseudorangeTable, solution, *, predict_untracked: bool = True,
                          horizon_s: float = 300.0) -> SkyArrays:
    """:class:`~features.gnss.features.SkyArrays` of every epoch of ``table`` solved by ``solution``.

    One column per satellite (system letter, svid) in order of first appearance (module docstring).
    Epochs without a fix borrow the nearest fix's position for the look angles of expected
    satellites (a car moves metres, the angles move by nothing). Raises DataError when no epoch
    has a fix.
    """
    t, start, stop = table.epochs()
    if len(solution.t_s) != len(t) or not np.array_equal(solution.t_s, t):
        raise DataError("sky_from_pseudoranges: the solution is not that of this table (epochs differ)")
    if not solution.has_fix.any():
        raise DataError("sky_from_pseudoranges: no epoch has a fix, so no look angle can be computed")
    keys, col = _columns(table)
    e_n, m_n = len(t), len(keys)
    row_epoch = np.repeat(np.arange(e_n), stop - start)
    nan = np.full((e_n, m_n), np.nan)
    cn0, el, az = nan.copy(), nan.copy(), nan.copy()
    sat = np.full((e_n, m_n, 3), np.nan)
    tracked = np.zeros((e_n, m_n), dtype=bool)
    used = np.zeros((e_n, m_n), dtype=bool)
    cn0[row_epoch, col] = table.cn0_dbhz
    el[row_epoch, col] = solution.elevation_deg
    az[row_epoch, col] = solution.azimuth_deg
    sat[row_epoch, col] = table.sat_ecef_m
    tracked[row_epoch, col] = True
    used[row_epoch, col] = solution.used
    in_view = tracked.copy()
    if predict_untracked:
        pred = predict_untracked_positions(t, sat, tracked, horizon_s)
        fix = _nearest_fix(solution)
        lat, lon, alt = pymap3d.ecef2geodetic(fix[:, 0], fix[:, 1], fix[:, 2])
        a_p, e_p, _ = pymap3d.ecef2aer(pred[..., 0], pred[..., 1], pred[..., 2],
                                       lat[:, None], lon[:, None], alt[:, None])
        expected = ~tracked & np.isfinite(e_p) & (np.nan_to_num(e_p, nan=-90.0) >= 0.0)
        el = np.where(expected, e_p, el)
        az = np.where(expected, a_p, az)
        in_view |= expected
    interval = float(np.median(np.diff(t))) if e_n > 1 else math.nan
    return SkyArrays(t_s=t, sat_keys=tuple(keys), el_deg=el, az_deg=az, cn0_dbhz=cn0, in_view=in_view,
                     used=used, hdop=np.asarray(solution.hdop, float), interval_s=interval)


def _columns(table: PseudorangeTable) -> tuple[list, np.ndarray]:
    """Distinct (system, svid) in order of first appearance, and each row's column."""
    code = np.char.add(table.system.astype("<U1"), table.svid.astype("<U12"))
    _, first, inv = np.unique(code, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    keys = [(str(table.system[i]), int(table.svid[i])) for i in first[order]]
    return keys, rank[inv.ravel()]


def _nearest_fix(solution) -> np.ndarray:
    """Each epoch's fix, or the nearest epoch's fix when it has none; (E, 3)."""
    k = np.flatnonzero(solution.has_fix)
    j = np.clip(np.searchsorted(solution.t_s[k], solution.t_s), 0, len(k) - 1)
    j_prev = np.maximum(j - 1, 0)
    closer_prev = np.abs(solution.t_s[k][j_prev] - solution.t_s) < np.abs(solution.t_s[k][j] - solution.t_s)
    return solution.ecef_m[k[np.where(closer_prev, j_prev, j)]]


def pseudorange_features(table: PseudorangeTable, solution, config: GnssFeatureConfig | None = None,
                         reference: Cn0Reference | None = None, *, predict_untracked: bool = True,
                         horizon_s: float = 300.0) -> dict[str, np.ndarray]:
    """The five features per window (:func:`~features.gnss.features.gnss_features`) from pseudorange data.

    Without ``predict_untracked`` no satellite is known to be untracked: ζ is then NaN (missing,
    not 0) and λ, whose "all in view" is then the tracked set, NaN too.
    """
    sky = sky_from_pseudoranges(table, solution, predict_untracked=predict_untracked, horizon_s=horizon_s)
    out = gnss_features(sky, config, reference)
    if not predict_untracked:
        out["invisible_ratio"] = np.full_like(out["invisible_ratio"], np.nan)
        out["dop_growth"] = np.full_like(out["dop_growth"], np.nan)
    return out
