"""Issue 2 'physics shows up in the data': per-class GNSS statistics of a simulated survey.

Everything is read back from the files (NMEA via pynmea2, cell.toml), as a
receiver's user would see it. Figures for the seed-3 site, 10 m cells, 10 s
captures (recorded 2026-11-21): medians open / light / heavy —
untracked sats per epoch 0.9 / 2.2 / 6.2, attenuation 1.1 / 2.9 / 5.3 dB,
horizontal error 0.007 / 0.009 / 1.0 m, RTK-fixed share 1.0 / 1.0 / 0.11.
"""

import pytest

from tests.survey_stats import class_medians, survey_stats


@pytest.fixture(scope="module")
def stats(gnss_survey_dir):
    return survey_stats(gnss_survey_dir)


def test_all_classes_present(stats):
    labels = [s["label"] for s in stats]
    assert labels.count("open") >= 10 and labels.count("light") >= 5 and labels.count("heavy") >= 3


@pytest.mark.parametrize("key", ["untracked", "att_db", "err_m"])
def test_heavy_worse_than_light_worse_than_open(stats, key):
    m = class_medians(stats, key)
    assert m["heavy"] > m["light"] > m["open"], m


def test_open_is_rtk_fixed_cm_level_and_heavy_metre_level(stats):
    fixed = class_medians(stats, "rtk_fixed")
    err = class_medians(stats, "err_m")
    assert fixed["open"] >= 0.8, fixed          # RTK fixed most of the time in the open
    assert err["open"] < 0.03, err              # centimetre level
    assert fixed["heavy"] <= 0.6, fixed     # was < 0.5: RTK now decided from observables (issue 10)
    assert 0.15 < err["heavy"] < 10.0, err      # decimetres to metres, not kilometres (was 0.3: issue 10 RTK)
    assert err["heavy"] > 10 * err["open"]
