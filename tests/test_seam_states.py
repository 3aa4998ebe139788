"""The states a long walk's segment hands the next (issue 25 item 3, walks/segments.py): a filter, the PDR heading
and the standing intervals resumed on a later piece of a record give what the run over the whole record gives."""

import math

import numpy as np
import pytest

from features.imu.heading import HeadingConfig, estimate_heading
from models.fusion import EventEKF, FilterError, FilterResume, GnssEvents, StepEvents, merge_events
from models.fusion.noise import FixedNoise
from walks.inputs import _stands


def _stream(seed: int, t0: float = 0.0):
    """Steps every 0.5 s heading east, GNSS fixes every 1 s with 1 m noise (a fixed seed), from ``t0`` on."""
    rng = np.random.default_rng(seed)
    ts = np.arange(0.5, 60.0, 0.5)
    tg = np.arange(0.0, 60.0, 1.0)
    east = 0.7 * np.floor(tg / 0.5) + rng.normal(0, 1, tg.size)
    north = rng.normal(0, 1, tg.size)
    s, g = ts >= t0, tg >= t0
    return merge_events(StepEvents(ts[s], np.full(s.sum(), 0.7), np.full(s.sum(), math.pi / 2)),
                        GnssEvents.from_sigma(tg[g], east[g], north[g], np.ones(g.sum())))


def test_a_filter_resumed_on_a_later_piece_of_the_stream_is_the_whole_run_from_there():
    """The whole stream filtered once against its piece from 20 s (warm-up from 20 s, resumed at 30 s with the
    whole run's posterior before 30 s): the same x and P at every event from 30 s, to rounding; before 30 s the
    piece is its own run (different)."""
    whole_ev = _stream(3)
    piece_ev = _stream(3, t0=20.0)
    ekf = EventEKF(noise=FixedNoise(1.0, 0.5))
    whole = ekf.run(whole_ev)
    state = whole.state_before(30.0)
    i = int(np.searchsorted(whole.t_s, 30.0)) - 1
    assert state.t_s == 30.0 and np.array_equal(state.x, whole.x[i]) and whole.t_s[i] < 30.0 <= whole.t_s[i + 1]
    piece = ekf.run(piece_ev, resume=state)
    w = whole.t_s >= 30.0
    p = piece.t_s >= 30.0
    assert np.array_equal(whole.t_s[w], piece.t_s[p])
    np.testing.assert_allclose(piece.x[p], whole.x[w], rtol=0, atol=1e-12)
    np.testing.assert_allclose(piece.P[p], whole.P[w], rtol=0, atol=1e-12)
    fresh = ekf.run(piece_ev)                              # not resumed: started from the piece's first fix
    assert np.max(np.abs(fresh.x[p][:, :2] - whole.x[w][:, :2])) > 1e-3
    # a resume past the piece's last event changes nothing; a state of another size is refused
    assert np.array_equal(ekf.run(piece_ev, resume=FilterResume(99.0, state.x, state.P)).x, fresh.x)
    with pytest.raises(FilterError, match="cannot resume"):
        ekf.run(piece_ev, resume=FilterResume(30.0, np.zeros(6), np.eye(6)))


def _imu(n: int, rate_hz: float, seed: int):
    """A level body turning slowly (yaw rate 0.2·sin(0.05 t) rad/s), gyro bias 0.01 rad/s with noise, the
    horizontal field of 20 µT north with 40 µT down, a steel disturbance (field +30 %) over samples 5,000-9,000."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    rate = 0.2 * np.sin(0.05 * t)
    psi = np.cumsum(rate) / rate_hz
    acc = np.tile([0.0, 0.0, -9.81], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    gyro = np.zeros((n, 3))
    gyro[:, 2] = rate + 0.01 + rng.normal(0, 0.002, n)
    # the field in the body frame (x forward, y right, z down): north component rotated by −ψ
    mag = np.column_stack([20 * np.cos(psi), -20 * np.sin(psi), np.full(n, 40.0)]) + rng.normal(0, 0.2, (n, 3))
    mag[5000:9000] *= 1.3
    return acc, gyro, mag


def test_the_heading_resumed_from_its_state_is_the_whole_records_heading():
    """Headings of a 200 s record at 100 Hz against its piece from sample 6,000 (inside the disturbed spell: the
    gate's offset comes from the state) resumed at sample 7,000 from the whole run's state after 6,999: equal to
    1e-7 rad after the resume (the low-pass transients of the piece's first 10 s are gone), NaN before it."""
    rate = 100.0
    acc, gyro, mag = _imu(20_000, rate, 4)
    cfg = HeadingConfig()
    whole = estimate_heading(acc, gyro, mag, rate, cfg)
    assert whole.mag_disturbed[5200:8800].all() and whole.mag_disturbed[12000:].mean() < 0.05
    state = whole.state_at(6999, 69.99)
    piece = estimate_heading(acc[6000:], gyro[6000:], mag[6000:], rate, cfg, state, 1000)
    assert np.isnan(piece.fused[:1000]).all()
    d = np.angle(np.exp(1j * (piece.fused[1000:] - whole.fused[7000:])))
    assert np.max(np.abs(d)) < 1e-7          # measured 4.4e-9: round-off of the two cumulative sums
    np.testing.assert_allclose(piece.gyro_bias_rad_s[1000:], whole.gyro_bias_rad_s[7000:], rtol=0, atol=1e-10)
    # the record's start statistics travel with the state: the gate's reference is the first 300 s median
    assert piece.intensity_ref == whole.intensity_ref == pytest.approx(math.hypot(20, 40), rel=0.01)
    # started afresh the piece is off by the gyro bias it has not learnt (hundredths of a radian)
    fresh = estimate_heading(acc[6000:], gyro[6000:], mag[6000:], rate, cfg)
    assert np.max(np.abs(np.angle(np.exp(1j * (fresh.fused[1000:] - whole.fused[7000:]))))) > 1e-3


def test_a_stop_at_the_end_of_the_record_is_standing():
    """Steps at 0, 0.5, 1 and 5 s in a record ending at 10 s: standing 1.5-4.5 s (between steps, as before) and
    5.5-10 s (after the last step, to the record's end); a record ending 1 s after its last step: no second."""
    st = _stands(np.array([0.0, 0.5, 1.0, 5.0]), 10.0)
    np.testing.assert_allclose(st.start_s, [1.5, 5.5])
    np.testing.assert_allclose(st.end_s, [4.5, 10.0])
    st = _stands(np.array([0.0, 0.5, 1.0, 5.0]), 6.0)
    np.testing.assert_allclose(st.start_s, [1.5])


def test_the_heading_resumed_inside_a_long_disturbed_spell_keeps_the_whole_records_branch():
    """The record of the test above with its steel spell 60 s long (samples 5,000-11,000) and the field turning
    within it by 6 rad against the gyro (a walker alongside a transformer's tank): resumed at sample 9,000 from
    the whole run's state, the magnetometer and gyro headings stand more than π further apart than at the spell's
    start. The piece's headings are the whole run's to round-off, through the spell and after it, when the
    magnetometer takes over again. Before, the resumed gate offset and complementary heading were each put on
    the branch nearest the piece's first magnetometer heading: 2π off here, so that when the spell ended the
    filter pulled the heading the long way round (up to π off; a 48 s IMU hole across a long walk's seam did
    the same, walks/segments.py)."""
    rate = 100.0
    n = 20_000
    acc, gyro, mag = _imu(n, rate, 5)
    k = np.arange(n)
    spell = (k >= 5000) & (k < 11000)
    turn = np.where(spell, 6.0 * np.clip((k - 5000) / 4000.0, 0.0, 1.0), 0.0)   # rad, rotating the field
    c, s = np.cos(turn), np.sin(turn)
    mx, my = mag[:, 0].copy(), mag[:, 1].copy()
    mag[:, 0], mag[:, 1] = c * mx - s * my, s * mx + c * my
    mag[spell, :2] *= 1.3
    cfg = HeadingConfig()
    whole = estimate_heading(acc, gyro, mag, rate, cfg)
    assert whole.mag_disturbed[5200:10800].all() and whole.mag_disturbed[13000:].mean() < 0.05
    state = whole.state_at(8999, 89.99)
    drift = state.mag_minus_gyro_rad - state.gate_offset_rad
    assert abs(drift) > math.pi                               # the case the branch rule got wrong
    piece = estimate_heading(acc[8000:], gyro[8000:], mag[8000:], rate, cfg, state, 1000)
    d = np.angle(np.exp(1j * (piece.fused[1000:] - whole.fused[9000:])))
    assert np.max(np.abs(d)) < 1e-7, np.max(np.abs(d))
    dg = np.angle(np.exp(1j * (piece.gyro_only[1000:] - whole.gyro_only[9000:])))
    assert np.max(np.abs(dg)) < 1e-7
    # the gate's offset is the unwrapped magnetometer − gyro heading at the spell's last undisturbed sample
    good = np.flatnonzero(~whole.mag_disturbed[:9000])[-1]
    assert state.gate_offset_rad == pytest.approx(float(whole.mag_minus_gyro[good]), abs=1e-12)
    assert abs(np.angle(np.exp(1j * (state.gate_offset_rad - (whole.mag_only[good] - whole.gyro_only[good]))))) < 1e-9


def test_a_cut_stands_from_the_whole_walks_last_step_before_it():
    """``_stands`` of a cut handed the whole walk's last step before its segment (``last_step_s``), by hand:
    steps at 80, 80.5, 81 s in a cut from 40 s whose walk last stepped at 29.6 s: standing 30.1-79.5 s (as the
    whole walk stands between 29.6 and 80) and after 81 s to the record's end at 90 s; a handed step the cut
    holds itself adds nothing; a walk with no step before (−inf) stands nothing before the cut's first step,
    as the whole walk stands nothing before its first; a cut with no step stands from 0.5 s after the handed
    one to its end. Before, a cut stood from its first IMU sample (here 78 s), 1.7 s of standing instead of 49.4."""
    st = _stands(np.array([80.0, 80.5, 81.0]), 90.0, 40.0, last_step_s=29.6)
    np.testing.assert_allclose(st.start_s, [30.1, 81.5])
    np.testing.assert_allclose(st.end_s, [79.5, 90.0])
    assert st.standing_time(np.array([80.0]))[0] - st.standing_time(np.array([29.8]))[0] == pytest.approx(49.4)
    same = _stands(np.array([29.6, 80.0, 80.5, 81.0]), 90.0, 40.0, last_step_s=29.6 + 1e-6)
    np.testing.assert_allclose(same.start_s, [30.1, 81.5])
    none_before = _stands(np.array([80.0, 80.5, 81.0]), 90.0, 40.0, last_step_s=-math.inf)
    np.testing.assert_allclose(none_before.start_s, [81.5])
    still = _stands(np.zeros(0), 90.0, 40.0, last_step_s=29.6)
    np.testing.assert_allclose([still.start_s[0], still.end_s[0]], [30.1, 90.0])
    old = _stands(np.array([80.0, 80.5, 81.0]), 90.0, 78.0)
    np.testing.assert_allclose(old.start_s, [78.0, 81.5])


def test_the_stream_hand_over_carries_the_last_event_and_step_through_a_silent_segment():
    """``events_state_before``: the last event and the last step before the seam (58.0 s and 57.5 s of a cut with
    steps every 0.5 s to 57.5 s and a fix at 58 s); a segment whose cut has neither before its end hands on what
    it was handed (a silence longer than a segment); the walk's first segment without a step hands −inf (no
    step yet), not the handed value it never had."""
    from types import SimpleNamespace

    from walks.inputs import EventsResume, events_state_before

    def inputs(steps, fixes):
        ev = merge_events(StepEvents(steps, np.full(len(steps), 0.7), np.zeros(len(steps))) if len(steps) else None,
                          GnssEvents.from_sigma(fixes, np.zeros(len(fixes)), np.zeros(len(fixes)),
                                                np.ones(len(fixes))) if len(fixes) else None)
        pdr = SimpleNamespace(result=_Steps(steps))
        return SimpleNamespace(events=ev, data=SimpleNamespace(pdr=pdr))

    walked = inputs(np.arange(40.0, 58.0, 0.5), np.array([45.0, 58.0, 61.0]))
    assert events_state_before(walked, 60.0) == EventsResume(58.0, 57.5)
    silent = inputs(np.zeros(0), np.array([125.0]))
    assert events_state_before(silent, 120.0, EventsResume(58.0, 57.5)) == EventsResume(58.0, 57.5)
    assert events_state_before(silent, 120.0) == EventsResume(-math.inf, -math.inf)


class _Steps:
    """A PDR result's step columns (the part ``events_state_before`` reads)."""

    def __init__(self, t):
        self.t_s, self.heading_rad, self.step_length_m = t, np.zeros(len(t)), np.full(len(t), 0.7)

    def __len__(self):
        return len(self.t_s)


def test_a_hole_in_the_imu_log_is_not_standing():
    """By hand: a 100 Hz record from 0 to 10 s whose samples 2.00-5.99 s were filled by the reader (valid False)
    and 8.00-8.99 s (1 s, shorter than the 1.5 s stand gap): one hole, [2, 6). Stand intervals [1, 3), [4, 7)
    and [9, 9.5) less it: [1, 2), [6, 7), [9, 9.5). Before, a gap between steps across a hole in the log was a
    stop, and the filters held a walker who walked on unseen as still (on a 200 s walk with a 48 s IMU hole
    while walking, kf_quality's mean error in the hole 15.9 m, imm's 25.7 m; now 1.5 and 0.32 m)."""
    from types import SimpleNamespace

    from models.fusion import StandIntervals
    from walks.inputs import _imu_holes, _without

    t = np.round(np.arange(1000) / 100.0, 2)
    valid = ~(((t >= 2.0) & (t < 6.0)) | ((t >= 8.0) & (t < 9.0)))
    hs, he = _imu_holes(SimpleNamespace(t_s=t, valid=valid, rate_hz=100.0))
    np.testing.assert_allclose(np.c_[hs, he], [[2.0, 6.0]])
    st = _without(StandIntervals(np.array([1.0, 4.0, 9.0]), np.array([3.0, 7.0, 9.5])), hs, he)
    np.testing.assert_allclose(np.c_[st.start_s, st.end_s], [[1.0, 2.0], [6.0, 7.0], [9.0, 9.5]])
    # a hole at the record's end runs to one interval past its last sample; none: the stands as they were
    end = ~(t >= 7.0)
    np.testing.assert_allclose(np.c_[_imu_holes(SimpleNamespace(t_s=t, valid=end, rate_hz=100.0))], [[7.0, 10.0]])
    same = StandIntervals(np.array([1.0]), np.array([3.0]))
    assert _without(same, np.zeros(0), np.zeros(0)) is same
