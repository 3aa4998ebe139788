"""Integer ambiguity resolution as an RTK engine does it: LAMBDA, the ratio test, the bootstrapping success rate.

* :func:`lambda_search` — the LAMBDA method (Teunissen 1995, "The
  least-squares ambiguity decorrelation adjustment: a method for fast GPS
  integer ambiguity estimation", J. Geodesy 70): LᵀDL factorisation of the
  float ambiguities' covariance Q, decorrelation by integer Gauss
  transformations and permutations (de Jonge & Tiberius 1996, LGR series 12,
  TU Delft), and the search for the best two integer vectors by integer least
  squares, min (â − a)ᵀQ⁻¹(â − a), in the modified form of Chang, Yang & Zhou
  (2005), "MLAMBDA: a modified LAMBDA method for integer least-squares
  estimation", J. Geodesy 79. Ported from RTKLIB's ``lambda.c`` (T. Takasu,
  BSD 2-clause), the engine most low-cost RTK receivers' firmware descends
  from; compiled with numba because no maintained Python package carries it
  (pyrtklib binds all of RTKLIB for one function) and an RTK engine runs it at
  every epoch it is not fixed.
* **Ratio test**: the fix is accepted when the second-best candidate's
  squared norm is at least ``threshold`` times the best's (RTKLIB default
  3.0, option ``pos2-arthres``; Takasu, RTKLIB 2.4.2 manual, Table F.4-1).
* :func:`bootstrap_success_rate` — P_s = Π_i (2Φ(1/(2σ_{i|I})) − 1) from the
  decorrelated conditional variances D (Teunissen 1998, "Success probability
  of integer GPS ambiguity rounding and bootstrapping", J. Geodesy 72): the
  receiver's own figure of how likely its integers are right, given its own
  (unbiased) error model. A bias b in the float ambiguities lowers the true
  success rate to Π_i [Φ((1 − 2β_i)/(2σ_i)) + Φ((1 + 2β_i)/(2σ_i)) − 1]
  with β the conditional bias (Teunissen 2001, "Integer estimation in the
  presence of biases", J. Geodesy 75) — the receiver cannot compute that, as
  it does not know b; the simulation shows it by rounding the biased floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.special import ndtr

__all__ = ["LambdaResult", "ld_factor", "decorrelate", "lambda_search", "bootstrap_success_rate",
           "biased_bootstrap_success_rate"]


@dataclass(frozen=True)
class LambdaResult:
    """Best and second-best integer vectors (n,) and their squared norms; ``ratio`` = q2/q1; ``d`` the decorrelated
    conditional variances (n,) (for :func:`bootstrap_success_rate`)."""

    best: np.ndarray
    second: np.ndarray
    q_best: float
    q_second: float
    d: np.ndarray

    @property
    def ratio(self) -> float:
        return self.q_second / max(self.q_best, 1e-300)


@njit(cache=True)
def _ld(q):
    n = q.shape[0]
    a = q.copy()
    lo = np.zeros((n, n))
    d = np.zeros(n)
    for i in range(n - 1, -1, -1):
        d[i] = a[i, i]
        if d[i] <= 0.0:
            return lo, d, False
        sq = math.sqrt(d[i])
        for j in range(i + 1):
            lo[i, j] = a[i, j] / sq
        for j in range(i):
            for k in range(j + 1):
                a[j, k] -= lo[i, k] * lo[i, j]
        for j in range(i + 1):
            lo[i, j] /= lo[i, i]
    return lo, d, True


def ld_factor(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Q = Lᵀ·diag(D)·L with L unit lower triangular (RTKLIB ``LD``); raises ``np.linalg.LinAlgError`` if Q is not
    positive definite.

    >>> L, d = ld_factor(np.array([[4.0, 2.0], [2.0, 3.0]]))
    >>> np.allclose(L.T @ np.diag(d) @ L, [[4.0, 2.0], [2.0, 3.0]])
    True
    """
    lo, d, ok = _ld(np.ascontiguousarray(q, dtype=np.float64))
    if not ok:
        raise np.linalg.LinAlgError("ambiguity covariance is not positive definite")
    return lo, d


@njit(cache=True)
def _decorrelate(lo, d):
    n = d.shape[0]
    z = np.eye(n)
    j = n - 2
    k = n - 2
    while j >= 0:
        if j <= k:
            for i in range(j + 1, n):
                mu = math.floor(lo[i, j] + 0.5)
                if mu != 0.0:
                    for r in range(i, n):
                        lo[r, j] -= mu * lo[r, i]
                    for r in range(n):
                        z[r, j] -= mu * z[r, i]
        delta = d[j] + lo[j + 1, j] * lo[j + 1, j] * d[j + 1]
        if delta + 1e-6 < d[j + 1]:
            eta = d[j] / delta
            lam = d[j + 1] * lo[j + 1, j] / delta
            d[j] = eta * d[j + 1]
            d[j + 1] = delta
            for c in range(j):
                a0 = lo[j, c]
                a1 = lo[j + 1, c]
                lo[j, c] = -lo[j + 1, j] * a0 + a1
                lo[j + 1, c] = eta * a0 + lam * a1
            lo[j + 1, j] = lam
            for r in range(j + 2, n):
                tmp = lo[r, j]
                lo[r, j] = lo[r, j + 1]
                lo[r, j + 1] = tmp
            for r in range(n):
                tmp = z[r, j]
                z[r, j] = z[r, j + 1]
                z[r, j + 1] = tmp
            k = j
            j = n - 2
        else:
            j -= 1
    return z


def decorrelate(lo: np.ndarray, d: np.ndarray) -> np.ndarray:
    """LAMBDA reduction in place on (L, D): integer Gauss transformations and permutations; returns Z with
    z = Zᵀa and Zᵀ·Q·Z = Lᵀ·diag(D)·L (RTKLIB ``reduction``)."""
    return _decorrelate(lo, d)


@njit(cache=True)
def _sgn(x):
    return -1.0 if x <= 0.0 else 1.0


@njit(cache=True)
def _search(lo, d, zs, max_loops):
    """The two integer vectors nearest ``zs`` in the metric Lᵀ·diag(D)·L (RTKLIB ``search``, m = 2).

    Returns (candidates (2, n), squared norms (2,), number found)."""
    n = d.shape[0]
    s_mat = np.zeros((n, n))
    dist = np.zeros(n)
    zb = np.zeros(n)
    z = np.zeros(n)
    step = np.zeros(n)
    zn = np.zeros((2, n))
    sn = np.full(2, np.inf)
    nn = 0
    imax = 0
    maxdist = 1e99
    k = n - 1
    zb[k] = zs[k]
    z[k] = math.floor(zb[k] + 0.5)
    y = zb[k] - z[k]
    step[k] = _sgn(y)
    for _ in range(max_loops):
        newdist = dist[k] + y * y / d[k]
        if newdist < maxdist:
            if k != 0:
                k -= 1
                dist[k] = newdist
                for i in range(k + 1):
                    s_mat[k, i] = s_mat[k + 1, i] + (z[k + 1] - zb[k + 1]) * lo[k + 1, i]
                zb[k] = zs[k] + s_mat[k, k]
                z[k] = math.floor(zb[k] + 0.5)
                y = zb[k] - z[k]
                step[k] = _sgn(y)
            else:
                if nn < 2:
                    if nn == 0 or newdist > sn[imax]:
                        imax = nn
                    zn[nn, :] = z
                    sn[nn] = newdist
                    nn += 1
                else:
                    if newdist < sn[imax]:
                        zn[imax, :] = z
                        sn[imax] = newdist
                        imax = 0 if sn[0] >= sn[1] else 1
                    maxdist = sn[imax]
                z[0] += step[0]
                y = zb[0] - z[0]
                step[0] = -step[0] - _sgn(step[0])
        else:
            if k == n - 1:
                break
            k += 1
            z[k] += step[k]
            y = zb[k] - z[k]
            step[k] = -step[k] - _sgn(step[k])
    if nn == 2 and sn[1] < sn[0]:
        zn = zn[::-1].copy()
        sn = sn[::-1].copy()
    return zn, sn, nn


@njit(cache=True)
def _gesv(a, b):
    """``numpy.linalg.solve(a, b)`` (b (n,) or (n, m)) as LAPACK gesv gives it, raising on a singular ``a``; a
    non-finite ``a`` or ``b`` gives NaN, as numpy hands them to LAPACK where numba's ``solve`` refuses them."""
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return np.full(b.shape, np.nan)
    return np.ascontiguousarray(np.linalg.solve(a, b))      # numba's is Fortran-ordered: one layout, C, for both


@njit(cache=True)
def _lambda(a, q):
    """:func:`lambda_search` compiled, for the RTK engine's loop: (ok, best, second, q_best, q_second, d, found);
    ok False when Q is not positive definite. Z⁻ᵀ as numpy's ``inv`` forms it (LAPACK gesv against I)."""
    lo, d, ok = _ld(q)
    n = a.shape[0]
    if not ok:
        return False, np.zeros(n), np.zeros(n), np.inf, np.inf, d, 0
    z = _decorrelate(lo, d)
    zs = z.T @ a
    zn, sn, nn = _search(lo, d, zs, 100_000)
    zi = _gesv(z.T, np.eye(n))
    best = np.rint(zi @ zn[0])
    second = np.rint(zi @ zn[1]) if nn > 1 else best
    return True, best, second, sn[0], sn[1] if nn > 1 else np.inf, d, nn


def lambda_search(a_float: np.ndarray, q: np.ndarray) -> LambdaResult:
    """Integer least-squares estimate of the float ambiguities ``a_float`` (n,) with covariance ``q`` (n, n), cycles;
    raises ``np.linalg.LinAlgError`` if ``q`` is not positive definite.

    >>> r = lambda_search(np.array([0.1, 2.9]), np.diag([0.01, 0.01]))
    >>> r.best.tolist(), round(r.q_best, 3), round(r.ratio, 2)
    ([0.0, 3.0], 2.0, 41.0)
    """
    ok, best, second, q_best, q_second, d, _ = _lambda(np.asarray(a_float, np.float64),
                                                       np.ascontiguousarray(q, dtype=np.float64))
    if not ok:
        raise np.linalg.LinAlgError("ambiguity covariance is not positive definite")
    return LambdaResult(best, second, float(q_best), float(q_second), d)


@njit(cache=True)
def _ndtr(x: float) -> float:
    """Φ(x) by Cephes' formula, as scipy's ``ndtr`` forms it (0.5 + 0.5·erf(x/√2) near 0, 0.5·erfc(|x|/√2)
    beyond), on the C library's erf and erfc."""
    t = x * 0.7071067811865476
    z = abs(t)
    if z < 0.7071067811865476:
        return 0.5 + 0.5 * math.erf(t)
    y = 0.5 * math.erfc(z)
    return 1.0 - y if t > 0.0 else y


@njit(cache=True, error_model="numpy")
def _bootstrap(d):
    p = 1.0
    for i in range(d.shape[0]):
        p *= 2.0 * _ndtr(1.0 / (2.0 * math.sqrt(d[i]))) - 1.0
    return p


def bootstrap_success_rate(d: np.ndarray) -> float:
    """P_s = Π (2Φ(1/(2√dᵢ)) − 1) of integer bootstrapping, dᵢ the conditional variances (cycles²) (Teunissen 1998).

    >>> round(bootstrap_success_rate(np.array([0.04, 0.01])), 4)      # σ 0.2 and 0.1 cycles
    0.9876
    """
    return float(_bootstrap(np.asarray(d, np.float64).ravel()))


def biased_bootstrap_success_rate(d: np.ndarray, bias_cycles: np.ndarray) -> float:
    """Success rate of bootstrapping with conditional biases β (cycles): Π [Φ((1 − 2β)/(2σ)) + Φ((1 + 2β)/(2σ)) − 1]
    (Teunissen 2001). Equal to :func:`bootstrap_success_rate` at β = 0; about one half per ambiguity at β = ½.

    >>> round(biased_bootstrap_success_rate(np.array([0.0025]), np.array([0.5])), 3)
    0.5
    """
    sig = np.sqrt(np.asarray(d, float))
    b = np.asarray(bias_cycles, float)
    return float(np.prod(ndtr((1.0 - 2.0 * b) / (2.0 * sig)) + ndtr((1.0 + 2.0 * b) / (2.0 * sig)) - 1.0))
