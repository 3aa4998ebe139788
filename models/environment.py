"""Online environment classifier: a window's 14 features → class probabilities, occlusion, OOD flag.

t-SNE cannot place new points, so the classes the embedding + density-peak
clustering found (or map labels, in the supervised mode) are learnt by a
classifier in the standardised 14-D feature space, which then classifies
every new window.

Model. Multinomial logistic regression (softmax of a linear score; Bishop,
*Pattern Recognition and Machine Learning*, 2006, §4.3.4) on standardised
features, optionally with their pairwise products (``degree=2``: a quadratic
decision boundary, as quadratic discriminant analysis has, with the
regularisation of a linear model). Chosen over forests because prediction is
one small matrix product (millions of windows per second) and the learnt
state is a few arrays that are saved without pickle.

Missing modality. A window without GNSS (no satellites in view) or without a
beacon chirp has those five or nine features missing (NaN). Imputation would
invent the very statistics that tell the classes apart, so one sub-model is
fitted per available set — both, GNSS only, acoustic only — on the training
windows that have it, and each window is answered by the sub-model of what
it has. A window with neither gets the training class frequencies and the
OOD flag.

Out of distribution (OOD). Class-conditional Gaussians with a shared
covariance in the standardised space of each sub-model (Lee, Lee, Lee & Shin,
"A simple unified framework for detecting out-of-distribution samples",
NeurIPS 2018, eq. 2): the score of a window is its smallest Mahalanobis
distance² to a class mean, min_c (z − μ_c)ᵀ Σ⁻¹ (z − μ_c); beyond the
``ood_quantile`` of the training windows' own scores it is flagged rather
than forced into a class. A few 14 × 14 products per window — a k-NN density
test over the library measured 280 µs per window and grew with the library;
this one does not, and a bundle keeps no training windows.

Continuous occlusion. Where training windows carry the blocked-sky share, a
fractional-logit network on the same standardised inputs estimates it, in
(0, 1) by construction (:class:`models.occlusion.OcclusionRegressor`); the
fusion filter can use it as a soft input beside the class. Bundles saved
before it hold a ridge regression on the expanded inputs (``share_coef``,
``share_intercept``; clipped to [0, 1]) and still answer with it.

Cells. :func:`combine_windows` gives a cell the class of its windows'
combined probabilities (the product of window likelihoods, i.e. the sum of
log-probabilities, renormalised).
"""

from __future__ import annotations

import numpy as np

from features.schema import ENV_CLASSES, FEATURES, modality_columns
from models.occlusion import OcclusionRegressor

__all__ = ["EnvironmentClassifier", "combine_windows", "availability", "SUBMODELS"]

SUBMODELS = ("both", "gnss", "acoustic")
"""Sub-model names, by the modalities a window has."""

SHARE_PREFIX = "share."
"""Key prefix, in a sub-model's arrays, of the blocked-sky share estimator's state."""

_COLUMNS = {"both": tuple(range(len(FEATURES))), "gnss": modality_columns("gnss"),
            "acoustic": modality_columns("acoustic")}


def _expand(z: np.ndarray, degree: int) -> np.ndarray:
    """Standardised inputs, and with ``degree=2`` their pairwise products (i ≤ j) appended."""
    if degree == 1:
        return z
    i, j = np.triu_indices(z.shape[1])
    return np.hstack([z, z[:, i] * z[:, j]])


def availability(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gnss_available, acoustic_available) per row: every feature of the modality finite."""
    X = np.asarray(X, float)
    return (np.isfinite(X[:, list(_COLUMNS["gnss"])]).all(axis=1),
            np.isfinite(X[:, list(_COLUMNS["acoustic"])]).all(axis=1))


class EnvironmentClassifier:
    """Classify feature windows into environment classes, with sub-models per available modality.

    Parameters
    ----------
    C : float
        Inverse L2 regularisation strength of the logistic regressions (scikit-learn's ``C``).
    degree : {1, 2}
        1: linear in the standardised features; 2: with pairwise products too.
    ood_quantile : float
        Quantile of the training windows' own k-distances beyond which a window is OOD.
    min_samples : int
        A sub-model is fitted only with at least this many training windows (and two classes).
    class_names : tuple of str
        Names of the class codes 0..n-1 (default open, light, heavy).
    class_weight : {"balanced", None}
        scikit-learn's class weights of the logistic regressions. ``"balanced"`` (the default) weighs each
        class by the inverse of its share, so the rare heavy and light windows count as much as the open
        majority: the target is recall per class. Chosen on validation sites of the standard split's
        *training* sites (fitted on 101–103, scored on 104–106, satellite-sky label, cells ≥ 3 points from
        a boundary; surveys simulated before the coverage deployment and the RTK convergence gate):
        recall open / light / heavy 92.3 / 53.1 / 85.7 → 88.4 / 60.2 / 90.5 %, macro-F1 76.2 → 77.6 %.

    Attributes
    ----------
    classes_ : ndarray of shape (n_classes,)
        Class codes seen in training.
    prior_ : ndarray of shape (n_classes,)
        Training class frequencies.
    submodels_ : dict
        Per sub-model name: ``mean``, ``scale``, ``coef``, ``intercept``, ``class_mean`` and ``precision``
        (the OOD Gaussians), ``ood_threshold``, and the share estimator's arrays (``share.mean``, ``share.w0``, ...;
        ``share_coef``/``share_intercept`` in bundles saved before it) when shares were given.
    """

    def __init__(self, *, C: float = 1.0, degree: int = 2, ood_quantile: float = 0.995,
                 min_samples: int = 30, class_names: tuple = ENV_CLASSES, class_weight: str | None = "balanced"):
        self.C = C
        self.class_weight = class_weight
        self.degree = degree
        self.ood_quantile = ood_quantile
        self.min_samples = min_samples
        self.class_names = class_names

    # -- fitting ---------------------------------------------------------------------------------

    def _validate(self) -> None:
        if not (isinstance(self.C, (int, float)) and self.C > 0):
            raise ValueError(f"C must be a positive number, got {self.C!r}")
        if self.degree not in (1, 2):
            raise ValueError(f"degree must be 1 or 2, got {self.degree!r}")
        if self.class_weight not in (None, "balanced"):
            raise ValueError(f"class_weight must be None or 'balanced', got {self.class_weight!r}")
        if not 0.5 <= self.ood_quantile < 1:
            raise ValueError(f"ood_quantile must lie in [0.5, 1), got {self.ood_quantile!r}")
        if not (isinstance(self.min_samples, int) and self.min_samples >= 2):
            raise ValueError(f"min_samples must be an integer >= 2, got {self.min_samples!r}")

    def fit(self, X, y, share=None) -> "EnvironmentClassifier":
        """Fit every sub-model the data allow.

        Parameters
        ----------
        X : array-like of shape (n_windows, 14)
            Features in :data:`features.schema.FEATURES` order; NaN where a modality is missing.
        y : array-like of shape (n_windows,)
            Class codes (ints into ``class_names``) or class names.
        share : array-like of shape (n_windows,), optional
            Blocked-sky share per window in [0, 1], for the continuous estimate.
        """
        self._validate()
        X = np.asarray(X, float)
        if X.ndim != 2 or X.shape[1] != len(FEATURES):
            raise ValueError(f"X must have shape (n_windows, {len(FEATURES)}), got {X.shape}")
        y = self._codes(y)
        if len(y) != len(X):
            raise ValueError(f"X has {len(X)} rows but y has {len(y)}")
        if share is not None:
            share = np.asarray(share, float)
            if share.shape != (len(X),):
                raise ValueError(f"share must have shape ({len(X)},), got {share.shape}")
        self.n_classes_ = len(self.class_names)
        self.classes_ = np.unique(y)
        self.prior_ = np.bincount(y, minlength=self.n_classes_) / len(y)
        g, a = availability(X)
        masks = {"both": g & a, "gnss": g, "acoustic": a}
        self.submodels_ = {}
        for name in SUBMODELS:
            rows = masks[name]
            if rows.sum() >= self.min_samples and len(np.unique(y[rows])) >= 2:
                self.submodels_[name] = self._fit_one(X[rows][:, list(_COLUMNS[name])], y[rows],
                                                      None if share is None else share[rows])
        if not self.submodels_:
            raise ValueError(f"no sub-model could be fitted: need at least {self.min_samples} windows with "
                             "finite GNSS or acoustic features and two classes among them")
        return self

    def _codes(self, y) -> np.ndarray:
        y = np.asarray(y)
        if y.dtype.kind in "USO":
            try:
                return np.array([self.class_names.index(str(v)) for v in y], int)
            except ValueError:
                bad = sorted({str(v) for v in y} - set(self.class_names))
                raise ValueError(f"unknown class names {bad}; expected {self.class_names}") from None
        y = y.astype(int)
        if y.size and (y.min() < 0 or y.max() >= len(self.class_names)):
            raise ValueError(f"class codes must lie in [0, {len(self.class_names) - 1}]")
        return y

    def _fit_one(self, X: np.ndarray, y: np.ndarray, share) -> dict:
        # Imported here: prediction is numpy alone, and importing scikit-learn costs every evaluate
        # worker about 0.4 s of start-up (more where scipy.stats is not loaded yet).
        from sklearn.linear_model import LogisticRegression

        mean = X.mean(axis=0)
        scale = X.std(axis=0)
        constant = scale < 1e-12
        scale = np.where(constant, 1.0, scale)       # a constant feature carries no information: z = 0
        z = (X - mean) / scale
        # Newton–Cholesky: the same convex optimum as lbfgs (probabilities within 0.022, lbfgs's tolerance) in
        # 12 Newton steps instead of 236 quasi-Newton ones: 1.0 s against 44 s on four sites' 3,600 windows
        # with pairwise products (105 inputs), on 2 loaded cores; eight sites took lbfgs 262 s (issue 27).
        lr = LogisticRegression(C=self.C, max_iter=2000, class_weight=self.class_weight, solver="newton-cholesky")
        lr.fit(_expand(z, self.degree), y)
        coef = np.zeros((self.n_classes_, lr.coef_.shape[1]))
        intercept = np.full(self.n_classes_, -1e3)   # classes never seen: probability ~0
        if len(lr.classes_) == 2:                    # scikit-learn's binary form: one score for classes_[1]
            coef[lr.classes_[1]] = lr.coef_[0]
            intercept[lr.classes_[1]] = lr.intercept_[0]
            intercept[lr.classes_[0]] = 0.0
        else:
            coef[lr.classes_] = lr.coef_
            intercept[lr.classes_] = lr.intercept_
        present = np.unique(y)
        centres = np.zeros((self.n_classes_, z.shape[1]))
        resid = np.empty_like(z)
        for c in present:
            centres[c] = z[y == c].mean(axis=0)
            resid[y == c] = z[y == c] - centres[c]
        # Σ = within-class covariance (shared), regularised so that a constant direction stays finite
        cov = resid.T @ resid / max(len(z) - len(present), 1) + 1e-3 * np.eye(z.shape[1])
        precision = np.linalg.inv(cov)
        centres[np.setdiff1d(np.arange(self.n_classes_), present)] = np.inf    # never the nearest
        score = _mahalanobis_min(z, centres, precision)
        out = {"mean": mean, "scale": scale, "coef": coef, "intercept": intercept, "class_mean": centres,
               "precision": precision, "ood_threshold": np.array(float(np.quantile(score, self.ood_quantile)))}
        if share is not None and np.isfinite(share).all():
            _, share_arrays = OcclusionRegressor().fit(z, share).get_state()
            out.update({f"{SHARE_PREFIX}{k}": v for k, v in share_arrays.items()})
        return out

    # -- prediction ------------------------------------------------------------------------------

    def _route(self, X: np.ndarray) -> np.ndarray:
        """Sub-model index (into SUBMODELS) per row, −1 when no fitted sub-model can answer."""
        g, a = availability(X)
        route = np.full(len(X), -1)
        for i, (name, ok) in enumerate(zip(SUBMODELS, (g & a, g & ~a, a & ~g))):
            if name in self.submodels_:
                route[ok] = i
        # A window with both modalities but no "both" model: the better-populated single one.
        if "both" not in self.submodels_:
            for name in ("gnss", "acoustic"):
                if name in self.submodels_:
                    route[(g & a) & (route < 0)] = SUBMODELS.index(name)
        return route

    def _z(self, name: str, X: np.ndarray) -> np.ndarray:
        m = self.submodels_[name]
        return (X[:, list(_COLUMNS[name])] - m["mean"]) / m["scale"]

    def predict_proba(self, X) -> np.ndarray:
        """Class probabilities, shape (n_windows, n_classes); the prior where no sub-model answers."""
        X = np.atleast_2d(np.asarray(X, float))
        route = self._route(X)
        out = np.tile(self.prior_, (len(X), 1))
        for i, name in enumerate(SUBMODELS):
            rows = route == i
            if rows.any():
                m = self.submodels_[name]
                s = _expand(self._z(name, X[rows]), self.degree) @ m["coef"].T + m["intercept"]
                s -= s.max(axis=1, keepdims=True)
                p = np.exp(s)
                out[rows] = p / p.sum(axis=1, keepdims=True)
        return out

    def answers(self, X) -> np.ndarray:
        """True per window where a fitted sub-model answers (False: :meth:`predict_proba` gives the prior)."""
        return self._route(np.atleast_2d(np.asarray(X, float))) >= 0

    def fit_prior(self) -> np.ndarray:
        """The class prior the probabilities were fitted under, shape (n_classes,): uniform over the classes
        seen with ``class_weight="balanced"`` (each class weighted by the inverse of its share, so every class
        carries the same total weight), else the training frequencies ``prior_``. Dividing a posterior by it
        gives a scaled likelihood (:func:`models.temporal.scaled_likelihood`). A class never seen keeps 1
        (its probability is ~0 anyway)."""
        if self.class_weight != "balanced":
            return np.where(self.prior_ > 0, self.prior_, 1.0)
        seen = self.prior_ > 0
        return np.where(seen, 1.0 / max(int(seen.sum()), 1), 1.0)

    def predict(self, X) -> np.ndarray:
        """Most probable class code per window, shape (n_windows,)."""
        return np.argmax(self.predict_proba(X), axis=1)

    def is_ood(self, X) -> np.ndarray:
        """True where a window's Mahalanobis score exceeds the training quantile (or it has no features)."""
        X = np.atleast_2d(np.asarray(X, float))
        route = self._route(X)
        flag = route < 0
        for i, name in enumerate(SUBMODELS):
            rows = route == i
            if rows.any():
                m = self.submodels_[name]
                score = _mahalanobis_min(self._z(name, X[rows]), m["class_mean"], m["precision"])
                flag[rows] = score > float(m["ood_threshold"])
        return flag

    def occlusion(self, X) -> np.ndarray:
        """Estimated blocked-sky share in [0, 1] per window; NaN where no share model answers."""
        X = np.atleast_2d(np.asarray(X, float))
        route = self._route(X)
        out = np.full(len(X), np.nan)
        for i, name in enumerate(SUBMODELS):
            rows = route == i
            m = self.submodels_.get(name)
            if not rows.any() or m is None:
                continue
            if f"{SHARE_PREFIX}w0" in m:
                reg = OcclusionRegressor.from_arrays({k[len(SHARE_PREFIX):]: v for k, v in m.items()
                                                      if k.startswith(SHARE_PREFIX)})
                out[rows] = reg.predict(self._z(name, X[rows]))
            elif "share_coef" in m:                  # a bundle saved before the fractional-logit estimate
                est = _expand(self._z(name, X[rows]), self.degree) @ m["share_coef"] + float(m["share_intercept"])
                out[rows] = np.clip(est, 0.0, 1.0)
        return out

    # -- state for bundles (no pickle) -----------------------------------------------------------

    def get_state(self) -> tuple[dict, dict]:
        """(parameters as JSON-able dict, arrays as a flat dict of ndarrays) for a model bundle."""
        params = {"C": self.C, "degree": self.degree, "ood_quantile": self.ood_quantile,
                  "min_samples": self.min_samples, "class_names": list(self.class_names),
                  "class_weight": self.class_weight,
                  "submodels": sorted(self.submodels_), "features": list(FEATURES)}
        arrays = {"prior": self.prior_, "classes": self.classes_}
        for name, m in self.submodels_.items():
            for key, value in m.items():
                arrays[f"{name}.{key}"] = np.asarray(value)
        return params, arrays

    @classmethod
    def from_state(cls, params: dict, arrays: dict) -> "EnvironmentClassifier":
        """Rebuild a fitted classifier from :meth:`get_state`'s output; raises ValueError if inconsistent."""
        if list(params.get("features", [])) != list(FEATURES):
            raise ValueError("the model's feature order differs from this version's "
                             f"({params.get('features')} vs {list(FEATURES)})")
        self = cls(C=params["C"], degree=params["degree"], ood_quantile=params["ood_quantile"], min_samples=params["min_samples"],
                   class_names=tuple(params["class_names"]), class_weight=params.get("class_weight"))
        self._validate()
        self.n_classes_ = len(self.class_names)
        self.prior_ = np.asarray(arrays["prior"], float)
        self.classes_ = np.asarray(arrays["classes"], int)
        self.submodels_ = {}
        for name in params["submodels"]:
            if name not in SUBMODELS:
                raise ValueError(f"unknown sub-model {name!r}")
            m = {key.split(".", 1)[1]: np.asarray(v) for key, v in arrays.items() if key.startswith(name + ".")}
            n_in = len(_COLUMNS[name])
            n_exp = _expand(np.zeros((1, n_in)), self.degree).shape[1]
            if (m.get("coef", np.zeros(0)).shape != (self.n_classes_, n_exp) or m["mean"].shape != (n_in,)
                    or m.get("precision", np.zeros(0)).shape != (n_in, n_in)
                    or m.get("class_mean", np.zeros(0)).shape != (self.n_classes_, n_in)):
                raise ValueError(f"sub-model {name!r}: arrays do not match its shape")
            for key in ("ood_threshold", "share_intercept"):
                if key in m:
                    m[key] = np.asarray(m[key], float).reshape(-1)[0]     # scalars may come back as shape (1,)
            self.submodels_[name] = m
        return self


def _mahalanobis_min(z: np.ndarray, centres: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """min_c (z − μ_c)ᵀ P (z − μ_c) per row; rows (n, d), centres (k, d) (inf rows skipped), P (d, d)."""
    best = np.full(len(z), np.inf)
    for mu in centres:
        if np.all(np.isfinite(mu)):
            d = z - mu
            best = np.minimum(best, np.einsum("ij,jk,ik->i", d, precision, d))
    return best


def combine_windows(proba: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """A cell's class probabilities from its windows': normalised product of the window probabilities.

    Parameters
    ----------
    proba : ndarray of shape (n_windows, n_classes)

    >>> combine_windows(np.array([[0.6, 0.3, 0.1], [0.5, 0.4, 0.1]])).round(3).tolist()
    [0.698, 0.279, 0.023]
    """
    proba = np.asarray(proba, float)
    if proba.ndim != 2 or len(proba) == 0:
        raise ValueError("proba must have shape (n_windows, n_classes) with at least one window")
    s = np.log(np.clip(proba, eps, 1.0)).sum(axis=0)
    p = np.exp(s - s.max())
    return p / p.sum()
