"""``envfuse features gnss``: outputs, skipped-line report, clean errors."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from pipeline.cli import main
from tests.conftest import SHARED_DATA

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="module")
def site_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("site")
    (d / "site.toml").write_text('name = "t"\n[origin]\nlat_deg = 30.0\nlon_deg = 120.0\nalt_m = 20.0\n')
    return d


def test_writes_features_epochs_and_positions(tmp_path, site_dir, capsys):
    out, ep, pos = tmp_path / "f.csv", tmp_path / "e.jsonl", tmp_path / "p.csv"
    rc = main(["features", "gnss", str(DATA / "bad_checksum.nmea"), "--site", str(site_dir), "--out", str(out),
               "--epochs", str(ep), "--positions", str(pos), "--window-s", "1", "--hop-s", "1"])
    assert rc == 0
    report = capsys.readouterr().out
    assert "skipped 2 (bad checksum 2)" in report and "2 epochs" in report
    rows = list(csv.DictReader(out.open()))
    # 1 Hz epochs at t = 0, 1 are tagged by the second each measured, (t − 1, t]: windows [−1, 0) and
    # [0, 1) (issue 11 window centring; before, by t: 0.5, 1.5)
    assert [r["t_s"] for r in rows] == ["-0.5", "0.5"]
    assert rows[1]["n_tracked"] == "5" and rows[1]["n_in_view"] == "6"  # PRN 24 at 5° is under the mask
    assert float(rows[1]["invisible_ratio"]) == pytest.approx(1 / 6, rel=1e-9)
    lines = [json.loads(x) for x in ep.read_text().splitlines()]
    assert len(lines) == 2 and lines[0]["time"] == "2024-06-15T12:00:00.000Z"   # fixed precision (issue 12 item 19)
    assert lines[1]["satellites"][0] == {"system": "GPS", "prn": 10, "signal": 1, "el_deg": 45.0, "az_deg": 90.0,
                                         "cn0_dbhz": 46.0, "used": True}
    prow = list(csv.DictReader(pos.open()))
    assert len(prow) == 2 and prow[0]["quality"] == "2"


def test_start_utc_shifts_the_time_base(tmp_path):
    out = tmp_path / "f.csv"
    assert main(["features", "gnss", str(DATA / "good.nmea"), "--out", str(out),
                 "--start-utc", "2024-06-15T11:59:50Z"]) == 0
    # first epoch at t = 10 s, tagged 9.5 (1 Hz, issue 11): first window [9, 11) (before: [10, 12))
    assert list(csv.DictReader(out.open()))[0]["t_s"] == "10"


def test_no_usable_epoch_is_one_clean_error(tmp_path, capsys):
    bad = tmp_path / "bad.nmea"
    bad.write_bytes(b"garbage\n$GPGGA,120000*00\n")
    out = tmp_path / "f.csv"
    rc = main(["features", "gnss", str(bad), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("envfuse: error:") and "no usable epoch" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def test_positions_need_a_site(tmp_path, capsys):
    rc = main(["features", "gnss", str(DATA / "good.nmea"), "--out", str(tmp_path / "f.csv"),
               "--positions", str(tmp_path / "p.csv")])
    assert rc == 1 and "--positions needs --site" in capsys.readouterr().err
    rc = main(["features", "gnss", str(DATA / "good.nmea"), "--out", str(tmp_path / "f.csv"), "--window-s", "-1"])
    assert rc == 2


def test_fit_reference_round_trip(tmp_path, capsys):
    gpsd = SHARED_DATA / "nmea" / "gpsd"
    log = gpsd / "quectel-l76k-nmea.log"
    if not log.exists():
        pytest.skip(f"{log} absent")
    ref = tmp_path / "ref.json"
    assert main(["features", "gnss", str(log), "--out", str(tmp_path / "a.csv"), "--fit-cn0-reference", str(ref)]) == 0
    model = json.loads(ref.read_text())
    assert "C_ref fitted" in capsys.readouterr().out and 15 < model["intercept_dbhz"] < 45
    # feeding the fitted model back: attenuation is measured against it, so it drops against the default's
    assert main(["features", "gnss", str(log), "--out", str(tmp_path / "b.csv"), "--cn0-reference", str(ref)]) == 0
    mean = [sum(float(r["att_mean_db"]) for r in csv.DictReader((tmp_path / n).open()) if r["att_mean_db"])
            for n in ("a.csv", "b.csv")]
    assert mean[1] < 0.5 * mean[0]
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert main(["features", "gnss", str(log), "--out", str(tmp_path / "c.csv"), "--cn0-reference", str(bad)]) == 1
