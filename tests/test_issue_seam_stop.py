"""A long walk in segments shorter than the warm-up, the walker standing through whole segments (the bad-input
tour's walk7: ``run --method pdr --segment-s 60`` 21.4 m off the whole walk after a 100 s stop, ``--segment-s
90`` 56 epochs without a position), and ``run``'s out-of-range ``--segment-s`` / ``--lag-s`` (exit 1, now usage
errors, exit 2).

What was wrong: a segment that owned no epoch of a method (no step of ``pdr`` while the walker stood) handed
the next one the state of its cut's last epoch before its end, an epoch of the warm-up, which that cut had
dead-reckoned from its own first fix (or, before its heading resumed, without a heading: NaN onwards) instead
of from the state it was handed; and a cut holding the walk's start other than the first (segments shorter
than the 120 s warm-up) read the heading gate's reference field from less than its 300 s span, so its heading
was not the whole walk's (0.05-0.15 m on walk7 from 60 s on). And where the walker stood for longer than a cut's
warm-up, the cut walked where the whole walk stood (the filters' process noise: 0.3-0.9 m after a 181 s stop),
and the UWB/PDR filter's PDR track spread the step after a stop over the whole stop (0.03-0.45 m at seams in a
stop; 23.6 m on seed 78 of walks/segments.py's table)."""

import math

import numpy as np
import pytest

from tests.test_seam_resume import PDR_SEAM_TOL_M, _distances

STOP_S = (172.0, 278.0)
"""Walk times the walker of :func:`stop_walk` stands through, s: they hold the 60 s segment [180, 240) and the
90 s segment [180, 270) whole."""


@pytest.fixture(scope="module")
def stop_walk(walk_dir, tmp_path_factory):
    """The 60 s session walk looped 5 times (300 s, its UWB log too), its IMU standing still over :data:`STOP_S`: every sample
    there the walk's mean specific force, angular rate and field (gravity, the gyro's bias, the Earth's field
    on a waist device at rest) plus white noise of a consumer MEMS unit at 100 Hz (0.02 m/s², 0.002 rad/s,
    0.3 µT; seed 5), so that no step is detected and the heading holds. GNSS and audio go on as recorded (the
    dead reckoning does not read them past its start)."""
    import csv

    from tests.long_walk import loop_walk

    d = loop_walk(walk_dir, tmp_path_factory.mktemp("seam_stop") / "x5", 5, extra=("uwb",))
    path = d / "imu.csv"
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    head, body = rows[0], np.array(rows[1:], float)
    t = body[:, 0]
    still = (t >= STOP_S[0]) & (t < STOP_S[1])
    sigma = np.repeat([0.02, 0.002, 0.3], 3)
    rng = np.random.default_rng(5)
    body[still, 1:] = body[:, 1:].mean(axis=0) + rng.normal(0.0, 1.0, (int(still.sum()), 9)) * sigma
    with open(path, "w", newline="") as fh:
        fh.write(",".join(head) + "\n")
        np.savetxt(fh, body, fmt="%.6f", delimiter=",")
    return d


@pytest.mark.parametrize("segment_s", [60.0, 90.0])
def test_pdr_in_segments_shorter_than_the_warm_up_with_a_stop_across_a_cut(model_and_walk, stop_walk, segment_s):
    """``pdr`` of the standing walk in 60 and 90 s segments (the 120 s warm-up: the first two or three cuts hold
    the walk's start) against the whole walk: every step at the same time and place within PDR_SEAM_TOL_M
    (measured 1e-6 m on walk7); a segment owns no step (the case under test). Before the fix (merge32) the
    segments after the stop were metres off (dead-reckoned from the wrong cut's first fix) or NaN."""
    from walks.fuse import fuse_walk, segmented_tracks

    model, _ = model_and_walk
    whole = fuse_walk(stop_walk, model, ("pdr",), force=True).tracks
    t = whole["pdr"].t_s
    own_none = [k for k in range(1, math.ceil(290 / segment_s) - 1)
                if not np.any((t >= k * segment_s) & (t < (k + 1) * segment_s))]
    assert own_none, "no segment without a step: the walk does not test the hand-over across a stop"
    assert np.any(t >= (own_none[-1] + 1) * segment_s), "no step after the stop"
    seg = segmented_tracks(stop_walk, model, ("pdr",), segment_s, force=True)
    assert np.isfinite(seg["pdr"][1]).all()
    d = _distances(whole, seg)
    print(f"{segment_s:g} s segments, owning no step: {own_none}; pdr max m: {d['pdr']:.2g}")
    assert d["pdr"] < PDR_SEAM_TOL_M


def test_run_writes_the_whole_walks_pdr_track_in_60_s_segments(model_and_walk, stop_walk, tmp_path):
    """``envfuse run --method pdr --segment-s 60`` (its library path, :func:`walks.fuse.fuse_to_file`) on the
    standing walk: the same rows as one segment, every one with a position, within PDR_SEAM_TOL_M."""
    import csv

    from walks.fuse import fuse_to_file

    model, _ = model_and_walk
    out = {}
    for s in (60.0, 1e6):
        done = fuse_to_file(stop_walk, model, "pdr", tmp_path / f"{s:g}.csv", "csv", force=True, segment_s=s)
        assert done.placed == done.n > 0 and not done.skipped
        with open(tmp_path / f"{s:g}.csv") as fh:
            out[s] = np.array([[float(r["t_s"]), float(r["east_m"]), float(r["north_m"])] for r in csv.DictReader(fh)])
    seg, whole = out[60.0], out[1e6]
    assert seg.shape == whole.shape
    np.testing.assert_allclose(seg[:, 0], whole[:, 0], rtol=0, atol=1e-6)
    assert np.hypot(*(seg[:, 1:] - whole[:, 1:]).T).max() < PDR_SEAM_TOL_M


def test_filters_in_segments_whose_cut_starts_in_a_stop(model_and_walk, stop_walk, monkeypatch):
    """With a 40 s warm-up, the cut of the 60 s segment [240, 300) starts at 200 s (192 s on the 32 s grid of
    before), inside the stop (172-278 s),
    so it holds no step before the stop's end: the EKF (``kf_quality``) must still stand there (the whole
    walk's standing noise q_stand, not the walking one), and the UWB/PDR filter's PDR track must not depend
    on the step before the stop (it spread the next step over the whole stop). Every filter track and its
    ``+lag`` within FILTER_SEAM_TOL_M of the whole walk (measured ≤ 5e-9 m; merge32: ``kf_quality`` 34 m,
    ``uwb_aoa_pdr`` 0.23 m, its ``+lag`` 0.45 m)."""
    from tests.test_seam_resume import FILTER_SEAM_TOL_M
    from walks import segments
    from walks.fuse import fuse_walk, segmented_tracks

    model, _ = model_and_walk
    monkeypatch.setattr(segments, "WARMUP_S", 40.0)
    methods = ("kf_quality", "uwb_aoa_pdr")
    whole = fuse_walk(stop_walk, model, methods, force=True, smooth=False).tracks
    seg = segmented_tracks(stop_walk, model, methods, 60.0, force=True, smooth=False)
    d = _distances(whole, seg)
    print("segmented vs whole, max m:", {k: f"{v:.2g}" for k, v in sorted(d.items())})
    assert set(d) == {"kf_quality", "kf_quality+lag", "uwb_aoa_pdr", "uwb_aoa_pdr+lag"}
    for name, dist in d.items():
        assert dist < FILTER_SEAM_TOL_M, (name, dist)


def test_stands_of_a_later_cut_and_the_uwb_pdr_track_through_a_stop():
    """By hand: steps at 10, 10.5 and 100 s of a cut read from 5 s to 120 s: standing 11-99.5 s and from
    100.5 s to the end; as a later cut of a long walk also 5-9.5 s (its start); a later cut without a step
    stands throughout. The UWB/PDR filter's PDR track through the stop: still at the 10.5 s position until
    the step after the stop starts (100 − 0.55 s), then linear over that step."""
    from models.uwb_pdr import STAND_GAP_S as UWB_GAP, STEP_S, pdr_track_at
    from walks.inputs import STAND_GAP_S, TYPICAL_STEP_S, _stands

    assert (UWB_GAP, STEP_S) == (STAND_GAP_S, TYPICAL_STEP_S)
    t = np.array([10.0, 10.5, 100.0])
    whole = _stands(t, 120.0)
    np.testing.assert_allclose(np.c_[whole.start_s, whole.end_s], [[11.0, 99.5], [100.5, 120.0]])
    later = _stands(t, 120.0, 5.0)
    np.testing.assert_allclose(np.c_[later.start_s, later.end_s], [[5.0, 9.5], [11.0, 99.5], [100.5, 120.0]])
    np.testing.assert_allclose(later.standing_time(np.array([120.0])), [4.5 + 88.5 + 19.5])
    empty = _stands(np.zeros(0), 120.0, 5.0)
    np.testing.assert_allclose(np.c_[empty.start_s, empty.end_s], [[5.0, 120.0]])
    e, _ = pdr_track_at([10.5, 50.0, 99.45, 99.725, 100.0], t, [0.7, 1.4, 2.1], [0.0, 0.0, 0.0], (0.0, 0.0))
    np.testing.assert_allclose(e, [1.4, 1.4, 1.4, 1.75, 2.1], atol=1e-12)


def test_cuts_holding_the_walks_start_read_it_as_the_whole_walk(stop_walk):
    """60 s segments of the 300 s walk with the 120 s warm-up of the methods that start afresh on each cut
    (walks.segments.FRESH_WARMUP_S): the cuts of segments 0-2 start at the walk's start (the warm-up reaches
    before it) and reach at least the heading gate's 300 s reference span, as the whole walk's read
    does; a segment whose next cut holds the walk's start keeps no reader state (states_from_s inf), the
    others keep them 10 s into the next cut."""
    import tomllib

    from features.imu.heading import GATE_REFERENCE_S
    from walks.segments import RESUME_AFTER_S, walk_cuts

    seen = []
    for seg in walk_cuts(stop_walk, 60.0, warmup_s=120.0):
        audio_start = float(tomllib.loads((seg.directory / "walk.toml").read_text())["audio"]["start_s"])
        imu_t = np.loadtxt(seg.directory / "imu.csv", delimiter=",", skiprows=1, usecols=0)
        seen.append((seg.index, audio_start, imu_t[0], imu_t[-1], seg.next_from_s, seg.states_from_s))
        if seg.index <= 2:      # the walk's last IMU sample is at 299.99 s
            assert audio_start == 0.0 and imu_t[0] == 0.0
            assert imu_t[-1] >= GATE_REFERENCE_S - 0.02
        else:
            assert audio_start > 0.0 and imu_t[0] > 0.0
    print(seen)
    assert [s[5] for s in seen[:2]] == [math.inf, math.inf]     # the next cut starts at the walk's start
    assert seen[2][5] == pytest.approx(seen[2][4] + RESUME_AFTER_S) and math.isfinite(seen[2][4])
    assert seen[-1][5] == math.inf


@pytest.mark.parametrize("option, value", [("--segment-s", "0"), ("--segment-s", "-5"), ("--segment-s", "nan"),
                                           ("--segment-s", "inf"), ("--segment-s", "1e9"), ("--segment-s", "59.9"),
                                           ("--lag-s", "-1"), ("--lag-s", "nan"), ("--lag-s", "1e9")])
def test_run_refuses_out_of_range_segment_and_lag_as_usage_errors(tmp_path, capsys, option, value):
    """Each is one line naming the option and the value, exit 2 (README: out-of-range options are usage
    errors), before anything is read."""
    from pipeline.cli import main

    rc = main(["run", str(tmp_path / "walk"), "--model", str(tmp_path / "model"), "--out", str(tmp_path / "t.csv"),
               option, value])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert option in err and repr(value) in err and "Traceback" not in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "t.csv").exists()
