"""Rauch–Tung–Striebel smoothing of an event-driven filter run.

Rauch, Tung & Striebel (1965), AIAA J. 3(8); in the extended form for a
linearised step model (the extended RTS smoother, Särkkä 2013, *Bayesian
Filtering and Smoothing*, ch. 9), backwards over the events, k = m − 2 … 0::

    # C_k = P_k F'_{k+1} (P⁻_{k+1})⁻¹
    # x^s_k = x_k + C_k (x^s_{k+1} − x⁻_{k+1})
    # P^s_k = P_k + C_k (P^s_{k+1} − P⁻_{k+1}) C'_k

with x⁻, P⁻ the priors and F the Jacobians a :class:`~models.fusion.ekf.FilterRun`
stores (identity between fixes, the step Jacobian on steps). It needs nothing
else, so it smooths every method's run, the multiple-model one included — for
that it smooths the moment-matched mixture (an approximation of the IMM
smoother of Helmick, Blair & Hoffman 1995, stated as such).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SmoothedTrack", "rts_smooth"]


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


def rts_smooth(run) -> SmoothedTrack:
    """Smooth a filter run (any object with ``x``, ``P``, ``x_prior``, ``P_prior``, ``F``, ``t_s``, ``kind``).

    Returns a :class:`SmoothedTrack` named ``<method>+rts``; its last row equals the filter's.
    """
    x, P, xp, Pp, F = run.x, run.P, run.x_prior, run.P_prior, run.F
    m = x.shape[0]
    xs = np.empty_like(x)
    Ps = np.empty_like(P)
    xs[-1], Ps[-1] = x[-1], P[-1]
    if m < 2:
        return SmoothedTrack(f"{run.method}+rts", run.t_s, run.kind, xs, Ps)
    # C_k = P_k F'_{k+1} (P⁻_{k+1})⁻¹ for all k at once (the gains do not depend on the smoothed values):
    # solved as (P⁻_{k+1})⁻¹ F_{k+1} P_k, transposed, since P⁻ and P are symmetric
    C = np.swapaxes(np.linalg.solve(Pp[1:], F[1:] @ P[:-1]), 1, 2)
    xs_next = xs[-1]
    Ps_next = Ps[-1]
    for k in range(m - 2, -1, -1):
        Ck = C[k]
        # x^s = x + C (x^s_{k+1} − x⁻_{k+1})
        xk = x[k] + Ck @ (xs_next - xp[k + 1])
        # P^s = P + C (P^s_{k+1} − P⁻_{k+1}) C'
        Pk = P[k] + Ck @ (Ps_next - Pp[k + 1]) @ Ck.T
        Pk = 0.5 * (Pk + Pk.T)
        xs[k], Ps[k] = xk, Pk
        xs_next, Ps_next = xk, Pk
    return SmoothedTrack(f"{run.method}+rts", run.t_s, run.kind, xs, Ps)
