"""``foot_ins_fkf``: the foot-mounted INS with zero-velocity updates, UWB positions and magnetic heading in a
federated Kalman filter (issue 26; seed paper by Chen, Zhang, Chen, Liu & Wang: SBG Ellipse2-A at the right
ankle, 100 Hz, Mini3s UWB, UWB dropped with fewer than three anchors). Registered on import (``walks/__init__``).

What it reads (as a real crew's logs, never the simulator): ``imu_foot.csv``
(:func:`features.imu.foot.read_foot_imu`), ``uwb.csv`` as :func:`walks.reader.read_walk` holds it, solved range-only
multilateration (:func:`features.uwb.position.uwb_positions` with ``use_aoa="never"``: rounds with fewer than
three anchors are dropped, as in the seed paper), the declination ``walk.toml`` states.

* local filters (:mod:`models.foot.ins`): ZUPT-INS, UWB position, magnetic heading; β = 1/3 each, 1/2 each on
  a walk without ``uwb.csv`` (:class:`models.foot.federated.SharingFactors` says why); the track's
  ``info['note']`` names the filters that ran;
* a UWB fix is rejected by its quality — the round's weighted residual RMS above :data:`UWB_MAX_RMS` (the
  ranges disagree: an NLOS range in the round) — or by its innovation, the χ²₂ gate of the local filter;
* the UWB tag is worn on the body, the IMU at the ankle: the fix's covariance gets the foot's horizontal
  offset from the body, σ = :data:`FOOT_LEVER_SIGMA_M`, per axis;
* the output is the body's (waist's) track, as truth and every other method give it: the foot's positions at
  mid-stance, shifted by half the step width (:class:`models.foot.body.BodyFromFoot`, 8 cm assumed) across
  the direction of travel, interpolated (:func:`models.foot.body.body_from_foot`); the side from
  ``[imu_foot] placement``. On the held-out study walks this took the open-sky mean from 0.28–0.30 m (the
  ankle) to 0.16–0.17 m (bench/bench_foot_fkf.py --study);
* the start: the median of the UWB fixes of the first :data:`START_WINDOW_S`, else the track is anchored on the
  first good GNSS fix (:func:`walks.reader.pdr_start_from_gnss`, as PDR is);
* skipped (:class:`~walks.methods.MethodSkipped`) on walks without ``imu_foot.csv`` or whose file the reader
  refuses; walks written before this method ran every other method as before.
"""

from __future__ import annotations

import math

import numpy as np

from features.errors import DataError
from features.imu.foot import read_foot_imu
from models.foot.body import BodyFromFoot, body_from_foot
from models.foot.mechanisation import quat_to_dcm
from models.foot.ins import FootInsConfig, UwbFixes, run_foot_ins
from walks.methods import Method, MethodContext, MethodSkipped, register
from walks.reader import pdr_start_from_gnss
from walks.track import Track

__all__ = ["foot_ins_fkf", "foot_side", "walk_uwb_fixes", "UWB_MAX_RMS", "FOOT_LEVER_SIGMA_M", "START_WINDOW_S", "TRACK_RATE_HZ"]

UWB_MAX_RMS = 3.0
"""A UWB round whose weighted residual RMS exceeds this (its ranges disagree by 3σ) is rejected before the filter."""

FOOT_LEVER_SIGMA_M = 0.3
"""σ of the ankle's horizontal offset from the body-worn UWB tag, m: over a stride the foot swings from
≈ 0.4 m behind the pelvis to ≈ 0.4 m ahead (half a stride each way) and sits ≈ 0.1 m to the side."""

START_WINDOW_S = 2.0
"""The start position is the median of the UWB fixes of this first span of the walk, s."""

TRACK_RATE_HZ = 10.0
"""The track is written at this rate (every k-th INS sample), Hz."""


def _first_stance(stance: np.ndarray) -> int:
    """Index of the first stance sample (0 when none)."""
    idx = np.flatnonzero(stance)
    return int(idx[0]) if len(idx) else 0


def walk_uwb_fixes(ctx: MethodContext) -> tuple[UwbFixes | None, str]:
    """The walk's UWB fixes for the UWB local filter (quality-filtered, lever arm added), and a note."""
    from features.uwb.position import UwbSolveConfig

    data = ctx.inputs.data
    if data.walk.path("uwb") is None:
        return None, "no uwb.csv"
    if not data.site.uwb_anchors:
        return None, "uwb.csv but the site lists no [[uwb_anchors]]"
    if data.uwb is None:            # read_walk refused the file and said why in its notes
        why = next((n for n in data.notes if n.startswith("uwb")), "not readable")
        return None, f"uwb.csv unusable ({why})"
    try:                            # the log read_walk already holds, solved range-only (the seed paper's rule)
        fixes = data.uwb.positions(UwbSolveConfig(use_aoa="never"))
    except DataError as exc:
        return None, f"uwb.csv unusable ({exc})"
    rms = np.nan_to_num(np.asarray(fixes.rms_residual, float), nan=0.0)
    ok = (rms <= UWB_MAX_RMS) & np.isfinite(fixes.east_m) & np.isfinite(fixes.north_m)
    if not ok.any():
        return None, "no UWB round with three or more consistent anchors"
    cov = np.asarray(fixes.cov_en, float)[ok] + np.eye(2) * FOOT_LEVER_SIGMA_M ** 2
    en = np.column_stack([fixes.east_m[ok], fixes.north_m[ok]])
    return UwbFixes(np.asarray(fixes.t_s, float)[ok], en, cov), f"{ok.sum()} of {len(fixes)} UWB fixes passed quality"


def foot_side(placement: str) -> int:
    """+1 for a right foot, −1 for a left one, from ``walk.toml``'s ``[imu_foot] placement`` (e.g. "right
    ankle"); a placement naming neither side is taken as the right (the seed paper's)."""
    p = str(placement).lower()
    return -1 if "left" in p and "right" not in p else 1


def foot_ins_fkf(ctx: MethodContext, cfg: FootInsConfig = FootInsConfig(),
                 body: BodyFromFoot | None = BodyFromFoot()) -> Track:
    """The federated foot INS on one walk (module docstring); the track is the body's by the mid-stance rule
    (:func:`models.foot.body.body_from_foot`, ``body``), or the foot's own with ``body=None``."""
    data = ctx.inputs.data
    path = data.walk.path("imu_foot")
    if path is None:
        raise MethodSkipped("no imu_foot.csv (a foot-mounted IMU) in this walk")
    try:
        imu = read_foot_imu(path)
    except DataError as exc:
        raise MethodSkipped(f"imu_foot.csv unusable: {exc}") from None
    table = data.walk.streams.get("imu_foot", {})
    decl = math.radians(float(table.get("declination_deg", data.walk.streams.get("imu", {}).get("declination_deg",
                                                                                                  0.0))))
    uwb, uwb_note = walk_uwb_fixes(ctx)
    start = (0.0, 0.0)
    if uwb is not None:
        early = uwb.t_s <= uwb.t_s[0] + START_WINDOW_S
        start = tuple(np.median(uwb.en_m[early], axis=0))
    run = run_foot_ins(imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, imu.mag_ut, cfg, start_en_m=start,
                       declination_rad=decl, latitude_deg=data.site.origin.lat_deg, uwb=uwb)
    east, north = run.pos_m[:, 0].copy(), run.pos_m[:, 1].copy()
    if uwb is None:
        anchor = pdr_start_from_gnss(data.gnss.positions) if data.gnss is not None else None
        if anchor is None:
            raise MethodSkipped("no UWB fix and no GNSS fix to place the foot INS track")
        t_fix, e_fix, n_fix = anchor
        east += e_fix - np.interp(t_fix, run.t_s, east)
        north += n_fix - np.interp(t_fix, run.t_s, north)
    output = "foot"
    if body is not None:
        # fallback direction of travel: the foot's x axis (forward as strapped in the seed paper) in ENU
        x_enu = quat_to_dcm(run.quat[_first_stance(run.stance)])[:, 0]
        yaw = float(np.arctan2(x_enu[0], x_enu[1]))
        side = foot_side(table.get("placement", "right ankle"))
        en = body_from_foot(run.t_s, np.column_stack([east, north]), run.stance, imu.rate_hz,
                            BodyFromFoot(body.step_width_m, side * body.side), cfg.stance, yaw)
        east, north = en[:, 0], en[:, 1]
        output = f"body by mid-stance (step width {body.step_width_m:.2f} m, {'right' if side > 0 else 'left'} foot)"
    filters = ["ZUPT-INS"] + (["UWB"] if run.active[1] else []) + (["heading"] if run.active[2] else [])
    beta = ", ".join(f"{b:.2f}" for b, a in zip(run.sharing, run.active) if a)
    note = f"local filters {' + '.join(filters)} (beta {beta}); UWB: {uwb_note}; output {output}"
    k = max(int(round(imu.rate_hz / TRACK_RATE_HZ)), 1)
    sl = slice(0, None, k)
    info = {"note": note, "strides": run.strides, "uwb_accepted_share":
            float(run.uwb_accepted.mean()) if len(run.uwb_accepted) else float("nan"),
            "heading_updates": int(run.heading_used.sum()), "class_proba": ctx.inputs.classes.at(run.t_s[sl])}
    return Track("foot_ins_fkf", run.t_s[sl], east[sl], north[sl], run.P_pos_m2[sl].copy(), info)


register(Method("foot_ins_fkf", foot_ins_fkf, "foot INS + ZUPT, UWB and magnetic heading in a federated KF "
                "(Carlson 1990)"))
