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


def _true_found(walk_dir, detector=None):
    from features.acoustic.features import analyse_audio
    from features.acoustic.positions import PositionConfig
    from features.acoustic.timing import timing_from_walk
    from features.walk import load_walk

    w = load_walk(walk_dir)
    site = w.load_site()
    timing = timing_from_walk(w, site)
    truth = {(int(r["beacon_id"]), round(float(r["emit_t_s"]), 3)): float(r["arrival_sample"]) / 48_000
             for r in csv.DictReader(open(walk_dir / "audio_truth.csv"))}
    from features.acoustic.detection import DetectorConfig

    res = analyse_audio(w.path("audio"), site, timing, detector or DetectorConfig(), keep_frames=True,
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


# --- Issue 21, item 6: impulses at the rates HV equipment emits them (impulse removal before the filter) -----
#
# False chirps per minute (bench/false_chirps.py, 3 × 60 s; "before" = DetectorConfig(impulse_ratio=0)), on the
# 24-beacon two-band deployment of yard 201: impulses 10/s 44.3 → 0, with a 20 kHz tone under them 45.3 → 0,
# 50/s of spread levels 56.0 → 0; noise, tones and the real phone files 0 → 0. True chirps on three held-out
# walks 8,491 → 8,493 (default discharges), 8,026 → 8,152 (heavy discharges). Table: docs/receiver_consistency.md.

from features.acoustic.impulses import ImpulseBlanker  # noqa: E402
from tests.acoustic_synth import add_chirp  # noqa: E402


def _blank(x, block=None, **kw):
    b = ImpulseBlanker(48_000.0, **kw)
    block = block or len(x)
    out = np.concatenate([b.process(x[i:i + block]) for i in range(0, len(x), block)] + [b.flush()])
    return out, b


def test_blanker_finds_impulses_and_passes_everything_else():
    """Hand-checked: impulses of 50·σ at known samples in white noise are found (one hole each; two within a
    hold make one), the hole runs from one sample before the impulse to ``hold`` (24) samples after the last
    sample where its prediction error stands out (the impulse's own, or up to ``order`` (12) after it when a
    coefficient of the fitted model is large), and every other sample is passed bit for bit."""
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 0.002, 48_000).astype(np.float32)
    for i in (5_000, 20_000, 20_020, 41_234):
        x[i] += 0.1
    out, b = _blank(x)
    assert b.n_impulses == 3
    changed = np.flatnonzero(out != x)
    holes = np.split(changed, np.flatnonzero(np.diff(changed) > 1) + 1)
    assert [h[0] for h in holes] == [4_999, 19_999, 41_233]
    for h, last in zip(holes, (5_000, 20_020, 41_234)):
        assert last + 24 <= h[-1] <= last + 24 + 12
    assert b.n_blanked == sum(len(h) for h in holes)


def test_blanker_fills_holes_with_what_the_signal_was():
    """Under a 20 kHz tone (0.05) and a 300 Hz hum (0.02), both exactly autoregressive, the least-squares AR
    interpolation of a hole (Janssen et al. 1986) gives back the impulse-free signal to within 1e-3
    (−34 dB re. the tone; noise 1e-4); a straight line across the same hole is off by up to the tone's
    amplitude, i.e. cuts a 0.5 ms click out of it."""
    rng = np.random.default_rng(6)
    t = np.arange(48_000) / 48_000
    clean = 0.05 * np.sin(2 * np.pi * 20_000 * t) + 0.02 * np.sin(2 * np.pi * 300 * t + 1) + rng.normal(0, 1e-4, len(t))
    y = clean.copy()
    y[[10_000, 30_007]] += 0.3
    out, b = _blank(y.astype(np.float32))
    changed = np.flatnonzero(out != y.astype(np.float32))
    holes = np.split(changed, np.flatnonzero(np.diff(changed) > 1) + 1)
    assert b.n_impulses == 2 and [h[0] for h in holes] == [9_999, 30_006]
    for h in holes:
        assert np.abs(out[h] - clean[h]).max() < 1e-3
        line = np.interp(h, [h[0] - 1, h[-1] + 1], [y[h[0] - 1], y[h[-1] + 1]])
        assert np.abs(line - clean[h]).max() > 0.03


def test_blanker_leaves_chirps_alone():
    """A chirp 60 dB above the noise (its onset rises from the noise within a millisecond: 15–17× a one-sided
    mean, which is why the reference is two-sided), and two equal paths 5 ms apart beating: nothing blanked."""
    x = np.random.default_rng(1).normal(0.0, 0.0002, 48_000)
    add_chirp(x, 0.1003, 0.2)
    add_chirp(x, 0.5001, 0.2)
    add_chirp(x, 0.5051, 0.2)
    out, b = _blank(x.astype(np.float32))
    assert b.n_impulses == 0 and np.array_equal(out, x.astype(np.float32))


def test_blanker_output_does_not_depend_on_the_block_size():
    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 0.002, 100_000).astype(np.float32)
    x[rng.integers(0, len(x), 40)] += 0.2
    whole, _ = _blank(x)
    for block in (997, 4_096, 33_333):
        assert np.array_equal(_blank(x, block)[0], whole)


def test_blanking_under_hum_adds_no_click():
    """A 0.02 (−34 dBFS) hum of 100–400 Hz under the impulses: the line across each hole keeps it continuous,
    so the 17–23 kHz energy of the blanked signal around the holes is the noise's (zeroed holes would leave
    two steps each, a new broadband click)."""
    fs = 48_000
    t = np.arange(fs) / fs
    hum = sum(0.02 * 10 ** (-3 * h / 20) * np.sin(2 * np.pi * 100 * (h + 1) * t + h) for h in range(4))
    noise = np.random.default_rng(3).normal(0.0, 0.0005, fs)
    at = np.arange(2_400, fs - 2_400, 4_800)
    imp = np.zeros(fs)
    imp[at] = 0.2
    x = (hum + noise + imp).astype(np.float32)
    out, b = _blank(x)
    # One hole per impulse, and one at the very start: the step from the zeros before the stream to the hum.
    changed = np.flatnonzero(out != x)
    starts = changed[np.r_[True, np.diff(changed) > 1]]
    assert starts.tolist() == [0] + (at - 1).tolist() and b.n_impulses == len(at) + 1

    def band(y):
        spec = np.fft.rfft(y)
        f = np.fft.rfftfreq(len(y), 1 / fs)
        spec[(f < 17_000) | (f > 23_000)] = 0
        return np.fft.irfft(spec, len(y))

    # The in-band peak of what blanking left besides the hum, near the holes, against the noise's own:
    # the lines add nothing; zeroed holes (the alternative) leave the hum's steps, clicks 3–4× the noise.
    near = np.zeros(fs, bool)
    for i in at:
        near[i - 200: i + 200] = True
    zeroed = x.astype(float)
    zeroed[changed] = 0.0
    sigma = band(noise).std()
    assert np.abs(band(out - hum)[near]).max() < 4.5 * sigma
    assert np.abs(band(zeroed - hum)[near]).max() > 8 * sigma


@pytest.mark.parametrize("kind", ["impulses 10/s", "impulses 10/s + 20 kHz tone", "impulses 50/s (levels)"])
def test_impulses_at_hv_rates_give_no_chirps_on_a_coverage_site(kind, tmp_path):
    """The review's case (issue 21): noise with 10 impulses a second, with and without a 20 kHz tone, and 50 a
    second of spread levels, on a 24-beacon two-band deployment. Without the blanker the same 30 s gave
    4 / 0 / 5 false chirps (a few per minute; more on other seeds, see bench/false_chirps.py); with it none."""
    from bench.false_chirps import sites

    p = tmp_path / "x.wav"
    write_wav(p, synthetic(kind, seconds=30.0, seed=4))
    n, seconds = count(p, sites()["yard 201, 24 beacons"])
    assert seconds == pytest.approx(30.0)
    assert n == 0


def test_impulse_removal_loses_no_true_chirp_on_a_walk(walk_dir):
    """The conftest walk with its simulated discharges: the chirps found within 2 ms of the truth with impulses
    removed are at least those found without (measured equal ±4 on three held-out 300 s walks), and the fixes
    within 2 %."""
    from features.acoustic.detection import DetectorConfig

    found, fixes = _true_found(walk_dir)
    found_without, fixes_without = _true_found(walk_dir, DetectorConfig(impulse_ratio=0.0))
    assert found_without > 100
    assert found >= 0.995 * found_without
    assert abs(fixes - fixes_without) <= 0.02 * fixes_without + 1
