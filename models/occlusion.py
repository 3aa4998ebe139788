"""Continuous occlusion estimate: a window's features → its blocked-sky share in [0, 1].

Model. Fractional logit (Papke & Wooldridge, "Econometric methods for fractional response variables with an
application to 401(k) plan participation rates", J. Appl. Econometrics 11(6), 1996): the share s ∈ [0, 1] has
conditional mean E[s | x] = σ(f(x)), σ the logistic function, and f is fitted by the Bernoulli
quasi-likelihood

    L(f) = −Σ_i [ s_i ln σ(f(x_i)) + (1 − s_i) ln(1 − σ(f(x_i))) ] + (α / 2) Σ ‖W‖²,

which is consistent for the conditional mean whatever the distribution of s (Papke & Wooldridge 1996, §3),
so the many cells with a share of exactly 0 need no special case. Beta regression (Ferrari & Cribari-Neto,
"Beta regression for modelling rates and proportions", J. Appl. Stat. 31(7), 2004) models the same mean with
a beta likelihood, but a beta density is 0 or ∞ at s = 0 and 13 % of the survey cells of the standard split are
exactly open sky (s = 0): they would have to be squeezed into (0, 1) first (Smithson & Verkuilen 2006) — the
quasi-likelihood needs no such step. The output lies in (0, 1) by construction: no clipping.

``f`` is either linear in the inputs (``hidden=()``: the generalised linear model, a logistic regression on a
fractional target) or a small tanh network (``hidden=(h, ...)``: one or more hidden layers). The L2 penalty
weighs the weight matrices, not the biases, as scikit-learn's logistic regression does (C = 1/α). Fitted by
full-batch L-BFGS (torch, float64, strong-Wolfe line search; Nocedal & Wright, *Numerical Optimization*,
2006, §7.2): deterministic for a given ``random_state`` (which draws the initial weights), and for
``hidden=()`` it reaches the convex optimum that scikit-learn's ``LogisticRegression`` finds for the same
objective written as weighted rows (a row with target s is a positive row of weight s and a negative row of
weight 1 − s) — the test's independent reference.

Prediction is numpy alone (a few small matrix products); the learnt state is the standardisation and the
weight arrays, saved without pickle (:meth:`OcclusionRegressor.get_state`).

Chosen (issue 27 item 5) by leave-one-site-out over the standard split's six *training* sites only (fitted on
five sites' survey windows, 10 m cells / 10 s captures; residual SD per window, points of share, in / out of the
±3-point band around 10 % and 40 %): the ridge the classifier had (degree-2 inputs, clipped) 6.60 / 5.30; the
ridge followed by isotonic calibration on out-of-site predictions 6.53 / 5.14; this model linear 8.00 / 5.54,
on degree-2 inputs (α = 10) 6.55 / 5.33; one tanh layer of 8, α = 1, single initialisations 6.13-6.76 /
4.70-4.81 (seed 0, 1, 2), their five-member average 6.47 / 4.64 (6.30 / 4.56 stopped at 100 L-BFGS iterations:
the default); α = 3: 6.60 / 4.59; 16 units,
α = 3: 6.52 / 4.58; a second layer or 32 units did not help (6.58 / 4.63); the classifier's class
log-probabilities beside the features made it worse (6.53 / 5.01; alone 8.03 / 6.26): fitted on the same
training windows, they are surer there than on a new site. Out of band the net gains 0.7 points
on the ridge; in the band, where the classes are decided, nothing tried gains more than 0.1-0.2: the error
there is the cell's (5.3 points between cells of one site, 3.4 between sites, 2.0 between the windows of one
capture), and ``bench/env_occlusion.py`` shows why no model of these features closes it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["OcclusionRegressor"]


def _sigmoid(x: np.ndarray) -> np.ndarray:
    """Logistic function σ(x) = 1 / (1 + e^(−x)), written to stay finite for large |x|."""
    out = np.empty_like(x, dtype=float)
    pos = x >= 0
    out[pos] = 1.0 / (1.0 + np.exp(-x[pos]))
    e = np.exp(x[~pos])
    out[~pos] = e / (1.0 + e)
    return out


class OcclusionRegressor:
    """Fractional-logit regression of a share in [0, 1], linear or through a small tanh network.

    Parameters
    ----------
    hidden : tuple of int
        Hidden-layer widths; ``()`` for the linear (GLM) form.
    alpha : float
        L2 penalty on the weight matrices (α in the module docstring; scikit-learn's C = 1/α).
    max_iter : int
        L-BFGS iterations at most. A network rarely converges in 100 (the linear form does, in a few dozen); stopping
        there costs nothing held out (leave-one-site-out on the training sites, 5 members: 6.30 / 4.56 points in /
        out of the band at 100 iterations, 6.40 / 4.63 at 200, 6.45 / 4.64 at 400) and a fourth of the time
        (0.14 s a member on six sites' 5,500 windows).
    n_members : int
        Networks fitted from different initial weights whose estimates are averaged (an ensemble over
        initialisations, Lakshminarayanan, Pritzel & Blundell, NeurIPS 2017, without their adversarial
        term): the penalised objective of a network has several minima, and on held-out sites one
        initialisation's residual SD varied by 0.6 points in the band. The linear form is convex: one member.
    random_state : int
        Seed of the initial weights (one ``torch.Generator`` draws every member's); the fit is otherwise
        deterministic.

    Attributes
    ----------
    mean_, scale_ : ndarray of shape (n_inputs,)
        Standardisation of the inputs (a constant input gets scale 1).
    weights_ : list of ndarray
        ``[W0, b0, W1, b1, ...]`` with a leading member axis: ``Wk`` of shape (n_members, out, in), ``bk`` of
        shape (n_members, out); layer k maps its input by ``h @ Wk[m].T + bk[m]``; the last layer has one output.
    n_iter_ : list of int
        L-BFGS iterations run, per member.
    """

    def __init__(self, *, hidden: tuple = (8,), alpha: float = 1.0, n_members: int = 5, max_iter: int = 100,
                 random_state: int = 0):
        self.hidden = hidden
        self.alpha = alpha
        self.n_members = n_members
        self.max_iter = max_iter
        self.random_state = random_state

    def _validate(self) -> None:
        if not (isinstance(self.hidden, (tuple, list)) and all(isinstance(h, int) and h > 0 for h in self.hidden)):
            raise ValueError(f"hidden must be a tuple of positive integers, got {self.hidden!r}")
        if not (isinstance(self.alpha, (int, float)) and self.alpha >= 0 and np.isfinite(self.alpha)):
            raise ValueError(f"alpha must be a finite number >= 0, got {self.alpha!r}")
        if not (isinstance(self.n_members, int) and self.n_members >= 1):
            raise ValueError(f"n_members must be an integer >= 1, got {self.n_members!r}")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise ValueError(f"max_iter must be an integer >= 1, got {self.max_iter!r}")
        if not isinstance(self.random_state, (int, np.integer)):
            raise ValueError(f"random_state must be an integer, got {self.random_state!r}")

    def fit(self, X, share) -> "OcclusionRegressor":
        """Fit on inputs ``X`` (n, d), all finite, and shares ``share`` (n,) in [0, 1]."""
        import torch

        self._validate()
        X = np.asarray(X, float)
        s = np.asarray(share, float)
        if X.ndim != 2 or len(X) == 0:
            raise ValueError(f"X must have shape (n, d) with n >= 1, got {X.shape}")
        if s.shape != (len(X),):
            raise ValueError(f"share must have shape ({len(X)},), got {s.shape}")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(s))):
            raise ValueError("X and share must be finite")
        if s.min() < 0 or s.max() > 1:
            raise ValueError(f"share must lie in [0, 1], got [{s.min():g}, {s.max():g}]")
        self.mean_ = X.mean(axis=0)
        scale = X.std(axis=0)
        self.scale_ = np.where(scale < 1e-12, 1.0, scale)
        z = torch.as_tensor((X - self.mean_) / self.scale_, dtype=torch.float64)
        y = torch.as_tensor(s, dtype=torch.float64)
        gen = torch.Generator().manual_seed(int(self.random_state))
        m = float(np.clip(s.mean(), 1e-6, 1 - 1e-6))
        members = [self._fit_member(z, y, gen, np.log(m / (1 - m)))
                   for _ in range(self.n_members if self.hidden else 1)]
        self.n_iter_ = [k for _, k in members]
        self.weights_ = [np.stack([w[i] for w, _ in members]) for i in range(len(members[0][0]))]
        if not all(np.all(np.isfinite(w)) for w in self.weights_):
            raise ValueError("the occlusion fit diverged (non-finite weights)")
        return self

    def _fit_member(self, z, y, gen, logit_mean: float) -> tuple[list, int]:
        """One network from initial weights drawn from ``gen``, fitted by L-BFGS: (weights, iterations)."""
        import torch

        widths = [z.shape[1], *self.hidden, 1]
        params = []
        for k in range(len(widths) - 1):
            # Glorot-uniform weights (Glorot & Bengio 2010, eq. 16), zero biases
            lim = np.sqrt(6.0 / (widths[k] + widths[k + 1]))
            w = (torch.rand(widths[k + 1], widths[k], generator=gen, dtype=torch.float64) * 2 - 1) * lim
            params += [w.requires_grad_(), torch.zeros(widths[k + 1], dtype=torch.float64, requires_grad=True)]
        with torch.no_grad():                          # start the output at the mean share's logit
            params[-1].fill_(logit_mean)
            if self.hidden:
                params[-2].mul_(0.1)
        opt = torch.optim.LBFGS(params, lr=1.0, max_iter=self.max_iter, tolerance_grad=1e-9,
                                tolerance_change=1e-12, history_size=20, line_search_fn="strong_wolfe")
        n = float(len(y))

        def closure():
            opt.zero_grad()
            f = _forward_torch(params, z)
            # Bernoulli quasi-likelihood with a fractional target (Papke & Wooldridge 1996, eq. 3.3)
            nll = torch.nn.functional.binary_cross_entropy_with_logits(f, y, reduction="sum")
            penalty = 0.5 * self.alpha * sum((w ** 2).sum() for w in params[0::2])
            loss = (nll + penalty) / n               # /n: the same optimum, a better-scaled line search
            loss.backward()
            return loss

        opt.step(closure)
        return [p.detach().numpy().copy() for p in params], int(opt.state[opt._params[0]].get("n_iter", 0))

    def _members_logit(self, X) -> np.ndarray:
        """f_m(x) of every member, shape (n_members, n)."""
        X = np.atleast_2d(np.asarray(X, float))
        if X.shape[1] != self.mean_.shape[0]:
            raise ValueError(f"X has {X.shape[1]} columns, the model takes {self.mean_.shape[0]}")
        h = np.broadcast_to((X - self.mean_) / self.scale_, (self.weights_[0].shape[0],) + X.shape)
        w = self.weights_
        for k in range(0, len(w) - 2, 2):
            h = np.tanh(h @ np.swapaxes(w[k], 1, 2) + w[k + 1][:, None, :])
        return (h @ np.swapaxes(w[-2], 1, 2) + w[-1][:, None, :])[:, :, 0]

    def predict(self, X) -> np.ndarray:
        """Estimated share in (0, 1), shape (n,): the members' σ(f_m(x)), averaged."""
        return _sigmoid(self._members_logit(X)).mean(axis=0)

    # -- state (no pickle) -----------------------------------------------------------------------

    def get_state(self) -> tuple[dict, dict]:
        """(JSON-able parameters, flat dict of arrays): ``mean``, ``scale``, ``w0``, ``b0``, ``w1``, ..."""
        params = {"hidden": list(self.hidden), "alpha": self.alpha, "n_members": self.n_members,
                  "max_iter": self.max_iter, "random_state": int(self.random_state)}
        arrays = {"mean": self.mean_, "scale": self.scale_}
        for k in range(len(self.weights_) // 2):
            arrays[f"w{k}"], arrays[f"b{k}"] = self.weights_[2 * k], self.weights_[2 * k + 1]
        return params, arrays

    @classmethod
    def from_arrays(cls, arrays: dict) -> "OcclusionRegressor":
        """Rebuild for prediction from :meth:`get_state`'s arrays alone: the hidden widths are read from the
        weight shapes (the fitting parameters ``alpha``, ``max_iter``, ``random_state`` do not enter prediction
        and are left at their defaults)."""
        n_layers = sum(1 for k in arrays if k.startswith("w") and k[1:].isdigit())
        if n_layers == 0:
            raise ValueError("occlusion model: no weight arrays (w0, ...)")
        hidden = [int(np.shape(arrays[f"w{k}"])[-2]) if f"w{k}" in arrays else -1 for k in range(n_layers - 1)]
        if any(h < 1 for h in hidden):
            raise ValueError("occlusion model: weight arrays are not numbered w0..w{n-1}")
        n_members = int(np.shape(arrays["w0"])[0]) if "w0" in arrays and np.ndim(arrays["w0"]) == 3 else 1
        return cls.from_state({"hidden": hidden, "alpha": 1.0, "n_members": n_members, "max_iter": 100,
                               "random_state": 0}, arrays)

    @classmethod
    def from_state(cls, params: dict, arrays: dict) -> "OcclusionRegressor":
        """Rebuild from :meth:`get_state`'s output; raises ValueError when the arrays do not fit the parameters."""
        self = cls(hidden=tuple(int(h) for h in params["hidden"]), alpha=params["alpha"],
                   n_members=int(params.get("n_members", 1)), max_iter=int(params["max_iter"]),
                   random_state=int(params["random_state"]))
        self._validate()
        self.mean_ = np.asarray(arrays["mean"], float).reshape(-1)
        self.scale_ = np.asarray(arrays["scale"], float).reshape(-1)
        widths = [self.mean_.shape[0], *self.hidden, 1]
        n_m = int(np.shape(arrays.get("w0", np.zeros((0, 0, 0))))[0]) if np.ndim(arrays.get("w0")) == 3 else 0
        self.weights_ = []
        for k in range(len(widths) - 1):
            w = np.asarray(arrays.get(f"w{k}", np.zeros(0)), float)
            b = np.asarray(arrays.get(f"b{k}", np.zeros(0)), float)
            if n_m < 1 or w.shape != (n_m, widths[k + 1], widths[k]) or b.shape != (n_m, widths[k + 1]):
                raise ValueError(f"occlusion layer {k}: weights {w.shape} and bias {b.shape} do not match the "
                                 f"widths {widths}")
            self.weights_ += [w, b]
        if self.scale_.shape != self.mean_.shape or not np.all(self.scale_ > 0):
            raise ValueError("occlusion model: scale must match mean and be positive")
        if not all(np.all(np.isfinite(a)) for a in [self.mean_, self.scale_, *self.weights_]):
            raise ValueError("occlusion model: non-finite values in its arrays")
        return self


def _forward_torch(params: list, z):
    """The network's f(z) (n,) in torch, the same sequence of layers as :meth:`OcclusionRegressor.decision_function`."""
    import torch

    h = z
    for k in range(0, len(params) - 2, 2):
        h = torch.tanh(h @ params[k].T + params[k + 1])
    return (h @ params[-2].T + params[-1])[:, 0]
