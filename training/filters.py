"""Fitting the fusion model from training walks with ground truth (``envfuse train fusion``).

:func:`train_fusion` reads each training walk once, exactly as at run time
(:func:`walks.reader.read_walk`, :func:`walks.inputs.walk_inputs`), and fits:

1. the fixes' errors against truth (fix − truth at the fix time), per source;
2. R per source (``kf``): the second moment of those errors;
3. the UERE per GGA quality, the GST and acoustic scales (``kf_quality``);
4. R per class and source twice: with the class of the map at the true
   position (``kf_map``), and with the class the online classifier predicts
   at the fix time (``imm``), because that is what it will see running; and
   the context error model — white scale, Gauss–Markov bias and outlier
   prior per (predicted class, GGA quality) — and its environment-blind twin
   (``adaptive_nobp``, ``adaptive_nobp_blind``: :mod:`models.fusion.context`);
5. the UWB NLOS prior per predicted class and its blind twin (:class:`models.uwb_pdr.UwbNoisePrior`,
   from the UWB fixes' eᵀC⁻¹e against truth; walks with ``uwb.csv`` only);
6. the BP networks on the tuned ``adaptive_nobp`` runs of the training walks:
   the parameter network that sets each fix's R (and its environment-blind
   twin), trained through the filter's update (:mod:`models.bp_params`), and
   the literal position corrector (target: truth − filter position,
   :mod:`models.bp`), each with early stopping on whole validation walks.

Nothing here sees a test site: the benchmark split (:mod:`simulation.split`) keeps them apart.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from features.errors import ConfigError, DataError
from models.bp import BPConfig, BPCorrector
from models.bp_params import OneStep, ParamNet, ParamNetConfig
from models.environment import EnvironmentClassifier
from models.fusion import FixedNoise, PerClassNoise, QualityNoise
from models.fusion.context import ContextNoise, ErrorSeries
from models.fusion.calibration import CalibrationConfig
from models.fusion.ekf import EkfConfig
from models.fusion.model import FusionModel
from models.uwb_pdr import UwbNoisePrior, uwb_nees
from training.temporal import fit_class_hmm
from walks.inputs import CLASS_SMOOTHING, WalkInputs, walk_inputs
from walks.methods import adaptive_run, bp_features, parameter_rows, parameter_run, tuned
from walks.reader import WalkData, read_walk

__all__ = ["WalkTraining", "training_rows", "fit_noise", "fit_context", "fit_fusion_model", "train_fusion",
           "fit_param_net", "DEFAULT_EKF"]


@dataclass(frozen=True)
class WalkTraining:
    """One training walk's fixes against truth.

    GNSS: ``g_t`` (n,) fix times, ``g_err`` (n, 2) fix − truth, ``g_cov`` (n, 2, 2) the reader's reported
    covariance, ``g_quality`` (n,), ``g_hdop`` (n,), ``g_map_class`` (n,) truth class, ``g_pred_class`` (n,)
    classifier's class; acoustic likewise ``a_t``, ``a_err`` (k, 2), ``a_cov`` (k, 2, 2), ``a_map_class``,
    ``a_pred_class``.
    """

    name: str
    g_err: np.ndarray
    g_quality: np.ndarray
    g_hdop: np.ndarray
    g_map_class: np.ndarray
    g_pred_class: np.ndarray
    a_err: np.ndarray
    a_cov: np.ndarray
    a_map_class: np.ndarray
    a_pred_class: np.ndarray
    g_t: np.ndarray = None
    g_cov: np.ndarray = None
    a_t: np.ndarray = None
    g_gst: np.ndarray = None
    u_nees: np.ndarray = None
    u_pred_class: np.ndarray = None

    def error_series(self) -> tuple[ErrorSeries, ErrorSeries]:
        """The walk's GNSS and acoustic fixes as :class:`~models.fusion.context.ErrorSeries` (classes as predicted)."""
        g = ErrorSeries(self.g_t, self.g_err, self.g_cov, self.g_quality, self.g_pred_class)
        a = ErrorSeries(self.a_t, self.a_err, self.a_cov, np.zeros(len(self.a_t), int), self.a_pred_class)
        return g, a


def _cat(rows, name, shape_tail):
    parts = [getattr(r, name) for r in rows if len(getattr(r, name))]
    return np.concatenate(parts) if parts else np.zeros((0,) + shape_tail)


def fit_noise(rows: list[WalkTraining], n_classes: int = 3, estimator: str = "mean"
              ) -> tuple[FixedNoise, QualityNoise, PerClassNoise, PerClassNoise]:
    """(fixed, quality, per-class by map, per-class by classifier) noise policies from training walks."""
    g_err, a_err = _cat(rows, "g_err", (2,)), _cat(rows, "a_err", (2,))
    if len(g_err) + len(a_err) == 0:
        raise DataError("the training walks hold no GNSS or acoustic fix with truth")
    g = g_err if len(g_err) else None
    a = a_err if len(a_err) else None
    fixed = FixedNoise().fit(gnss_errors_m=g, acoustic_errors_m=a)
    gst = None
    if g is not None:
        gst = np.concatenate([r.g_gst if r.g_gst is not None else np.full((len(r.g_err), 2), np.nan)
                              for r in rows if len(r.g_err)])
    quality = QualityNoise().fit(quality=_cat(rows, "g_quality", ()), hdop=_cat(rows, "g_hdop", ()),
                                 gnss_errors_m=g, gst_sigma_m=gst if gst is not None and len(gst) == len(g) else None,
                                 acoustic_cov_m2=_cat(rows, "a_cov", (2, 2)) if a is not None else None,
                                 acoustic_errors_m=a, estimator=estimator)
    per_map = PerClassNoise(n_classes=n_classes).fit(
        gnss_class=_cat(rows, "g_map_class", ()) if g is not None else None, gnss_errors_m=g,
        acoustic_class=_cat(rows, "a_map_class", ()) if a is not None else None, acoustic_errors_m=a)
    per_cls = PerClassNoise(n_classes=n_classes).fit(
        gnss_class=_cat(rows, "g_pred_class", ()) if g is not None else None, gnss_errors_m=g,
        acoustic_class=_cat(rows, "a_pred_class", ()) if a is not None else None, acoustic_errors_m=a)
    return fixed, quality, per_map, per_cls


def fit_context(rows: list[WalkTraining], n_classes: int) -> ContextNoise:
    """The context error model (:class:`~models.fusion.context.ContextNoise`) of the training walks: per
    predicted class and GGA quality with ``n_classes`` > 1, pooled over classes (the environment-blind twin)
    with ``n_classes`` = 1."""
    pairs = [r.error_series() for r in rows]
    return ContextNoise(n_classes=n_classes).fit([g for g, _ in pairs if len(g.t_s)],
                                                 [a for _, a in pairs if len(a.t_s)])


def fit_fusion_model(rows: list[WalkTraining], classifier: EnvironmentClassifier,
                     bp_data: Callable[[FusionModel], tuple[list, list]] | None = None,
                     bp_config: BPConfig = BPConfig(), ekf: EkfConfig = EkfConfig(), meta: dict | None = None,
                     progress: Callable[[int, int], None] | None = None,
                     noise_estimator: str = "mean") -> FusionModel:
    """Fit the noise policies, then (when ``bp_data`` is given) the BP network.

    ``noise_estimator``: how the UERE table and the acoustic and GST scales are fitted from the training
    errors (:func:`models.fusion.noise.chi2_2_mean`).

    ``bp_data(model)`` runs ``adaptive_nobp`` of the noise-only model on every training walk and returns
    (inputs per walk, targets per walk) (:func:`train_fusion` builds it over the walks it read).
    """
    fixed, quality, per_map, per_cls = fit_noise(rows, classifier.n_classes_, estimator=noise_estimator)
    model = FusionModel(classifier=classifier, fixed=fixed, quality=quality, per_class_map=per_map, per_class=per_cls,
                        context=fit_context(rows, classifier.n_classes_), context_blind=fit_context(rows, 1),
                        ekf=ekf, bp=None, meta=dict(meta or {}))
    model.meta["noise_estimator"] = noise_estimator
    u = [r for r in rows if r.u_nees is not None and len(r.u_nees)]
    if u:
        nees, cls = np.concatenate([r.u_nees for r in u]), np.concatenate([r.u_pred_class for r in u])
        model.uwb_prior = UwbNoisePrior(classifier.n_classes_).fit(nees, cls)
        model.uwb_prior_blind = UwbNoisePrior(1).fit(nees, cls)
    if bp_data is not None:
        X, Y = bp_data(model)
        model.bp = BPCorrector(bp_config).fit(X, Y, progress=progress)
    model.meta.setdefault("training_walks", [r.name for r in rows])
    return model


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
    g_t, g_cov, g_gst = np.zeros(0), np.zeros((0, 2, 2)), np.zeros((0, 2))
    ev = inputs.events
    if data.gnss is not None and len(data.gnss.positions):
        p = data.gnss.positions
        ok, g_err, g_mc, g_pc = against(p.t_s, p.east_m, p.north_m)
        g_q, g_h = p.quality[ok], np.where(p.hdop_assumed, np.nan, p.hdop)[ok]
        g_t = p.t_s[ok]
        g_cov = ev.gnss.cov_m2[ok] if ev.gnss is not None else np.eye(2) * (p.sigma_en_m[ok] ** 2)[:, None, None]
        g_gst = ev.gnss.gst_sigma_m[ok] if ev.gnss is not None else np.full((int(ok.sum()), 2), np.nan)
    a_err, a_cov, a_mc, a_pc = np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0, int), np.zeros(0, int)
    a_t = np.zeros(0)
    if data.acoustic is not None and len(data.acoustic.t_s):
        a = data.acoustic
        ok, a_err, a_mc, a_pc = against(a.t_s, a.east_m, a.north_m)
        a_cov, a_t = a.covariance_en_m2[ok], a.t_s[ok]
    u_nees = u_pc = None
    if data.uwb is not None:
        from walks.uwb_methods import AOA_SOLVE

        f = data.uwb.positions(AOA_SOLVE)
        ok, u_err, _u_mc, u_pc = against(f.t_s, f.east_m, f.north_m)
        u_nees = uwb_nees(u_err, f.cov_en[ok])
    return WalkTraining(name, g_err, g_q, g_h, g_mc, g_pc, a_err, a_cov, a_mc, a_pc, g_t, g_cov, a_t, g_gst,
                        u_nees, u_pc)


DEFAULT_EKF = EkfConfig(outlier="huber")
"""The fusion model's filter settings: Huber down-weighting, not the χ² gate. On the held-out sites of the
``quick`` split (3 sites, 6 walks of 180 s) the gate locked one walk out of its fixes once PDR had drifted
(kf_quality mean 4.10 m, p95 34.8 m, max 50 m) where Huber stayed on them (0.22 m, p95 1.28 m, max 3.2 m)."""


def train_fusion(walk_dirs: list, classifier: EnvironmentClassifier, *, bp: bool = True,
                 bp_config: BPConfig = BPConfig(), ekf: EkfConfig = DEFAULT_EKF, meta: dict | None = None,
                 progress: Callable[[str], None] | None = None, noise_estimator: str = "median",
                 tune: bool = True, tune_evals: int = 60, class_map_for: Callable | None = None,
                 calibrate: bool = True, smooth_classes: bool = True,
                 class_smoothing: str = "forward") -> FusionModel:
    """Fit a :class:`~models.fusion.model.FusionModel` on ``walk_dirs`` (each with truth.csv): the noise
    policies, then (``tune``) every filter method's knobs by its own error on the same walks
    (:mod:`training.tuning`, at most ``tune_evals`` passes each), then the BP network on the tuned
    ``adaptive_nobp``, then (``calibrate``) the covariance calibrators of the filters' tracks
    (:mod:`training.calibration`). ``noise_estimator``: :func:`models.fusion.noise.chi2_2_mean` (the median form by
    default: a few wrong RTK-fixed epochs would otherwise set the fixed UERE). ``class_map_for``: site →
    :class:`~models.fusion.events.ClassMap`, so the map baseline can be tuned too (None: it keeps its fit).
    ``smooth_classes``: fit the class HMM on the walks' truth classes (:func:`training.temporal.fit_class_hmm`) and
    train on its causally smoothed classes; False: the windows one by one, as before it. ``class_smoothing``: how
    that HMM smooths the classes every training step sees (:data:`walks.inputs.CLASS_SMOOTHING`): ``"forward"``
    (causal, what ``run`` hands the filters) by default; ``"none"`` fits the noise, tuning, BP and calibration on
    the windows one by one (the twin that measures what the smoothing gains, ``bench/env_fusion_gain.py``); it is
    recorded in the model's ``meta["class_smoothing"]``."""
    if class_smoothing not in CLASS_SMOOTHING:
        raise ConfigError(f"class smoothing must be one of {', '.join(CLASS_SMOOTHING)}, got {class_smoothing!r}")
    say = progress or (lambda line: None)
    read = []
    for w in walk_dirs:
        data = read_walk(w)
        if data.truth is None:
            raise DataError(f"{w}: a training walk needs truth.csv")
        read.append((str(w), data))
        say(f"read {os.path.basename(str(w))}")
    # the class HMM first: the noise per classifier class and the tuning see the causally smoothed classes
    # that `run` will hand the filters
    temporal = fit_class_hmm([d for _, d in read], classifier.n_classes_) if smooth_classes else None
    if temporal is not None:
        say("class HMM: mean dwell " + ", ".join(f"{c} {v:.0f} s" for c, v in zip(classifier.class_names,
                                                                               temporal.dwell_s_)))
    walks = [(n, d, walk_inputs(d, classifier, temporal, class_smoothing)) for n, d in read]
    rows = [training_rows(d, i, n) for n, d, i in walks]

    def bp_data(model: FusionModel):
        X, Y = [], []
        for _, data, inputs in walks:
            run = adaptive_run(model, inputs)
            te, tn = data.truth.at(run.t_s)
            inside = (run.t_s >= data.truth.t_s[0]) & (run.t_s <= data.truth.t_s[-1])
            y = np.stack([te - run.x[:, 0], tn - run.x[:, 1]], axis=1)
            y[~inside] = np.nan
            X.append(bp_features(run, inputs))
            Y.append(y)
        return X, Y

    meta = dict(meta or {})
    meta["training_walks"] = [n for n, _, _ in walks]
    meta["class_smoothing"] = class_smoothing if temporal is not None else "none"
    meta["sites"] = sorted({d.site.name for _, d, _ in walks})
    model = fit_fusion_model(rows, classifier, None, ekf=ekf, meta=meta, noise_estimator=noise_estimator)
    model.temporal = temporal
    if tune:
        from training.tuning import KNOBS, TuningWalk, tune_method

        tw = [TuningWalk.of(i, class_map_for(d.site) if class_map_for else None) for _, d, i in walks]
        for name in KNOBS:
            knobs, before, after = tune_method(model, name, tw, tune_evals)
            if not math.isfinite(before):
                say(f"not tuned {name}: it runs on none of the training walks (no site map for kf_map?)")
                continue
            model.tuning[name] = knobs
            model.meta.setdefault("tuning_report", {})[name] = {"error_before_m": before, "error_after_m": after}
            say(f"tuned {name}: training error {before:.3f} -> {after:.3f} m ("
                + ", ".join(f"{k} x{v:.2f}" for k, v in knobs.items()) + ")")
    if bp:
        X, Y = bp_data(model)
        model.bp = BPCorrector(bp_config).fit(X, Y, progress=lambda k, n: say(f"BP corrector {k}/{n}"))
        pcfg = ParamNetConfig(hidden=bp_config.hidden, seed=bp_config.seed)
        for blind in (False, True):
            net = fit_param_net(model, [i for _, _, i in walks], blind, pcfg)
            setattr(model, "bp_params_blind" if blind else "bp_params", net)
            say(f"BP parameter network{' (blind)' if blind else ''}: one-step validation error "
                f"{net.validation_error_m_:.3f} m")
    if calibrate:
        from training.calibration import fit_calibration

        model.calibration = fit_calibration(model, walks, CalibrationConfig(seed=bp_config.seed), say)
    return model


def _one_step(model: FusionModel, inputs: WalkInputs, first, second, blind: bool) -> OneStep:
    """The fixes of a walk for training through the filter: inputs from the ``first`` pass, priors, H and the
    nominal R of the pass being improved (``second``: the first pass itself in round 1)."""
    from dataclasses import replace

    from models.fusion.ekf import measurement_models

    ev = inputs.events
    policy = model.context_blind if blind else model.adaptive_policy()
    cfg, scales = tuned(model, "adaptive_nobp_blind" if blind else "adaptive_nobp")
    spec = policy.measurement_noise(ev, classes=None if blind else inputs.classes)
    H, idx = measurement_models(ev, replace(cfg, outlier="mixture"), spec)
    truth = inputs.data.truth
    fix = np.flatnonzero(second.updated & (ev.t_s >= truth.t_s[0]) & (ev.t_s <= truth.t_s[-1]))
    te, tn = truth.at(ev.t_s[fix])
    X = parameter_rows(first, inputs, blind)[fix]
    return OneStep(X, second.x_prior[fix], second.P_prior[fix], H[idx[fix]], first.R[fix], ev.z_m[fix],
                   np.column_stack([te, tn]))


def fit_param_net(model: FusionModel, walks: list[WalkInputs], blind: bool, config: ParamNetConfig) -> ParamNet:
    """The BP parameter network (:mod:`models.bp_params`) of ``model`` on the training walks, trained through
    the filter in ``config.rounds`` rounds (round r on the priors of a second pass run with round r − 1's net)."""
    name = "adaptive_nobp_blind" if blind else "adaptive_nobp"
    firsts = [adaptive_run(model, i, name, blind=blind) for i in walks]
    net = ParamNet(config)
    seconds = firsts
    for r in range(config.rounds):
        data = [_one_step(model, i, f, s, blind) for i, f, s in zip(walks, firsts, seconds)]
        net.fit_round([d for d in data if len(d.X)], warm=r > 0)
        trial = replace_nets(model, net, blind)
        seconds = [parameter_run(trial, i, f, blind, "adaptive") for i, f in zip(walks, firsts)]
    return net


def replace_nets(model: FusionModel, net: ParamNet, blind: bool) -> FusionModel:
    """A copy of ``model`` with ``net`` as its (blind) BP parameter network."""
    from dataclasses import replace

    return replace(model, **{"bp_params_blind" if blind else "bp_params": net})
