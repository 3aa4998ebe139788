"""Issue 20: the noise policies' variances against numbers worked out by hand.

A UERE is the 1σ range error; the horizontal error of a fix is UERE·HDOP (its 2-D rms), so each axis gets
σ² = (UERE·HDOP)²/2 (Kaplan & Hegarty 2006, ch. 7). The fits invert that: UERE² = E[(e² + n²)/HDOP²] and,
for the acoustic covariance scale, k² = E[e'C⁻¹e]/2 (2 degrees of freedom). The context model's R, outlier
prior and κ are expectations over the class probabilities. Every expected number below is written out, not
computed by the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from models.fusion import ClassTrack, ContextNoise, GnssEvents, PerClassNoise, QualityNoise, merge_events
from models.fusion.context import ErrorSeries
from models.fusion.events import AcousticEvents


def _context(cells: dict, acoustic: dict) -> ContextNoise:
    cn = ContextNoise(n_classes=3, bias=False)
    cn.gnss_ = {k: {"s2": v[0], "eps": v[1], "kappa": v[2], "sb2": 0.0, "tau_s": 1.0} for k, v in cells.items()}
    cn.acoustic_ = {c: {"s2": v[0], "eps": v[1], "kappa": v[2]} for c, v in acoustic.items()}
    return cn


def test_context_r_eps_kappa_are_the_expectations_under_the_class_probabilities():
    """R = C·Σ p_c s²_c, ε = Σ p_c ε_c, κ = exp Σ p_c ln κ_c per fix (the class probabilities in force)."""
    cn = _context({(0, 1): (1.0, 0.01, 10.0), (1, 1): (4.0, 0.05, 20.0), (2, 1): (9.0, 0.2, 80.0)},
                  {-1: (1.0, 0.0, 4.0), 0: (1.0, 0.01, 4.0), 1: (2.0, 0.02, 16.0), 2: (3.0, 0.1, 64.0)})
    gnss = GnssEvents(np.array([1.0]), np.array([0.0]), np.array([0.0]), np.tile(np.diag([0.5, 2.0]), (1, 1, 1)),
                      quality=np.array([1]), hdop=np.array([1.5]))
    acoustic = AcousticEvents(np.array([2.0]), np.array([0.0]), np.array([0.0]), np.array([np.diag([0.5, 0.25])]))
    ev = merge_events(gnss=gnss, acoustic=acoustic)
    spec = cn.measurement_noise(ev, ClassTrack(np.array([0.0]), np.array([[0.2, 0.3, 0.5]])))
    g, a = ev.kind == 1, ev.kind == 2
    # Σ p s² = 0.2·1 + 0.3·4 + 0.5·9 = 5.9, times C = diag(0.5, 2)
    np.testing.assert_allclose(spec.r_event[g][0], np.diag([2.95, 11.8]), rtol=1e-12)
    # ε = 0.2·0.01 + 0.3·0.05 + 0.5·0.2 = 0.117;  κ = 10^0.2 · 20^0.3 · 80^0.5 = 38.57...
    assert spec.eps_event[g][0] == pytest.approx(0.117, rel=1e-12)
    assert spec.kappa_event[g][0] == pytest.approx(10 ** 0.2 * 20 ** 0.3 * 80 ** 0.5, rel=1e-12)
    # acoustic: C · (0.2·1 + 0.3·2 + 0.5·3 = 2.3);  κ = 4^0.2 · 16^0.3 · 64^0.5 = 2^(0.4 + 1.2 + 3) = 2^4.6
    np.testing.assert_allclose(spec.r_event[a][0], np.diag([1.15, 0.575]), rtol=1e-12)
    assert spec.kappa_event[a][0] == pytest.approx(2 ** 4.6, rel=1e-12)


def test_context_white_scale_by_hand():
    """Errors ±(0.3, 0) alternating under C = 0.01·I: every first difference is (0.6, 0), so
    Δe'(2C)⁻¹Δe/2 = 0.36/0.02/2 = 9 for each pair, and the robust Exp-scale estimate is median/ln 2 = 9/ln 2."""
    n = 50
    e = np.column_stack([0.3 * (-1.0) ** np.arange(n), np.zeros(n)])
    series = ErrorSeries(np.arange(n) * 0.2, e, np.tile(0.01 * np.eye(2), (n, 1, 1)), np.full(n, 5),
                         np.zeros(n, int))
    cn = ContextNoise(n_classes=1, bias=False, mixture=False).fit([series], [])
    assert cn.gnss_[(0, 5)]["s2"] == pytest.approx(9.0 / np.log(2.0), rel=1e-12)


def test_quality_noise_r_and_fit_by_hand():
    q = QualityNoise(uere_m={1: 3.0, 4: 0.02}).fit()
    r = q.gnss_r(np.array([1, 4]), np.array([2.0, 1.0]), np.full((2, 2), np.nan), np.tile(np.eye(2), (2, 1, 1)))
    np.testing.assert_allclose(r, [18.0 * np.eye(2), 0.0002 * np.eye(2)], rtol=1e-12)     # (3·2)²/2, (0.02·1)²/2
    # 10 fixes 6 m off at HDOP 3 → UERE² = 36/9 = 4
    fitted = QualityNoise().fit(quality=np.ones(10, int), hdop=np.full(10, 3.0), gnss_errors_m=np.tile([6.0, 0.0], (10, 1)))
    assert fitted.uere_m_[1] == pytest.approx(2.0, rel=1e-12)


def test_per_class_r_is_the_second_moment_of_each_class():
    cls = np.array([0] * 10 + [2] * 10)
    err = np.vstack([np.tile([[1.0, 0.0], [-1.0, 0.0]], (5, 1)), np.tile([[0.0, 3.0], [0.0, -3.0]], (5, 1))])
    pc = PerClassNoise(3, min_samples=10).fit(gnss_class=cls, gnss_errors_m=err)
    np.testing.assert_allclose(pc.R_gnss_[0], [[1.0, 0.0], [0.0, 1e-6]])       # E[ee'], the 1 mm floor
    np.testing.assert_allclose(pc.R_gnss_[2], [[1e-6, 0.0], [0.0, 9.0]])
    # a class without samples takes the pooled second moment: diag(0.5, 4.5)
    np.testing.assert_allclose(pc.R_gnss_[1], [[0.5, 0.0], [0.0, 4.5]])
