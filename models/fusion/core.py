"""The one Kalman filter core: time update, PDR step, position update (Joseph form, NIS, gate, Huber), compiled.

Every event-driven filter of envfuse runs these functions and no others:
:class:`~models.fusion.ekf.EventEKF` through :func:`run_ekf_events`, the IMM
(:mod:`models.fusion.imm`) through the same :func:`predict_step` and
:func:`kalman_update` per mode. They are written once, as matrix algebra with
the equation above each line (filterpy's habit), and compiled by numba
(``@njit(cache=True)``): the compiled loop is this text, not a hand-unrolled
twin. The small-matrix products are the loops of :func:`mm` / :func:`mmt` /
:func:`mv` rather than ``@``, because numba sends ``@`` to BLAS, whose call
costs ~0.5 µs on a 4×4 product (measured: 1.7 µs for H P H' against 0.2 µs
with the loops).

State (n ≥ 4): ``x = [east_m, north_m, δψ_rad, s, b...]`` — position, the PDR
heading offset δψ (true heading ψ + δψ), the step-scale error s (true length
(1 + s)·L), then any bias states. A measurement picks its own model per event:
``H`` of shape (2, n) from a stack of models (position only, or position plus
the bias block it shares), so bias states enter only the measurements they
describe.

Per event k (Δt since the previous one):

1. time update: x ← Φ x, P ← Φ P Φ' + Q with Φ = diag(φ_k) (φ = 1 for the
   position, heading and scale states, e^(−Δt/τ) for a first-order
   Gauss–Markov bias; Gelb 1974, *Applied Optimal Estimation*, ch. 3) and Q
   diagonal (the stationary random walks and the bias driving noise);
2. a PDR step of length L and heading ψ (θ = ψ + δψ, g = 1 + s):
   e += g·L·sin θ, n += g·L·cos θ, P ← F P F' + G diag(σ_L², σ_ψ²) G';
3. a position fix z with noise R: the EKF update of Bar-Shalom, Li &
   Kirubarajan (2001, ch. 5), the covariance in the Joseph form
   P = (I − KH) P (I − KH)' + K R K' (Bucy & Joseph 1968), which stays
   symmetric positive definite for any gain; outliers by the χ² validation
   gate on the NIS or by Huber (1964) weights w = min(1, k/√NIS) applied as R/w
   (the robust KF of Masreliez & Martin 1977 in its covariance-inflation form).

Noise modes of the EKF loop (``noise_mode``): R given per event (every static
policy of :mod:`models.fusion.noise`), R per class looked up in a site map at
the prior position (``kf_map``), or the variational-Bayes adaptive R of
Särkkä & Nummenmaa (2009) (:mod:`models.fusion.adaptive`).

Bias states are first-order Gauss–Markov processes whose φ and Q the caller
sets per event (a reset is φ = 0, Q = the prior variance); they may be
Schmidt consider states (estimated never, accounted for always).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["GATE", "HUBER", "NO_OUTLIER", "MIXTURE", "R_PER_EVENT", "R_MAP", "R_VB", "STEP_KIND", "mm", "mmt", "mv",
           "inv2", "time_update", "predict_step", "kalman_update", "mixture_update", "map_class", "run_ekf_events",
           "rts_step", "rts_pass", "fixed_lag_pass"]

GATE, HUBER, NO_OUTLIER, MIXTURE = 0, 1, 2, 3
"""Outlier handling codes: χ² gate, Huber weights, none, an ε-contaminated Gaussian likelihood
(:func:`mixture_update`, ε and κ given per fix)."""

MIXTURE_DROP = 1e-6
"""Weight below which :func:`mixture_update` drops a component of the Gaussian sum (most fixes are plainly
inliers: their outlier weight is far below this)."""

R_PER_EVENT, R_MAP, R_VB = 0, 1, 2
"""Noise modes of :func:`run_ekf_events`."""

STEP_KIND = 0
"""Event kind of a PDR step (:data:`models.fusion.events.STEP`)."""


@njit(cache=True)
def mm(A, B):
    """A B for small dense matrices (loops: no BLAS call)."""
    n, k = A.shape
    m = B.shape[1]
    C = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for l in range(k):
                s += A[i, l] * B[l, j]
            C[i, j] = s
    return C


@njit(cache=True)
def mmt(A, B):
    """A B' for small dense matrices (:func:`mm` on the transposed view)."""
    return mm(A, B.T)


@njit(cache=True)
def mv(A, v):
    """A v for a small dense matrix and vector."""
    n, k = A.shape
    out = np.zeros(n)
    for i in range(n):
        s = 0.0
        for l in range(k):
            s += A[i, l] * v[l]
        out[i] = s
    return out


@njit(cache=True)
def inv2(S):
    """Inverse and determinant of a 2×2 matrix: S⁻¹ = adj(S) / det S."""
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    Si = np.empty((2, 2))
    Si[0, 0] = S[1, 1] / det
    Si[1, 1] = S[0, 0] / det
    Si[0, 1] = -S[0, 1] / det
    Si[1, 0] = -S[1, 0] / det
    return Si, det


@njit(cache=True)
def time_update(x, P, phi, q):
    """x ← Φ x, P ← Φ P Φ' + diag(q) with Φ = diag(φ), in place; φ, q of shape (n,)."""
    n = x.shape[0]
    for i in range(n):
        # x = Φ x
        x[i] *= phi[i]
    for i in range(n):
        for j in range(n):
            # P = Φ P Φ'
            P[i, j] *= phi[i] * phi[j]
        # P += Q_Δt
        P[i, i] += q[i]


@njit(cache=True)
def predict_step(x, P, L, psi, sl2, sp2):
    """One PDR step of length ``L`` (m) and heading ``psi`` (rad); ``sl2``, ``sp2``: σ_L² (m²), σ_ψ² (rad²).

    Returns (x⁻, P⁻, F) with F the step Jacobian ∂f/∂x (n, n).
    """
    n = x.shape[0]
    g = 1.0 + x[3]
    th = psi + x[2]
    sn, cs = math.sin(th), math.cos(th)
    gl = g * L
    xp = x.copy()
    # e += (1+s)·L·sin(ψ+δψ),  n += (1+s)·L·cos(ψ+δψ)
    xp[0] += gl * sn
    xp[1] += gl * cs
    # F = ∂f/∂x: ∂e/∂δψ = gL cos θ, ∂e/∂s = L sin θ, ∂n/∂δψ = −gL sin θ, ∂n/∂s = L cos θ
    F = np.eye(n)
    F[0, 2] = gl * cs
    F[0, 3] = L * sn
    F[1, 2] = -gl * sn
    F[1, 3] = L * cs
    # P⁻ = F P F'
    Pp = mmt(mm(F, P), F)
    # Q_step = G diag(σ_L², σ_ψ²) G',  G = ∂(e, n)/∂(L, ψ) = [[g sin θ, gL cos θ], [g cos θ, −gL sin θ]]
    vl = g * g * sl2
    vp = gl * gl * sp2
    Pp[0, 0] += vl * sn * sn + vp * cs * cs
    Pp[1, 1] += vl * cs * cs + vp * sn * sn
    c = (vl - vp) * sn * cs
    Pp[0, 1] += c
    Pp[1, 0] += c
    return xp, Pp, F


@njit(cache=True)
def kalman_update(x, P, z, R, H, outlier, gate_nis, huber_k, joseph, consider=None):
    """One position update of the prior (x⁻ (n,), P⁻ (n, n)) by the fix z (2,) with noise R (2, 2), H (2, n).

    Returns (x, P, ν, S, K, R_used, NIS, weight, accepted). The NIS is that of the unweighted S; with Huber
    weights ``S``, ``K`` and ``R_used`` are those of R/w; a gated fix returns the prior unchanged, weight 0
    and K = 0. ``consider`` (n,) bool marks Schmidt consider states (Schmidt 1966): their rows of K are
    zero, so they are never estimated but their uncertainty still enters every other state's update (the
    Joseph form keeps P exact for that suboptimal gain).
    """
    n = x.shape[0]
    # ν = z − H x⁻
    nu = z - mv(H, x)
    PHt = mmt(P, H)
    HPH = mm(H, PHt)
    # S = H P⁻ H' + R
    S = HPH + R
    Si, det = inv2(S)
    # NIS = ν' S⁻¹ ν
    nis = nu[0] * (Si[0, 0] * nu[0] + Si[0, 1] * nu[1]) + nu[1] * (Si[1, 0] * nu[0] + Si[1, 1] * nu[1])
    w = 1.0
    if outlier == GATE and nis > gate_nis:
        return x, P, nu, S, np.zeros((n, 2)), R, nis, 0.0, False
    if outlier == HUBER:
        d = math.sqrt(max(nis, 0.0))
        if d > huber_k:
            # w = k / √NIS,  R ← R / w   (Huber weight on the Mahalanobis norm)
            w = huber_k / d
            R = R / w
            # S = H P⁻ H' + R/w
            S = HPH + R
            Si, det = inv2(S)
    # K = P⁻ H' S⁻¹
    K = mm(PHt, Si)
    if consider is not None:
        for i in range(n):
            if consider[i]:
                # K_i = 0 for a consider state (Schmidt–Kalman)
                K[i, 0] = 0.0
                K[i, 1] = 0.0
    # x = x⁻ + K ν
    xn = x + mv(K, nu)
    # K H P⁻ = K (P⁻H')'   (n × n from n × 2 products: P⁻ is symmetric)
    KHP = mmt(K, PHt)
    if joseph:
        # P = (I − KH) P⁻ (I − KH)' + K R K'   (Joseph form: symmetric PD for any K), expanded as
        # P = P⁻ − K H P⁻ − (K H P⁻)' + K (H P⁻ H' + R) K' = P⁻ − KHP⁻ − (KHP⁻)' + K S K'
        Pn = P - KHP - KHP.T + mmt(mm(K, S), K)
    else:
        # P = (I − KH) P⁻   (short form: exact for the optimal K only)
        Pn = P - KHP
    # P = (P + P') / 2
    Pn = 0.5 * (Pn + Pn.T)
    return xn, Pn, nu, S, K, R, nis, w, True


@njit(cache=True)
def mixture_update(x, P, z, R, H, eps, kappa, joseph, consider=None):
    """A fix whose noise is an ε-contaminated Gaussian: N(0, R) with probability 1 − ε, N(0, κR) with ε.

    The exact posterior is a two-component Gaussian sum (Sorenson & Alspach 1971); it is collapsed to its
    mean and covariance (the moment matching of the IMM, Bar-Shalom, Li & Kirubarajan 2001, §11.6):
    with ν = z − Hx⁻, S₁ = HP⁻H' + R, S₂ = HP⁻H' + κR,

        β = ε N(ν; 0, S₂) / ((1 − ε) N(ν; 0, S₁) + ε N(ν; 0, S₂))      (the fix's outlier probability)
        x = (1 − β) x₁ + β x₂,  P = Σ_i w_i (P_i + (x_i − x)(x_i − x)')

    with (x_i, P_i) the Kalman updates under R and κR. Returns what :func:`kalman_update` returns, with the
    inlier model's ν, S, R and NIS, the mixed gain K = (1 − β)K₁ + βK₂ and weight 1 − β.
    """
    # ν = z − Hx⁻;  S₁ = HP⁻H' + R;  S₂ = HP⁻H' + κR
    nu = z - mv(H, x)
    HPH = mm(H, mmt(P, H))
    Rk = kappa * R
    Si1, det1 = inv2(HPH + R)
    Si2, det2 = inv2(HPH + Rk)
    nis = nu[0] * (Si1[0, 0] * nu[0] + Si1[0, 1] * nu[1]) + nu[1] * (Si1[1, 0] * nu[0] + Si1[1, 1] * nu[1])
    nis2 = nu[0] * (Si2[0, 0] * nu[0] + Si2[0, 1] * nu[1]) + nu[1] * (Si2[1, 0] * nu[0] + Si2[1, 1] * nu[1])
    # ln of (1 − ε) N(ν; S₁) and ε N(ν; S₂), the common −ln 2π dropped
    l1 = math.log(max(1.0 - eps, 1e-300)) - 0.5 * (nis + math.log(det1))
    l2 = math.log(max(eps, 1e-300)) - 0.5 * (nis2 + math.log(det2))
    top = max(l1, l2)
    # β = ε N₂ / ((1 − ε) N₁ + ε N₂)
    beta = math.exp(l2 - top) / (math.exp(l1 - top) + math.exp(l2 - top))
    if beta < MIXTURE_DROP:
        # a component of weight below MIXTURE_DROP is dropped (and its update not computed): it would move
        # the mean by less than that fraction of the two updates' difference
        beta = 0.0
    elif beta > 1.0 - MIXTURE_DROP:
        beta = 1.0
    if beta < 1.0:
        x1, P1, _, S1, K1, _, _, _, _ = kalman_update(x, P, z, R, H, NO_OUTLIER, 0.0, 1.0, joseph, consider)
    if beta > 0.0:
        x2, P2, _, S2, K2, _, _, _, _ = kalman_update(x, P, z, Rk, H, NO_OUTLIER, 0.0, 1.0, joseph, consider)
    if beta == 0.0:
        return x1, P1, nu, S1, K1, R, nis, 1.0, True
    if beta == 1.0:
        return x2, P2, nu, HPH + R, K2, R, nis, 0.0, True
    # x = (1 − β) x₁ + β x₂
    xn = (1.0 - beta) * x1 + beta * x2
    d1 = x1 - xn
    d2 = x2 - xn
    n = x.shape[0]
    Pn = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            # P = (1 − β)(P₁ + d₁d₁') + β (P₂ + d₂d₂')
            Pn[i, j] = (1.0 - beta) * (P1[i, j] + d1[i] * d1[j]) + beta * (P2[i, j] + d2[i] * d2[j])
    K = (1.0 - beta) * K1 + beta * K2
    return xn, 0.5 * (Pn + Pn.T), nu, S1, K, R, nis, 1.0 - beta, True


@njit(cache=True)
def map_class(grid, geo, east_m, north_m):
    """Class code of the map cell nearest (east_m, north_m) (a point half-way between two centres takes the
    east / north one): ``grid`` (n_north, n_east) int, ``geo`` = (east of column 0, north of row 0, column
    spacing, row spacing), m; clipped at the map's edge."""
    ni, nj = grid.shape
    i = min(max(int(math.floor((north_m - geo[1]) / geo[3] + 0.5)), 0), ni - 1)
    j = min(max(int(math.floor((east_m - geo[0]) / geo[2] + 0.5)), 0), nj - 1)
    return grid[i, j]


@njit(cache=True)
def _vb_prior(alpha, beta, cap, s, rho):
    """VB-AKF forgetting and the first iterate of source ``s`` (Särkkä & Nummenmaa 2009, eqs. 20–21):
    α⁻ = ρα + ½ per axis, β⁻ = ρβ, R = diag(min(β⁻/α, cap)). Returns (α, β⁻, R)."""
    a = np.empty(2)
    bp = np.empty(2)
    R = np.zeros((2, 2))
    for i in range(2):
        # α = ρ·α + 1/2,  β⁻ = ρ·β   (the heuristic forgetting dynamics, one measurement per axis)
        a[i] = rho * alpha[s, i] + 0.5
        bp[i] = rho * beta[s, i]
        # R = diag(β⁻ / α), at most the cap
        R[i, i] = min(bp[i] / a[i], cap[s, i])
    return a, bp, R


@njit(cache=True)
def _vb_refine(a, bp, cap_s, res, HPH):
    """VB-AKF fixed-point step: β = β⁻ + ½ (z − Hx)² + ½ diag(H P H'), R = diag(min(β/α, cap)).
    Returns (β, R)."""
    b = np.empty(2)
    R = np.zeros((2, 2))
    for i in range(2):
        b[i] = bp[i] + 0.5 * (res[i] * res[i] + HPH[i, i])
        R[i, i] = min(b[i] / a[i], cap_s[i])
    return b, R


@njit(cache=True)
def _vb_update(x, P, z, H, s, alpha, beta, cap, rho, n_iter, outlier, gate_nis, huber_k, joseph):
    """A fix through the variational-Bayes adaptive R (Särkkä & Nummenmaa 2009, algorithm 1), in place of the
    policy state α, β (3, 2). The gate and Huber weight act on the first iterate; further iterates update from
    the same prior with the refined R. Returns what :func:`kalman_update` returns (NIS of the first iterate)."""
    a, bp, R = _vb_prior(alpha, beta, cap, s, rho)
    xn, Pn, nu, S, K, Ru, nis, w, ok = kalman_update(x, P, z, R, H, outlier, gate_nis, huber_k, joseph)
    if not ok:
        return xn, Pn, nu, S, K, Ru, nis, w, ok
    b = bp.copy()
    for _ in range(1, n_iter):
        # variational step: R from the residual of this iterate, then the update again from the prior
        b, Ru = _vb_refine(a, bp, cap[s], z - mv(H, xn), mm(H, mmt(Pn, H)))
        xn, Pn, _, _, K, _, _, _, _ = kalman_update(x, P, z, Ru, H, NO_OUTLIER, gate_nis, huber_k, joseph)
    # the posterior residual sets this update's β
    b, _ = _vb_refine(a, bp, cap[s], z - mv(H, xn), mm(H, mmt(Pn, H)))
    for i in range(2):
        alpha[s, i] = a[i]
        beta[s, i] = b[i]
    # S = H P⁻ H' + R of the last iterate
    S = mm(H, mmt(P, H)) + Ru
    return xn, Pn, nu, S, K, Ru, nis, w, ok


@njit(cache=True)
def run_ekf_events(kind, avail, z, length_m, heading_rad, phi, q, h_idx, H, x0, P0, sl2, sp2, outlier, gate_nis,
                   huber_k, joseph, consider, noise_mode, r_event, eps_event, kappa_event, r_table, map_grid, map_geo,
                   vb_alpha, vb_beta, vb_cap, vb_rho, vb_n_iter, x_prior, P_prior, F_rec, x_post, P_post, nu_rec,
                   S_rec, K_rec, R_rec, nis_rec, w_rec, updated, accepted, restart, x_restart,
                   P_restart, vb_alpha_restart, vb_beta_restart, vb_alpha_rec, vb_beta_rec):
    """Filter m events once, writing the records in place (shapes: see :class:`~models.fusion.ekf.FilterRun`).

    Per event: ``kind`` (m,) step/GNSS/acoustic code, ``avail`` (m,) a fix may update, ``z`` (m, 2),
    ``length_m``, ``heading_rad`` (m,) of steps, ``phi``, ``q`` (m, n) the time update's Φ diagonal and Q
    diagonal (a reset of a bias state is φ = 0, q = its prior variance), ``h_idx`` (m,) the row of ``H``
    (n_models, 2, n) a fix uses; ``consider`` (n,) the Schmidt consider states. Noise (``noise_mode``):
    ``r_event`` (m, 2, 2); or ``r_table`` (3, n_classes, 2, 2) per kind and class with the map ``map_grid``,
    ``map_geo``; or the VB-AKF state ``vb_alpha``, ``vb_beta``, ``vb_cap`` (3, 2), updated in place. With
    ``outlier`` = :data:`MIXTURE`, ``eps_event`` and ``kappa_event`` (m,) give each fix's outlier prior and
    variance ratio. ``restart`` ≥ 0 (−1: none): the posterior before event ``restart`` is replaced by ``x_restart`` (n,),
    ``P_restart`` (n, n) — the filter resumed from another run's state there (a long walk's previous segment,
    :class:`~models.fusion.ekf.FilterResume`); the events before it are filtered from ``x0``, ``P0`` as usual.
    With the VB-AKF, ``vb_alpha_restart``, ``vb_beta_restart`` (3, 2) replace its α, β there too (the noise
    estimate the other run had reached), and ``vb_alpha_rec``, ``vb_beta_rec`` (m, 3, 2) record α, β after
    every event (size 0 for the other noise modes: not recorded).
    """
    m = kind.shape[0]
    x = x0.copy()
    P = P0.copy()
    record_vb = noise_mode == R_VB and vb_alpha_rec.shape[0] == m
    for k in range(m):
        if k == restart:
            x = x_restart.copy()
            P = P_restart.copy()
            if noise_mode == R_VB:
                vb_alpha[:, :] = vb_alpha_restart
                vb_beta[:, :] = vb_beta_restart
        # 1. x = Φ x;  P = Φ P Φ' + Q_Δt
        time_update(x, P, phi[k], q[k])
        if kind[k] == STEP_KIND:
            # 2. the PDR step;  F = F_step Φ   (bias decay first, then the step)
            x, P, Fs = predict_step(x, P, length_m[k], heading_rad[k], sl2, sp2)
            F_rec[k] = Fs * phi[k]
        else:
            for i in range(x.shape[0]):
                F_rec[k, i, i] = phi[k, i]
        x_prior[k] = x
        P_prior[k] = P
        if kind[k] != STEP_KIND and avail[k]:
            Hk = H[h_idx[k]]
            if noise_mode == R_VB:
                out = _vb_update(x, P, z[k], Hk, kind[k], vb_alpha, vb_beta, vb_cap, vb_rho, vb_n_iter, outlier,
                                 gate_nis, huber_k, joseph)
            else:
                if noise_mode == R_MAP:
                    Rk = r_table[kind[k], map_class(map_grid, map_geo, x[0], x[1])]
                else:
                    Rk = r_event[k]
                if outlier == MIXTURE:
                    out = mixture_update(x, P, z[k], Rk, Hk, eps_event[k], kappa_event[k], joseph, consider)
                else:
                    out = kalman_update(x, P, z[k], Rk, Hk, outlier, gate_nis, huber_k, joseph, consider)
            xn, Pn, nu, S, K, Ru, nis, w, ok = out
            nu_rec[k] = nu
            S_rec[k] = S
            R_rec[k] = Ru
            nis_rec[k] = nis
            w_rec[k] = w
            updated[k] = True
            accepted[k] = ok
            if ok:
                K_rec[k] = K
                x, P = xn, Pn
        x_post[k] = x
        P_post[k] = P
        if record_vb:
            vb_alpha_rec[k] = vb_alpha
            vb_beta_rec[k] = vb_beta


@njit(cache=True)
def rts_step(x, P, xp_next, Pp_next, C, xs_next, Ps_next, xs, Ps, T):
    """One backward step of the RTS smoother (Rauch, Tung & Striebel 1965), written into ``xs`` (n,) and ``Ps``
    (n, n); ``T`` (n, n) is work space. The smoothers run it tens of times per event (:func:`fixed_lag_pass`),
    so it writes into buffers rather than allocating five arrays a step (over a third of the fixed-lag pass's time);
    each sum is the one :func:`mv` / :func:`mm` form, in the same order, so the result is theirs to the bit."""
    n = x.shape[0]
    # x^s = x + C (x^s_{k+1} − x⁻_{k+1})
    for i in range(n):
        s = 0.0
        for l in range(n):
            s += C[i, l] * (xs_next[l] - xp_next[l])
        xs[i] = x[i] + s
    # T = C (P^s_{k+1} − P⁻_{k+1})
    for i in range(n):
        for j in range(n):
            s = 0.0
            for l in range(n):
                s += C[i, l] * (Ps_next[l, j] - Pp_next[l, j])
            T[i, j] = s
    # P^s = P + T C', then symmetrised: ½ (P^s + P^s')
    for i in range(n):
        for j in range(n):
            s = 0.0
            for l in range(n):
                s += T[i, l] * C[j, l]
            Ps[i, j] = P[i, j] + s
    for i in range(n):
        for j in range(i, n):
            v = 0.5 * (Ps[i, j] + Ps[j, i])
            Ps[i, j] = v
            Ps[j, i] = v


@njit(cache=True)
def fixed_lag_pass(t, x, P, xp, Pp, C, lag_s):
    """The fixed-lag smoothed state of every event: the RTS recursion (:func:`rts_step`) from the last event at
    most ``lag_s`` after it back to it. Shapes: t (m,), x, xp (m, n), P, Pp (m, n, n), C (m − 1, n, n)."""
    m, n = x.shape
    xs_out = np.empty((m, n))
    Ps_out = np.empty((m, n, n))
    # the step reads one pair of buffers and writes the other
    xs, Ps, xs_new, Ps_new, T = np.empty(n), np.empty((n, n)), np.empty(n), np.empty((n, n)), np.empty((n, n))
    j = 0
    for k in range(m):
        if j < k:
            j = k
        while j + 1 < m and t[j + 1] <= t[k] + lag_s:
            j += 1
        xs[:] = x[j]
        Ps[:, :] = P[j]
        for i in range(j - 1, k - 1, -1):
            rts_step(x[i], P[i], xp[i + 1], Pp[i + 1], C[i], xs, Ps, xs_new, Ps_new, T)
            xs, xs_new = xs_new, xs
            Ps, Ps_new = Ps_new, Ps
        xs_out[k] = xs
        Ps_out[k] = Ps
    return xs_out, Ps_out


@njit(cache=True)
def rts_pass(x, P, xp, Pp, C):
    """The RTS smoothed state of every event (:func:`rts_step` from the last event back); shapes as
    :func:`fixed_lag_pass`."""
    m, n = x.shape
    xs_out = np.empty((m, n))
    Ps_out = np.empty((m, n, n))
    T = np.empty((n, n))
    xs_out[m - 1] = x[m - 1]
    Ps_out[m - 1] = P[m - 1]
    for k in range(m - 2, -1, -1):
        rts_step(x[k], P[k], xp[k + 1], Pp[k + 1], C[k], xs_out[k + 1], Ps_out[k + 1], xs_out[k], Ps_out[k], T)
    return xs_out, Ps_out

