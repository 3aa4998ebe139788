"""Interacting multiple model filter, one mode per environment class (method ``imm``).

Blom & Bar-Shalom (1988), IEEE TAC 33(8); Bar-Shalom, Li & Kirubarajan
(2001), ch. 11. All modes share the event-driven model of
:mod:`models.fusion.ekf` and run the same compiled kernels of
:mod:`models.fusion.core` (time update, PDR step, Kalman update with its gate
or Huber weights); they differ in the measurement noise R_j of each source,
the per-class R a :class:`~models.fusion.noise.PerClassNoise` learnt. Each
event is one IMM cycle:

1. mixing with the transition matrix of the elapsed time,
   π_ii = e^(−λΔt), π_ij = (1 − e^(−λΔt))/(M − 1) (a continuous-time chain of
   switch rate λ, so irregular event rates need no resampling);
2. mode-matched predict (step or stationary) and update;
3. mode probabilities from the Gaussian innovation likelihoods (of the
   unweighted S), in logs;
4. optional classifier evidence: when the class track moves to a new window,
   μ_j ∝ μ_j · p_j^w (``evidence_weight`` w; 0 ignores the classifier);
5. the moment-matched combination, recorded like an EKF run (the combined
   prior, posterior and the probability-weighted Jacobian), so
   :func:`~models.fusion.smoother.rts_smooth` smooths it too.

Moments are taken about mode 0 (x = Σ w_i x_i, P = Σ w_i (P_i + e_i e_i') −
f f' with e_i = x_i − x_0, f = x − x_0), which keeps the products small
while the modes stay close.

Written on the project's core rather than ``filterpy.kalman.IMMEstimator``:
that class mixes filterpy filters whose ``predict()`` takes a fixed F and Q and
whose ``update(z)`` a fixed R, whereas here each event brings its own step
Jacobian, H, R per mode and elapsed time; the mixing and combination equations
are filterpy's (its ``_compute_mixing_probabilities`` and
``_compute_state_estimate``), and tests/test_filters.py checks a run against
filterpy's IMMEstimator on a linear stream.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from models.fusion.core import STEP_KIND, inv2, kalman_update, mm, mmt, predict_step, time_update
from models.fusion.ekf import (OUTLIER_CODES, EkfConfig, FilterError, FilterResume, FilterRun, empty_records,
                               initial_state,
                               measurement_models, step_variances, time_noise)
from models.fusion.events import ACOUSTIC, GNSS, ClassTrack, EventStream

__all__ = ["IMMFilter"]

_LN_2PI = math.log(2.0 * math.pi)


@njit(cache=True)
def _moments(w, xs, Ps):
    """Moment matching of modes with weights w (M,), means xs (M, n), covariances Ps (M, n, n), about mode 0."""
    M, n = xs.shape
    x = np.zeros(n)
    P = np.zeros((n, n))
    for i in range(M):
        # x = Σ w_i x_i;  P = Σ w_i (P_i + e_i e_i'),  e_i = x_i − x_0
        e = xs[i] - xs[0]
        x += w[i] * xs[i]
        for a in range(n):
            for b in range(n):
                P[a, b] += w[i] * (Ps[i, a, b] + e[a] * e[b])
    # P −= f f',  f = x − x_0
    f = x - xs[0]
    for a in range(n):
        for b in range(n):
            P[a, b] -= f[a] * f[b]
    return x, P


@njit(cache=True)
def _mix(mu, xs, Ps, stay, leave):
    """Mixing step: c̄_j = Σ_i π_ij μ_i, μ_{i|j} = π_ij μ_i / c̄_j, and each mode's mixed (x0_j, P0_j)."""
    M, n = xs.shape
    cbar = np.empty(M)
    for j in range(M):
        # c̄_j = μ_j π_jj + (1 − μ_j) π_ij   (Σ μ = 1, every off-diagonal π equal)
        cbar[j] = mu[j] * stay + (1.0 - mu[j]) * leave
    xm = np.empty((M, n))
    Pm = np.empty((M, n, n))
    w = np.empty(M)
    for j in range(M):
        for i in range(M):
            # μ_{i|j} = π_ij μ_i / c̄_j
            w[i] = (stay if i == j else leave) * mu[i] / cbar[j]
        xm[j], Pm[j] = _moments(w, xs, Ps)
    return cbar, xm, Pm


@njit(cache=True)
def _mode_updates(xs, Ps, z, H, R_modes, cbar, xp, Pp, outlier, gate_nis, huber_k, joseph):
    """Steps 2 (update) and 3 of the IMM cycle for a fix: each mode updated in place by its own R_j, then
    μ_j ∝ Λ_j c̄_j. Returns (μ, and the records of the combined prior (xp, Pp): ν, S, R̄ = Σ c̄_j R_j, NIS,
    K̄ = Σ μ_j K_j, w̄ = Σ μ_j w_j, accepted by any mode)."""
    M, n = xs.shape
    lp = np.empty(M)
    Ks = np.zeros((M, n, 2))
    ws = np.zeros(M)
    Rbar = np.zeros((2, 2))
    any_ok = False
    for j in range(M):
        Rbar += cbar[j] * R_modes[j]
        # ln Λ_j = −½ (ν'S⁻¹ν + ln det S) − ln 2π, with the unweighted S = H P⁻ H' + R_j
        _, det0 = inv2(mm(H, mmt(Ps[j], H)) + R_modes[j])
        xn, Pn, nu, S, K, Ru, nis, w, ok = kalman_update(xs[j], Ps[j], z, R_modes[j], H, outlier, gate_nis,
                                                         huber_k, joseph)
        lp[j] = -0.5 * (nis + math.log(det0)) - _LN_2PI + math.log(max(cbar[j], 1e-300))
        xs[j], Ps[j] = xn, Pn
        Ks[j] = K
        ws[j] = w
        any_ok = any_ok or ok
    # μ_j ∝ Λ_j c̄_j   (in logs)
    lp -= lp.max()
    mu = np.exp(lp)
    mu /= mu.sum()
    Kbar = np.zeros((n, 2))
    wbar = 0.0
    for j in range(M):
        Kbar += mu[j] * Ks[j]
        wbar += mu[j] * ws[j]
    # the combined prior's innovation: ν = z − H x⁻,  S = H P⁻ H' + R̄
    nu_c = z - mm(H, xp.reshape(n, 1))[:, 0]
    S_c = mm(H, mmt(Pp, H)) + Rbar
    Si, _ = inv2(S_c)
    nis_c = nu_c[0] * (Si[0, 0] * nu_c[0] + Si[0, 1] * nu_c[1]) + nu_c[1] * (Si[1, 0] * nu_c[0] + Si[1, 1] * nu_c[1])
    return mu, nu_c, S_c, Rbar, nis_c, Kbar, wbar, any_ok


@njit(cache=True)
def _imm_events(kind, avail, z, length_m, heading_rad, dt, phi, q, h_idx, H, x0, P0, sl2, sp2, outlier, gate_nis,
                huber_k, joseph, r_table, mu0, switch_rate_hz, rows, proba_w, x_prior, P_prior, F_rec, x_post, P_post,
                nu_rec, S_rec, K_rec, R_rec, nis_rec, w_rec, updated, accepted, mode_p, mode_x, mode_P, restart,
                xs_restart, Ps_restart, mu_restart):
    """The IMM over m events, records written in place; ``r_table`` (3, M, 2, 2) per event kind and mode,
    ``rows`` (m,) the class-track row in force (−1: no evidence), ``proba_w`` (n_rows, M) = p^w. ``mode_x``
    (m, M, n), ``mode_P`` (m, M, n, n) record each mode's posterior. ``restart`` ≥ 0 (−1: none): before event
    ``restart`` the modes' states and probabilities are replaced by ``xs_restart`` (M, n), ``Ps_restart``
    (M, n, n), ``mu_restart`` (M,) (another run's, :class:`~models.fusion.ekf.FilterResume`)."""
    m = kind.shape[0]
    M = mu0.shape[0]
    n = x0.shape[0]
    xs = np.empty((M, n))
    Ps = np.empty((M, n, n))
    for j in range(M):
        xs[j] = x0
        Ps[j] = P0
    mu = mu0.copy()
    off_share = 1.0 / max(M - 1, 1)
    for k in range(m):
        if k == restart:
            xs = xs_restart.copy()
            Ps = Ps_restart.copy()
            mu = mu_restart.copy()
        # 1. mixing over the elapsed time (identity when Δt = 0)
        stay = math.exp(-switch_rate_hz * dt[k])
        if stay < 1.0:
            cbar, xs, Ps = _mix(mu, xs, Ps, stay, (1.0 - stay) * off_share)
        else:
            cbar = mu.copy()
        # 2. mode-matched predict; F = Σ_j c̄_j F_j (F_j = F_step,j Φ)
        Fk = np.zeros((n, n))
        for j in range(M):
            time_update(xs[j], Ps[j], phi[k], q[k])
            if kind[k] == STEP_KIND:
                xs[j], Ps[j], Fs = predict_step(xs[j], Ps[j], length_m[k], heading_rad[k], sl2, sp2)
                Fk += cbar[j] * (Fs * phi[k])
            else:
                for i in range(n):
                    Fk[i, i] += cbar[j] * phi[k, i]
        F_rec[k] = Fk
        xp, Pp = _moments(cbar, xs, Ps)
        x_prior[k] = xp
        P_prior[k] = Pp
        mu = cbar.copy()
        if kind[k] != STEP_KIND and avail[k]:
            mu, nu_rec[k], S_rec[k], R_rec[k], nis_rec[k], K_rec[k], w_rec[k], accepted[k] = _mode_updates(
                xs, Ps, z[k], H[h_idx[k]], r_table[kind[k]], cbar, xp, Pp, outlier, gate_nis, huber_k, joseph)
            updated[k] = True
        # 4. classifier evidence once per new window: μ_j ∝ μ_j p_j^w
        if rows[k] >= 0 and (k == 0 or rows[k] != rows[k - 1]):
            mu = mu * proba_w[rows[k]]
            mu /= mu.sum()
        # 5. combination
        x_post[k], P_post[k] = _moments(mu, xs, Ps)
        mode_p[k] = mu
        mode_x[k] = xs
        mode_P[k] = Ps


class IMMFilter:
    """IMM over environment classes.

    ``noise``: a :class:`~models.fusion.noise.PerClassNoise` (fitted; its classes are the modes);
    ``switch_rate_hz`` λ; ``evidence_weight`` w; ``mu0`` (M,) initial mode probabilities (uniform);
    ``scales``: ``{"gnss", "acoustic"}`` multipliers of every mode's R (a method's tuning).
    """

    def __init__(self, noise, config: EkfConfig | None = None, switch_rate_hz: float = 0.05,
                 evidence_weight: float = 1.0, mu0=None, method: str = "imm", scales: dict | None = None):
        self.noise = noise
        self.config = config
        self.switch_rate_hz = switch_rate_hz
        self.evidence_weight = evidence_weight
        self.mu0 = mu0
        self.method = method
        self.scales = scales

    def run(self, stream: EventStream, x0_en=None, classes: ClassTrack | None = None, x0=None, P0=None,
            resume: FilterResume | None = None) -> FilterRun:
        """Filter the stream; the result's ``mode_proba`` (m, M) holds the posterior mode probabilities,
        ``mode_x``, ``mode_P`` each mode's posterior. ``resume``: the state of a run of this filter over an
        earlier piece of the stream (:meth:`FilterRun.state_before`: its modes' states and probabilities); the
        events from ``resume.t_s`` on continue from it (those before are filtered from the prior, a warm-up)."""
        cfg = self.config or EkfConfig()
        if not hasattr(self.noise, "R_gnss_"):
            self.noise.fit()
        M = self.noise.R_gnss_.shape[0]
        table = np.zeros((3, M, 2, 2))
        sc = self.scales or {}
        table[GNSS] = self.noise.R_gnss_ * float(sc.get("gnss", 1.0))
        table[ACOUSTIC] = self.noise.R_acoustic_ * float(sc.get("acoustic", 1.0))
        if not (math.isfinite(self.switch_rate_hz) and self.switch_rate_hz >= 0):
            raise FilterError(f"switch_rate_hz must be finite and >= 0, got {self.switch_rate_hz}")
        if classes is not None and classes.n_classes != M:
            raise FilterError(f"classes has {classes.n_classes} classes, the IMM {M} modes")
        mu = np.full(M, 1.0 / M) if self.mu0 is None else np.asarray(self.mu0, float) / np.sum(self.mu0)
        x, P = initial_state(stream, cfg, x0_en, x0, P0)
        m, n = len(stream), cfg.n_state
        q, phi = time_noise(stream, cfg)
        H, h_idx = measurement_models(stream, cfg)
        w_ev = float(self.evidence_weight)
        if classes is not None and w_ev > 0:
            rows = classes.row_at(stream.t_s).astype(np.int64)
            proba_w = np.maximum(classes.proba, 1e-12) ** w_ev
        else:
            rows, proba_w = np.full(m, -1, np.int64), np.ones((1, M))
        rec = empty_records(m, n)
        mode_p = np.empty((m, M))
        mode_x, mode_P = np.empty((m, M, n)), np.empty((m, M, n, n))
        restart, xs_r, Ps_r, mu_r = _restart_modes(stream, resume, M, n)
        sl2, sp2 = step_variances(stream, cfg)
        _imm_events(stream.kind.astype(np.int64), stream.available, stream.z_m, stream.step_length_m,
                    stream.heading_rad, stream.dt_s, phi, q, h_idx, H, x, P, sl2, sp2, OUTLIER_CODES[cfg.outlier], cfg.gate_nis, cfg.huber_k, cfg.joseph,
                    table, mu, float(self.switch_rate_hz), rows, proba_w, rec["x_prior"], rec["P_prior"], rec["F"],
                    rec["x"], rec["P"], rec["nu"], rec["S"], rec["K"], rec["R"], rec["nis"], rec["weight"],
                    rec["updated"], rec["accepted"], mode_p, mode_x, mode_P, restart, xs_r, Ps_r, mu_r)
        return FilterRun(self.method, stream.t_s, stream.kind, x.copy(), P.copy(), available=stream.available,
                         mode_proba=mode_p, mode_x=mode_x, mode_P=mode_P, **rec)


def _restart_modes(stream: EventStream, resume: FilterResume | None, M: int, n: int) -> tuple:
    """(event index, modes' x (M, n), P (M, n, n), μ (M,)) the IMM restarts from: ``resume``'s at the stream's
    first event at or after its time, or index −1 (placeholders) without one or when no event follows it."""
    none = (-1, np.zeros((M, n)), np.zeros((M, n, n)), np.full(M, 1.0 / M))
    if resume is None:
        return none
    if resume.mode_x is None or resume.mode_P is None or resume.mode_proba is None:
        raise FilterError("cannot resume an IMM from a state without its modes (a single-model filter's)")
    if resume.mode_x.shape != (M, n) or resume.mode_P.shape != (M, n, n) or resume.mode_proba.shape != (M,):
        raise FilterError(f"cannot resume an IMM of {M} modes and {n} states from one of shape "
                          f"{resume.mode_x.shape}")
    i = int(np.searchsorted(stream.t_s, resume.t_s, side="left"))
    if i >= len(stream):
        return none
    return (i, np.asarray(resume.mode_x, float), np.asarray(resume.mode_P, float),
            np.asarray(resume.mode_proba, float))
