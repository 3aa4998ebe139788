"""Settings of the factor-graph methods (:mod:`models.graph`): process noise, priors, kernels, solvers.

One frozen dataclass, validated in ``__post_init__`` (error messages name the
parameter and its value). The PDR and stationary process noise default to the
event-driven EKF's (:class:`models.fusion.ekf.EkfConfig`, via
:meth:`GraphConfig.from_ekf`), so a graph and a filter fed the same events
describe the same motion model and differ only in how they solve it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from features.errors import EnvfuseError

__all__ = ["GraphConfig", "GraphError", "KERNELS"]

KERNELS = ("gauss", "huber", "cauchy", "dcs")
"""Measurement kernels of GNSS and acoustic factors: Gaussian (least squares), Huber (1964), Cauchy
(the Lorentzian, a Student-t with one degree of freedom) and dynamic covariance scaling (Agarwal et al.
2013, the closed form of Sünderhauf & Protzel's switchable constraints)."""


class GraphError(EnvfuseError, ValueError):
    """A graph setting is out of range, or a graph cannot be built from the given inputs."""


@dataclass(frozen=True)
class GraphConfig:
    """Factor-graph settings (units in the names; q are per second of walk time).

    Motion (as :class:`~models.fusion.ekf.EkfConfig`): ``sigma_step_length_m`` and ``sigma_heading_rad``
    per step; ``q_walk_m2_s`` / ``q_stand_m2_s`` the position random walk between events while walking /
    standing; ``q_heading_rad2_s`` / ``q_scale_1_s`` the random walks of the PDR heading offset δψ and step
    scale s; priors ``sigma0_*``.

    ``calibration``: estimate (δψ, s) as variables (one per ``calib_block_s`` of walk time, a random walk
    between blocks); False fixes them at zero (the graph is then linear-Gaussian in the positions).

    ``gnss_bias``: a GNSS bias variable at every GNSS fix, first-order Gauss–Markov between fixes with
    ``bias_sigma_m``, ``bias_tau_s`` (the EKF's bias states, :class:`models.fusion.ekf.EkfConfig`); the
    acoustic fixes do not share it.

    Measurements: ``gnss_kernel`` / ``acoustic_kernel`` one of :data:`KERNELS` with width ``*_width`` in
    units of the whitened residual (Huber's k, Cauchy's c, DCS's Φ as √Φ).

    Tightly coupled acoustic ranges (:mod:`models.graph.tight`): ``range_kernel`` of width ``range_width``
    on each range's σ, inflated by ``range_extra_sigma_m`` (added in quadrature). Cauchy 2.5 was chosen on
    the *training* walks of the quick split (sites 101–103, 3 walks): mean error 0.122 m against 0.200 m
    with Huber 2.5 (a third of the ranges lie beyond 0.5 m of the truth: echoes, NLOS, wrong
    associations, which a convex kernel still follows), 0.133 m with Cauchy 1.0, 0.126 m with DCS
    √Φ = 2 and 0.1 m added, 0.141 m loosely coupled.

    Solvers: Levenberg–Marquardt ``lm_max_iterations``, ``lm_rel_tol`` (relative error decrease to stop);
    iSAM2 relinearisation threshold ``isam_relin_threshold`` and skip ``isam_relin_skip`` (checking every
    variable for relinearisation at each update is O(n): with skip 1 an update took 3.4 ms after 5 min of
    walk and growing, with skip 10 a flat 0.7 ms, the error the same to 4 mm); the fixed-lag smoother's
    window ``lag_s`` and kind ``lag_smoother``: ``"incremental"`` (iSAM2 with marginalisation; its
    memory is the window's, but gtsam leaves an empty slot per removed factor, so an update's cost creeps
    up with the walk: 0.50 ms in the first tenth of a synthetic hour, 0.88 ms in the last) or ``"batch"``
    (``BatchFixedLagSmoother``: Levenberg–Marquardt over the window at each update, slots reused, a flat
    cost of about 1.5–2.5 ms).
    """

    sigma_step_length_m: float = 0.05
    sigma_heading_rad: float = 0.03
    q_walk_m2_s: float = 1e-3
    q_stand_m2_s: float = 1e-5
    q_heading_rad2_s: float = 1e-6
    q_scale_1_s: float = 1e-7
    sigma0_pos_m: float = 5.0
    sigma0_heading_rad: float = 0.3
    sigma0_scale: float = 0.1
    calibration: bool = True
    calib_block_s: float = 10.0
    gnss_kernel: str = "huber"
    gnss_width: float = 2.5
    acoustic_kernel: str = "huber"
    acoustic_width: float = 2.5
    gnss_bias: bool = False
    bias_sigma_m: float = 1.5
    bias_tau_s: float = 30.0
    range_kernel: str = "cauchy"
    range_width: float = 2.5
    range_extra_sigma_m: float = 0.0
    lm_max_iterations: int = 50
    lm_rel_tol: float = 1e-6
    isam_relin_threshold: float = 0.1
    isam_relin_skip: int = 10
    lag_s: float = 5.0
    lag_smoother: str = "incremental"
    min_var_m2: float = 1e-8

    def __post_init__(self):
        for name in ("sigma_step_length_m", "sigma_heading_rad", "q_walk_m2_s", "q_stand_m2_s", "q_heading_rad2_s",
                     "q_scale_1_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise GraphError(f"{name} must be finite and >= 0, got {v!r}")
        for name in ("sigma0_pos_m", "sigma0_heading_rad", "sigma0_scale", "calib_block_s", "gnss_width",
                     "acoustic_width", "range_width", "bias_sigma_m", "bias_tau_s", "lm_rel_tol", "isam_relin_threshold", "lag_s", "min_var_m2"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise GraphError(f"{name} must be finite and > 0, got {v!r}")
        if not (math.isfinite(self.range_extra_sigma_m) and self.range_extra_sigma_m >= 0):
            raise GraphError(f"range_extra_sigma_m must be finite and >= 0, got {self.range_extra_sigma_m!r}")
        for name in ("gnss_kernel", "acoustic_kernel", "range_kernel"):
            if getattr(self, name) not in KERNELS:
                raise GraphError(f"{name} must be one of {KERNELS}, got {getattr(self, name)!r}")
        if self.lag_smoother not in ("incremental", "batch"):
            raise GraphError(f"lag_smoother must be 'incremental' or 'batch', got {self.lag_smoother!r}")
        for name in ("lm_max_iterations", "isam_relin_skip"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise GraphError(f"{name} must be an integer >= 1, got {v!r}")

    @classmethod
    def from_ekf(cls, ekf, **overrides) -> "GraphConfig":
        """The motion model and priors of an :class:`~models.fusion.ekf.EkfConfig`, the Huber width its
        ``huber_k``; ``overrides`` set any other field."""
        shared = {f.name: getattr(ekf, f.name) for f in fields(cls) if hasattr(ekf, f.name)}
        shared.setdefault("gnss_width", ekf.huber_k)
        shared.setdefault("acoustic_width", ekf.huber_k)
        shared.update(overrides)
        return cls(**shared)
