"""The fitted fusion model: what ``envfuse train fusion`` learns and ``run`` / ``evaluate`` apply.

A :class:`FusionModel` holds, for one substation family:

- the online environment classifier (:class:`models.environment.EnvironmentClassifier`),
- the measurement-noise policies fitted on training walks: ``kf`` (one R per
  source), ``kf_quality`` (UERE per GGA quality, GST and acoustic scales),
  ``kf_map`` (R per class, classes from the site map at the truth position),
  ``imm`` (R per class, classes from the online classifier — what it will
  see when running), ``adaptive_nobp`` and its environment-blind twin (the
  error model in context, :class:`~models.fusion.context.ContextNoise`: white
  scale, Gauss–Markov bias and outlier prior per class and GGA quality),
- the filter's process-noise settings (:class:`models.fusion.ekf.EkfConfig`) and, per method, the knobs
  it was tuned to on the training walks (``tuning``: scales of R, the walking noise, the bias variance),
- the BP networks: the parameter network and its environment-blind twin (:class:`models.bp_params.ParamNet`,
  ``adaptive`` / ``adaptive_blind``) and the literal position corrector (:class:`models.bp.BPCorrector`,
  ``adaptive_correction``), each or None,
- the covariance calibrators per track name (:class:`models.fusion.calibration.CovarianceCalibrator`,
  ``calibration``): what multiplies a track's reported covariance so its NEES holds (empty: raw covariances),
- the UWB NLOS prior per class and its blind twin (:class:`models.uwb_pdr.UwbNoisePrior`,
  ``uwb_aoa_pdr_env`` / ``uwb_aoa_pdr_blind``), each None when no training walk had UWB,
- metadata: the training walks and their hashes, the site names, versions.

Saved as one bundle (:mod:`models.bundle`, kind ``"fusion"``): JSON parameters
and safetensors arrays, never pickle.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from models.bp import BPCorrector
from models.bp_params import ParamNet
from models.bundle import BundleError, load_bundle, save_bundle
from models.checks import check_bp, check_classifier, check_covariances, check_positive
from models.environment import EnvironmentClassifier
from models.fusion.calibration import CovarianceCalibrator
from models.fusion.ekf import EkfConfig
from models.fusion.context import ContextNoise
from models.fusion.noise import FixedNoise, PerClassNoise, QualityNoise
from models.uwb_pdr import UwbNoisePrior

__all__ = ["FusionModel", "save_fusion_model", "load_fusion_model"]


@dataclass
class FusionModel:
    """Everything the fusion methods need at run time (see the module docstring)."""

    classifier: EnvironmentClassifier
    fixed: FixedNoise
    quality: QualityNoise
    per_class_map: PerClassNoise
    per_class: PerClassNoise
    context: ContextNoise | None = None
    context_blind: ContextNoise | None = None
    ekf: EkfConfig = field(default_factory=EkfConfig)
    bp: BPCorrector | None = None
    meta: dict = field(default_factory=dict)
    tuning: dict = field(default_factory=dict)
    bp_params: ParamNet | None = None
    bp_params_blind: ParamNet | None = None
    calibration: dict = field(default_factory=dict)
    """{track name: CovarianceCalibrator}, e.g. ``adaptive_blind+lag``."""
    uwb_prior: UwbNoisePrior | None = None
    uwb_prior_blind: UwbNoisePrior | None = None

    def adaptive_policy(self):
        """The adaptive methods' noise policy: R per class and GGA quality when the model has it, else per class."""
        return self.context if self.context is not None else self.per_class


def _noise_arrays(model: FusionModel) -> dict:
    a = {"fixed.R_gnss": model.fixed.R_gnss_, "fixed.R_acoustic": model.fixed.R_acoustic_,
         "map.R_gnss": model.per_class_map.R_gnss_, "map.R_acoustic": model.per_class_map.R_acoustic_,
         "cls.R_gnss": model.per_class.R_gnss_, "cls.R_acoustic": model.per_class.R_acoustic_}
    return {k: np.asarray(v, float) for k, v in a.items()}


def save_fusion_model(model: FusionModel, path, overwrite: bool = False):
    """Write ``model`` as a ``fusion`` bundle at ``path``."""
    cls_params, cls_arrays = model.classifier.get_state()
    params = {"classifier": cls_params, "ekf": asdict(model.ekf),
              "quality": {"uere_m": {str(k): v for k, v in model.quality.uere_m_.items()},
                          "gst_scale": model.quality.gst_scale_, "acoustic_scale": model.quality.acoustic_scale_},
              "per_class": {"combine": model.per_class.combine}, "per_class_map": {"combine": model.per_class_map.combine},
              "bp": None, "context": model.context.get_state() if model.context else None,
              "context_blind": model.context_blind.get_state() if model.context_blind else None,
              "tuning": {m: {k: float(v) for k, v in kn.items()} for m, kn in model.tuning.items()},
              "uwb_prior": model.uwb_prior.get_state() if model.uwb_prior is not None else None,
              "uwb_prior_blind": model.uwb_prior_blind.get_state() if model.uwb_prior_blind is not None else None}
    arrays = {"classifier": cls_arrays, "noise": _noise_arrays(model)}
    if model.bp is not None:
        bp_params, bp_arrays = model.bp.get_state()
        params["bp"] = bp_params
        arrays["bp"] = bp_arrays
    for key in ("bp_params", "bp_params_blind"):
        net = getattr(model, key)
        params[key] = None
        if net is not None:
            params[key], arrays[key] = net.get_state()
    params["calibration"] = {}
    if model.calibration:
        arrays["calibration"] = {}
        for name, cal in model.calibration.items():
            cp, ca = cal.get_state()
            cp = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in cp.items()}
            params["calibration"][name] = cp
            arrays["calibration"].update({f"{name}/{k}": v for k, v in ca.items()})
    return save_bundle(path, "fusion", params, arrays, meta=model.meta, overwrite=overwrite)


def load_fusion_model(path) -> FusionModel:
    """Read a ``fusion`` bundle; a damaged or inconsistent one raises :class:`~models.bundle.BundleError`.

    Beyond the bundle's hashes, the contents are checked (:mod:`models.checks`): every R a symmetric
    positive-definite 2×2 matrix of the right count, UEREs and scales positive, the classifier's and the BP
    network's numbers finite and of the shapes this version uses."""
    b = load_bundle(path, "fusion")
    try:
        p, a = b.params, b.arrays
        clf = EnvironmentClassifier.from_state(p["classifier"], a["classifier"])
        check_classifier(clf)
        n = a["noise"]
        k = clf.n_classes_
        shapes = {"fixed.R_gnss": (2, 2), "fixed.R_acoustic": (2, 2), "map.R_gnss": (k, 2, 2),
                  "map.R_acoustic": (k, 2, 2), "cls.R_gnss": (k, 2, 2), "cls.R_acoustic": (k, 2, 2)}
        for name, shape in shapes.items():
            if name not in n:
                raise ValueError(f"noise array {name} is missing")
            if n[name].shape != shape:
                raise ValueError(f"noise array {name} has shape {n[name].shape}, expected {shape}")
            check_covariances(f"noise array {name}", n[name])
        fixed = FixedNoise()
        fixed.R_gnss_, fixed.R_acoustic_ = n["fixed.R_gnss"], n["fixed.R_acoustic"]
        q = QualityNoise()
        q.uere_m_ = {int(c): check_positive(f"UERE of GGA quality {c}", v) for c, v in p["quality"]["uere_m"].items()}
        q.gst_scale_ = check_positive("GST scale", p["quality"]["gst_scale"])
        q.acoustic_scale_ = check_positive("acoustic scale", p["quality"]["acoustic_scale"])
        per_map = PerClassNoise(n_classes=k, combine=p["per_class_map"]["combine"])
        per_map.R_gnss_, per_map.R_acoustic_ = n["map.R_gnss"], n["map.R_acoustic"]
        per = PerClassNoise(n_classes=k, combine=p["per_class"]["combine"])
        per.R_gnss_, per.R_acoustic_ = n["cls.R_gnss"], n["cls.R_acoustic"]
        bp = BPCorrector.from_state(p["bp"], a["bp"]) if p.get("bp") else None
        if bp is not None:
            check_bp(bp)
        nets = {k: ParamNet.from_state(p[k], a[k]) if p.get(k) else None for k in ("bp_params", "bp_params_blind")}
        ctx = ContextNoise.from_state(p["context"]) if p.get("context") else None
        ctx_blind = ContextNoise.from_state(p["context_blind"]) if p.get("context_blind") else None
        ekf = EkfConfig(**p["ekf"])
        uwb = {k: UwbNoisePrior.from_state(p[k]) if p.get(k) else None for k in ("uwb_prior", "uwb_prior_blind")}
        tuning = {str(m): {str(k): float(v) for k, v in kn.items()} for m, kn in p.get("tuning", {}).items()}
        calibration = {}
        for name, cp in (p.get("calibration") or {}).items():     # a bundle from before calibration has none
            cp = {k: (float("nan") if v is None else v) for k, v in cp.items()}
            ca = {k.split("/", 1)[1]: v for k, v in a["calibration"].items() if k.split("/", 1)[0] == name}
            calibration[str(name)] = CovarianceCalibrator.from_state(cp, ca)
        for m, kn in tuning.items():
            if not all(math.isfinite(v) and v > 0 for v in kn.values()):
                raise ValueError(f"tuning of {m} holds a non-positive or non-finite knob {kn}")
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise BundleError(f"{path}: the fusion model is inconsistent ({exc})") from None
    return FusionModel(classifier=clf, fixed=fixed, quality=q, per_class_map=per_map, per_class=per,
                       context=ctx, context_blind=ctx_blind, ekf=ekf, bp=bp, meta=b.meta, tuning=tuning,
                       calibration=calibration, **nets, **uwb)
