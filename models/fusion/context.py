"""The error model of a fix in its context: a white part, a correlated bias, and the prior that it is an outlier.

What is left of the GNSS error once a quality-aware R is used is neither white
nor Gaussian: RTK-float, DGNSS and autonomous fixes carry biases of decimetres
that drift over tens of seconds (NLOS, multipath), and a fix the receiver
reports as good is sometimes metres off — more often where the sky is blocked.
:class:`ContextNoise` models each fix's error as

    e_k = b_k + w_k,   w_k ~ (1 − ε) N(0, R_k) + ε N(0, κ R_k)

* R_k = s²·C_k: C_k the fix's own reported covariance (the receiver's GST, else
  the C/N0 or UERE·HDOP model of :mod:`features.gnss.positions`), s² fitted;
* b_k a first-order Gauss–Markov bias (σ_b, τ) shared by consecutive fixes of
  one quality and reset when the quality changes or after a gap (lock lost, a
  new ambiguity set): a float run's drifting NLOS bias, and a fixed run's wrong
  integers, which persist until lock is lost (σ_b ≈ 0 for a fixed run in the
  open; a run never shares the bias of another quality's run — the defect of a
  single bias shared by every fix); it becomes two filter states
  (:mod:`models.fusion.ekf`);
* ε, κ the contamination of the white part (Huber 1964's ε-contaminated
  normal), which the filter core's :func:`~models.fusion.core.mixture_update`
  turns into a per-fix outlier probability.

Each of s, σ_b, τ, ε, κ is fitted per GGA quality and — for the
environment-aware method — per environment class, from training fixes against
truth: σ_b and τ from the pooled autocovariance of the errors (Gelb 1974 §3.8:
C(τ) = σ_b² e^(−τ/T) for lags within a segment), s, ε and κ by EM on the
Mahalanobis distances of the errors (a two-component mixture of exponentials,
Dempster, Laird & Rubin 1977). At run time every parameter is the expectation
over the classifier's class probabilities (τ, κ in logs). With
``n_classes = 1`` the same machinery is environment-blind: the twin that
measures what the class adds.

Acoustic fixes: the solver's covariance times a per-class scale and their own
contamination (ε, κ) per class; no bias state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.fusion.events import ACOUSTIC, GNSS, ClassTrack, EventStream
from models.fusion.noise import NoiseError, NoiseSpec

__all__ = ["ContextNoise", "BIASED_QUALITIES", "fit_gauss_markov", "fit_contamination", "ErrorSeries"]

BIASED_QUALITIES = (1, 2, 5, 6)
"""GGA fix qualities modelled with a bias state by default: autonomous, DGNSS, RTK float, estimated (NMEA 0183
§GGA); each run of one quality has its own (the state is reset at every change of quality). RTK-fixed (4) runs
are not: their error is centimetres but for rare wrong integers, which a Gauss–Markov bias models badly (on the
demo split's held-out walks a q4 bias of 6 cm fitted from 2 % wrong epochs slowed every float→fixed transition:
adaptive_nobp 0.031 / 0.064 m under q4 against 0.012 / 0.016 for kf_quality); they are the contamination's
outliers instead. ``biased_qualities`` can add them (a receiver whose wrong fixes are frequent and long)."""

_MIN_SCALE2 = 1e-4
"""Smallest fitted white-variance scale s², so no fix is ever trusted beyond 1 % of its reported σ."""


@dataclass(frozen=True)
class ErrorSeries:
    """One training walk's fixes of one source against truth: ``t_s`` (n,), ``err_m`` (n, 2), ``cov_m2``
    (n, 2, 2) the reported covariance, ``quality`` (n,) (GNSS; 0 for acoustic), ``cls`` (n,) the class the
    classifier gave at the fix (−1 unknown)."""

    t_s: np.ndarray
    err_m: np.ndarray
    cov_m2: np.ndarray
    quality: np.ndarray
    cls: np.ndarray


def _mahalanobis2(e: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """e'C⁻¹e per row: e (n, 2), C (n, 2, 2)."""
    det = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]
    return (cov[:, 1, 1] * e[:, 0] ** 2 - (cov[:, 0, 1] + cov[:, 1, 0]) * e[:, 0] * e[:, 1]
            + cov[:, 0, 0] * e[:, 1] ** 2) / det


def fit_gauss_markov(series: list[ErrorSeries], select, reset_gap_s: float = 5.0, max_lag_s: float = 60.0,
                     bin_s: float = 1.0) -> tuple[float, float, float, int]:
    """σ_b² (m², per axis), τ (s), C(0) (m², per axis) and the sample count of a Gauss–Markov bias fitted to
    the errors of ``series`` for which ``select(s)`` (a per-series boolean mask) holds.

    Pairs of fixes are taken within one segment (same quality, no gap above ``reset_gap_s``, both selected):
    C(τ) = mean of (e_i · e_j)/2 over pairs |t_i − t_j| in each ``bin_s`` bin up to ``max_lag_s``, and
    ln C(τ) = ln σ_b² − τ/T fitted by weighted least squares over the bins with C > 0 (Gelb 1974 §3.8).
    Returns (0, 1, C(0), n) when no lag bin is positive.
    """
    nbins = int(max_lag_s / bin_s)
    acc = np.zeros(nbins)
    cnt = np.zeros(nbins)
    c0, n0 = 0.0, 0
    for s in series:
        sel = select(s)
        if not np.any(sel):
            continue
        t, e, q = s.t_s, s.err_m, s.quality
        c0 += float(np.sum(e[sel] ** 2)) / 2.0
        n0 += int(sel.sum())
        seg = np.concatenate([[0], np.cumsum((np.diff(t) > reset_gap_s) | (np.diff(q) != 0))])
        for lag in range(1, len(t)):
            a, b = np.arange(len(t) - lag), np.arange(lag, len(t))
            ok = sel[a] & sel[b] & (seg[a] == seg[b])
            dt = t[b] - t[a]
            ok &= dt < max_lag_s
            if not ok.any():
                if np.all(dt >= max_lag_s):
                    break
                continue
            k = np.minimum((dt[ok] / bin_s).astype(int), nbins - 1)
            np.add.at(acc, k, np.sum(e[a[ok]] * e[b[ok]], axis=1) / 2.0)
            np.add.at(cnt, k, 1.0)
    if n0 == 0:
        return 0.0, 1.0, 0.0, 0
    c0 /= n0
    use = (cnt > 20) & (acc > 0)
    if use.sum() < 2:
        return 0.0, 1.0, c0, n0
    lag = (np.arange(nbins) + 0.5) * bin_s
    c = acc[use] / cnt[use]
    # ln C(τ) = ln σ_b² − τ / T   (weighted by the pair counts)
    w = np.sqrt(cnt[use])
    A = np.column_stack([np.ones(use.sum()), -lag[use]]) * w[:, None]
    coef, *_ = np.linalg.lstsq(A, np.log(c) * w, rcond=None)
    inv_tau = max(float(coef[1]), 1.0 / 600.0)
    sb2 = min(float(math.exp(coef[0])), 0.95 * c0)
    return sb2, min(max(1.0 / inv_tau, 1.0), 600.0), c0, n0


def fit_contamination(u: np.ndarray, n_iter: int = 200, kappa_min: float = 4.0,
                      s2: float | None = None) -> tuple[float, float, float]:
    """(s², ε, κ) of u = d²/2 (d² a Mahalanobis distance with 2 degrees of freedom) under the mixture
    (1 − ε)·Exp(mean s²) + ε·Exp(mean κs²), by EM (Dempster, Laird & Rubin 1977), κ ≥ ``kappa_min``;
    ``s2`` given: the inlier scale held at it (only ε and κ fitted).

    Under no contamination u is Exp(1): s² ≈ 1, ε ≈ 0.

    >>> rng = np.random.default_rng(0)
    >>> u = np.concatenate([rng.exponential(2.0, 9000), rng.exponential(50.0, 1000)])
    >>> s2, eps, kappa = fit_contamination(u)
    >>> round(s2, 1), round(eps, 2), round(kappa)
    (2.0, 0.1, 25)
    """
    u = np.asarray(u, float)
    u = u[np.isfinite(u)]
    fixed = s2 is not None
    if u.size < 10:
        return (s2 if fixed else 1.0), 0.01, 25.0
    if not fixed:
        s2 = float(np.median(u) / math.log(2.0))
    eps, kappa = 0.05, 25.0
    for _ in range(n_iter):
        # responsibilities of the outlier component
        l1 = math.log(1.0 - eps) - math.log(s2) - u / s2
        l2 = math.log(eps) - math.log(kappa * s2) - u / (kappa * s2)
        top = np.maximum(l1, l2)
        r = np.exp(l2 - top) / (np.exp(l1 - top) + np.exp(l2 - top))
        new_eps = float(np.clip(r.mean(), 1e-4, 0.5))
        s2_new = s2 if fixed else float(np.sum((1 - r) * u) / max(np.sum(1 - r), 1e-9))
        k_new = max(float(np.sum(r * u) / max(np.sum(r), 1e-9)) / s2_new, kappa_min)
        done = abs(new_eps - eps) < 1e-7 and abs(s2_new - s2) < 1e-9 * s2 and abs(k_new - kappa) < 1e-6
        eps, s2, kappa = new_eps, s2_new, k_new
        if done:
            break
    return s2, eps, kappa


class ContextNoise:
    """R, the GNSS Gauss–Markov bias and the outlier prior per (environment class, GGA quality).

    Parameters
    ----------
    n_classes : int
        1: environment-blind (one class); 3: open / light / heavy from the classifier's probabilities.
    bias : bool
        Whether fixes of :data:`BIASED_QUALITIES` share a Gauss–Markov bias state.
    mixture : bool
        Whether the white part is ε-contaminated (the filter then runs the mixture update).
    reset_gap_s : float
        A GNSS gap longer than this (lock lost) resets the bias, as does a change of quality.
    biased_qualities : tuple of int
        GGA qualities whose runs carry a bias state (default :data:`BIASED_QUALITIES`).
    min_samples : int
        Fixes a (class, quality) cell needs for its own parameters (else the quality's, pooled over classes).

    Attributes (after ``fit``)
    --------------------------
    gnss_ : dict ``{(class, quality): {"s2", "eps", "kappa", "sb2", "tau_s"}}`` (class −1: pooled)
    acoustic_ : dict ``{class: {"s2", "eps", "kappa"}}`` (class −1: pooled)
    """

    def __init__(self, n_classes: int = 3, bias: bool = True, mixture: bool = True, reset_gap_s: float = 5.0,
                 min_samples: int = 200, biased_qualities: tuple = BIASED_QUALITIES):
        self.n_classes = n_classes
        self.bias = bias
        self.mixture = mixture
        self.reset_gap_s = reset_gap_s
        self.min_samples = min_samples
        self.biased_qualities = biased_qualities

    # -- fitting -----------------------------------------------------------------------------------------

    def fit(self, gnss: list[ErrorSeries], acoustic: list[ErrorSeries]) -> "ContextNoise":
        """Fit from training walks' GNSS and acoustic error series (:class:`ErrorSeries`)."""
        if self.n_classes < 1:
            raise NoiseError(f"n_classes must be >= 1, got {self.n_classes}")
        cls_of = (lambda s: np.zeros(len(s.t_s), int)) if self.n_classes == 1 else (lambda s: s.cls)
        qualities = sorted({int(q) for s in gnss for q in np.unique(s.quality)})
        self.gnss_ = {}
        for q in qualities:
            pooled = self._fit_cell(gnss, lambda s, q=q: s.quality == q, q)
            self.gnss_[(-1, q)] = pooled
            for c in range(self.n_classes):
                cell = (lambda s, q=q, c=c: (s.quality == q) & (cls_of(s) == c))
                n = sum(int(cell(s).sum()) for s in gnss)
                self.gnss_[(c, q)] = self._fit_cell(gnss, cell, q) if n >= self.min_samples else pooled
        self.acoustic_ = {-1: self._fit_acoustic(acoustic, lambda s: np.ones(len(s.t_s), bool))}
        for c in range(self.n_classes):
            cell = (lambda s, c=c: cls_of(s) == c)
            n = sum(int(cell(s).sum()) for s in acoustic)
            self.acoustic_[c] = (self._fit_acoustic(acoustic, cell) if n >= self.min_samples
                                 else self.acoustic_[-1])
        return self

    def _fit_cell(self, series, select, quality: int) -> dict:
        """One (class, quality) cell: the white scale s² from first differences of consecutive fixes of one
        segment (the bias, slow against 0.2–1 s, cancels: Var(e_k − e_{k−1}) = R_k + R_{k−1}), robust as
        median/ln 2 of an Exp variable; σ_b, τ from the autocovariance; ε, κ by EM with the inlier scale
        held at the fitted white-plus-bias variance."""
        biased = self.bias and quality in self.biased_qualities
        ud, u_tot = [], []
        for s in series:
            sel = select(s)
            if sel.sum() < 2:
                continue
            seg = np.concatenate([[0], np.cumsum((np.diff(s.t_s) > self.reset_gap_s) | (np.diff(s.quality) != 0))])
            pair = sel[1:] & sel[:-1] & (seg[1:] == seg[:-1])
            d = s.err_m[1:][pair] - s.err_m[:-1][pair]
            # Δe'(C_k + C_{k−1})⁻¹Δe / 2 ~ Exp(s²) under white noise of covariance s²C
            ud.append(_mahalanobis2(d, s.cov_m2[1:][pair] + s.cov_m2[:-1][pair]) / 2.0)
        ud = np.concatenate(ud) if ud else np.zeros(0)
        s2 = float(np.median(ud) / math.log(2.0)) if ud.size >= 10 else 1.0
        s2 = max(s2, _MIN_SCALE2)
        sb2, tau = 0.0, 1.0
        if biased:
            sb2, tau, _, _ = fit_gauss_markov(series, select, self.reset_gap_s)
        for s in series:
            sel = select(s)
            if sel.any():
                # d²/2 = e'(s² C + σ_b² I)⁻¹ e / 2
                u_tot.append(_mahalanobis2(s.err_m[sel], s2 * s.cov_m2[sel] + sb2 * np.eye(2)) / 2.0)
        u_tot = np.concatenate(u_tot) if u_tot else np.zeros(0)
        eps, kappa = 0.0, 1.0
        if self.mixture:
            _, eps, kappa = fit_contamination(u_tot, s2=1.0)
        return {"s2": s2, "eps": eps, "kappa": kappa, "sb2": sb2 if biased else 0.0, "tau_s": tau,
                "n": int(u_tot.size)}

    def _fit_acoustic(self, series, select) -> dict:
        u = []
        for s in series:
            sel = select(s)
            if sel.any():
                u.append(_mahalanobis2(s.err_m[sel], s.cov_m2[sel]) / 2.0)
        u = np.concatenate(u) if u else np.zeros(0)
        if self.mixture:
            s2, eps, kappa = fit_contamination(u)
        else:
            s2, eps, kappa = (float(np.mean(u)) if u.size else 1.0), 0.0, 1.0
        return {"s2": max(s2, _MIN_SCALE2), "eps": eps, "kappa": kappa, "n": int(u.size)}

    # -- running -----------------------------------------------------------------------------------------

    def _table(self, quality: int, key: str) -> np.ndarray:
        """Parameter ``key`` of ``quality`` per class, (n_classes,) (the pooled or default value where unfitted)."""
        pooled = self.gnss_.get((-1, quality), _DEFAULT)
        return np.array([self.gnss_.get((c, quality), pooled)[key] for c in range(self.n_classes)], float)

    def _expect(self, p: np.ndarray, quality: np.ndarray, key: str, log: bool = False) -> np.ndarray:
        """The expectation of ``key`` over the class probabilities ``p`` (m, n_classes) at each event's quality
        (m,) — in logs for the scale-like τ and κ."""
        out = np.zeros(len(quality))
        for q in np.unique(quality):
            sel = quality == q
            v = self._table(int(q), key)
            out[sel] = np.exp(p[sel] @ np.log(v)) if log else p[sel] @ v
        return out

    def measurement_noise(self, stream: EventStream, classes: ClassTrack | None = None,
                          class_at=None) -> NoiseSpec:
        """R, ε, κ of every fix and the GNSS bias process of every event (see the module docstring)."""
        if not hasattr(self, "gnss_"):
            raise NoiseError("ContextNoise must be fitted before a run")
        m = len(stream)
        if self.n_classes == 1:
            p = np.ones((m, 1))
        else:
            if classes is None:
                raise NoiseError("ContextNoise with classes needs class evidence (a ClassTrack)")
            if classes.n_classes != self.n_classes:
                raise NoiseError(f"classes has {classes.n_classes} classes, the policy {self.n_classes}")
            p = classes.at(stream.t_s)
            p = p / np.maximum(p.sum(axis=1, keepdims=True), 1e-300)
        r = np.array(stream.cov_m2, copy=True)
        eps = np.zeros(m)
        kappa = np.ones(m)
        quality = np.full(m, -1)
        g = stream.kind == GNSS
        if stream.gnss is not None and g.any():
            quality[g] = stream.gnss.quality[stream.index[g]]
            # R = E_c[s²_{c,q}] σ_rep² I;  ε = E_c[ε_{c,q}];  κ = exp E_c[ln κ_{c,q}]
            r[g] *= self._expect(p[g], quality[g], "s2")[:, None, None]
            eps[g] = self._expect(p[g], quality[g], "eps")
            kappa[g] = self._expect(p[g], quality[g], "kappa", log=True)
        a = stream.kind == ACOUSTIC
        if a.any():
            ac = [self.acoustic_.get(c, self.acoustic_[-1]) for c in range(self.n_classes)]
            r[a] *= (p[a] @ np.array([v["s2"] for v in ac]))[:, None, None]
            eps[a] = p[a] @ np.array([v["eps"] for v in ac])
            kappa[a] = np.exp(p[a] @ np.log([v["kappa"] for v in ac]))
        extra = {"eps_event": eps, "kappa_event": kappa}
        if self.bias:
            extra.update(self._bias_process(stream, p, quality))
        return NoiseSpec.per_event(r).with_fields(**extra)

    def _bias_process(self, stream: EventStream, p: np.ndarray, quality: np.ndarray) -> dict:
        """Per event: which GNSS fixes share the bias (m,), and its φ and Q (m,).

        The regime is the quality of the latest biased fix; between events the bias decays with that regime's
        τ and σ_b (class-expected at the event, the process rescaled when σ_b changes). A biased fix resets it (φ = 0, Q = σ_b²: b = 0 with its prior
        variance) when the previous available GNSS fix had another quality or lies more than ``reset_gap_s``
        back (a new ambiguity or tracking state, a new bias).
        """
        m = len(stream)
        shared = (stream.kind == GNSS) & np.isin(quality, self.biased_qualities) & stream.available
        # the regime in force at each event: the latest biased fix's quality (its own at a biased fix)
        last = np.where(shared, np.arange(m), -1)
        last = np.maximum.accumulate(last)
        regime = np.where(last >= 0, quality[np.maximum(last, 0)], self.biased_qualities[0])
        tau = self._expect(p, regime, "tau_s", log=True)
        # floored as σ_b below: a quality never seen in training has σ_b = 0, and a bias state reset to zero
        # variance makes P singular (the RTS smoother's gain solve then fails; issue 24, a drive's autonomous
        # fixes against a model trained on RTK walks)
        sb2 = np.maximum(self._expect(p, regime, "sb2"), 1e-8)
        # a Gauss–Markov process whose stationary σ_b follows the context: b/σ_b is a unit Gauss–Markov, so
        # b_k = (σ_k/σ_{k−1}) e^(−Δt/τ) b_{k−1} + w_k,  Var w_k = σ_k² (1 − e^(−2Δt/τ))
        # (a bias learnt under occlusion shrinks when the sky opens, as its variance says it must)
        decay = np.exp(-stream.dt_s / tau)
        sig = np.sqrt(sb2)
        ratio = sig / np.concatenate([[sig[0]], sig[:-1]])
        phi = ratio * decay
        q = sb2 * (1.0 - decay * decay)
        fix = np.flatnonzero((stream.kind == GNSS) & stream.available)
        prev_q = np.concatenate([[-1], quality[fix][:-1]])
        prev_t = np.concatenate([[-np.inf], stream.t_s[fix][:-1]])
        reset = fix[shared[fix] & ((prev_q != quality[fix]) | (stream.t_s[fix] - prev_t > self.reset_gap_s))]
        phi[reset] = 0.0
        q[reset] = sb2[reset]
        return {"bias_shared": shared, "bias_phi": phi, "bias_q": q}

    # -- state -------------------------------------------------------------------------------------------

    def get_state(self) -> dict:
        return {"n_classes": self.n_classes, "bias": self.bias, "mixture": self.mixture,
                "reset_gap_s": self.reset_gap_s, "min_samples": self.min_samples,
                "biased_qualities": list(self.biased_qualities),
                "gnss": [[c, q, v] for (c, q), v in self.gnss_.items()],
                "acoustic": [[c, v] for c, v in self.acoustic_.items()]}

    @classmethod
    def from_state(cls, state: dict) -> "ContextNoise":
        self = cls(n_classes=int(state["n_classes"]), bias=bool(state["bias"]), mixture=bool(state["mixture"]),
                   reset_gap_s=float(state["reset_gap_s"]), min_samples=int(state["min_samples"]),
                   biased_qualities=tuple(int(q) for q in state["biased_qualities"]))
        self.gnss_ = {(int(c), int(q)): {k: float(x) for k, x in v.items()} for c, q, v in state["gnss"]}
        self.acoustic_ = {int(c): {k: float(x) for k, x in v.items()} for c, v in state["acoustic"]}
        for v in list(self.gnss_.values()) + list(self.acoustic_.values()):
            if not all(math.isfinite(x) for x in v.values()) or v["s2"] <= 0 or not 0 <= v["eps"] < 1:
                raise NoiseError(f"ContextNoise state holds an unusable parameter set {v}")
        return self


_DEFAULT = {"s2": 1.0, "eps": 0.0, "kappa": 1.0, "sb2": 0.0, "tau_s": 30.0}
"""Parameters of a quality never seen in training: the reported σ as it is, no bias, no contamination."""
