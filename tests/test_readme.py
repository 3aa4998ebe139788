"""The README's commands work as written: quick start wiring and the CLI tour."""

import re
import shlex
import subprocess
from pathlib import Path

from pipeline.cli import main

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()


def _block_after(heading: str) -> list[str]:
    part = README.split(heading, 1)[1]
    block = re.search(r"```\n(.*?)```", part, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_quick_start_is_exactly_make_demo_and_make_test():
    assert _block_after("## Quick start") == ["make demo", "make test"]


def test_makefile_targets_install_then_run():
    for target, needle in (("demo", "-m pipeline demo"), ("test", "-m pytest")):
        r = subprocess.run(["make", "-n", "-B", target], cwd=REPO, capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        lines = r.stdout.splitlines()
        torch = [i for i, line in enumerate(lines) if "torch==2.13.0" in line]
        pkg = [i for i, line in enumerate(lines) if "install" in line and "-e" in line]
        run = [i for i, line in enumerate(lines) if needle in line]
        assert torch and pkg and run and torch[0] < pkg[0] < run[0], r.stdout


def test_ci_runs_make_test():
    assert "make test" in (REPO / ".ci" / "run").read_text()


def test_tour_commands_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for line in _block_after("## A tour of the command line"):
        argv = shlex.split(line)
        assert argv[0] == "envfuse"
        code = main(argv[1:])
        err = capsys.readouterr().err
        assert code == 0, f"{line}\n{err}"
    tour = tmp_path / "tour"
    assert (tour / "site" / "site.png").is_file() and (tour / "walk.png").stat().st_size > 20_000
    for name, header in (("steps.csv", "t_s,time_utc,step_length_m,heading_rad,east_m,north_m,lat_deg,lon_deg,h_ell_m"),
                         ("gnss_features.csv",
                          "t_s,time_utc,att_mean_db,att_std_db,fluct_per_s,invisible_ratio,dop_growth"),
                         ("audio_features.csv", "t_s,time_utc,"),
                         ("gnss_positions.csv", "t_s,time_utc,east_m,north_m,up_m,lat_deg,lon_deg,h_ell_m")):
        lines = (tour / name).read_text().splitlines()
        assert lines[0].startswith(header) and len(lines) > 5, name
    assert len((tour / "survey" / "cells").iterdir().__next__().name) > 0


def test_fusion_commands_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for line in _block_after("## Environment model and fusion"):
        argv = shlex.split(line)
        assert argv[0] == "envfuse"
        code = main(argv[1:])
        err = capsys.readouterr().err
        assert code == 0, f"{line}\n{err}"
    fuse = tmp_path / "fuse"
    assert (fuse / "track.geojson").stat().st_size > 1000
    assert (fuse / "report" / "metrics.csv").read_text().startswith("walk,method,env_class,n,mean_m")
