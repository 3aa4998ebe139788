"""Fit the covariance calibrators of a fusion model on its training walks (:mod:`models.fusion.calibration`).

Every method of :data:`walks.calibrate.CALIBRATED` is run on the training walks with the model as it stands
(tuned, with its BP networks), raw covariances; each of its tracks (filter, ``+lag``, ``+rts``) gets a
calibrator fitted on the NEES of its epochs against truth, with the walks' sites as the groups held out
(the walks themselves when they are all of one site).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from features.errors import DataError
from models.fusion.calibration import CalibrationConfig, CovarianceCalibrator
from walks.calibrate import CALIBRATED, CALIBRATED_SUFFIXES, track_inputs
from walks.methods import LAG_S, run_methods
from walks.score import track_errors

__all__ = ["calibration_data", "fit_calibration"]


def calibration_data(model, walks: list, methods=tuple(CALIBRATED)) -> dict:
    """{track name: (X (n, d), nees (n,), groups (n,))} over ``walks`` [(name, WalkData, WalkInputs)], the
    model's calibration switched off (raw covariances)."""
    raw = replace(model, calibration={})
    sites = {d.site.name for _, d, _ in walks}
    out = {}
    for name, data, inputs in walks:
        group = data.site.name if len(sites) > 1 else name
        tracks, _ = run_methods(raw, inputs, methods, smooth=True, lag_s=LAG_S)
        for base in methods:
            if base not in tracks:
                continue
            run = tracks[base].info["run"]
            for suffix in CALIBRATED_SUFFIXES:
                tr = tracks.get(base + suffix)
                if tr is None or tr.cov_m2 is None:
                    continue
                te = track_errors(tr, data.truth)
                X = track_inputs(tr, run, inputs, CALIBRATED[base])[te["ok"]]
                rows = out.setdefault(base + suffix, ([], [], []))
                rows[0].append(X)
                rows[1].append(te["nees"])
                rows[2].append(np.full(len(X), group, dtype=object))
    return {k: (np.vstack(v[0]), np.concatenate(v[1]), np.concatenate(v[2]).astype(str)) for k, v in out.items()}


def fit_calibration(model, walks: list, config: CalibrationConfig = CalibrationConfig(),
                    progress: Callable[[str], None] | None = None) -> dict:
    """{track name: fitted CovarianceCalibrator} for the calibrated methods' tracks on ``walks``
    [(name, WalkData, WalkInputs)]; a track with too few epochs is left out (its covariance stays raw)."""
    say = progress or (lambda line: None)
    cals = {}
    for name, (X, nees, groups) in calibration_data(model, walks).items():
        try:
            cals[name] = CovarianceCalibrator(config).fit(X, nees, groups)
        except DataError as why:
            say(f"covariance of {name} left raw: {why}")
            continue
        c = cals[name]
        if np.isfinite(c.oof_share_):
            say(f"calibrated {name}: NEES in the 95 % region {c.oof_share_raw_:.2f} -> {c.oof_share_:.2f} "
                f"(out of fold, multiplier {c.multiplier_:.2f})")
        else:   # one training walk: no fold to hold out, so no honest figure of the calibrated share
            say(f"calibrated {name}: NEES in the 95 % region {c.oof_share_raw_:.2f} before, multiplier "
                f"{c.multiplier_:.2f}; no out-of-fold figure after (it needs two or more training walks)")
    return cals
