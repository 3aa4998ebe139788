"""The body's track from a foot track by the mid-stance rule (models.foot.body), on hand-built gaits whose body
line is known: the foot is set down at the body's position at mid-stance plus half the step width to its side."""

import numpy as np
import pytest

from models.foot.body import BodyFromFoot, body_from_foot, mid_stance

RATE = 100.0


def _gait(body, t_end, stride_s=1.2, stance_s=0.6, half_w=0.04, side=1, stop=None):
    """A foot track (n, 2) and its stance flags (n,) for a body path ``body(t) -> (e, n, heading_rad)``: stance
    spells of ``stance_s`` every ``stride_s``, the foot at body(t_mid) + side·half_w·right during each, moved
    linearly in the swings; ``stop`` = (t0, t1): one stance spell over [t0, t1]."""
    t = np.arange(0.0, t_end, 1.0 / RATE)
    spells = []
    s = 0.1
    while s + stance_s < t_end:
        if stop is not None and s + stance_s > stop[0] and s < stop[1]:
            spells.append((stop[0], stop[1]))
            s = stop[1] + (stride_s - stance_s)
            continue
        spells.append((s, s + stance_s))
        s += stride_s
    stance = np.zeros(len(t), bool)
    knots_t, knots_p = [], []
    for a, b in spells:
        ia, ib = int(round(a * RATE)), int(round(b * RATE))
        stance[ia:ib] = True
        tm = t[(ia + ib - 1) // 2] if stop is None or (a, b) != stop else t[ia + 30]
        e, n, psi = body(tm)
        p = np.array([e, n]) + side * half_w * np.array([np.cos(psi), -np.sin(psi)])
        knots_t += [t[ia], t[ib - 1]]
        knots_p += [p, p]
    kp = np.array(knots_p)
    foot = np.column_stack([np.interp(t, knots_t, kp[:, 0]), np.interp(t, knots_t, kp[:, 1])])
    return t, foot, stance


def test_straight_walk_east_recovers_the_body_line():
    # body along east at 1.2 m/s, north = 0; the right foot 4 cm south of it (east heading: right = −north)
    t, foot, stance = _gait(lambda tt: (1.2 * tt, 0.0, np.pi / 2), 20.0)
    assert np.allclose(foot[stance][:, 1], -0.04)
    b = body_from_foot(t, foot, stance, RATE, BodyFromFoot(step_width_m=0.08))
    tm, _ = mid_stance(t, foot, stance, RATE)
    inside = (t >= tm[0]) & (t <= tm[-1])
    # between the first and last mid-stance the body line is exact: east 1.2 t, north 0
    assert np.max(np.abs(b[inside, 0] - 1.2 * t[inside])) < 1e-9
    assert np.max(np.abs(b[inside, 1])) < 1e-9
    # the foot track itself is 4 cm off across and up to ±0.36 m along (half a stance of walking)
    assert np.max(np.abs(foot[inside, 0] - 1.2 * t[inside])) > 0.3


def test_north_walk_left_foot_sign():
    # body north at 1 m/s; a LEFT foot sits west of it (heading 0: right = +east, left = −east)
    t, foot, stance = _gait(lambda tt: (5.0, 1.0 * tt, 0.0), 15.0, side=-1, half_w=0.06)
    assert np.allclose(foot[stance][:, 0], 5.0 - 0.06)
    b = body_from_foot(t, foot, stance, RATE, BodyFromFoot(step_width_m=0.12, side=-1))
    tm, _ = mid_stance(t, foot, stance, RATE)
    inside = (t >= tm[0]) & (t <= tm[-1])
    assert np.max(np.abs(b[inside, 0] - 5.0)) < 1e-9
    assert np.max(np.abs(b[inside, 1] - t[inside])) < 1e-9
    # the wrong side would put the body 12 cm off
    wrong = body_from_foot(t, foot, stance, RATE, BodyFromFoot(step_width_m=0.12, side=1))
    assert np.allclose(wrong[inside, 0], 5.0 - 0.12)


def test_a_stop_holds_the_body_still():
    # the body walks east at 1 m/s until it stops at t = 6.3 s (x = 6.3) and stands until 12.3 s, then goes on
    def body(tt):
        x = tt if tt < 6.3 else (6.3 if tt < 12.3 else 6.3 + (tt - 12.3))
        return x, 0.0, np.pi / 2

    t, foot, stance = _gait(body, 20.0, stop=(6.0, 12.6))
    b = body_from_foot(t, foot, stance, RATE, BodyFromFoot(step_width_m=0.08))
    standing = (t >= 6.3) & (t <= 12.28)   # the last anchor is half a stance (30 samples) before the toe-off sample
    # the body holds the stop's position for the whole stop, not a slow slide to the spell's middle
    assert np.max(np.hypot(b[standing, 0] - 6.3, b[standing, 1])) < 1e-9


def test_settings_are_validated():
    with pytest.raises(ValueError):
        BodyFromFoot(step_width_m=-0.1)
    with pytest.raises(ValueError):
        BodyFromFoot(side=0)
