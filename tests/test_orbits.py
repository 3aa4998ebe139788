"""Constellation geometry: GMST, GEO closed form, periods, IGSO ground track, visible counts."""

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from features.constants import GEO_RADIUS_M, SIDEREAL_DAY_S, WGS84_A_M
from simulation.gnss.orbits import (
    BDS_GEO_LON_DEG, all_satellites, azel, beidou_constellation, ecef_positions, eci_positions, gmst_rad,
    gps_constellation, to_unix_s,
)

T0 = datetime(2026, 5, 1, tzinfo=timezone.utc).timestamp()


def test_gmst_matches_the_gps_reference_epoch():
    # GPS SPS Performance Standard: Greenwich hour angle at 1993-07-01 00:00 UT is 18h36m14.4s.
    t = datetime(1993, 7, 1, tzinfo=timezone.utc).timestamp()
    gha_deg = (18 + 36 / 60 + 14.4 / 3600) * 15.0
    assert abs(np.degrees(gmst_rad(t)[()]) - gha_deg) < 0.01
    # One sidereal day later the angle is the same; half a solar day later it has moved ≈ 180.5°.
    assert abs(np.degrees(gmst_rad(t + SIDEREAL_DAY_S)[()] - gmst_rad(t)[()])) < 1e-3
    step = np.degrees(np.mod(gmst_rad(t + 43_200.0)[()] - gmst_rad(t)[()], 2 * np.pi))
    assert abs(step - 180.49) < 0.01


def _geo_closed_form(lat_deg, lon_deg, sat_lon_deg):
    """Spherical-Earth GEO look angles: cosγ = cosφ·cosΔλ, el = atan((cosγ − Re/Rs)/sinγ), az by great circle."""
    phi = np.radians(lat_deg)
    dl = np.radians(sat_lon_deg - lon_deg)
    cg = np.cos(phi) * np.cos(dl)
    sg = np.sqrt(1.0 - cg ** 2)
    el = np.degrees(np.arctan((cg - WGS84_A_M / GEO_RADIUS_M) / sg))
    az = np.mod(np.degrees(np.arctan2(np.sin(dl), -np.sin(phi) * np.cos(dl))), 360.0)
    return az, el


@pytest.mark.parametrize("site", [(35.0, 115.0), (22.3, 114.2), (40.0, 116.4), (30.5, 104.0), (45.8, 126.6)])
def test_geo_look_angles_match_closed_form(site):
    sats = beidou_constellation()
    geo = sats.orbit == "GEO"
    times = T0 + np.array([0.0, 3_600.0, 40_000.0])
    az, el = azel(times, (site[0], site[1], 0.0), sats)
    az_ref, el_ref = _geo_closed_form(site[0], site[1], np.array(BDS_GEO_LON_DEG))
    d_az = np.abs((np.degrees(az[:, geo]) - az_ref + 180.0) % 360.0 - 180.0)
    d_el = np.abs(np.degrees(el[:, geo]) - el_ref)
    assert d_el.max() < 0.5 and d_az.max() < 0.5, (d_az.max(), d_el.max())
    # GEO satellites do not move in the sky.
    assert np.ptp(el[:, geo], axis=0).max() < 1e-6


def test_orbital_periods_and_radii():
    gps = gps_constellation()
    bds = beidou_constellation()
    assert len(gps) == 31 and len(set(gps.prn)) == 31 and set(gps.prn) <= set(range(1, 33))
    assert len(bds) == 30 and (bds.orbit == "MEO").sum() == 24
    # GPS: half a sidereal day (11 h 58 min); BeiDou MEO: 12 h 53 min; IGSO/GEO: one sidereal day.
    assert np.allclose(gps.period_s, SIDEREAL_DAY_S / 2.0, atol=5.0)
    meo = bds.orbit == "MEO"
    assert np.allclose(bds.period_s[meo] / 60.0, 12 * 60 + 53, atol=1.0)
    assert np.allclose(bds.period_s[~meo], SIDEREAL_DAY_S, atol=0.5)
    # Inertial positions repeat after one period and stay on the circle.
    sats = all_satellites()
    for j in (0, 20, 40, 55):
        r0 = eci_positions(sats.select([j]), T0)
        r1 = eci_positions(sats.select([j]), T0 + sats.period_s[j])
        assert np.linalg.norm(r1 - r0) < 1.0
        assert abs(np.linalg.norm(r0) - sats.a_m[j]) < 1e-3


def test_beidou_walker_pattern():
    bds = beidou_constellation()
    meo = bds.orbit == "MEO"
    raan = np.round(np.degrees(bds.raan_rad[meo])) % 360
    assert sorted(set(raan.tolist())) == [0.0, 120.0, 240.0]
    assert all((raan == r).sum() == 8 for r in (0.0, 120.0, 240.0))
    assert np.allclose(np.degrees(bds.inc_rad[meo]), 55.0)
    assert np.allclose(bds.a_m[meo] - 6_378_137.0, 21_528_000.0)


def test_igso_share_a_figure_eight_track_with_node_at_118e():
    bds = beidou_constellation()
    igso = bds.select(bds.orbit == "IGSO")
    t = T0 + np.arange(0.0, SIDEREAL_DAY_S, 30.0)
    r = ecef_positions(igso, t)
    lat = np.degrees(np.arcsin(r[..., 2] / np.linalg.norm(r, axis=-1)))
    lon = np.degrees(np.arctan2(r[..., 1], r[..., 0]))
    assert np.allclose(lat.max(axis=0), 55.0, atol=0.1)
    for j in range(3):
        up = np.flatnonzero((lat[:-1, j] < 0) & (lat[1:, j] >= 0))
        assert len(up) == 1
        assert abs(lon[up[0], j] - 118.0) < 0.5
        # The figure-8 is centred on the node longitude; a 55° IGSO swings ≈ ±15.7° in longitude.
        assert abs(0.5 * (lon[:, j].max() + lon[:, j].min()) - 118.0) < 0.5
        assert 28.0 < np.ptp(lon[:, j]) < 35.0


def test_times_as_datetimes_equal_floats():
    dts = [datetime(2026, 5, 1, tzinfo=timezone.utc) + timedelta(seconds=s) for s in (0, 10, 20)]
    a1, e1 = azel(dts, (35.0, 115.0, 0.0))
    a2, e2 = azel(to_unix_s(dts), (35.0, 115.0, 0.0))
    assert np.array_equal(a1, a2) and np.array_equal(e1, e2)
    assert a1.shape == (3, len(all_satellites()))


def test_visible_counts_at_mid_latitude_over_a_day():
    sats = all_satellites()
    t = T0 + np.arange(0.0, 86_400.0, 300.0)
    for site in [(35.0, 115.0, 50.0), (31.0, 118.0, 0.0)]:
        _, el = azel(t, site, sats)
        above = np.degrees(el) > 10.0
        n_gps = above[:, sats.system == "GPS"].sum(axis=1)
        n_bds = above[:, sats.system == "BDS"].sum(axis=1)
        assert 8 <= np.median(n_gps) <= 12, np.median(n_gps)
        assert 10 <= np.median(n_bds) <= 16, np.median(n_bds)
        assert n_gps.min() >= 4 and n_gps.max() <= 14
        assert n_bds.min() >= 7 and n_bds.max() <= 18
