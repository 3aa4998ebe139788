"""``envfuse simulate`` end to end: outputs, determinism, and bad input handled cleanly."""

import subprocess
import sys
import tomllib

import pytest

from pipeline.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_site_with_plot(tmp_path, capsys):
    code, out, err = run(capsys, "simulate", "site", "--seed", "4", "--out", str(tmp_path / "s"), "--plot")
    assert code == 0, err
    assert (tmp_path / "s" / "site.toml").is_file()
    png = (tmp_path / "s" / "site.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert "area open" in out


def test_walk_files_and_same_seed_same_bytes(site_dir, tmp_path, capsys):
    for name in ("a", "b"):
        code, _, err = run(capsys, "simulate", "walk", str(site_dir), "--seed", "9", "--duration", "20",
                           "--out", str(tmp_path / name))
        assert code == 0, err
    a, b = tmp_path / "a", tmp_path / "b"
    assert {"walk.toml", "gnss.nmea", "truth.csv"} <= {p.name for p in a.iterdir()}
    for p in a.iterdir():
        if p.name != "walk.toml":  # walk.toml names its own directory
            assert p.read_bytes() == (b / p.name).read_bytes(), p.name
    walk = tomllib.loads((a / "walk.toml").read_text())
    assert walk["seed"] == 9 and walk["duration_s"] == 20.0 and walk["gnss"]["rate_hz"] == 5.0
    truth = (a / "truth.csv").read_text().splitlines()
    assert truth[0] == "t_s,east_m,north_m,env_class" and len(truth) == 1 + 201
    code, _, err = run(capsys, "simulate", "walk", str(site_dir), "--seed", "10", "--duration", "20",
                       "--out", str(tmp_path / "c"))
    assert (tmp_path / "c" / "gnss.nmea").read_bytes() != (a / "gnss.nmea").read_bytes()


def test_survey_cells(site_dir, tmp_path, capsys):
    code, out, err = run(capsys, "simulate", "survey", str(site_dir), "--out", str(tmp_path / "sv"),
                         "--cell-size", "25", "--capture-s", "2")
    assert code == 0, err
    cells = sorted((tmp_path / "sv" / "cells").iterdir())
    assert len(cells) >= 8
    assert (tmp_path / "sv" / "site.toml").is_file()
    for c in cells:
        meta = tomllib.loads((c / "cell.toml").read_text())
        assert meta["id"] == c.name and meta["map_label"] in ("open", "light", "heavy")
        assert {"east_m", "north_m", "start_utc"} <= set(meta)
        assert (c / "gnss.nmea").stat().st_size > 0


@pytest.mark.parametrize("argv,needle", [
    (["simulate", "walk", "{missing}", "--seed", "1", "--out", "{out}"], "file not found"),
    (["simulate", "walk", "{bad}", "--seed", "1", "--out", "{out}"], "malformed TOML"),
    (["simulate", "site", "--seed", "-3", "--out", "{out}"], "non-negative integer"),
    (["simulate", "site", "--seed", "1", "--out", "{out}", "--colour"], "unrecognized arguments: --colour"),
    (["simulate", "walk", "{site}", "--seed", "1", "--duration", "0", "--out", "{out}"], "positive number"),
    (["simulate", "survey", "{site}", "--out", "{out}", "--cell-size", "0.1"], "--cell-size must lie in"),
    (["simulate", "teleport"], "invalid choice"),
])
def test_bad_input_one_line_nonzero_nothing_written(tmp_path, site_dir, capsys, argv, needle):
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "site.toml").write_text("name = 'x'\n[origin\n")
    subs = {"{missing}": str(tmp_path / "nowhere"), "{bad}": str(tmp_path / "bad"), "{out}": str(tmp_path / "out"),
            "{site}": str(site_dir)}
    argv = [subs.get(a, a) for a in argv]
    code, out, err = run(capsys, *argv)
    assert code != 0
    assert needle in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "s"
    assert run(capsys, "simulate", "site", "--seed", "1", "--out", str(out))[0] == 0
    before = (out / "site.toml").read_bytes()
    code, _, err = run(capsys, "simulate", "site", "--seed", "2", "--out", str(out))
    assert code == 1 and "not empty" in err and (out / "site.toml").read_bytes() == before
    assert run(capsys, "simulate", "site", "--seed", "2", "--out", str(out), "--force")[0] == 0
    assert (out / "site.toml").read_bytes() != before


def test_python_dash_m_pipeline_and_console_script_help():
    r = subprocess.run([sys.executable, "-m", "pipeline", "simulate", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "site" in r.stdout and "walk" in r.stdout and "survey" in r.stdout
