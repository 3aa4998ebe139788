"""The satellite-weighted sky of the environment label (issue 13 item 0), against the uniform one."""

import numpy as np
import pytest

from simulation.site.environment import SatelliteSky, blocked_share, satellite_sky
from simulation.site.geometry import sky_blocked_fraction

LAT, LON = 31.2, 118.8                 # the generated sites' origin


@pytest.fixture(scope="module")
def sky():
    return satellite_sky(LAT, LON, 10.0, 360)


def test_limits(sky):
    assert sky.n_samples > 10_000          # ~60 satellites × 720 epochs, ~40 % above the mask
    assert sky.blocked(np.zeros((1, 360)))[0] == 0.0
    assert sky.blocked(np.full((1, 360), np.pi / 2))[0] == pytest.approx(1.0)


def test_blocked_counts_samples_strictly_below_the_skyline_by_hand():
    """Three bins holding elevations {0.2, 0.4, 0.6}, {} and {0.3}: a skyline (0.4, 1.0, 0.31) hides 0.2 (0.4
    itself is not below it) and 0.3, 2 of 4 samples; (0.61, 0, 0) hides 3; an empty bin counts nothing."""
    sky = SatelliteSky((np.array([0.2, 0.4, 0.6]), np.zeros(0), np.array([0.3])), 4)
    np.testing.assert_array_equal(sky.blocked(np.array([[0.4, 1.0, 0.31], [0.61, 0.0, 0.0], [0.0, 1.5, 0.3]])),
                                  [0.5, 0.75, 0.0])
    with pytest.raises(ValueError, match="azimuth bins"):
        sky.blocked(np.zeros((1, 2)))


def test_no_gps_north_hole_but_beidou_south(sky):
    """At 31° N the 55° orbits leave the sky towards the celestial pole nearly empty (the 'north hole'), and the
    GEO and IGSO BeiDou satellites sit to the south: the southern 60° of azimuth hold far more samples than the
    northern 60° (measured 3,218 vs 1,166), east and west alike (1,958 vs 1,955)."""
    counts = np.array([len(e) for e in sky.el_sorted])
    north = counts[np.r_[0:30, 330:360]].sum()
    south = counts[150:210].sum()
    east, west = counts[60:120].sum(), counts[240:300].sum()
    assert south > 2.0 * north
    assert abs(east - west) < 0.05 * (east + west)


def _wall(side: str):
    # a long 10 m wall 3 m north or south of the receiver
    return np.array([[-500.0, 500.0, 3.0, 4.0, 10.0]]) if side == "north" else \
        np.array([[-500.0, 500.0, -4.0, -3.0, 10.0]])


def test_a_wall_to_the_south_hides_more_satellites_than_one_to_the_north(sky):
    p = np.zeros((1, 2))
    uni_n = sky_blocked_fraction(p, _wall("north"), 1.2)[0]
    uni_s = sky_blocked_fraction(p, _wall("south"), 1.2)[0]
    sat_n = sky_blocked_fraction(p, _wall("north"), 1.2, sky=sky)[0]
    sat_s = sky_blocked_fraction(p, _wall("south"), 1.2, sky=sky)[0]
    assert uni_n == pytest.approx(uni_s, rel=1e-6)           # the uniform sky cannot tell: 0.375 both
    assert sat_s > uni_s > sat_n and sat_s > 1.2 * sat_n      # the satellites can
    # change detectors (measured): 0.345 north, 0.448 south
    assert sat_n == pytest.approx(0.345, abs=0.02) and sat_s == pytest.approx(0.448, abs=0.02)


def test_blocked_share_on_a_site(site_dir):
    from features.site import load_site

    site = load_site(site_dir)
    e, n = np.array([10.0, 60.0, 100.0]), np.array([10.0, 40.0, 70.0])
    uni = blocked_share(site, e, n)
    sat = blocked_share(site, e, n, sky="satellites")
    assert uni.shape == sat.shape == (3,) and np.all((sat >= 0) & (sat <= 1))
    assert isinstance(satellite_sky(round(site.origin.lat_deg, 4), round(site.origin.lon_deg, 4), 10.0, 360),
                      SatelliteSky)
    with pytest.raises(ValueError, match="sky must be one of"):
        blocked_share(site, e, n, sky="stars")
