"""The 4-state event-driven EKF written out in scalars: the same equations as :mod:`models.fusion.ekf`, no numpy
in the loop.

numpy spends ~1 µs of call overhead per operation on 4×4 matrices, a dozen
of them per event; written out, with P held as its 10 distinct entries
(p00 p01 p02 p03 p11 p12 p13 p22 p23 p33), a step costs ~40 float operations
and a Joseph-form update ~150, which CPython runs several times faster
(bench/bench_fusion.py gives the figures). Used by :class:`~models.fusion.ekf.EventEKF`
for the 4-state model with every noise policy (fixed, quality, per class, map
lookup inline; VB-AKF and Sage–Husa through their float interfaces and the
per-mode update of :mod:`models.fusion.fast_imm`); tests/test_filters.py
checks it against the matrix form to rounding.

With F = I + [[0, 0, a, b], [0, 0, c, d], 0, 0] (the step Jacobian), F P F' needs only
rows 0 and 1::

    # (FP)_0j = p_0j + a p_2j + b p_3j,   (FP)_1j = p_1j + c p_2j + d p_3j
    # (FPF')_00 = (FP)_00 + a (FP)_02 + b (FP)_03, and likewise 01, 11

and with H = [I₂ 0], the Joseph form P⁺ = (I − KH) P (I − KH)' + K R K' as
M = (I − KH) P = P − K (HP), then P⁺ = M + (KR − MH') K' (the same products, grouped).
"""

from __future__ import annotations

import array
import math

import numpy as np

from models.fusion.events import STEP

__all__ = []

_IU = (np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 3]), np.array([0, 1, 2, 3, 1, 2, 3, 2, 3, 3]))
"""Upper-triangle indices of the 10 stored entries of the symmetric 4×4 P."""


def _to_full(p10: np.ndarray) -> np.ndarray:
    """(m, 10) upper-triangle rows → (m, 4, 4) symmetric."""
    m = p10.shape[0]
    P = np.empty((m, 4, 4))
    P[:, _IU[0], _IU[1]] = p10
    P[:, _IU[1], _IU[0]] = p10
    return P


def run_fast4(stream, cfg, runner, x0: np.ndarray, P0: np.ndarray, q: np.ndarray) -> dict:
    """Filter ``stream`` with the 4-state model; returns the record arrays of a FilterRun."""
    m = len(stream)
    adaptive = hasattr(runner, "r_s")
    static = not adaptive and hasattr(runner, "R")
    if static:
        R = runner.R
        rl = np.stack([R[:, 0, 0], R[:, 0, 1], R[:, 1, 1]], axis=1).tolist()
    else:
        rl = [None] * m
    # one tuple per event: (kind, fix available, z, L, ψ, q_pos, q_δψ, q_s, R)
    per_event = zip(stream.kind.tolist(), stream.available.tolist(), stream.z_m.tolist(),
                    stream.step_length_m.tolist(), stream.heading_rad.tolist(), q[:, 0].tolist(), q[:, 2].tolist(),
                    q[:, 3].tolist(), rl)
    sl2 = cfg.sigma_step_length_m ** 2
    sp2 = cfg.sigma_heading_rad ** 2
    mode = {"gate": 0, "huber": 1, "none": 2}[cfg.outlier]
    gate = cfg.gate_nis
    hk = cfg.huber_k
    joseph = cfg.joseph
    sin, cos, sqrt = math.sin, math.cos, math.sqrt
    x0_, x1, x2, x3 = (float(v) for v in x0)
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = (float(v) for v in P0[_IU])
    # flat float buffers (array.extend of a tuple is the cheapest append CPython has; numpy views them at
    # the end): posterior (x, P upper triangle) per event, step Jacobian entries per step, and per
    # processed fix (k, ν, S, R, NIS, w, accepted, K). Priors are not stored: a step's prior is its
    # posterior, a fix's is the previous posterior plus diag(Q_Δt) — rebuilt exactly in _assemble.
    post, fab, ups = (array.array("d") for _ in range(3))
    post_a, fab_a, ups_a = post.extend, fab.extend, ups.extend
    no_gain = (0.0,) * 8
    for k, (c, av, z, L, psi, qp, qh, qs, r) in enumerate(per_event):
        # P += Q_Δt   (stationary model)
        p00 += qp
        p11 += qp
        p22 += qh
        p33 += qs
        if c == STEP:
            g = 1.0 + x3
            th = psi + x2
            sn, cs = sin(th), cos(th)
            gl = g * L
            # x: e += (1+s) L sin θ, n += (1+s) L cos θ
            x0_ += gl * sn
            x1 += gl * cs
            # F entries: a = ∂e/∂δψ, b = ∂e/∂s, c = ∂n/∂δψ, d = ∂n/∂s
            fa, fb, fc, fd = gl * cs, L * sn, -gl * sn, L * cs
            # P⁻ = F P F'
            n02 = p02 + fa * p22 + fb * p23
            n03 = p03 + fa * p23 + fb * p33
            n12 = p12 + fc * p22 + fd * p23
            n13 = p13 + fc * p23 + fd * p33
            f00 = p00 + fa * p02 + fb * p03
            f01 = p01 + fa * p12 + fb * p13
            f11 = p11 + fc * p12 + fd * p13
            p00 = f00 + fa * n02 + fb * n03
            p01 = f01 + fc * n02 + fd * n03
            p11 = f11 + fc * n12 + fd * n13
            p02, p03, p12, p13 = n02, n03, n12, n13
            # + G diag(σ_L², σ_ψ²) G'
            vl = g * g * sl2
            vp = gl * gl * sp2
            p00 += vl * sn * sn + vp * cs * cs
            p11 += vl * cs * cs + vp * sn * sn
            p01 += (vl - vp) * sn * cs
            fab_a((fa, fb, fc, fd))
            post_a((x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33))
            continue
        if not av:
            post_a((x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33))
            continue
        if adaptive:
            md = _adaptive_update(k, (x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33), z,
                                  runner, mode, gate, hk, ups_a, joseph)
            x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = md
            post_a(md)
            continue
        if r is None:
            rm = runner.r(k, (x0_, x1))
            r00, r01, r11 = float(rm[0, 0]), float(rm[0, 1]), float(rm[1, 1])
        else:
            r00, r01, r11 = r
        # ν = z − H x⁻
        v0, v1 = z[0] - x0_, z[1] - x1
        # S = H P⁻ H' + R
        s00, s01, s11 = p00 + r00, p01 + r01, p11 + r11
        det = s00 * s11 - s01 * s01
        # NIS = ν' S⁻¹ ν
        nis = (s11 * v0 * v0 - 2.0 * s01 * v0 * v1 + s00 * v1 * v1) / det
        w = 1.0
        if mode == 0 and nis > gate:
            ups_a((k, v0, v1, s00, s01, s11, r00, r01, r11, nis, 0.0, 0.0))
            ups_a(no_gain)
            post_a((x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33))
            continue
        if mode == 1:
            d = sqrt(nis)
            if d > hk:
                # R ← R / w,  w = k / √NIS   (Huber)
                w = hk / d
                r00, r01, r11 = r00 / w, r01 / w, r11 / w
                s00, s01, s11 = p00 + r00, p01 + r01, p11 + r11
                det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        # K = P⁻ H' S⁻¹   (rows i: (p_i0, p_i1) S⁻¹)
        k00, k01 = p00 * i00 + p01 * i01, p00 * i01 + p01 * i11
        k10, k11 = p01 * i00 + p11 * i01, p01 * i01 + p11 * i11
        k20, k21 = p02 * i00 + p12 * i01, p02 * i01 + p12 * i11
        k30, k31 = p03 * i00 + p13 * i01, p03 * i01 + p13 * i11
        # x = x⁻ + K ν
        x0_ += k00 * v0 + k01 * v1
        x1 += k10 * v0 + k11 * v1
        x2 += k20 * v0 + k21 * v1
        x3 += k30 * v0 + k31 * v1
        if not joseph:
            # P = (I − KH) P⁻   (short form, upper triangle): P_ij = p_ij − K_i0 p_0j − K_i1 p_1j
            p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = (
                p00 - k00 * p00 - k01 * p01, p01 - k00 * p01 - k01 * p11, p02 - k00 * p02 - k01 * p12,
                p03 - k00 * p03 - k01 * p13, p11 - k10 * p01 - k11 * p11, p12 - k10 * p02 - k11 * p12,
                p13 - k10 * p03 - k11 * p13, p22 - k20 * p02 - k21 * p12, p23 - k20 * p03 - k21 * p13,
                p33 - k30 * p03 - k31 * p13)
            ups_a((k, v0, v1, s00, s01, s11, r00, r01, r11, nis, w, 1.0, k00, k01, k10, k11, k20, k21, k30, k31))
            post_a((x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33))
            continue
        # M = (I − KH) P⁻:  M_ij = p_ij − K_i0 p_0j − K_i1 p_1j   (M is not symmetric; M_32 is not needed)
        m00 = p00 - k00 * p00 - k01 * p01
        m01 = p01 - k00 * p01 - k01 * p11
        m02 = p02 - k00 * p02 - k01 * p12
        m03 = p03 - k00 * p03 - k01 * p13
        m10 = p01 - k10 * p00 - k11 * p01
        m11 = p11 - k10 * p01 - k11 * p11
        m12 = p12 - k10 * p02 - k11 * p12
        m13 = p13 - k10 * p03 - k11 * p13
        m20 = p02 - k20 * p00 - k21 * p01
        m21 = p12 - k20 * p01 - k21 * p11
        m22 = p22 - k20 * p02 - k21 * p12
        m23 = p23 - k20 * p03 - k21 * p13
        m30 = p03 - k30 * p00 - k31 * p01
        m31 = p13 - k30 * p01 - k31 * p11
        m33 = p33 - k30 * p03 - k31 * p13
        # D = K R − M H' (rows i: (KR)_i − (M_i0, M_i1)), so that
        # P = M (I − KH)' + K R K' = M + D K'   (Joseph form, regrouped):  P_ij = M_ij + D_i0 K_j0 + D_i1 K_j1
        d00, d01 = k00 * r00 + k01 * r01 - m00, k00 * r01 + k01 * r11 - m01
        d10, d11 = k10 * r00 + k11 * r01 - m10, k10 * r01 + k11 * r11 - m11
        d20, d21 = k20 * r00 + k21 * r01 - m20, k20 * r01 + k21 * r11 - m21
        d30, d31 = k30 * r00 + k31 * r01 - m30, k30 * r01 + k31 * r11 - m31
        p00 = m00 + d00 * k00 + d01 * k01
        p01 = m01 + d00 * k10 + d01 * k11
        p02 = m02 + d00 * k20 + d01 * k21
        p03 = m03 + d00 * k30 + d01 * k31
        p11 = m11 + d10 * k10 + d11 * k11
        p12 = m12 + d10 * k20 + d11 * k21
        p13 = m13 + d10 * k30 + d11 * k31
        p22 = m22 + d20 * k20 + d21 * k21
        p23 = m23 + d20 * k30 + d21 * k31
        p33 = m33 + d30 * k30 + d31 * k31
        ups_a((k, v0, v1, s00, s01, s11, r00, r01, r11, nis, w, 1.0, k00, k01, k10, k11, k20, k21, k30, k31))
        post_a((x0_, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33))
    return _assemble(stream, post, fab, ups, x0, P0, q)


def _adaptive_update(k, md, z, runner, mode, gate, hk, ups_a, joseph=True):
    """One fix with an innovation-adaptive policy (VB-AKF iterations, Sage–Husa feedback), through the
    per-mode scalar update of :mod:`models.fusion.fast_imm`; records as the inline update does."""
    from models.fusion.fast_imm import _update

    z0, z1 = z
    p00, p01, p11 = md[4], md[5], md[8]
    r00, r01, r11 = runner.r_s(k, md[0], md[1])
    v0, v1 = z0 - md[0], z1 - md[1]
    s00, s01, s11 = p00 + r00, p01 + r01, p11 + r11
    # NIS = ν' S⁻¹ ν   (with the first iterate's R)
    nis = (s11 * v0 * v0 - 2.0 * s01 * v0 * v1 + s00 * v1 * v1) / (s00 * s11 - s01 * s01)
    post, _, w, ok, K = _update(md, z0, z1, r00, r01, r11, mode, gate, hk, joseph)
    if not ok:
        runner.feedback_s(k, v0, v1, p00, p01, p11, False)
        ups_a((k, v0, v1, s00, s01, s11, r00, r01, r11, nis, 0.0, 0.0))
        ups_a((0.0,) * 8)
        return md
    if mode == 1:
        # the Huber weight of the first iterate: R ← R / w
        r00, r01, r11 = r00 / w, r01 / w, r11 / w
    n_iter = runner.n_iter
    for _ in range(1, n_iter):
        # variational step: R from the residual of this iterate, then the update again from the prior
        r00, r01, r11 = runner.refine_s(k, z0 - post[0], z1 - post[1], post[4], post[8])
        post, _, _, _, K = _update(md, z0, z1, r00, r01, r11, 2, gate, hk, joseph)
    if hasattr(runner, "refine_s"):
        # the posterior residual sets this update's β
        runner.refine_s(k, z0 - post[0], z1 - post[1], post[4], post[8])
    runner.feedback_s(k, v0, v1, p00, p01, p11, True)
    ups_a((k, v0, v1, p00 + r00, p01 + r01, p11 + r11, r00, r01, r11, nis, w, 1.0))
    ups_a(K)
    return post


def _view(buf: array.array, width: int) -> np.ndarray:
    return np.frombuffer(buf, dtype=float).reshape(-1, width).copy()


def _assemble(stream, post, fab, ups, x0, P0, q) -> dict:
    from models.fusion.ekf import _records

    m = len(stream)
    rec = _records(m, 4)
    a = _view(post, 14)
    step = stream.kind == STEP
    # priors: a step's is its posterior; a fix's the previous posterior (x0, P0 first) plus diag(Q_Δt)
    prev = np.concatenate([np.concatenate([x0, P0[_IU]])[None], a[:-1]])
    prev[:, [4, 8, 11, 13]] += q[:, [0, 1, 2, 3]]
    b = np.where(step[:, None], a, prev)
    rec["x_prior"], rec["P_prior"] = b[:, :4].copy(), _to_full(b[:, 4:])
    rec["x"], rec["P"] = a[:, :4].copy(), _to_full(a[:, 4:])
    f = _view(fab, 4)
    F = rec["F"]
    F[step, 0, 2], F[step, 0, 3], F[step, 1, 2], F[step, 1, 3] = f[:, 0], f[:, 1], f[:, 2], f[:, 3]
    if len(ups):
        u = _view(ups, 20)
        k = u[:, 0].astype(int)
        ok = u[:, 11] > 0.5
        rec["nu"][k] = u[:, 1:3]
        rec["S"][k] = u[:, [3, 4, 4, 5]].reshape(-1, 2, 2)
        rec["R"][k] = u[:, [6, 7, 7, 8]].reshape(-1, 2, 2)
        rec["nis"][k] = u[:, 9]
        rec["weight"][k] = u[:, 10]
        rec["updated"][k] = True
        rec["accepted"][k] = ok
        rec["K"][k[ok]] = u[ok, 12:20].reshape(-1, 4, 2)
    return rec
