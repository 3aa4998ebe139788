"""The federated Kalman filter's master fusion and information sharing (Carlson 1990).

Carlson, N. A. (1990), "Federated square root filter for decentralized parallel processes", IEEE Trans.
Aerosp. Electron. Syst. 26(3):517–525. N local filters share one error state (here the foot INS's); each
processes its own sensor. The master fuses their estimates in information form:

    P_g⁻¹ = Σᵢ Pᵢ⁻¹,        x_g = P_g Σᵢ Pᵢ⁻¹ xᵢ

and then shares the fused information back by the factors βᵢ (Σ βᵢ = 1; the master keeps no share here,
β_m = 0, as it has no sensor of its own):

    xᵢ = x_g,   Pᵢ = P_g / βᵢ,   and between fusions each local filter's process noise is Qᵢ = Q / βᵢ.

Splitting the prior and Q this way makes the local filters' errors uncorrelated, so the information sum is
exact: with a reset after every local update ("fusion-reset" mode) the federated filter reproduces the
centralised Kalman filter whatever the βᵢ (Carlson 1990). The βᵢ then set how much each local filter leans
on its own sensor between fusions and how wide its innovation gate is (its S = H P_g H'/βᵢ + R).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["fuse_information", "share_information", "SharingFactors"]


@njit(cache=True)
def fuse_information(x, P, active):
    """Master fusion of the active local filters: (x_g (n,), P_g (n, n)) from x (N, n), P (N, n, n), active (N,)
    bool — P_g⁻¹ = Σᵢ Pᵢ⁻¹, x_g = P_g Σᵢ Pᵢ⁻¹ xᵢ (Carlson 1990)."""
    n = x.shape[1]
    if np.sum(active) == 1:
        # one local filter holds all the information (β = 1): the fusion is the identity
        for i in range(x.shape[0]):
            if active[i]:
                return x[i].copy(), P[i].copy()
    info = np.zeros((n, n))
    y = np.zeros(n)
    for i in range(x.shape[0]):
        if active[i]:
            Pi = np.linalg.inv(P[i])
            # Σ Pᵢ⁻¹;  Σ Pᵢ⁻¹ xᵢ
            info += Pi
            y += Pi @ x[i]
    # P_g = (Σ Pᵢ⁻¹)⁻¹
    Pg = np.linalg.inv(info)
    Pg = 0.5 * (Pg + Pg.T)
    # x_g = P_g Σ Pᵢ⁻¹ xᵢ
    return Pg @ y, Pg


@njit(cache=True)
def share_information(xg, Pg, beta, active, x, P):
    """Reset every active local filter to the fused estimate with its share: xᵢ = x_g, Pᵢ = P_g / βᵢ
    (in place on x (N, n), P (N, n, n))."""
    for i in range(x.shape[0]):
        if active[i]:
            x[i] = xg
            P[i] = Pg / beta[i]


@dataclass(frozen=True)
class SharingFactors:
    """Information-sharing factors β of the three local filters (ZUPT-INS, UWB position, magnetic heading).

    Default: equal shares over the local filters a walk has (1/3 each; 1/2 each without UWB). Why: with a
    fusion after every local update the fused estimate does not depend on β (module docstring), so β only
    scales each local prior, P_g/β — it sets the width of each local innovation gate and how far a local
    filter follows its own sensor between fusions. No sensor is trusted more a priori, so no local filter's
    gate is made looser than another's; Carlson's equal split. ``normalised`` renormalises over the
    active filters so that Σ β = 1 (the master keeps no share).
    """

    zupt: float = 1.0 / 3.0
    uwb: float = 1.0 / 3.0
    heading: float = 1.0 / 3.0

    def __post_init__(self):
        for name in ("zupt", "uwb", "heading"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0.0 < v <= 1.0):
                raise ValueError(f"SharingFactors.{name} must lie in (0, 1], got {v}")

    def normalised(self, active) -> np.ndarray:
        """β (3,) over the active local filters, summing to 1 (inactive ones keep 1: never used)."""
        a = np.asarray(active, bool)
        if not a.any():
            raise ValueError("at least one local filter must be active")
        b = np.array([self.zupt, self.uwb, self.heading])
        out = np.ones(3)
        out[a] = b[a] / b[a].sum()
        return out
