"""The BP corrector: a small back-propagation network that corrects the fusion filter's position.

After Xue, Han & Wang (2023, §3.3): a 3-layer BP network (input, one hidden
layer, output; hidden size 8 by default) takes the environment class and the
Kalman filter's own state of mind — gain, innovation, update step — and
outputs a position correction added to the filter's output. Here, per event
of a filter run, its inputs are (:func:`bp_inputs`):

- class probabilities (3; one-hot when the class is hard);
- of the latest update at or before the event: the position block of the gain
  K (4), the innovation ν (2, m), the update step posterior − prior (2, m),
  log(1 + NIS), its source (GNSS / acoustic one-hot, 2), whether the fix was
  accepted, and the time since it (s);
- availability: whether a GNSS and an acoustic fix arrived in the last 2 s (2).

Uncertainty. Each network has a variance head (mean and log-variance of the
correction, trained on the Gaussian negative log-likelihood; Nix & Weigend
1994) and an ensemble of them is trained from different seeds
(Lakshminarayanan et al. 2017): the correction is the ensemble mean, its
variance the mean variance plus the spread of the means.

Guards (:meth:`BPCorrector.correct`):

1. out of distribution — an input farther from the training inputs than the
   ``ood_quantile`` of their own (standardised) norms gets no correction;
2. significance — a correction smaller than its own standard deviation
   (|c|² < tr Var c) is not applied;
3. innovations — the next fix is independent evidence the network has not seen:
   over the last ``guard_window`` updates, the mean NIS of each fix against the
   corrected prior is compared with that against the uncorrected prior; while
   the corrected one is larger, the correction is switched off (it is
   hurting), and back on when it is not.

Training uses torch (seeded; early stopping on a validation split of *walks*,
never of samples); prediction uses the learnt weights in numpy (a few
microseconds per event, no torch call). Weights are saved as plain arrays
(safetensors, :mod:`models.bundle`), never pickle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from features.errors import DataError

__all__ = ["BPConfig", "BPCorrector", "bp_inputs", "N_INPUTS", "Correction"]

N_CLASSES = 3
N_INPUTS = N_CLASSES + 4 + 2 + 2 + 1 + 2 + 1 + 1 + 2
"""Width of an input row (see the module docstring)."""

GNSS_KIND, ACOUSTIC_KIND = 1, 2
"""Event kinds of a filter run (``models.fusion.events``: 0 step, 1 GNSS, 2 acoustic)."""


def bp_inputs(t_s, kind, updated, accepted, K, nu, dx, nis, class_proba, recent_s: float = 2.0) -> np.ndarray:
    """Input rows of the BP network, one per event, shape (m, N_INPUTS).

    Parameters
    ----------
    t_s, kind, updated, accepted, nis : ndarray of shape (m,)
    K : ndarray of shape (m, n_state, 2)  (gain; NaN where no update)
    nu, dx : ndarray of shape (m, 2)      (innovation; posterior − prior position)
    class_proba : ndarray of shape (m, 3)
    """
    t_s = np.asarray(t_s, float)
    m = t_s.shape[0]
    out = np.zeros((m, N_INPUTS))
    out[:, :N_CLASSES] = class_proba
    upd = np.flatnonzero(np.asarray(updated, bool))
    # Index of the latest update at or before each event (−1 before the first).
    last = np.full(m, -1)
    last[upd] = upd
    last = np.maximum.accumulate(last)
    have = last >= 0
    j = last[have]
    c = N_CLASSES
    out[have, c:c + 4] = np.asarray(K)[j, :2, :].reshape(-1, 4)
    out[have, c + 4:c + 6] = np.asarray(nu)[j]
    out[have, c + 6:c + 8] = np.asarray(dx)[j, :2]
    out[have, c + 8] = np.log1p(np.asarray(nis)[j])
    kind = np.asarray(kind)
    out[have, c + 9] = kind[j] == GNSS_KIND
    out[have, c + 10] = kind[j] == ACOUSTIC_KIND
    out[have, c + 11] = np.asarray(accepted, bool)[j]
    out[:, c + 12] = np.where(have, t_s - np.where(have, t_s[np.maximum(last, 0)], 0.0), recent_s * 10)
    for col, k in ((c + 13, GNSS_KIND), (c + 14, ACOUSTIC_KIND)):
        tk = t_s[np.asarray(updated, bool) & (kind == k)]
        idx = np.searchsorted(tk, t_s, side="right") - 1
        prev = np.where(idx >= 0, tk[np.maximum(idx, 0)] if tk.size else 0.0, -np.inf)
        out[:, col] = (t_s - prev) <= recent_s
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


@dataclass(frozen=True)
class BPConfig:
    """Training settings: ``hidden`` units (the source method uses 8), ``n_members`` of the ensemble,
    ``epochs`` at most, ``patience`` epochs without validation gain before stopping, ``lr``,
    ``weight_decay``, ``batch``, ``seed``; guard settings ``ood_quantile``, ``guard_window``."""

    hidden: int = 8
    n_members: int = 5
    epochs: int = 300
    patience: int = 20
    lr: float = 3e-3
    weight_decay: float = 1e-4
    batch: int = 256
    seed: int = 0
    ood_quantile: float = 0.995
    guard_window: int = 10

    def __post_init__(self):
        for name in ("hidden", "n_members", "epochs", "patience", "batch", "guard_window"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"BPConfig.{name} must be a positive integer, got {v!r}")
        if not 0.5 <= self.ood_quantile < 1:
            raise ValueError(f"BPConfig.ood_quantile must lie in [0.5, 1), got {self.ood_quantile!r}")
        if not (self.lr > 0 and self.weight_decay >= 0):
            raise ValueError("BPConfig.lr must be > 0 and weight_decay >= 0")


@dataclass(frozen=True)
class Correction:
    """Per event: ``delta_m`` (m, 2) the correction applied (zero where a guard said no),
    ``raw_m`` (m, 2) the network's, ``var_m2`` (m, 2) its variance, and the guard flags
    ``ood``, ``insignificant``, ``innovation_off`` (m,)."""

    delta_m: np.ndarray
    raw_m: np.ndarray
    var_m2: np.ndarray
    ood: np.ndarray
    insignificant: np.ndarray
    innovation_off: np.ndarray

    @property
    def disabled_share(self) -> float:
        """Share of events where some guard withheld the correction."""
        off = self.ood | self.insignificant | self.innovation_off
        return float(off.mean()) if off.size else 0.0


class BPCorrector:
    """An ensemble of 3-layer BP networks with variance heads, and the guards around them."""

    def __init__(self, config: BPConfig = BPConfig()):
        self.config = config

    # -- training --------------------------------------------------------------------------------

    def fit(self, X_walks: list, Y_walks: list, progress=None) -> "BPCorrector":
        """Fit on per-walk inputs (list of (m_i, N_INPUTS)) and targets (list of (m_i, 2): truth −
        filter position); the last ~20 % of walks (at least one) are the validation split."""
        import torch

        cfg = self.config
        if len(X_walks) != len(Y_walks) or not X_walks:
            raise ValueError("need the same positive number of input and target walks")
        n_val = max(1, round(0.2 * len(X_walks))) if len(X_walks) > 1 else 0
        X_tr = np.vstack(X_walks[: len(X_walks) - n_val])
        Y_tr = np.vstack(Y_walks[: len(Y_walks) - n_val])
        X_va = np.vstack(X_walks[len(X_walks) - n_val:]) if n_val else X_tr
        Y_va = np.vstack(Y_walks[len(Y_walks) - n_val:]) if n_val else Y_tr
        if X_tr.shape[1] != N_INPUTS or Y_tr.shape[1] != 2:
            raise ValueError(f"inputs must have {N_INPUTS} columns and targets 2, got {X_tr.shape}, {Y_tr.shape}")
        ok = np.isfinite(Y_tr).all(axis=1)
        X_tr, Y_tr = X_tr[ok], Y_tr[ok]
        okv = np.isfinite(Y_va).all(axis=1)
        X_va, Y_va = X_va[okv], Y_va[okv]
        if len(X_tr) < 20:
            raise DataError(f"too few training events for the BP network ({len(X_tr)}; need at least 20)")
        self.x_mean_ = X_tr.mean(axis=0)
        self.x_scale_ = np.where(X_tr.std(axis=0) > 1e-9, X_tr.std(axis=0), 1.0)
        self.y_scale_ = float(max(np.sqrt(np.mean(Y_tr ** 2)), 1e-3))
        z_tr = (X_tr - self.x_mean_) / self.x_scale_
        z_va = (X_va - self.x_mean_) / self.x_scale_
        norms = np.sqrt(np.mean(z_tr ** 2, axis=1))
        self.ood_threshold_ = float(np.quantile(norms, cfg.ood_quantile))
        torch.set_num_threads(1)
        xt = torch.as_tensor(z_tr, dtype=torch.float32)
        yt = torch.as_tensor(Y_tr / self.y_scale_, dtype=torch.float32)
        xv = torch.as_tensor(z_va, dtype=torch.float32)
        yv = torch.as_tensor(Y_va / self.y_scale_, dtype=torch.float32)
        self.members_ = []
        self.history_ = []
        for k in range(cfg.n_members):
            weights, hist = _train_member(xt, yt, xv, yv, cfg, seed=cfg.seed * 1000 + k)
            self.members_.append(weights)
            self.history_.append(hist)
            if progress is not None:
                progress(k + 1, cfg.n_members)
        return self

    # -- prediction ------------------------------------------------------------------------------

    def predict(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ensemble mean correction (m, 2) and its variance (m, 2), m."""
        z = (np.asarray(X, float) - self.x_mean_) / self.x_scale_
        means, variances = [], []
        for w in self.members_:
            h = np.tanh(z @ w["w1"].T + w["b1"])
            o = h @ w["w2"].T + w["b2"]
            means.append(o[:, :2])
            variances.append(np.exp(np.clip(o[:, 2:], -20.0, 10.0)))
        mu = np.mean(means, axis=0)
        var = np.mean(variances, axis=0) + np.var(means, axis=0)
        return mu * self.y_scale_, var * self.y_scale_ ** 2

    def is_ood(self, X: np.ndarray) -> np.ndarray:
        z = (np.asarray(X, float) - self.x_mean_) / self.x_scale_
        return np.sqrt(np.mean(z ** 2, axis=1)) > self.ood_threshold_

    def correct(self, X: np.ndarray, prior_en: np.ndarray, z_en: np.ndarray, S: np.ndarray,
                updated: np.ndarray) -> Correction:
        """Guarded corrections for the events of one run (see the module docstring).

        ``prior_en`` (m, 2) prior positions, ``z_en`` (m, 2) the fixes, ``S`` (m, 2, 2) innovation
        covariances, ``updated`` (m,) where a fix was processed — for the innovation guard.
        """
        raw, var = self.predict(X)
        ood = self.is_ood(X)
        insignificant = np.sum(raw ** 2, axis=1) < np.sum(var, axis=1)
        off = _innovation_off(raw, ood | insignificant, prior_en, z_en, S, updated, self.config.guard_window)
        delta = np.where((ood | insignificant | off)[:, None], 0.0, raw)
        return Correction(delta_m=delta, raw_m=raw, var_m2=var, ood=ood, insignificant=insignificant,
                          innovation_off=off)

    # -- state -----------------------------------------------------------------------------------

    def get_state(self) -> tuple[dict, dict]:
        """(JSON parameters, flat arrays) for :func:`models.bundle.save_bundle`."""
        params = {"config": self.config.__dict__ | {}, "n_inputs": N_INPUTS, "n_members": len(self.members_),
                  "y_scale": self.y_scale_, "ood_threshold": self.ood_threshold_}
        arrays = {"x_mean": self.x_mean_, "x_scale": self.x_scale_}
        for k, w in enumerate(self.members_):
            for name, a in w.items():
                arrays[f"m{k}.{name}"] = a
        return params, arrays

    @classmethod
    def from_state(cls, params: dict, arrays: dict) -> "BPCorrector":
        if params.get("n_inputs") != N_INPUTS:
            raise ValueError(f"BP network expects {params.get('n_inputs')} inputs, this version builds {N_INPUTS}")
        self = cls(BPConfig(**params["config"]))
        self.y_scale_ = float(params["y_scale"])
        self.ood_threshold_ = float(params["ood_threshold"])
        self.x_mean_, self.x_scale_ = np.asarray(arrays["x_mean"], float), np.asarray(arrays["x_scale"], float)
        h = self.config.hidden
        self.members_ = []
        for k in range(int(params["n_members"])):
            w = {n: np.asarray(arrays[f"m{k}.{n}"], float) for n in ("w1", "b1", "w2", "b2")}
            if w["w1"].shape != (h, N_INPUTS) or w["w2"].shape != (4, h):
                raise ValueError(f"BP member {k}: weight shapes do not match hidden={h}")
            self.members_.append(w)
        return self


def _innovation_off(raw: np.ndarray, withheld: np.ndarray, prior_en: np.ndarray, z_en: np.ndarray, S: np.ndarray,
                    updated: np.ndarray, window: int) -> np.ndarray:
    """The innovation guard (module docstring, guard 3), vectorised: (m,) True where the correction is off.

    At each processed fix the NIS of the fix against the prior, and against the prior moved by the
    correction the previous event would have applied (zero where that one was withheld), are compared as
    means over the last ``window`` fixes; once that window holds three fixes, the guard is off while the corrected mean
    is the larger, and holds its state between fixes.
    """
    m = len(raw)
    applied_prev = np.zeros((m, 2))
    applied_prev[1:] = np.where(withheld[:-1, None], 0.0, raw[:-1])
    use = np.asarray(updated, bool) & np.all(np.isfinite(S), axis=(1, 2)) & np.all(np.isfinite(z_en), axis=1)
    k = np.flatnonzero(use)
    off = np.zeros(m, bool)
    if k.size == 0:
        return off
    s_inv = np.linalg.inv(S[k])
    v0 = z_en[k] - prior_en[k]
    v1 = v0 - applied_prev[k]
    # NIS = ν' S⁻¹ ν, uncorrected and corrected
    n0 = np.einsum("ni,nij,nj->n", v0, s_inv, v0)
    n1 = np.einsum("ni,nij,nj->n", v1, s_inv, v1)
    # equal window lengths: comparing the means is the sign of Σ (NIS₁ − NIS₀) over the window. Summed as
    # differences, a window where no correction was applied sums to exactly 0 (enabled, as the loop's equal
    # means say); differences of running sums of each would leave rounding residue there and flip the guard.
    d = np.concatenate([np.zeros(window - 1), n1 - n0])
    win = np.lib.stride_tricks.sliding_window_view(d, window).sum(axis=1)
    j = np.arange(1, k.size + 1)
    disabled = (win > 0.0) & (np.minimum(j, window) >= 3)
    # hold the state of the latest fix at or before each event (enabled before the first)
    idx = np.searchsorted(k, np.arange(m), side="right") - 1
    off[idx >= 0] = disabled[idx[idx >= 0]]
    return off


def _train_member(xt, yt, xv, yv, cfg: BPConfig, seed: int):
    """One network: Linear(N_INPUTS, hidden) → tanh → Linear(hidden, 4) (mean 2, log-variance 2),
    Gaussian NLL, Adam, early stopping on the validation walks' loss."""
    import torch

    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    net = torch.nn.Sequential(torch.nn.Linear(N_INPUTS, cfg.hidden), torch.nn.Tanh(), torch.nn.Linear(cfg.hidden, 4))
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    nll = torch.nn.GaussianNLLLoss(reduction="mean")

    def loss_of(x, y):
        o = net(x)
        return nll(o[:, :2], y, torch.exp(o[:, 2:].clamp(-20, 10)))

    best, best_state, waited, hist = math.inf, None, 0, []
    n = xt.shape[0]
    for _ in range(cfg.epochs):
        net.train()
        perm = torch.randperm(n, generator=g)
        for a in range(0, n, cfg.batch):
            idx = perm[a:a + cfg.batch]
            opt.zero_grad()
            loss = loss_of(xt[idx], yt[idx])
            loss.backward()
            opt.step()
        net.eval()
        with torch.no_grad():
            v = float(loss_of(xv, yv))
        hist.append(v)
        if v < best - 1e-4:
            best, waited = v, 0
            best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
        else:
            waited += 1
            if waited >= cfg.patience:
                break
    net.load_state_dict(best_state)
    sd = net.state_dict()
    weights = {"w1": sd["0.weight"].numpy().astype(float), "b1": sd["0.bias"].numpy().astype(float),
               "w2": sd["2.weight"].numpy().astype(float), "b2": sd["2.bias"].numpy().astype(float)}
    return weights, hist
