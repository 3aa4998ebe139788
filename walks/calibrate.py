"""Covariance calibration of the filter tracks a model has calibrators for (:mod:`models.fusion.calibration`).

:data:`CALIBRATED` names the filters whose tracks (the filter itself, ``+lag`` and ``+rts``) are calibrated, and
whether their calibrator sees the class probabilities: an environment-aware method's does, its blind twin's and
``kf_quality``'s do not — the same machinery with the class inputs removed.
"""

from __future__ import annotations

import numpy as np

from models.fusion.calibration import calibration_inputs
from models.fusion.ekf import FilterResume, FilterRun

__all__ = ["CALIBRATED", "CALIBRATED_SUFFIXES", "track_inputs", "calibrate_tracks"]

CALIBRATED = {"kf_quality": False, "adaptive": True, "adaptive_blind": False}
"""Filter method → whether its calibrator takes the class probabilities."""

CALIBRATED_SUFFIXES = ("", "+lag", "+rts")


def track_inputs(track, run: FilterRun, inputs, aware: bool, resumed: FilterResume | None = None) -> np.ndarray:
    """Calibrator inputs (m, d) at the epochs of ``track`` (the filter run ``run`` or one of its smoothed
    tracks; same epochs) of the walk behind ``inputs`` (:class:`walks.inputs.WalkInputs`). ``resumed``: the
    state ``run`` resumed from (a long walk's segment, :mod:`walks.segments`): its NIS history stands for the
    run's events before it, the cut's warm-up, filtered without it."""
    g = inputs.events.gnss
    gt, gq = (None, None) if g is None else (g.t_s[_usable(g)], np.asarray(g.quality)[_usable(g)])
    proba = inputs.classes.at(track.t_s) if aware else None
    nis_t, nis = run.t_s, run.nis
    if resumed is not None and resumed.nis_t_s is not None:
        own = run.t_s >= resumed.t_s
        nis_t = np.concatenate([resumed.nis_t_s[resumed.nis_t_s < resumed.t_s], run.t_s[own]])
        nis = np.concatenate([resumed.nis[resumed.nis_t_s < resumed.t_s], run.nis[own]])
    return calibration_inputs(track.t_s, track.cov_m2, nis_t, nis, gt, gq, proba)


def _usable(fixes) -> np.ndarray:
    """(n,) the rows of a fix table that may update a filter (all when it has no ``available`` column)."""
    av = getattr(fixes, "available", None)
    return np.ones(len(fixes.t_s), bool) if av is None else np.asarray(av, bool)


def calibrate_tracks(tracks: dict, base: str, run: FilterRun, model, inputs) -> None:
    """Multiply, in place, the covariance of ``base`` and its smoothed tracks in ``tracks`` by the model's
    calibrated scale where the model has a calibrator for that track name; ``info["cov_scale"]`` (m,) holds the
    multiplier (absent: the track reports its raw covariance)."""
    cals = getattr(model, "calibration", None) or {}
    resumed = (getattr(inputs, "resume", None) or {}).get(base)
    for suffix in CALIBRATED_SUFFIXES:
        name = base + suffix
        tr = tracks.get(name)
        if tr is None or name not in cals or tr.cov_m2 is None:
            continue
        s = cals[name].scale(track_inputs(tr, run, inputs, CALIBRATED.get(base, False), resumed))
        tr.cov_m2 = tr.cov_m2 * s[:, None, None]
        tr.info["cov_scale"] = s
