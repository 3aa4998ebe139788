"""The IMM of :mod:`models.fusion.imm` for the 4-state model written out in scalars (no numpy in the loop).

Same equations, same order of operations as the batched matrix form up to
rounding (tests/test_filters.py compares them): mixing, mode-matched step
predict and Joseph-form update per mode, log-likelihood mode probabilities,
classifier evidence, moment matching. Each mode is a 14-tuple
(x0, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33).
"""

from __future__ import annotations

import array
import math

import numpy as np

from models.fusion.events import STEP
from models.fusion.fast import _to_full

__all__ = []

_PAIRS = ((0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3), (2, 2), (2, 3), (3, 3))
"""(row, column) of the 10 stored covariance entries."""

_LN_2PI = math.log(2.0 * math.pi)


def _lincomb(weights, rows):
    """Σ_i w_i row_i of equal-length float sequences (one comprehension per row, no generators)."""
    acc = [weights[0] * v for v in rows[0]]
    for w, r in zip(weights[1:], rows[1:]):
        acc = [a + w * v for a, v in zip(acc, r)]
    return acc


def _spread(modes):
    """(reference mean, rows (x_i, P_i + e_i e_i') with e_i = x_i − reference): the terms every moment
    matching of these modes needs (the reference, mode 0, keeps the products small: modes stay close)."""
    r0, r1, r2, r3 = ref = modes[0][:4]
    rows = []
    for x0, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 in modes:
        e0, e1, e2, e3 = x0 - r0, x1 - r1, x2 - r2, x3 - r3
        rows.append((x0, x1, x2, x3, p00 + e0 * e0, p01 + e0 * e1, p02 + e0 * e2, p03 + e0 * e3, p11 + e1 * e1,
                     p12 + e1 * e2, p13 + e1 * e3, p22 + e2 * e2, p23 + e2 * e3, p33 + e3 * e3))
    return ref, rows


def _matched(weights, ref, rows):
    """Moment matching: x = Σ w_i x_i, P = Σ w_i (P_i + e_i e_i') − f f' with f = x − reference."""
    x0, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = _lincomb(weights, rows)
    f0, f1, f2, f3 = x0 - ref[0], x1 - ref[1], x2 - ref[2], x3 - ref[3]
    return (x0, x1, x2, x3, p00 - f0 * f0, p01 - f0 * f1, p02 - f0 * f2, p03 - f0 * f3, p11 - f1 * f1,
            p12 - f1 * f2, p13 - f1 * f3, p22 - f2 * f2, p23 - f2 * f3, p33 - f3 * f3)


def _moments(weights, modes):
    """Σ w_j (x_j, P_j + (x_j − x)(x_j − x)') of 14-tuples: the moment-matched 14-tuple."""
    ref, rows = _spread(modes)
    return _matched(weights, ref, rows)


def _step(md, L, psi, sl2, sp2):
    """One PDR step of one mode (see models/fusion/fast.py); returns (mode, (a, b, c, d))."""
    x0, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = md
    g = 1.0 + x3
    th = psi + x2
    sn, cs = math.sin(th), math.cos(th)
    gl = g * L
    fa, fb, fc, fd = gl * cs, L * sn, -gl * sn, L * cs
    # P⁻ = F P F'
    n02 = p02 + fa * p22 + fb * p23
    n03 = p03 + fa * p23 + fb * p33
    n12 = p12 + fc * p22 + fd * p23
    n13 = p13 + fc * p23 + fd * p33
    q00 = p00 + fa * p02 + fb * p03 + fa * n02 + fb * n03
    q01 = p01 + fa * p12 + fb * p13 + fc * n02 + fd * n03
    q11 = p11 + fc * p12 + fd * p13 + fc * n12 + fd * n13
    # + G diag(σ_L², σ_ψ²) G'
    vl = g * g * sl2
    vp = gl * gl * sp2
    q00 += vl * sn * sn + vp * cs * cs
    q11 += vl * cs * cs + vp * sn * sn
    q01 += (vl - vp) * sn * cs
    return ((x0 + gl * sn, x1 + gl * cs, x2, x3, q00, q01, n02, n03, q11, n12, n13, p22, p23, p33),
            (fa, fb, fc, fd))


def _update(md, z0, z1, r00, r01, r11, mode, gate, hk, joseph=True):
    """Joseph-form update of one mode by a position fix; returns (mode, ln Λ, w, accepted, K 8-tuple)."""
    x0, x1, x2, x3, p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = md
    # ν = z − H x⁻,  S = H P⁻ H' + R
    v0, v1 = z0 - x0, z1 - x1
    s00, s01, s11 = p00 + r00, p01 + r01, p11 + r11
    det = s00 * s11 - s01 * s01
    nis = (s11 * v0 * v0 - 2.0 * s01 * v0 * v1 + s00 * v1 * v1) / det
    # ln Λ = −½ (ν'S⁻¹ν + ln det S) − ln 2π   (unweighted S)
    loglik = -0.5 * (nis + math.log(det)) - _LN_2PI
    w = 1.0
    if mode == 0 and nis > gate:
        return md, loglik, 0.0, False, (0.0,) * 8
    if mode == 1:
        # w = min(1, k / √NIS),  R ← R / w
        w = min(1.0, hk / math.sqrt(max(nis, 1e-300)))
        r00, r01, r11 = r00 / w, r01 / w, r11 / w
        s00, s01, s11 = p00 + r00, p01 + r01, p11 + r11
        det = s00 * s11 - s01 * s01
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    # K = P⁻ H' S⁻¹
    k00, k01 = p00 * i00 + p01 * i01, p00 * i01 + p01 * i11
    k10, k11 = p01 * i00 + p11 * i01, p01 * i01 + p11 * i11
    k20, k21 = p02 * i00 + p12 * i01, p02 * i01 + p12 * i11
    k30, k31 = p03 * i00 + p13 * i01, p03 * i01 + p13 * i11
    xn = (x0 + k00 * v0 + k01 * v1, x1 + k10 * v0 + k11 * v1, x2 + k20 * v0 + k21 * v1, x3 + k30 * v0 + k31 * v1)
    if not joseph:
        # P = (I − KH) P⁻   (short form, upper triangle)
        return (xn + (p00 - k00 * p00 - k01 * p01, p01 - k00 * p01 - k01 * p11, p02 - k00 * p02 - k01 * p12,
                      p03 - k00 * p03 - k01 * p13, p11 - k10 * p01 - k11 * p11, p12 - k10 * p02 - k11 * p12,
                      p13 - k10 * p03 - k11 * p13, p22 - k20 * p02 - k21 * p12, p23 - k20 * p03 - k21 * p13,
                      p33 - k30 * p03 - k31 * p13), loglik, w, True, (k00, k01, k10, k11, k20, k21, k30, k31))
    # M = (I − KH) P⁻
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
    # P = M + (KR − MH') K'   (Joseph form, regrouped)
    d00, d01 = k00 * r00 + k01 * r01 - m00, k00 * r01 + k01 * r11 - m01
    d10, d11 = k10 * r00 + k11 * r01 - m10, k10 * r01 + k11 * r11 - m11
    d20, d21 = k20 * r00 + k21 * r01 - m20, k20 * r01 + k21 * r11 - m21
    d30, d31 = k30 * r00 + k31 * r01 - m30, k30 * r01 + k31 * r11 - m31
    out = xn + (m00 + d00 * k00 + d01 * k01, m01 + d00 * k10 + d01 * k11, m02 + d00 * k20 + d01 * k21,
           m03 + d00 * k30 + d01 * k31, m11 + d10 * k10 + d11 * k11, m12 + d10 * k20 + d11 * k21,
           m13 + d10 * k30 + d11 * k31, m22 + d20 * k20 + d21 * k21, m23 + d20 * k30 + d21 * k31,
           m33 + d30 * k30 + d31 * k31)
    return out, loglik, w, True, (k00, k01, k10, k11, k20, k21, k30, k31)


def run_imm4(stream, cfg, tables, mu0, x0, P0, q, switch_rate_hz, rows, proba, w_ev) -> tuple[dict, np.ndarray]:
    """IMM over M modes for the 4-state model; ``tables`` {kind: (M, 2, 2)}. Returns (records, mode_proba)."""
    M = len(mu0)
    rtab = {c: [tuple(map(float, (r[0, 0], r[0, 1], r[1, 1]))) for r in t] for c, t in tables.items()}
    mode = {"gate": 0, "huber": 1, "none": 2}[cfg.outlier]
    gate, hk, joseph = cfg.gate_nis, cfg.huber_k, cfg.joseph
    sl2, sp2 = cfg.sigma_step_length_m ** 2, cfg.sigma_heading_rad ** 2
    off_share = 1.0 / max(M - 1, 1)
    start = tuple(float(v) for v in x0) + tuple(float(P0[a, b]) for a, b in _PAIRS)
    modes = [start] * M
    mu = [float(v) for v in mu0]
    ev_rows = rows.tolist() if rows is not None else None
    prob_rows = [[max(float(p), 1e-12) ** w_ev for p in r] for r in proba] if rows is not None else None
    pri, post, fab, ups, mps = (array.array("d") for _ in range(5))
    per_event = zip(stream.kind.tolist(), stream.available.tolist(), stream.z_m.tolist(), stream.step_length_m.tolist(),
                    stream.heading_rad.tolist(), stream.dt_s.tolist(), q[:, 0].tolist(), q[:, 2].tolist(),
                    q[:, 3].tolist())
    for k, (c, av, z, L, psi, dt, qp, qh, qs) in enumerate(per_event):
        # 1. mixing: c̄_j = Σ_i π_ij μ_i,  μ_{i|j} = π_ij μ_i / c̄_j,  x0_j, P0_j by moments about mode 0
        stay = math.exp(-switch_rate_hz * dt)
        if stay < 1.0:
            leave = (1.0 - stay) * off_share
            cbar = [mu[j] * stay + (1.0 - mu[j]) * leave for j in range(M)]
            ref, rows = _spread(modes)
            modes = [_matched([(stay if i == j else leave) * mu[i] / cbar[j] for i in range(M)], ref, rows)
                     for j in range(M)]
        else:
            cbar = mu
        # 2. mode-matched predict: P += Q_Δt, then the step
        modes = [md[:4] + (md[4] + qp, md[5], md[6], md[7], md[8] + qp, md[9], md[10], md[11] + qh, md[12],
                           md[13] + qs) for md in modes]
        if c == STEP:
            stepped = [_step(md, L, psi, sl2, sp2) for md in modes]
            modes = [s_[0] for s_ in stepped]
            fab.extend(_lincomb(cbar, [s_[1] for s_ in stepped]))
        prior = _moments(cbar, modes)
        pri.extend(prior)
        mu = cbar
        if c != STEP and av:
            z0, z1 = z
            rs = rtab[c]
            res = [_update(md, z0, z1, *rs[j], mode, gate, hk, joseph) for j, md in enumerate(modes)]
            modes = [r_[0] for r_ in res]
            # 3. μ_j ∝ Λ_j c̄_j   (in logs)
            lp = [r_[1] + math.log(max(cb, 1e-300)) for r_, cb in zip(res, cbar)]
            top = max(lp)
            ex = [math.exp(v - top) for v in lp]
            tot = sum(ex)
            mu = [v / tot for v in ex]
            rb = _lincomb(cbar, rs)
            v0, v1 = z0 - prior[0], z1 - prior[1]
            s00, s01, s11 = prior[4] + rb[0], prior[5] + rb[1], prior[8] + rb[2]
            nis = (s11 * v0 * v0 - 2.0 * s01 * v0 * v1 + s00 * v1 * v1) / (s00 * s11 - s01 * s01)
            gains = _lincomb(mu, [r_[4] for r_ in res])
            ups.extend((k, v0, v1, s00, s01, s11, rb[0], rb[1], rb[2], nis, _lincomb(mu, [(r_[2],) for r_ in res])[0],
                        1.0 if any(r_[3] for r_ in res) else 0.0))
            ups.extend(gains)
        # 4. classifier evidence once per new window: μ_j ∝ μ_j p_j^w
        if ev_rows is not None and w_ev > 0 and (k == 0 or ev_rows[k] != ev_rows[k - 1]):
            pw = prob_rows[ev_rows[k]]
            mu = [a * b for a, b in zip(mu, pw)]
            tot = sum(mu)
            mu = [v / tot for v in mu]
        # 5. combination
        post.extend(_moments(mu, modes))
        mps.extend(mu)
    return _assemble(stream, pri, post, fab, ups, M), np.frombuffer(mps, dtype=float).reshape(-1, M).copy()


def _assemble(stream, pri, post, fab, ups, M) -> dict:
    from models.fusion.ekf import _records

    m = len(stream)
    rec = _records(m, 4)
    a = np.frombuffer(pri, dtype=float).reshape(-1, 14)
    rec["x_prior"], rec["P_prior"] = a[:, :4].copy(), _to_full(a[:, 4:])
    a = np.frombuffer(post, dtype=float).reshape(-1, 14)
    rec["x"], rec["P"] = a[:, :4].copy(), _to_full(a[:, 4:])
    f = np.frombuffer(fab, dtype=float).reshape(-1, 4)
    step = stream.kind == STEP
    F = rec["F"]
    F[step, 0, 2], F[step, 0, 3], F[step, 1, 2], F[step, 1, 3] = f[:, 0], f[:, 1], f[:, 2], f[:, 3]
    if len(ups):
        u = np.frombuffer(ups, dtype=float).reshape(-1, 20)
        k = u[:, 0].astype(int)
        rec["nu"][k] = u[:, 1:3]
        rec["S"][k] = u[:, [3, 4, 4, 5]].reshape(-1, 2, 2)
        rec["R"][k] = u[:, [6, 7, 7, 8]].reshape(-1, 2, 2)
        rec["nis"][k] = u[:, 9]
        rec["weight"][k] = u[:, 10]
        rec["updated"][k] = True
        rec["accepted"][k] = u[:, 11] > 0.5
        rec["K"][k] = u[:, 12:20].reshape(-1, 4, 2)
    return rec
