"""Issue 20: the bad-input corpus (``tests/bad_inputs.py``) through every command, in this process.

Every case must be *clean*: the right exit status (1 bad data, 2 usage) with one line naming the problem,
or an accepted input whose result is right and whose quirks are noted; never an internal error, a silent
wrong answer or a file lost. ``bench/bad_inputs.py`` runs the same corpus as subprocesses against any
source tree and prints the counts (the before → after table of the issue).
"""

from __future__ import annotations

import pytest

from tests import bad_inputs as B

CASES = B.cases()


def test_the_corpus_is_large_and_covers_every_command():
    assert len(CASES) >= 250
    commands = {" ".join(c.name.split(",")[0].split()[:2]) for c in CASES}
    for cmd in ("run", "evaluate", "survey map", "survey build", "train env", "train fusion", "benchmark", "demo",
                "features gnss", "features audio", "features imu", "simulate walk", "simulate survey",
                "simulate site"):
        assert any(c.startswith(cmd) for c in commands), cmd
    assert {c.group for c in CASES} >= {"outputs", "truth.csv", "NMEA", "WAV", "IMU", "TOML", "bundles", "libraries",
                                        "options", "semantics"}


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_is_handled_cleanly(case, bad_input_world, tmp_path):
    W, argv, before = B.prepare(case, bad_input_world, tmp_path)
    outcome = B.judge(case, W, tmp_path, before, B.run_inprocess(argv, tmp_path))
    assert outcome.kind == "clean", f"{outcome.kind}: {outcome.why}\nargv: {argv}\nstderr: {outcome.err[-1500:]}"


def _fake_case(expect, check=None, may_change=()):
    return B.Case("fake", "test", lambda W, d: [], expect, ("named",), may_change, check)


@pytest.mark.parametrize("status, err, out, expect, kind", [
    (1, "envfuse: error: x.csv named the problem\n", "", 1, "clean"),
    (3, "envfuse: internal error: ValueError: boom\n", "", 1, "internal error"),
    (1, "Traceback (most recent call last):\nValueError\n", "", 1, "internal error"),
    (0, "", "done, named", 1, "silent wrong"),
    (1, "envfuse: error: named\n", "", 2, "unclear"),
    (2, "envfuse: error: something else\n", "", 2, "unclear"),
    (0, "/x/numpy/core.py:1: RuntimeWarning: Mean of empty slice\n", "named", 0, "unclear"),
])
def test_the_judge_tells_the_outcomes_apart(tmp_path, status, err, out, expect, kind):
    """The verdicts the corpus counts, on hand-made outcomes (a judge that always said 'clean' would pass the
    corpus)."""
    o = B.judge(_fake_case(expect), None, tmp_path, {}, B.Outcome(status, out, err, 0.0))
    assert o.kind == kind, o.why


def test_the_judge_sees_a_changed_or_lost_file(tmp_path):
    keep, gone, mine = tmp_path / "input.csv", tmp_path / "other.csv", tmp_path / "rep" / "metrics.csv"
    for p in (keep, gone, mine):
        B.put(p, "a\n")
    before = B._fingerprint(tmp_path)
    B.put(mine, "b\n")                       # the case's own output may change
    assert B.judge(_fake_case(0, may_change=("rep",)), None, tmp_path, before,
                   B.Outcome(0, "named", "", 0.0)).kind == "clean"
    gone.unlink()
    o = B.judge(_fake_case(0, may_change=("rep",)), None, tmp_path, before, B.Outcome(0, "named", "", 0.0))
    assert o.kind == "data lost" and "other.csv" in o.why
    B.put(gone, "a\n")                       # same content, but a new file: still reported
    assert B.judge(_fake_case(1), None, tmp_path, before, B.Outcome(1, "", "envfuse: error: named", 0.0)).kind \
        == "data lost"


def test_the_judge_runs_the_cases_own_check(tmp_path):
    case = _fake_case(0, check=lambda W, d, out, err: "stale plot left")
    o = B.judge(case, None, tmp_path, {}, B.Outcome(0, "named", "", 0.0))
    assert o.kind == "silent wrong" and o.why == "stale plot left"
