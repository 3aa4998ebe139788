"""The compiled least-squares core (features/acoustic/lsq.py) against an independent reference (issue 25 item 1).

The reference solves each problem with ``scipy.optimize.least_squares`` (trust-region reflective, its own
Jacobian by finite differences) on the whitened residuals, and the exclusion search by brute force over every
subset: no line of it is shared with the core. Which bug each test would catch is said in its docstring.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.optimize
import scipy.stats

from features.acoustic import lsq
from features.acoustic.positions import BeaconRange, PositionConfig, solve_position

C = 343.2
H = 1.0
RING = [(0.0, 0.0), (15.0, 0.0), (30.0, 0.0), (30.0, 15.0), (30.0, 30.0), (15.0, 30.0), (0.0, 30.0), (0.0, 15.0)]


def _frame(rng, east, north, clock_s, sigma_m, bias):
    """Beacons of the 30 m ring (poles of 3 m), noisy pseudoranges with the given NLOS biases (index → m)."""
    s = np.array([(e, n, 3.0) for e, n in RING])
    d = np.sqrt((s[:, 0] - east) ** 2 + (s[:, 1] - north) ** 2 + (s[:, 2] - H) ** 2)
    rho = d + C * clock_s + rng.normal(0.0, sigma_m, len(d)) + np.array([bias.get(i, 0.0) for i in range(len(d))])
    sig = np.full(len(d), sigma_m)
    return s[:, 0].copy(), s[:, 1].copy(), s[:, 2].copy(), rho, sig


def _reference(se, sn, su, rho, sig, x0, prior=None):
    """x, covariance (JᵀWJ)⁻¹ at x, χ² by scipy's least squares (clock prior (δ₀, σ) as one more residual)."""
    def residuals(x):
        r = (rho - np.sqrt((x[0] - se) ** 2 + (x[1] - sn) ** 2 + (H - su) ** 2) - C * x[2]) / sig
        return r if prior is None else np.append(r, (prior[0] - x[2]) / prior[1])

    sol = scipy.optimize.least_squares(residuals, x0, x_scale=[1.0, 1.0, 1e-3], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    j = sol.jac
    return sol.x, np.linalg.inv(j.T @ j), float(sol.fun @ sol.fun)


def test_gauss_newton_matches_scipy_least_squares():
    """20 random frames with and without a clock prior: position within 1 µm, clock within 1 ns, covariance
    within 1e-4 relative and χ² within 1e-6 of scipy's — would catch a wrong Jacobian column, a dropped prior
    term, a transposed inverse or a χ² taken at the wrong point."""
    rng = np.random.default_rng(3)
    for k in range(20):
        east, north = rng.uniform(3.0, 27.0, 2)
        se, sn, su, rho, sig = _frame(rng, east, north, 0.004, 0.03, {})
        prior = (0.004 + rng.normal(0, 1e-4), 2e-4) if k % 2 else None
        pd, pw = (0.0, 0.0) if prior is None else (prior[0], 1.0 / prior[1] ** 2)
        ok, x, cov, _, chi2 = lsq.gauss_newton(se, sn, su, rho, sig, H, C, 20, np.zeros(3), False, pd, pw)
        assert ok
        x_ref, cov_ref, chi2_ref = _reference(se, sn, su, rho, sig, np.array([15.0, 15.0, 0.0]), prior)
        assert math.hypot(x[0] - x_ref[0], x[1] - x_ref[1]) < 1e-6
        assert abs(x[2] - x_ref[2]) < 1e-9
        np.testing.assert_allclose(cov, cov_ref, rtol=1e-4, atol=1e-14)
        assert chi2 == pytest.approx(chi2_ref, rel=1e-6, abs=1e-9)


def _brute_force_exclusion(se, sn, su, rho, sig, x0, max_excluded, alpha):
    """The largest subset (≥ 4) passing the χ² test, the smallest χ² among equals, every subset by scipy."""
    n = len(rho)
    for size in range(n - 1, max(3, n - 1 - max_excluded), -1):
        best = None
        for keep in itertools.combinations(range(n), size):
            k = list(keep)
            x, _, chi2 = _reference(se[k], sn[k], su[k], rho[k], sig[k], x0)
            if chi2 <= scipy.stats.chi2.isf(alpha, size - 3) and (best is None or chi2 < best[2]):
                best = (keep, x, chi2)
        if best is not None:
            return best
    return None


@pytest.mark.parametrize("bias", [{2: 2.5}, {1: 3.0, 5: 1.8}, {0: 4.0, 3: 2.2, 6: 1.5}])
def test_exclusion_keeps_the_subset_a_brute_force_search_keeps(bias):
    """One, two and three NLOS beacons of eight (the scalar path of 7-subsets, the batched path of 28 and 56):
    the compiled search leaves out exactly the beacons a brute-force scipy search does, and its fix lies within
    1 µm of that subset's — would catch a wrong combination order, an off-by-one in the sizes tried, the χ²
    limit taken at the wrong degrees of freedom, or residuals of the wrong rows."""
    rng = np.random.default_rng(5)
    se, sn, su, rho, sig = _frame(rng, 11.0, 19.0, -0.002, 0.02, bias)
    ok, x0, _, _, chi2 = lsq.gauss_newton(se, sn, su, rho, sig, H, C, 20, np.zeros(3), False, 0.0, 0.0)
    assert ok and chi2 > scipy.stats.chi2.isf(1e-3, 5)
    limits = np.array([scipy.stats.chi2.isf(1e-3, d) if d > 0 else np.inf for d in range(9)])
    found, keep, x, _, res, chi2 = lsq.exclude(se, sn, su, rho, sig, H, C, 20, x0, 0.0, 0.0, np.zeros(3), limits,
                                               3, 0)
    ref = _brute_force_exclusion(se, sn, su, rho, sig, x0, 3, 1e-3)
    assert found and ref is not None
    assert tuple(np.flatnonzero(keep)) == ref[0]
    assert sorted(set(range(8)) - set(ref[0])) == sorted(bias)
    assert math.hypot(x[0] - ref[1][0], x[1] - ref[1][1]) < 1e-6
    assert chi2 == pytest.approx(ref[2], rel=1e-6)
    assert np.all(res[~keep] == 0.0) and np.any(res[keep] != 0.0)


def test_solve_position_reports_the_compiled_search():
    """Through :func:`solve_position`: two NLOS beacons rejected by id, the fix within 3 cm of the truth and the
    rms residual that of the kept ranges only (hand check: a 2 m residual kept would give an rms above 0.5 m)."""
    rng = np.random.default_rng(8)
    se, sn, su, rho, sig = _frame(rng, 9.0, 21.0, 0.001, 0.01, {3: 2.0, 6: 2.6})
    ranges = [BeaconRange(i + 1, se[i], sn[i], su[i], rho[i], sig[i], 0.0) for i in range(8)]
    from features.site import AcousticConfig, Beacon, Grid, Origin, Site

    site = Site(name="ring", origin=Origin(31.0, 118.0), device_height_m=H, grid=Grid(5.0, -5.0, 35.0, -5.0, 35.0),
                acoustic=AcousticConfig(n_slots=8),
                beacons=tuple(Beacon(id=i + 1, east_m=e, north_m=n, up_m=3.0, slot=i) for i, (e, n) in enumerate(RING)))
    fix = solve_position(ranges, site, C, PositionConfig(path_rel_sigma=0.0, air_rel_sigma=0.0, wind_sigma_m_s=0.0))
    assert fix.rejected_ids == (4, 7)
    assert math.hypot(fix.east_m - 9.0, fix.north_m - 21.0) < 0.03
    assert fix.rms_residual_m < 0.03


def test_consider_covariance_matches_the_matrix_formula():
    """P_c = P + K·G·Σ·Gᵀ·Kᵀ written out with numpy matrices (K = P·JᵀW, G = [−(p − sᵢ)_h/c, −rᵢ]) — would catch a
    sign, a missing weight or a transposed gain in the compiled sum."""
    rng = np.random.default_rng(2)
    se, sn, su, rho, sig = _frame(rng, 12.0, 7.0, 0.0, 0.03, {})
    ok, x, cov, _, _ = lsq.gauss_newton(se, sn, su, rho, sig, H, C, 20, np.zeros(3), False, 0.0, 0.0)
    out = lsq.consider_covariance(se, sn, su, sig, x, cov, H, C, 2.0, 0.003)
    d = np.column_stack([x[0] - se, x[1] - sn, H - su])
    r = np.linalg.norm(d, axis=1)
    j = np.column_stack([d[:, 0] / r, d[:, 1] / r, np.full(len(r), C)])
    g = np.column_stack([-d[:, 0] / C, -d[:, 1] / C, -r])
    k = cov @ j.T @ np.diag(1.0 / sig ** 2)
    expected = cov + k @ g @ np.diag([4.0, 4.0, 0.003 ** 2]) @ g.T @ k.T
    np.testing.assert_allclose(out, expected, rtol=1e-10)
