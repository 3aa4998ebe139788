"""Robust measurement kernels of the graph, and their widths fitted per environment class.

Kernels (``gtsam.noiseModel.mEstimator``; the weight w multiplies the squared whitened residual, d the
Mahalanobis distance of the whole 2-D residual, so a fix is down-weighted as one, as the filter core's
Huber weight is):

* Huber (1964): w = 1 for d ≤ k, k/d beyond (:func:`huber_weight`);
* Cauchy (the Lorentzian, a Student-t with one degree of freedom): w = 1 / (1 + d²/c²) (:func:`cauchy_weight`);
* dynamic covariance scaling, DCS (Agarwal, Tipaldi, Spinello, Stachniss & Burgard 2013, ICRA, eq. 19):
  the scale s = min(1, 2Φ/(Φ + d²)) on the residual, w = s² (:func:`dcs_weight`) — the closed-form
  optimum of Sünderhauf & Protzel's (2012, IROS) switchable constraints, with Φ = 1/Ξ² for a switch prior
  of standard deviation Ξ; a larger Φ trusts a fix further.

:class:`KernelTable` is the environment-aware part: per environment class (and, for GNSS, per GGA
quality) a scale on the reported σ and a DCS Φ, fitted on training walks' fixes against truth by a
two-component scale mixture on the squared whitened error d² (EM, :func:`fit_scale_mixture`): inliers
d² ~ s_in²·χ²₂, outliers d² ~ s_out²·χ²₂ (χ²₂ scaled by s² is exponential with mean 2s², so each EM step
is closed form; Dempster, Laird & Rubin 1977). Φ is set at the Bayes boundary between the two
components in units of the inlier scale (:func:`bayes_boundary_d2`): DCS leaves a fix its full weight
exactly where it is more likely an inlier than an outlier. The blind twin is the same fit with the class
removed (every class pooled): ``KernelTable.fit(..., classes=None)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.graph.config import KERNELS, GraphError

__all__ = ["huber_weight", "cauchy_weight", "dcs_weight", "noise_model", "fit_scale_mixture", "bayes_boundary_d2",
           "MixtureFit", "KernelTable", "whitened_d2"]


def huber_weight(d, k: float):
    """Huber weight w(d) = min(1, k/d) (Huber 1964), d ≥ 0 the Mahalanobis distance.

    >>> float(huber_weight(3.0, 2.0))
    0.6666666666666666
    """
    d = np.asarray(d, float)
    return np.where(d <= k, 1.0, k / np.maximum(d, 1e-300))


def cauchy_weight(d, c: float):
    """Cauchy weight w(d) = 1 / (1 + d²/c²).

    >>> round(float(cauchy_weight(3.0, 2.0)), 6)
    0.307692
    """
    d = np.asarray(d, float)
    return 1.0 / (1.0 + (d / c) ** 2)


def dcs_weight(d, phi: float):
    """DCS weight w = s², s = min(1, 2Φ/(Φ + d²)) (Agarwal et al. 2013, eq. 19).

    >>> round(float(dcs_weight(3.0, 4.0)), 6)
    0.378698
    """
    d2 = np.asarray(d, float) ** 2
    s = np.minimum(1.0, 2.0 * phi / (phi + d2))
    return s * s


def noise_model(cov_m2: np.ndarray, kernel: str, width: float):
    """A gtsam noise model of covariance ``cov_m2`` (2, 2) under ``kernel`` (:data:`KERNELS`) of ``width``
    (Huber's k, Cauchy's c, DCS's √Φ, all in whitened units)."""
    import gtsam

    gauss = gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov_m2, float))
    if kernel == "gauss":
        return gauss
    m = gtsam.noiseModel.mEstimator
    if kernel == "huber":
        est = m.Huber.Create(float(width))
    elif kernel == "cauchy":
        est = m.Cauchy.Create(float(width))
    elif kernel == "dcs":
        est = m.DCS.Create(float(width) ** 2)
    else:
        raise GraphError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    return gtsam.noiseModel.Robust.Create(est, gauss)


def whitened_d2(err_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance e'R⁻¹e of errors (n, 2) under covariances (n, 2, 2), shape (n,)."""
    e = np.asarray(err_m, float)
    return np.einsum("ni,nij,nj->n", e, np.linalg.inv(np.asarray(cov_m2, float)), e)


@dataclass(frozen=True)
class MixtureFit:
    """A two-component fit of d²: inlier weight ``pi_in``, scales ``s_in``, ``s_out`` (on σ), sample count."""

    pi_in: float
    s_in: float
    s_out: float
    n: int

    @property
    def phi(self) -> float:
        """DCS Φ: the Bayes boundary in d²/s_in² (:func:`bayes_boundary_d2`)."""
        return bayes_boundary_d2(self.pi_in, self.s_in, self.s_out) / self.s_in ** 2


def _exp_pdf(x: np.ndarray, s2: float) -> np.ndarray:
    """Density of d² = s²·χ²₂: exponential with mean 2s²."""
    return np.exp(-x / (2.0 * s2)) / (2.0 * s2)


def fit_scale_mixture(d2: np.ndarray, n_iter: int = 200, tol: float = 1e-9) -> MixtureFit:
    """EM for d² ~ π·s_in²·χ²₂ + (1 − π)·s_out²·χ²₂ (see the module docstring), d2 of shape (n,), n ≥ 10.

    Starts from the median (inliers: s_in² = median/(2 ln 2), the χ²₂ median being 2 ln 2) and the
    upper decile; s_out is kept ≥ 2·s_in so the components do not swap.
    """
    x = np.asarray(d2, float)
    x = x[np.isfinite(x) & (x >= 0)]
    if x.size < 10:
        raise GraphError(f"a scale mixture needs at least 10 samples, got {x.size}")
    s_in2 = max(float(np.median(x)) / (2.0 * math.log(2.0)), 1e-12)
    s_out2 = max(float(np.percentile(x, 90)) / 2.0, 4.0 * s_in2)
    pi = 0.8
    prev = -np.inf
    for _ in range(n_iter):
        a = pi * _exp_pdf(x, s_in2)
        b = (1.0 - pi) * _exp_pdf(x, s_out2)
        tot = np.maximum(a + b, 1e-300)
        g = a / tot
        ll = float(np.sum(np.log(tot)))
        # M step: π = mean γ, s² = Σγ·d² / (2Σγ) per component
        pi = float(np.clip(g.mean(), 1e-3, 1.0 - 1e-3))
        s_in2 = max(float(np.sum(g * x) / (2.0 * max(g.sum(), 1e-12))), 1e-12)
        s_out2 = max(float(np.sum((1 - g) * x) / (2.0 * max((1 - g).sum(), 1e-12))), 4.0 * s_in2)
        if abs(ll - prev) <= tol * max(abs(ll), 1.0):
            break
        prev = ll
    return MixtureFit(pi, math.sqrt(s_in2), math.sqrt(s_out2), int(x.size))


def bayes_boundary_d2(pi_in: float, s_in: float, s_out: float) -> float:
    """d² where π·p_in(d²) = (1 − π)·p_out(d²) for exponential densities of means 2s_in², 2s_out²:
    d² = ln(π s_out² / ((1 − π) s_in²)) / (1/(2s_in²) − 1/(2s_out²)); at least 2·s_in² (the inlier
    mean) so a fix is never down-weighted below its own expected size.

    >>> round(bayes_boundary_d2(0.5, 1.0, 2.0), 5)          # ln 4 / (1/2 − 1/8) = 1.386294 / 0.375
    3.69678
    """
    a, b = s_in * s_in, s_out * s_out
    if not b > a:
        return math.inf
    d2 = math.log(pi_in * b / ((1.0 - pi_in) * a)) / (0.5 / a - 0.5 / b)
    return max(d2, 2.0 * a)


class KernelTable:
    """Scale on the reported σ and DCS Φ per (class, GGA quality) for GNSS and per class for acoustic fixes.

    ``fit(gnss_d2, gnss_quality, gnss_class, acoustic_d2, acoustic_class)``: d² the squared whitened
    training errors under the reported covariance; ``*_class`` (n,) int class of each fix (the online
    classifier's at the fix time), or None for the blind twin (one pooled fit). A cell with fewer than
    ``min_samples`` fixes takes its class's pooled fit, and that its source's (GNSS per quality: that
    quality's over all classes).

    ``gnss_params(quality (n,), proba (n, n_classes) or None)`` → (scale (n,), Φ (n,)): each class's
    value weighted by its probability (scale² and Φ averaged); the acoustic likewise.
    """

    def __init__(self, n_classes: int = 3, min_samples: int = 30):
        self.n_classes = n_classes
        self.min_samples = min_samples

    def fit(self, gnss_d2=None, gnss_quality=None, gnss_class=None, acoustic_d2=None, acoustic_class=None):
        self.blind_ = gnss_class is None and acoustic_class is None
        k = 1 if self.blind_ else self.n_classes
        self.gnss_ = {}
        self.gnss_default_ = (1.0, float(KernelTable._default_phi))
        if gnss_d2 is not None and len(gnss_d2):
            d2 = np.asarray(gnss_d2, float)
            q = np.asarray(gnss_quality, int)
            c = np.zeros(len(d2), int) if self.blind_ else np.asarray(gnss_class, int)
            self.gnss_default_ = self._pair(self._fit(d2), None)
            for qual in np.unique(q):
                pooled = self._pair(self._fit(d2[q == qual]), self.gnss_default_)
                for cls in range(k):
                    sel = (q == qual) & (c == cls)
                    self.gnss_[(cls, int(qual))] = self._pair(self._fit(d2[sel]), pooled)
        self.acoustic_ = [(1.0, float(KernelTable._default_phi))] * k
        if acoustic_d2 is not None and len(acoustic_d2):
            d2 = np.asarray(acoustic_d2, float)
            c = np.zeros(len(d2), int) if self.blind_ else np.asarray(acoustic_class, int)
            pooled = self._pair(self._fit(d2), None)
            self.acoustic_ = [self._pair(self._fit(d2[c == cls]), pooled) for cls in range(k)]
        return self

    _default_phi = 2.5 ** 2

    def _fit(self, d2: np.ndarray) -> MixtureFit | None:
        return fit_scale_mixture(d2) if d2.size >= self.min_samples else None

    @staticmethod
    def _pair(fit: MixtureFit | None, fallback):
        if fit is None:
            if fallback is None:
                return (1.0, float(KernelTable._default_phi))
            return fallback
        return (fit.s_in, float(fit.phi))

    def _weights(self, proba, n: int) -> np.ndarray:
        if self.blind_ or proba is None:
            return np.ones((n, 1))
        p = np.asarray(proba, float)
        if p.shape != (n, self.n_classes):
            raise GraphError(f"class probabilities must have shape ({n}, {self.n_classes}), got {p.shape}")
        return p / np.maximum(p.sum(axis=1, keepdims=True), 1e-12)

    def gnss_params(self, quality, proba=None) -> tuple[np.ndarray, np.ndarray]:
        """(scale (n,), Φ (n,)) of GNSS fixes of GGA ``quality`` (n,) under class ``proba`` (n, k)."""
        q = np.asarray(quality, int)
        w = self._weights(proba, len(q))
        s2 = np.zeros(len(q))
        phi = np.zeros(len(q))
        for cls in range(w.shape[1]):
            vals = np.array([self.gnss_.get((cls, int(v)), self.gnss_default_) for v in q]).reshape(-1, 2)
            s2 += w[:, cls] * vals[:, 0] ** 2
            phi += w[:, cls] * vals[:, 1]
        return np.sqrt(s2), phi

    def acoustic_params(self, n: int, proba=None) -> tuple[np.ndarray, np.ndarray]:
        """(scale (n,), Φ (n,)) of ``n`` acoustic fixes under class ``proba`` (n, k)."""
        w = self._weights(proba, n)
        vals = np.array(self.acoustic_)
        return np.sqrt(w @ vals[:, 0] ** 2), w @ vals[:, 1]

    def get_state(self) -> dict:
        """JSON-able state (no pickle)."""
        return {"n_classes": self.n_classes, "min_samples": self.min_samples, "blind": self.blind_,
                "gnss": [[c, q, s, p] for (c, q), (s, p) in sorted(self.gnss_.items())],
                "gnss_default": list(self.gnss_default_), "acoustic": [list(v) for v in self.acoustic_]}

    @classmethod
    def from_state(cls, state: dict) -> "KernelTable":
        try:
            t = cls(int(state["n_classes"]), int(state["min_samples"]))
            t.blind_ = bool(state["blind"])
            t.gnss_ = {(int(c), int(q)): (float(s), float(p)) for c, q, s, p in state["gnss"]}
            t.gnss_default_ = tuple(float(v) for v in state["gnss_default"])
            t.acoustic_ = [tuple(float(x) for x in v) for v in state["acoustic"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise GraphError(f"kernel table state is malformed ({exc})") from None
        vals = [v for pair in list(t.gnss_.values()) + t.acoustic_ + [t.gnss_default_] for v in pair]
        if not all(math.isfinite(v) and v > 0 for v in vals):
            raise GraphError("kernel table holds a non-positive or non-finite scale or Φ")
        return t
