"""Interacting multiple model filter, one mode per environment class (method ``imm``).

Blom & Bar-Shalom (1988), IEEE TAC 33(8); Bar-Shalom, Li & Kirubarajan
(2001), ch. 11. All modes share the event-driven model of
:mod:`models.fusion.ekf`; they differ in the measurement noise R_j of each
source, the per-class R a :class:`~models.fusion.noise.PerClassNoise` learnt.
Each event is one IMM cycle:

1. mixing with the transition matrix of the elapsed time,
   π_ii = e^(−λΔt), π_ij = (1 − e^(−λΔt))/(M − 1) (a continuous-time chain of
   switch rate λ, so irregular event rates need no resampling);
2. mode-matched predict (step or stationary) and update (Joseph form, the
   same gate or Huber weights as the EKF, per mode);
3. mode probabilities from the Gaussian innovation likelihoods, in logs;
4. optional classifier evidence: when the class track moves to a new window,
   μ_j ∝ μ_j · p_j^w (``evidence_weight`` w; 0 ignores the classifier);
5. the moment-matched combination, recorded like an EKF run (the combined
   prior, posterior and the probability-weighted Jacobian), so
   :func:`~models.fusion.smoother.rts_smooth` smooths it too.

Hand-written rather than ``filterpy.kalman.IMMEstimator``: that class mixes
filterpy filters whose ``predict()`` takes a fixed F and Q and whose
``update(z)`` a fixed R, whereas here each event brings its own step
Jacobian, H, R per mode and elapsed time; the mixing and combination
equations are the same as filterpy's (its ``_compute_mixing_probabilities``
and ``_compute_state_estimate``).
"""

from __future__ import annotations

import math

import numpy as np

from models.fusion.ekf import (EkfConfig, FilterError, FilterRun, _h_matrices, _initial, _records, _step_predict,
                               _time_noise, _update)
from models.fusion.events import ACOUSTIC, GNSS, STEP, ClassTrack, EventStream

__all__ = ["IMMFilter"]


class _Fixed:
    """The per-mode 'runner' the shared update wants: a fixed R, no adaptation."""

    n_iter = 1

    def feedback(self, k, nu, hph, accepted):
        pass


def _combine(mu, xs, Ps):
    """Moment matching of modes with weights mu (M,), means xs (M, n), covariances Ps (M, n, n)."""
    M, n = xs.shape
    # x = Σ μ_j x_j
    x = mu @ xs
    d = xs - x
    # P = Σ μ_j (P_j + (x_j − x)(x_j − x)')
    P = (mu @ (Ps + d[:, :, None] * d[:, None, :]).reshape(M, n * n)).reshape(n, n)
    return x, 0.5 * (P + P.T)


def _mix(mix, xs, Ps):
    """Mixed initial conditions per mode j: weights mix (M_i, M_j), returns (M, n) and (M, n, n)."""
    M, n = xs.shape
    # x0_j = Σ_i μ_{i|j} x_i
    xm = mix.T @ xs
    # P0_j = Σ_i μ_{i|j} (P_i + (x_i − x0_j)(x_i − x0_j)'), as Σ_i μ_{i|j} (P_i + e_i e_i') − f_j f_j'
    # with e, f measured from a reference mode (no cancellation: modes stay close)
    e = xs - xs[0]
    f = xm - xs[0]
    Pm = (mix.T @ (Ps + e[:, :, None] * e[:, None, :]).reshape(M, n * n)).reshape(M, n, n)
    Pm -= f[:, :, None] * f[:, None, :]
    return xm, 0.5 * (Pm + np.swapaxes(Pm, 1, 2))


def _nis(nu, S) -> tuple[float, float]:
    """(ν'S⁻¹ν, det S) of a 2-vector innovation and its 2×2 covariance."""
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    return (S[1, 1] * nu[0] * nu[0] - (S[0, 1] + S[1, 0]) * nu[0] * nu[1] + S[0, 0] * nu[1] * nu[1]) / det, det


def _loglik(nu, S) -> float:
    """ln N(ν; 0, S) for a 2-vector: −½ (ν'S⁻¹ν + ln det S) − ln 2π."""
    q, det = _nis(nu, S)
    return -0.5 * (q + math.log(det)) - math.log(2.0 * math.pi)


def _batch_step(xs, Ps, L, psi, cfg):
    """Step predict of all modes at once: xs (M, n), Ps (M, n, n) → (xs, Ps, F (M, n, n))."""
    M, n = xs.shape
    g = 1.0 + xs[:, 3]
    th = psi + xs[:, 2]
    sn, cs = np.sin(th), np.cos(th)
    gl = g * L
    xs = xs.copy()
    # e += (1+s)·L·sin(ψ+δψ),  n += (1+s)·L·cos(ψ+δψ)
    xs[:, 0] += gl * sn
    xs[:, 1] += gl * cs
    F = np.broadcast_to(np.eye(n), (M, n, n)).copy()
    F[:, 0, 2], F[:, 0, 3], F[:, 1, 2], F[:, 1, 3] = gl * cs, L * sn, -gl * sn, L * cs
    # P⁻ = F P F'
    Ps = F @ Ps @ np.swapaxes(F, 1, 2)
    # + G diag(σ_L², σ_ψ²) G'
    vl = (g * cfg.sigma_step_length_m) ** 2
    vp = (gl * cfg.sigma_heading_rad) ** 2
    Ps[:, 0, 0] += vl * sn * sn + vp * cs * cs
    Ps[:, 1, 1] += vl * cs * cs + vp * sn * sn
    c = (vl - vp) * sn * cs
    Ps[:, 0, 1] += c
    Ps[:, 1, 0] += c
    return xs, Ps, F


def _inv2(S):
    """Inverse and determinant of a stack of 2×2 matrices (M, 2, 2)."""
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    Si = np.empty_like(S)
    Si[:, 0, 0], Si[:, 1, 1] = S[:, 1, 1] / det, S[:, 0, 0] / det
    Si[:, 0, 1], Si[:, 1, 0] = -S[:, 0, 1] / det, -S[:, 1, 0] / det
    return Si, det


def _batch_update(xs, Ps, z, R, H, cfg, gate):
    """Mode-matched updates of all modes by one fix; R (M, 2, 2). Returns (xs, Ps, K, w, ok, ln Λ)."""
    M, n = xs.shape
    # ν = z − H x⁻
    nu = z - xs @ H.T
    PHt = Ps @ H.T
    HPH = H @ PHt
    # S = H P⁻ H' + R
    S = HPH + R
    Si, det = _inv2(S)
    # NIS = ν' S⁻¹ ν
    nis = (nu[:, None, :] @ Si @ nu[:, :, None])[:, 0, 0]
    # ln Λ_j = −½ (ν'S⁻¹ν + ln det S) − ln 2π, with the unweighted S
    loglik = -0.5 * (nis + np.log(det)) - math.log(2.0 * math.pi)
    w = np.ones(M)
    ok = np.ones(M, bool)
    if cfg.outlier == "gate":
        ok = nis <= gate
    elif cfg.outlier == "huber":
        # w = min(1, k / √NIS),  R ← R / w
        w = np.minimum(1.0, cfg.huber_k / np.sqrt(np.maximum(nis, 1e-300)))
        R = R / w[:, None, None]
        Si, _ = _inv2(HPH + R)
    # K = P⁻ H' S⁻¹
    K = PHt @ Si
    # x = x⁻ + K ν
    xn = xs + (K @ nu[:, :, None])[:, :, 0]
    # P = (I − KH) P⁻ (I − KH)' + K R K'   (Joseph form)
    A = np.eye(n) - K @ H
    if cfg.joseph:
        Pn = A @ Ps @ np.swapaxes(A, 1, 2) + K @ R @ np.swapaxes(K, 1, 2)
    else:
        # P = (I − KH) P⁻   (short form)
        Pn = A @ Ps
    Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
    if not ok.all():
        xn[~ok], Pn[~ok], K[~ok] = xs[~ok], Ps[~ok], 0.0
        w = np.where(ok, w, 0.0)
    return xn, Pn, K, w, ok, loglik


class IMMFilter:
    """IMM over environment classes.

    ``noise``: a :class:`~models.fusion.noise.PerClassNoise` (fitted; its classes are the modes);
    ``switch_rate_hz`` λ; ``evidence_weight`` w; ``mu0`` (M,) initial mode probabilities (uniform);
    ``fast``: the 4-state model runs in the scalar loop of :mod:`models.fusion.fast_imm` (default);
    otherwise, or with the bias states, ``batched``: all modes in one stack of matrices per operation,
    or mode by mode through the EKF's own update (the reference the tests compare against).
    """

    def __init__(self, noise, config: EkfConfig | None = None, switch_rate_hz: float = 0.05,
                 evidence_weight: float = 1.0, mu0=None, method: str = "imm", batched: bool = True,
                 fast: bool = True):
        self.noise = noise
        self.config = config
        self.switch_rate_hz = switch_rate_hz
        self.evidence_weight = evidence_weight
        self.mu0 = mu0
        self.method = method
        self.batched = batched
        self.fast = fast

    def run(self, stream: EventStream, x0_en=None, classes: ClassTrack | None = None, x0=None, P0=None) -> FilterRun:
        """Filter the stream; the result's ``mode_proba`` (m, M) holds the posterior mode probabilities."""
        cfg = self.config or EkfConfig()
        if not hasattr(self.noise, "R_gnss_"):
            self.noise.fit()
        table = {GNSS: self.noise.R_gnss_, ACOUSTIC: self.noise.R_acoustic_}
        M = table[GNSS].shape[0]
        if not (math.isfinite(self.switch_rate_hz) and self.switch_rate_hz >= 0):
            raise FilterError(f"switch_rate_hz must be finite and >= 0, got {self.switch_rate_hz}")
        if classes is not None and classes.n_classes != M:
            raise FilterError(f"classes has {classes.n_classes} classes, the IMM {M} modes")
        mu = np.full(M, 1.0 / M) if self.mu0 is None else np.asarray(self.mu0, float) / np.sum(self.mu0)
        x, P = _initial(stream, cfg, x0_en, x0, P0)
        x0c, P0c = x.copy(), P.copy()
        m, n = len(stream), cfg.n_state
        xs = np.repeat(x[None], M, axis=0)
        Ps = np.repeat(P[None], M, axis=0)
        rec = _records(m, n)
        mode_p = np.empty((m, M))
        q, phi = _time_noise(stream, cfg)
        H = _h_matrices(cfg)
        gate = cfg.gate_nis
        fixed = _Fixed()
        rows = classes.row_at(stream.t_s) if classes is not None else None
        w_ev = float(self.evidence_weight)
        idx = np.arange(n)
        off = ~np.eye(M, dtype=bool)
        eye = np.eye(n)
        if self.fast and n == 4:
            from models.fusion.fast_imm import run_imm4

            rec, mode_p = run_imm4(stream, cfg, table, mu, x, P, q, self.switch_rate_hz, rows,
                                   None if classes is None else classes.proba, w_ev)
            return FilterRun(self.method, stream.t_s, stream.kind, x0c, P0c, available=stream.available,
                             mode_proba=mode_p, info={"fast": True}, **rec)
        kinds, dts, avail = stream.kind.tolist(), stream.dt_s.tolist(), stream.available.tolist()
        for k in range(m):
            # 1. mixing: π(Δt);  c̄_j = Σ_i π_ij μ_i;  μ_{i|j} = π_ij μ_i / c̄_j   (identity when Δt = 0)
            stay = math.exp(-self.switch_rate_hz * dts[k])
            if stay < 1.0:
                pi = np.where(off, (1.0 - stay) / max(M - 1, 1), stay)
                cbar = mu @ pi
                mix = pi * mu[:, None] / cbar[None, :]
                xs, Ps = _mix(mix, xs, Ps)
            else:
                cbar = mu
            # 2. mode-matched predict
            c = kinds[k]
            xs, Ps = xs.copy(), Ps.copy()
            if cfg.gnss_bias:
                # b = φ b;  P = Φ P Φ'
                xs[:, 4:6] *= phi[k]
                Ps[:, 4:6, :] *= phi[k]
                Ps[:, :, 4:6] *= phi[k]
            Ps[:, idx, idx] += q[k]
            if c == STEP:
                if self.batched:
                    xs, Ps, Fb = _batch_step(xs, Ps, stream.step_length_m[k], stream.heading_rad[k], cfg)
                else:
                    Fb = np.empty((M, n, n))
                    for j in range(M):
                        Fb[j] = eye
                        xs[j], Ps[j] = _step_predict(xs[j], Ps[j], stream.step_length_m[k], stream.heading_rad[k],
                                                     cfg, Fb[j])
                Fk = (cbar @ Fb.reshape(M, -1)).reshape(n, n)
            else:
                Fk = eye.copy()
            if cfg.gnss_bias:
                # F = F_step Φ   (bias decay first, then the step)
                Fk[:, 4:6] *= phi[k]
            rec["F"][k] = Fk
            rec["x_prior"][k], rec["P_prior"][k] = xp, Pp = _combine(cbar, xs, Ps)
            mu = cbar
            if c != STEP and avail[k]:
                Hk = H[GNSS] if c == GNSS else H["other"]
                z = stream.z_m[k]
                if self.batched:
                    xs, Ps, Ks, ws, oks, loglik = _batch_update(xs, Ps, z, table[c], Hk, cfg, gate)
                else:
                    xs, Ps, Ks, ws, oks, loglik = self._mode_updates(xs, Ps, z, table[c], Hk, cfg, fixed, k, gate)
                # 3. μ_j ∝ Λ_j c̄_j
                lp = loglik + np.log(np.maximum(cbar, 1e-300))
                lp -= lp.max()
                mu = np.exp(lp)
                mu /= mu.sum()
                Rbar = (cbar @ table[c].reshape(M, 4)).reshape(2, 2)
                Sc = Hk @ Pp @ Hk.T + Rbar
                nu_c = z - Hk @ xp
                rec["nu"][k], rec["S"][k], rec["R"][k] = nu_c, Sc, Rbar
                rec["nis"][k] = _nis(nu_c, Sc)[0]
                rec["K"][k] = (mu @ Ks.reshape(M, -1)).reshape(n, 2)
                rec["weight"][k] = float(mu @ ws)
                rec["updated"][k] = True
                rec["accepted"][k] = bool(oks.any())
            # 4. classifier evidence once per new window: μ_j ∝ μ_j p_j^w
            if rows is not None and w_ev > 0 and (k == 0 or rows[k] != rows[k - 1]):
                p = np.maximum(classes.proba[rows[k]], 1e-12)
                mu = mu * p ** w_ev
                mu /= mu.sum()
            # 5. combination
            rec["x"][k], rec["P"][k] = _combine(mu, xs, Ps)
            mode_p[k] = mu
        return FilterRun(self.method, stream.t_s, stream.kind, x0c, P0c, available=stream.available,
                         mode_proba=mode_p, **rec)

    @staticmethod
    def _mode_updates(xs, Ps, z, R, H, cfg, fixed, k, gate):
        """Reference path: each mode through the EKF's own :func:`~models.fusion.ekf._update`."""
        M, n = xs.shape
        xs, Ps = xs.copy(), Ps.copy()
        loglik, ws, oks, Ks = np.empty(M), np.empty(M), np.zeros(M, bool), np.zeros((M, n, 2))
        for j in range(M):
            # ln Λ_j with the unweighted S = H P⁻ H' + R_j
            loglik[j] = _loglik(z - H @ xs[j], H @ Ps[j] @ H.T + R[j])
            xs[j], Ps[j], _, _, K, _, _, ws[j], oks[j] = _update(xs[j], Ps[j], z, R[j], H, cfg, fixed, k, gate)
            if oks[j]:
                Ks[j] = K
        return xs, Ps, Ks, ws, oks, loglik
