"""Walk report: every raw source read from the walk's files, errors per class, PNG."""

import numpy as np
import pytest

from pipeline.walk_report import error_table, plot_walk, walk_sources


@pytest.fixture(scope="module")
def sources(walk_dir):
    return walk_sources(walk_dir)


def test_all_sources_present_on_the_walk_time_base(sources):
    assert set(sources.tracks) == {"GNSS", "acoustic", "PDR"}
    t_end = sources.truth.t_s[-1]
    for name, tr in sources.tracks.items():
        assert len(tr.t_s) > 0, name
        assert -0.5 <= tr.t_s[0] and tr.t_s[-1] <= t_end + 1.0, name  # walk time base, not file-relative


def test_errors_per_source_are_sensor_like(sources):
    """Change detector: the bounds are about 3x either side of what this simulated walk (site 3, walk 11,
    60 s) measured when they were set (issue 12 item 26; they were 7-70x wider), medians in m.

    Re-pinned after issue 13's satellite-sky label redrew site 3 (the walk now visits open and light
    only; before: GNSS all 0.020, open 0.0055, heavy 0.68; acoustic 0.22 over 14 fixes; PDR mean 0.32,
    K 0.424) and the issue-10/11 receiver and RTK changes: GNSS all 0.0113, open 0.0115 (RTK fixed after
    29 s of float: the 20 s convergence gate), light mean 0.65 against open mean 0.19; acoustic 0.21 over
    58 fixes (coverage deployment, 0.96 s frames); PDR mean 0.56 over 62 m walked, K 0.418 — 3.48 m
    before the calibrated PDR track was re-anchored on the GNSS fix its start came from (the anchor
    is the first RTK-fixed epoch, 29 s in). The invariant light > open in mean is the physical check;
    the independent references (gpsd, Oxford truth, closed forms) live in the reader and simulator
    tests.

    Re-pinned after issue 21 (inspection stops in the default routes, the GNSS world from the ambiguities, GST):
    walk 11 now spends 88 % of its 60 s in the open and stands 18 s beside equipment in light ground, RTK-fixed
    there. GNSS all median 0.0113 → 0.0069, open 0.0115 → 0.0065, light mean 0.65 → 0.015 (fixed, not float:
    the invariant light > open no longer holds on this walk, whose open mean carries the float of the cold
    start; occlusion degrading GNSS is pinned per class on many walks in tests/test_calibration.py); acoustic
    58 → 60 fixes, median 0.21 → 0.14 m; PDR mean 0.56 → 0.30 m over 64 m walked, K 0.418 → 0.425."""
    table = error_table(sources)
    gnss = table["GNSS"]
    assert 0.0069 / 3 < gnss["all"][2] < 0.0069 * 3           # median: RTK most of the walk
    assert 0.0065 / 3 < gnss["open"][2] < 0.0065 * 3
    assert 0.015 / 3 < gnss["light"][1] < 0.015 * 3            # mean: RTK fixed beside the equipment
    ac = table["acoustic"]["all"]
    assert 60 / 3 <= ac[0] <= 60 * 3 and 0.14 / 3 < ac[2] < 0.14 * 3
    pdr = sources.tracks["PDR"]
    assert "calibrated_steps" in pdr.info and 0.425 * 0.9 < pdr.info["k"] < 0.425 * 1.1
    walked = float(np.sum(np.hypot(np.diff(sources.truth.east_m), np.diff(sources.truth.north_m))))
    assert 0.30 / 3 < table["PDR"]["all"][1] < 0.30 * 3        # mean PDR error, m
    assert table["PDR"]["all"][1] < 0.02 * walked


def test_plot(sources, tmp_path):
    png = plot_walk(sources, tmp_path / "walk.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size > 30_000
