"""Issue 12 items 12-16: out-of-range options are usage errors (2) naming the option, messages name the
option or site.toml key the user wrote, nonsense site files are refused, a directory is not "missing", a
survey cell finds its survey's site, and NMEA without checksums can be opted into."""

from __future__ import annotations

from functools import reduce
from pathlib import Path

import pytest

from features.errors import ConfigError
from features.site import site_from_dict
from pipeline.cli import main
from tests.conftest import shared_data

DATA = Path(__file__).resolve().parent / "data"
ORIGIN = {"lat_deg": 30.0, "lon_deg": 120.0, "alt_m": 20.0}


def _err(capsys):
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    return err


@pytest.mark.parametrize("argv,needle", [
    (["features", "audio", "x.wav", "--site", "s", "--out", "f.csv", "--p-fa", "2"], "--p-fa: expected a value in (0, 1)"),
    (["features", "audio", "x.wav", "--site", "s", "--out", "f.csv", "--p-fa", "0"], "--p-fa"),
    (["features", "gnss", "x.nmea", "--out", "f.csv", "--elevation-mask-deg", "95"], "--elevation-mask-deg"),
    (["simulate", "survey", "s", "--out", "o", "--cell-size", "500"], "--cell-size"),
    (["simulate", "survey", "s", "--out", "o", "--cell-size-m", "0"], "--cell-size-m"),
    (["features", "imu", "x.csv", "--out", "f.csv", "--declination-deg", "400"], "--declination-deg"),
    (["features", "imu", "x.csv", "--out", "f.csv", "--k", "20876"], "--k"),
])
def test_out_of_range_options_are_usage_errors(argv, needle, capsys):
    assert main(argv) == 2
    assert needle in _err(capsys)


def test_calibration_distance_is_named_not_the_internal_model(tmp_path, capsys):
    assert main(["features", "imu", str(DATA / "imu_good.csv"), "--calibrate-distance-m", "1e6",
                 "--out", str(tmp_path / "s.csv")]) == 1
    err = _err(capsys)
    assert "--calibrate-distance-m" in err and "StepLengthModel" not in err
    assert not (tmp_path / "s.csv").exists()


def _site(**beacon_overrides):
    b1 = {"id": 1, "east_m": 0.0, "north_m": 0.0, "up_m": 3.0, "slot": 0}
    b2 = {"id": 2, "east_m": 200.0, "north_m": 0.0, "up_m": 3.0, "slot": 0}
    b2.update(beacon_overrides)
    return {"name": "t", "origin": ORIGIN, "beacons": [b1, b2]}


def test_site_messages_name_the_toml_keys():
    with pytest.raises(ConfigError) as exc:
        site_from_dict(_site(east_m="x"))
    msg = str(exc.value)
    assert "[[beacons]] #2 (id 2): east_m must be a finite number" in msg and "Beacon." not in msg
    with pytest.raises(ConfigError, match=r"\[\[beacons\]\] #2 \(id 2\): missing key\(s\) \['north_m'\]"):
        d = _site()
        del d["beacons"][1]["north_m"]
        site_from_dict(d)
    with pytest.raises(ConfigError, match=r"atmosphere.temperature_c must be a finite number"):
        site_from_dict({"name": "t", "origin": ORIGIN, "atmosphere": {"temperature_c": "warm"}})


def test_slot_mates_closer_than_the_protocol_allows_are_refused():
    site_from_dict(_site())                                    # 200 m apart: fine
    with pytest.raises(ConfigError, match=r"id 1 and id 2 share slot 0 and band but stand 30.0 m apart.*145 m"):
        site_from_dict(_site(east_m=30.0))
    site_from_dict(_site(east_m=30.0, f0_hz=23_500.0, f1_hz=24_000.0))   # disjoint bands may share a slot
    d = _site(east_m=30.0, slot=1)
    d["acoustic"] = {"n_slots": 2}
    site_from_dict(d)                                          # own slots: fine


def test_per_beacon_chirp_longer_than_its_slot_is_refused():
    with pytest.raises(ConfigError, match=r"id 2: chirp_duration_s 0.2 must lie in \(0, acoustic.slot_s = 0.1\)"):
        site_from_dict(_site(chirp_duration_s=0.2))
    site_from_dict(_site(chirp_duration_s=0.02))


def test_site_toml_error_through_the_cli(tmp_path, capsys):
    (tmp_path / "site.toml").write_text('name = "t"\n[origin]\nlat_deg = 30.0\nlon_deg = 120.0\n'
                                        '[[beacons]]\nid = 1\neast_m = 0.0\nnorth_m = 0.0\nup_m = 3.0\nslot = 0\n'
                                        '[[beacons]]\nid = 2\neast_m = 30.0\nnorth_m = 0.0\nup_m = 3.0\nslot = 0\n')
    wav = tmp_path / "a.wav"
    wav.write_bytes(b"")
    assert main(["features", "audio", str(wav), "--site", str(tmp_path), "--out", str(tmp_path / "f.csv")]) == 1
    assert "share slot 0" in _err(capsys)


def test_audio_path_that_is_a_directory(tmp_path, capsys):
    (tmp_path / "site.toml").write_text('name = "t"\n[origin]\nlat_deg = 30.0\nlon_deg = 120.0\n')
    d = tmp_path / "rec.wav"
    d.mkdir()
    assert main(["features", "audio", str(d), "--site", str(tmp_path), "--out", str(tmp_path / "f.csv")]) == 1
    err = _err(capsys)
    assert "is a directory" in err and "does not exist" not in err


def test_survey_cell_finds_the_survey_site(survey_dir, tmp_path, capsys):
    cell = sorted((survey_dir / "cells").iterdir())[0]
    out = tmp_path / "f.csv"
    rc = main(["features", "audio", str(cell / "audio.wav"), "--out", str(out), "--window-s", "2"])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert out.is_file()
    pos = tmp_path / "p.csv"
    assert main(["features", "gnss", str(cell / "gnss.nmea"), "--out", str(out), "--positions", str(pos)]) == 0
    assert pos.is_file()


def test_lone_cell_without_a_survey_names_what_it_looked_for(survey_dir, tmp_path, capsys):
    import shutil

    cell = sorted((survey_dir / "cells").iterdir())[0]
    lone = tmp_path / "c"
    shutil.copytree(cell, lone)
    assert main(["features", "gnss", str(lone / "gnss.nmea"), "--out", str(tmp_path / "f.csv"),
                 "--positions", str(tmp_path / "p.csv")]) == 1
    err = _err(capsys)
    assert "survey cell names no site" in err and "--site" in err and "walk" not in err.split("--site")[0]


def _s(body):
    return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"


def test_missing_checksums_opt_in(tmp_path, capsys):
    p = tmp_path / "nock.nmea"
    lines = [_s("GPRMC,120000.00,A,3000.0000,N,12000.0000,E,0.0,0.0,150624,,,A").split("*")[0],
             _s("GPGGA,120000.00,3000.0000,N,12000.0000,E,1,08,0.9,10.0,M,0.0,M,,").split("*")[0],
             _s("GPRMC,120001.00,A,3000.0000,N,12000.0000,E,0.0,0.0,150624,,,A")[:-3] + "*00"]   # a wrong one
    p.write_text("\n".join(lines) + "\n")
    assert main(["features", "gnss", str(p), "--out", str(tmp_path / "f.csv")]) == 1
    assert "--allow-missing-checksum" in _err(capsys)
    assert main(["features", "gnss", str(p), "--out", str(tmp_path / "f.csv"), "--allow-missing-checksum"]) == 0
    out = capsys.readouterr().out
    assert "1 epochs" in out and "bad checksum 1" in out


def test_real_no_checksum_file_with_the_opt_in(tmp_path, capsys):
    path = shared_data("nmea", "gnss_lib_py", "nmea_no_checksum.nmea")
    assert main(["features", "gnss", str(path), "--out", str(tmp_path / "f.csv")]) == 1
    capsys.readouterr()
    assert main(["features", "gnss", str(path), "--out", str(tmp_path / "f.csv"), "--allow-missing-checksum"]) == 0
    assert "2 epochs" in capsys.readouterr().out


def test_command_level_usage_errors_name_options_and_carry_the_prefix(tmp_path, capsys):
    wav = tmp_path / "a.wav"
    import numpy as np
    import soundfile as sf

    sf.write(wav, np.zeros(48_000, dtype=np.float32), 48_000)
    (tmp_path / "site.toml").write_text('name = "t"\n[origin]\nlat_deg = 30.0\nlon_deg = 120.0\n'
                                        '[[beacons]]\nid = 1\neast_m = 0.0\nnorth_m = 0.0\nup_m = 3.0\nslot = 0\n')
    assert main(["features", "audio", str(wav), "--site", str(tmp_path), "--out", str(tmp_path / "f.csv"),
                 "--window-s", "1", "--hop-s", "3"]) == 2
    err = _err(capsys)
    assert err.startswith("envfuse: error: --window-s") and "window_s" not in err
    nmea = tmp_path / "x.nmea"
    nmea.write_bytes((DATA / "good.nmea").read_bytes())
    assert main(["features", "gnss", str(nmea), "--out", str(nmea)]) == 2
    assert _err(capsys).startswith("envfuse: error: --out")
    assert main(["report", "walk", str(tmp_path), "--k", "100"]) == 2
    assert "--k" in _err(capsys)


def test_bad_walk_toml_declination_names_the_key(tmp_path, capsys):
    (tmp_path / "imu.csv").write_bytes((DATA / "imu_good.csv").read_bytes())
    (tmp_path / "walk.toml").write_text('start_utc = "2026-06-01T08:00:00Z"\n[imu]\nfile = "imu.csv"\n'
                                        'declination_deg = 400\n')
    assert main(["features", "imu", str(tmp_path / "imu.csv"), "--out", str(tmp_path / "s.csv")]) == 1
    assert "[imu] declination_deg" in _err(capsys)
