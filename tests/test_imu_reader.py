"""IMU CSV reader and repair: defects counted, never an exception; one clear error for missing columns."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from features.errors import ImuError
from features.imu.reader import RepairConfig, read_imu_csv, repair_imu
from features.imu.pdr import run_pdr
from pipeline.cli import main

DATA = Path(__file__).resolve().parent / "data"


def test_good_file_reads_clean_at_100_hz():
    d = read_imu_csv(DATA / "imu_good.csv")
    assert d.report.n_defects == 0
    assert len(d) == 1567 and d.rate_hz == pytest.approx(100.0, rel=1e-6)
    assert d.gyro_rad_s.shape == (1567, 3) and d.mag_ut.shape == (1567, 3)
    assert d.valid.all() and not d.saturated.any()
    # standing at the start: specific force ≈ −g along body down (FRD), |f| ≈ 9.81
    assert np.linalg.norm(d.acc_m_s2[:100], axis=1).mean() == pytest.approx(9.81, abs=0.1)


def test_bad_file_is_repaired_with_every_defect_counted():
    """imu_bad.csv: the good file with a 1 s gap, 5 duplicated rows, two swaps, NaN, a text token, clipping."""
    d = read_imu_csv(DATA / "imu_bad.csv")
    r = d.report
    assert (r.n_rows, r.n_duplicate_t, r.n_unsorted) == (1472, 5, 4)
    assert (r.n_nan_acc, r.n_nan_gyro, r.n_saturated_acc) == (2, 1, 5)
    assert r.n_gaps == 1 and r.gap_total_s == pytest.approx(1.01, abs=1e-6)
    assert np.all(np.diff(d.t_s) > 0) and np.isfinite(d.acc_m_s2).all() and np.isfinite(d.gyro_rad_s).all()
    assert (~d.valid).sum() == 105            # the gap's interior and the 50-ms clipped run: interpolated
    assert d.saturated.sum() == 5 and not (d.saturated & d.valid).any()
    good = read_imu_csv(DATA / "imu_good.csv")
    np.testing.assert_allclose(d.acc_m_s2[:300], good.acc_m_s2[:300])   # untouched before the defects
    # steps are still found outside the gap (20 in the clean file)
    n_bad, n_good = len(run_pdr(d)), len(run_pdr(good))
    assert n_good == 20 and 16 <= n_bad <= n_good


def test_missing_columns_one_error_naming_them():
    with pytest.raises(ImuError, match=r"missing required column\(s\) t_s, az"):
        read_imu_csv(DATA / "imu_missing_columns.csv")


def test_partial_triple_and_empty_file_are_errors(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("t_s,ax,ay,az,gx\n0,0,0,-9.8,0\n0.01,0,0,-9.8,0\n")
    with pytest.raises(ImuError, match="gx, gy, gz must all be present"):
        read_imu_csv(p)
    p.write_text("")
    with pytest.raises(ImuError, match="empty file"):
        read_imu_csv(p)
    with pytest.raises(ImuError, match="not found"):
        read_imu_csv(tmp_path / "nope.csv")


def test_accelerometer_only_gives_steps_and_lengths_without_heading():
    d = read_imu_csv(DATA / "imu_acc_only.csv")
    assert d.gyro_rad_s is None and d.mag_ut is None
    r = run_pdr(d)
    full = run_pdr(read_imu_csv(DATA / "imu_good.csv"))
    assert len(r) == len(full) == 20
    np.testing.assert_allclose(r.step_length_m, full.step_length_m, rtol=1e-4)
    assert np.isnan(r.heading_rad).all() and np.isnan(r.east_m).all() and r.heading is None


def test_repair_in_memory_nan_everywhere_in_one_column_and_unsorted():
    t = np.array([0.03, 0.0, 0.01, 0.02, 0.02])
    acc = np.tile([0.0, 0.0, -9.8], (5, 1))
    acc[2, 0] = np.nan
    d = repair_imu(t, acc, config=RepairConfig(rate_hz=100.0))
    assert (d.report.n_unsorted, d.report.n_duplicate_t, d.report.n_nan_acc, len(d)) == (1, 1, 1, 4)
    assert np.isfinite(d.acc_m_s2).all()
    with pytest.raises(ImuError, match="fewer than 2"):
        repair_imu([np.nan, 1.0], [[0, 0, 0], [0, 0, 0]])


def test_cli_writes_steps_and_reports_repairs(tmp_path, capsys):
    out = tmp_path / "steps.csv"
    rc = main(["features", "imu", str(DATA / "imu_bad.csv"), "--start-east", "10", "--start-north", "-5",
               "--k", "0.45", "--out", str(out)])
    assert rc == 0
    err = capsys.readouterr().err
    assert "n_gaps=1" in err and "n_duplicate_t=5" in err
    rows = out.read_text().splitlines()
    # time_utc and lat/lon/h_ell_m are empty: no walk.toml beside the file names a start or a site
    assert rows[0] == "t_s,time_utc,step_length_m,heading_rad,east_m,north_m,lat_deg,lon_deg,h_ell_m"
    cols = [0, 2, 3, 4, 5]
    vals = np.array([[float(r.split(",")[c]) for c in cols] for r in rows[1:]])
    assert len(vals) >= 16 and np.all(np.diff(vals[:, 0]) > 0)
    # the walk starts north from (10, -5): the first step lies within a step length of the start
    assert np.hypot(vals[0, 3] - 10.0, vals[0, 4] + 5.0) == pytest.approx(vals[0, 1], abs=0.05)


def test_cli_acc_only_leaves_heading_empty_and_missing_columns_fail_cleanly(tmp_path, capsys):
    out = tmp_path / "steps.csv"
    assert main(["features", "imu", str(DATA / "imu_acc_only.csv"), "--out", str(out)]) == 0
    rows = out.read_text().splitlines()[1:]
    assert len(rows) == 20 and all(r.endswith(",,,") for r in rows)
    capsys.readouterr()
    out2 = tmp_path / "none.csv"
    assert main(["features", "imu", str(DATA / "imu_missing_columns.csv"), "--out", str(out2)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing required column(s) t_s, az" in err[0]
    assert not out2.exists()


def test_cli_calibrates_k_from_a_known_distance_and_rejects_a_bad_k(tmp_path, capsys):
    out = tmp_path / "steps.csv"
    assert main(["features", "imu", str(DATA / "imu_good.csv"), "--calibrate-distance-m", "13.4",
                 "--out", str(out)]) == 0
    lengths = np.array([float(r.split(",")[2]) for r in out.read_text().splitlines()[1:]])  # step_length_m
    assert lengths.sum() == pytest.approx(13.4, abs=0.01)
    assert "K = " in capsys.readouterr().out
    # a bad --k is a usage error (2) naming the option, not the internal StepLengthModel.k (issue 12 item 12)
    assert main(["features", "imu", str(DATA / "imu_good.csv"), "--k", "5", "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "--k" in err and "expected a value in [0.05, 3]" in err and "StepLengthModel" not in err


def _with_every_50th_az(tmp_path, value: str):
    rows = (DATA / "imu_good.csv").read_text().splitlines()
    out = [rows[0]]
    for i, line in enumerate(rows[1:]):
        parts = line.split(",")
        if i % 50 == 25:
            parts[3] = value
        out.append(",".join(parts))
    p = tmp_path / f"imu_{value}.csv"
    p.write_text("\n".join(out) + "\n")
    return p


@pytest.mark.parametrize("value", ["-156.9064", "1e308", "-1e308"])
def test_clipped_and_absurd_samples_are_interpolated_before_filtering(tmp_path, capsys, value):
    """Every 50th az at −16 g full scale (or ±1e308): same steps and distance as the clean file, no warning."""
    good = run_pdr(read_imu_csv(DATA / "imu_good.csv"))
    d = read_imu_csv(_with_every_50th_az(tmp_path, value))
    assert d.report.n_saturated_acc == 31 and d.saturated.sum() == 31
    assert d.valid.all() and np.abs(d.acc_m_s2).max() < 30.0      # lone clipped samples: bridged, still valid
    r = run_pdr(d)
    assert len(r) == len(good) == 20
    assert r.distance_m == pytest.approx(good.distance_m, rel=0.02)
    capsys.readouterr()
    out = tmp_path / "steps.csv"
    with warnings.catch_warnings(record=True) as caught:        # pytest would otherwise swallow them
        warnings.simplefilter("always")
        with np.errstate(all="warn"):
            assert main(["features", "imu", str(_with_every_50th_az(tmp_path, value)), "--out", str(out)]) == 0
    assert [str(w.message) for w in caught] == []
    err = capsys.readouterr().err
    assert "Warning" not in err and len(err.strip().splitlines()) == 1 and "n_saturated_acc=31" in err


def _edited(tmp_path, name, edit):
    """imu_good.csv with ``edit(rows)`` applied to its data rows (list of lists of str)."""
    lines = (DATA / "imu_good.csv").read_text().splitlines()
    rows = [ln.split(",") for ln in lines[1:]]
    header = edit(rows) or lines[0]
    p = tmp_path / name
    p.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return p


def _cli(path, tmp_path, capsys):
    capsys.readouterr()
    out = tmp_path / "steps.csv"
    rc = main(["features", "imu", str(path), "--out", str(out)])
    cap = capsys.readouterr()
    return rc, cap.err.strip().splitlines(), out


@pytest.mark.parametrize("row,value", [(700, "1e9"), (700, "1e308"), (1566, "1e308"), (0, "-1e9")])
def test_isolated_corrupt_timestamp_is_dropped_not_allocated(tmp_path, row, value):
    def edit(rows):
        rows[row][0] = value
    d = read_imu_csv(_edited(tmp_path, "jump.csv", edit))
    assert d.report.n_bad_time == 1 and len(d) <= 1567 and d.t_s[-1] < 16.0
    assert len(run_pdr(d)) == 20


def test_a_real_huge_gap_is_rejected_with_one_line(tmp_path, capsys):
    def edit(rows):
        for r in rows[800:]:
            r[0] = f"{float(r[0]) + 1e9:.2f}"
    rc, err, out = _cli(_edited(tmp_path, "gap.csv", edit), tmp_path, capsys)
    assert rc == 1 and len(err) == 1 and "t_s jumps by 1e+09 s" in err[0] and "split" in err[0]
    assert not out.exists()
    # many bounded gaps that together would blow the grid up are rejected too, before any allocation
    t = (np.arange(2000) % 10) * 0.01 + (np.arange(2000) // 10) * 500.0
    with pytest.raises(ImuError, match=r"gaps fill 99482.1 s of a 99500.1 s record .* need 99500\d\d samples"):
        repair_imu(t, np.tile([0.0, 0.0, -9.8], (2000, 1)))
    # a long but bounded gap (5 min) is bridged and flagged, not rejected
    def edit2(rows):
        for r in rows[800:]:
            r[0] = f"{float(r[0]) + 300:.2f}"
    d = read_imu_csv(_edited(tmp_path, "gap2.csv", edit2))
    assert d.report.n_gaps == 1 and (~d.valid).sum() == 30000     # 300.01 s at 100 Hz


def test_a_break_of_up_to_an_hour_is_a_hole_and_a_longer_one_is_refused(tmp_path):
    """A logger paused for 40 minutes over a break: the record on both sides of it is read on one grid, the
    2,400.01 s between its rows 799 and 800 a hole of 240,000 samples not ``valid`` (100 Hz: the rows are
    0.01 s apart, so the hole holds (2,400.01 − 0.01) / 0.01 samples), and PDR finds the file's steps on both
    sides and none inside (before 2026-12-03 any gap past 600 s refused the whole record, so a walk lost its
    PDR for a lunch break). A gap past the hour (3,600.5 s: more than 360,000 samples at 100 Hz) is still
    refused, naming it; at 200 Hz the samples allow half an hour (1,800 s), at 1 kHz the 600 s that any rate
    is allowed."""
    def moved(by):
        def edit(rows):
            for r in rows[800:]:
                r[0] = f"{float(r[0]) + by:.2f}"
        return edit

    whole = run_pdr(read_imu_csv(DATA / "imu_good.csv"))
    split_at = float(read_imu_csv(DATA / "imu_good.csv").t_s[800])
    d = read_imu_csv(_edited(tmp_path, "break.csv", moved(2400.0)))
    assert d.report.n_gaps == 1 and d.report.gap_total_s == pytest.approx(2400.01, abs=1e-6)
    assert (~d.valid).sum() == 240000 and len(d) == 1567 + 240000
    hole = (d.t_s > d.t_s[799] + 1e-6) & (d.t_s < d.t_s[799] + 2400.01 - 1e-6)
    assert not d.valid[hole].any() and d.valid[~hole].all()
    steps = run_pdr(d)
    assert not np.any((steps.t_s > split_at) & (steps.t_s < split_at + 2400.0))
    # the file's steps away from the cut (a step spanning it is lost), each 2,400 s later after it
    far = np.abs(whole.t_s - split_at) > 1.0
    got = np.where(steps.t_s > split_at, steps.t_s - 2400.0, steps.t_s)
    assert all(np.min(np.abs(got - t)) < 0.02 for t in whole.t_s[far])
    with pytest.raises(ImuError, match=r"t_s jumps by 3600.51 s .* more than the 3600(\.\d+)? s filled at 100 Hz: "
                                       r"split the record there"):
        read_imu_csv(_edited(tmp_path, "too_long.csv", moved(3600.5)))
    for rate, ok_s, refused_s in ((200.0, 1700.0, 1900.0), (1000.0, 550.0, 650.0)):
        n = int(rate)                           # a second before the gap and a second after it
        t = np.r_[np.arange(n), np.arange(n) + n + ok_s * rate] / rate
        acc = np.random.default_rng(1).normal([0.0, 0.0, -9.8], 0.05, (2 * n, 3))   # a device at rest
        d = repair_imu(t, acc)
        assert d.report.n_gaps == 1 and (~d.valid).sum() == round(ok_s * rate)
        t[n:] += (refused_s - ok_s)
        with pytest.raises(ImuError, match=f"more than the {max(600.0, 360_000 / rate):g} s filled"):
            repair_imu(t, acc)


def test_millisecond_timestamps_are_rejected_clearly(tmp_path, capsys):
    def edit(rows):
        for r in rows:
            r[0] = f"{float(r[0]) * 1000:.0f}"
    rc, err, _ = _cli(_edited(tmp_path, "ms.csv", edit), tmp_path, capsys)
    assert rc == 1 and len(err) == 1
    assert "(0.1 Hz) is outside 10-2000 Hz" in err[0] and "milliseconds" in err[0]


def test_utf8_bom_is_read(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf" + (DATA / "imu_good.csv").read_bytes())
    d = read_imu_csv(p)
    assert len(d) == 1567 and d.report.n_defects == 0 and d.mag_ut is not None


def test_huge_binary_header_is_truncated_in_the_error(tmp_path, capsys):
    p = tmp_path / "junk.csv"
    p.write_bytes(b"\x00\x01\x1b[31m" + b"A,\x07\xff" * 2_000_000 + b"\n1,2,3\n")
    rc, err, _ = _cli(p, tmp_path, capsys)
    assert rc == 1 and len(err) == 1 and len(err[0]) < 400
    assert "missing required column(s) t_s, ax, ay, az" in err[0] and "\\x00" in err[0] and "\x1b" not in err[0]
