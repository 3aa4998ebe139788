"""The BP network as the seed's abstract reads it: signal environment → the parameters of the Kalman filter.

Xue, Han & Wang (2023), abstract: "the signal environment features are mapped
to the parameters of the Kalman filter". Here a 3-layer BP network (input,
one tanh hidden layer of 8 by default, output) maps, for every fix of a walk,

- the environment: class probabilities (3) and the window's 14 features (NaN → 0, with 2 availability
  flags) — removed in the environment-blind twin;
- the fix: its source (GNSS / acoustic), GGA quality (1, 2, 4, 5, other), log₁₀ of its reported σ;
- the filter's state of mind at that fix in a first pass (the ``adaptive_nobp`` run): log(1 + NIS), the
  innovation's size, the update step's size (posterior − prior) and the position gain's trace;

onto one number, the log-multiplier of the fix's measurement noise R, which a second pass of the same filter
uses (:func:`walks.methods` ``adaptive``). Every input at a fix comes from that fix and earlier events, so the
two passes run online together.

Why R: the class already sets the bias process and the outlier prior of each (class, quality) in the context
error model (:mod:`models.fusion.context`); what a per-event network can add is how much this particular fix
deserves, given what the filter saw at it — and R is the parameter through which a Kalman filter weighs a fix.

Training through the filter (one step): at every fix of the training walks, with the prior (x⁻, P⁻), H and
R the filter actually had there, the posterior position of the Kalman update with s·R,

    x⁺(s) = x⁻ + P⁻H'(HP⁻H' + sR)⁻¹(z − Hx⁻),

is a differentiable function of s; the network is trained (torch, Adam, seeded, early stopping on whole
validation walks) to minimise the mean horizontal error of x⁺ against the truth, with a small penalty on
(ln s)². Because the priors of the second pass differ from the first's, this is done twice: the second
round trains on the priors of a second pass run with the first round's network (the data-aggregation idea of
Ross, Gordon & Bagnell 2011, in its simplest form). Guard: an input farther from the training inputs than the
``ood_quantile`` of their own norms gets s = 1 (the first pass's R).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from features.errors import DataError

__all__ = ["ParamNetConfig", "ParamNet", "parameter_inputs", "N_CLASSES", "N_WINDOW"]

N_CLASSES = 3
N_WINDOW = 14 + 2
"""Window features and the two availability flags."""

QUALITIES = (1, 2, 4, 5)
"""GGA qualities with their own one-hot input (any other: the 'other' input)."""

LOG_S_LIMIT = 3.0
"""|ln s| at most: R is changed by a factor e³ ≈ 20 at the most."""


def parameter_inputs(kind, quality, cov_m2, nis, nu, dx, K, class_proba=None, window=None) -> np.ndarray:
    """Input rows of the network, one per event (m, d); rows of steps are zero (the network acts on fixes).

    kind, quality, nis : (m,); cov_m2 : (m, 2, 2) reported covariance; nu, dx : (m, 2) the first pass's
    innovation and update step; K : (m, n, 2) its gain; class_proba : (m, 3) or None (blind);
    window : (m, 16) the window features in force with the availability flags, or None (blind).
    """
    kind = np.asarray(kind)
    m = kind.shape[0]
    fix = kind != 0
    cols = []
    if class_proba is not None:
        cols.append(np.asarray(class_proba, float))
    cols.append(np.column_stack([kind == 1, kind == 2]).astype(float))
    q = np.asarray(quality)
    cols.append(np.column_stack([(q == v) & (kind == 1) for v in QUALITIES]
                                + [(~np.isin(q, QUALITIES)) & (kind == 1)]).astype(float))
    tr = np.nan_to_num(np.trace(np.asarray(cov_m2, float), axis1=1, axis2=2), nan=1.0)
    cols.append(np.log10(np.sqrt(np.maximum(tr / 2.0, 1e-12)))[:, None])
    kpos = np.nan_to_num(np.asarray(K, float)[:, 0, 0] + np.asarray(K, float)[:, 1, 1])
    cols.append(np.column_stack([np.log1p(np.nan_to_num(np.asarray(nis, float))),
                                 np.log1p(np.hypot(*np.nan_to_num(np.asarray(nu, float)).T)),
                                 np.log1p(np.hypot(*np.nan_to_num(np.asarray(dx, float))[:, :2].T)), kpos]))
    if window is not None:
        w = np.asarray(window, float)
        cols.append(np.nan_to_num(w))
    X = np.hstack(cols)
    X[~fix] = 0.0
    return X


@dataclass(frozen=True)
class ParamNetConfig:
    """``hidden`` units (the source method uses 8), ``epochs`` at most, ``patience``, ``lr``,
    ``weight_decay``, ``shrink`` (the penalty weight on (ln s)²), ``rounds`` of training through the filter,
    ``seed``, ``ood_quantile``."""

    hidden: int = 8
    epochs: int = 400
    patience: int = 25
    lr: float = 3e-3
    weight_decay: float = 1e-4
    shrink: float = 0.01
    rounds: int = 2
    seed: int = 0
    ood_quantile: float = 0.995

    def __post_init__(self):
        for name in ("hidden", "epochs", "patience", "rounds"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"ParamNetConfig.{name} must be a positive integer, got {v!r}")
        if not (self.lr > 0 and self.weight_decay >= 0 and self.shrink >= 0 and 0.5 <= self.ood_quantile < 1):
            raise ValueError("ParamNetConfig: lr > 0, weight_decay >= 0, shrink >= 0, ood_quantile in [0.5, 1)")


@dataclass(frozen=True)
class OneStep:
    """One walk's fixes for training through the filter: inputs ``X`` (k, d), priors ``x`` (k, n), ``P``
    (k, n, n), ``H`` (k, 2, n), ``R`` (k, 2, 2), fixes ``z`` (k, 2), truth positions ``truth`` (k, 2)."""

    X: np.ndarray
    x: np.ndarray
    P: np.ndarray
    H: np.ndarray
    R: np.ndarray
    z: np.ndarray
    truth: np.ndarray


class ParamNet:
    """The BP network that sets each fix's R multiplier (see the module docstring)."""

    def __init__(self, config: ParamNetConfig = ParamNetConfig()):
        self.config = config

    # -- training --------------------------------------------------------------------------------

    def fit_round(self, walks: list[OneStep], warm: bool = False) -> "ParamNet":
        """One round of training on the walks' fixes (the last ~20 % of walks, at least one, validate)."""
        import torch

        cfg = self.config
        if not walks:
            raise DataError("no training walks with fixes for the BP parameter network")
        n_val = max(1, round(0.2 * len(walks))) if len(walks) > 1 else 0
        tr, va = walks[: len(walks) - n_val], (walks[len(walks) - n_val:] if n_val else walks)
        Xtr = np.vstack([w.X for w in tr])
        if not warm:
            self.x_mean_ = Xtr.mean(axis=0)
            self.x_scale_ = np.where(Xtr.std(axis=0) > 1e-9, Xtr.std(axis=0), 1.0)
            z = (Xtr - self.x_mean_) / self.x_scale_
            self.ood_threshold_ = float(np.quantile(np.sqrt(np.mean(z ** 2, axis=1)), cfg.ood_quantile))
        torch.set_num_threads(1)
        g = torch.Generator().manual_seed(cfg.seed)
        torch.manual_seed(cfg.seed)
        d = Xtr.shape[1]
        net = torch.nn.Sequential(torch.nn.Linear(d, cfg.hidden), torch.nn.Tanh(), torch.nn.Linear(cfg.hidden, 1))
        if warm:
            with torch.no_grad():
                for p, key in zip(net.parameters(), ("w1", "b1", "w2", "b2")):
                    p.copy_(torch.as_tensor(self.weights_[key], dtype=torch.float64).to(p.dtype))
        else:
            with torch.no_grad():                               # start at s = 1 everywhere
                net[2].weight.mul_(0.01)
                net[2].bias.zero_()
        net = net.double()
        batches = [self._tensors(w) for w in tr]
        val = [self._tensors(w) for w in va]
        opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        best, best_state, waited = math.inf, None, 0
        for _ in range(cfg.epochs):
            net.train()
            for i in torch.randperm(len(batches), generator=g).tolist():
                opt.zero_grad()
                loss = _loss(net, batches[i], cfg.shrink)
                loss.backward()
                opt.step()
            net.eval()
            with torch.no_grad():
                v = float(sum(_loss(net, b, 0.0) * b[0].shape[0] for b in val) / sum(b[0].shape[0] for b in val))
            if v < best - 1e-6:
                best, waited = v, 0
                best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
            else:
                waited += 1
                if waited >= cfg.patience:
                    break
        net.load_state_dict(best_state)
        sd = net.state_dict()
        self.weights_ = {"w1": sd["0.weight"].numpy().astype(float), "b1": sd["0.bias"].numpy().astype(float),
                         "w2": sd["2.weight"].numpy().astype(float), "b2": sd["2.bias"].numpy().astype(float)}
        self.validation_error_m_ = best
        return self

    def _tensors(self, w: OneStep):
        import torch

        z = (w.X - self.x_mean_) / self.x_scale_
        return tuple(torch.as_tensor(a, dtype=torch.float64) for a in (z, w.x, w.P, w.H, w.R, w.z, w.truth))

    # -- prediction ------------------------------------------------------------------------------

    def log_scale(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ln s per row (m,), guarded (m,) bool: out of the training inputs' range, s set to 1)."""
        z = (np.asarray(X, float) - self.x_mean_) / self.x_scale_
        w = self.weights_
        out = (np.tanh(z @ w["w1"].T + w["b1"]) @ w["w2"].T + w["b2"])[:, 0]
        out = LOG_S_LIMIT * np.tanh(out / LOG_S_LIMIT)
        ood = np.sqrt(np.mean(z ** 2, axis=1)) > self.ood_threshold_
        return np.where(ood, 0.0, out), ood

    # -- state -----------------------------------------------------------------------------------

    def get_state(self) -> tuple[dict, dict]:
        params = {"config": dict(self.config.__dict__), "ood_threshold": self.ood_threshold_,
                  "n_inputs": int(self.x_mean_.shape[0])}
        return params, {"x_mean": self.x_mean_, "x_scale": self.x_scale_, **self.weights_}

    @classmethod
    def from_state(cls, params: dict, arrays: dict) -> "ParamNet":
        self = cls(ParamNetConfig(**params["config"]))
        self.ood_threshold_ = float(params["ood_threshold"])
        self.x_mean_, self.x_scale_ = np.asarray(arrays["x_mean"], float), np.asarray(arrays["x_scale"], float)
        self.weights_ = {k: np.asarray(arrays[k], float) for k in ("w1", "b1", "w2", "b2")}
        d, h = int(params["n_inputs"]), self.config.hidden
        if (self.x_mean_.shape != (d,) or self.weights_["w1"].shape != (h, d) or self.weights_["w2"].shape != (1, h)
                or not all(np.all(np.isfinite(a)) for a in self.weights_.values())
                or not np.all(self.x_scale_ > 0)):
            raise ValueError("BP parameter network: weights of the wrong shape or not finite")
        return self


def _loss(net, batch, shrink: float):
    """Mean horizontal error of the one-step posterior x⁺(s) + shrink·mean (ln s)²."""
    import torch

    z, x, P, H, R, zz, truth = batch
    log_s = LOG_S_LIMIT * torch.tanh(net(z)[:, 0] / LOG_S_LIMIT)
    s = torch.exp(log_s)
    PHt = P @ H.transpose(1, 2)
    # S = H P⁻ H' + s R
    S = H @ PHt + s[:, None, None] * R
    # x⁺ = x⁻ + P⁻H' S⁻¹ (z − H x⁻)
    nu = zz - (H @ x[:, :, None])[:, :, 0]
    xp = x + (PHt @ torch.linalg.solve(S, nu[:, :, None]))[:, :, 0]
    err = torch.sqrt(torch.sum((xp[:, :2] - truth) ** 2, dim=1) + 1e-8)
    return err.mean() + shrink * torch.mean(log_s ** 2)
