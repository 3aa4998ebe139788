"""Solving the walk's graph: in one batch (Levenberg–Marquardt), incrementally (iSAM2), or in a fixed lag.

* :func:`solve_batch` — the whole walk at once, ``gtsam.LevenbergMarquardtOptimizer`` (Moré 1978's
  trust-region Gauss–Newton as gtsam implements it); marginal covariances from ``gtsam.Marginals``.
  With a non-convex kernel (Cauchy, DCS) the solve starts from the Huber solution of the same graph
  (graduated robustness: a convex problem first), since IRLS on a non-convex loss keeps whatever basin
  its start lies in.
* :func:`solve_isam2` — causal: the graph grows node by node in ``gtsam.ISAM2`` (Kaess et al. 2012,
  IJRR 31(2)), and each event's position is the estimate of its node right after the update that
  added it (what ``run`` could show live); the marginal covariance of that node from the same
  Bayes tree. Its memory grows with the walk (measured: 134 MB and 3.3 ms per update after a
  synthetic hour): for long walks the fixed lag below.
* :func:`solve_fixed_lag` — ``gtsam.IncrementalFixedLagSmoother`` (or ``BatchFixedLagSmoother``,
  :attr:`GraphConfig.lag_smoother`): variables older than ``lag_s`` are marginalised out (their
  information kept as a linear prior on the window), so the solver holds the window only, however long
  the walk (≤ 43 variables over a synthetic 8 h); each node's position is its estimate at the last
  update before it leaves the window (a fixed-lag smoothed track, ``lag_s`` late), or with ``causal``
  its estimate right after the update that added it.

Each returns a :class:`GraphRun`: one row per event of the stream, like a filter run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from models.fusion.events import EventStream
from models.graph.build import FixNoise, GraphPart, X, graph_factors, iter_parts, plan_nodes
from models.graph.config import GraphConfig, GraphError

__all__ = ["GraphRun", "solve_batch", "solve_isam2", "solve_fixed_lag", "initial_position"]


@dataclass
class GraphRun:
    """A graph method's track, one row per event: ``t_s``, ``kind`` (m,), ``east_m``, ``north_m`` (m,),
    ``cov_m2`` (m, 2, 2) marginal covariance (NaN where not computed); ``info``: solver figures
    (iterations, seconds, nodes, factors, peak window size...)."""

    method: str
    t_s: np.ndarray
    kind: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    cov_m2: np.ndarray
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def initial_position(stream: EventStream) -> np.ndarray:
    """The first available fix (east, north): where the prior is centred, as for the EKF."""
    fixes = np.flatnonzero(stream.available)
    if fixes.size == 0:
        raise GraphError("no available fix to centre the prior on")
    return stream.z_m[fixes[0]].copy()


def _graph(parts: list[GraphPart]):
    import gtsam

    g = gtsam.NonlinearFactorGraph()
    v = gtsam.Values()
    for p in parts:
        for f in p.factors:
            g.add(f)
        for key, val in p.values.items():
            v.insert(key, val)
    return g, v


def _lm(g, v, cfg: GraphConfig):
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.lm_max_iterations)
    params.setRelativeErrorTol(cfg.lm_rel_tol)
    params.setAbsoluteErrorTol(0.0)
    opt = gtsam.LevenbergMarquardtOptimizer(g, v, params)
    return opt.optimize(), opt.iterations()


def _rows(plan, values, covs=None):
    pos = np.array([values.atPoint2(X(i)) for i in range(plan.n_nodes)])
    ev = plan.event_node
    cov = np.full((len(ev), 2, 2), np.nan) if covs is None else covs[ev]
    return pos[ev, 0], pos[ev, 1], cov


def solve_batch(stream: EventStream, noise: FixNoise, cfg: GraphConfig, method: str = "fg_batch",
                x0_en=None, covariance: bool = True) -> GraphRun:
    """The whole walk in one Levenberg–Marquardt solve (see the module docstring)."""
    import gtsam

    t0 = time.perf_counter()
    x0 = initial_position(stream) if x0_en is None else x0_en
    info = {}
    start = None
    for kern in ("gnss_kernel", "acoustic_kernel"):
        if getattr(cfg, kern) in ("cauchy", "dcs"):
            huber = replace(cfg, gnss_kernel="huber" if cfg.gnss_kernel != "gauss" else "gauss",
                            acoustic_kernel="huber" if cfg.acoustic_kernel != "gauss" else "gauss")
            _, parts_h = graph_factors(stream, noise, huber, x0)
            start, it_h = _lm(*_graph(parts_h), cfg)
            info["huber_start_iterations"] = it_h
            break
    plan, parts = graph_factors(stream, noise, cfg, x0)
    g, v = _graph(parts)
    result, iters = _lm(g, start if start is not None else v, cfg)
    covs = None
    if covariance:
        marg = gtsam.Marginals(g, result)
        covs = np.array([marg.marginalCovariance(X(i)) for i in range(plan.n_nodes)])
    e, n, cov = _rows(plan, result, covs)
    info.update(iterations=iters, seconds=time.perf_counter() - t0, nodes=plan.n_nodes, factors=g.size(),
                error=g.error(result))
    return GraphRun(method, stream.t_s, stream.kind, e, n, cov, info)


def _marginal_of(smoother):
    """The marginal covariance of a key in a fixed-lag smoother: iSAM2's own, or (batch smoother) from
    ``gtsam.Marginals`` over the window's factors at its estimate."""
    import gtsam

    if hasattr(smoother, "marginalCovariance"):
        return smoother.marginalCovariance

    def marginal(key):
        graph = gtsam.NonlinearFactorGraph()
        factors = smoother.getFactors()
        for i in range(factors.size()):
            if factors.exists(i):
                graph.add(factors.at(i))
        return gtsam.Marginals(graph, smoother.calculateEstimate()).marginalCovariance(key)

    return marginal


def _isam2_params(cfg: GraphConfig):
    """iSAM2's settings. The Bayes tree is factored by QR, not GTSAM's default Cholesky. GTSAM's own note on
    ``ISAM2Params::factorization`` says Cholesky can turn numerically indefinite on poorly conditioned problems,
    "when uncertainty is very low in some variables and very high in others", and recommends QR where that
    happens. It does happen here: centimetre RTK fixes beside 37 m GNSS σ in heavy areas. On the standard
    split's held-out walk 205/w1 (300 s), Cholesky declared the system indeterminate and the walk lost every
    method; QR solves it, at 1.8 s for fg_isam2 and fg_batch together."""
    import gtsam

    p = gtsam.ISAM2Params()
    p.setFactorization("QR")
    p.setRelinearizeThreshold(cfg.isam_relin_threshold)
    p.relinearizeSkip = cfg.isam_relin_skip
    return p


def _predicted(part: GraphPart, estimate_prev: np.ndarray | None, dead_reckoned_prev: np.ndarray | None):
    """Initial values of a part's new variables: the new node moved by its dead-reckoned step from the
    previous node's current estimate (instead of the dead reckoning from the start, which drifts)."""
    vals = dict(part.values)
    key = X(part.node)
    if estimate_prev is not None and dead_reckoned_prev is not None and key in vals:
        vals[key] = estimate_prev + (vals[key] - dead_reckoned_prev)
    return vals


def solve_isam2(stream: EventStream, noise: FixNoise, cfg: GraphConfig, method: str = "fg_isam2",
                x0_en=None, covariance: bool = True) -> GraphRun:
    """Causal incremental solve: one iSAM2 update per node; each node's estimate right after it (see the
    module docstring)."""
    import gtsam

    t0 = time.perf_counter()
    x0 = initial_position(stream) if x0_en is None else x0_en
    plan, parts = graph_factors(stream, noise, cfg, x0)
    isam = gtsam.ISAM2(_isam2_params(cfg))
    pos = np.full((plan.n_nodes, 2), np.nan)
    covs = np.full((plan.n_nodes, 2, 2), np.nan)
    prev_est = prev_dr = None
    for p in parts:
        g = gtsam.NonlinearFactorGraph()
        for f in p.factors:
            g.add(f)
        v = gtsam.Values()
        vals = _predicted(p, prev_est, prev_dr)
        for key, val in vals.items():
            v.insert(key, val)
        isam.update(g, v)
        est = isam.calculateEstimatePoint2(X(p.node))
        pos[p.node] = est
        if covariance:
            covs[p.node] = isam.marginalCovariance(X(p.node))
        prev_est, prev_dr = est, p.values[X(p.node)]
    ev = plan.event_node
    info = {"seconds": time.perf_counter() - t0, "nodes": plan.n_nodes, "updates": len(parts)}
    return GraphRun(method, stream.t_s, stream.kind, pos[ev, 0], pos[ev, 1], covs[ev], info)


def solve_fixed_lag(stream: EventStream, noise: FixNoise, cfg: GraphConfig, method: str = "fg_lag",
                    x0_en=None, covariance: bool = True, parts=None, plan=None, causal: bool = False) -> GraphRun:
    """Fixed-lag smoothing over ``cfg.lag_s``: each node's estimate at the last update before it leaves the
    window (see the module docstring); ``causal``: each node's estimate right after the update that added it
    instead (the filtered track, no lag). ``parts``/``plan``: an iterable of prebuilt parts (e.g. with range
    factors) and their plan; by default the parts of :func:`models.graph.build.iter_parts`, generated as
    the smoother consumes them, so nothing but the window and the output rows is held."""
    import gtsam

    t0 = time.perf_counter()
    if parts is None:
        x0 = initial_position(stream) if x0_en is None else x0_en
        plan = plan_nodes(stream, cfg)
        parts = iter_parts(stream, noise, cfg, x0, plan)
    if cfg.lag_smoother == "batch":
        lm = gtsam.LevenbergMarquardtParams()
        lm.setMaxIterations(cfg.lm_max_iterations)
        smoother = gtsam.BatchFixedLagSmoother(cfg.lag_s, lm)
    else:
        smoother = gtsam.IncrementalFixedLagSmoother(cfg.lag_s, _isam2_params(cfg))
    marginal = _marginal_of(smoother)
    pos = np.full((plan.n_nodes, 2), np.nan)
    covs = np.full((plan.n_nodes, 2, 2), np.nan)
    window: list[int] = []            # nodes in the smoother not yet written out, oldest first
    stamp: dict[int, float] = {}      # last timestamp given to each window node's key
    prev_est = prev_dr = None
    peak = 0
    for p in parts:
        g = gtsam.NonlinearFactorGraph()
        for f in p.factors:
            g.add(f)
        v = gtsam.Values()
        for key, val in _predicted(p, prev_est, prev_dr).items():
            v.insert(key, val)
        # nodes the update at p.t_s marginalises (last stamped before p.t_s − lag): written out first
        while window and stamp[window[0]] < p.t_s - cfg.lag_s:
            i = window.pop(0)
            del stamp[i]
            if not causal:
                pos[i] = smoother.calculateEstimatePoint2(X(i))
                if covariance:
                    covs[i] = marginal(X(i))
        stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        for key in set(p.keys) | set(p.values):
            stamps.insert((key, p.t_s))
        for i in (p.node - 1, p.node):
            if i in stamp or i == p.node:
                stamp[i] = p.t_s
        smoother.update(g, v, stamps)
        window.append(p.node)
        peak = max(peak, smoother.getLinearizationPoint().size())
        prev_est, prev_dr = smoother.calculateEstimatePoint2(X(p.node)), p.values[X(p.node)]
        if causal:
            pos[p.node] = prev_est
            if covariance:
                covs[p.node] = marginal(X(p.node))
    for i in ([] if causal else window):
        pos[i] = smoother.calculateEstimatePoint2(X(i))
        if covariance:
            covs[i] = marginal(X(i))
    ev = plan.event_node
    info = {"seconds": time.perf_counter() - t0, "nodes": plan.n_nodes, "updates": plan.n_nodes,
            "peak_variables": peak, "final_factors": smoother.getFactors().nrFactors(),
            "final_variables": smoother.getLinearizationPoint().size()}
    return GraphRun(method, stream.t_s, stream.kind, pos[ev, 0], pos[ev, 1], covs[ev], info)
