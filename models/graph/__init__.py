"""Factor-graph fusion on GTSAM: the walk as a graph of PDR, GNSS and acoustic factors.

Pure maths on in-memory event streams (:mod:`models.fusion.events`), like :mod:`models.fusion`; gtsam is
imported inside the functions that need it, so importing this package stays cheap. Which module to
open for what:

* ``config`` — :class:`GraphConfig` (motion model from the EKF's, kernels, solver settings);
* ``build`` — variables at every event time, PDR between-factors with a linear calibration
  (heading offset and step scale), GNSS / acoustic position factors;
* ``robust`` — Huber, Cauchy and DCS kernels, and :class:`KernelTable`, their widths per environment
  class fitted on training walks (its blind twin: the same fit without classes);
* ``solve`` — batch Levenberg–Marquardt, causal iSAM2, fixed-lag smoothing;
* ``tight`` — tightly coupled acoustic range factors with a receiver clock per frame (fixed lag);
* ``ins`` — IMU preintegration factors (the seed's SINS/GNSS form) with GNSS and acoustic factors;
* ``model`` — :class:`GraphModel`, the fitted parameters, stored as JSON (no pickle).
"""

from models.graph.build import FixNoise, GraphPlan, graph_factors, plan_nodes
from models.graph.config import KERNELS, GraphConfig, GraphError
from models.graph.robust import KernelTable, cauchy_weight, dcs_weight, fit_scale_mixture, huber_weight
from models.graph.solve import GraphRun, solve_batch, solve_fixed_lag, solve_isam2

__all__ = ["GraphConfig", "GraphError", "KERNELS", "FixNoise", "GraphPlan", "graph_factors", "plan_nodes",
           "KernelTable", "huber_weight", "cauchy_weight", "dcs_weight", "fit_scale_mixture", "GraphRun",
           "solve_batch", "solve_isam2", "solve_fixed_lag"]
