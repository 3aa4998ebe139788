"""The fitted parameters of the graph methods and the RTK/PDR EKF, stored as JSON (no pickle).

:class:`GraphModel` holds what ``training.graph_fit`` learns on training walks:

* ``kernels_env`` — the environment-aware :class:`~models.graph.robust.KernelTable` (scale and DCS Φ per
  class and GGA quality), ``kernels_blind`` — its blind twin (the same fit without classes);
* ``step_k``, ``step_beta`` — the improved step-length model of the RTK/PDR EKF (Zhang et al. 2023;
  :class:`features.imu.steps.StepLengthModel`), None when not fitted;
* ``heading_tau_s`` — the time constant of its complementary heading filter, β = τ/(τ + ΔT).

Until the fusion model has a field for it, a :class:`GraphModel` travels in the fusion model's
metadata (``FusionModel.meta["graph_model"]``, written to ``bundle.json`` as JSON by
:func:`models.fusion.model.save_fusion_model`): :func:`attach_graph_model` puts it there,
:func:`graph_model_of` reads it back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from models.graph.config import GraphError
from models.graph.robust import KernelTable

__all__ = ["GraphModel", "attach_graph_model", "graph_model_of", "META_KEY"]

META_KEY = "graph_model"
"""Key of the graph model in ``FusionModel.meta``."""

FORMAT_VERSION = 1


@dataclass(frozen=True)
class GraphModel:
    """Fitted graph-method parameters (see the module docstring)."""

    kernels_env: KernelTable | None = None
    kernels_blind: KernelTable | None = None
    step_k: float | None = None
    step_beta: float | None = None
    heading_tau_s: float = 2.0
    meta: dict | None = None

    def __post_init__(self):
        if not (math.isfinite(self.heading_tau_s) and self.heading_tau_s > 0):
            raise GraphError(f"heading_tau_s must be finite and > 0, got {self.heading_tau_s}")
        if (self.step_k is None) != (self.step_beta is None):
            raise GraphError("step_k and step_beta are fitted together: give both or neither")
        if self.step_k is not None and not (math.isfinite(self.step_k) and self.step_k > 0
                                            and math.isfinite(self.step_beta)):
            raise GraphError(f"step model K={self.step_k}, beta={self.step_beta} is not usable")

    def get_state(self) -> dict:
        """JSON-able state."""
        return {"format_version": FORMAT_VERSION,
                "kernels_env": self.kernels_env.get_state() if self.kernels_env is not None else None,
                "kernels_blind": self.kernels_blind.get_state() if self.kernels_blind is not None else None,
                "step_k": self.step_k, "step_beta": self.step_beta, "heading_tau_s": self.heading_tau_s,
                "meta": dict(self.meta or {})}

    @classmethod
    def from_state(cls, state: dict) -> "GraphModel":
        if not isinstance(state, dict):
            raise GraphError(f"graph model state must be a mapping, got {type(state).__name__}")
        if state.get("format_version", 0) > FORMAT_VERSION:
            raise GraphError(f"graph model written by a newer envfuse (format {state.get('format_version')})")
        try:
            env = KernelTable.from_state(state["kernels_env"]) if state.get("kernels_env") else None
            blind = KernelTable.from_state(state["kernels_blind"]) if state.get("kernels_blind") else None
            k = state.get("step_k")
            b = state.get("step_beta")
            return cls(env, blind, None if k is None else float(k), None if b is None else float(b),
                       float(state.get("heading_tau_s", 2.0)), dict(state.get("meta") or {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise GraphError(f"graph model state is malformed ({exc})") from None


def attach_graph_model(fusion_model, graph_model: GraphModel) -> None:
    """Store ``graph_model`` in ``fusion_model.meta`` (saved with it as JSON)."""
    fusion_model.meta[META_KEY] = graph_model.get_state()


def graph_model_of(fusion_model) -> GraphModel | None:
    """The graph model stored in ``fusion_model.meta``, or None."""
    state = (fusion_model.meta or {}).get(META_KEY)
    return None if state is None else GraphModel.from_state(state)
