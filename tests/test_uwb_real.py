"""The UWB NLOS model's reference: measured DW1000 ranges in ../shared/data/cir_uwb (Kolakowski & Modelski 2018).

Range error = DecaRanging's ``Dist`` − the true anchor–tag distance from the dataset's location tables. The
figures asserted are those ``bench/bench_uwb.py`` prints beside the simulator's; skipped without the data."""

import numpy as np
import pytest

from tests.conftest import shared_data


@pytest.fixture(scope="module")
def measured():
    import importlib.util
    from pathlib import Path

    root = shared_data("cir_uwb")
    spec = importlib.util.spec_from_file_location("bench_uwb", Path(__file__).parents[1] / "bench" / "bench_uwb.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench.measured_rows(root)


def test_measured_range_bias_by_label(measured):
    by = {lab: np.concatenate([r[3] for r in measured if r[1] == lab]) for lab in ("LOS", "NLOS", "NDP NLOS")}
    assert [sum(r[1] == lab for r in measured) for lab in by] == [6, 7, 9]          # the README's 6 / 7 / 9 files
    los = np.median(by["LOS"])
    assert 0.15 < los < 0.30                       # the pair's uncalibrated offset, +0.226 m
    assert 0.0 < np.median(by["NLOS"]) - los < 0.15    # an attenuated direct path: centimetres more
    assert 0.5 < np.median(by["NDP NLOS"]) - los < 1.0  # no direct path: decimetres to metres (+0.68 m)
    assert np.percentile(by["NDP NLOS"], 95) > 2.0
    # the chip's own indicator, first-path minus received level: LOS near −3 dB, no direct path near −11 dB
    q = {lab: np.concatenate([r[4] for r in measured if r[1] == lab]) for lab in ("LOS", "NDP NLOS")}
    assert -4.0 < np.median(q["LOS"]) < -2.5 and np.median(q["NDP NLOS"]) < -9.0


def test_simulated_no_direct_path_is_biased_like_the_measured(measured):
    # the simulator's bent first path (round a steel plate 10 m away) is biased by decimetres, the same order as
    # the measured no-direct-path logs relative to LOS (0.61–3.10 m per log, minus the +0.23 m offset)
    import math

    from features.site import Box, Grid, Origin, Site
    from simulation.uwb.channel import PATH_BENT, build_uwb_scene, uwb_paths

    plate = Box("equipment", "steel", False, 4.0, 5.0, -1.0, 1.0, 6.0)
    site = Site(name="u", origin=Origin(31.2, 118.8), grid=Grid(1.0, -20.0, 40.0, -20.0, 40.0), layout=(plate,))
    p = uwb_paths(build_uwb_scene(site), (0.0, 0.0, 1.0), math.radians(90.0), (10.0, 0.0, 1.0))
    los = np.median(np.concatenate([r[3] for r in measured if r[1] == "LOS"]))
    per_log = [np.median(r[3]) - los for r in measured if r[1] == "NDP NLOS"]
    assert p.kind[0] == PATH_BENT and 0.1 < p.excess_m[0] < max(per_log)
