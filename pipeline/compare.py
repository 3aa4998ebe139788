"""Comparing methods on held-out walks: paired per-walk differences with a site-level bootstrap interval.

Walks of one site share its layout, beacons and sky, so they are not
independent samples of a method's error: a gain seen on three walks of one
lucky site is one observation. The comparison of method A against B is
therefore the ratio of their pooled mean errors over the same walks,

    Δ = Σ_w n_w ē_A,w / Σ_w n_w ē_B,w − 1      (negative: A better)

(n_w the walk's epochs, ē the mean horizontal error; per-walk means are first
averaged over the model seeds), and its 95 % interval is the percentile
interval of Δ over a cluster bootstrap that resamples *sites* with
replacement, keeping each site's walks together (Davison & Hinkley 1997,
§3.8; Field & Welsh 2007 on cluster resampling).

With one long recording (a single drive) there is one site and one walk: the
same Δ is then taken over the paired epochs of the two methods,
Δ = Σ_k e_A,k / Σ_k e_B,k − 1, and its interval from a block bootstrap that
resamples non-overlapping blocks of ``block_s`` seconds with replacement
(Carlstein 1986, Ann. Stat. 14(3); Künsch 1989 for the moving-block variant):
errors persist over tens of seconds (NLOS, a filter's memory), so epochs are
not independent, while blocks longer than that nearly are
(:func:`block_compare`; the same :func:`cluster_bootstrap` with a block as the
cluster).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["WalkScores", "walk_scores", "Comparison", "compare", "cluster_bootstrap", "BlockComparison",
           "block_compare"]


@dataclass(frozen=True)
class WalkScores:
    """Per method and class, per walk: the pooled mean error ``mean_m`` and epoch count ``n`` (averaged over the
    seeds), with each walk's ``site``."""

    walks: tuple[str, ...]
    sites: tuple[str, ...]
    mean_m: dict            # (method, class) -> (n_walks,) mean error, NaN where the method has no epochs
    n: dict                 # (method, class) -> (n_walks,) epochs


def walk_scores(results_by_seed: list[list[dict]]) -> WalkScores:
    """From :func:`pipeline.evaluate.evaluate`'s ``results`` of each seed (the same walks in each)."""
    walks = [r["walk"] for r in results_by_seed[0]]
    sites = [r["site"] for r in results_by_seed[0]]
    acc: dict = {}
    for s, results in enumerate(results_by_seed):
        if [r["walk"] for r in results] != walks:
            raise ValueError("every seed must evaluate the same walks in the same order")
        for i, res in enumerate(results):
            for row in res["rows"]:
                key = (row["method"], row["env_class"])
                m, n = acc.setdefault(key, (np.zeros((len(results_by_seed), len(walks))),
                                            np.zeros((len(results_by_seed), len(walks)))))
                m[s, i], n[s, i] = row["mean_m"], row["n"]
    mean_m, n = {}, {}
    for key, (m, c) in acc.items():
        with np.errstate(invalid="ignore"):
            mean_m[key] = np.where(c.sum(0) > 0, (m * c).sum(0) / c.sum(0), np.nan)
        n[key] = c.mean(0)
    return WalkScores(tuple(walks), tuple(sites), mean_m, n)


def cluster_bootstrap(stat, clusters: np.ndarray, n_boot: int = 4000, seed: int = 0,
                      prob: float = 0.95) -> tuple[float, float]:
    """Percentile interval of ``stat(rows)`` (rows: indices into the data, with repeats) over resamples of the
    distinct ``clusters`` with replacement, each drawn cluster contributing all its rows.

    >>> v = np.array([1.0, 3.0])
    >>> cluster_bootstrap(lambda rows: float(v[rows].mean()), np.array(["a", "b"]), n_boot=2000)
    (1.0, 3.0)
    """
    labels = np.unique(clusters)
    members = [np.flatnonzero(clusters == c) for c in labels]
    rng = np.random.default_rng(seed)
    vals = np.empty(n_boot)
    for b in range(n_boot):
        pick = rng.integers(0, len(labels), len(labels))
        vals[b] = stat(np.concatenate([members[i] for i in pick]))
    a = (1.0 - prob) / 2.0
    return float(np.nanquantile(vals, a)), float(np.nanquantile(vals, 1.0 - a))


@dataclass(frozen=True)
class Comparison:
    """Method ``a`` against ``b`` on class ``env_class``: Δ (ratio of pooled means − 1) and its 95 % interval
    over site resamples, the pooled means, and the walks and sites it rests on."""

    a: str
    b: str
    env_class: str
    delta: float
    lo: float
    hi: float
    mean_a_m: float
    mean_b_m: float
    n_walks: int
    n_sites: int

    @property
    def excludes_zero(self) -> bool:
        return self.hi < 0.0 or self.lo > 0.0

    def __str__(self) -> str:
        return (f"{self.a} vs {self.b} ({self.env_class}): {100 * self.delta:+.1f} % "
                f"[{100 * self.lo:+.1f}, {100 * self.hi:+.1f}] ({self.mean_a_m:.3f} vs {self.mean_b_m:.3f} m; "
                f"{self.n_walks} walks, {self.n_sites} sites)")


def compare(scores: WalkScores, a: str, b: str, env_class: str = "all", n_boot: int = 4000,
            seed: int = 0) -> Comparison | None:
    """Δ of ``a`` against ``b`` over the walks where both have epochs of ``env_class``, with its site-level
    bootstrap interval; None when no walk has both."""
    ka, kb = (a, env_class), (b, env_class)
    if ka not in scores.mean_m or kb not in scores.mean_m:
        return None
    ma, mb, n = scores.mean_m[ka], scores.mean_m[kb], scores.n[kb]
    ok = np.isfinite(ma) & np.isfinite(mb) & (n > 0)
    if not ok.any():
        return None
    ma, mb, n = ma[ok], mb[ok], n[ok]
    sites = np.asarray(scores.sites)[ok]

    def delta(rows):
        # Δ = Σ n ē_A / Σ n ē_B − 1
        return float(np.sum(n[rows] * ma[rows]) / np.sum(n[rows] * mb[rows]) - 1.0)

    every = np.arange(len(ma))
    lo, hi = cluster_bootstrap(delta, sites, n_boot=n_boot, seed=seed)
    return Comparison(a, b, env_class, delta(every), lo, hi, float(np.sum(n * ma) / n.sum()),
                      float(np.sum(n * mb) / n.sum()), int(ok.sum()), int(len(np.unique(sites))))


@dataclass(frozen=True)
class BlockComparison:
    """Method ``a`` against ``b`` over the paired epochs of one recording: Δ (ratio of mean errors − 1) and its
    95 % interval over resamples of ``n_blocks`` blocks of ``block_s`` seconds, the mean errors and epochs."""

    a: str
    b: str
    delta: float
    lo: float
    hi: float
    mean_a_m: float
    mean_b_m: float
    n_epochs: int
    n_blocks: int
    block_s: float

    @property
    def excludes_zero(self) -> bool:
        return self.hi < 0.0 or self.lo > 0.0

    def __str__(self) -> str:
        return (f"{self.a} vs {self.b}: {100 * self.delta:+.1f} % [{100 * self.lo:+.1f}, {100 * self.hi:+.1f}] "
                f"({self.mean_a_m:.2f} vs {self.mean_b_m:.2f} m; {self.n_epochs} epochs, {self.n_blocks} blocks of "
                f"{self.block_s:g} s)")


def block_compare(t_a: np.ndarray, err_a: np.ndarray, t_b: np.ndarray, err_b: np.ndarray, a: str = "a",
                  b: str = "b", block_s: float = 20.0, n_boot: int = 4000, seed: int = 0) -> BlockComparison | None:
    """Δ of method ``a`` against ``b`` over the epochs both have (row by row when the times are equal, as for two
    filters run on one event stream; else the times both have), Δ = Σ e_A / Σ e_B − 1, with the block-bootstrap interval (module docstring);
    None without a common epoch.

    >>> t = np.arange(40.0)
    >>> c = block_compare(t, np.full(40, 1.0), t, np.r_[np.full(20, 1.0), np.full(20, 3.0)], block_s=20, n_boot=500)
    >>> round(c.delta, 3), round(c.lo, 3), round(c.hi, 3), c.n_blocks
    (-0.5, -0.667, 0.0, 2)
    """
    ta, tb = np.asarray(t_a, float), np.asarray(t_b, float)
    ea, eb = np.asarray(err_a, float), np.asarray(err_b, float)
    if ta.shape == tb.shape and np.array_equal(ta, tb):
        common, ia, ib = ta, np.arange(ta.size), np.arange(tb.size)     # one event stream: row by row
    else:
        common, ia, ib = np.intersect1d(ta, tb, return_indices=True)
    ok = np.isfinite(ea[ia]) & np.isfinite(eb[ib])
    common, ea, eb = common[ok], ea[ia][ok], eb[ib][ok]
    if common.size == 0:
        return None
    blocks = np.floor((common - common.min()) / block_s).astype(int)

    def delta(rows):
        # Δ = Σ e_A / Σ e_B − 1
        return float(np.sum(ea[rows]) / np.sum(eb[rows]) - 1.0)

    lo, hi = cluster_bootstrap(delta, blocks, n_boot=n_boot, seed=seed)
    every = np.arange(common.size)
    return BlockComparison(a, b, delta(every), lo, hi, float(ea.mean()), float(eb.mean()), int(common.size),
                           int(len(np.unique(blocks))), float(block_s))
