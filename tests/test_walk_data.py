"""The spine (walks.reader.read_walk): one read of a walk, every source on its time base."""

import shutil

import numpy as np
import pytest

from features.acoustic.timing import timing_from_walk
from features.walk import load_walk
from walks.reader import read_walk, walk_has


@pytest.fixture(scope="module")
def data(walk_dir):
    return read_walk(walk_dir)


def test_every_stream_is_read_with_its_uncertainty(data):
    g, a, p = data.gnss, data.acoustic, data.pdr
    n = len(g.positions)
    assert n > 200                                             # 60 s at 5 Hz, most epochs with a fix
    assert g.positions.sigma_en_m.shape == (n,) and np.all(g.positions.sigma_en_m > 0)
    assert set(g.features) >= {"t_s", "att_mean_db", "att_std_db", "fluct_per_s", "invisible_ratio", "dop_growth"}
    m = len(a.t_s)
    assert m >= 5 and a.covariance_en_m2.shape == (m, 2, 2)
    cov = a.covariance_en_m2
    assert np.allclose(cov, np.transpose(cov, (0, 2, 1)))       # symmetric
    assert np.all(np.linalg.eigvalsh(cov) > 0)                 # positive definite
    assert len(a.feature_rows) > 50                            # one row per 1 s hop
    assert len(p.result) > 50 and np.all(np.diff(p.result.t_s) > 0)


def test_sources_share_the_walk_time_base(data):
    t_end = data.truth.t_s[-1]
    for t in (data.gnss.positions.t_s, data.acoustic.t_s, data.pdr.result.t_s):
        assert -0.5 <= t[0] and t[-1] <= t_end + 1.0
    assert data.acoustic.timing == timing_from_walk(load_walk(data.walk.directory), data.site)


def test_a_missing_stream_is_none(walk_dir, tmp_path):
    d = tmp_path / "w"
    shutil.copytree(walk_dir, d)
    (d / "audio.wav").unlink()
    assert walk_has(d) == {"gnss": True, "audio": False, "imu": True, "gnss_pseudoranges": False, "odometry": False,
                           "uwb": True, "imu_foot": True, "truth": True}
    partial = read_walk(d)
    assert partial.acoustic is None and partial.gnss is not None and partial.pdr is not None


def test_pdr_is_run_once_and_translated_to_the_gnss_anchor(walk_dir):
    """Issue 14 (speed): read_walk ran PDR twice (from the origin, then from the anchor); the track
    is start + Σ steps, so translating the first run gives exactly the rerun's numbers."""
    from walks import reader as wd

    data = wd.read_walk(walk_dir)
    rerun = wd.read_pdr_stream(data.walk, data.pdr.start_en_m, None)
    np.testing.assert_array_equal(data.pdr.result.east_m, rerun.result.east_m)
    np.testing.assert_array_equal(data.pdr.result.north_m, rerun.result.north_m)
    assert data.pdr.start_en_m != (0.0, 0.0)
