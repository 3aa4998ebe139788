"""What ``envfuse run`` tells of a walk: the share of epochs out of the environment model's distribution, and an
NMEA log that cannot be the walk's (placed a day away from it by a wrong ``start_utc`` or wrong dates)."""

import shutil
from datetime import timedelta

import numpy as np
import pytest

from features.errors import DataError
from features.walk import load_walk
from pipeline.commands.fuse import ood_text
from walks.reader import PLACE_MARGIN_S, _check_overlap, read_walk


def test_the_out_of_distribution_share_never_reads_zero_beside_a_guess():
    """By hand: 3 of 2,121 epochs are 0.14 % ("<1 %", before "0 %" with "their class is a guess"); 0 of 10 reads
    "0 %" with no guess; 11 of 2,121 are 0.52 %: "1 %"; 1 of 2 is 50 %."""
    assert ood_text(3, 2121) == "<1 % out of the environment model's training distribution (their class is a guess)"
    assert ood_text(0, 10) == "0 % out of the environment model's training distribution"
    assert ood_text(11, 2121).startswith("1 % out")
    assert ood_text(1, 2).startswith("50 % out")
    assert ood_text(0, 0).startswith("0 % out")


def test_a_log_a_day_away_from_start_utc_is_refused_with_what_is_wrong(walk_dir, tmp_path):
    """The session walk with its start_utc put one day later (a local date taken for UTC's): its NMEA epochs,
    placed by their own dates, all lie 86,400 s before the walk. The read notes why and goes on without GNSS
    (as for any unusable stream), instead of fusing the fixes a day before the other streams with nothing said.
    A log overlapping the walk by one epoch, or within a minute of it, is the walk's."""
    walk = tmp_path / "w"
    shutil.copytree(walk_dir, walk)
    toml = (walk / "walk.toml").read_text()
    start = load_walk(walk).start_utc
    later = start + timedelta(days=1)
    stamp = start.strftime("%Y-%m-%dT%H:%M:%S")
    assert stamp in toml
    (walk / "walk.toml").write_text(toml.replace(stamp, later.strftime("%Y-%m-%dT%H:%M:%S"), 1))
    data = read_walk(walk, truth=False)
    assert data.gnss is None
    note = next(n for n in data.notes if n.startswith("gnss:"))
    # by hand: the 60 s walk's 5 Hz epochs, 0-59.8 s less 86,400 s, have the median -86,370.1 s
    assert "lie -86,370 s (median)" in note and "1 whole day before it" in note
    info = load_walk(walk_dir)
    end = info.duration_s
    _check_overlap(info, np.array([-86400.0, end + PLACE_MARGIN_S]))          # one epoch inside: the walk's
    _check_overlap(info, np.array([-PLACE_MARGIN_S + 1.0]))
    with pytest.raises(DataError, match="none within the walk"):
        _check_overlap(info, np.array([end + PLACE_MARGIN_S + 1.0, end + 500.0]))


def test_a_time_rounded_to_zero_is_written_0_not_minus_0():
    """A track row at t_s = −0.0 (an epoch placed at −1e-9 s and rounded to the microsecond grid) reads "0" in the
    CSV, as 0.0 does; a true negative stays negative and NaN stays empty."""
    from walks.track import _fmt

    assert _fmt(-0.0) == _fmt(0.0) == "0"
    assert _fmt(-0.2) == "-0.2" and _fmt(float("nan")) == "" and _fmt(1234.5678901234) == "1234.56789"


def test_a_track_is_written_and_scored_at_the_last_state_of_each_instant():
    """By hand: a filter's events at 0.2 (a step's piece), 0.2 (the fix there), 0.4, 0.6 (piece) and 0.6 (fix)
    s, errors 1, 0.1, 0.5, 2 and 0.2 m against a truth at the origin. The instants are 0.2, 0.4 and 0.6 s, each
    scored by its last state: mean (0.1 + 0.5 + 0.2) / 3 = 0.2667 m. Before, all five rows counted: 0.76 m
    here; on a simulated walk, where the fix instants carry the smallest errors, the repeats flattered the
    filters instead (adaptive+lag 0.086 m with them, 0.108 m without)."""
    from types import SimpleNamespace

    from walks.score import track_errors
    from walks.track import Track, latest_per_time

    t = np.array([0.2, 0.2, 0.4, 0.6, 0.6])
    assert latest_per_time(t).tolist() == [False, True, True, False, True]
    assert latest_per_time(np.zeros(0)).size == 0
    east = np.array([1.0, 0.1, 0.5, 2.0, 0.2])
    tr = Track("kf", t, east, np.zeros(5), None)
    truth = SimpleNamespace(t_s=np.array([0.0, 1.0]), at=lambda x: (np.zeros(len(x)), np.zeros(len(x))),
                            class_at=lambda x: np.zeros(len(x), int))
    te = track_errors(tr, truth)
    assert te["t_s"].tolist() == [0.2, 0.4, 0.6]
    assert float(np.mean(te["err_m"])) == pytest.approx(0.8 / 3)
