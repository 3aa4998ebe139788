"""Filter consistency: NEES against truth, NIS of the innovations, chi-square bounds.

Bar-Shalom, Li & Kirubarajan (2001), *Estimation with Applications to
Tracking and Navigation*, §5.4: for a consistent filter the normalised
estimation error squared ε_k = (x_k − x̂_k)' P_k⁻¹ (x_k − x̂_k) is χ² with
n_x degrees of freedom; averaged over N Monte Carlo runs, N·ε̄_k is χ² with
N·n_x, so the two-sided 95 % region of ε̄_k is
[χ²_{N·n_x}(0.025), χ²_{N·n_x}(0.975)] / N and about 95 % of the epochs of a
consistent filter fall inside. The normalised innovation squared
ν' S⁻¹ ν (NIS) is χ² with n_z = 2 the same way, and needs no truth.
"""

from __future__ import annotations

import numpy as np
from scipy.special import chdtri

__all__ = ["nees", "chi2_bounds", "in_bounds_share", "nis_summary"]


def nees(x_est: np.ndarray, P_est: np.ndarray, x_true: np.ndarray, dims=(0, 1)) -> np.ndarray:
    """ε_k = e' P⁻¹ e over the state components ``dims``, e = x_true − x_est.

    x_est, x_true : (m, n) (or (m, len(dims)) truth); P_est : (m, n, n) → (m,).

    >>> float(nees(np.zeros((1, 2)), np.eye(2)[None] * 4.0, np.array([[2.0, 0.0]]))[0])
    1.0
    """
    d = list(dims)
    xt = np.asarray(x_true, float)
    xt = xt[:, d] if xt.shape[1] != len(d) else xt
    e = xt - np.asarray(x_est, float)[:, d]
    Pd = np.asarray(P_est, float)[:, d][:, :, d]
    # ε = e' P⁻¹ e
    return np.einsum("mi,mi->m", e, np.linalg.solve(Pd, e[..., None])[..., 0])


def chi2_bounds(dof: int, n_runs: int = 1, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided ``prob`` region of the run-averaged NEES (or NIS) with ``dof`` per run.

    >>> tuple(round(b, 3) for b in chi2_bounds(2))
    (0.051, 7.378)
    """
    a = (1.0 - prob) / 2.0
    df = dof * n_runs
    # χ² quantiles by the inverse survival function, chi2.ppf(q, df) = chdtri(df, 1 − q): scipy.special
    # is all this needs, and scipy.stats is a 0.6–0.8 s import.
    return float(chdtri(df, 1.0 - a) / n_runs), float(chdtri(df, a) / n_runs)


def in_bounds_share(values: np.ndarray, dof: int, prob: float = 0.95, pooled: bool = False) -> float:
    """Share of epochs whose NEES lies in the two-sided χ² region.

    values : (m,) one run, or (n_runs, m) Monte Carlo runs, averaged over runs per epoch first
    (Bar-Shalom's test, bounds of χ²_{N·n_x}/N); ``pooled=True`` instead tests every (run, epoch)
    against the single-run bounds — the same expected share, 0.95, but N Bernoulli trials per
    epoch instead of one, so far less spread when the epochs of a run are correlated.
    """
    v = np.asarray(values, float)
    n_runs = 1 if v.ndim == 1 or pooled else v.shape[0]
    eps = v.ravel() if pooled else (v if v.ndim == 1 else v.mean(axis=0))
    lo, hi = chi2_bounds(dof, n_runs, prob)
    ok = np.isfinite(eps)
    return float(np.mean((eps[ok] >= lo) & (eps[ok] <= hi)))


def nis_summary(run, prob: float = 0.95) -> dict:
    """NIS statistics per source of a filter run: count, mean (2 for a consistent filter), share inside the
    two-sided χ²₂ region, and the share the update rejected.

    Returns ``{kind_code: {"n", "mean", "in_bounds", "rejected"}}``.
    """
    out = {}
    lo, hi = chi2_bounds(2, 1, prob)
    for code in np.unique(run.kind[run.updated]):
        sel = run.updated & (run.kind == code)
        v = run.nis[sel]
        out[int(code)] = {"n": int(sel.sum()), "mean": float(np.mean(v)),
                          "in_bounds": float(np.mean((v >= lo) & (v <= hi))),
                          "rejected": float(np.mean(~run.accepted[sel]))}
    return out
