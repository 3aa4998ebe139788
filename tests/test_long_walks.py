"""Long walks in bounded memory (issue 25 item 3): cuts, the block writer, identity on short walks, and the
peak memory of ``envfuse run`` not growing with the walk."""

import math

import numpy as np
import pytest
import soundfile as sf

from models.environment import EnvironmentClassifier
from models.fusion.model import save_fusion_model
from tests.long_walk import loop_walk, peak_rss_mib, shift_nmea_line
from training.filters import train_fusion
from walks import fuse as fuse_module
from walks.fuse import fuse_to_file, fuse_walk
from walks.inputs import window_features
from walks.reader import read_walk
from features.imu.heading import GATE_REFERENCE_S
from features.walk import load_walk
from walks.segments import TAIL_S, WARMUP_S, audio_cut_step, plan_segments, walk_cuts
from walks.track import TrackWriter, track_rows, track_text


@pytest.fixture(scope="module")
def model(walk_dir):
    from models.bp import BPConfig

    data = read_walk(walk_dir)
    t, X = window_features(data)
    clf = EnvironmentClassifier(min_samples=5).fit(X, data.truth.class_at(t - 1.0))
    return train_fusion([walk_dir], clf, bp_config=BPConfig(n_members=2, epochs=40))


@pytest.fixture(scope="module")
def model_dir(model, tmp_path_factory):
    d = tmp_path_factory.mktemp("lw_model") / "fm"
    save_fusion_model(model, d)
    return d


@pytest.fixture(scope="module")
def looped(walk_dir, tmp_path_factory):
    """The 60 s session walk looped: 3, 5 and 11 minutes."""
    d = tmp_path_factory.mktemp("looped")
    return {n: loop_walk(walk_dir, d / f"x{n}", n) for n in (3, 5, 11)}


def test_shift_nmea_line_crosses_midnight_with_a_valid_checksum():
    rmc = "$GNRMC,235959.80,A,3112.0371799,N,11848.0299802,E,0.034,,311226,,,D,V*"
    body = rmc[1:-1]
    from tests.long_walk import _checksum

    line = rmc + _checksum(body) + "\n"
    out = shift_nmea_line(line, 0.4)
    # 23:59:59.80 + 0.4 s = 00:00:00.20 the next day, 31 Dec 2026 → 1 Jan 2027; checksum by hand-free XOR
    assert out.startswith("$GNRMC,000000.20,A,") and ",010127," in out
    assert out.strip().endswith("*" + _checksum(out[1:out.rindex("*")]))
    gsv = "$GPGSV,3,1,12,03,22,300,31*7A\n"
    assert shift_nmea_line(gsv, 100.0) == gsv


def test_cuts_own_every_sample_and_line_once(looped, tmp_path):
    """Each cut holds the walk's own lines and samples of its span (warm-up and tail included); the owned
    spans tile the walk: the IMU rows owned by the segments are the file's rows, each once, in order."""
    walk = looped[3]
    n, _ = plan_segments(walk, 60.0)
    assert n == math.ceil((180.0 - TAIL_S) / 60.0) == 3
    imu_rows = (walk / "imu.csv").read_text().splitlines()[1:]
    audio, fs = sf.read(str(walk / "audio.wav"), dtype="int16")
    owned, nmea_lines = [], 0
    for seg in walk_cuts(walk, 60.0, workdir=tmp_path):
        rows = (seg.directory / "imu.csv").read_text().splitlines()[1:]
        t = np.array([float(r.split(",")[0]) for r in rows])
        lo = -math.inf if seg.index == 0 else seg.own_from_s - WARMUP_S
        hi = math.inf if seg.index == n - 1 else seg.own_to_s + TAIL_S
        if lo < audio_cut_step(fs) / fs:
            # a cut moved back to the walk's start (the first; with 60 s segments the next two too) holds the
            # heading gate's reference span, as the whole walk's read
            hi = max(hi, GATE_REFERENCE_S)
        assert t.min() >= lo and t.max() < hi
        owned += [r for r, tk in zip(rows, t) if seg.own_from_s <= tk < seg.own_to_s]
        # audio: the cut's samples are the walk's from its start_s on, sample for sample
        from features.walk import load_walk

        cut = load_walk(seg.directory)
        start = float(cut.streams["audio"]["start_s"])
        x, _ = sf.read(str(seg.directory / "audio.wav"), dtype="int16")
        a0 = round(start * fs)
        assert np.array_equal(x, audio[a0:a0 + len(x)]) and abs(a0 / fs - max(lo, 0.0)) < 1.0 / fs
        nmea_lines += sum(1 for _ in open(seg.directory / "gnss.nmea"))
    assert owned == imu_rows
    assert nmea_lines > sum(1 for _ in open(walk / "gnss.nmea"))  # overlaps repeat lines, nothing is lost


@pytest.mark.parametrize("fmt", ["csv", "geojson"])
def test_block_writer_gives_the_bytes_of_the_whole_text(model, walk_dir, tmp_path, fmt):
    fused = fuse_walk(walk_dir, model, ("adaptive_blind",), smooth=False, truth=False)
    rows = track_rows(fused.tracks["adaptive_blind+lag"], fused.inputs)
    want = track_text(rows, fmt, {"walk": "w", "method": "m"})
    for block in (1, 7, len(rows)):
        w = TrackWriter(tmp_path / f"t{block}", fmt, {"walk": "w", "method": "m"})
        for i in range(0, len(rows), block):
            w.write(rows[i:i + block])
        w.close()
        assert (tmp_path / f"t{block}").read_text() == want
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"t{b}" for b in (1, 7, len(rows)))


def test_a_walk_of_one_segment_gives_todays_track_in_any_row_block(model, walk_dir, tmp_path, monkeypatch):
    """run's streamed path on a walk that fits in one segment writes exactly what the whole-walk path
    (fuse_walk → track_rows → track_text, main's ``run`` before issue 25) writes, for any rows per write: the
    last state of each instant (:func:`walks.track.latest_per_time`)."""
    from walks.track import latest_per_time

    fused = fuse_walk(walk_dir, model, ("adaptive_blind",), smooth=False, truth=False)
    track = fused.tracks["adaptive_blind+lag"]
    want = track_text(track_rows(track.take(latest_per_time(track.t_s)), fused.inputs), "csv")
    for block in (13, 20_000):
        monkeypatch.setattr(fuse_module, "ROWS_PER_WRITE", block)
        out = tmp_path / f"b{block}.csv"
        done = fuse_to_file(walk_dir, model, "adaptive_blind+lag", out, "csv")
        assert done.segments == 1 and out.read_text() == want


def test_segments_give_the_whole_walk_track(model, looped, tmp_path, monkeypatch):
    """The 5-minute looped walk fused in 90 s segments (40 s of warm-up: cuts of at most 140 s after the first,
    which reaches the heading gate's 300 s reference span) against the same walk fused whole: every epoch at
    the same time, and positions equal to round-off where every filter and reader resumed what the previous
    segment handed over (walks/segments.py); restarted afresh at each seam instead (the state before issue 25's
    hand-over, emulated by dropping it) the segments are centimetres to metres off."""
    from walks import segments

    monkeypatch.setattr(segments, "WARMUP_S", 40.0)
    walk = looped[5]
    whole, seg = tmp_path / "whole.csv", tmp_path / "seg.csv"
    fuse_to_file(walk, model, "adaptive_blind+lag", whole, "csv", segment_s=1e6)
    done = fuse_to_file(walk, model, "adaptive_blind+lag", seg, "csv", segment_s=90.0)
    assert done.segments == 4

    def load(p):
        a = np.genfromtxt(p, delimiter=",", names=True, dtype=None, encoding="utf-8")
        return a["t_s"], a["east_m"], a["north_m"]

    ta, ea, na = load(whole)
    tb, eb, nb = load(seg)
    assert len(ta) == len(tb) and np.max(np.abs(ta - tb)) < 1e-3   # the CSV's millisecond times
    d = np.hypot(eb - ea, nb - na)
    print("segmented vs whole, m: median", np.median(d), "p95", np.percentile(d, 95), "max", np.max(d))
    assert np.max(d) < SEAM_TOLERANCE_M, np.max(d)
    # without the hand-over (each segment's filters and readers started afresh at its cut's start)
    monkeypatch.setattr(fuse_module.FusedWalk, "handover", lambda self, t_s, states_from_s: None)
    fresh = tmp_path / "fresh.csv"
    fuse_to_file(walk, model, "adaptive_blind+lag", fresh, "csv", segment_s=90.0)
    tc, ec, nc = load(fresh)
    dc = np.hypot(ec - np.interp(tc, ta, ea), nc - np.interp(tc, ta, na))
    print("restarted segments vs whole, m: median", np.median(dc), "max", np.max(dc))
    assert np.max(dc) > 100 * SEAM_TOLERANCE_M


SEAM_TOLERANCE_M = 1e-4
"""Largest distance allowed between the segmented and the whole-walk track, m (the CSV writes millimetres, so
this is "equal as written"). On the 21-minute walk of walks/segments.py's docstring the segments agree to 6.4e-8 m
at 600 s; at 300 s a round-off flip in the receiver's float32 matched filter gave 0.022 m once."""

def _segments_give_the_whole_track(walk, model, tmp_path, segment_s: float = 60.0,
                                   method: str = "adaptive_blind+lag") -> float:
    """``method`` of ``walk`` fused in ``segment_s`` segments against it fused whole: the same epochs,
    positions within :data:`SEAM_TOLERANCE_M`; returns the largest distance, m."""
    whole, seg = tmp_path / "whole.csv", tmp_path / "seg.csv"
    fuse_to_file(walk, model, method, whole, "csv", segment_s=1e6, force=True)
    fuse_to_file(walk, model, method, seg, "csv", segment_s=segment_s, force=True)
    a = np.genfromtxt(whole, delimiter=",", names=True, dtype=None, encoding="utf-8")
    b = np.genfromtxt(seg, delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert len(a) == len(b) and np.max(np.abs(a["t_s"] - b["t_s"])) < 1e-3
    d = np.hypot(a["east_m"] - b["east_m"], a["north_m"] - b["north_m"])
    assert np.max(d) < SEAM_TOLERANCE_M, np.max(d)
    return float(np.max(d))



GROWTH_BOUND_MIB = 12.0
"""Largest peak-memory growth allowed from the 5- to the 11-minute walk at 60 s segments, MiB. Both reach the
steady cut (120 s warm-up + 60 s + 10 s tail) by their third segment; measured growth 0.8 MiB (292.2 → 293.1).
Fused whole (a regression that reads the whole walk again: ``--segment-s 1e5``) the same walks grow by 24 MiB
(280.9 → 304.8, about 4 MiB per minute of walk), failing this bound."""


def test_evaluate_scores_a_long_walk_segment_by_segment_as_it_scores_it_whole(looped, model_dir):
    """evaluate's per-walk task on the 3-minute walk in 60 s segments against the same walk whole: every
    method scored, the same number of epochs within 5 %, mean errors within 10 % (the filters agree to
    round-off across the seams, but the first cut holds the whole 3 minutes here: this checks the scoring), and
    each metric row equal to the metric of its own series (hand check: mean, median, max of the errors)."""
    from pipeline.evaluate import evaluate_walk

    methods = ("gnss", "pdr", "kf_quality", "adaptive_blind")
    whole = evaluate_walk(looped[3], str(model_dir), methods, force=True, segment_s=1e6)
    seg = evaluate_walk(looped[3], str(model_dir), methods, force=True, segment_s=60.0)
    rw = {(r["method"], r["env_class"]): r for r in whole["rows"]}
    rs = {(r["method"], r["env_class"]): r for r in seg["rows"]}
    assert set(rs) == set(rw) and seg["walk"] == whole["walk"]
    for m in ("gnss", "kf_quality", "adaptive_blind", "adaptive_blind+lag"):
        a, b = rw[(m, "all")], rs[(m, "all")]
        assert abs(b["n"] - a["n"]) <= 0.05 * a["n"]
        assert b["mean_m"] == pytest.approx(a["mean_m"], rel=0.1, abs=0.01)
        err = seg["series"][m]["err_m"].astype(float)
        assert len(err) == b["n"] and np.all(np.diff(seg["series"][m]["t_s"]) >= 0)
        assert b["mean_m"] == pytest.approx(err.mean(), rel=1e-6) and b["max_m"] == pytest.approx(err.max(), rel=1e-6)
    # the GNSS fixes are the same fixes whichever way the walk is cut
    assert rs[("gnss", "all")]["n"] == rw[("gnss", "all")]["n"]
    assert rs[("gnss", "all")]["mean_m"] == pytest.approx(rw[("gnss", "all")]["mean_m"], rel=1e-9)
    assert len(seg["series"]["_truth"]["t_s"]) == len(whole["series"]["_truth"]["t_s"])


def peak_growth_mib(looped: dict, model_dir, out_dir, segment_s: float, method: str | None = None) -> float:
    """Peak memory of ``envfuse run`` (``method``: run's default) on the 11-minute walk minus that on the 5-minute
    one, MiB."""
    more = [] if method is None else ["--method", method]
    peaks = {n: peak_rss_mib(["run", str(looped[n]), "--model", str(model_dir), "--out", str(out_dir / f"{n}.csv"),
                               "--segment-s", f"{segment_s:g}", "--force"] + more) for n in (5, 11)}
    print("peaks, MiB:", peaks)
    return peaks[11] - peaks[5]


@pytest.mark.parametrize("method", [None, "adaptive_blind+rts"])
def test_peak_memory_of_run_does_not_grow_with_the_walk(looped, model_dir, tmp_path, method):
    """Would catch any stage that holds the whole walk again (GROWTH_BOUND_MIB says how it was checked); for a
    ``+rts`` track too, whose segments' filter events go to files (walks/segment_rts.py): a store that kept each
    segment's fused walk instead would grow like the whole walk's read. (The events themselves, ~1 KB each, are
    too few on these walks to show: the 8-hour bench measures them, bench/bench_pipeline.py --memory-only
    --method adaptive_blind+rts.)"""
    growth = peak_growth_mib(looped, model_dir, tmp_path, 60.0, method)
    print("peak growth 5 -> 11 min, MiB:", growth)
    assert growth < GROWTH_BOUND_MIB, growth


def test_run_of_a_long_walk_reports_its_progress_segment_by_segment(looped, model_dir, tmp_path, capsys):
    """``envfuse run`` on the 3-minute walk at 60 s segments writes one progress line per segment on stderr (a log,
    not a terminal: plain lines, one per tenth of the work), the last at 3/3; the walk fused whole writes none."""
    from pipeline.cli import main

    assert main(["run", str(looped[3]), "--model", str(model_dir), "--out", str(tmp_path / "seg.csv"),
                 "--segment-s", "60", "--force"]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("run x3:")]
    assert lines == ["run x3: 1/3 segments (33 %)", "run x3: 2/3 segments (67 %)", "run x3: 3/3 segments (100 %)"]
    assert main(["run", str(looped[3]), "--model", str(model_dir), "--out", str(tmp_path / "whole.csv"),
                 "--segment-s", "1000", "--force"]) == 0
    assert "segments (" not in capsys.readouterr().err


@pytest.mark.parametrize("workers", [1, 2])
def test_evaluate_of_long_walks_reports_its_progress_segment_by_segment(looped, model_dir, tmp_path, capsys, workers):
    """``envfuse evaluate`` of the 3- and 5-minute walks at 60 s segments tells each walk's segments as they are
    scored (a log: one line at each tenth of a walk, here every segment) beside the walks finished; from Dask's
    worker processes too (``--workers 2``: the workers' events reach this process through the scheduler, each
    before its walk's result). A walk of one segment tells no segments."""
    from pipeline.cli import main
    from pipeline.parallel import task_progress

    task_progress(1, 2)          # outside a task: nothing, no error
    assert main(["evaluate", str(looped[3]), str(looped[5]), "--model", str(model_dir), "--report",
                 str(tmp_path / "rep"), "--methods", "kf_quality", "--segment-s", "60", "--workers", str(workers),
                 "--no-plots"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("evaluate:")]
    x3 = [f"evaluate: x3: {k}/3 segments ({100 * k / 3:.0f} %)" for k in (1, 2, 3)]
    x5 = [f"evaluate: x5: {k}/5 segments ({20 * k} %)" for k in range(1, 6)]
    assert sorted(lines) == sorted(x3 + x5 + ["evaluate: 1/2 walks (50 %)", "evaluate: 2/2 walks (100 %)"])
    for walk in (x3, x5):           # each walk's segments in order, all before the last walk finished
        at = [lines.index(line) for line in walk]
        assert at == sorted(at) and at[-1] < lines.index("evaluate: 2/2 walks (100 %)")
    if workers == 1:                # serially: the walks one after the other, in input order
        assert lines == x3 + ["evaluate: 1/2 walks (50 %)"] + x5 + ["evaluate: 2/2 walks (100 %)"]
    assert main(["evaluate", str(looped[3]), "--model", str(model_dir), "--report", str(tmp_path / "rep1"),
                 "--methods", "kf_quality", "--workers", "1", "--no-plots"]) == 0
    assert "segments (" not in capsys.readouterr().err


@pytest.fixture(scope="module")
def midnight_walk(site_dir, tmp_path_factory):
    """A 150 s walk on the session's site that starts at 23:59:00 UTC: it crosses midnight 60 s in (a morning
    shift in China, UTC+8, that starts before 08:00)."""
    from datetime import datetime, timezone

    from simulation.walk import simulate_walk

    return simulate_walk(site_dir, tmp_path_factory.mktemp("midnight") / "w11", seed=11, duration_s=150.0,
                         start_utc=datetime(2026, 8, 4, 23, 59, 0, tzinfo=timezone.utc), progress=False)


def test_cuts_of_a_walk_across_midnight_hold_their_own_nmea(midnight_walk, tmp_path):
    """Each 60 s cut of the walk across midnight holds the NMEA epochs of its own span and only those, as the
    reader places them on the walk's time base (from the RMC dates): each segment's own epochs, and together the
    whole walk's. Would catch a midnight counted twice (the cutter's bug until 2026-12-03: every
    epoch after midnight was put a day late, so the cuts after it held no NMEA and the last one all of it)."""
    from features.walk import load_walk
    from walks.reader import placed_nmea_epochs

    def epoch_times(walk):              # as the reader places them (read_gnss_stream)
        return placed_nmea_epochs(load_walk(walk))[0].col("t_s")

    whole = epoch_times(midnight_walk)
    assert whole.min() < 60.0 < whole.max()                 # the walk's own epochs run through midnight
    n, _ = plan_segments(midnight_walk, 60.0)
    held = []
    for seg in walk_cuts(midnight_walk, 60.0, workdir=tmp_path):
        t = epoch_times(seg.directory)
        owned = whole[seg.owns(whole)]
        span = min(seg.own_to_s, whole.max()) - max(seg.own_from_s, 0.0)
        assert len(owned) > 0.9 * 5.0 * span, (seg.index, len(owned))    # 5 Hz
        mine = t[seg.owns(t)]
        assert np.array_equal(mine, owned), (seg.index, len(mine), len(owned))
        assert t.max() <= whole.max()                       # nothing a day late
        held.append(mine)
    assert len(held) == n == 3 and np.array_equal(np.concatenate(held), whole)


def test_a_walk_across_midnight_in_segments_gives_its_whole_track(model, midnight_walk, tmp_path):
    """The walk across midnight fused in 60 s segments gives the whole walk's track, through midnight too (the
    cut after it once had no GNSS at all)."""
    assert plan_segments(midnight_walk, 60.0)[0] == 3
    print("across midnight, segmented vs whole, m: max", _segments_give_the_whole_track(midnight_walk, model, tmp_path))


def test_nmea_cutter_places_a_day_long_log_without_drift(tmp_path):
    """The NMEA cutter's walk time of each of 450,000 sentences at 5 Hz over 25 h from 22:20 UTC (midnight
    crossed twice): the exact time since the start (the decimal k/5 s), to the rounding of one subtraction,
    however long the log; the sentences at each 300 s boundary on or after it (a cut starts at them). Would catch
    a midnight counted twice (a day late after it) and walk times summed from sentence to sentence (their
    round-off accumulates: one epoch in a 4-hour walk's last cut changed sides)."""
    from types import SimpleNamespace
    from datetime import datetime, timezone

    from walks.segments import _NmeaCutter

    n = 25 * 3600 * 5
    start = datetime(2026, 8, 4, 22, 20, 0, tzinfo=timezone.utc)
    path = tmp_path / "gnss.nmea"
    with open(path, "w") as f:
        for k in range(n):
            tod = (80400 * 5 + k) % (86400 * 5)                  # fifths of a second
            f.write(f"$GPGGA,{tod // 18000:02d}{tod // 300 % 60:02d}{tod % 300 / 5:05.2f},0,N*00\n")
    cutter = _NmeaCutter(path, SimpleNamespace(start_utc=start))
    with open(path, "rb") as lines:
        t = np.array([cutter.line_time(line, -math.inf) for line in lines])
    exact = np.arange(n) / 5.0
    assert np.max(np.abs(t - exact)) < 2e-11 * 86400, np.max(np.abs(t - exact))  # ~1 ulp of a day's seconds
    at_boundary = np.arange(0, n, 1500)                                # every 300 s
    assert np.all(t[at_boundary] >= exact[at_boundary]) and t[-1] > 86400.0
    cutter.close()


@pytest.fixture(scope="module")
def garbled_walk(midnight_walk, tmp_path_factory):
    """The walk across midnight with two single-line defects of real logs: the GGA at 00:00:40 UTC (walk time
    100 s) with its hour 00 turned 01 and its checksum left as it was (a corrupted sentence, which the reader
    refuses), and the IMU row at 70 s with 1,000 s added to its ``t_s`` (a garbled time, which the IMU reader
    repairs)."""
    import shutil

    d = tmp_path_factory.mktemp("garbled") / "w11g"
    shutil.copytree(midnight_walk, d)
    nmea = (d / "gnss.nmea").read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(nmea) if line[3:7] == "GGA," and line[7:13] == "000040")
    nmea[k] = nmea[k][:7] + "01" + nmea[k][9:]
    (d / "gnss.nmea").write_text("".join(nmea))
    imu = (d / "imu.csv").read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(imu[1:], 1) if float(line.split(",", 1)[0]) >= 70.0)
    t, rest = imu[k].split(",", 1)
    imu[k] = f"{float(t) + 1000.0:.2f},{rest}"
    (d / "imu.csv").write_text("".join(imu))
    return d


def test_one_garbled_line_does_not_end_a_stream_in_the_later_cuts(garbled_walk, tmp_path):
    """Each 60 s cut of the garbled walk holds the NMEA epochs and IMU rows the whole walk's readers place in its
    span. A line whose time runs past its cut's end while the lines after it do not is one line out of place:
    it goes with the line before it (the cut's reader refuses or repairs it as the whole walk's does). Until
    2026-12-03 such a line ended its cut, and every later cut at its first line (each resumed there): the GGA at
    100 s took every GNSS epoch from 100 s on from the segments, the IMU row at 70 s every IMU row from 70 s on."""
    from features.walk import load_walk
    from walks.reader import placed_nmea_epochs

    def epoch_times(walk):
        return placed_nmea_epochs(load_walk(walk))[0].col("t_s")

    def imu_rows(walk):                 # the rows as written, each with its stated t_s
        lines = (walk / "imu.csv").read_text().splitlines()[1:]
        return lines, np.array([float(line.split(",", 1)[0]) for line in lines])

    g_whole = epoch_times(garbled_walk)
    i_whole, t_whole = imu_rows(garbled_walk)
    garbled = i_whole[int(np.argmax(t_whole))]
    assert g_whole.max() > 140.0 and t_whole[-1] > 140.0 and float(garbled.split(",")[0]) > 1000.0
    g_held, i_held = [], []
    for seg in walk_cuts(garbled_walk, 60.0, workdir=tmp_path):
        g = epoch_times(seg.directory)
        g_held.append(g[seg.owns(g)])
        assert np.array_equal(g_held[-1], g_whole[seg.owns(g_whole)]), (seg.index, len(g_held[-1]))
        lines, t = imu_rows(seg.directory)
        mine = [line for line, ti in zip(lines, t) if seg.owns(np.array([ti]))[0] and line != garbled]
        assert mine == [line for line, ti in zip(i_whole, t_whole)
                        if seg.owns(np.array([ti]))[0] and line != garbled], seg.index
        i_held += mine
        # the garbled row reaches the reader of every cut that holds rows on both sides of it (70 s)
        fine = t[t < 1000.0]
        assert (garbled in lines) == (fine.min() < 70.0 < fine.max()), seg.index
    assert np.array_equal(np.concatenate(g_held), g_whole)
    assert i_held == [line for line in i_whole if line != garbled]


def test_a_garbled_walk_in_segments_gives_its_whole_track(model, garbled_walk, tmp_path):
    _segments_give_the_whole_track(garbled_walk, model, tmp_path)


def test_a_line_cutter_ends_a_cut_only_where_the_lines_after_confirm_it(tmp_path):
    """A CSV of t_s 0, 0.1, … 9.9 s with row 30 garbled to 1003.0: cut [0, 5) holds rows 0-49 (the garbled one
    with them, where the reader meets it), cut [4, 10) rows 40-99; a stream that really jumps past the end
    (rows from 5 s on shifted by 100 s) ends the first cut at its jump, and the second cut gets nothing before
    its end. Each of those two cuts ends in the jump's hole and so holds the two rows after it (an IMU's: the
    reader fills the hole between them as the whole file's read does)."""
    from walks.segments import _CsvCutter

    def cut(rows, spans):
        p = tmp_path / "imu.csv"
        p.write_text("t_s,x\n" + "".join(f"{t:.1f},{k}\n" for k, t in enumerate(rows)))
        c = _CsvCutter(p, "imu")
        out = []
        for k, (lo, hi, next_lo) in enumerate(spans):
            d = tmp_path / f"c{k}"
            d.mkdir(exist_ok=True)
            c.write(d, lo, hi, next_lo)
            out.append([int(line.split(",")[1]) for line in (d / "imu.csv").read_text().splitlines()[1:]])
        c.close()
        return out

    t = np.arange(100) / 10.0
    garbled = t.copy()
    garbled[30] = 1003.0
    first, second = cut(garbled, [(0.0, 5.0, 4.0), (4.0, 10.0, 10.0)])
    assert first == list(range(50)) and second == list(range(40, 100))
    jumped = np.where(t >= 5.0, t + 100.0, t)
    first, second = cut(jumped, [(0.0, 5.0, 4.0), (4.0, 10.0, 10.0)])
    assert first == list(range(52)) and second == list(range(40, 52))


def test_line_cutters_read_what_the_readers_read(tmp_path):
    """Cuts of files the readers take as they are: an IMU CSV whose ``t_s`` is not its first column (the reader
    finds it by name), one whose lines end in CR alone, and NMEA sentences behind a logger's time stamp. Each
    cut [0, 5) / [4, 10) holds the rows of its span; before, the first file's rows were cut by ``ax`` (the first
    cut took every row, the second none), the CR file went whole into the first cut as one line, and the
    prefixed NMEA all into the first cut."""
    from datetime import datetime, timezone
    from types import SimpleNamespace

    from walks.segments import _CsvCutter, _NmeaCutter

    def cut(cutter, name, spans):
        out = []
        for k, (lo, hi, next_lo) in enumerate(spans):
            d = tmp_path / f"{name}{k}"
            d.mkdir()
            cutter.write(d, lo, hi, next_lo)
            out.append((d / cutter.path.name).read_bytes())
        cutter.close()
        return out

    spans = [(0.0, 5.0, 4.0), (4.0, 10.0, 10.0)]
    t = np.arange(100) / 10.0
    (tmp_path / "a").mkdir()
    p = tmp_path / "a" / "imu.csv"
    p.write_text("ax,T_S ,gz\n" + "".join(f"{9.8 - k},{ti:.1f},{k}\n" for k, ti in enumerate(t)))
    first, second = cut(_CsvCutter(p, "imu"), "a", spans)
    assert [int(r.split(b",")[2]) for r in first.splitlines()[1:]] == list(range(50))
    assert [int(r.split(b",")[2]) for r in second.splitlines()[1:]] == list(range(40, 100))
    (tmp_path / "b").mkdir()
    p = tmp_path / "b" / "imu.csv"
    p.write_bytes(b"t_s,x\r" + b"".join(f"{ti:.1f},{k}\r".encode() for k, ti in enumerate(t)))
    first, second = cut(_CsvCutter(p, "imu"), "b", spans)
    assert first == b"t_s,x\r" + b"".join(f"{ti:.1f},{k}\r".encode() for k, ti in enumerate(t[:50]))
    assert second == b"t_s,x\r" + b"".join(f"{t[k]:.1f},{k}\r".encode() for k in range(40, 100))
    (tmp_path / "c").mkdir()
    p = tmp_path / "c" / "gnss.nmea"
    p.write_text("".join(f"{ti:.3f} $GPGGA,1200{ti:05.2f},0,N*00\n" for ti in t))
    start = SimpleNamespace(start_utc=datetime(2026, 8, 4, 12, 0, 0, tzinfo=timezone.utc))
    first, second = cut(_NmeaCutter(p, start), "c", spans)
    assert len(first.splitlines()) == 50 and len(second.splitlines()) == 60
    assert second.splitlines()[0].startswith(b"4.000 $GPGGA,120004.00")


def _edit_rmc(walk, out, edit):
    """A copy of ``walk`` whose RMC sentences pass through ``edit(walk time, fields) -> fields or None`` (None:
    the sentence dropped), their checksums made good."""
    import shutil

    from tests.long_walk import _checksum

    shutil.copytree(walk, out)
    start = load_walk(walk).start_utc
    start_tod = start.hour * 3600 + start.minute * 60 + start.second
    lines = []
    for line in (out / "gnss.nmea").read_text().splitlines(keepends=True):
        if line[3:7] == "RMC,":
            f = line[1:line.rindex("*")].split(",")
            tod = int(f[1][0:2]) * 3600 + int(f[1][2:4]) * 60 + float(f[1][4:])
            f = edit((tod - start_tod) % 86400.0, f)
            if f is None:
                continue
            body = ",".join(f)
            line = f"${body}*{_checksum(body)}\n"
        lines.append(line)
    (out / "gnss.nmea").write_text("".join(lines))
    return out


def _cut_epochs_are_the_whole_walks(walk, tmp_path, segment_s=60.0):
    from walks.reader import placed_nmea_epochs

    def epoch_times(w):
        return placed_nmea_epochs(load_walk(w))[0].col("t_s")

    whole = epoch_times(walk)
    held = []
    for seg in walk_cuts(walk, segment_s, workdir=tmp_path):
        t = epoch_times(seg.directory)
        held.append(t[seg.owns(t)])
        assert np.array_equal(held[-1], whole[seg.owns(whole)]), (seg.index, len(held[-1]), t[:2])
    assert np.array_equal(np.concatenate(held), whole)
    return whole


@pytest.mark.parametrize("defect", ["cold_start_dates", "rmc_stops"])
def test_cuts_place_the_nmea_as_the_whole_walks_reader_does(midnight_walk, tmp_path, defect):
    """The walk across midnight with a cold start's bogus RMC date (1980-01-06, the GPS epoch a receiver
    reports before it decodes the real one) from 40 to 90 s: a third of the walk, so the whole walk's median
    date is right, but most of the 60-130 s cut's dates (40-130 s); or with its RMC, its only dated sentence,
    gone after 50 s (a logger set to drop it). Each cut's epochs lie where the whole walk's reader puts them:
    the cut is placed by its times of day and the whole log's date offset. Before, by its own dates' median: the
    first defect put the second cut's epochs 46 years early, the second left the later cuts without a date, so
    fused without GNSS."""
    if defect == "cold_start_dates":
        walk = _edit_rmc(midnight_walk, tmp_path / "w", lambda t, f: f[:9] + ["060180"] + f[10:]
                         if 40.0 <= t < 90.0 else f)
    else:
        walk = _edit_rmc(midnight_walk, tmp_path / "w", lambda t, f: f if t < 50.0 else None)
    whole = _cut_epochs_are_the_whole_walks(walk, tmp_path)
    assert 0.0 <= whole[0] < 0.5 and 149.0 < whole[-1] <= 150.0 and len(whole) > 0.99 * 5 * 150


def test_the_log_date_offset_is_the_readers_median_of_its_epochs(tmp_path):
    """The cutter's one pass over a log: each epoch weighed once with the date it carries on (a dated sentence
    sets it for its epoch and the epochs after), the median_low of (date - start's date - the days unwrapped)
    x 86,400 s over them. 10 epochs at 1 Hz from 23:59:55 UTC: RMC in epochs 0-3 (two of them with the bogus
    1980 date), none after; the epochs after midnight carry 4 Aug + 0 days, the same date as 5 Aug + 1 day.
    Offsets: epochs 0, 2 bogus (1980-01-06 less 2026-08-04, x 86,400 s); 1 and 3-9 good (0): the median_low of
    10 values is the 5th smallest, 0. A bad checksum sets nothing: epoch 3's good date refused, epoch 2's bogus
    one carries on to epoch 9, and the median is bogus, as with bogus dates in epochs 0 and 2-4."""
    from datetime import datetime, timezone
    from types import SimpleNamespace

    from tests.long_walk import _checksum
    from walks.segments import _NmeaCutter

    def log(dates, bad=()):
        lines = []
        for k in range(10):
            tod = (86395 + k) % 86400
            hhmmss = f"{tod // 3600:02d}{tod // 60 % 60:02d}{tod % 60:02d}.00"
            gga = f"GPGGA,{hhmmss},3112.0,N,11848.0,E,1,08,1.0,20.0,M,0.0,M,,"
            lines.append(f"${gga}*{_checksum(gga)}\n")
            if k < len(dates):
                rmc = f"GPRMC,{hhmmss},A,3112.0,N,11848.0,E,0.0,,{dates[k]},,,A"
                lines.append(f"${rmc}*{'00' if k in bad else _checksum(rmc)}\n")
        p = tmp_path / "gnss.nmea"
        p.write_text("".join(lines))
        c = _NmeaCutter(p, SimpleNamespace(start_utc=datetime(2026, 8, 4, 23, 59, 55, tzinfo=timezone.utc)))
        c.close()
        return c.date_offset_s

    bogus = (datetime(1980, 1, 6).toordinal() - datetime(2026, 8, 4).toordinal()) * 86400.0
    assert log(["040826", "040826", "040826", "040826"]) == 0.0
    assert log(["060180", "040826", "060180", "040826"]) == 0.0
    assert log(["060180", "040826", "060180", "040826"], bad={3}) == bogus     # epoch 2's date carried on to 9
    assert log(["060180", "040826", "060180", "060180", "060180"]) == bogus
    assert log([]) is None


def test_an_imu_hole_across_a_seam_gives_the_whole_walks_track(model, midnight_walk, tmp_path):
    """The walk across midnight without IMU rows from 112 to 132 s (a logger's hole across the 120 s seam of 60 s
    segments). The 60-120 s segment's cut (40-130 s) ends in the hole: it holds the two rows after it, so its
    reader fills the hole as the whole walk's does, its record runs to the cut's end, and it hands the whole
    walk's filters over. Before, its record ended at its last sample and the tracks parted (on a 700 s walk by
    up to 5.2 m for the next segment). (The whole walk then stood through the hole; a hole is no stop now.)"""
    import shutil

    walk = tmp_path / "w"
    shutil.copytree(midnight_walk, walk)
    lines = (walk / "imu.csv").read_text().splitlines(keepends=True)
    (walk / "imu.csv").write_text("".join(lines[:1] + [line for line in lines[1:]
                                                      if not 112.0 <= float(line.split(",", 1)[0]) < 132.0]))
    _segments_give_the_whole_track(walk, model, tmp_path)


def test_a_break_of_ten_minutes_in_the_imu_log_keeps_the_walks_pdr(model, looped, tmp_path):
    """The 11-minute looped walk without IMU rows from 25 to 640 s (615 s: a logger paused over a break). Whole,
    the walk is read with its PDR, steps before the hole and after it and none inside; in 300 s segments (``run``'s
    default), the track is the whole walk's. Before 2026-12-03 the reader refused any IMU record with a gap past
    600 s: the whole walk lost its PDR (a note, no step at all), while the segments away from the hole kept theirs
    and the two tracks parted."""
    walk = _silenced(looped[11], tmp_path / "w", 25.0, 640.0, streams=("imu",))
    data = read_walk(walk)
    assert data.pdr is not None, data.notes
    steps = data.pdr.result.t_s
    assert np.sum(steps < 25.0) >= 10 and np.sum(steps >= 640.0) >= 10
    assert not np.any((steps > 26.0) & (steps < 640.0))
    _segments_give_the_whole_track(walk, model, tmp_path, segment_s=300.0)


def test_a_cuts_keys_in_a_walk_toml_are_numbers_or_one_clear_error(midnight_walk, tmp_path):
    """The keys a long walk's cut writes into its walk.toml (``[gnss] cut_from_s``, ``date_offset_s``, ``[imu]
    cut_to_s``), found in a walk with a value that is not a number: one error naming the file and key, not a
    traceback; ``date_offset_s`` without ``cut_from_s`` is not a cut's and the walk is placed by its dates."""
    import re
    import shutil

    from features.errors import EnvfuseError
    from walks.inputs import walk_inputs
    from walks.reader import placed_nmea_epochs

    walk = tmp_path / "w"
    shutil.copytree(midnight_walk, walk)
    toml = (walk / "walk.toml").read_text()
    whole = placed_nmea_epochs(load_walk(midnight_walk))[0].col("t_s")
    (walk / "walk.toml").write_text(re.sub(r"^\[gnss\]$", "[gnss]\ndate_offset_s = 86400.0", toml, flags=re.M))
    assert np.array_equal(placed_nmea_epochs(load_walk(walk))[0].col("t_s"), whole)
    (walk / "walk.toml").write_text(re.sub(r"^\[gnss\]$", '[gnss]\ndate_offset_s = "a day"\ncut_from_s = 0.0',
                                           toml, flags=re.M))
    with pytest.raises(EnvfuseError, match=r"\[gnss\] date_offset_s must be a number, got 'a day'"):
        placed_nmea_epochs(load_walk(walk))
    (walk / "walk.toml").write_text(re.sub(r"^\[imu\]$", '[imu]\ncut_to_s = "end"', toml, flags=re.M))
    with pytest.raises(EnvfuseError, match=r"\[imu\] cut_to_s must be a number, got 'end'"):
        walk_inputs(read_walk(walk), None)


def _silenced(walk, out, lo_s: float, hi_s: float, streams=("gnss", "imu", "uwb", "imu_foot", "audio")):
    """A copy of ``walk`` with ``streams`` silent over walk times [lo_s, hi_s): no NMEA epoch, IMU, UWB or foot-IMU
    row there, and the audio's samples zero (a logger paused, a phone in a pocket against a steel door)."""
    import shutil
    from datetime import datetime

    shutil.copytree(walk, out)
    for name in ("imu", "uwb", "imu_foot"):
        p = out / f"{name}.csv"
        if name in streams and p.exists():
            lines = p.read_text().splitlines(keepends=True)
            p.write_text("".join(lines[:1] + [r for r in lines[1:] if not lo_s <= float(r.split(",", 1)[0]) < hi_s]))
    if "gnss" in streams:
        start = load_walk(out).start_utc
        t0 = start.hour * 3600 + start.minute * 60 + start.second
        keep = []
        for line in (out / "gnss.nmea").read_text().splitlines(keepends=True):
            f = line.split(",")
            if len(f) > 1 and len(f[1]) >= 6 and f[1][:6].isdigit():
                t = (int(f[1][:2]) * 3600 + int(f[1][2:4]) * 60 + float(f[1][4:]) - t0) % 86400.0
                if lo_s <= t < hi_s:
                    continue
            keep.append(line)
        (out / "gnss.nmea").write_text("".join(keep))
    if "audio" in streams:
        a, fs = sf.read(str(out / "audio.wav"), dtype="int16")
        a[int(lo_s * fs):int(hi_s * fs)] = 0
        sf.write(str(out / "audio.wav"), a, fs, subtype="PCM_16")
    return out


@pytest.fixture(scope="module")
def silent_walk(midnight_walk, tmp_path_factory):
    """The walk across midnight with every stream silent from 30 to 78 s: 48 s, across the 60 s seam of 60 s
    segments and longer than the warm-up, so the 60-120 s segment's cut (40-130 s) holds no event before 78 s."""
    return _silenced(midnight_walk, tmp_path_factory.mktemp("silent") / "w11s", 30.0, 78.0)


@pytest.mark.parametrize("method", ["adaptive_blind+lag", "adaptive", "imm"])
def test_a_walk_silent_across_a_seam_in_segments_gives_its_whole_track(model, silent_walk, tmp_path, method):
    """Every stream silent for 48 s across a seam: the segments give the whole walk's track (measured 2.7e-7 m
    on a 200 s walk of the same site). Before, the cut's first event took Δt = 0 and no standing time, its IMU
    record began after the hole and the heading filter resumed on another branch (π off), the GNSS windows
    that reach back over the silence to its first epoch were missing and the class in force before them was
    the prior: 9.6 m off (``adaptive_blind``) on that walk, 0.26 m (``adaptive``)."""
    _segments_give_the_whole_track(silent_walk, model, tmp_path, method=method)


def test_an_imu_cut_starting_in_a_hole_holds_the_rows_around_it(midnight_walk, tmp_path):
    """The IMU without rows from 95 to 135 s, across the 100 s start of the last segment's cut (60 s segments)
    and the 130 s end of the one before: the last cut holds the two rows before the hole (94.98, 94.99 s), so its
    reader fills the hole as the whole walk's does (the samples of both reads agree), and the cut before holds
    the two rows after it (135.00, 135.01 s). One row alone would be taken for a garbled time by the reader and
    dropped; none, and the cut's heading filter would resume 40 s late."""
    from walks.reader import read_walk as read

    walk = _silenced(midnight_walk, tmp_path / "w", 95.0, 135.0, streams=("imu",))
    whole = read(walk, truth=False).pdr.imu
    rows = {}
    for seg in walk_cuts(walk, 60.0, workdir=tmp_path):
        t = [float(r.split(",", 1)[0]) for r in (seg.directory / "imu.csv").read_text().splitlines()[1:]]
        rows[seg.index] = t
        if seg.index == 2:
            assert t[:3] == [94.98, 94.99, 135.0]
            imu = read(seg.directory, truth=False).pdr.imu
            i0 = int(np.searchsorted(whole.t_s, imu.t_s[0] - 1e-6))
            n = len(imu.t_s)
            np.testing.assert_allclose(imu.t_s, whole.t_s[i0:i0 + n], atol=1e-9)
            np.testing.assert_allclose(imu.acc_m_s2, whole.acc_m_s2[i0:i0 + n], atol=1e-6)
            assert not imu.valid[2:3990].any() and imu.valid[4010:].all()
    assert rows[1][-3:] == [94.99, 135.0, 135.01]


def test_a_segment_silent_throughout_hands_on_and_the_walk_runs_to_its_end(model, midnight_walk, tmp_path):
    """Every stream silent from 30 to 140 s: the 60-120 s segment's cut (40-130 s) holds no event (nor, but for
    the two IMU rows either side of the hole, any row). ``run`` goes on past it with a note, the segment handing
    on what it was handed, and gives the whole walk's track (the whole walk has no epoch there either). Before,
    ``run`` stopped with "no events" at that segment and ``evaluate`` skipped the walk; its scores are now the
    whole walk's."""
    walk = _silenced(midnight_walk, tmp_path / "w", 30.0, 140.0)
    _segments_give_the_whole_track(walk, model, tmp_path)
    done = fuse_to_file(walk, model, "adaptive", tmp_path / "a.csv", "csv", segment_s=60.0, force=True)
    assert done.segments == 3 and not done.skipped and done.n > 0
    assert any("walk times 60-120 s: no event in any stream" in n for n in done.notes)
    _segments_score_as_whole(walk, model, ("adaptive_blind", "imm"))


def _segments_score_as_whole(walk, model, methods) -> dict:
    """evaluate's result of ``walk`` in 60 s segments, its metric rows those of the walk evaluated whole
    (relative 1e-6: the segmented filters agree to 1e-7 m); returns the segmented result."""
    from pipeline.evaluate_segments import evaluate_segmented

    res = evaluate_segmented(walk, model, methods, None, True, "w", segment_s=60.0)
    whole = evaluate_segmented(walk, model, methods, None, True, "w", segment_s=1e6)
    assert len(res["rows"]) == len(whole["rows"]) > 0
    for a, b in zip(res["rows"], whole["rows"]):
        assert a.keys() == b.keys()
        for k, v in a.items():
            if isinstance(v, float):
                assert v == pytest.approx(b[k], rel=1e-6, abs=1e-9, nan_ok=True), k
            else:
                assert v == b[k], k
    return res


@pytest.mark.parametrize("keep", ["hole", "short"])
def test_evaluate_in_segments_scores_a_walk_whose_truth_has_a_hole_or_ends_early(model, midnight_walk, tmp_path,
                                                                                 keep):
    """truth.csv without rows from 35 to 135 s ("hole": the 60-120 s segment's cut, 40-130 s, lies inside it), or
    ending at 35 s ("short": two cuts hold none of it): ``evaluate`` in 60 s segments scores the walk as it
    scores it whole (the whole walk interpolates its truth across the hole and scores nothing past its end).
    Each cut holds the truth's two rows either side of it; a cut with fewer than two is read without truth and
    its epochs are not scored, with a note. Before, ``evaluate`` skipped the walk ("truth.csv: has the columns
    but no rows")."""
    import shutil

    walk = tmp_path / "w"
    shutil.copytree(midnight_walk, walk)
    lines = (walk / "truth.csv").read_text().splitlines(keepends=True)
    t = [float(r.split(",", 1)[0]) for r in lines[1:]]
    cut = (lambda x: 35.0 <= x < 135.0) if keep == "hole" else (lambda x: x >= 35.0)
    (walk / "truth.csv").write_text("".join(lines[:1] + [r for r, x in zip(lines[1:], t) if not cut(x)]))
    res = _segments_score_as_whole(walk, model, ("adaptive_blind", "kf_quality"))   # (+rts and +lag tracks too)
    assert any("no truth there" in n for n in res["notes"]) == (keep == "short")


def test_a_walker_walking_through_an_imu_hole_is_not_held_still(model, midnight_walk, tmp_path, monkeypatch):
    """The walk across midnight without IMU rows from 30 to 78 s while the walker walks (GNSS and the beacons
    go on): ``kf_quality`` and ``imm`` follow the fixes through the hole (the hole is no stop: walking process
    noise), their mean error there under 3 m and less than half what they reach when the hole is taken for a
    stop, as before (measured on a 200 s walk of the same site: kf_quality 15.9 → 1.5 m, imm 25.7 → 0.32 m)."""
    from walks import inputs as walk_inputs_module

    walk = _silenced(midnight_walk, tmp_path / "w", 30.0, 78.0, streams=("imu",))

    def hole_errors():
        fused = fuse_walk(walk, model, ("kf_quality", "imm"), smooth=False, lag_s=None)
        truth = fused.data.truth
        out = {}
        for m in ("kf_quality", "imm"):
            tr = fused.tracks[m]
            k = (tr.t_s >= 31.0) & (tr.t_s < 78.0)
            te, tn = truth.at(tr.t_s[k])
            out[m] = float(np.mean(np.hypot(tr.east_m[k] - te, tr.north_m[k] - tn)))
        return out

    truth = read_walk(walk).truth
    k = (truth.t_s >= 30.0) & (truth.t_s < 78.0)
    assert np.hypot(*np.diff(np.c_[truth.east_m[k], truth.north_m[k]], axis=0).T).sum() > 20.0   # walking
    now = hole_errors()
    monkeypatch.setattr(walk_inputs_module, "_imu_holes", lambda imu: (np.zeros(0), np.zeros(0)))
    before = hole_errors()
    print("mean error in the hole, m: now", now, "taken for a stop", before)
    for m in now:
        assert now[m] < 3.0 and now[m] < 0.5 * before[m], (m, now[m], before[m])
