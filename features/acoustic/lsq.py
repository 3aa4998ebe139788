"""The compiled least-squares core of the acoustic fix: Gauss–Newton, the NLOS exclusion search, the consider covariance.

The model and its sources are in :mod:`features.acoustic.positions` (which calls these
kernels through :func:`~features.acoustic.positions.solve_position`); this module holds the
arithmetic, compiled with numba (``@njit(cache=True)``): a frame has a few to a few tens
of ranges and the exclusion search solves up to 256 subsets of them, so in Python the
interpreter, not the arithmetic, set the receiver's speed (issue 25 item 1).

Ranges come as arrays: beacon ``se``, ``sn``, ``su`` (east, north, up, m), pseudoranges
``rho`` (m) and their σ ``sig`` (m). The unknowns are x = (east m, north m, clock offset s);
J's clock column is c. A clock prior (δ₀, σ_δ) enters as ``prior_d``, ``prior_w`` = 1/σ_δ²
(``prior_w`` = 0: none); the track's position prior (east, north, σ) as ``pos_prior`` with
``pos_prior[2]`` ≤ 0 for none. Equations:

    # f(x) = ‖p − sᵢ‖ + c·δ;  J = [∂f/∂e, ∂f/∂n, c];  N = JᵀWJ (+ prior_w at δ);  g = JᵀW(ρ − f) (+ prior)
    # x ← x + N⁻¹·g   (Björck 1996 §9.2),  covariance N⁻¹ at convergence,  χ² = Σ wᵢ·vᵢ² (+ prior)

Two solvers, as before the port (their results are compared in ``bench/receiver_identity.py``):
:func:`gauss_newton` stops each problem when a step moves less than 0.1 mm and takes χ² along
the last linearisation (cheap, for a handful of problems); :func:`gauss_newton_subsets` iterates
a batch of subsets together until every step is below 1 µm and evaluates at the end (the
exclusion search's many subsets).

Speed (issue 25): :func:`_subset_normal` returns its sums as scalars (three small arrays per subset and
iteration cost more than the sums) and skips the ranges a subset leaves out (they add exact zeros): the
4,270 exclusion searches recorded on three held-out walks took 0.246 s, now 0.164 s (process CPU, best of 3),
every result the same to the bit. Tried and left out: stopping each subset of a batch at its own convergence
(0.12 s) moved fixes by up to 1.7e-7 m, since a batch's subsets keep stepping until the slowest has
converged and that shared rule is part of the result; freezing a subset once a step leaves it bitwise
unchanged (exact) gained nothing measurable.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["gauss_newton", "gauss_newton_subsets", "exclude", "multistart", "consider_covariance", "STEP_TOL_M",
           "MAX_SUBSETS", "SCALAR_SUBSETS"]

STEP_TOL_M = 1e-4
"""Gauss-Newton (:func:`gauss_newton`) stops once a step moves the position and c·δ by less than this, m."""

SCALAR_SUBSETS = 16
"""Up to this many subsets of one size are solved one by one (each stopping on its own); more together."""

MAX_SUBSETS = 256
"""Most beacon subsets the exhaustive exclusion tries (C(8, 4) = 70, C(10, 5) = 252)."""


@njit(cache=True)
def _inverse3(a00, a01, a02, a10, a11, a12, a20, a21, a22):
    """Inverse of a 3×3 matrix by its adjugate, (9-tuple row-major, regular); singular when |det| ≤
    1e-14·(|a00| + |a11| + |a22|)³ or not finite."""
    c00, c01, c02 = a11 * a22 - a12 * a21, a02 * a21 - a01 * a22, a01 * a12 - a02 * a11
    det = a00 * c00 + a10 * c01 + a20 * c02
    scale = abs(a00) + abs(a11) + abs(a22)
    if not (math.isfinite(det) and abs(det) > 1e-14 * scale ** 3):
        return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), False
    return ((c00 / det, c01 / det, c02 / det,
             (a12 * a20 - a10 * a22) / det, (a00 * a22 - a02 * a20) / det, (a02 * a10 - a00 * a12) / det,
             (a10 * a21 - a11 * a20) / det, (a01 * a20 - a00 * a21) / det, (a00 * a11 - a01 * a10) / det), True)


@njit(cache=True)
def _inverse3_sym(a, b, c, e, f, i):
    """Upper triangle (00, 01, 02, 11, 12, 22) of the inverse of [[a, b, c], [b, e, f], [c, f, i]], and
    whether it is regular (|det| > 1e-14·(|a| + |e| + |i|)³)."""
    c00, c01, c02 = e * i - f * f, c * f - b * i, b * f - c * e
    det = a * c00 + b * c01 + c * c02
    scale = abs(a) + abs(e) + abs(i)
    if not (math.isfinite(det) and abs(det) > 1e-14 * scale ** 3):
        return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), False
    return (c00 / det, c01 / det, c02 / det, (a * i - c * c) / det, (b * c - a * f) / det, (a * e - b * b) / det), True


@njit(cache=True)
def gauss_newton(se, sn, su, rho, sig, h, c, iterations, x0, has_start, prior_d, prior_w):
    """One problem: (ok, x (3,), covariance (3, 3), residuals (n,), χ²).

    Starts from ``x0`` when ``has_start``, else from the weighted centroid of the beacons with the
    median clock offset. Stops when a step moves less than :data:`STEP_TOL_M`: residuals and covariance
    are then those of the last linearisation point (less than the tolerance away) and χ² moves along
    the linear model, ‖v − J·s‖²_W − ‖v‖²_W = −sᵀg (the step solves N·s = g). Not ok when a σ is not
    positive, the receiver sits on a beacon at its height, or N is singular."""
    n = rho.shape[0]
    x_out = np.zeros(3)
    cov_out = np.zeros((3, 3))
    res = np.zeros(n)
    for i in range(n):
        if not sig[i] > 0:
            return False, x_out, cov_out, res, 0.0
    w = np.empty(n)
    du2 = np.empty(n)
    for i in range(n):
        w[i] = 1.0 / (sig[i] * sig[i])
        du2[i] = (h - su[i]) ** 2
    if has_start:
        e, nn, d = x0[0], x0[1], x0[2]
    else:
        w_sum = 0.0
        se_sum = 0.0
        sn_sum = 0.0
        for i in range(n):
            w_sum += w[i]
        for i in range(n):
            se_sum += w[i] * se[i]
        for i in range(n):
            sn_sum += w[i] * sn[i]
        e, nn = se_sum / w_sum, sn_sum / w_sum
        off = np.empty(n)
        for i in range(n):
            off[i] = rho[i] - math.sqrt((se[i] - e) ** 2 + (sn[i] - nn) ** 2 + du2[i])
        d = np.median(off) / c
    w_sum = 0.0
    for i in range(n):
        w_sum += w[i]
    # The clock column of J is c for every range: its sums need only Σw, Σw·j and Σw·v.
    a22 = c * c * w_sum + prior_w
    converged = False
    chi2_shift = 0.0
    d_prior = d
    a00 = a01 = a11 = s0 = s1 = g0 = g1 = gv = 0.0
    inv = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for it in range(iterations + 1):
        a00 = a01 = a11 = s0 = s1 = g0 = g1 = gv = 0.0
        cd = c * d
        for i in range(n):
            de, dn = e - se[i], nn - sn[i]
            r = math.sqrt(de * de + dn * dn + du2[i])
            if r == 0.0:                     # on a beacon at the device's height: no direction, no fix
                return False, x_out, cov_out, res, 0.0
            v = rho[i] - r - cd
            res[i] = v
            j0, j1 = de / r, dn / r
            wj0, wj1 = w[i] * j0, w[i] * j1
            a00 += wj0 * j0
            a01 += wj0 * j1
            a11 += wj1 * j1
            s0 += wj0
            s1 += wj1
            g0 += wj0 * v
            g1 += wj1 * v
            gv += w[i] * v
        a02, a12, g2 = c * s0, c * s1, c * gv
        if prior_w > 0.0:
            g2 += (prior_d - d) * prior_w
        if it == iterations:
            break
        inv, regular = _inverse3_sym(a00, a01, a02, a11, a12, a22)
        if not regular:
            return False, x_out, cov_out, res, 0.0
        s_e = inv[0] * g0 + inv[1] * g1 + inv[2] * g2
        s_n = inv[1] * g0 + inv[3] * g1 + inv[4] * g2
        s_d = inv[2] * g0 + inv[4] * g1 + inv[5] * g2
        e, nn, d = e + s_e, nn + s_n, d + s_d
        if s_e * s_e + s_n * s_n < STEP_TOL_M ** 2 and abs(s_d) * c < STEP_TOL_M:
            converged = True
            chi2_shift = -(s_e * g0 + s_n * g1 + s_d * g2)
            d_prior = d - s_d
            break
    if not converged:
        d_prior = d
        inv, regular = _inverse3_sym(a00, a01, a02, a11, a12, a22)
        if not regular:
            return False, x_out, cov_out, res, 0.0
    if not (math.isfinite(inv[0]) and math.isfinite(inv[1]) and math.isfinite(inv[2]) and math.isfinite(inv[3])
            and math.isfinite(inv[4]) and math.isfinite(inv[5])):
        return False, x_out, cov_out, res, 0.0
    if min(inv[0], min(inv[3], inv[5])) <= 0 or inv[0] + inv[3] > 1e8:
        return False, x_out, cov_out, res, 0.0
    chi2 = 0.0
    for i in range(n):
        chi2 += w[i] * res[i] * res[i]
    chi2 += chi2_shift
    if prior_w > 0.0:
        chi2 += (prior_d - d_prior) ** 2 * prior_w
    x_out[0], x_out[1], x_out[2] = e, nn, d
    cov_out[0, 0], cov_out[0, 1], cov_out[0, 2] = inv[0], inv[1], inv[2]
    cov_out[1, 0], cov_out[1, 1], cov_out[1, 2] = inv[1], inv[3], inv[4]
    cov_out[2, 0], cov_out[2, 1], cov_out[2, 2] = inv[2], inv[4], inv[5]
    return True, x_out, cov_out, res, chi2


@njit(cache=True)
def _subset_normal(se, sn, du2, rho, w, x0, x1, x2, c, prior_d, prior_w):
    """Normal matrix (nine scalars, row-major) and gradient (three) of one subset (weights ``w``, zero for the
    ranges left out) at (``x0``, ``x1``, ``x2``), each sum over the kept ranges in order.

    A range left out adds exact zeros to every sum, so it is skipped (no square root, no division), unless the
    receiver sits on its beacon at its height: its Jacobian is then 0/0 and the sums NaN (the subset is then
    singular), as they were when every range was summed. Scalars, not arrays: this runs for every subset at
    every iteration of the exclusion search, where three small allocations cost more than the sums."""
    n = rho.shape[0]
    n00 = n01 = n02 = n10 = n11 = n12 = n20 = n21 = n22 = 0.0
    g0 = g1 = g2 = 0.0
    cx2 = c * x2
    for i in range(n):
        wi = w[i]
        de, dn = x0 - se[i], x1 - sn[i]
        if wi == 0.0 and not (de == 0.0 and dn == 0.0 and du2[i] == 0.0):
            continue
        r = math.sqrt(de * de + dn * dn + du2[i])
        j0, j1, j2 = de / r, dn / r, c
        v = rho[i] - (r + cx2)
        a0, a1, a2 = j0 * wi, j1 * wi, j2 * wi
        n00 += a0 * j0
        n01 += a0 * j1
        n02 += a0 * j2
        n10 += a1 * j0
        n11 += a1 * j1
        n12 += a1 * j2
        n20 += a2 * j0
        n21 += a2 * j1
        n22 += a2 * j2
        g0 += a0 * v
        g1 += a1 * v
        g2 += a2 * v
    n22 += prior_w
    if prior_w > 0.0:
        g2 += (prior_d - x2) * prior_w
    return n00, n01, n02, n10, n11, n12, n20, n21, n22, g0, g1, g2


@njit(cache=True)
def gauss_newton_subsets(se, sn, su, rho, sig, masks, h, c, iterations, x0, prior_d, prior_w):
    """Many subsets of one problem together (the exclusion search): x (k, 3), covariance (k, 3, 3),
    residuals (k, n), χ² (k,), ok (k,). ``masks`` (k, n) bool selects each subset's ranges (a range
    left out gets weight 0). Every subset is iterated until every subset's step is below 1 µm (those
    already there keep taking their small steps), then evaluated at the end."""
    k, n = masks.shape
    du2 = np.empty(n)
    for i in range(n):
        du2[i] = (h - su[i]) ** 2
    w = np.zeros((k, n))
    for j in range(k):
        for i in range(n):
            if masks[j, i]:
                w[j, i] = 1.0 / sig[i] ** 2
    x = np.empty((k, 3))
    for j in range(k):
        x[j, 0], x[j, 1], x[j, 2] = x0[0], x0[1], x0[2]
    ok = np.ones(k, dtype=np.bool_)
    for _ in range(iterations):
        done = True
        for j in range(k):
            if not ok[j]:
                continue
            a00, a01, a02, a10, a11, a12, a20, a21, a22, g0, g1, g2 = _subset_normal(
                se, sn, du2, rho, w[j], x[j, 0], x[j, 1], x[j, 2], c, prior_d, prior_w)
            inv, regular = _inverse3(a00, a01, a02, a10, a11, a12, a20, a21, a22)
            if not regular:
                ok[j] = False
                continue
            s0 = inv[0] * g0 + inv[1] * g1 + inv[2] * g2
            s1 = inv[3] * g0 + inv[4] * g1 + inv[5] * g2
            s2 = inv[6] * g0 + inv[7] * g1 + inv[8] * g2
            x[j, 0] += s0
            x[j, 1] += s1
            x[j, 2] += s2
            if not (s0 * s0 + s1 * s1 < 1e-12 and abs(s2) * c < 1e-6):
                done = False
        if done:
            break
    cov = np.zeros((k, 3, 3))
    res = np.zeros((k, n))
    chi2 = np.zeros(k)
    for j in range(k):
        a00, a01, a02, a10, a11, a12, a20, a21, a22, g0, g1, g2 = _subset_normal(
            se, sn, du2, rho, w[j], x[j, 0], x[j, 1], x[j, 2], c, prior_d, prior_w)
        inv, regular = _inverse3(a00, a01, a02, a10, a11, a12, a20, a21, a22)
        for a in range(3):
            for b in range(3):
                cov[j, a, b] = 0.5 * (inv[3 * a + b] + inv[3 * b + a])
        finite = True
        for q in range(9):
            finite = finite and math.isfinite(inv[q])
        ok[j] = ok[j] and regular and finite and inv[0] > 0 and inv[4] > 0 and inv[8] > 0 and inv[0] + inv[4] <= 1e8
        # χ² over the kept ranges (a range left out has weight 0); residuals of every range.
        s = 0.0
        for i in range(n):
            de, dn = x[j, 0] - se[i], x[j, 1] - sn[i]
            r = rho[i] - (math.sqrt(de * de + dn * dn + du2[i]) + c * x[j, 2])
            res[j, i] = r
            s += w[j, i] * r * r
        if prior_w > 0.0:
            s += (prior_d - x[j, 2]) ** 2 * prior_w
        chi2[j] = s
    return x, cov, res, chi2, ok


@njit(cache=True)
def _prior_share(east, north, pos_prior):
    """‖p − p̂‖²/σ² of a fix against the track's prediction (east, north, σ): its share of an exclusion score."""
    return ((east - pos_prior[0]) ** 2 + (north - pos_prior[1]) ** 2) / pos_prior[2] ** 2


@njit(cache=True)
def _next_combination(idx, n):
    """Advance ``idx`` (sorted indices) to the next combination of range(n) in lexicographic order; False at the end."""
    m = idx.shape[0]
    i = m - 1
    while i >= 0 and idx[i] == n - m + i:
        i -= 1
    if i < 0:
        return False
    idx[i] += 1
    for j in range(i + 1, m):
        idx[j] = idx[j - 1] + 1
    return True


@njit(cache=True)
def _n_choose_k(n, k):
    out = 1
    for i in range(k):
        out = out * (n - i) // (i + 1)
    return out


@njit(cache=True)
def exclude(se, sn, su, rho, sig, h, c, iterations, x0, prior_d, prior_w, pos_prior, limits, max_excluded,
            most_excluded):
    """Largest subset (of four or more, three with a clock prior) whose residuals pass the chi-square test;
    among equals the smallest score (χ² plus the position prior's share). Returns (found, keep mask (n,),
    x, covariance, residuals of the kept (n,; zeros elsewhere), χ²).

    Subsets are tried by decreasing size, at most ``max_excluded`` beacons left out and
    :data:`MAX_SUBSETS` subsets in all, in lexicographic order; a size's subsets are solved one by one
    (:func:`gauss_newton`) when at most :data:`SCALAR_SUBSETS`, else together
    (:func:`gauss_newton_subsets`). ``limits[dof]``: the test's χ² limit per degree of freedom. Where the
    budget runs out, or ``most_excluded`` (from ``max_excluded_share``) allows more exclusions than
    ``max_excluded``, :func:`_backward_elimination` goes on.
    """
    n = rho.shape[0]
    n_prior = 1 if prior_w > 0.0 else 0
    smallest = 4 - n_prior
    tried = 0
    truncated = False
    empty = np.zeros(n, dtype=np.bool_)
    lowest = max(smallest - 1, n - 1 - max_excluded)
    for size in range(n - 1, lowest, -1):
        total = _n_choose_k(n, size)
        budget = MAX_SUBSETS - tried
        truncated = total > budget
        count = total if total < budget else budget
        tried += count
        if count <= 0:
            break
        limit = limits[size + n_prior - 3]
        masks = np.zeros((count, n), dtype=np.bool_)
        idx = np.arange(size)
        for row in range(count):
            for q in range(size):
                masks[row, idx[q]] = True
            _next_combination(idx, n)
        if count <= SCALAR_SUBSETS:
            best_score = np.inf
            best_row = -1
            best = (np.zeros(3), np.zeros((3, 3)), np.zeros(n), 0.0)
            for row in range(count):
                keep = np.flatnonzero(masks[row])
                ok, x, cov, r, chi2 = gauss_newton(se[keep], sn[keep], su[keep], rho[keep], sig[keep], h, c,
                                                   iterations, x0, True, prior_d, prior_w)
                if not ok or not chi2 <= limit:
                    continue
                score = chi2
                if pos_prior[2] > 0.0:
                    score += _prior_share(x[0], x[1], pos_prior)
                if score < best_score:
                    full_res = np.zeros(n)
                    full_res[keep] = r
                    best_score, best_row, best = score, row, (x, cov, full_res, chi2)
            if best_row >= 0:
                return True, masks[best_row].copy(), best[0], best[1], best[2], best[3]
        else:
            x, cov, res, chi2, ok = gauss_newton_subsets(se, sn, su, rho, sig, masks, h, c, iterations, x0,
                                                         prior_d, prior_w)
            best_row = -1
            best_score = np.inf
            for row in range(count):
                score = chi2[row] if (ok[row] and chi2[row] <= limit) else np.inf
                if pos_prior[2] > 0.0:
                    score += _prior_share(x[row, 0], x[row, 1], pos_prior)
                if score < best_score:
                    best_score, best_row = score, row
            if best_row >= 0 and math.isfinite(best_score):
                r = res[best_row] * masks[best_row]
                return True, masks[best_row].copy(), x[best_row].copy(), cov[best_row].copy(), r, chi2[best_row]
        if truncated:
            break
    if not truncated and most_excluded <= max_excluded:
        return False, empty, np.zeros(3), np.zeros((3, 3)), np.zeros(n), 0.0
    return _backward_elimination(se, sn, su, rho, sig, h, c, iterations, x0, prior_d, prior_w, pos_prior, limits,
                                 max(max_excluded, most_excluded), smallest)


@njit(cache=True)
def _backward_elimination(se, sn, su, rho, sig, h, c, iterations, x0, prior_d, prior_w, pos_prior, limits, most,
                          smallest):
    """Iterative exclusion (RAIM FDE's one-at-a-time form; Brown 1992, "A baseline GPS RAIM scheme",
    Navigation 39(3)): leave each remaining beacon out in turn (one batched solve), drop the one whose
    removal leaves the smallest score (χ² plus the position prior's share), until the test passes; at
    most ``most`` dropped and at least ``smallest`` kept."""
    n = rho.shape[0]
    n_prior = 1 if prior_w > 0.0 else 0
    keep = np.ones(n, dtype=np.bool_)
    n_keep = n
    start = x0.copy()
    while n_keep - 1 >= smallest and n - n_keep < most:
        size = n_keep - 1
        kept_idx = np.flatnonzero(keep)
        masks = np.zeros((n_keep, n), dtype=np.bool_)
        for row in range(n_keep):
            masks[row] = keep
            masks[row, kept_idx[row]] = False
        x, cov, res, chi2, ok = gauss_newton_subsets(se, sn, su, rho, sig, masks, h, c, iterations, start,
                                                     prior_d, prior_w)
        best_row = -1
        best_score = np.inf
        for row in range(n_keep):
            score = chi2[row] if ok[row] else np.inf
            if pos_prior[2] > 0.0:
                score += _prior_share(x[row, 0], x[row, 1], pos_prior)
            if score < best_score:
                best_score, best_row = score, row
        if best_row < 0 or not math.isfinite(best_score):
            break
        keep = masks[best_row].copy()
        n_keep -= 1
        start = x[best_row].copy()
        if chi2[best_row] <= limits[size + n_prior - 3]:
            return True, keep, x[best_row].copy(), cov[best_row].copy(), res[best_row] * keep, chi2[best_row]
    return False, np.zeros(n, dtype=np.bool_), np.zeros(3), np.zeros((3, 3)), np.zeros(n), 0.0


@njit(cache=True)
def multistart(se, sn, su, rho, sig, h, c, iterations, starts_en, prior_d, prior_w):
    """Gauss-Newton from each of ``starts_en`` (m, 2) (the clock from the median pseudorange less the median
    distance from there); the solution of least χ² (first among equals), as :func:`gauss_newton` returns it.

    From the beacons' centroid Gauss-Newton can diverge when few beacons are heard from one side
    (pseudorange problems have a second, spurious solution; Abel & Chaffee 1991, IEEE Trans. AES 27(6)).
    """
    n = rho.shape[0]
    clock0 = np.median(rho) / c
    best_ok = False
    best = (np.zeros(3), np.zeros((3, 3)), np.zeros(n), np.inf)
    for m in range(starts_en.shape[0]):
        geo = np.empty(n)
        for i in range(n):
            geo[i] = math.sqrt((starts_en[m, 0] - se[i]) ** 2 + (starts_en[m, 1] - sn[i]) ** 2 + (h - su[i]) ** 2)
        x0 = np.array([starts_en[m, 0], starts_en[m, 1], clock0 - np.median(geo) / c])
        ok, x, cov, res, chi2 = gauss_newton(se, sn, su, rho, sig, h, c, iterations, x0, True, prior_d, prior_w)
        if ok and (not best_ok or chi2 < best[3]):
            best_ok, best = True, (x, cov, res, chi2)
    return best_ok, best[0], best[1], best[2], best[3]


@njit(cache=True)
def consider_covariance(se, sn, su, sig, x, cov, h, c, wind_sigma_m_s, scale_sigma):
    """The fix covariance with the air's common errors as consider parameters (Tapley, Schutz & Born,
    "Statistical Orbit Determination", 2004, §6.3):

        # ρᵢ = rᵢ·(1 − w·n̂ᵢ/c − k) + c·δ  ⇒  ∂ρᵢ/∂w = −(p − sᵢ)_h/c,  ∂ρᵢ/∂k = −rᵢ
        # P_c = P + K·G·Σ·Gᵀ·Kᵀ,  K = P·JᵀW,  Σ = diag(σ_w², σ_w², σ_k²)

    K·G = P·Σᵢ wᵢ·jᵢ·gᵢᵀ is one 3×3 sum over the kept ranges."""
    e, n = x[0], x[1]
    sw, sk = wind_sigma_m_s / c, scale_sigma
    m = np.zeros((3, 3))
    for i in range(sig.shape[0]):
        de, dn, du = e - se[i], n - sn[i], h - su[i]
        dist = math.sqrt(de * de + dn * dn + du * du)
        w = 1.0 / (sig[i] * sig[i])
        j0, j1, j2 = w * de / dist, w * dn / dist, w * c          # wᵢ·jᵢ
        g0, g1, g2 = -de * sw, -dn * sw, -dist * sk               # gᵢ·Σ^½
        m[0, 0] += j0 * g0
        m[0, 1] += j0 * g1
        m[0, 2] += j0 * g2
        m[1, 0] += j1 * g0
        m[1, 1] += j1 * g1
        m[1, 2] += j1 * g2
        m[2, 0] += j2 * g0
        m[2, 1] += j2 * g1
        m[2, 2] += j2 * g2
    kg = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            kg[a, b] = cov[a, 0] * m[0, b] + cov[a, 1] * m[1, b] + cov[a, 2] * m[2, b]
    out = np.empty((3, 3))
    # P_c = P + (KG)(KG)ᵀ, symmetric by construction
    for a in range(3):
        for b in range(3):
            out[a, b] = cov[a, b] + kg[a, 0] * kg[b, 0] + kg[a, 1] * kg[b, 1] + kg[a, 2] * kg[b, 2]
    return out
