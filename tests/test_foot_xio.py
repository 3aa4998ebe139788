"""The foot INS on the real x-io Gait-Tracking walks (NGIMU at the foot, 400 Hz, two closed loops): the
loop-closure error within a stated factor of x-io's published figures and the stride count against a count made
by hand (bench/bench_foot_ins.py says how: swing bursts of the gyro magnitude counted by eye on a plot)."""

from __future__ import annotations

import numpy as np
import pytest

from features.imu.foot import read_xio_gait_csv
from models.foot.ins import FootInsConfig, run_foot_ins
from models.foot.stance import StanceConfig

from tests.conftest import shared_data

PUBLISHED_MM = {"short_walk": 82.0, "long_walk": 421.0}
HAND_STRIDES = {"short_walk": 16, "long_walk": 37}
FACTOR = {"short_walk": 7.0, "long_walk": 1.5}
"""How far above x-io's figure our causal filter may end (measured: 538 mm = 6.6×, 518 mm = 1.2×). x-io removes
each moving period's velocity drift after the fact (a look-ahead); the ZUPT filter here cannot."""


@pytest.mark.parametrize("name", ["short_walk", "long_walk"])
def test_loop_closure_and_stride_count_on_the_xio_walks(name):
    imu = read_xio_gait_csv(shared_data("imu", "xio_gait_tracking", f"{name}.csv"))
    assert imu.rate_hz == pytest.approx(400.0, rel=0.01)
    run = run_foot_ins(imu.t_s, imu.acc_m_s2, imu.gyro_rad_s, None, FootInsConfig(stance=StanceConfig(gamma=1e5)))
    err_mm = 1000 * float(np.linalg.norm(run.pos_m[-1] - run.pos_m[0]))
    assert err_mm < FACTOR[name] * PUBLISHED_MM[name], err_mm
    assert abs(run.strides - HAND_STRIDES[name]) <= 1, run.strides
    # the walk's length is ~25 m / ~60 m (x-io's README): a scale error of the INS would show here
    path_m = float(np.sum(np.linalg.norm(np.diff(run.pos_m[:, :2], axis=0), axis=1)))
    assert path_m == pytest.approx({"short_walk": 25.0, "long_walk": 60.0}[name], rel=0.12)
    # the foot is still at both ends: velocity at the last sample is that of a ZUPT
    assert np.linalg.norm(run.vel_m_s[-1]) < 0.02


def test_xio_reader_refuses_a_file_without_the_xio_header(tmp_path):
    from features.errors import ImuError

    p = tmp_path / "x.csv"
    p.write_text("t_s,ax,ay,az\n0,0,0,1\n0.01,0,0,1\n")
    with pytest.raises(ImuError, match="x-io header"):
        read_xio_gait_csv(p)
