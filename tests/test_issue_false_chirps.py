"""Issue 12, item 2: clicks and tones are not chirps (the pulse-compression test of
:mod:`features.acoustic.detection`).

False chirps per hour (``bench/false_chirps.py``; five-beacon square, bare-WAV timing):

=======================  ========  ======
signal                   before    after
=======================  ========  ======
noise + 2 clicks/s       5,550     72 (600 s, 5 seeds: 1 % of clicks)
1 kHz sine, half scale   120       0
20 kHz sine in noise     0         0
ultrasense (5 phones)    0         0
=======================  ========  ======

True chirps kept: six held-out 300 s walks (sites 41, 52, 63) 6,496 chirps found within 2 ms
of the truth against 6,319 without the test (tracking holds better), other detections 2,587
against 2,918, fixes 723 against 678. The residual click rate comes from click pairs within one
chirp length, whose outputs beat into narrow peaks; a stricter share (±1/B, 15 %) rejected those
too but lost 10 % of the true chirps on the same walks, so it was not taken.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

import features.acoustic.detection as detection
from bench.false_chirps import count, synthetic
from tests.acoustic_synth import write_wav


@pytest.mark.parametrize("kind", ["clicks", "tone 1 kHz", "tone 20 kHz"])
def test_clicks_and_tones_give_no_chirps(kind, tmp_path):
    p = tmp_path / "x.wav"
    write_wav(p, synthetic(kind, seconds=30.0, seed=3))
    n, seconds = count(p)
    assert seconds == pytest.approx(30.0)
    # Before: 47 for 60 clicks, 2 for the 1 kHz tone. A click pair within one chirp length beats
    # into narrow peaks that can pass (1 % of clicks): at most 2 of 60.
    assert n <= (2 if kind == "clicks" else 0)


def test_real_phone_recordings_give_no_chirps():
    from tests.conftest import shared_data

    files = sorted(shared_data("audio_ultrasense").glob("*.wav"))
    assert len(files) == 5
    assert sum(count(p)[0] for p in files) == 0


def _true_found(walk_dir):
    from features.acoustic.features import analyse_audio
    from features.acoustic.positions import PositionConfig
    from features.acoustic.timing import timing_from_walk
    from features.walk import load_walk

    w = load_walk(walk_dir)
    site = w.load_site()
    timing = timing_from_walk(w, site)
    truth = {(int(r["beacon_id"]), round(float(r["emit_t_s"]), 3)): float(r["arrival_sample"]) / 48_000
             for r in csv.DictReader(open(walk_dir / "audio_truth.csv"))}
    res = analyse_audio(w.path("audio"), site, timing, keep_frames=True,
                        positions=PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05,
                                                 motion_speed_m_s=1.4))
    hits = [abs(d.arrival_s - timing.start_s - truth[(d.beacon_id, round(d.tx_s, 3))]) < 0.002
            for fr in res.frames for d in fr.detections if (d.beacon_id, round(d.tx_s, 3)) in truth]
    return sum(hits), len(res.fixes)


def test_true_chirps_are_still_found_on_a_walk(walk_dir, monkeypatch):
    """Re-pinned for the coverage deployment (two 2.9 kHz sub-bands, issue 10 item 7): true chirps kept
    by the compression test ≥ 97 % → ≥ 90 % (measured 425 of 461 with the −6 dB width limit scaled to
    6/B; 245 of 461 with the fixed 1 ms limit)."""
    found, fixes = _true_found(walk_dir)
    print("true chirps found", found, "fixes", fixes)
    monkeypatch.setattr(detection, "_MIN_COMPRESSED_SHARE", -1e9)
    monkeypatch.setattr(detection, "_MAX_PEAK_WIDTH_S", 1e3)
    found_without, fixes_without = _true_found(walk_dir)
    assert found_without > 100
    print("without the test", found_without, fixes_without)
    assert found >= 0.9 * found_without
    assert fixes >= 0.9 * fixes_without
