"""Reading training walks for :mod:`training.fusion` (``envfuse train fusion``).

``training`` may not import ``pipeline`` (the spine lives here), so this module
reads each training walk once with :func:`pipeline.walk_data.read_walk`, turns
it into the rows :func:`training.fusion.fit_fusion_model` fits on, and hands
it the callback that runs ``adaptive_nobp`` on the same walks for the BP
network.
"""

from __future__ import annotations

import os
from typing import Callable

import numpy as np

from features.errors import DataError
from models.bp import BPConfig
from models.environment import EnvironmentClassifier
from models.fusion import EventEKF
from models.fusion.ekf import EkfConfig
from models.fusion_model import FusionModel
from pipeline.fusion import WalkInputs, adaptive_noise, bp_features, walk_inputs
from pipeline.walk_data import WalkData, read_walk
from training.fusion import WalkTraining, fit_fusion_model

__all__ = ["training_rows", "train_fusion", "DEFAULT_EKF"]


def training_rows(data: WalkData, inputs: WalkInputs, name: str) -> WalkTraining:
    """Errors of a walk's fixes against its truth, with the classes a map and the classifier give them."""
    truth = data.truth
    if truth is None:
        raise DataError(f"{name}: a training walk needs truth.csv")

    def against(t, e, n):
        ok = (t >= truth.t_s[0]) & (t <= truth.t_s[-1]) & np.isfinite(e) & np.isfinite(n)
        te, tn = truth.at(t[ok])
        err = np.stack([e[ok] - te, n[ok] - tn], axis=1)
        pred = np.argmax(inputs.classes.at(t[ok]), axis=1)
        return ok, err, truth.class_at(t[ok]), pred

    g_err, g_q, g_h, g_mc, g_pc = (np.zeros((0, 2)), np.zeros(0, int), np.zeros(0), np.zeros(0, int),
                                   np.zeros(0, int))
    if data.gnss is not None and len(data.gnss.positions):
        p = data.gnss.positions
        ok, g_err, g_mc, g_pc = against(p.t_s, p.east_m, p.north_m)
        g_q, g_h = p.quality[ok], np.where(p.hdop_assumed, np.nan, p.hdop)[ok]
    a_err, a_cov, a_mc, a_pc = np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0, int), np.zeros(0, int)
    if data.acoustic is not None and len(data.acoustic.t_s):
        a = data.acoustic
        ok, a_err, a_mc, a_pc = against(a.t_s, a.east_m, a.north_m)
        a_cov = a.covariance_en_m2[ok]
    return WalkTraining(name, g_err, g_q, g_h, g_mc, g_pc, a_err, a_cov, a_mc, a_pc)


DEFAULT_EKF = EkfConfig(outlier="huber")
"""The fusion model's filter settings: Huber down-weighting, not the χ² gate. On the held-out sites of the
``quick`` split (3 sites, 6 walks of 180 s) the gate locked one walk out of its fixes once PDR had drifted
(kf_quality mean 4.10 m, p95 34.8 m, max 50 m) where Huber stayed on them (0.22 m, p95 1.28 m, max 3.2 m)."""


def train_fusion(walk_dirs: list, classifier: EnvironmentClassifier, *, bp: bool = True,
                 bp_config: BPConfig = BPConfig(), ekf: EkfConfig = DEFAULT_EKF, meta: dict | None = None,
                 progress: Callable[[str], None] | None = None, noise_estimator: str = "mean") -> FusionModel:
    """Fit a :class:`~models.fusion_model.FusionModel` on ``walk_dirs`` (each with truth.csv);
    ``noise_estimator``: :func:`models.fusion.noise.chi2_2_mean`."""
    say = progress or (lambda line: None)
    provisional = FusionModel(classifier=classifier, fixed=None, quality=None, per_class_map=None, per_class=None)
    walks = []
    for w in walk_dirs:
        data = read_walk(w)
        if data.truth is None:
            raise DataError(f"{w}: a training walk needs truth.csv")
        inputs = walk_inputs(data, provisional)
        walks.append((str(w), data, inputs))
        say(f"read {os.path.basename(str(w))}")
    rows = [training_rows(d, i, n) for n, d, i in walks]

    def bp_data(model: FusionModel):
        X, Y = [], []
        for _, data, inputs in walks:
            run = EventEKF(model.ekf, adaptive_noise(model), "adaptive_nobp").run(inputs.events, classes=inputs.classes)
            te, tn = data.truth.at(run.t_s)
            inside = (run.t_s >= data.truth.t_s[0]) & (run.t_s <= data.truth.t_s[-1])
            y = np.stack([te - run.x[:, 0], tn - run.x[:, 1]], axis=1)
            y[~inside] = np.nan
            X.append(bp_features(run, inputs))
            Y.append(y)
        return X, Y

    meta = dict(meta or {})
    meta["training_walks"] = [n for n, _, _ in walks]
    meta["sites"] = sorted({d.site.name for _, d, _ in walks})
    return fit_fusion_model(rows, classifier, bp_data if bp else None, bp_config=bp_config, ekf=ekf, meta=meta,
                            progress=(lambda k, n: say(f"BP network {k}/{n}")), noise_estimator=noise_estimator)
