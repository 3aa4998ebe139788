"""Does the environment model see where positioning goes wrong? Its occlusion evidence against the error, window by window.

Along a walk or drive the online classifier answers once per 2 s feature window
(:class:`walks.inputs.WalkInputs`: ``window_t_s`` the window ends, ``classes`` the probabilities). The
question a reference trajectory can answer even without any environment label is whether the windows
it calls more occluded are those where the per-epoch solver is worse:

- :func:`window_error`: the mean horizontal error of the fixes inside each window;
- :func:`occlusion_scores`: what "more occluded" means for a classifier: P(heavy), the expected
  severity E[c] = P(light) + 2·P(heavy) (classes ordered open < light < heavy), and the continuous
  blocked-sky share where the model has a regression for it
  (:meth:`models.environment.EnvironmentClassifier.occlusion`);
- :func:`rank_correlation`: Spearman's ρ (scipy.stats.spearmanr: Pearson's correlation of the ranks,
  ties given their mean rank; Spearman 1904), with scipy's p-value — which assumes independent
  windows, and 2 s windows with a 1 s hop on a drive whose errors persist for tens of seconds are
  not — and a 95 % interval from a block bootstrap over ``block_s`` blocks of consecutive windows
  (non-overlapping blocks resampled with replacement, Carlstein 1986, Ann. Stat. 14(3); the
  cluster resampling of :func:`pipeline.compare.cluster_bootstrap`, a block being the cluster).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.compare import cluster_bootstrap

__all__ = ["window_error", "occlusion_scores", "RankCorrelation", "rank_correlation", "time_blocks"]


def window_error(window_end_s: np.ndarray, fix_t_s: np.ndarray, err_m: np.ndarray,
                 window_s: float = 2.0) -> np.ndarray:
    """Mean of ``err_m`` (n,) over the fixes with ``window_end − window_s < t ≤ window_end`` for each window end
    (k,); NaN for a window without a fix.

    >>> window_error(np.array([2.0, 3.0]), np.array([0.5, 1.5, 2.5]), np.array([1.0, 3.0, 5.0])).tolist()
    [2.0, 4.0]
    """
    t = np.asarray(fix_t_s, float)
    order = np.argsort(t, kind="stable")
    t, e = t[order], np.asarray(err_m, float)[order]
    csum = np.r_[0.0, np.cumsum(e)]
    end = np.asarray(window_end_s, float)
    hi = np.searchsorted(t, end, side="right")
    lo = np.searchsorted(t, end - window_s, side="right")
    n = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (csum[hi] - csum[lo]) / np.maximum(n, 1), np.nan)


def occlusion_scores(proba: np.ndarray, classifier=None, X: np.ndarray | None = None) -> dict:
    """{name: (k,) score} of per-window occlusion from class probabilities ``proba`` (k, 3) (open, light, heavy):
    ``P(heavy)``, ``E[severity]`` (0 open … 2 heavy) and, where ``classifier`` has a share regression and the
    windows ``X`` (k, 14) are given, ``blocked share``."""
    p = np.asarray(proba, float)
    out = {"P(heavy)": p[:, 2], "E[severity]": p @ np.arange(p.shape[1], dtype=float)}
    if classifier is not None and X is not None:
        share = classifier.occlusion(X)
        if np.isfinite(share).any():
            out["blocked share"] = share
    return out


def time_blocks(t_s: np.ndarray, block_s: float) -> np.ndarray:
    """Block label of each time: ⌊(t − t_min) / block_s⌋ (consecutive, non-overlapping blocks).

    >>> time_blocks(np.array([0.0, 19.9, 20.0, 45.0]), 20.0).tolist()
    [0, 0, 1, 2]
    """
    t = np.asarray(t_s, float)
    return np.floor((t - np.min(t)) / block_s).astype(int) if t.size else np.zeros(0, int)


@dataclass(frozen=True)
class RankCorrelation:
    """Spearman's ρ of ``score`` against the error over ``n`` windows, scipy's two-sided p-value (independent
    windows assumed) and the 95 % block-bootstrap interval over ``n_blocks`` blocks of ``block_s``."""

    score: str
    rho: float
    p_value: float
    lo: float
    hi: float
    n: int
    n_blocks: int
    block_s: float

    def __str__(self) -> str:
        return (f"{self.score}: Spearman rho {self.rho:+.2f} [{self.lo:+.2f}, {self.hi:+.2f}] "
                f"({self.n} windows, {self.n_blocks} blocks of {self.block_s:g} s; p = {self.p_value:.2g} "
                f"if the windows were independent)")


def rank_correlation(score: np.ndarray, error: np.ndarray, t_s: np.ndarray, *, name: str = "score",
                     block_s: float = 20.0, n_boot: int = 4000, seed: int = 0) -> RankCorrelation:
    """Spearman's ρ of ``score`` and ``error`` (k,) over the windows where both are finite, with the block
    bootstrap interval over blocks of ``block_s`` of the windows' times ``t_s`` (k,) (module docstring)."""
    from scipy.stats import spearmanr

    s, e, t = (np.asarray(a, float) for a in (score, error, t_s))
    ok = np.isfinite(s) & np.isfinite(e) & np.isfinite(t)
    s, e, t = s[ok], e[ok], t[ok]
    if s.size < 3 or np.ptp(s) == 0 or np.ptp(e) == 0:
        return RankCorrelation(name, float("nan"), float("nan"), float("nan"), float("nan"), int(s.size), 0, block_s)
    res = spearmanr(s, e)
    blocks = time_blocks(t, block_s)

    def stat(rows):
        if np.ptp(s[rows]) == 0 or np.ptp(e[rows]) == 0:
            return float("nan")
        return float(spearmanr(s[rows], e[rows]).statistic)

    lo, hi = cluster_bootstrap(stat, blocks, n_boot=n_boot, seed=seed)
    return RankCorrelation(name, float(res.statistic), float(res.pvalue), lo, hi, int(s.size),
                           int(len(np.unique(blocks))), float(block_s))
