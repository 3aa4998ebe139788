"""Beacon and recorder hardware (issue 10 item 4): survey errors, emission delays, codec roll-off."""

import numpy as np
import pytest
from scipy import signal

from simulation.acoustic.hardware import CodecFilter, HardwareConfig, beacon_delays_s, true_beacon_positions
from simulation.site.layout import generate_site


def test_beacons_are_a_few_centimetres_off_the_survey_and_stay_there():
    site = generate_site(4)
    pos = true_beacon_positions(site)
    d = np.array([pos[b.id] - np.array([b.east_m, b.north_m, b.up_m]) for b in site.beacons])
    assert 0.005 < np.sqrt(np.mean(d[:, :2] ** 2)) < 0.05 and np.abs(d).max() < 0.15
    again = true_beacon_positions(site)
    assert all(np.array_equal(pos[k], again[k]) for k in pos)  # the poles do not move between walks
    delays = np.array(list(beacon_delays_s(site).values()))
    assert 5e-6 < delays.std() < 80e-6
    none = true_beacon_positions(site, HardwareConfig(survey_sigma_h_m=0.0, survey_sigma_v_m=0.0))
    assert all(np.allclose(none[b.id], [b.east_m, b.north_m, b.up_m]) for b in site.beacons)


def test_codec_rolls_off_the_top_of_the_band():
    f = CodecFilter(48_000, np.random.default_rng(1))
    assert 21_000 <= f.corner_hz <= 23_000
    w, h = signal.sosfreqz(f.sos, worN=[17_000, f.corner_hz, 23_500], fs=48_000)
    db = 20 * np.log10(np.abs(h))
    assert db[0] > -1.0 and db[1] == pytest.approx(-3.01, abs=0.05) and db[2] < -3.0
    # Block by block equals all at once (state carried).
    x = np.random.default_rng(2).standard_normal(10_000)
    g = CodecFilter(48_000, np.random.default_rng(1))
    y = np.concatenate([g(x[:3000]), g(x[3000:])])
    assert np.allclose(y, signal.sosfilt(f.sos, x))
