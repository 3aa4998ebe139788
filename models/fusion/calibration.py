"""Covariance calibration: a track's reported covariance made to hold the errors it actually has.

Why. A filter's covariance P describes the errors its model allows. Where the
model is wrong — fixes whose errors are correlated over tens of seconds, an
RTK "fixed" fix a metre off under occlusion — P is too small exactly there:
on held-out sites the default track's NEES lay inside the two-sided 95 % χ²₂
region on 63 % of epochs (light occlusion 55 %, heavy 30 %; issue 22). A
static inflation per GGA quality or class reaches about 0.79 (a class or
quality describes where errors are large on average, not which stretch is in
trouble now); what tells the stretch apart is what the filter saw lately.

What. Per epoch of a track, the log-scale of its covariance is regressed on
what the filter saw up to that epoch (:func:`calibration_inputs`): the log
trace of its own P, the mean NIS of its updates over the last 2, 5 and 15 s,
the GGA quality of the latest GNSS fix (none when older than
:data:`GNSS_AGE_S`) and — for the environment-aware methods only — the class
probabilities. The model is multiplicative heteroscedasticity (Harvey 1976,
"Estimating regression models with multiplicative heteroscedasticity",
Econometrica 44(3), eq. 2): for e ~ N(0, s·P) the NEES ε = e'P⁻¹e is s·χ²₂,
so ln ε = ln s + ln χ²₂ and E[ln ε | inputs] = ln s(inputs) + E[ln χ²₂], with
E[ln χ²_k] = ψ(k/2) + ln 2 (ψ the digamma function; for k = 2 it is
ln 2 − γ ≈ 0.1159). A small network (torch, Adam, seeded, early stopping on
whole validation walks; tanh, two hidden layers) fits E[ln ε | inputs] by
least squares; ŝ = exp(prediction − E[ln χ²₂]).

ŝ is itself an estimate, so the NEES given the inputs is a scale mixture of
χ²₂, wider than χ²₂. One multiplier m on ŝ is chosen so that, on predictions
each made by a network that did not see the walk's own group (site-grouped
K-fold, out of fold), the share of epochs inside the two-sided 95 % χ²₂ region
is largest: the recalibration step of Kuleshov, Fenner & Ermon (2018),
"Accurate uncertainties for deep learning using calibrated regression"
(ICML), with the region's share as the calibration target.

The estimate is never touched: only the covariance the track reports is
multiplied by s = m·ŝ, so a method's error figures are the same with or without
it; its NEES figures change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri, digamma

from features.errors import DataError

__all__ = ["CalibrationConfig", "CovarianceCalibrator", "calibration_inputs", "with_covariance", "running_mean",
           "E_LOG_CHI2_2", "GNSS_AGE_S", "NIS_WINDOWS_S", "QUALITY_COLUMNS"]

E_LOG_CHI2_2 = float(digamma(1.0) + math.log(2.0))
"""E[ln χ²₂] = ψ(1) + ln 2 = ln 2 − γ ≈ 0.1159 (the mean of the log of a 2-degree-of-freedom χ²)."""

NIS_WINDOWS_S = (2.0, 5.0, 15.0)
"""Windows of the running mean NIS, s."""

GNSS_AGE_S = 2.0
"""A GNSS fix older than this (s) counts as none for the quality input."""

QUALITY_COLUMNS = (1, 2, 4, 5)
"""GGA qualities with their own one-hot input; two more columns: no recent fix, any other quality."""

_LOG_NIS_NONE = math.log(2.0)
"""ln of the running NIS where a window holds no update: the value a consistent filter averages (E[χ²₂] = 2)."""


def running_mean(t_s: np.ndarray, t_values_s: np.ndarray, values: np.ndarray, window_s: float) -> np.ndarray:
    """Mean of the finite ``values`` (k,) stamped ``t_values_s`` (k, non-decreasing) in (t − window_s, t] at each
    of ``t_s`` (m,); NaN where the window holds none.

    >>> running_mean(np.array([1.0, 3.0]), np.array([0.0, 1.0, 2.5]), np.array([2.0, 4.0, 6.0]), 2.0)
    array([3., 6.])
    """
    v = np.asarray(values, float)
    good = np.isfinite(v)
    csum = np.concatenate([[0.0], np.cumsum(np.where(good, v, 0.0))])
    ccnt = np.concatenate([[0], np.cumsum(good)])
    t = np.asarray(t_s, float)
    hi = np.searchsorted(t_values_s, t, side="right")
    lo = np.searchsorted(t_values_s, t - window_s, side="right")
    n = ccnt[hi] - ccnt[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (csum[hi] - csum[lo]) / np.maximum(n, 1), np.nan)


def calibration_inputs(t_s: np.ndarray, cov_m2: np.ndarray, nis_t_s: np.ndarray, nis: np.ndarray,
                       gnss_t_s: np.ndarray | None, gnss_quality: np.ndarray | None,
                       class_proba: np.ndarray | None = None) -> np.ndarray:
    """Input rows of the calibrator, one per track epoch (m, 10) blind or (m, 10 + n_classes) with ``class_proba``.

    t_s : (m,) the track's epochs; cov_m2 : (m, 2, 2) its covariance; nis_t_s, nis : (k,) the filter's
    events and their NIS (NaN where no update); gnss_t_s, gnss_quality : (g,) the GNSS fixes (None: none);
    class_proba : (m, n_classes) at the epochs, or None (the environment-blind form).
    Columns: ln tr P; ln of the running mean NIS over each of :data:`NIS_WINDOWS_S` (ln 2 where empty);
    one-hot of the latest GNSS fix's quality (:data:`QUALITY_COLUMNS`, other, none); class probabilities.
    Tried and left out (held-out share of the default track's NEES in the region, standard split, seed 0;
    0.898 with these columns): the ages of the latest GNSS and acoustic fixes, 0.896; the running mean
    squared innovation over 5 and 15 s and the share of down-weighted updates, 0.891.
    """
    t = np.asarray(t_s, float)
    cols = [_log_trace(cov_m2)]
    for w in NIS_WINDOWS_S:
        r = running_mean(t, np.asarray(nis_t_s, float), nis, w)
        cols.append(np.where(np.isfinite(r), np.log(np.maximum(r, 1e-6)), _LOG_NIS_NONE))
    q = np.full(len(t), -1)
    if gnss_t_s is not None and len(gnss_t_s):
        i = np.searchsorted(np.asarray(gnss_t_s, float), t, side="right") - 1
        fresh = (i >= 0) & (t - np.asarray(gnss_t_s, float)[np.clip(i, 0, None)] <= GNSS_AGE_S)
        q = np.where(fresh, np.asarray(gnss_quality)[np.clip(i, 0, None)], -1)
    known = np.isin(q, QUALITY_COLUMNS)
    cols += [(q == c).astype(float) for c in QUALITY_COLUMNS]
    cols += [((q != -1) & ~known).astype(float), (q == -1).astype(float)]
    X = np.column_stack(cols)
    if class_proba is not None:
        X = np.hstack([X, np.asarray(class_proba, float)])
    return X


def with_covariance(X: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """Calibrator inputs ``X`` (:func:`calibration_inputs`) with the covariance column computed from ``cov_m2``
    (m, 2, 2) instead: the inputs of another track at the same epochs of the same run (a smoothed track's
    whole-walk covariance, :mod:`walks.segment_rts`). A copy."""
    X = np.array(X, float)
    X[:, 0] = _log_trace(cov_m2)
    return X


def _log_trace(cov_m2: np.ndarray) -> np.ndarray:
    """The calibrator's covariance column: ln tr P (m,), P floored at 1e-12 m²."""
    return np.log(np.maximum(np.trace(np.asarray(cov_m2, float), axis1=1, axis2=2), 1e-12))


@dataclass(frozen=True)
class CalibrationConfig:
    """Settings of :class:`CovarianceCalibrator`: ``hidden`` units per layer (two tanh layers), ``epochs`` at
    most, ``patience`` epochs without validation gain, ``lr`` (Adam), ``batch`` rows, ``max_rows`` (a seeded
    subsample of at most this many training epochs), ``folds`` (groups held out for the multiplier), ``seed``."""

    hidden: int = 16
    epochs: int = 40
    patience: int = 4
    lr: float = 1e-2
    batch: int = 1024
    max_rows: int = 40_000
    folds: int = 3
    seed: int = 0

    def __post_init__(self):
        for name in ("hidden", "epochs", "patience", "batch", "max_rows", "folds"):
            if getattr(self, name) < 1:
                raise ValueError(f"CalibrationConfig.{name} must be >= 1, got {getattr(self, name)}")
        if not self.lr > 0:
            raise ValueError(f"CalibrationConfig.lr must be > 0, got {self.lr}")


def in_region_share(nees: np.ndarray, prob: float = 0.95) -> float:
    """Share of finite ``nees`` (n,) inside the two-sided ``prob`` χ²₂ region (Bar-Shalom et al. 2001, §5.4)."""
    a = (1.0 - prob) / 2.0
    lo, hi = float(chdtri(2, 1.0 - a)), float(chdtri(2, a))
    v = np.asarray(nees, float)
    v = v[np.isfinite(v)]
    return float(np.mean((v >= lo) & (v <= hi))) if len(v) else float("nan")


class CovarianceCalibrator:
    """Covariance scale per epoch from what the filter saw (see the module docstring).

    ``fit(X, nees, groups)`` on training epochs; ``scale(X)`` (m,) the multiplier of the reported covariance.
    Fitted: ``x_mean_``, ``x_scale_``, ``weights_`` (w1 b1 w2 b2 w3 b3), ``multiplier_``, ``log_range_`` (the
    training ln ε range the prediction is clipped to), ``oof_share_`` (out-of-fold share in the region at the
    chosen multiplier) and ``oof_share_raw_`` (the same with the raw covariance).
    """

    def __init__(self, config: CalibrationConfig = CalibrationConfig()):
        self.config = config

    def fit(self, X: np.ndarray, nees: np.ndarray, groups: np.ndarray) -> "CovarianceCalibrator":
        """X (n, d) inputs, nees (n,) their NEES against truth, groups (n,) the walk or site of each epoch
        (whole groups are held out, both for early stopping and for the multiplier)."""
        X, y, g = self._rows(X, nees, groups)
        self.x_mean_ = X.mean(axis=0)
        sd = X.std(axis=0)
        self.x_scale_ = np.where(sd > 1e-9, sd, 1.0)
        ln = np.log(y)
        self.log_range_ = (float(ln.min()), float(ln.max()))
        groups_u = np.unique(g)
        k = min(self.config.folds, len(groups_u))
        oof = np.full(len(y), np.nan)
        if k >= 2:
            fold = {u: i % k for i, u in enumerate(groups_u)}
            f = np.array([fold[u] for u in g])
            for i in range(k):
                w = self._train(X[f != i], ln[f != i], g[f != i])
                oof[f == i] = self._forward(w, X[f == i])
        self.weights_ = self._train(X, ln, g)
        grid = np.exp(np.linspace(-1.5, 3.0, 91))
        if np.all(np.isfinite(oof)):
            s_hat = np.exp(np.clip(oof, *self.log_range_) - E_LOG_CHI2_2)
            shares = [in_region_share(y / (s_hat * m)) for m in grid]
            self.multiplier_ = float(grid[int(np.argmax(shares))])
            self.oof_share_ = float(max(shares))
        else:                       # one group only: no held-out predictions to choose m from
            self.multiplier_, self.oof_share_ = 1.0, float("nan")
        self.oof_share_raw_ = in_region_share(y)
        return self

    def _rows(self, X, nees, groups):
        X = np.asarray(X, float)
        y = np.asarray(nees, float)
        g = np.asarray(groups)
        if X.ndim != 2 or len(X) != len(y) or len(g) != len(y):
            raise DataError(f"calibration: X {X.shape}, nees {y.shape} and groups {g.shape} do not match")
        ok = np.isfinite(y) & (y > 0) & np.all(np.isfinite(X), axis=1)
        if ok.sum() < 50:
            raise DataError(f"calibration needs at least 50 epochs with a finite NEES, got {int(ok.sum())}")
        X, y, g = X[ok], y[ok], g[ok]
        if len(y) > self.config.max_rows:
            keep = np.sort(np.random.default_rng(self.config.seed).choice(len(y), self.config.max_rows, replace=False))
            X, y, g = X[keep], y[keep], g[keep]
        return X, y, g

    def _train(self, X: np.ndarray, ln: np.ndarray, g: np.ndarray) -> dict:
        """Least-squares fit of ln ε on the standardised inputs; the last ~20 % of groups validate."""
        import torch

        cfg = self.config
        torch.set_num_threads(1)
        torch.manual_seed(cfg.seed)
        gen = torch.Generator().manual_seed(cfg.seed)
        groups_u = np.unique(g)
        n_val = max(1, round(0.2 * len(groups_u))) if len(groups_u) > 1 else 0
        val = np.isin(g, groups_u[len(groups_u) - n_val:]) if n_val else np.ones(len(g), bool)
        trn = ~val if n_val else val
        Z = torch.as_tensor((X - self.x_mean_) / self.x_scale_, dtype=torch.float32)
        Y = torch.as_tensor(ln, dtype=torch.float32)
        h = cfg.hidden
        net = torch.nn.Sequential(torch.nn.Linear(X.shape[1], h), torch.nn.Tanh(), torch.nn.Linear(h, h),
                                  torch.nn.Tanh(), torch.nn.Linear(h, 1))
        with torch.no_grad():
            net[4].bias.fill_(float(np.mean(ln)))
        opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
        it = torch.as_tensor(np.flatnonzero(trn))
        iv = torch.as_tensor(np.flatnonzero(val))
        best, best_state, waited = math.inf, None, 0
        for _ in range(cfg.epochs):
            perm = it[torch.randperm(len(it), generator=gen)]
            for b in range(0, len(perm), cfg.batch):
                rows = perm[b:b + cfg.batch]
                opt.zero_grad()
                loss = ((net(Z[rows])[:, 0] - Y[rows]) ** 2).mean()
                loss.backward()
                opt.step()
            with torch.no_grad():
                v = float(((net(Z[iv])[:, 0] - Y[iv]) ** 2).mean())
            if v < best - 1e-5:
                best, waited = v, 0
                best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
            else:
                waited += 1
                if waited >= cfg.patience:
                    break
        sd = best_state
        return {"w1": sd["0.weight"].numpy().astype(float), "b1": sd["0.bias"].numpy().astype(float),
                "w2": sd["2.weight"].numpy().astype(float), "b2": sd["2.bias"].numpy().astype(float),
                "w3": sd["4.weight"].numpy().astype(float), "b3": sd["4.bias"].numpy().astype(float)}

    def _forward(self, w: dict, X: np.ndarray) -> np.ndarray:
        """The network's E[ln ε | X] (m,)."""
        z = (np.asarray(X, float) - self.x_mean_) / self.x_scale_
        h1 = np.tanh(z @ w["w1"].T + w["b1"])
        h2 = np.tanh(h1 @ w["w2"].T + w["b2"])
        return (h2 @ w["w3"].T + w["b3"])[:, 0]

    def scale(self, X: np.ndarray) -> np.ndarray:
        """The covariance multiplier s = m·exp(E[ln ε | X] − E[ln χ²₂]) per row (m,); rows with a non-finite
        input get the multiplier of their finite part's mean input (m·exp(b) at the standardised origin)."""
        X = np.asarray(X, float)
        if X.ndim != 2 or X.shape[1] != self.x_mean_.shape[0]:
            raise DataError(f"calibration inputs have shape {X.shape}, the calibrator takes (m, {self.x_mean_.shape[0]})")
        Xf = np.where(np.isfinite(X), X, self.x_mean_)
        ln = np.clip(self._forward(self.weights_, Xf), *self.log_range_)
        return self.multiplier_ * np.exp(ln - E_LOG_CHI2_2)

    # -- state -----------------------------------------------------------------------------------

    def get_state(self) -> tuple[dict, dict]:
        params = {"config": dict(self.config.__dict__), "multiplier": self.multiplier_,
                  "log_range": list(self.log_range_), "oof_share": self.oof_share_,
                  "oof_share_raw": self.oof_share_raw_, "n_inputs": int(self.x_mean_.shape[0])}
        return params, {"x_mean": self.x_mean_, "x_scale": self.x_scale_, **self.weights_}

    @classmethod
    def from_state(cls, params: dict, arrays: dict) -> "CovarianceCalibrator":
        self = cls(CalibrationConfig(**params["config"]))
        self.multiplier_ = float(params["multiplier"])
        self.log_range_ = tuple(float(v) for v in params["log_range"])
        self.oof_share_, self.oof_share_raw_ = float(params["oof_share"]), float(params["oof_share_raw"])
        self.x_mean_, self.x_scale_ = np.asarray(arrays["x_mean"], float), np.asarray(arrays["x_scale"], float)
        self.weights_ = {k: np.asarray(arrays[k], float) for k in ("w1", "b1", "w2", "b2", "w3", "b3")}
        d, h = int(params["n_inputs"]), self.config.hidden
        shapes = {"w1": (h, d), "b1": (h,), "w2": (h, h), "b2": (h,), "w3": (1, h), "b3": (1,)}
        if (self.x_mean_.shape != (d,) or self.x_scale_.shape != (d,)
                or any(self.weights_[k].shape != s for k, s in shapes.items())
                or not all(np.all(np.isfinite(a)) for a in self.weights_.values())
                or not np.all(self.x_scale_ > 0) or not (self.multiplier_ > 0 and math.isfinite(self.multiplier_))
                or not self.log_range_[0] <= self.log_range_[1]):
            raise ValueError("covariance calibrator: weights of the wrong shape, or values not finite")
        return self
