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
    # the share beside the class since issue 13 (the satellite-sky label): every error can be told by its
    # distance from a class boundary
    assert truth[0] == "t_s,east_m,north_m,env_class,blocked_sky_share" and len(truth) == 1 + 201
    for row in truth[1:]:
        cls, share = row.split(",")[3:]
        assert cls == ("open" if float(share) < 0.10 else "light" if float(share) <= 0.40 else "heavy")
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
    (["simulate", "walk", "{site}", "--seed", "1", "--duration", "0", "--out", "{out}"], "expected a value in [1, 21600] s"),
    (["simulate", "walk", "{site}", "--seed", "1", "--start", "9999-12-31T23:59:59Z", "--out", "{out}"], "outside 1980-2099"),
    (["demo", "--seed", "-1", "--out", "{out}"], "non-negative integer"),
    (["demo", "--workers", "0", "--out", "{out}"], "--workers must be at least 1"),
    (["simulate", "survey", "{site}", "--out", "{out}", "--cell-size", "0.1"],
     "--cell-size-m/--cell-size: expected a value in [0.5, 50] m"),  # usage error (2) under either name
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


def test_features_gnss_takes_time_base_and_site_from_walk_toml(tmp_path, capsys):
    """Without --start-utc/--site, `features gnss` uses the walk.toml beside the NMEA file."""
    import tomllib

    from pipeline.cli import main as cli
    site = tmp_path / "site"
    assert cli(["simulate", "site", "--seed", "2", "--out", str(site)]) == 0
    assert cli(["simulate", "walk", str(site), "--seed", "3", "--duration", "12", "--out", str(tmp_path / "w")]) == 0
    capsys.readouterr()
    code = cli(["features", "gnss", str(tmp_path / "w" / "gnss.nmea"), "--out", str(tmp_path / "f.csv"),
                "--positions", str(tmp_path / "p.csv")])
    assert code == 0, capsys.readouterr().err
    rows = (tmp_path / "p.csv").read_text().splitlines()
    assert rows[1].split(",")[0] == "0"  # first fix at the walk's start: t_s on the walk's time base
    truth = (tmp_path / "w" / "truth.csv").read_text().splitlines()[1].split(",")
    first = dict(zip(rows[0].split(","), rows[1].split(",")))
    assert abs(float(first["east_m"]) - float(truth[1])) < 1.0 and abs(float(first["north_m"]) - float(truth[2])) < 1.0
    walk_start = tomllib.loads((tmp_path / "w" / "walk.toml").read_text())["start_utc"]
    assert first["time_utc"][:19] == walk_start[:19]      # t_s = 0 is the walk's start_utc (issue 12 item 19)
    assert tomllib.loads((tmp_path / "w" / "walk.toml").read_text())["gnss"]["file"] == "gnss.nmea"
    # the audio command likewise finds walk.toml (time base, frames) and the site through it
    code = cli(["features", "audio", str(tmp_path / "w" / "audio.wav"), "--out", str(tmp_path / "a.csv")])
    assert code == 0, capsys.readouterr().err
    rows = (tmp_path / "a.csv").read_text().splitlines()
    assert rows[0].startswith("t_s,") and len(rows) >= 10
    assert float(rows[1].split(",")[0]) == 1.0  # first 2 s window centred 1 s after the walk's start


def test_features_gnss_writes_all_outputs_or_none(tmp_path, capsys):
    nmea = tmp_path / "nogsv.nmea"
    nmea.write_text("$GPGGA,120000.00,3112.00,N,11848.00,E,1,05,1.0,10.0,M,0.0,M,,*6F\r\n")
    code = main(["features", "gnss", str(nmea), "--out", str(tmp_path / "g.csv"), "--epochs", "/proc/e.jsonl"])
    err = capsys.readouterr().err
    assert code == 1 and "cannot write /proc/e.jsonl" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "g.csv").exists()
