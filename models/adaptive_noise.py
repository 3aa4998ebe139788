"""The adaptive method's noise policy: R per environment class *and* what each device reports about itself.

Environment class alone cannot tell an RTK-fixed epoch (centimetres) from a
float one (metres) in the same light-occlusion aisle, and the device's own
report alone cannot tell that a "fixed" epoch among fire walls is more often
wrong than one in the open. So the UERE of the GNSS error model
σ_axis = UERE·HDOP/√2 (Kaplan & Hegarty 2006, ch. 7) is learnt per (class,
GGA quality) from training walks, UERE² = E[(e² + n²)/HDOP²] (the maximum-
likelihood estimate under that model), and the acoustic solver's covariance
is scaled per class, k_c² = E[e'C⁻¹e]/2. A (class, quality) cell with fewer
than ``min_samples`` fixes falls back to the quality's value pooled over
classes, then to the device table.

At run time the class comes from the online classifier as probabilities; R is
their expectation, R = Σ_c p_c R_c (or the most probable class's with
``combine="argmax"``).
"""

from __future__ import annotations

import math

import numpy as np

from models.fusion.events import ACOUSTIC, GNSS, ClassTrack, EventStream
from models.fusion.noise import NoiseError, QualityNoise, chi2_2_mean

__all__ = ["ClassQualityNoise"]


class _Precomputed:
    """Per-run R computed for the whole stream beforehand (no feedback: the fast scalar loop may run it)."""

    n_iter = 1
    fast = True

    def __init__(self, r_m2: np.ndarray):
        self.R = r_m2

    def r(self, k, x):
        return self.R[k]

    def feedback(self, k, nu, hph, accepted):
        pass


class ClassQualityNoise:
    """R per (environment class, GGA quality) for GNSS and per class for the acoustic covariance.

    Parameters
    ----------
    n_classes : int
    min_samples : int
        Fixes needed in a (class, quality) cell before it gets its own UERE.
    combine : {"mean", "argmax"}

    Attributes
    ----------
    uere_m_ : dict
        ``{class: {quality: UERE}}``.
    acoustic_scale_ : ndarray of shape (n_classes,)
    """

    def __init__(self, n_classes: int = 3, min_samples: int = 20, combine: str = "mean"):
        self.n_classes = n_classes
        self.min_samples = min_samples
        self.combine = combine

    def fit(self, gnss_class, quality, hdop, gnss_errors_m, acoustic_class=None, acoustic_cov_m2=None,
            acoustic_errors_m=None, prior: QualityNoise | None = None,
            estimator: str = "mean") -> "ClassQualityNoise":
        """Fit from training fixes: GNSS class (n,), quality (n,), hdop (n,), errors (n, 2) fix − truth;
        acoustic class (k,), covariance (k, 2, 2), errors (k, 2). ``prior``: the class-free fit it falls back to.
        ``estimator``: see :func:`models.fusion.noise.chi2_2_mean`."""
        if self.combine not in ("mean", "argmax"):
            raise NoiseError(f"combine must be 'mean' or 'argmax', got {self.combine!r}")
        prior = prior if prior is not None else QualityNoise().fit()
        if not hasattr(prior, "uere_m_"):
            prior.fit()
        cls = np.asarray(gnss_class, int)
        q = np.asarray(quality, int)
        h = np.asarray(hdop, float)
        h = np.where(np.isfinite(h) & (h > 0), h, prior.assumed_hdop)
        e = np.asarray(gnss_errors_m, float).reshape(-1, 2)
        r2 = np.sum(e * e, axis=1)
        ok = np.isfinite(r2)
        self.uere_m_ = {}
        for c in range(self.n_classes):
            table = dict(prior.uere_m_)
            for code in np.unique(q):
                sel = ok & (cls == c) & (q == code)
                if sel.sum() >= self.min_samples:
                    # UERE² = E[(e² + n²) / HDOP²]
                    table[int(code)] = float(math.sqrt(chi2_2_mean(r2[sel] / h[sel] ** 2, estimator)))
            self.uere_m_[c] = table
        self.acoustic_scale_ = np.full(self.n_classes, float(prior.acoustic_scale_))
        if acoustic_errors_m is not None and len(acoustic_errors_m):
            ac = np.asarray(acoustic_class, int)
            ea = np.asarray(acoustic_errors_m, float)
            ca = np.asarray(acoustic_cov_m2, float)
            good = np.all(np.isfinite(ea), axis=1) & np.all(np.isfinite(ca), axis=(1, 2))
            d2 = np.full(len(ea), np.nan)
            d2[good] = np.einsum("ni,nij,nj->n", ea[good], np.linalg.inv(ca[good]), ea[good])
            for c in range(self.n_classes):
                sel = good & (ac == c)
                if sel.sum() >= self.min_samples:
                    # k² = E[e' C⁻¹ e] / 2
                    self.acoustic_scale_[c] = float(math.sqrt(chi2_2_mean(d2[sel], estimator) / 2.0))
        self.assumed_hdop_ = float(prior.assumed_hdop)
        return self

    def gnss_var_m2(self, quality: np.ndarray, hdop: np.ndarray) -> np.ndarray:
        """Per-axis variance of each fix under each class, shape (n, n_classes)."""
        q = np.asarray(quality, int)
        h = np.asarray(hdop, float)
        h = np.where(np.isfinite(h) & (h > 0), h, self.assumed_hdop_)
        out = np.empty((q.size, self.n_classes))
        for c in range(self.n_classes):
            u = np.array([self.uere_m_[c].get(int(v), np.nan) for v in q]) if q.size else np.zeros(0)
            out[:, c] = (u * h) ** 2 / 2.0
        return out

    def _start(self, stream: EventStream, classes: ClassTrack | None = None, class_at=None):
        if not hasattr(self, "uere_m_"):
            raise NoiseError("ClassQualityNoise must be fitted before a run")
        if classes is None:
            raise NoiseError("ClassQualityNoise needs class evidence (a ClassTrack)")
        p = classes.at(stream.t_s)
        if self.combine == "argmax":
            p = np.eye(self.n_classes)[np.argmax(p, axis=1)]
        p = p / np.maximum(p.sum(axis=1, keepdims=True), 1e-300)
        r = np.array(stream.cov_m2, copy=True)
        sel = stream.kind == GNSS
        if stream.gnss is not None and sel.any():
            g, i = stream.gnss, stream.index[sel]
            var = self.gnss_var_m2(g.quality[i], g.hdop[i])
            known = np.all(np.isfinite(var), axis=1)
            # R = Σ_c p_c σ²_c I
            v = np.sum(p[sel] * np.where(np.isfinite(var), var, 0.0), axis=1)
            rr = r[sel]
            rr[known] = v[known, None, None] * np.eye(2)
            r[sel] = rr
        sel = stream.kind == ACOUSTIC
        if sel.any():
            # R = C · Σ_c p_c k_c²
            r[sel] *= (p[sel] @ self.acoustic_scale_ ** 2)[:, None, None]
        return _Precomputed(r)

    # -- state ------------------------------------------------------------------------------------

    def get_state(self) -> dict:
        return {"n_classes": self.n_classes, "min_samples": self.min_samples, "combine": self.combine,
                "uere_m": {str(c): {str(q): u for q, u in t.items()} for c, t in self.uere_m_.items()},
                "acoustic_scale": self.acoustic_scale_.tolist(), "assumed_hdop": self.assumed_hdop_}

    @classmethod
    def from_state(cls, state: dict) -> "ClassQualityNoise":
        self = cls(n_classes=int(state["n_classes"]), min_samples=int(state["min_samples"]), combine=state["combine"])
        self.uere_m_ = {int(c): {int(q): float(u) for q, u in t.items()} for c, t in state["uere_m"].items()}
        self.acoustic_scale_ = np.asarray(state["acoustic_scale"], float)
        self.assumed_hdop_ = float(state["assumed_hdop"])
        if sorted(self.uere_m_) != list(range(self.n_classes)) or self.acoustic_scale_.shape != (self.n_classes,):
            raise ValueError("ClassQualityNoise state does not match its number of classes")
        return self
