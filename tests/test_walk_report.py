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
    table = error_table(sources)
    assert table["GNSS"]["all"][2] < 0.5                      # median: RTK most of the walk
    if "open" in table["GNSS"]:
        assert table["GNSS"]["open"][2] < 0.05
    assert table["acoustic"]["all"][0] >= 5 and table["acoustic"]["all"][2] < 0.5
    pdr = sources.tracks["PDR"]
    assert "calibrated_steps" in pdr.info and 0.3 < pdr.info["k"] < 0.7
    walked = float(np.sum(np.hypot(np.diff(sources.truth.east_m), np.diff(sources.truth.north_m))))
    assert table["PDR"]["all"][1] < 0.05 * walked             # mean PDR error under 5 % of distance


def test_plot(sources, tmp_path):
    png = plot_walk(sources, tmp_path / "walk.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size > 30_000
