"""The walk's fixes as filter events: the receiver's own GST σ reaches the quality-aware policy (issue 21 item 3)."""

from __future__ import annotations

import numpy as np

from features.gnss.positions import GnssPositions
from models.fusion import QualityNoise, merge_events
from walks.inputs import gnss_events


def _positions():
    n = 3
    return GnssPositions(t_s=np.arange(n, dtype=float), east_m=np.zeros(n), north_m=np.zeros(n), up_m=np.zeros(n),
                         sigma_en_m=np.array([0.02, 2.0, 0.5]), sigma_up_m=np.ones(n), quality=np.array([4, 1, 5]),
                         n_used=np.full(n, 9), hdop=np.array([0.8, 1.5, 1.0]),
                         hdop_assumed=np.array([False, False, True]),
                         sigma_east_m=np.array([0.015, 2.0, 0.4]), sigma_north_m=np.array([0.02, 2.0, 0.5]),
                         sigma_source=np.array(["gst", "cn0", "gst"]))


def test_gst_sigma_and_the_reported_covariance_reach_the_events():
    g = gnss_events(_positions())
    np.testing.assert_allclose(g.gst_sigma_m[0], [0.015, 0.02])
    assert np.all(np.isnan(g.gst_sigma_m[1])) and g.gst_sigma_m[2].tolist() == [0.4, 0.5]
    np.testing.assert_allclose(g.cov_m2[0], np.diag([0.015 ** 2, 0.02 ** 2]))
    np.testing.assert_allclose(g.cov_m2[1], np.eye(2) * 4.0)
    assert np.isnan(g.hdop[2]) and g.hdop[0] == 0.8


def test_kf_quality_takes_gst_times_its_scale_and_the_table_elsewhere():
    """R of the GST fixes: (k·σ_GST)² per axis; the C/N0 fix: UERE(1)·HDOP/√2 per axis (Kaplan & Hegarty)."""
    ev = merge_events(gnss=gnss_events(_positions()))
    q = QualityNoise(uere_m={1: 3.0, 4: 0.02, 5: 1.0}, gst_scale=2.0)
    q.fit()
    r = q.measurement_noise(ev).r_event
    np.testing.assert_allclose(np.diag(r[0]), (2.0 * np.array([0.015, 0.02])) ** 2)
    np.testing.assert_allclose(r[1], np.eye(2) * (3.0 * 1.5) ** 2 / 2)
    np.testing.assert_allclose(np.diag(r[2]), (2.0 * np.array([0.4, 0.5])) ** 2)
