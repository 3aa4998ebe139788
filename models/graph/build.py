"""The walk as a factor graph: position variables at every event time, PDR and GNSS/acoustic factors.

Variables (gtsam keys): ``x<i>`` a :class:`gtsam.Point2` (east_m, north_m) per *node*, node 0 the prior
state at the stream's start and then one node per distinct event time (a fix at the time of the step
that ends there shares its node, so fixes at 5 Hz, acoustic frames and steps fuse without resampling:
the non-equidistant fusion the seed stresses, Yang et al. 2023); ``c<j>`` the PDR calibration of
calibration block j (:attr:`GraphConfig.calib_block_s` of walk time), a vector c = (a, b).

PDR calibration, linear. The EKF's step model (:mod:`models.fusion.core`) moves the walker by
(1 + s)·L·(sin(ψ + δψ), cos(ψ + δψ)) for a heading offset δψ and step scale s. With
a = (1 + s)·cos δψ and b = (1 + s)·sin δψ the same displacement is linear in (a, b)::

    # d = M(u)·c,   u = L·(sin ψ, cos ψ),   M(u) = [[u_e, u_n], [u_n, −u_e]]

(the rotation-and-scale group of the plane written as a 2-vector, a similarity in complex form), so a
step is the linear factor x_k − x_{k−1} − M(u)·c_j = w, w ~ N(0, Q_step + Q_walk Δt), held in a
``gtsam.LinearContainerFactor`` (exact, since every variable lives in a vector space). Q_step is the
EKF's G diag(σ_L², σ_ψ²) G' at the measured heading (g = 1). The prior on c_0 is
N((1, 0), diag(σ_s0², σ_ψ0²)) and c_j − c_{j−1} ~ N(0, diag(q_s, q_ψ)·Δt) — the EKF's priors and random
walks to first order in (s, δψ). Between events without a step: x_k − x_{k−1} ~ N(0, Q_walk Δt)
(``BetweenFactorPoint2``). With calibration off the steps are ``BetweenFactorPoint2`` with d = u.

Measurements: a fix z with covariance R is ``PriorFactorPoint2(x, z, R)`` under its source's kernel
(:mod:`models.graph.robust`). With :attr:`GraphConfig.gnss_bias` a GNSS fix measures x + b: the variable
``g<i>`` holds n = −b, so the fix is ``BetweenFactorPoint2(g_i, x_i, z)`` (x − n = z, robust kernels
apply), and between GNSS nodes n_i − φ·n_j ~ N(0, σ_b²(1 − φ²)), φ = e^(−Δt/τ) (Gelb 1974, ch. 3; exact
over any Δt, so the chain matches the EKF's per-event bias decay), n at the first GNSS node ~ N(0, σ_b²).

Everything is a C++ factor: gtsam's Python ``CustomFactor`` is passed a copy of the whole ``Values``
at every call inside an optimiser (measured: 10 ms per factor on a 5,000-node graph, 60 s per
Gauss–Newton iteration), so it is kept for the few factors of a small fixed-lag window
(:mod:`models.graph.tight`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.fusion.events import GNSS, STEP, EventStream
from models.graph.config import GraphConfig, GraphError
from models.graph.robust import noise_model

__all__ = ["FixNoise", "GraphPlan", "plan_nodes", "step_covariance", "step_matrix", "graph_factors", "iter_parts",
           "X", "C", "G", "GraphPart"]


def X(i: int) -> int:
    """Key of position node i."""
    import gtsam

    return gtsam.symbol("x", int(i))


def C(j: int) -> int:
    """Key of calibration block j."""
    import gtsam

    return gtsam.symbol("c", int(j))


def G(i: int) -> int:
    """Key of the (negated) GNSS bias at node i."""
    import gtsam

    return gtsam.symbol("g", int(i))


@dataclass(frozen=True)
class FixNoise:
    """The noise of every event's fix: ``cov_m2`` (m, 2, 2) (NaN on steps), the kernel ``width`` (m,) in
    whitened units (NaN: the config's width of the source), and ``use`` (m,) bool: the fix enters the graph."""

    cov_m2: np.ndarray
    width: np.ndarray
    use: np.ndarray

    @classmethod
    def from_cov(cls, stream: EventStream, cov_m2: np.ndarray) -> "FixNoise":
        cov = np.asarray(cov_m2, float)
        m = len(stream)
        if cov.shape != (m, 2, 2):
            raise GraphError(f"fix covariances must have shape ({m}, 2, 2), got {cov.shape}")
        use = (stream.kind != STEP) & stream.available & np.all(np.isfinite(cov), axis=(1, 2))
        return cls(cov, np.full(m, np.nan), use)


@dataclass(frozen=True)
class GraphPlan:
    """Nodes of a stream: ``t_s`` (n_nodes,) node times (node 0 the prior at the first event's time),
    ``event_node`` (m,) the node of each event, ``block`` (m,) the calibration block of each step (−1 else)."""

    t_s: np.ndarray
    event_node: np.ndarray
    block: np.ndarray

    @property
    def n_nodes(self) -> int:
        return int(self.t_s.shape[0])


def plan_nodes(stream: EventStream, cfg: GraphConfig) -> GraphPlan:
    """One node per distinct event time (a non-step event at the previous event's time shares its node)."""
    m = len(stream)
    if m == 0:
        raise GraphError("the event stream is empty")
    is_step = stream.kind == STEP
    new = is_step | (stream.dt_s > 0)
    node = np.cumsum(new).astype(np.int64)
    t_nodes = np.concatenate([[stream.t_s[0] - stream.dt_s[0]], stream.t_s[new]])
    block = np.where(is_step, np.floor((stream.t_s - t_nodes[0]) / cfg.calib_block_s).astype(np.int64), -1)
    return GraphPlan(t_nodes, node, block)


def step_matrix(length_m: float, heading_rad: float) -> np.ndarray:
    """M(u) of the module docstring, (2, 2): d = M(u)·(a, b), u = L·(sin ψ, cos ψ).

    >>> step_matrix(1.0, 0.0).tolist()
    [[0.0, 1.0], [1.0, -0.0]]
    """
    ue, un = length_m * math.sin(heading_rad), length_m * math.cos(heading_rad)
    return np.array([[ue, un], [un, -ue]])


def step_covariance(length_m: float, heading_rad: float, sigma_l2: float, sigma_psi2: float) -> np.ndarray:
    """Q_step = G diag(σ_L², σ_ψ²) G', G = [[sin ψ, L cos ψ], [cos ψ, −L sin ψ]] (the EKF's, g = 1), (2, 2)."""
    s, c = math.sin(heading_rad), math.cos(heading_rad)
    vl, vp = sigma_l2, length_m * length_m * sigma_psi2
    off = (vl - vp) * s * c
    return np.array([[vl * s * s + vp * c * c, off], [off, vl * c * c + vp * s * s]])


@dataclass
class GraphPart:
    """Factors and new variables that complete at one node: ``node``, ``t_s``, ``factors`` (list of gtsam
    factors), ``values`` ({key: initial value}), ``keys`` (every key the factors touch, for fixed-lag
    timestamps), ``fix_events`` (event indices of the fixes at this node)."""

    node: int
    t_s: float
    factors: list
    values: dict
    keys: list
    fix_events: list


def _whitened_linear(keys_mats: list, cov: np.ndarray):
    """JacobianFactor Σ A_i x_i = 0 with noise N(0, cov), whitened (A ← W A, W = L⁻¹, cov = L L')."""
    import gtsam

    W = np.linalg.inv(np.linalg.cholesky(cov))
    args = []
    for key, A in keys_mats:
        args += [key, W @ A]
    jf = gtsam.JacobianFactor(*args, np.zeros(2), gtsam.noiseModel.Unit.Create(2))
    lin = gtsam.Values()
    for key, A in keys_mats:
        lin.insert(key, np.zeros(A.shape[1]))
    return gtsam.LinearContainerFactor(jf, lin)


def graph_factors(stream: EventStream, noise: FixNoise, cfg: GraphConfig, x0_en) -> tuple[GraphPlan, list]:
    """Every factor of the walk's graph, grouped by the node at which it completes (time order).

    Returns (plan, parts): parts[i] is the :class:`GraphPart` of node i (:func:`iter_parts`, materialised).
    """
    plan = plan_nodes(stream, cfg)
    return plan, list(iter_parts(stream, noise, cfg, x0_en, plan))


def _calibration_factors(part: GraphPart, j: int, last_block: int | None, cfg: GraphConfig) -> None:
    """Create block j's calibration variable in ``part``: the prior on the first, else the random walk from
    the last block with steps."""
    import gtsam

    calib0 = np.array([1.0, 0.0])
    part.values[C(j)] = calib0.copy()
    if last_block is None:
        part.factors.append(gtsam.PriorFactorVector(C(j), calib0, gtsam.noiseModel.Diagonal.Sigmas(
            np.array([cfg.sigma0_scale, cfg.sigma0_heading_rad]))))
        return
    span = (j - last_block) * cfg.calib_block_s
    sig = np.sqrt(np.array([cfg.q_scale_1_s, cfg.q_heading_rad2_s]) * span) + 1e-12
    part.factors.append(gtsam.BetweenFactorVector(C(last_block), C(j), np.zeros(2),
                                                  gtsam.noiseModel.Diagonal.Sigmas(sig)))
    part.keys.append(C(last_block))


def _bias_factors(part: GraphPart, i: int, last: tuple | None, cfg: GraphConfig) -> None:
    """Create the bias variable of node i in ``part``: its prior, or the Gauss–Markov step from the last."""
    import gtsam

    part.values[G(i)] = np.zeros(2)
    if last is None:
        part.factors.append(gtsam.PriorFactorPoint2(G(i), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(
            2, cfg.bias_sigma_m)))
        return
    phi = math.exp(-(part.t_s - last[1]) / cfg.bias_tau_s)
    # n_i − φ n_j ~ N(0, σ_b²(1 − φ²))
    var = max(cfg.bias_sigma_m ** 2 * (1.0 - phi * phi), cfg.min_var_m2)
    part.factors.append(_whitened_linear([(G(last[0]), -phi * np.eye(2)), (G(i), np.eye(2))], np.eye(2) * var))
    part.keys.append(G(last[0]))


def iter_parts(stream: EventStream, noise: FixNoise, cfg: GraphConfig, x0_en, plan: GraphPlan | None = None):
    """Yield the :class:`GraphPart` of each node in time order, each once complete (its transition from the
    previous node and its fixes): a generator, so a fixed-lag solver holds only its window, never the
    whole walk's factors. Initial values dead-reckon the PDR from ``x0_en`` (2,) with c = (1, 0)."""
    import gtsam

    plan = plan_nodes(stream, cfg) if plan is None else plan
    x0 = np.asarray(x0_en, float)
    if x0.shape != (2,) or not np.all(np.isfinite(x0)):
        raise GraphError(f"the initial position must be a finite (2,) east/north, got {x0_en!r}")
    sl2, sp2 = cfg.sigma_step_length_m ** 2, cfg.sigma_heading_rad ** 2
    current = GraphPart(0, float(plan.t_s[0]), [gtsam.PriorFactorPoint2(
        X(0), x0, gtsam.noiseModel.Isotropic.Sigma(2, cfg.sigma0_pos_m))], {X(0): x0.copy()}, [X(0)], [])
    pos = x0.copy()
    last_block = None
    kinds = {1: (cfg.gnss_kernel, cfg.gnss_width), 2: (cfg.acoustic_kernel, cfg.acoustic_width)}
    dt_pending = stand_pending = 0.0
    last_bias = None          # (node, time) of the newest GNSS bias variable
    for k in range(len(stream)):
        i = int(plan.event_node[k])
        dt_pending += float(stream.dt_s[k])
        stand_pending += float(stream.dt_stand_s[k])
        if i != current.node:
            yield current
            # the transition from node i−1 to node i: Q_walk over the time since, plus the step if one
            q = max(cfg.q_walk_m2_s * (dt_pending - stand_pending) + cfg.q_stand_m2_s * stand_pending, 0.0)
            current = GraphPart(i, float(plan.t_s[i]), [], {}, [X(i - 1), X(i)], [])
            if stream.kind[k] == STEP:
                L, psi = float(stream.step_length_m[k]), float(stream.heading_rad[k])
                cov = step_covariance(L, psi, sl2, sp2) + np.eye(2) * q
                cov += np.eye(2) * max(cfg.min_var_m2 - np.linalg.eigvalsh(cov)[0], 0.0)
                Mu = step_matrix(L, psi)
                if cfg.calibration:
                    j = int(plan.block[k])
                    if j != last_block:
                        _calibration_factors(current, j, last_block, cfg)
                        last_block = j
                    # x_i − x_{i−1} − M(u)·c_j = w,  w ~ N(0, Q_step + Q_walk Δt)
                    current.factors.append(_whitened_linear([(X(i - 1), -np.eye(2)), (X(i), np.eye(2)),
                                                             (C(j), -Mu)], cov))
                else:
                    current.factors.append(gtsam.BetweenFactorPoint2(X(i - 1), X(i), Mu @ np.array([1.0, 0.0]),
                                                                     gtsam.noiseModel.Gaussian.Covariance(cov)))
                pos = pos + Mu @ np.array([1.0, 0.0])
            else:
                current.factors.append(gtsam.BetweenFactorPoint2(X(i - 1), X(i), np.zeros(2),
                                                                 gtsam.noiseModel.Isotropic.Variance(
                                                                     2, max(q, cfg.min_var_m2))))
            current.values[X(i)] = pos.copy()
            if last_block is not None and C(last_block) not in current.keys:
                current.keys.append(C(last_block))      # keeps the calibration in a fixed-lag window
            if last_bias is not None:
                current.keys.append(G(last_bias[0]))    # and the newest bias
            dt_pending = stand_pending = 0.0
        if noise.use[k]:
            kernel, width = kinds[int(stream.kind[k])]
            w = width if not np.isfinite(noise.width[k]) else float(noise.width[k])
            model = noise_model(noise.cov_m2[k], kernel, w)
            if cfg.gnss_bias and stream.kind[k] == GNSS:
                if last_bias is None or last_bias[0] != i:
                    _bias_factors(current, i, last_bias, cfg)
                    last_bias = (i, current.t_s)
                current.factors.append(gtsam.BetweenFactorPoint2(G(i), X(i), stream.z_m[k], model))
                current.keys.append(G(i))
            else:
                current.factors.append(gtsam.PriorFactorPoint2(X(i), stream.z_m[k], model))
            current.fix_events.append(k)
    yield current
