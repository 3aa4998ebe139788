"""An independent reference of the event-driven filters, for tests: written from the equations, not from the code.

Nothing here imports :mod:`models.fusion.core`, ``ekf`` or ``imm``: only the
event stream and the config dataclasses (the inputs). Every event is the
textbook cycle with full numpy matrices and ``np.linalg.inv``; the Kalman
update itself is filterpy's ``KalmanFilter.update`` (Joseph form), except
where a robust variant needs its own R (Huber: filterpy with R/w) or a gate
(filterpy's NIS via its own ``S``, ``y``). The IMM is Blom & Bar-Shalom's
cycle as in Bar-Shalom, Li & Kirubarajan (2001, ch. 11.6) with the
continuous-time mode chain the filter documents; the VB-AKF is Särkkä &
Nummenmaa (2009), algorithm 1.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import KalmanFilter

STEP, GNSS = 0, 1


def _step_model(x, L, psi, cfg):
    """x⁻, F and Q_step of a PDR step (the filter's documented model)."""
    n = x.size
    g, th = 1.0 + x[3], psi + x[2]
    xp = x.copy()
    xp[0] += g * L * math.sin(th)
    xp[1] += g * L * math.cos(th)
    F = np.eye(n)
    F[0, 2], F[0, 3] = g * L * math.cos(th), L * math.sin(th)
    F[1, 2], F[1, 3] = -g * L * math.sin(th), L * math.cos(th)
    G = np.zeros((n, 2))
    G[0] = [g * math.sin(th), g * L * math.cos(th)]
    G[1] = [g * math.cos(th), -g * L * math.sin(th)]
    Q = G @ np.diag([cfg.sigma_step_length_m ** 2, cfg.sigma_heading_rad ** 2]) @ G.T
    return xp, F, Q


def _time_model(dt, dt_stand, cfg):
    """Φ and Q of the stationary model over Δt (of which Δt_stand standing)."""
    n = cfg.n_state
    q = np.zeros(n)
    q[0] = q[1] = cfg.q_walk_m2_s * (dt - dt_stand) + cfg.q_stand_m2_s * dt_stand
    q[2], q[3] = cfg.q_heading_rad2_s * dt, cfg.q_scale_1_s * dt
    phi = np.ones(n)
    if cfg.gnss_bias:
        phi[4:6] = math.exp(-dt / cfg.bias_tau_s)
        q[4:6] = cfg.bias_sigma_m ** 2 * (1 - phi[4] ** 2)
    return np.diag(phi), np.diag(q)


def _H(kind, cfg):
    H = np.zeros((2, cfg.n_state))
    H[0, 0] = H[1, 1] = 1.0
    if cfg.gnss_bias and kind == GNSS:
        H[0, 4] = H[1, 5] = 1.0
    return H


def _filterpy_update(x, P, z, R, H):
    kf = KalmanFilter(dim_x=x.size, dim_z=2)
    kf.x, kf.P, kf.R, kf.H = x.reshape(-1, 1).copy(), P.copy(), R.copy(), H.copy()
    kf.update(z.reshape(-1, 1))
    return kf.x.ravel(), kf.P, kf.K


def robust_update(x, P, z, R, H, cfg):
    """(x, P, K, NIS, weight, accepted) with the gate or Huber of ``cfg.outlier``, the update by filterpy."""
    S = H @ P @ H.T + R
    nu = z - H @ x
    nis = float(nu @ np.linalg.inv(S) @ nu)
    w = 1.0
    if cfg.outlier == "gate" and nis > -2 * math.log(1 - cfg.gate_prob):
        return x, P, None, nis, 0.0, False
    if cfg.outlier == "huber" and math.sqrt(nis) > cfg.huber_k:
        w = cfg.huber_k / math.sqrt(nis)
    xn, Pn, K = _filterpy_update(x, P, z, R / w, H)
    return xn, Pn, K, nis, w, True


def reference_ekf(ev, cfg, r_of, x0, P0):
    """Posterior (m, n) and covariance (m, n, n) per event; ``r_of(k, x_prior)`` gives each fix's R."""
    x, P = x0.copy(), P0.copy()
    xs, Ps = [], []
    for k in range(len(ev)):
        Phi, Q = _time_model(ev.dt_s[k], ev.dt_stand_s[k], cfg)
        x, P = Phi @ x, Phi @ P @ Phi.T + Q
        if ev.kind[k] == STEP:
            x, F, Qs = _step_model(x, ev.step_length_m[k], ev.heading_rad[k], cfg)
            P = F @ P @ F.T + Qs
        elif ev.available[k]:
            x, P, *_ = robust_update(x, P, ev.z_m[k], r_of(k, x), _H(ev.kind[k], cfg), cfg)
        xs.append(x)
        Ps.append(P)
    return np.array(xs), np.array(Ps)


def reference_vb(ev, cfg, r0, rho, n_iter, dof0, cap_ratio, x0, P0):
    """The VB-AKF of Särkkä & Nummenmaa (2009, algorithm 1), diagonal R per source (``r0``: {kind: R0}).

    Per source and axis: α⁻ = ρα + ½, β⁻ = ρβ; iterate R = diag(β/α) (capped at cap_ratio·R0),
    update from the prior, β = β⁻ + ½ (z − Hx)² + ½ diag(HPH'); the gate / Huber weight act on the first
    iterate. Returns the posteriors and the R used at each fix (last iterate)."""
    x, P = x0.copy(), P0.copy()
    alpha = {k: np.full(2, float(dof0)) for k in r0}
    beta = {k: dof0 * np.diag(r0[k]).copy() for k in r0}
    cap = {k: cap_ratio * np.diag(r0[k]) for k in r0}
    xs, Rs = [], []
    for k in range(len(ev)):
        Phi, Q = _time_model(ev.dt_s[k], ev.dt_stand_s[k], cfg)
        x, P = Phi @ x, Phi @ P @ Phi.T + Q
        R_used = np.full((2, 2), np.nan)
        if ev.kind[k] == STEP:
            x, F, Qs = _step_model(x, ev.step_length_m[k], ev.heading_rad[k], cfg)
            P = F @ P @ F.T + Qs
        elif ev.available[k]:
            s, H = int(ev.kind[k]), _H(ev.kind[k], cfg)
            a = rho * alpha[s] + 0.5
            bp = rho * beta[s]
            R = np.diag(np.minimum(bp / a, cap[s]))
            xn, Pn, _, _, w, ok = robust_update(x, P, ev.z_m[k], R, H, cfg)
            if ok:
                R_used = R / w
                for _ in range(1, n_iter):
                    b = bp + 0.5 * ((ev.z_m[k] - H @ xn) ** 2 + np.diag(H @ Pn @ H.T))
                    R_used = np.diag(np.minimum(b / a, cap[s]))
                    xn, Pn, _ = _filterpy_update(x, P, ev.z_m[k], R_used, H)
                beta[s] = bp + 0.5 * ((ev.z_m[k] - H @ xn) ** 2 + np.diag(H @ Pn @ H.T))
                alpha[s] = a
                x, P = xn, Pn
        xs.append(x)
        Rs.append(R_used)
    return np.array(xs), np.array(Rs)


def reference_imm(ev, cfg, tables, mu0, switch_rate_hz, x0, P0, evidence=None):
    """IMM (Bar-Shalom, Li & Kirubarajan 2001, §11.6.6): ``tables`` {kind: (M, 2, 2)}; ``evidence``:
    (rows (m,), proba (k, M), w) or None. Returns (combined posterior (m, n), (m, n, n), mode probabilities)."""
    M = len(mu0)
    xs = [x0.copy() for _ in range(M)]
    Ps = [P0.copy() for _ in range(M)]
    mu = np.asarray(mu0, float)
    out_x, out_P, out_mu = [], [], []
    for k in range(len(ev)):
        stay = math.exp(-switch_rate_hz * ev.dt_s[k])
        Pi = np.full((M, M), (1 - stay) / max(M - 1, 1))
        np.fill_diagonal(Pi, stay)
        cbar = mu @ Pi
        mix = Pi * mu[:, None] / cbar[None, :]
        xm = [sum(mix[i, j] * xs[i] for i in range(M)) for j in range(M)]
        Pm = [sum(mix[i, j] * (Ps[i] + np.outer(xs[i] - xm[j], xs[i] - xm[j])) for i in range(M)) for j in range(M)]
        Phi, Q = _time_model(ev.dt_s[k], ev.dt_stand_s[k], cfg)
        loglik = np.zeros(M)
        for j in range(M):
            x, P = Phi @ xm[j], Phi @ Pm[j] @ Phi.T + Q
            if ev.kind[k] == STEP:
                x, F, Qs = _step_model(x, ev.step_length_m[k], ev.heading_rad[k], cfg)
                P = F @ P @ F.T + Qs
            elif ev.available[k]:
                H, R = _H(ev.kind[k], cfg), tables[int(ev.kind[k])][j]
                S = H @ P @ H.T + R
                nu = ev.z_m[k] - H @ x
                # ln N(ν; 0, S) (in logs: a tight mode's likelihood underflows a double)
                loglik[j] = -0.5 * nu @ np.linalg.inv(S) @ nu - math.log(2 * math.pi * math.sqrt(np.linalg.det(S)))
                x, P, *_ = robust_update(x, P, ev.z_m[k], R, H, cfg)
            xs[j], Ps[j] = x, P
        if ev.kind[k] != STEP and ev.available[k]:
            lp = np.log(cbar) + loglik
            mu = np.exp(lp - lp.max())
        else:
            mu = cbar
        mu = mu / mu.sum()
        if evidence is not None:
            rows, proba, w = evidence
            if k == 0 or rows[k] != rows[k - 1]:
                mu = mu * np.maximum(proba[rows[k]], 1e-12) ** w
                mu = mu / mu.sum()
        x = sum(mu[j] * xs[j] for j in range(M))
        P = sum(mu[j] * (Ps[j] + np.outer(xs[j] - x, xs[j] - x)) for j in range(M))
        out_x.append(x)
        out_P.append(P)
        out_mu.append(mu)
    return np.array(out_x), np.array(out_P), np.array(out_mu)
