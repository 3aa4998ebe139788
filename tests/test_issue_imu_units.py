"""Issue 12 item 1: IMU files in g and deg/s were read as m/s² and rad/s ("0 steps, 0.0 m", exit 0).

The unit is now detected from the median |a| (gravity) and the 99th percentile of |ω|, or stated with
--accel-unit / --gyro-unit; an accelerometer whose magnitude is gravity in no unit is refused.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from features.errors import ImuError
from features.imu.pdr import run_pdr
from features.imu.reader import read_imu_csv
from pipeline.cli import main
from tests.conftest import shared_data
from tests.test_imu_reader import DATA

G = 9.80665


def _rescaled(tmp_path, acc_factor, gyro_factor, name="imu.csv"):
    """imu_good.csv with the accelerometer divided by acc_factor and the gyro by gyro_factor."""
    rows = list(csv.reader((DATA / "imu_good.csv").open()))
    head = rows[0]
    idx = {n: i for i, n in enumerate(head)}
    out = [head]
    for r in rows[1:]:
        r = list(r)
        for c in ("ax", "ay", "az"):
            r[idx[c]] = repr(float(r[idx[c]]) / acc_factor)
        for c in ("gx", "gy", "gz"):
            r[idx[c]] = repr(float(r[idx[c]]) / gyro_factor)
        out.append(r)
    p = tmp_path / name
    p.write_text("\n".join(",".join(r) for r in out) + "\n")
    return p


def test_g_and_deg_s_are_detected_and_give_the_same_steps(tmp_path):
    good = read_imu_csv(DATA / "imu_good.csv")
    d = read_imu_csv(_rescaled(tmp_path, G, math.pi / 180))
    assert "accelerometer in g" in d.units and "gyro in deg/s" in d.units
    assert "accelerometer in m/s2" in good.units and "gyro in rad/s" in good.units
    np.testing.assert_allclose(d.acc_m_s2, good.acc_m_s2, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(d.gyro_rad_s, good.gyro_rad_s, rtol=1e-9, atol=1e-12)
    assert len(run_pdr(d)) == len(run_pdr(good)) == 20


def test_mg_is_detected(tmp_path):
    d = read_imu_csv(_rescaled(tmp_path, G / 1000, 1.0))
    assert "accelerometer in mg" in d.units
    assert np.linalg.norm(d.acc_m_s2[:100], axis=1).mean() == pytest.approx(9.81, abs=0.1)


def test_stated_units_override_and_a_wrong_statement_is_refused(tmp_path):
    p = _rescaled(tmp_path, G, math.pi / 180)
    d = read_imu_csv(p, accel_unit="g", gyro_unit="deg/s")
    assert "(given)" in d.units
    with pytest.raises(ImuError, match="--accel-unit m/s2.*not gravity"):
        read_imu_csv(p, accel_unit="m/s2")


def test_unknown_accelerometer_scale_is_refused_naming_the_option(tmp_path):
    p = _rescaled(tmp_path, 100.0, 1.0)      # median |a| ≈ 0.098: gravity in no unit
    with pytest.raises(ImuError, match="--accel-unit"):
        read_imu_csv(p)


def test_cli_reports_units_and_steps(tmp_path, capsys):
    p = _rescaled(tmp_path, G, math.pi / 180)
    out = tmp_path / "steps.csv"
    assert main(["features", "imu", str(p), "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "accelerometer in g" in cap.err and "gyro in deg/s" in cap.err
    assert cap.out.startswith("20 steps")
    assert main(["features", "imu", str(p), "--accel-unit", "m/s2", "--out", str(tmp_path / "x.csv")]) == 1
    err = capsys.readouterr().err
    assert "--accel-unit" in err and len(err.strip().splitlines()) == 1
    assert main(["features", "imu", str(p), "--accel-unit", "furlong", "--out", str(out)]) == 2


def test_real_xio_file_in_g_and_deg_s():
    """x-io NGIMU foot walk (short_walk.csv, columns labelled g and deg/s): both units detected.

    (The foot-mounted 400 Hz record is not a waist walk, so steps are not counted here.)"""
    src = shared_data("imu", "xio_gait_tracking", "short_walk.csv")
    raw = np.loadtxt(src, delimiter=",", skiprows=1)
    from features.imu.reader import detect_units, repair_imu

    f_acc, f_gyro, note = detect_units(raw[:, 4:7], raw[:, 1:4])
    assert (f_acc, f_gyro) == (G, math.pi / 180), note
    d = repair_imu(raw[:, 0], raw[:, 4:7] * f_acc, raw[:, 1:4] * f_gyro)
    assert np.median(np.linalg.norm(d.acc_m_s2, axis=1)) == pytest.approx(G, rel=0.05)
    assert 1.0 < np.percentile(np.linalg.norm(d.gyro_rad_s, axis=1), 99) < 15.0   # rad/s of a walking foot


def test_zero_steps_is_a_warning_not_silence(tmp_path, capsys):
    p = tmp_path / "still.csv"
    t = np.arange(0, 20, 0.01)
    p.write_text("t_s,ax,ay,az\n" + "".join(f"{x:.2f},0,0,-9.81\n" for x in t))
    assert main(["features", "imu", str(p), "--out", str(tmp_path / "s.csv")]) == 0
    assert "warning: " in capsys.readouterr().err
