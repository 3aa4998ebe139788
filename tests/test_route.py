"""Walking routes: stay in the aisles, walk at human speed, stop, and visit every class."""

from datetime import datetime, timezone

import numpy as np
import pytest

from features.site import load_site
from simulation.site.environment import environment_class
from simulation.site.geometry import boxes_array, inside_boxes
from simulation.rng import stream_rng
from simulation.site.route import RouteConfig, plan_route, route_trajectory

T0 = datetime(2026, 6, 1, tzinfo=timezone.utc)


@pytest.fixture(scope="module")
def traj(site_dir):
    site = load_site(site_dir)
    poly, stops, v = plan_route(site, stream_rng(21, "route"), 300.0)
    return site, route_trajectory(poly, stops, v, 300.0, T0, site.device_height_m), v


def test_route_stays_out_of_structures(traj):
    site, tr, _ = traj
    solid = boxes_array([b for b in site.layout if not b.porous])
    assert not inside_boxes(np.column_stack([tr.east_m, tr.north_m]), solid, margin_m=0.3).any()


def test_human_walking_speed_with_stops(traj):
    _, tr, v = traj
    assert 1.0 <= v <= 1.5
    assert tr.speed_m_s.max() <= v + 1e-6
    moving = tr.speed_m_s > 0.05
    assert 0.6 < moving.mean() < 0.98  # standing start and some stops
    assert np.median(tr.speed_m_s[moving]) > 0.85 * v
    acc = np.diff(tr.speed_m_s) * tr.rate_hz
    assert np.percentile(np.abs(acc), 99) <= 1.0


def test_heading_follows_motion(traj):
    _, tr, _ = traj
    de, dn = np.gradient(tr.east_m), np.gradient(tr.north_m)
    fast = tr.speed_m_s > 0.8
    motion = np.arctan2(de[fast], dn[fast])
    err = np.angle(np.exp(1j * (motion - tr.heading_rad[fast])))
    assert np.percentile(np.abs(err), 95) < np.radians(10)


def test_walk_visits_every_class(traj):
    site, tr, _ = traj
    cls = environment_class(site, tr.east_m[::50], tr.north_m[::50])
    for c in ("open", "light", "heavy"):
        assert cls.count(c) >= 0.05 * len(cls), (c, cls.count(c))


def test_route_deterministic(site_dir):
    site = load_site(site_dir)
    a = plan_route(site, stream_rng(5, "route"), 60.0)
    b = plan_route(site, stream_rng(5, "route"), 60.0)
    c = plan_route(site, stream_rng(6, "route"), 60.0)
    assert np.array_equal(a[0], b[0]) and not np.array_equal(a[0][:3], c[0][:3])


def test_route_config_validation():
    with pytest.raises(ValueError, match="speed_m_s"):
        RouteConfig(speed_m_s=(0.5, 3.0))
