"""Issue 12 item 20: a simulated survey states its size before writing, warns above 0.25 GB and refuses
above --max-size-gb (default 2) or the free disk space."""

from __future__ import annotations

import pytest

from pipeline.cli import main
from pipeline.commands.simulate import survey_size_bytes


def _du(path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def test_estimate_within_10_percent_of_what_a_survey_writes(site_dir, survey_dir):
    """The session survey (10 m cells, 10-s captures); on a 4-s, 30 m survey estimate/actual was 0.984."""
    n, est = survey_size_bytes(site_dir, 10.0, 10.0)
    assert n == len(list((survey_dir / "cells").iterdir()))
    assert 0.9 < est / _du(survey_dir) < 1.1


def test_help_example_size_is_refused_under_a_lower_limit(site_dir, tmp_path, capsys):
    rc = main(["simulate", "survey", str(site_dir), "--out", str(tmp_path / "sv"), "--cell-size-m", "5",
               "--capture-s", "30", "--max-size-gb", "1"])
    err = capsys.readouterr().err
    assert rc == 1 and "--max-size-gb 1" in err and "GB" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "sv").exists() and not list(tmp_path.glob(".sv*"))
    n, est = survey_size_bytes(site_dir, 5.0, 30.0)
    assert 1.0e9 < est < 1.4e9                 # the --help example: about 1.1-1.3 GB (the site's layout decides)


def test_warning_before_a_large_survey(site_dir, tmp_path, capsys, monkeypatch):
    import pipeline.commands.simulate as sim

    calls = []
    monkeypatch.setattr("simulation.survey.simulate_survey", lambda *a, **k: calls.append(1) or tmp_path)
    (tmp_path / "cells").mkdir()
    monkeypatch.setattr(sim, "SIZE_WARN_GB", 0.0001)
    assert main(["simulate", "survey", str(site_dir), "--out", str(tmp_path / "sv"), "--cell-size-m", "30",
                 "--capture-s", "4"]) == 0
    assert "warning: the survey will write about" in capsys.readouterr().err and calls == [1]


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_bad_limit_is_a_usage_error(site_dir, tmp_path, value, capsys):
    assert main(["simulate", "survey", str(site_dir), "--out", str(tmp_path / "sv"), "--max-size-gb", value]) == 2
