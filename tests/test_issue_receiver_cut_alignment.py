"""Issue 25 (long walks in segments): a cut of a recording, read with its first sample's index in the whole
(``first_sample``), detects what the whole run detects once its buffers have filled and its tracker is resumed.

Before, the cut's audio blocks, impulse-blanker segments, matched-filter FFT blocks and decimation grid were
aligned on the cut's first sample: float32 round-off then differed from the whole run's, and a detection near
a threshold could move or flip (walks/segments.py: seed 78, one 300 s segment held 7 fixes more).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import soundfile as sf

from features.acoustic.audio import iter_audio_blocks
from features.acoustic.features import analyse_audio
from features.acoustic.impulses import ImpulseBlanker
from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank, StreamingMatchedFilter
from features.acoustic.positions import PositionConfig
from features.acoustic.timing import timing_from_walk
from features.walk import load_walk

FS = 48_000
CUT = 20 * FS + 1237        # 20.026 s: not on a block (4 s), blanker segment (4096), FFT hop or decimation (4)
RESUME_S = 30.0             # the cut's warm-up: 10 s, as walks/segments.py's RESUME_AFTER_S


def test_audio_blocks_of_a_cut_end_where_the_whole_recordings_do(tmp_path):
    """Blocks of 0.5 s (24,000 samples) of a file whose first sample is sample 30,000 of the whole: the first
    block runs to 48,000, the next ones to whole multiples of 24,000; indices count from 30,000."""
    sf.write(tmp_path / "a.wav", np.zeros(100_000, np.float32), FS, subtype="FLOAT")
    blocks = list(iter_audio_blocks(tmp_path / "a.wav", block_s=0.5, first_index=30_000))
    assert [b.start_index for b in blocks] == [30_000, 48_000, 72_000, 96_000, 120_000]
    assert [len(b.samples) for b in blocks] == [18_000, 24_000, 24_000, 24_000, 10_000]


def test_matched_filter_of_a_cut_is_on_the_whole_streams_grid():
    """White noise filtered whole in 4 s blocks and from sample 10,003 on in blocks ending at the same indices:
    the cut's outputs carry the whole's indices (10,003 // 4 = 2,500 first) and, from one block on, are the
    whole's to the bit; the first block's outputs within a kernel length of the cut differ (zeros before it)."""
    bank = MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], FS)
    x = np.random.default_rng(4).standard_normal(3 * 192_000).astype(np.float32)
    whole = StreamingMatchedFilter(bank)
    env_whole = np.concatenate([whole.process(x[i: i + 192_000])[1] for i in range(0, len(x), 192_000)], axis=1)
    first = 10_003
    cut = StreamingMatchedFilter(bank, first_index=first)
    j0, e0 = cut.process(x[first: 192_000])
    assert j0 == first // 4
    envs = [e0] + [cut.process(x[i: i + 192_000])[1] for i in range(192_000, len(x), 192_000)]
    env_cut = np.concatenate(envs, axis=1)
    j_from = 192_000 // 4                                       # the second block on
    assert np.array_equal(env_cut[:, j_from - j0:], env_whole[:, j_from:])
    assert not np.array_equal(env_cut[:, :10], env_whole[:, j0: j0 + 10])


def test_blanker_of_a_cut_decides_as_the_whole(tmp_path):
    """Impulses of 50σ in noise with a 20 kHz tone (the AR model, not the second difference, whitens it): the
    blanker run from sample 100,001 with ``first_index`` releases, from its second 4096-sample segment on,
    the samples the whole run releases, bit for bit (the AR models of the same segments, the same holes)."""
    rng = np.random.default_rng(7)
    n = 4 * 192_000
    x = (0.01 * rng.standard_normal(n) + 0.05 * np.sin(2 * np.pi * 20_000 / FS * np.arange(n))).astype(np.float32)
    at = rng.integers(0, n, 400)
    x[at] += 0.5 * np.sign(rng.standard_normal(400)).astype(np.float32)
    blocks = [(i, min(i + 192_000, n)) for i in range(0, n, 192_000)]
    whole = ImpulseBlanker(FS)
    out_whole = np.concatenate([whole.process(x[a:b]) for a, b in blocks] + [whole.flush()])
    first = 100_001
    cut = ImpulseBlanker(FS, first_index=first)
    out_cut = np.concatenate([cut.process(x[max(a, first):b]) for a, b in blocks if b > first] + [cut.flush()])
    assert len(out_whole) == n and len(out_cut) == n - first
    settled = (first // 4096 + 2) * 4096                     # the segment after the cut's first whole one
    assert whole.n_impulses > 300
    assert np.array_equal(out_cut[settled - first:], out_whole[settled:])


def _receiver_setup(walk):
    """(site, timing, solver settings) the receiver reads ``walk`` with, as walks.reader does (walking prior
    1.4 m/s)."""
    site = walk.load_site()
    timing = timing_from_walk(walk, site)
    return site, timing, PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05, motion_speed_m_s=1.4)


@pytest.fixture(scope="module")
def whole_and_cut(walk_dir, tmp_path_factory):
    """The conftest walk (60 s) read whole, keeping the receiver's state at 30 s, and its audio from sample CUT
    on written as its own file and read with ``first_sample`` = CUT and the whole walk's timing, resumed there."""
    walk = load_walk(walk_dir)
    site, timing, pos = _receiver_setup(walk)
    whole = analyse_audio(walk.path("audio"), site, timing, positions=pos, keep_frames=True,
                          keep_state_from_s=RESUME_S)
    x, fs = sf.read(str(walk.path("audio")), dtype="int16")
    assert fs == FS and len(x) > CUT + 20 * FS
    d = tmp_path_factory.mktemp("cut")
    sf.write(d / "audio.wav", x[CUT:], FS, subtype="PCM_16")
    cut = analyse_audio(d / "audio.wav", site, timing, positions=pos, keep_frames=True,
                        resume=whole.receiver_state, first_sample=CUT)
    return whole, cut


def _detections(frames, from_frame):
    return [(f.frame, d.beacon_id, d.tx_s, d.arrival_s, d.snr_db, d.associated, tuple(d.features))
            for f in frames if f.frame >= from_frame for d in f.detections]


def test_a_cut_off_block_detects_what_the_whole_walk_detects(whole_and_cut):
    """From the resumed frame on, every detection (beacon, emission, arrival, SNR, CIR features) and every fix
    of the cut is the whole run's, bit for bit; the cut's first frames (warm-up) are its own."""
    whole, cut = whole_and_cut
    k0 = whole.receiver_state.frame
    assert any(f.frame == k0 for f in cut.frames)
    a, b = _detections(whole.frames, k0), _detections(cut.frames, k0)
    assert len(a) > 50                                          # 30 s of chirps from several beacons
    assert a == b
    fa = [(f.t_s, f.east_m, f.north_m, f.clock_offset_s, f.used_ids) for f in whole.fixes if f.t_s >= RESUME_S + 1]
    fb = [(f.t_s, f.east_m, f.north_m, f.clock_offset_s, f.used_ids) for f in cut.fixes if f.t_s >= RESUME_S + 1]
    assert len(fa) >= 10 and fa == fb


def test_a_cuts_feature_windows_start_at_its_first_sample(whole_and_cut):
    """The cut's windows lie on the walk's time base from its first sample (20.026 s): the first centred at
    20.026 + 1 s, and as many as its 40 s hold."""
    _, cut = whole_and_cut
    t = [r["t_s"] for r in cut.rows]
    assert math.isclose(t[0], CUT / FS + 1.0, abs_tol=1e-9)
    assert len(t) == math.floor(cut.duration_s - 2.0 + 1e-9) + 1


def test_a_negative_or_fractional_first_sample_is_refused(walk_dir):
    """One clear message naming the parameter, before any audio is read."""
    from features.errors import ConfigError

    walk = load_walk(walk_dir)
    site = walk.load_site()
    for bad in (-1, 2.5):
        with pytest.raises(ConfigError, match="first_sample"):
            analyse_audio(walk.path("audio"), site, timing_from_walk(walk, site), first_sample=bad)


def test_feature_batches_do_not_change_the_fixes(site_dir, tmp_path_factory, monkeypatch):
    """The receiver computes CIR features for 32 frames at a time and then releases them; an acquisition fix is
    reported only once the next frame confirms it, and is handed to the frame before. Frames released in batches
    of 1, 2 or 7 give the same fixes and detections as one batch of the whole walk (the reference: nothing
    released before the end). Before, a batch's last frame was released before the next frame could hand it its
    confirmed acquisition fix, so every batch boundary falling there lost a fix (with batches of 1, all three of
    this walk's), and a long walk's cut, whose batches start at its own first frame, lost other fixes than the
    whole walk."""
    import features.acoustic.detection as detection
    from features.acoustic.tracking import ClockPositionTracker
    from simulation.walk import simulate_walk

    walk = load_walk(simulate_walk(site_dir, tmp_path_factory.mktemp("walks") / "w1", seed=1, duration_s=60.0))
    site, timing, pos = _receiver_setup(walk)
    confirmed = []
    take = ClockPositionTracker.take_confirmed_tentative

    def counted(self):
        fix = take(self)
        if fix is not None:
            confirmed.append(fix.t_s)
        return fix

    monkeypatch.setattr(ClockPositionTracker, "take_confirmed_tentative", counted)

    def read(batch):
        monkeypatch.setattr(detection, "_FEATURE_BATCH_FRAMES", batch)
        a = analyse_audio(walk.path("audio"), site, timing, positions=pos, keep_frames=True)
        fixes = [(f.t_s, f.east_m, f.north_m, f.clock_offset_s, f.used_ids) for f in a.fixes]
        return fixes, _detections(a.frames, -10**9), [f.frame for f in a.frames]

    reference = read(10**9)
    assert len(confirmed) >= 2                              # acquisition fixes confirmed a frame later
    assert all(any(f[0] == t for f in reference[0]) for t in confirmed)
    assert len(reference[0]) >= 20
    for batch in (1, 2, 7):
        got = read(batch)
        assert got[2] == reference[2]                       # every frame once, in order
        assert got[0] == reference[0], f"batches of {batch}: {len(got[0])} fixes, whole {len(reference[0])}"
        assert got[1] == reference[1]


def test_a_resumed_cut_places_chirps_in_the_whole_walks_windows(walk_dir, whole_and_cut, tmp_path):
    """The feature windows (CIR statistics, chirp counts, SNR) of a cut on the 1 s window grid (at 20 s, as a long
    walk's cuts lie), from the resumed frame on, are the whole run's, bit for bit: a chirp goes to a window by its
    arrival less the latest fix's clock offset, and the cut resumes that offset with the receiver
    (``ReceiverState.window_clock_s``) instead of taking its own warm-up's (no fix yet: 0). On this walk a fix
    follows the resumption at once, so the windows agreed before that too; the stand-in detector below checks
    the resumed offset where no fix follows."""
    whole, _ = whole_and_cut
    walk = load_walk(walk_dir)
    site, timing, pos = _receiver_setup(walk)
    x, _ = sf.read(str(walk.path("audio")), dtype="int16")
    sf.write(tmp_path / "audio.wav", x[20 * FS:], FS, subtype="PCM_16")
    cut = analyse_audio(tmp_path / "audio.wav", site, timing, positions=pos, resume=whole.receiver_state,
                        first_sample=20 * FS)
    assert whole.receiver_state.window_clock_s != 0.0          # a clock offset was known at the resumption
    t0 = RESUME_S + 2.0                                          # windows holding nothing before the resumption
    a = [r for r in whole.rows if r["t_s"] >= t0 and r["t_s"] <= cut.rows[-1]["t_s"]]
    b = [r for r in cut.rows if r["t_s"] >= t0]
    assert len(a) >= 20 and len(a) == len(b)
    for ra, rb in zip(a, b):
        assert ra.keys() == rb.keys()
        for key in ra:
            assert ra[key] == rb[key] or (ra[key] != ra[key] and rb[key] != rb[key]), (ra["t_s"], key)


def test_window_clock_is_resumed_with_the_receiver(walk_dir, monkeypatch):
    """By hand, with a stand-in detector (frames of 1 s; the windows 2 s long, 1 s apart): the whole run's latest
    fix before frame 5 put the clock 0.3 s ahead (``window_clock_s`` = 0.3 kept at frame 5); the cut, resumed
    at frame 5, had its own warm-up fix at frame 3 with offset 0, and frames 5-7 hold one chirp each, stated
    at 5.2, 6.2 and 7.2 s, but no fix. Placed by the resumed 0.3 s they arrive at 4.9, 5.9 and 6.9 s true time:
    one chirp in each of hops 4, 5 and 6, so the windows [4, 6), [5, 7), [6, 8) count 2, 2 and 1. Placed by
    the cut's 0, hops 5, 6, 7: the window [4, 6) would count 1 and [7, 9) 1."""
    import dataclasses
    import types

    import features.acoustic.features as features
    from features.acoustic.detection import ChirpDetection, FrameResult
    from features.acoustic.tracking import ReceiverState

    walk = load_walk(walk_dir)
    site = walk.load_site()
    timing = timing_from_walk(walk, site)
    fix0 = types.SimpleNamespace(clock_offset_s=0.0)
    chirp = np.full(len(features.FEATURE_NAMES), 1.0)

    def fake_detect_frames(path, site, timing_, detector, stats, positions, resume, keep_state_from_s,
                           first_sample):
        stats.duration_s = 10.0
        stats.n_samples, stats.n_clipped, stats.sum_sq = [4800] * 100, [0] * 100, [1.0] * 100
        for k in range(3, 10):
            dets = (ChirpDetection(k, "B1", k + 0.1, k + 0.2 - timing_.start_s, 20.0, chirp, True),) \
                if 5 <= k <= 7 else ()
            yield FrameResult(k, float(k), dets, fix0 if k == 3 else None, False)

    monkeypatch.setattr(features, "detect_frames", fake_detect_frames)
    resume = ReceiverState(5, None, window_clock_s=0.3)
    a = features.analyse_audio(walk.path("audio"), site, dataclasses.replace(timing, start_s=0.0), resume=resume)
    counts = {round(r["t_s"]): r["n_chirps"] for r in a.rows}
    assert [counts[t] for t in (5, 6, 7, 8)] == [2, 2, 1, 0]
