"""Ray/segment vs box geometry against hand-worked cases and closed forms."""

import numpy as np
import pytest

from simulation.site.geometry import (footprint_entry, horizon_elevation, inside_boxes, ray_blockers,
                                 segment_hits_boxes, sky_blocked_fraction)

WALL = np.array([[0.0, 20.0, 0.0, 10.0, 8.0]])  # 20 x 10 m footprint, 8 m tall


def test_footprint_entry_hand_cases():
    p = np.array([[10.0, 12.0]])
    t_in, t_out = footprint_entry(p, np.array([np.pi, 0.0, np.pi / 2]), WALL)
    assert t_in[0, 0, 0] == pytest.approx(2.0) and t_out[0, 0, 0] == pytest.approx(12.0)  # south: enters at 2 m
    assert np.isinf(t_in[0, 1, 0]) and np.isinf(t_in[0, 2, 0])  # north and east miss


def test_horizon_elevation_closed_form():
    # 2 m north of the wall, receiver at 1 m: skyline due south at atan(7/2)
    el = horizon_elevation(np.array([[10.0, 12.0]]), np.array([np.pi]), WALL, 1.0)
    assert el[0, 0] == pytest.approx(np.arctan2(7.0, 2.0))


def test_infinite_wall_blocks_half_sky_times_closed_form():
    # Very long wall (1 km): along azimuth φ from a point d from the wall, horizontal distance d/|cos φ|.
    wall = np.array([[-500.0, 500.0, -10.0, 0.0, 11.0]])
    d, z0, mask = 2.0, 1.0, np.radians(10.0)
    got = sky_blocked_fraction(np.array([[0.0, d]]), wall, z0, mask_deg=10.0, n_az=3600)[0]
    phi = (np.arange(3600) + 0.5) * 2 * np.pi / 3600
    cosf = -np.cos(phi)
    hor = np.where(cosf > 0, np.arctan2(10.0, d / np.maximum(cosf, 1e-12)), 0.0)
    want = np.mean(np.clip(np.sin(hor) - np.sin(mask), 0, None)) / (1 - np.sin(mask))
    assert got == pytest.approx(want, rel=1e-3)
    assert 0.4 < got < 0.5  # 2 m from a 10 m-high long wall is heavy


def test_inside_box_is_fully_blocked_and_far_away_is_open():
    f = sky_blocked_fraction(np.array([[10.0, 5.0], [500.0, 500.0]]), WALL, 1.0)
    assert f[0] == pytest.approx(1.0) and f[1] == 0.0


def test_ray_blockers_clearance_sign():
    p = np.array([[10.0, 12.0]])
    az = np.array([[np.pi, np.pi]])
    el = np.array([[np.radians(30), np.radians(80)]])
    blocked, clearance, t_in = ray_blockers(p, az, el, WALL, 1.0)
    assert blocked[0, 0, 0] and not blocked[0, 1, 0]
    assert clearance[0, 0, 0] == pytest.approx(7.0 - 2.0 * np.tan(np.radians(30)))
    assert t_in[0, 1, 0] == pytest.approx(2.0)


def test_segment_hits_boxes():
    a = np.array([[10.0, -5.0, 1.0], [10.0, -5.0, 1.0], [-5.0, -5.0, 1.0]])
    b = np.array([[10.0, 15.0, 1.0], [10.0, 15.0, 20.0], [-5.0, 15.0, 1.0]])
    hit = segment_hits_boxes(a, b, WALL)[:, 0]
    # through the box; climbing over it (z at the south face 1+19*5/20=5.75 < 8, so it hits); passing beside it
    assert hit.tolist() == [True, True, False]
    over = segment_hits_boxes(np.array([[10.0, -5.0, 9.0]]), np.array([[10.0, 15.0, 9.0]]), WALL)
    assert not over[0, 0]


def test_inside_boxes_margin():
    p = np.array([[-0.5, 5.0], [-1.5, 5.0]])
    assert inside_boxes(p, WALL, margin_m=1.0).tolist() == [True, False]
