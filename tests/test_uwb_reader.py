"""features.uwb.reader: uwb.csv read back, malformed lines counted, unusable files refused with one UwbError."""

import math
from pathlib import Path

import numpy as np
import pytest

from features.errors import DataError, UwbError
from features.uwb.reader import UwbLog, read_uwb, write_uwb

DATA = Path(__file__).parent / "data"


def test_good_file_values_and_missing_fields():
    log = read_uwb(DATA / "uwb_good.csv")
    assert len(log) == 5 and log.n_bad_lines == 1
    np.testing.assert_allclose(log.t_s, [0.0, 0.01, 0.02, 0.3, 0.31])
    np.testing.assert_array_equal(log.anchor, [1, 2, 3, 1, 2])
    np.testing.assert_allclose(log.range_m, [5.0, 7.25, 3.1, 5.1, 7.3])
    assert math.isnan(log.azimuth_deg[1]) and log.azimuth_deg[2] == -20.5
    assert math.isnan(log.quality[2]) and log.quality[1] == -8.0
    np.testing.assert_array_equal(log.anchors, [1, 2, 3])


def test_directory_resolves_to_uwb_csv(tmp_path):
    (tmp_path / "uwb.csv").write_text((DATA / "uwb_good.csv").read_text())
    assert len(read_uwb(tmp_path)) == 5


def test_round_trip(tmp_path):
    log = UwbLog(t_s=np.array([0.0, 0.1234]), anchor=np.array([4, 7]), range_m=np.array([12.3456, 0.5]),
                 azimuth_deg=np.array([np.nan, -45.04]), quality=np.array([-3.26, np.nan]))
    write_uwb(tmp_path / "uwb.csv", log)
    back = read_uwb(tmp_path / "uwb.csv")
    np.testing.assert_allclose(back.t_s, [0.0, 0.123])
    np.testing.assert_allclose(back.range_m, [12.346, 0.5])
    np.testing.assert_array_equal(back.anchor, [4, 7])
    assert math.isnan(back.azimuth_deg[0]) and back.azimuth_deg[1] == -45.0
    assert back.quality[0] == -3.3 and math.isnan(back.quality[1])


@pytest.mark.parametrize("name, text, needle", [
    ("empty.csv", "", "empty file"),
    ("header_only.csv", "t_s,anchor,range_m,azimuth_deg,quality\n", "no usable row"),
    ("negative.csv", "t_s,anchor,range_m\n0,1,-2\n0.1,1.5,2\n0.2,1,nan\n", "3 malformed"),
    ("binary.csv", b"\xff\xfe\x00\x81garbage", "not UTF-8"),
])
def test_unusable_files(tmp_path, name, text, needle):
    p = tmp_path / name
    (p.write_bytes if isinstance(text, bytes) else p.write_text)(text)
    with pytest.raises(UwbError, match=needle):
        read_uwb(p)


def test_missing_columns_backwards_and_absent():
    with pytest.raises(UwbError, match="missing required column.*t_s.*range_m"):
        read_uwb(DATA / "uwb_missing_columns.csv")
    with pytest.raises(UwbError, match="line 3: t_s 0.5 goes back"):
        read_uwb(DATA / "uwb_backwards.csv")
    with pytest.raises(DataError, match="file not found"):
        read_uwb(DATA / "no_such_uwb.csv")
