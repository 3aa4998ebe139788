"""Fine-tuning a fitted environment classifier on a user's few labelled windows: MAP adaptation.

The default model (trained on many simulated substations) is the prior; a user's own survey — map labels of
all its cells, or a handful of labelled cells — is the evidence. Each sub-model's multinomial logistic
regression (scores ``s = W φ(z) + b`` on the default's standardised inputs ``z`` and their pairwise products
``φ``) is re-fitted by minimising

    J(W, b) = Σ_i ω_i · (−log softmax(s_i)[y_i])  +  (‖W − W₀‖² + ‖b − b₀‖²) / (2σ²)

— the negative log-likelihood of the user's windows (``ω_i``: scikit-learn's "balanced" class weights, as
the default was fitted with) plus a Gaussian prior centred on the default weights ``(W₀, b₀)``. This is
the maximum-a-posteriori adaptation of a maximum-entropy model of Chelba & Acero, "Adaptation of maximum
entropy capitalizer: Little data can help a lot", *Computer Speech & Language* 20(4), 382–399 (2006), §3,
and the L2-SP penalty of Li, Grandvalet & Davoine, "Explicit inductive bias for transfer learning with
convolutional networks", ICML 2018. σ → ∞ is the unpenalised maximum-likelihood fit on the user's windows
alone; σ → 0 keeps the default weights. The default's standardisation (mean, scale) is kept, so the prior
speaks about the same inputs; its OOD Gaussians are kept too (they describe what the weights were learnt on).

The gradient is analytic: ∂J/∂W = Σ_i ω_i (p_i − e_{y_i}) φ_iᵀ + (W − W₀)/σ², ∂J/∂b = Σ_i ω_i (p_i − e_{y_i})
+ (b − b₀)/σ² (Bishop, *Pattern Recognition and Machine Learning*, 2006, eq. 4.109); J is convex, minimised by
L-BFGS-B (:func:`scipy.optimize.minimize`) from the default weights.

σ chosen by cross-validation (:func:`choose_sigma`): folds of whole cells (a cell's windows share their
position and so their errors; window-wise folds would leak), the σ of the grid with the smallest mean held-out
weighted log-loss. With fewer than two labelled cells the grid's middle is taken.
"""

from __future__ import annotations

import copy

import numpy as np
from scipy.optimize import minimize
from scipy.special import log_softmax, softmax

from models.environment import _COLUMNS, SUBMODELS, EnvironmentClassifier, _expand, availability

__all__ = ["map_objective", "fit_map", "finetune", "choose_sigma", "SIGMA_GRID", "balanced_weights"]

SIGMA_GRID = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
"""σ candidates (in units of the standardised-score weights). The default's own fit (scikit-learn, C = 1) is
a zero-centred prior of σ = 1 on the same summed likelihood, so the grid spans the default unchanged (σ = 0:
the user's cells may say it is best left alone), priors up to 300 times tighter than its own, and 3 times
looser. On the standard split's sites a first grid starting at 0.03 had 0.03 chosen most often (its edge),
hence the tighter values."""


def balanced_weights(y: np.ndarray) -> np.ndarray:
    """scikit-learn's ``class_weight="balanced"`` per sample: n / (n_classes_present · n_c)."""
    y = np.asarray(y, int)
    classes, counts = np.unique(y, return_counts=True)
    w = {c: len(y) / (len(classes) * n) for c, n in zip(classes, counts)}
    return np.array([w[c] for c in y], float)


def map_objective(theta: np.ndarray, Phi: np.ndarray, y: np.ndarray, weight: np.ndarray, theta0: np.ndarray,
                  sigma: float) -> tuple[float, np.ndarray]:
    """J and ∂J/∂θ (see the module docstring); θ = [W (K × d) row-major, b (K)] flattened, Phi (n, d)."""
    K = theta0.size // (Phi.shape[1] + 1)
    d = Phi.shape[1]
    W, b = theta[:K * d].reshape(K, d), theta[K * d:]
    s = Phi @ W.T + b
    logp = log_softmax(s, axis=1)
    nll = -float(np.sum(weight * logp[np.arange(len(y)), y]))
    r = softmax(s, axis=1)
    r[np.arange(len(y)), y] -= 1.0
    r *= weight[:, None]
    dev = theta - theta0
    if np.isinf(sigma):
        prior, gp = 0.0, 0.0
    else:
        prior, gp = float(dev @ dev) / (2 * sigma ** 2), dev / sigma ** 2
    grad = np.concatenate([(r.T @ Phi).ravel(), r.sum(axis=0)]) + gp
    return nll + prior, grad


def fit_map(Phi: np.ndarray, y: np.ndarray, weight: np.ndarray, W0: np.ndarray, b0: np.ndarray,
            sigma: float, max_iter: int = 500) -> tuple[np.ndarray, np.ndarray]:
    """The MAP weights (W, b) from the prior mean (W0, b0); σ = 0 returns the prior mean itself."""
    if sigma == 0:
        return W0.copy(), b0.copy()
    theta0 = np.concatenate([W0.ravel(), b0])
    res = minimize(map_objective, theta0.copy(), args=(Phi, y, weight, theta0, sigma), jac=True,
                   method="L-BFGS-B", options={"maxiter": max_iter, "gtol": 1e-6})
    K, d = W0.shape
    return res.x[:K * d].reshape(K, d), res.x[K * d:]


def _rows(clf: EnvironmentClassifier, X: np.ndarray) -> dict:
    """Per fitted sub-model, the rows of X it is fine-tuned on: every row that has its modalities."""
    g, a = availability(X)
    masks = {"both": g & a, "gnss": g, "acoustic": a}
    return {name: masks[name] for name in SUBMODELS if name in clf.submodels_}


def _phi(clf: EnvironmentClassifier, name: str, X: np.ndarray) -> np.ndarray:
    m = clf.submodels_[name]
    return _expand((X[:, list(_COLUMNS[name])] - m["mean"]) / m["scale"], clf.degree)


def _prior_weights(m: dict) -> tuple[np.ndarray, np.ndarray]:
    """The default's (W, b); a class the default never saw has intercept −1e3, held at a finite −30 (p ~ 1e-13)
    so that the prior is not astronomically far from anything the data could pull towards."""
    return np.asarray(m["coef"], float), np.maximum(np.asarray(m["intercept"], float), -30.0)


def finetune(default: EnvironmentClassifier, X, y, sigma: float) -> EnvironmentClassifier:
    """A copy of ``default`` whose sub-models' weights are MAP-adapted to the windows (X, y) with prior SD σ.

    Parameters
    ----------
    default : EnvironmentClassifier
        A fitted classifier (the shipped default, or any other).
    X : array-like of shape (n_windows, 14)
        Features in :data:`features.schema.FEATURES` order, NaN where a modality is missing.
    y : array-like of shape (n_windows,)
        Class codes (or names) of the windows.
    sigma : float
        Prior SD of every weight around the default's (``inf``: the data alone; 0: the default unchanged).
    """
    X = np.asarray(X, float)
    if X.ndim != 2 or X.shape[1] != len(_COLUMNS["both"]):
        raise ValueError(f"X must have shape (n_windows, {len(_COLUMNS['both'])}), got {X.shape}")
    y = default._codes(y)
    if len(y) != len(X):
        raise ValueError(f"X has {len(X)} rows but y has {len(y)}")
    if not (sigma >= 0):
        raise ValueError(f"sigma must be >= 0, got {sigma!r}")
    out = copy.deepcopy(default)
    for name, rows in _rows(default, X).items():
        if not rows.any():
            continue                        # nothing of the user's has this sub-model's modalities: keep it
        m = out.submodels_[name]
        W0, b0 = _prior_weights(m)
        W, b = fit_map(_phi(default, name, X[rows]), y[rows], balanced_weights(y[rows]), W0, b0, sigma)
        m["coef"], m["intercept"] = W, b
    return out


def _weighted_logloss(clf: EnvironmentClassifier, X: np.ndarray, y: np.ndarray) -> float:
    p = np.clip(clf.predict_proba(X)[np.arange(len(y)), y], 1e-12, 1.0)
    w = balanced_weights(y)
    return float(np.sum(-w * np.log(p)) / np.sum(w))


def choose_sigma(default: EnvironmentClassifier, X, y, groups, grid=SIGMA_GRID, n_folds: int = 5) -> tuple[float, dict]:
    """σ of ``grid`` with the smallest held-out log-loss over folds of whole groups (cells); (σ, {σ: loss}).

    Folds: the groups in a fixed order (sorted), dealt round-robin into min(n_folds, n_groups) folds; each
    fold's windows are scored by the model fine-tuned on the others, with the balanced weights of the
    held-out windows (so a rare class counts as it does in the fit). Fewer than two groups: the grid's middle.
    """
    X = np.asarray(X, float)
    y = default._codes(y)
    groups = np.asarray(groups)
    names = np.unique(groups)
    if len(names) < 2:
        mid = grid[len(grid) // 2]
        return float(mid), {}
    k = min(n_folds, len(names))
    fold_of = {g: i % k for i, g in enumerate(names)}
    fold = np.array([fold_of[g] for g in groups])
    losses = {}
    for s in grid:
        per = []
        for f in range(k):
            test = fold == f
            model = finetune(default, X[~test], y[~test], s)
            per.append(_weighted_logloss(model, X[test], y[test]))
        losses[float(s)] = float(np.mean(per))
    best = min(losses, key=losses.get)
    return best, losses
