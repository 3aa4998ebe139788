"""IMU realism (issue 10 item 6): warm-up bias drift, 50 Hz busbar fields aliased at 100 Hz, stated declination
error, PDR start from the first good GNSS fix."""

import math

import numpy as np
import pytest

from features.gnss.positions import GnssPositions
from features.site import Box, Origin, Site
from walks.reader import pdr_start_from_gnss
from simulation.imu.stream import stated_declination_error_deg
from simulation.imu.walker import SensorErrors, mains_field_ned_ut, warmup_kelvin


def test_warmup_is_first_order_and_bounded():
    e = SensorErrors()
    t = np.arange(0.0, 1800.0, 0.01)
    d = warmup_kelvin(t, e, np.random.default_rng(0))
    assert d[0] == 0.0 and e.warmup_min_k <= d[-1] <= e.warmup_max_k
    i_tau = int(e.warmup_tau_s / 0.01)
    assert d[i_tau] / (d[-1] / (1 - math.exp(-1800.0 / e.warmup_tau_s))) == pytest.approx(1 - math.exp(-1), rel=1e-3)


def test_busbar_field_follows_biot_savart_and_aliases_at_100_hz():
    gantry = Box("gantry", "steel lattice", True, -50.0, 50.0, -1.0, 1.0, 11.0)  # along east, top 11 m up
    site = Site("bus", Origin(30.0, 114.0, 0.0), layout=(gantry,))
    e = SensorErrors(busbar_current_a=500.0, mag_mains_gain=1.0, mains_sigma_hz=0.0)
    t = np.arange(0.0, 2.0, 0.01)  # 100 Hz
    pos = np.tile([0.0, 0.0, -1.0], (len(t), 1))  # NED, 1 m up, right below the bar (10 m)
    b = mains_field_ned_ut(site, pos, t, e, np.random.default_rng(1))
    amp = np.abs(b).max(axis=0)
    # B = μ0 I / (2π r) = 2e-7 · 500 / 10 m = 10 µT (times |sin| of the sampled phase), across the bar: north.
    phase_free = mains_field_ned_ut(site, pos[:1], np.array([0.0025]), e, np.random.default_rng(1))  # off-grid instant
    assert np.linalg.norm(phase_free) <= 10.0 + 1e-9
    mag = np.linalg.norm(b, axis=1)
    assert 0.5 < mag.max() <= 10.0 + 1e-9 and amp[1] == pytest.approx(0.0, abs=1e-9) and amp[2] < 1e-9
    # Exactly 50 Hz at 100 Hz: consecutive samples alternate in sign with a constant magnitude.
    assert np.allclose(b[1:, 0], -b[:-1, 0]) and np.allclose(mag, mag[0])
    far = mains_field_ned_ut(site, np.tile([40.0, 0.0, -1.0], (len(t), 1)), t, e, np.random.default_rng(1))
    assert np.abs(far).max() < 0.3 * np.abs(b).max()


def test_stated_declination_is_off_by_half_to_one_degree():
    errs = np.array([stated_declination_error_deg(s) for s in range(200)])
    assert np.all((np.abs(errs) >= 0.5) & (np.abs(errs) <= 1.0))
    assert 0.3 < np.mean(errs > 0) < 0.7
    assert stated_declination_error_deg(7) == stated_declination_error_deg(7)


def _positions(t, q, e, hdop):
    n = len(t)
    z = np.zeros(n)
    return GnssPositions(t_s=np.asarray(t, float), east_m=np.asarray(e, float), north_m=z, up_m=z, sigma_en_m=z + 1,
                         sigma_up_m=z + 1, quality=np.asarray(q), n_used=z + 10, hdop=np.asarray(hdop, float),
                         hdop_assumed=np.zeros(n, bool))


def test_pdr_start_is_the_first_good_fix_not_the_first_fix():
    p = _positions([0.0, 0.2, 0.4, 0.6], [2, 5, 4, 4], [10.0, 11.0, 12.0, 13.0], [3.0, 1.5, 0.8, 0.8])
    assert pdr_start_from_gnss(p) == (0.4, 12.0, 0.0)            # RTK fixed first
    p = _positions([0.0, 0.2, 0.4], [2, 5, 5], [10.0, 11.0, 12.0], [3.0, 1.5, 0.8])
    assert pdr_start_from_gnss(p) == (0.2, 11.0, 0.0)            # float with HDOP <= 2
    p = _positions([0.0, 0.2], [1, 1], [10.0, 11.0], [5.0, 5.0])
    assert pdr_start_from_gnss(p) == (0.0, 10.0, 0.0)            # any fix
    assert pdr_start_from_gnss(_positions([0.0], [0], [np.nan], [np.nan])) is None


def test_device_height_differs_per_walker_and_stays_per_walker():
    from simulation.site.layout import generate_site
    from simulation.walk import device_height_m
    site = generate_site(3)
    h = np.array([device_height_m(site, p) for p in range(300)])
    assert np.all(np.abs(h - site.device_height_m) <= 0.175 + 1e-12)
    assert 0.05 < h.std() < 0.09 and device_height_m(site, 5) == device_height_m(site, 5)
