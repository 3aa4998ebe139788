"""Issue 11 (smaller): audio feature windows hold the chirps of their true time, not of the
receiver's stated clock.

Five beacons, a static receiver whose audio clock runs 40 ms behind (δ = stated − true =
−0.04 s, within the stated ±0.05 s): by the stated clock every chirp lands 40 ms early, so the
chirps that truly arrive in the first 40 ms of a window were counted in the window before.
Counting the chirps per 1 s hop from the true arrivals is the reference; before, 20 of the 27
hops compared disagreed with it, now none does.
"""

from __future__ import annotations

import math

import numpy as np

from features.acoustic.detection import AudioTiming
from features.acoustic.features import WindowConfig, analyse_audio
from tests.acoustic_synth import C_20C_M_S, square_site, static_capture, write_wav


def test_chirps_go_to_the_window_of_their_true_arrival(tmp_path):
    site = square_site(5)
    cap = static_capture(site, 20.0, 25.0, 30.0, clock_offset_s=-0.04, seed=2)
    write_wav(tmp_path / "a.wav", cap.samples)
    res = analyse_audio(tmp_path / "a.wav", site, AudioTiming(0.0, 0.05, 0.0), windows=WindowConfig(1.0, 1.0))
    true_per_hop = np.zeros(len(res.rows), dtype=int)
    ac = site.acoustic
    for b in site.beacons:
        d = math.dist((20.0, 25.0, site.device_height_m), (b.east_m, b.north_m, b.up_m))
        k = 0
        while (tx := k * ac.frame_s + b.slot * ac.slot_s) < 30.0:
            hop = math.floor(tx + d / C_20C_M_S)
            if 0 <= hop < len(true_per_hop):
                true_per_hop[hop] += 1
            k += 1
    got = np.array([r["n_chirps"] for r in res.rows])
    # The first hops precede the lock (no clock known yet); compare once the receiver has a fix.
    first_fix = math.ceil(res.fixes[0].t_s) + 1
    assert len(res.fixes) > 20
    assert np.array_equal(got[first_fix:-1], true_per_hop[first_fix:-1])
