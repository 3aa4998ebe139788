"""Issue 20: the noise policies' variances against numbers worked out by hand.

A UERE is the 1σ range error; the horizontal error of a fix is UERE·HDOP (its 2-D rms), so each axis gets
σ² = (UERE·HDOP)²/2 (Kaplan & Hegarty 2006, ch. 7). The fits invert that: UERE² = E[(e² + n²)/HDOP²] and,
for the acoustic covariance scale, k² = E[e'C⁻¹e]/2 (2 degrees of freedom). Every expected number below is
written out, not computed by the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from models.fusion import ClassQualityNoise, ClassTrack, GnssEvents, PerClassNoise, QualityNoise, merge_events
from models.fusion.events import AcousticEvents


def _class_quality(uere: dict, acoustic_scale=(1.0, 1.0, 1.0)) -> ClassQualityNoise:
    cq = ClassQualityNoise(n_classes=3)
    cq.uere_m_ = uere
    cq.acoustic_scale_ = np.array(acoustic_scale, float)
    cq.assumed_hdop_ = 1.5
    return cq


def test_per_class_gnss_variance_is_uere_times_hdop_squared_over_two():
    cq = _class_quality({0: {1: 2.0, 4: 0.02}, 1: {1: 4.0, 4: 0.05}, 2: {1: 8.0, 4: 0.5}})
    var = cq.gnss_var_m2(np.array([1, 4, 1]), np.array([1.5, 2.0, np.nan]))
    # (2·1.5)²/2 = 4.5, (4·1.5)²/2 = 18, (8·1.5)²/2 = 72; RTK fixed at HDOP 2: (0.02·2)²/2 = 0.0008, ...;
    # an unknown HDOP takes the assumed 1.5
    np.testing.assert_allclose(var, [[4.5, 18.0, 72.0], [0.0008, 0.005, 0.5], [4.5, 18.0, 72.0]], rtol=1e-12)


def test_per_class_gnss_r_is_the_expectation_under_the_class_probabilities():
    cq = _class_quality({0: {1: 2.0}, 1: {1: 4.0}, 2: {1: 8.0}}, acoustic_scale=(1.0, 2.0, 3.0))
    gnss = GnssEvents(np.array([1.0]), np.array([0.0]), np.array([0.0]), np.tile(np.eye(2), (1, 1, 1)),
                      quality=np.array([1]), hdop=np.array([1.5]))
    acoustic = AcousticEvents(np.array([2.0]), np.array([0.0]), np.array([0.0]), np.array([np.diag([0.5, 0.25])]))
    ev = merge_events(gnss=gnss, acoustic=acoustic)
    classes = ClassTrack(np.array([0.0]), np.array([[0.2, 0.3, 0.5]]))
    r = cq.measurement_noise(ev, classes).r_event
    g = ev.kind == 1
    # Σ p_c σ²_c = 0.2·4.5 + 0.3·18 + 0.5·72 = 42.3 per axis
    np.testing.assert_allclose(r[g][0], 42.3 * np.eye(2), rtol=1e-12)
    # acoustic: C · Σ p_c k_c² = diag(0.5, 0.25) · (0.2·1 + 0.3·4 + 0.5·9 = 5.9)
    np.testing.assert_allclose(r[ev.kind == 2][0], np.diag([2.95, 1.475]), rtol=1e-12)


def test_class_quality_fit_inverts_the_variance_by_hand():
    # class 0, quality 1: 20 fixes each 3 m east and 4 m north off at HDOP 2 → UERE² = 25/4, UERE = 2.5
    e = np.tile([3.0, 4.0], (20, 1))
    # acoustic, class 1: errors (1, 1) under C = 0.5·I → e'C⁻¹e = 4 → k² = 2
    cq = ClassQualityNoise(n_classes=3).fit(np.zeros(20, int), np.ones(20, int), np.full(20, 2.0), e,
                                            acoustic_class=np.ones(20, int),
                                            acoustic_cov_m2=np.tile(0.5 * np.eye(2), (20, 1, 1)),
                                            acoustic_errors_m=np.ones((20, 2)))
    assert cq.uere_m_[0][1] == pytest.approx(2.5, rel=1e-12)
    assert cq.acoustic_scale_[1] == pytest.approx(np.sqrt(2.0), rel=1e-12)
    # and back: at HDOP 2 the per-axis variance is (2.5·2)²/2 = 12.5 = half of the 25 m² error
    assert cq.gnss_var_m2(np.array([1]), np.array([2.0]))[0, 0] == pytest.approx(12.5, rel=1e-12)


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
