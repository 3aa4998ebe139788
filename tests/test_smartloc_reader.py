"""smartLoc pseudorange / odometry / reference reader: hand-made files (one per failure mode) and the real drive.

Real data: ../shared/data/gnss_urban_smartloc, the first 170 s of smartLoc's Berlin Potsdamer Platz drive
(Reisdorf et al., TU Chemnitz; via TUC-ProAut/libRSF; CC BY-SA 4.0); figures from its README.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from features.errors import DataError, PseudorangeError
from features.gnss.pseudorange import PseudorangeTable, read_smartloc
from tests.conftest import shared_data

DATA = Path(__file__).resolve().parent / "data"


def test_good_file_decodes_every_field():
    log = read_smartloc(DATA / "smartloc_good.txt")
    p, o, r = log.pseudoranges, log.odometry, log.reference
    assert len(p) == 4 and len(o) == 2 and len(r) == 1
    assert p.t_s.tolist() == [0.0, 0.0, 0.29999995231628, 0.29999995231628]
    assert p.pseudorange_m[1] == 19713469.019098 and p.pseudorange_var_m2[1] == 64.0
    assert p.sat_ecef_m[0].tolist() == [14567933.924248, 2809850.9686675, 21875628.068424]
    assert p.system.tolist() == ["G", "R", "G", "R"] and p.svid.tolist() == [12, 320, 12, 320]
    assert p.elevation_deg[0] == 85.146780644512 and p.cn0_dbhz.tolist() == [49.0, 40.0, 49.0, 45.0]
    assert p.corrections == {"satellite_clock", "ionosphere", "troposphere"}
    t, start, stop = p.epochs()
    assert t.tolist() == [0.0, 0.29999995231628] and start.tolist() == [0, 2] and stop.tolist() == [2, 4]
    assert o.speed_m_s.tolist() == [5.85, 6.0777777777778]
    assert o.yaw_rate_rad_s[1] == -0.016929693744345
    assert o.velocity_var_m2_s2[0].tolist() == [0.0025, 0.0009, 0.0009]
    assert o.rate_var_rad2_s2[0].tolist() == [4e-06] * 3
    assert r.ecef_m[0].tolist() == [3785108.1107158, 899901.49390314, 5037234.4571748]
    assert r.cov_ecef_m2.shape == (1, 3, 3) and not r.cov_ecef_m2.any()
    s = log.stats
    assert (s.lines, s.blank_or_comment, s.other_types["imu3"], s.malformed) == (10, 2, 1, 0)
    assert dict(s.records) == {"pseudorange3": 4, "odom3": 2, "point3": 1}


@pytest.mark.parametrize("mode, words", [
    ("fields", "needs 10 fields after the type, got 9"),
    ("number", "field 10 is not a number: '58.1x'"),
    ("system", "system code 3 is none of"),
    ("variance", "variance must be > 0"),
    ("orbit", "not an orbit"),
    ("duplicate", "satellite G12 appears twice"),
    ("backwards", "does not follow the previous odom3 time"),
    ("elevation", "elevation must lie in [-90, 90]"),
    ("nan", "field 3 is not finite"),
])
def test_each_malformed_line_raises_one_error_naming_file_and_line(mode, words):
    path = DATA / f"smartloc_bad_{mode}.txt"
    with pytest.raises(PseudorangeError) as err:
        read_smartloc(path)
    text = str(err.value)
    assert text.startswith(f"{path}:3: ") and words in text
    assert isinstance(err.value, DataError) and isinstance(err.value, ValueError)


@pytest.mark.parametrize("mode", ["fields", "number", "system", "variance", "orbit", "backwards", "elevation"])
def test_lenient_mode_skips_and_counts_the_bad_line(mode):
    log = read_smartloc(DATA / f"smartloc_bad_{mode}.txt", strict=False)
    assert log.stats.malformed == 1 and ":3: " in log.stats.first_malformed
    assert len(log.odometry) == 1 and log.pseudoranges is None  # the one good line (line 2) is kept
    assert "skipped 1 malformed" in log.stats.summary()


def test_a_file_without_records_and_an_unreadable_file_are_refused(tmp_path):
    with pytest.raises(PseudorangeError, match="no pseudorange3, odom3 or point3 record in 3 lines"):
        read_smartloc(DATA / "smartloc_empty.txt")
    with pytest.raises(PseudorangeError, match="cannot read"):
        read_smartloc(tmp_path / "absent.txt")


def test_table_validates_what_a_rinex_stage_would_build():
    ok = dict(t_s=[0.0, 0.0], pseudorange_m=[2e7, 2.1e7], pseudorange_var_m2=[np.nan, np.nan],
              sat_ecef_m=np.full((2, 3), 1.5e7), svid=[1, 2], system=["G", "E"], elevation_deg=[np.nan] * 2,
              cn0_dbhz=[40.0, np.nan], corrections={"satellite_clock", "earth_rotation"})
    assert len(PseudorangeTable(**ok)) == 2
    with pytest.raises(PseudorangeError, match="sat_ecef_m must have shape"):
        PseudorangeTable(**{**ok, "sat_ecef_m": np.zeros((2, 2))})
    with pytest.raises(PseudorangeError, match="non-decreasing"):
        PseudorangeTable(**{**ok, "t_s": [1.0, 0.0]})


def test_real_drive_counts_match_the_readme():
    folder = shared_data("gnss_urban_smartloc")
    log = read_smartloc(folder / "Berlin_Potsdamer_Platz_Input.txt")
    p = log.pseudoranges
    assert dict(log.stats.records) == {"pseudorange3": 12211, "odom3": 823} and log.stats.malformed == 0
    t, start, stop = p.epochs()
    n = stop - start
    # README: 823 epochs 0.3 s apart or less, 7-17 satellites an epoch (mean 14.8), GPS + GLONASS
    assert len(t) == 823 and (n.min(), n.max()) == (7, 17) and abs(n.mean() - 14.8) < 0.05
    assert set(p.system.tolist()) == {"G", "R"}
    assert np.array_equal(t, log.odometry.t_s)
    gt = read_smartloc(folder / "Berlin_Potsdamer_Platz_GT.txt").reference
    assert len(gt) == 823 and np.array_equal(gt.t_s, t)
    # per-epoch mean C/N0 28.8-43.0 dB-Hz (README)
    mean_cn0 = np.add.reduceat(p.cn0_dbhz, start) / n
    assert abs(mean_cn0.min() - 28.8) <= 0.05 + 1e-9 and abs(mean_cn0.max() - 43.0) <= 0.05 + 1e-9  # README rounds
