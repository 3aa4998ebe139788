"""Tightly coupled acoustics: each beacon's pseudorange a factor, with a receiver clock per TDMA frame.

Loosely coupled, the acoustic receiver solves a frame's ranges for a fix (≥ 3 beacons, the residual
test passed) and the graph takes the fix. Tightly coupled, the graph takes the ranges themselves
(Groves 2013, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed.,
§14.1: tight integration uses the ranging measurements of frames too weak for a position solution), so
frames with one or two beacons, or whose fix the receiver refused, still inform the track. The pseudorange
of :func:`features.acoustic.positions.solve_position`::

    # ρ_i = ‖(p(t_i), h) − s_i‖ + k_j + v_i,   v_i ~ N(0, σ_i²)

with s_i the beacon (ENU), h the receiver's height, k_j = c·δ_j the clock offset of frame j in metres,
and p(t_i) the position at the range's time, interpolated between the nodes around it,
p = (1 − α)·x_a + α·x_b (the walker moves up to a metre over the ~1.3 s a frame's chirps take to arrive).
Clocks follow a random walk between frames, k_j − k_{j−1} ~ N(0, (c·ρ̇·Δt)² + σ_k²), ρ̇ the receiver
clock's drift bound.

The range factor is a ``gtsam.CustomFactor`` (its Jacobians below are analytic): a Python factor gets a
copy of the optimiser's whole ``Values`` per call, so it is used only inside the fixed-lag smoother,
whose window holds a few seconds of variables (:func:`solve_tight`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.fusion.events import ACOUSTIC, EventStream
from models.graph.build import FixNoise, X, iter_parts, plan_nodes
from models.graph.config import GraphConfig, GraphError
from models.graph.solve import GraphRun, initial_position, solve_fixed_lag

__all__ = ["RangeRows", "range_error", "solve_tight", "K", "CLOCK_DRIFT_PPM"]

CLOCK_DRIFT_PPM = 100.0
"""Bound on the audio clock's drift between frames (a consumer sample clock: tens of ppm), ppm."""


def K(j: int) -> int:
    """Key of the clock (metres) of the j-th acoustic frame heard (j ≥ 0)."""
    import gtsam

    return gtsam.symbol("k", int(j))


@dataclass(frozen=True)
class RangeRows:
    """Every associated beacon range of a walk, one row each (shapes (n,) unless stated):
    ``frame`` TDMA frame number, ``t_s`` walk time of the range (the stated arrival less the receiver's
    clock estimate), ``beacon_enu_m`` (n, 3), ``pseudorange_m`` c·(arrival − emission), ``sigma_m``,
    ``clock_hint_m`` c·δ of the nearest acoustic fix (an initial value; NaN without one);
    ``receiver_up_m`` the device height (m, up)."""

    frame: np.ndarray
    t_s: np.ndarray
    beacon_enu_m: np.ndarray
    pseudorange_m: np.ndarray
    sigma_m: np.ndarray
    clock_hint_m: np.ndarray
    receiver_up_m: float

    def __post_init__(self):
        n = np.asarray(self.t_s).shape[0]
        for name in ("frame", "t_s", "pseudorange_m", "sigma_m", "clock_hint_m"):
            if np.asarray(getattr(self, name)).shape != (n,):
                raise GraphError(f"ranges.{name} must have shape ({n},)")
        if np.asarray(self.beacon_enu_m).shape != (n, 3):
            raise GraphError(f"ranges.beacon_enu_m must have shape ({n}, 3)")
        if np.any(~(np.asarray(self.sigma_m) > 0)):
            raise GraphError("ranges.sigma_m must be positive")

    def __len__(self) -> int:
        return int(np.asarray(self.t_s).shape[0])


def range_error(a: np.ndarray, b: np.ndarray, k: float, alpha: float, beacon: np.ndarray, up_m: float,
                rho: float) -> tuple[float, np.ndarray, np.ndarray, float]:
    """Residual e = ‖((1−α)a + αb, h) − s‖ + k − ρ and its Jacobians (∂e/∂a (2,), ∂e/∂b (2,), ∂e/∂k).

    >>> e, Ja, Jb, Jk = range_error(np.zeros(2), np.array([2.0, 0.0]), 0.5, 0.5, np.array([4.0, 0.0, 1.0]), 1.0, 3.0)
    >>> round(e, 6), Ja.round(6).tolist(), Jb.round(6).tolist(), Jk    # p = (1, 0): 3 + 0.5 − 3
    (0.5, [-0.5, 0.0], [-0.5, 0.0], 1.0)
    """
    p = (1.0 - alpha) * a + alpha * b
    d = np.array([p[0] - beacon[0], p[1] - beacon[1], up_m - beacon[2]])
    r = math.sqrt(float(d @ d))
    u = d[:2] / max(r, 1e-9)
    return r + k - rho, (1.0 - alpha) * u, alpha * u, 1.0


def _range_factor(noise, key_a: int, key_b: int, key_k: int, alpha: float, beacon: np.ndarray, up_m: float,
                  rho: float):
    import gtsam

    same = key_a == key_b

    def error(this, values, H):
        a = values.atPoint2(key_a)
        b = a if same else values.atPoint2(key_b)
        k = float(values.atVector(key_k)[0])
        e, Ja, Jb, Jk = range_error(a, b, k, alpha, beacon, up_m, rho)
        if H is not None:
            if same:
                H[0] = (Ja + Jb).reshape(1, 2)
                H[1] = np.array([[Jk]])
            else:
                H[0] = Ja.reshape(1, 2)
                H[1] = Jb.reshape(1, 2)
                H[2] = np.array([[Jk]])
        return np.array([e])

    keys = [key_a, key_k] if same else [key_a, key_b, key_k]
    return gtsam.CustomFactor(noise, keys, error)


def _range_noise(sigma_m: float, cfg: GraphConfig):
    """N(0, σ² + σ_extra²) under the range kernel (:attr:`GraphConfig.range_kernel`)."""
    import gtsam

    gauss = gtsam.noiseModel.Isotropic.Sigma(1, math.hypot(float(sigma_m), cfg.range_extra_sigma_m))
    m = gtsam.noiseModel.mEstimator
    if cfg.range_kernel == "gauss":
        return gauss
    est = {"huber": lambda w: m.Huber.Create(w), "cauchy": lambda w: m.Cauchy.Create(w),
           "dcs": lambda w: m.DCS.Create(w * w)}[cfg.range_kernel](float(cfg.range_width))
    return gtsam.noiseModel.Robust.Create(est, gauss)


def tight_parts(stream: EventStream, noise: FixNoise, ranges: RangeRows, cfg: GraphConfig, x0_en, plan,
                clock_sigma0_m: float = 50.0, speed_of_sound_m_s: float = 343.0, counter: dict | None = None):
    """Yield the loosely coupled graph's parts (:func:`models.graph.build.iter_parts`) without the acoustic
    fixes, each with the range factors of the ranges since the previous node and a clock per new frame (see
    the module docstring). ``counter['ranges']`` receives the number of ranges used."""
    import gtsam

    use = noise.use & (stream.kind != ACOUSTIC)
    t_nodes = plan.t_s
    order = np.argsort(ranges.t_s, kind="stable")
    order = order[(ranges.t_s[order] >= t_nodes[0]) & (ranges.t_s[order] <= t_nodes[-1])]
    drift = CLOCK_DRIFT_PPM * 1e-6 * speed_of_sound_m_s
    r = 0
    last = None               # (frame, key time) of the newest clock
    created: dict = {}
    used = 0
    for part in iter_parts(stream, FixNoise(noise.cov_m2, noise.width, use), cfg, x0_en, plan):
        b = part.node
        while r < order.size and ranges.t_s[order[r]] <= part.t_s:
            i = order[r]
            r += 1
            t = float(ranges.t_s[i])
            a = max(b - 1, 0)
            span = t_nodes[b] - t_nodes[a]
            alpha = 1.0 if span <= 0 else (t - t_nodes[a]) / span
            frame = int(ranges.frame[i])
            if frame not in created:
                # clocks keyed in order of appearance (frame numbers may be negative)
                f = created[frame] = len(created)
                hint = float(ranges.clock_hint_m[i])
                part.values[K(f)] = np.array([hint if math.isfinite(hint) else 0.0])
                if last is None:
                    part.factors.append(gtsam.PriorFactorVector(K(f), part.values[K(f)],
                                                                gtsam.noiseModel.Isotropic.Sigma(1, clock_sigma0_m)))
                else:
                    # k_f − k_prev ~ N(0, (c·drift·Δt)² + (1 mm)²)
                    sd = math.hypot(drift * max(t - last[1], 0.0), 1e-3)
                    part.factors.append(gtsam.BetweenFactorVector(K(last[0]), K(f), np.zeros(1),
                                                                  gtsam.noiseModel.Isotropic.Sigma(1, sd)))
                    part.keys.append(K(last[0]))
                last = (f, t)
            f = created[frame]
            part.factors.append(_range_factor(_range_noise(ranges.sigma_m[i], cfg), X(a), X(b), K(f), alpha,
                                              np.asarray(ranges.beacon_enu_m[i], float), ranges.receiver_up_m,
                                              float(ranges.pseudorange_m[i])))
            part.keys += [X(a), X(b), K(f)]
            used += 1
        if last is not None and K(last[0]) not in part.keys:
            part.keys.append(K(last[0]))      # the newest clock stays in a fixed-lag window between frames
        if counter is not None:
            counter["ranges"] = used
        yield part


def solve_tight(stream: EventStream, noise: FixNoise, ranges: RangeRows, cfg: GraphConfig,
                method: str = "fg_tight", x0_en=None, covariance: bool = True) -> GraphRun:
    """Fixed-lag smoothing of the tightly coupled graph (:func:`tight_parts`)."""
    x0 = initial_position(stream) if x0_en is None else x0_en
    plan = plan_nodes(stream, cfg)
    counter = {"ranges": 0}
    run = solve_fixed_lag(stream, noise, cfg, method, covariance=covariance, plan=plan,
                          parts=tight_parts(stream, noise, ranges, cfg, x0, plan, counter=counter))
    run.info["ranges_used"] = counter["ranges"]
    return run
