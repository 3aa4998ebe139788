"""Rauch–Tung–Striebel smoothing of an event-driven filter run.

Rauch, Tung & Striebel (1965), AIAA J. 3(8); in the extended form for a
linearised step model (the extended RTS smoother, Särkkä 2013, *Bayesian
Filtering and Smoothing*, ch. 9), backwards over the events, k = m − 2 … 0
(the step is :func:`models.fusion.core.rts_step`, compiled)::

    # C_k = P_k F'_{k+1} (P⁻_{k+1})⁻¹
    # x^s_k = x_k + C_k (x^s_{k+1} − x⁻_{k+1})
    # P^s_k = P_k + C_k (P^s_{k+1} − P⁻_{k+1}) C'_k

with x⁻, P⁻ the priors and F the Jacobians a :class:`~models.fusion.ekf.FilterRun`
stores (identity between fixes, the step Jacobian on steps). It needs nothing
else, so it smooths every method's run, the multiple-model one included — for
that it smooths the moment-matched mixture (an approximation of the IMM
smoother of Helmick, Blair & Hoffman 1995, stated as such).

:func:`fixed_lag_smooth` runs the same recursion from the last event within a
lag back to each event: the estimate ``envfuse run`` can give a few seconds
late instead of at the end of the walk.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SmoothedTrack", "rts_smooth", "fixed_lag_smooth", "smoother_gains"]


@dataclass(frozen=True)
class SmoothedTrack:
    """Smoothed state per event: ``t_s`` (m,), ``x`` (m, n), ``P`` (m, n, n), ``method`` (e.g. ``"kf+rts"``)."""

    method: str
    t_s: np.ndarray
    kind: np.ndarray
    x: np.ndarray
    P: np.ndarray

    @property
    def east_m(self) -> np.ndarray:
        return self.x[:, 0]

    @property
    def north_m(self) -> np.ndarray:
        return self.x[:, 1]

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def smoother_gains(run) -> np.ndarray:
    """C_k = P_k F'_{k+1} (P⁻_{k+1})⁻¹ of every event but the last, (m − 1, n, n): solved as
    (P⁻_{k+1})⁻¹ F_{k+1} P_k, transposed, since P⁻ and P are symmetric (the gains do not depend on the
    smoothed values, so all at once)."""
    return np.swapaxes(np.linalg.solve(run.P_prior[1:], run.F[1:] @ run.P[:-1]), 1, 2)


def fixed_lag_smooth(run, lag_s: float) -> SmoothedTrack:
    """Fixed-lag smoothing of a filter run: the estimate at each event from every event up to ``lag_s`` later
    (Särkkä 2013, §12.5: the RTS recursion run back from the last event within the lag), so the track lags
    the walk by ``lag_s`` and no more. ``lag_s`` = 0 gives the filter's track; ∞, the RTS smoother's.
    Returns a :class:`SmoothedTrack` named ``<method>+lag``."""
    from models.fusion.core import fixed_lag_pass

    if not lag_s >= 0:
        raise ValueError(f"lag_s must be >= 0, got {lag_s}")
    m = run.x.shape[0]
    if m < 2:
        return SmoothedTrack(f"{run.method}+lag", run.t_s, run.kind, run.x.copy(), run.P.copy())
    xs, Ps = fixed_lag_pass(np.asarray(run.t_s, float), run.x, run.P, run.x_prior, run.P_prior,
                            smoother_gains(run), float(lag_s))
    return SmoothedTrack(f"{run.method}+lag", run.t_s, run.kind, xs, Ps)


def rts_smooth(run) -> SmoothedTrack:
    """Smooth a filter run (any object with ``x``, ``P``, ``x_prior``, ``P_prior``, ``F``, ``t_s``, ``kind``).

    Returns a :class:`SmoothedTrack` named ``<method>+rts``; its last row equals the filter's.
    """
    from models.fusion.core import rts_pass

    x, P = run.x, run.P
    if x.shape[0] < 2:
        return SmoothedTrack(f"{run.method}+rts", run.t_s, run.kind, x.copy(), P.copy())
    xs, Ps = rts_pass(x, P, run.x_prior, run.P_prior, smoother_gains(run))
    return SmoothedTrack(f"{run.method}+rts", run.t_s, run.kind, xs, Ps)
