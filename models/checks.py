"""Checks of a loaded model's contents: finite numbers, the shapes the code expects, covariances that are
covariances. A bundle's hashes say its files are the ones written; these say the numbers in them can be used
(a bundle edited and re-hashed, or written by a buggy fit, is refused by name instead of giving NaN tracks or
a broadcasting error mid-run).

Each function raises ValueError naming the array and what is wrong; the bundle loaders
(:func:`models.fusion.model.load_fusion_model`, :func:`training.env.load_env_model`) turn it into a
:class:`~models.bundle.BundleError`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_finite", "check_covariances", "check_classifier", "check_bp", "check_positive"]


def check_finite(name: str, a, shape: tuple | None = None) -> np.ndarray:
    """``a`` as a float array, every value finite, of ``shape`` when given (None entries: any length)."""
    a = np.asarray(a, float)
    if shape is not None and (a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape))):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} has shape {a.shape}, expected {want}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds {int(np.sum(~np.isfinite(a)))} non-finite values (NaN or inf)")
    return a


def check_positive(name: str, value) -> float:
    """A finite number > 0."""
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


def check_covariances(name: str, r, dim: int = 2) -> np.ndarray:
    """A covariance (dim, dim) or a stack (..., dim, dim): finite, symmetric and positive definite
    (Cholesky succeeds; a variance ≤ 0 or a correlation beyond ±1 does not)."""
    r = np.asarray(r, float)
    if r.ndim < 2 or r.shape[-2:] != (dim, dim):
        raise ValueError(f"{name} has shape {r.shape}, expected (..., {dim}, {dim}) covariance matrices")
    check_finite(name, r)
    flat = r.reshape(-1, dim, dim)
    if not np.allclose(flat, np.swapaxes(flat, 1, 2), rtol=1e-9, atol=1e-12):
        raise ValueError(f"{name} is not symmetric")
    for k, m in enumerate(flat):
        try:
            np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            where = f" (matrix {k})" if flat.shape[0] > 1 else ""
            raise ValueError(f"{name}{where} is not positive definite (diagonal {np.diag(m).tolist()})") from None
    return r


def check_classifier(clf) -> None:
    """A fitted :class:`~models.environment.EnvironmentClassifier`: prior a probability vector, every
    sub-model's standardisation, weights, precision and thresholds finite (a class never seen in training
    keeps its centre at +inf: the only non-finite value allowed), scales and precision usable."""
    k = int(clf.n_classes_)
    prior = check_finite("classifier prior", clf.prior_, (k,))
    if np.any(prior < 0) or abs(prior.sum() - 1.0) > 1e-6:
        raise ValueError(f"classifier prior {prior.tolist()} is not a probability vector")
    for name, m in clf.submodels_.items():
        where = f"classifier sub-model {name!r}"
        n_in = np.asarray(m["mean"]).shape[0] if np.ndim(m["mean"]) == 1 else -1
        check_finite(f"{where} mean", m["mean"], (None,))
        scale = check_finite(f"{where} scale", m["scale"], (n_in,))
        if np.any(scale <= 0):
            raise ValueError(f"{where} scale holds values <= 0")
        coef = check_finite(f"{where} coef", m["coef"], (k, None))
        check_finite(f"{where} intercept", m["intercept"], (k,))
        centres = np.asarray(m["class_mean"], float)
        if centres.shape != (k, n_in) or np.any(np.isnan(centres)) or np.any(centres == -np.inf):
            raise ValueError(f"{where} class_mean has shape {centres.shape} or NaN / -inf values")
        prec = check_covariances(f"{where} precision", m["precision"], n_in)
        del prec, coef
        check_finite(f"{where} ood_threshold", m["ood_threshold"])
        if "share_coef" in m:                       # bundles saved before the fractional-logit estimate
            check_finite(f"{where} share_coef", m["share_coef"], (None,))
            check_finite(f"{where} share_intercept", m["share_intercept"])
        share = {key[len("share."):]: v for key, v in m.items() if key.startswith("share.")}
        if share:
            from models.occlusion import OcclusionRegressor

            try:
                reg = OcclusionRegressor.from_arrays(share)     # shapes consistent, values finite, scales > 0
            except (KeyError, ValueError) as exc:
                raise ValueError(f"{where} share estimator: {exc}") from None
            if reg.mean_.shape != (n_in,):
                raise ValueError(f"{where} share estimator takes {reg.mean_.shape[0]} inputs, the sub-model {n_in}")


def check_bp(bp) -> None:
    """A loaded :class:`~models.bp.BPCorrector`: input standardisation and every member's weights finite,
    scales positive."""
    n_in = np.asarray(bp.x_mean_).shape[-1]
    check_finite("BP x_mean", bp.x_mean_, (n_in,))
    xs = check_finite("BP x_scale", bp.x_scale_, (n_in,))
    if np.any(xs <= 0):
        raise ValueError("BP x_scale holds values <= 0")
    check_positive("BP y_scale", bp.y_scale_)
    if not np.isfinite(bp.ood_threshold_):
        raise ValueError(f"BP ood_threshold is {bp.ood_threshold_}")
    if not bp.members_:
        raise ValueError("the BP network has no members")
    for k, w in enumerate(bp.members_):
        h = np.asarray(w["w1"]).shape[0]
        check_finite(f"BP member {k} w1", w["w1"], (h, n_in))
        check_finite(f"BP member {k} b1", w["b1"], (h,))
        check_finite(f"BP member {k} w2", w["w2"], (None, h))
        check_finite(f"BP member {k} b2", w["b2"], (np.asarray(w["w2"]).shape[0],))
