"""A drive's walk files (issue 24 item 5): gnss_pseudoranges.csv, odometry.csv, walk.toml and truth.csv with
env_class 'unknown' — round trips, and one clear message for every malformed input, also through the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from features.errors import ConfigError, DataError
from features.gnss.pseudorange import OdometryTable, PseudorangeTable
from features.raw_tables import (ODOMETRY_COLUMNS, PSEUDORANGE_COLUMNS, odometry_csv_text, pseudorange_csv_text,
                                 read_odometry_csv, read_pseudorange_csv)
from features.walk import UNKNOWN_CLASS, load_walk, read_truth

_SAT = (15_000_000.123456789, 3_000_000.5, 21_000_000.25)


def _table() -> PseudorangeTable:
    t = np.array([0.0, 0.0, 0.2999999523, 0.2999999523])
    return PseudorangeTable(t_s=t, pseudorange_m=np.array([2.1e7 + 0.123456789, 2.2e7 + 1 / 3, 2.1e7, 2.2e7 + 7.77]),
                            pseudorange_var_m2=np.array([25.0, np.nan, 64.0, 1e-3]),
                            sat_ecef_m=np.array([_SAT] * 4), svid=np.array([12, 320, 12, 320]),
                            system=np.array(["G", "R", "G", "R"]), elevation_deg=np.array([85.1, np.nan, 84.9, -3.0]),
                            cn0_dbhz=np.array([49.0, 40.0, np.nan, 33.0]), corrections=frozenset({"ionosphere"}))


def _odometry() -> OdometryTable:
    t = np.array([0.0, 0.2999999523, 0.5])
    z = np.zeros(3)
    return OdometryTable(t_s=t, velocity_body_m_s=np.column_stack([[5.85, 6.0777777777778, 6.2], z, z]),
                         rate_body_rad_s=np.column_stack([z, z, [-0.0059341194567807, -0.0169, 0.0]]),
                         velocity_var_m2_s2=np.column_stack([[0.0025] * 3, z, z]),
                         rate_var_rad2_s2=np.column_stack([z, z, [4e-6] * 3]))


def test_tables_round_trip_bit_for_bit(tmp_path):
    tab = _table()
    p = tmp_path / "gnss_pseudoranges.csv"
    p.write_text(pseudorange_csv_text(tab))
    back = read_pseudorange_csv(p, tab.corrections)
    for name in ("t_s", "pseudorange_m", "pseudorange_var_m2", "sat_ecef_m", "elevation_deg", "cn0_dbhz"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tab, name))      # NaN where NaN, else exact
    assert back.system.tolist() == ["G", "R", "G", "R"] and back.svid.tolist() == [12, 320, 12, 320]
    assert back.corrections == {"ionosphere"}
    o = _odometry()
    q = tmp_path / "odometry.csv"
    q.write_text(odometry_csv_text(o))
    ob = read_odometry_csv(q)
    np.testing.assert_array_equal(ob.speed_m_s, o.speed_m_s)
    np.testing.assert_array_equal(ob.yaw_rate_rad_s, o.yaw_rate_rad_s)
    np.testing.assert_array_equal(ob.velocity_var_m2_s2[:, 0], [0.0025] * 3)
    np.testing.assert_array_equal(ob.rate_var_rad2_s2[:, 2], [4e-6] * 3)


_GOOD_ROW = "0.0,G,12,21000000.5,25.0,15000000.0,3000000.0,21000000.0,85.1,49.0"


_HEADER = ",".join(PSEUDORANGE_COLUMNS)


@pytest.mark.parametrize("lines, where", [
    (["t_s,system,svid,pseudorange_m", _GOOD_ROW], "line 1 must be the header"),
    ([_HEADER, _GOOD_ROW.replace(",49.0", "")], ":2: 9 fields, expected 10"),
    ([_HEADER, _GOOD_ROW, _GOOD_ROW.replace("21000000.5", "21e6m")], ":3: pseudorange_m is not a number: '21e6m'"),
    ([_HEADER, _GOOD_ROW.replace("21000000.5", "nan")], ":2: pseudorange_m is not finite"),
    ([_HEADER, _GOOD_ROW.replace(",25.0,", ",-1,")], ":2: pseudorange_var_m2 must be > 0"),
    ([_HEADER, _GOOD_ROW.replace("0.0,G", "1.0,G"), _GOOD_ROW], ":3: t_s runs backwards"),
    ([_HEADER, _GOOD_ROW.replace(",G,", ",X,")], ":2: system must be one of"),
    ([_HEADER, _GOOD_ROW.replace(",12,", ",1.5,")], ":2: svid must be an integer"),
    ([_HEADER, _GOOD_ROW, _GOOD_ROW], ":3: svid repeats a satellite"),
    ([_HEADER, _GOOD_ROW.replace("15000000.0,3000000.0,21000000.0", "15000.0,3000.0,21000.0")],
     ":2: sat_x_m and sat_y_m"),
    ([_HEADER, _GOOD_ROW.replace(",85.1,", ",95.0,")], ":2: elevation_deg must lie in [-90, 90]"),
    ([_HEADER, _GOOD_ROW.replace(",49.0", ",0")], ":2: cn0_dbhz must lie in (0, 100)"),
    ([_HEADER], "no data rows"),
    ([], "line 1 must be the header"),
])
def test_malformed_pseudorange_rows_name_file_line_and_column(tmp_path, lines, where):
    p = tmp_path / "gnss_pseudoranges.csv"
    p.write_text("\n".join(lines) + ("\n" if lines else ""))
    with pytest.raises(DataError) as exc:
        read_pseudorange_csv(p)
    assert str(p) in str(exc.value) and where in str(exc.value)


def test_unknown_correction_and_missing_file(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text(",".join(PSEUDORANGE_COLUMNS) + "\n" + _GOOD_ROW + "\n")
    with pytest.raises(DataError, match=r"unknown corrections \['sagnac'\]"):
        read_pseudorange_csv(p, {"sagnac"})
    with pytest.raises(DataError, match="file not found"):
        read_odometry_csv(tmp_path / "none.csv")


@pytest.mark.parametrize("rows, where", [
    (["0.0,5.0,0.0,0.0025,4e-06", "0.0,5.1,0.0,0.0025,4e-06"], ":3: t_s does not increase"),
    (["0.0,5.0,0.0,-0.0025,4e-06"], ":2: speed_var_m2_s2 must be >= 0"),
    (["0.0,5.0,0.0,0.0025,-4e-06"], ":2: yaw_rate_var_rad2_s2 must be >= 0"),
    (["0.0,5.0,,0.0025,4e-06"], ":2: yaw_rate_rad_s is not a number: ''"),
])
def test_malformed_odometry_rows(tmp_path, rows, where):
    p = tmp_path / "odometry.csv"
    p.write_text("\n".join([",".join(ODOMETRY_COLUMNS)] + rows) + "\n")
    with pytest.raises(DataError) as exc:
        read_odometry_csv(p)
    assert where in str(exc.value)


def test_walk_toml_holds_one_gnss_and_one_dead_reckoning_stream(tmp_path):
    (tmp_path / "walk.toml").write_text('[gnss]\nfile = "g.nmea"\n[gnss_pseudoranges]\nfile = "g.csv"\n'
                                        'start_utc = "2026-01-01T00:00:00Z"\n')
    with pytest.raises(ConfigError, match=r"both \[gnss\] and \[gnss_pseudoranges\]"):
        load_walk(tmp_path)
    (tmp_path / "walk.toml").write_text('[imu]\nfile = "i.csv"\n[odometry]\nfile = "o.csv"\n')
    with pytest.raises(ConfigError, match=r"both \[imu\] and \[odometry\]"):
        load_walk(tmp_path)
    (tmp_path / "walk.toml").write_text('[odometry]\nfile = 3\n')
    with pytest.raises(ConfigError, match=r"\[odometry\] must be a table with a 'file' key"):
        load_walk(tmp_path)


def test_truth_with_unknown_class_and_malformed_truth(tmp_path):
    p = tmp_path / "truth.csv"
    p.write_text("t_s,east_m,north_m,env_class\n0.0,1.0,2.0,unknown\n0.3,1.5,2.5,heavy\n")
    tr = read_truth(p)
    assert tr.env_class.tolist() == [UNKNOWN_CLASS, 2]
    p.write_text("t_s,east_m,north_m,env_class\n0.0,1.0,2.0,urban\n0.3,1.5,2.5,heavy\n")
    with pytest.raises(DataError, match=r"line 2: env_class 'urban' is not one of"):
        read_truth(p)
    p.write_text("t_s,east_m,north_m,env_class\n0.3,1.0,2.0,open\n0.3,1.0,2.0,open\n")
    with pytest.raises(DataError, match=r"line 3: t_s 0.3 does not increase"):
        read_truth(p)


def test_metric_rows_of_unknown_class_epochs_are_all_only():
    from walks.score import metric_rows

    rows = metric_rows(np.array([1.0, 3.0, 2.0]), np.full(3, np.nan), np.array([UNKNOWN_CLASS, UNKNOWN_CLASS, 0]),
                       "w", "m")
    assert [(r["env_class"], r["n"], r["mean_m"]) for r in rows] == [("all", 3, 2.0), ("open", 1, 2.0)]


def test_cli_on_a_malformed_drive_is_one_line(tmp_path, capsys):
    from pipeline.cli import main

    d = tmp_path / "drive"
    d.mkdir()
    (d / "site.toml").write_text('name = "s"\n[origin]\nlat_deg = 52.5\nlon_deg = 13.37\nalt_m = 100.0\n')
    (d / "walk.toml").write_text('name = "drive"\nsite = "site.toml"\n[gnss_pseudoranges]\n'
                                 'file = "gnss_pseudoranges.csv"\n')
    (d / "gnss_pseudoranges.csv").write_text(_HEADER + "\n" + _GOOD_ROW.replace(",G,", ",Q,") + "\n")
    code = main(["report", "walk", str(d), "--out", str(tmp_path / "w.png")])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("envfuse: error:") and "gnss_pseudoranges.csv:2: system must be one of" in err
    assert "no usable stream" in err
    assert not (tmp_path / "w.png").exists()
