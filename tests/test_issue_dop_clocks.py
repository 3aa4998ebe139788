"""Issue 11 (smaller): λ's HDOP with one receiver clock per GNSS system, and no azimuth read as north.

HDOP of the used satellites against the receiver's own GGA HDOP (median ratio):

=========================  ==============  ===============
log                        one clock       clock per system
=========================  ==============  ===============
simulated, site 41 walk 2  0.981           1.000
simulated, site 52 walk 3  0.961           0.997
quectel-l76k (real)        0.929           0.977
ublox-neo-m9n (real)       0.978           1.079
ublox-zed-f9p (real)       1.055           1.113
unicore-um621 (real)       0.780           0.808
=========================  ==============  ===============

(The u-blox receivers' HDOP sits below the unweighted per-system figure; they weight their
satellites, which an azimuth/elevation HDOP cannot know. λ is a ratio of two such HDOPs.)
"""

from __future__ import annotations

import numpy as np
import pytest

from features.gnss.features import _hdop, epoch_dop_growth, sky_arrays
from features.gnss.nmea import read_nmea


def _reference_hdop(el_deg, az_deg, systems):
    el, az = np.radians(el_deg), np.radians(az_deg)
    names = sorted(set(systems))
    g = np.column_stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)]
                        + [np.array([s == n for s in systems], float) for n in names])
    q = np.linalg.inv(g.T @ g)
    return float(np.sqrt(q[0, 0] + q[1, 1]))


def test_hdop_with_a_clock_per_system_matches_the_closed_form():
    el = np.array([70.0, 40, 35, 20, 55, 30, 25])
    az = np.array([10.0, 100, 200, 300, 45, 160, 250])
    systems = ["GPS", "GPS", "GPS", "GPS", "BeiDou", "BeiDou", "BeiDou"]
    idx = np.array([sorted(set(systems)).index(s) for s in systems])
    ours = _hdop(np.radians(el)[None], np.radians(az)[None], np.ones((1, 7), bool), idx)[0]
    assert ours == pytest.approx(_reference_hdop(el, az, systems), rel=1e-12)
    one_clock = _hdop(np.radians(el)[None], np.radians(az)[None], np.ones((1, 7), bool))[0]
    assert one_clock == pytest.approx(_reference_hdop(el, az, ["x"] * 7), rel=1e-12)
    assert ours > one_clock                     # a second clock costs geometry
    # BeiDou absent from an epoch: its clock is decoupled, the GPS-only HDOP results.
    w = np.array([[True] * 4 + [False] * 3])
    gps_only = _hdop(np.radians(el)[None], np.radians(az)[None], w, idx)[0]
    assert gps_only == pytest.approx(_reference_hdop(el[:4], az[:4], systems[:4]), rel=1e-12)


def test_a_satellite_without_azimuth_is_not_north():
    el = np.array([[70.0, 40, 35, 20, 55, 50]])
    az = np.array([[10.0, 100, 200, 300, 45, np.nan]])
    view = np.ones((1, 6), bool)
    lam = epoch_dop_growth(el, az, view, view & ~np.isnan(az))
    assert lam[0] == pytest.approx(0.0, abs=1e-12)       # before: 0.015 (the az-less one taken at north)
    h = _hdop(np.radians(el), np.radians(az), view)[0]
    assert h == pytest.approx(_reference_hdop(el[0, :5], az[0, :5], ["x"] * 5), rel=1e-12)


def test_simulated_receiver_hdop_is_reproduced(walk_dir):
    sky = sky_arrays(read_nmea(walk_dir / "gnss.nmea")[0])
    systems = sorted({k[0] for k in sky.sat_keys})
    idx = np.array([systems.index(k[0]) for k in sky.sat_keys])
    h = _hdop(np.radians(sky.el_deg), np.radians(sky.az_deg), sky.used, idx)
    r = h / sky.hdop
    r = r[np.isfinite(r)]
    assert len(r) > 100
    assert np.median(r) == pytest.approx(1.0, abs=0.01)          # one clock: 0.96–0.98


def test_fluctuation_rate_weights_satellites_by_tracked_time():
    """Issue 11 (smaller): β weighted satellites equally however briefly they were tracked. Four
    satellites tracked 10 s with 8 extrema each, a fifth for 0.4 s with none: before 32/5/10 =
    0.64 per s (the brief one diluting as a whole satellite), now 32/(4·10 + 0.4) = 0.792."""
    from features.gnss.features import GnssFeatureConfig, SkyArrays, gnss_features

    t0 = np.arange(0.0, 10.0, 0.2)
    t = t0 + 0.2              # 5 Hz epochs measuring (0, 10]: all in the window [0, 10) by their tags t − 0.1
    el = np.tile(np.array([70.0, 40, 40, 40, 25]), (t.size, 1))
    az = np.tile(np.array([0.0, 90, 180, 270, 45]), (t.size, 1))
    wave = 40.0 + 3.0 * np.sign(np.sin(2 * np.pi * 0.5 * t0 + 0.1))
    cn0 = np.tile(wave[:, None], (1, 5))
    cn0[:, 4] = np.nan
    cn0[20:22, 4] = 40.0                                    # the fifth: two epochs, steady
    sky = SkyArrays(t, tuple(("GPS", i + 1) for i in range(5)), el, az, cn0, np.ones(el.shape, bool),
                    np.isfinite(cn0), np.ones(t.size))
    f = gnss_features(sky, GnssFeatureConfig(window_s=10.0, hop_s=10.0))
    assert f["fluct_per_s"][0] == pytest.approx(32 / (4 * 10 + 0.4))


def test_gnss_windows_lie_on_the_walks_grid():
    """Issue 11 (smaller): the GNSS window grid started at the first epoch (here 0.4 s), so its
    windows were 0.4 s off the audio windows (whole seconds from t = 0); now both lie on one grid."""
    from features.gnss.features import GnssFeatureConfig, SkyArrays, gnss_features

    t = np.arange(0.4, 6.0, 0.2)
    el = np.tile(np.array([70.0, 40, 40, 40, 25]), (t.size, 1))
    az = np.tile(np.array([0.0, 90, 180, 270, 45]), (t.size, 1))
    sky = SkyArrays(t, tuple(("GPS", i + 1) for i in range(5)), el, az, np.full(el.shape, 40.0),
                    np.ones(el.shape, bool), np.ones(el.shape, bool), np.ones(t.size))
    f = gnss_features(sky, GnssFeatureConfig(window_s=2.0, hop_s=1.0))
    assert f["t_s"].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]          # before: 1.4, 2.4, …, 5.4
    assert f["n_epochs"].tolist()[:2] == [9, 10]   # [0, 2) holds the epochs 0.4 … 2.0 (tags t − 0.1; before 0.4 … 1.8: 8)
