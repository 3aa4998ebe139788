"""A long walk in segments: each cut to the files a device rotating its logs would have written, fused alone,
and each resuming what the previous one's filters and readers reached, so the segments give the whole walk's
track.

A whole-walk read grows with the walk (about 12 MiB of peak memory per minute on a simulated walk, 2.7 GiB
projected for 8 hours: ``bench/bench_pipeline.py --memory-only``): the filters keep every event's state for the
BP network's second pass and the smoothers, the readers every sample. So a walk longer than one segment is fused
segment by segment:

- segment *k* owns the walk times [k·S, (k+1)·S) (``segment_s`` S, default :data:`SEGMENT_S`); the first one
  owns everything before S, the last everything after its start;
- its files are cut from the walk's by time, streaming (a line or an audio block at a time, never a whole
  file): NMEA sentences by the epoch they belong to (placed on the walk's time base from ``start_utc`` and the
  times of day, midnight crossings counted), IMU, UWB, foot-IMU and truth CSV rows by ``t_s``, audio samples by
  ``[audio] start_s`` (the cut's ``start_s`` moved to its first sample, so the TDMA frame phase is unchanged);
  the cut reaches :data:`WARMUP_S` before the segment (:data:`FRESH_WARMUP_S` when a method fused starts
  afresh on each cut, :func:`walks.fuse.warmup_for`), moved back to a whole second of the audio
  (:func:`audio_cut_step`; 32 s, :func:`audio_cut_period`, for audio at another rate than 48 kHz), and
  :data:`TAIL_S` after it (the fixed-lag smoother's 3 s, a
  step's split at the next fix, the last feature window); the first cut reaches at least the heading gate's
  reference span (:data:`features.imu.heading.GATE_REFERENCE_S`);
- the cutters read what the readers read: a CSV's ``t_s`` found by name, lines ending in CR alone, a logger's
  prefix before each sentence; a line whose time runs past its cut's end while the lines after it do not (a
  garbled time) goes with the line before it (:data:`LOOKAHEAD_LINES`); every cut's NMEA is placed by its
  times of day and the whole log's date offset, found in one pass before the first cut (``[gnss]
  date_offset_s``, ``cut_from_s``: :func:`walks.reader.placed_nmea_epochs`), not by the cut's own dates; and a
  cut's IMU record runs to the cut's end (``[imu] cut_to_s``), so a hole across its end stands as in the whole
  walk (:func:`walks.inputs._stands`); an IMU cut whose start or end lies in a hole of the log holds the
  :data:`BRACKET_ROWS` rows either side of it, so that its reader fills the hole as the whole walk's does (the
  truth's cut always holds them, for its interpolation), and a cut with fewer than two rows of truth has none;
- the cut is fused by the pipeline (:func:`walks.fuse.fuse_walk`) with what the previous segment handed over
  (:meth:`walks.fuse.FusedWalk.handover`), and only the segment's own epochs are kept:

  * every filter resumes at the segment's first event from what it carried after the last event before it
    (:class:`models.fusion.ekf.FilterResume`): the EKFs (``kf``, ``kf_quality``, ``kf_map``, the ``adaptive``
    family and both passes of the BP ones) their posterior x, P (bias states included); ``aekf`` also its
    variational-Bayes noise estimate α, β; ``imm`` its modes' x, P and their probabilities; the UWB/PDR filters
    (``uwb_aoa_pdr`` and its twins) their corrected position, P and count of fixes gated in a row, on the cut's
    own PDR increments. The cut's earlier events are the warm-up, so the per-event quantities derived from
    their neighbours (time since the previous event, standing time, the GNSS bias resets on a quality change
    or a gap) are the whole walk's; a cut whose walker stands from its start (a stop longer than the warm-up)
    stands up to its first step, as the whole walk does (:func:`walks.inputs.walk_inputs`'s ``resumed``), and
    the UWB/PDR filters' PDR track is still through a stop (:func:`models.uwb_pdr.pdr_track_at`);
  * a cut whose warm-up holds no event (every stream silent for longer than the warm-up across the seam) takes
    its first event's Δt and standing time from the whole walk's last event and last step before the segment
    (:class:`walks.inputs.EventsResume`), the class and window features in force before its first window from
    the window its class state was handed at, and the GNSS windows that reach back over the silence to its
    first epoch (``FluctuationState.window_origin_s``); the heading filter resumes on the whole run's branch of
    the magnetometer heading, however far gyro and magnetometer drifted apart in a disturbed spell
    (:class:`features.imu.heading.HeadingState`). A cut with no event at all (a silence longer than a segment)
    hands on what it was handed (:class:`walks.inputs.SilentCut`; ``run`` notes it). Measured on a 200 s walk
    of the tests' site silent 30-78 s at 60 s segments: ``adaptive_blind`` 9.6 m → 2.7e-7 m, ``adaptive``
    0.26 m → 4e-8 m; silent 30-140 s: ``run`` stopped at the silent segment, now within 2e-8 m of the whole
    walk;
  * ``pdr`` dead-reckons the segment's steps on from the position the previous segment's track reached;
  * a segment that owns no epoch of a method (no step of ``pdr`` while the walker stands through it, or the
    method skipped on its cut) hands on the state it was handed, as the class HMM does without a window of
    its own (:meth:`walks.fuse.FusedWalk.handover`): its cut's last epoch before its end is a warm-up epoch,
    filtered without the hand-over;
  * segments shorter than the warm-up (``run --segment-s`` down to 60 s): the first cuts all reach back to the
    walk's start; each such cut reads the walk as the whole walk's read does (at least the heading gate's
    reference span, no reader state handed over: :attr:`Segment.states_from_s` is inf before it), its
    filters resuming at its segment's start as any cut's;
  * the class HMM's forward probabilities take, at the cut's window that ended last before the segment, the
    whole walk's value there (:class:`walks.inputs.ClassResume`), and filter on from it;
  * the acoustic receiver resumes its tracker (lock, two-state clock filter, air estimate, acquisition memory)
    at its first frame :data:`RESUME_AFTER_S` into the cut, once its audio buffers are full
    (:class:`features.acoustic.tracking.ReceiverState`); the cut states its first sample's index in the walk's
    recording (``[audio] first_sample``) and the reader passes it to the receiver
    (:func:`features.acoustic.features.analyse_audio`), so every sample passes the same read blocks,
    impulse-blanker segments and matched-filter decimation phase as in the whole walk and the matched
    filter's float32 round-off is the same (before, the cut started on the 32 s grid where they coincide);
  * the GNSS feature ``fluct_per_s``'s extremum detector resumes its memory (each satellite's last C/N0, the
    direction of its last change and the value the next swing is measured from) at the reader's first epoch
    :data:`RESUME_AFTER_S` into the cut (:class:`features.gnss.features.FluctuationState`): while a
    satellite's C/N0 holds still (a stop) that memory outlasts any warm-up;
  * the NMEA epochs and IMU samples are placed on the microsecond grid (:func:`walks.reader.on_time_grid`), so
    that an epoch has the same walk time in every cut (the readers' time bases carry the file's first epoch
    or sample in their round-off);
  * the PDR heading filter resumes its heading, gyro bias, gyro-only heading and gate offset
    :data:`RESUME_AFTER_S` into the cut, after its low-pass filters' transients, with the record's start
    statistics (turn-on bias, gate reference field) of the walk
    (:class:`features.imu.heading.HeadingState`);
  * the rest is local in time and has settled within the warm-up: GNSS fixes (the NMEA time base and epoch
    interval are medians that agree on a steady log), steps (a 2nd-order zero-phase filter, bouts of seconds),
    feature windows. What rode on the 120 s warm-up of before was the GNSS extremum memory (now handed over):
    at 30 s of warm-up on main, seed 78's ``fluct_per_s`` differs at 925 s, the class probabilities by 0.009.

A walk that fits in one segment is fused exactly as before, from its own folder. Memory is bounded by one cut's
pipeline (S + :data:`WARMUP_S` + up to 1 s + :data:`TAIL_S` of walk; :data:`FRESH_WARMUP_S` for the methods
that start afresh) whatever the walk's length, plus what the caller keeps of each segment (``envfuse run`` writes its rows to the output's temporary file and keeps nothing).

What a segment cannot have: the future past its cut. A ``+rts`` track is therefore not smoothed per cut (that
left out every fix after the cut's end: the rows ``+rts`` of the table below, up to 1.8 m, measured that way) but
over the whole walk, :mod:`walks.segment_rts` (the filters that resume, :data:`walks.fuse.RESUMED_METHODS`;
``ekf_rtk_pdr``, which starts afresh on each cut, keeps its cut's smoother): each segment's owned filter events
are stored beside the output and one backward pass runs once the last segment is filtered (``run`` and
``evaluate``; 1.5-1.6 m → 7e-6 m on a 600 s walk at 120 s segments). The covariance calibrator's running means of
the NIS (15 s at most) read the previous segment's NIS, which the hand-over carries
(:attr:`models.fusion.ekf.FilterResume.nis`), not the cut's warm-up filtered without it (the default method's
variance was up to 2.9× off in the 15 s after each seam). (The UWB/PDR filters' PDR track spread a step over
the time since the previous one, a stop included, so a cut ending in a stop lost the step after it: 0.03-0.45 m
at such seams, ``+lag`` and the filter alike; it is now still through a stop, :func:`models.uwb_pdr.pdr_track_at`.)

Short segments and stops (seamfix; walk7 of the bad-input tour, 420 s, standing 260-388 s, and a 600 s walk of
seed 21 on the same site standing 101-224 s and 334-515 s, with the tour's fusion model; ``envfuse run`` and
``bench/seam_identity.py``): at 60, 90, 120 and 300 s segments every track of ``pdr``, ``acoustic``, ``kf_quality``,
``aekf``, ``imm``, ``adaptive`` (and its family), ``uwb_aoa_pdr`` (and its twins) and their ``+lag`` lies within
3e-6 m (``pdr``), 2e-5 m (the class-aware filters) and 1e-6 m (the others) of the whole walk's. Before:
``pdr`` 21.4 m from 360 s on at 60 s segments and 56 of 411 epochs without a position at 90 s (a segment
standing throughout handed on its warm-up's dead reckoning), 0.05-0.15 m from 60 s on at 60 s segments (a
second cut holding the walk's start read the heading gate's reference field from 130 s of it, not 300 s);
the filters 0.3-0.9 m after the 181 s stop at 60 s segments (a cut standing from its start walked), the
UWB/PDR filters 0.03-0.45 m at seams inside a stop. What is left at 60 s segments of the seed-21 walk: the
class-aware tracks (``imm`` 2e-5 m, ``uwb_aoa_pdr_env`` 4e-5 m, ``adaptive_correction`` 6e-4 m) at 523-540 s,
where the GNSS feature ``fluct_per_s`` of four windows differs (by 0.03-0.05 per s): its extremum detector
(:func:`features.gnss.features.fluctuation_extrema`) judges each extremum's swing from the previous one, a memory
that outlasts the warm-up while a satellite's C/N0 holds still through a stop; it is now handed over (warmup):
on a 600 s walk of seed 21 on the tests' site (generated site 3; standing 37-218, 243-367 and 380-563 s, the
tests' fusion model), 60 s segments, ``imm`` 0.017 → 5.1e-7 m and ``uwb_aoa_pdr_env`` 0.23 → 4.8e-7 m from the
whole walk (``kf_quality`` 2.5e-7, ``pdr`` 9.5e-7, ``uwb_aoa_pdr`` 2.8e-7 m, as before).

Measured (``bench/seam_identity.py``: simulated 21-minute walks, site 201 of the demo split and its model, 300 s
segments, largest distance from the whole walk's track at the same epoch over every owned epoch, m; "main":
da9cdfe, 120 s warm-up on the 32 s grid, measured in the same session on the same walks; now: 20 s on the 1 s
grid for the resumed methods, 120 s for the others):

=====================  ============  ============  ============  ============
track                  seed 77       (main)        seed 78       (main)
=====================  ============  ============  ============  ============
acoustic fixes         0 (g)         8.0e-11       0 (g)         8.0e-11 (b)
kf_quality             1.4e-7        1.0e-7        1.5e-7        0.71 (b)
aekf                   6.3e-8        7.2e-8        1.2e-7        0.096 (b)
imm                    2.2e-7        0.015 (c)     2.4e-7        1.2 (b)
adaptive_nobp_blind    2.2e-7        1.5e-7        2.1e-7        0.18 (b)
adaptive               1.9e-7        0.13 (c)      4.5e-7        0.18 (b)
uwb_aoa_pdr_env (i)    1.8e-6        5.6e-4 (c)    4.4e-7        0.0094
pdr                    5.4e-6 (d)    2.6e-6 (d)    5.0e-6 (d)    5.0e-6 (d)
uwb_aoa_pdr (i)        7.3e-7 (f)    5.8e-7 (f)    2.3e-7 (f)    1.8e-7 (f)
kf_quality+rts         0.022         0.022         0.94          1.0
aekf+rts               0.025         0.025         1.8           1.8
imm+rts                0.059         0.059         0.32          0.69
ekf_rtk_pdr (h)        1.7e-10       1.2e-9        0.013         0.013
fg_isam2 (h)           0.087         0.11          2.4           2.4
fg_lag (h)             0.037         0.051         1.4           1.0
fg_tight (h)           0.066         0.074         2.7           2.5
=====================  ============  ============  ============  ============

With 20 s of warm-up before the GNSS memory was handed over, on the 1 s grid, the tracks of both walks were
these; on main with 30 s, seed 78's ``fluct_per_s`` at 925 s differed (class probabilities by 0.009). The
``+rts`` tracks lost the data past the cut's end whatever the warm-up (now smoothed over the whole walk). (a)
(before issue 25's alignment) the cut's float32 blocks not on the walk's; (b) one acoustic fix of seed 78 (342.83 s) main's
segmented read does not give (its cut aligned on the 32 s grid; aligned by ``first_sample`` every fix is the
whole walk's to the bit): the filters move by up to 2.95 m (``kf_map``) after it; (c) three feature windows of
seed 77 (1137-1139 s) whose CIR features differ on main (one chirp's SNR by 0.1-1 dB): the class-aware filters
move by up to 0.15 m; equal now; (d) the resumed heading agrees to 3-5e-8 rad, not to round-off (the 0.3 Hz
zero-phase low-pass's transients at the cut's ends, e^-13 after 10 s), and dead reckoning accumulates it over
the segment; (e) before issue 25's heading resume, ``pdr`` and the UWB filter did not survive a seam; (f) since
seamfix, whose PDR track for the UWB/PDR filter is still through a stop; (g) bit for bit; (h) not resumed,
fused in cuts of :data:`FRESH_WARMUP_S` (``walks.fuse.warmup_for``): with 20 s ``ekf_rtk_pdr`` reads 1.23 m and
``fg_isam2`` 0.71 m on seed 77; the other ``fg_*`` within 0.008-0.02 m (seed 77) and 0.21-0.25 m (seed 78;
``fg_ins`` 11.1 m on both, as main); (i) measured with 20 s; the UWB/PDR filters took :data:`FRESH_WARMUP_S`
for a while, their run never fusing the cut's first UWB fix: a cut whose 20 s of warm-up held none lost one
(0.056 m on a walk standing in a UWB gap, 60 s segments); a resumed run now fuses it and the steps before it
(2.8e-7 m there, :data:`walks.fuse.RESUMED_METHODS`), and they take :data:`WARMUP_S` again.

``envfuse run --method adaptive_blind+lag`` (one core, best of 3 alternated fresh processes, load 4.5-6 from
other sessions; CPU of the process, imports and model load included), main → now: a 10-minute walk (seed 79)
segmented 5.43 → 4.88 s, unsegmented 3.86 → 3.81 s; a 21-minute walk (seed 77) segmented 12.29 → 10.41 s,
unsegmented 7.23 → 6.79 s. Peak memory (ru_maxrss) segmented: 292.3 → 285.7 MiB (10 minutes), 293.3 → 285.2
MiB (21 minutes); unsegmented 299 and 340 MiB on both. What the segmented read still costs besides the
warm-up's audio: writing the cuts (:func:`walk_cuts`' line-by-line Python copy of the NMEA, IMU, foot-IMU, UWB
and truth files: about 5 of 40 s of a profiled segmented run of seed 77, against 25-29 s unsegmented) and the
receiver's acquisition in each cut's first 10 s, before it resumes.
Two reviews then found what a cut still read differently (stop 34; twelve 600 s walks of sites 3, 5, 7 at 60 and
300 s segments): acquisition fixes lost where a 32-frame feature batch ended (whole walks too); a step's
prominence sought across a stop, and a bout's first step timed by the whole bout's median interval; the GNSS
extremum memory of a satellite no epoch of a cut listed; the feature windows' clock offset, not resumed with the
receiver; ``adaptive_correction``'s reach back to the last fix. Each fixed (now local, or handed over, or the
120 s warm-up): worst resumed track at 60 s segments 0.60 m → 1.6e-5 m on eleven walks; on the twelfth ``imm``
(mode probabilities swinging between 0.99 and 0.001 at each 5 Hz fix) amplifies the heading filter's 1e-8 rad
resumption round-off (note (d)) to 3.5e-4 m.
A walk holding a stream that cannot be cut by
time (a drive's pseudoranges or odometry, whose dead reckoning is fitted to the whole drive's fixes) is not
segmented (:func:`plan_segments` says why). Not resumed: ``foot_ins_fkf`` (its strapdown INS and local filters,
:mod:`models.foot`; its 10 Hz track is also sampled from the cut's first IMU sample), the factor-graph
methods (``fg_*``) and ``ekf_rtk_pdr`` (:mod:`walks.graph_methods`): their cuts take :data:`FRESH_WARMUP_S`.
"""

from __future__ import annotations

import collections
import datetime as dt
import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import soundfile as sf

from features.errors import DataError
from features.gnss.quirks import parse_ddmmyy
from features.gnss.tokens import ReadStats, parse_sentence
from features.imu.heading import GATE_REFERENCE_S
from features.imu.reader import RepairConfig
from features.fileio import read_toml
from features.walk import WalkInfo, load_walk

__all__ = ["SEGMENT_S", "WARMUP_S", "FRESH_WARMUP_S", "TAIL_S", "RESUME_AFTER_S", "Segment", "plan_segments",
           "walk_cuts"]

SEGMENT_S = 300.0
"""Walk time each segment owns by default, s: with the filters and readers resumed across the seams they cost
nothing measurable, so the segment is short and the peak memory of a long walk that of one cut: 300 s, the
warm-up (:data:`WARMUP_S`, or :data:`FRESH_WARMUP_S`), up to 1 s of the audio grid and :data:`TAIL_S` (331 s, or
431 s): a 10-minute walk (two segments) and an 8-hour one peak within 1.5 % of each other (286 and 290 MiB,
``bench/bench_pipeline.py --memory-only``, 2026-12-03). A 10-minute walk in two segments costs about 1 % more time
than fused whole."""

WARMUP_S = 20.0
"""Walk time a cut reaches before its segment when every method fused resumes what the previous segment handed
over (then moved back to the audio grid, :func:`audio_cut_step`: up to 1 s more at 48 kHz), s: the readers
resume :data:`RESUME_AFTER_S` into it, so their states hold from 10 s before the segment; what is not handed
over is local and settles within that (step detection's zero-phase filter and its bouts, the 2 s feature
windows, the GNSS bias resets on the fixes' neighbours), and the filters and the class HMM resume at the
segment's start. Was 120 s (plus up to 32 s of the block grid): the GNSS ``fluct_per_s`` extremum memory rode
on it (:class:`features.gnss.features.FluctuationState`, now handed over); measured in the module docstring."""

FRESH_WARMUP_S = 120.0
"""Walk time a cut reaches before its segment when a method fused starts afresh on each cut (nothing handed
over: the factor graphs ``fg_*``, ``ekf_rtk_pdr``, ``foot_ins_fkf``; ``adaptive_correction``, whose BP inputs
reach back to the last fix; :data:`walks.fuse.RESUMED_METHODS`), s: such a method converges within it
(``walks.fuse.warmup_for``)."""

TAIL_S = 10.0
"""Walk time a cut reaches after its segment, s: ≥ the fixed-lag smoother's lag (3 s), a step split at the
following fix (≤ 0.6 s) and the last 2 s feature window."""

BRACKET_ROWS = 2
"""Rows an IMU cut takes beyond a hole across its start or end (:class:`_CsvCutter`): two, as the IMU reader takes
a lone row a hole away from the rest for a garbled time (``features.imu.reader._time_outliers``)."""

LOOKAHEAD_LINES = 64
"""Lines a cutter reads past a line at or beyond its cut's end before ending the cut there: if any of them lies
before the end, that line is one out of place (a garbled time) and goes with the line before it. 64 lines are
about 1.3 s of a 5 Hz NMEA log of ten sentences an epoch and 0.6 s of a 100 Hz IMU log."""

RESUME_AFTER_S = 10.0
"""Walk time after its cut's start at which the readers resume the states handed over, s: the acoustic
receiver's audio buffers (a frame of envelope history and the search lead; frames last about a second) are full
by then and the PDR heading's zero-phase low-pass filters (0.3 Hz on the specific force, 1 Hz on the
magnetometer) have forgotten the cut's edge (their transients decay within a few seconds)."""

CUTTABLE = frozenset(("gnss", "imu", "audio", "uwb", "imu_foot"))
"""Streams a cut can hold (cut by time without changing what they mean)."""

_TIME_FIELD = {"GGA": 1, "RMC": 1, "GST": 1, "GNS": 1, "ZDA": 1, "GLL": 5, "GBS": 1}
"""Index of the hhmmss.ss field of each NMEA sentence that carries a time (after the address field)."""


@dataclass(frozen=True)
class Segment:
    """Segment ``index`` owns walk times [``own_from_s``, ``own_to_s``) (±inf at the walk's ends); ``directory``
    is its cut (a temporary walk folder), or the walk's own folder when the walk is one segment;
    ``next_from_s`` the walk time the next segment's cut starts at (inf for the last)."""

    index: int
    own_from_s: float
    own_to_s: float
    directory: Path
    next_from_s: float = math.inf

    @property
    def states_from_s(self) -> float:
        """Walk time from which this segment's read keeps the readers' states for the next segment: the next
        cut's start + :data:`RESUME_AFTER_S`; inf for the last segment and when the next cut starts at the walk's
        start (−inf: it reads the walk from there as the whole walk's read does, resuming no reader)."""
        return self.next_from_s + RESUME_AFTER_S if math.isfinite(self.next_from_s) else math.inf

    @property
    def whole(self) -> bool:
        """The segment owns the whole walk (a walk of one segment, fused from its own folder)."""
        return self.own_from_s == -math.inf and self.own_to_s == math.inf

    @property
    def span_text(self) -> str:
        """The walk times it owns, for a message: ``walk times 60-120 s``, ``walk times from 180 s``."""
        lo = max(self.own_from_s, 0.0)
        return f"walk times {lo:g}-{self.own_to_s:g} s" if math.isfinite(self.own_to_s) else f"walk times from {lo:g} s"

    def owns(self, t_s):
        """Which of ``t_s`` (array) belong to this segment."""
        return (t_s >= self.own_from_s) & (t_s < self.own_to_s)


def plan_segments(walk_dir: str | os.PathLike, segment_s: float = SEGMENT_S) -> tuple[int, str]:
    """(number of segments, why not more): 1 when the walk fits in one segment, holds a stream that cannot be
    cut, or states no ``start_utc`` (its NMEA times of day cannot be placed)."""
    if not (math.isfinite(segment_s) and segment_s > 0):
        raise ValueError(f"segment_s must be a positive number of seconds, got {segment_s}")
    walk = load_walk(walk_dir)
    other = sorted(s for s, t in walk.streams.items() if t and s not in CUTTABLE)
    if other:
        return 1, f"its {', '.join(other)} stream cannot be cut by time"
    if walk.streams.get("gnss") and walk.start_utc is None:
        return 1, "walk.toml states no start_utc"
    span = _span_s(walk)
    n = max(1, math.ceil((span - TAIL_S) / segment_s)) if math.isfinite(span) else 1
    return n, "" if n > 1 else "it fits in one segment"


def _span_s(walk: WalkInfo) -> float:
    """The walk's length: ``duration_s`` when stated, else its audio's or IMU's end (NaN without either)."""
    if walk.duration_s:
        return float(walk.duration_s)
    ends = []
    audio = walk.path("audio")
    if audio is not None and audio.is_file() and audio.stat().st_size:
        info = sf.info(str(audio))
        ends.append(float(walk.streams["audio"].get("start_s", 0.0)) + info.frames / info.samplerate)
    imu = walk.path("imu")
    if imu is not None and imu.is_file() and imu.stat().st_size:
        t = _last_csv_time(imu)
        if t is not None:
            ends.append(t)
    return max(ends) if ends else math.nan


def _last_csv_time(path: Path) -> float | None:
    """``t_s`` of a CSV's last parseable row, read from its tail."""
    with open(path, "rb") as fh:
        lines = fh.read(1 << 16).splitlines()
        col = _time_column([next((line for line in lines if line.strip() and not line.lstrip().startswith(b"#")),
                                 b"")])
        fh.seek(0, os.SEEK_END)
        fh.seek(max(0, fh.tell() - 4096))
        for line in reversed(fh.read().splitlines()):
            t = _csv_time(line, col)
            if t is not None:
                return t
    return None


def _csv_header(fh) -> list[bytes]:
    """The comment lines and the header line at the start of a CSV (the header last), read from ``fh`` (a file or
    a :class:`_LineCutter`: anything with ``readline``)."""
    head = []
    while True:
        line = fh.readline()
        if not line:
            break
        head.append(line)
        if line.strip() and not line.lstrip().startswith(b"#"):
            break
    return head


def _time_column(head: list[bytes]) -> int:
    """Index of the ``t_s`` column named in a CSV's header line (as the readers find it: by name, spaces and case
    aside, a UTF-8 byte-order mark dropped); 0 when none is named ``t_s``."""
    names = [h.strip().lower() for h in head[-1].decode("utf-8-sig", "replace").split(",")] if head else []
    return names.index("t_s") if "t_s" in names else 0


def _csv_time(line: bytes, col: int = 0) -> float | None:
    try:
        return float(line.split(b",", col + 1)[col])
    except (ValueError, IndexError):
        return None


def walk_cuts(walk_dir: str | os.PathLike, segment_s: float = SEGMENT_S, *,
              workdir: str | os.PathLike | None = None, warmup_s: float | None = None) -> Iterator[Segment]:
    """The walk's segments in time order (module docstring), each cut written just before it is yielded and
    deleted when the next is asked for; ``warmup_s``: the cuts' warm-up (default :data:`WARMUP_S`). A walk of
    one segment yields its own folder."""
    warmup = WARMUP_S if warmup_s is None else float(warmup_s)
    n, _ = plan_segments(walk_dir, segment_s)
    if n == 1:
        yield Segment(0, -math.inf, math.inf, Path(walk_dir), math.inf)
        return
    walk = load_walk(walk_dir)
    with tempfile.TemporaryDirectory(prefix=".envfuse-segments.", dir=workdir) as tmp:
        cutters = _cutters(walk)
        align = _audio_grid(walk)
        imu_end = _last_csv_time(walk.path("imu")) if "imu" in cutters else None
        for k in range(n):
            own_from = -math.inf if k == 0 else k * segment_s
            own_to = math.inf if k == n - 1 else (k + 1) * segment_s
            lo = -math.inf if k == 0 else align(own_from - warmup)
            hi = math.inf if k == n - 1 else own_to + TAIL_S
            if lo == -math.inf:
                # a cut holding the walk's start reads it as the whole walk's read does, the heading gate's
                # reference field included (a segment shorter than the warm-up: the first cuts all start there)
                hi = max(hi, GATE_REFERENCE_S)
            next_lo = align((k + 1) * segment_s - warmup)
            d = Path(tmp) / f"segment{k:04d}"
            d.mkdir()
            toml = {}
            for name, cut in cutters.items():
                toml.update(cut.write(d, lo, hi, next_lo))
            if "truth" in cutters and _data_rows(d / "truth.csv", cutters["truth"].head) < 2:
                # no truth in the cut's span (past the truth's end, or before its start): the cut has none, and its
                # epochs are not scored, as the whole walk scores none outside its truth's span
                (d / "truth.csv").unlink()
            if imu_end is not None and math.isfinite(hi):
                # where the cut's IMU record ends: its end, or the walk's IMU's if sooner. A cut whose own samples
                # stop short of it (a hole across its end) stands after its last step as the whole walk stands
                # through the hole (walks.inputs._stands); before, the cut ended its record at its last sample
                # and walked on, and the filters it handed over were metres off the whole walk's for a segment.
                toml["imu_cut_to_s"] = min(hi, imu_end)
            _write_walk_toml(walk, d, toml)
            yield Segment(k, own_from, own_to, d, math.inf if k == n - 1 else next_lo)
            shutil.rmtree(d)
        for cut in cutters.values():
            cut.close()


def _data_rows(path: Path, head: bytes) -> int:
    """Rows of a cut's CSV after its header ``head`` (a cut's CSV is short: read whole)."""
    return sum(1 for line in path.read_bytes()[len(head):].splitlines() if line.strip())


def audio_cut_step(fs_in_hz: int) -> int:
    """Input samples between the audio samples a cut may start at: at the acoustic reader's own rate (48 kHz)
    one hop of its feature windows (:class:`features.acoustic.features.WindowConfig`, 1 s), since the cut is
    read with its first sample's index in the whole recording (``[audio] first_sample``, :func:`_AudioCutter`;
    :func:`features.acoustic.features.analyse_audio`'s ``first_sample``), which puts its read blocks,
    impulse-blanker segments and matched-filter decimation where the whole recording's lie, and its windows
    then start on the whole recording's window grid. At another rate (resampled, whose blocks that index does
    not align) :func:`audio_cut_period`. 48,000 samples (1 s) at 48 kHz."""
    from features.acoustic.detection import DetectorConfig
    from features.acoustic.features import WindowConfig

    if int(fs_in_hz) != int(DetectorConfig().fs_hz):
        return audio_cut_period(fs_in_hz)
    hop = WindowConfig().hop_s * fs_in_hz
    if abs(hop - round(hop)) > 1e-9:
        return audio_cut_period(fs_in_hz)
    return int(round(hop))


def audio_cut_period(fs_in_hz: int) -> int:
    """Input samples between the audio samples a cut may start at, so that the acoustic reader processes every
    sample of the cut in the same blocks, impulse-blanker segments and decimation phase as in the whole walk
    (and hence gives the same float32 round-off; the blocks of :func:`features.acoustic.audio.iter_audio_blocks`
    start at the file's first sample): the least common multiple of the read block
    (:attr:`features.acoustic.detection.DetectorConfig.block_s`, a whole number of resampling periods), the
    blanker's segment (:class:`features.acoustic.impulses.ImpulseBlanker`) and the matched filter's decimation
    (4), in output samples, taken back to input samples. 1,536,000 samples (32 s) at 48 kHz."""
    from fractions import Fraction

    from features.acoustic.detection import DetectorConfig
    from features.acoustic.impulses import ImpulseBlanker

    cfg = DetectorConfig()
    ratio = Fraction(int(cfg.fs_hz), int(fs_in_hz))
    period = ratio.denominator
    block_in = max(period, int(round(cfg.block_s * fs_in_hz / period)) * period)
    block_out = int(block_in * ratio)
    grid_out = math.lcm(block_out, ImpulseBlanker(float(cfg.fs_hz)).segment, MATCHED_FILTER_DECIMATION)
    return block_in * (grid_out // block_out)


MATCHED_FILTER_DECIMATION = 4
"""Decimation of the acoustic reader's matched-filter envelopes
(:class:`features.acoustic.matched_filter.StreamingMatchedFilter`'s default)."""


def _audio_grid(walk: WalkInfo):
    """The function moving a cut's start back to the last walk time at or before it whose audio sample lies on
    :func:`audio_cut_step`'s grid counted from the WAV's first sample (identity without audio): the cut's
    warm-up grows by less than one step (1 s at 48 kHz; 32 s at another rate). A start moved back to the WAV's first sample (or
    before it) is −inf: that cut holds the walk from its start, as the whole walk's read does."""
    audio = walk.path("audio")
    if audio is None or not audio.is_file() or not audio.stat().st_size:
        return lambda t: t
    fs = sf.info(str(audio)).samplerate
    step = audio_cut_step(fs)
    start = float(walk.streams["audio"].get("start_s", 0.0))

    def align(t: float) -> float:
        i = math.floor((t - start) * fs / step + 1e-9) * step
        return start + i / fs if i > 0 else -math.inf     # from the audio's first sample: from the walk's start

    return align


def _cutters(walk: WalkInfo) -> dict:
    out = {}
    if walk.path("gnss") is not None and walk.path("gnss").is_file():
        out["gnss"] = _NmeaCutter(walk.path("gnss"), walk)
    if walk.path("imu") is not None and walk.path("imu").is_file():
        out["imu"] = _CsvCutter(walk.path("imu"), "imu")
    for stream in ("uwb", "imu_foot"):           # CSVs with a t_s column on the walk's time base
        if walk.path(stream) is not None and walk.path(stream).is_file():
            out[stream] = _CsvCutter(walk.path(stream), stream)
    if (walk.directory / "truth.csv").is_file():
        out["truth"] = _CsvCutter(walk.directory / "truth.csv", None)
    if walk.path("audio") is not None and walk.path("audio").is_file():
        out["audio"] = _AudioCutter(walk.path("audio"), float(walk.streams["audio"].get("start_s", 0.0)))
    return out


def _write_walk_toml(walk: WalkInfo, d: Path, changes: dict) -> None:
    """The cut's walk.toml: the walk's, with the site's absolute path and the cut's ``[audio] start_s``."""
    text = (walk.directory / "walk.toml").read_text()
    raw = read_toml(walk.directory / "walk.toml")
    site = (walk.directory / raw["site"]).resolve() if "site" in raw else None
    if site is not None:
        text = re.sub(r"^site\s*=.*$", lambda _: f"site = {_toml_str(str(site))}", text, count=1, flags=re.M)
    if "audio_start_s" in changes:
        text = _set_in_table(text, "audio", "start_s", repr(changes["audio_start_s"]))
    if "imu_cut_to_s" in changes:
        text = _set_in_table(text, "imu", "cut_to_s", _toml_float(changes["imu_cut_to_s"]))
    if "gnss_date_offset_s" in changes:
        text = _set_in_table(text, "gnss", "cut_from_s", _toml_float(changes["gnss_cut_from_s"]))
        text = _set_in_table(text, "gnss", "date_offset_s", _toml_float(changes["gnss_date_offset_s"]))
    if "audio_first_sample" in changes:
        text = _set_in_table(text, "audio", "first_sample", str(changes["audio_first_sample"]))
        text = _set_in_table(text, "audio", "recording_start_s", repr(changes["audio_recording_start_s"]))
    (d / "walk.toml").write_text(text)


def _toml_float(x: float) -> str:
    return ("-inf" if x < 0 else "inf") if math.isinf(x) else repr(float(x))


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _set_in_table(text: str, table: str, key: str, value: str) -> str:
    """``key = value`` in ``[table]`` of a TOML text (added after the table's header when absent)."""
    m = re.search(rf"^\[{table}\]\s*$", text, flags=re.M)
    if m is None:
        raise DataError(f"walk.toml has no [{table}] table")
    nxt = re.search(r"^\[", text[m.end():], flags=re.M)
    end = m.end() + (nxt.start() if nxt else len(text) - m.end())
    body = text[m.end():end]
    line = re.compile(rf"^{key}\s*=.*$", flags=re.M)
    body = line.sub(lambda _: f"{key} = {value}", body, count=1) if line.search(body) else \
        f"\n{key} = {value}" + body
    return text[:m.end()] + body + text[end:]


class _LineCutter:
    """A text stream cut by the walk time of each line, read once from start to end over all the cuts: each
    cut starts at the first line at or after the previous cut's ``next_lo``.

    A cut ends at the first line at or past its end that the lines after it confirm: one whose time runs ahead
    of the :data:`LOOKAHEAD_LINES` lines after it (any of them before the end) is one line out of place, a
    garbled time (a flipped digit, a corrupted sentence the reader will refuse by its checksum), and goes with
    the line before it, where the whole walk's reader meets it and judges it. (Before, such a line ended the
    cut, and every later cut at its first line, since each resumed there: one bad GGA or IMU row took the
    stream from the rest of the walk, with nothing said but "empty" of the cuts.)"""

    def __init__(self, path: Path):
        self.path = path
        self.fh = open(path, "rb")
        peek = self.fh.read(1 << 16)
        self.fh.seek(0)
        # Lines end in LF (or CR LF); a file whose lines end in CR alone (an old Mac logger's; the readers take
        # it, reading universal newlines) is split on CR, else it would be one line and go whole into one cut.
        self.cr_only = b"\r" in peek and b"\n" not in peek
        self._buf, self._at = b"", 0
        self.head = b""
        self.resume = 0
        self.resume_t = -math.inf
        self.bracket_gap_s: float | None = None
        self.before_resume: list[tuple[bytes, float]] | None = None

    def readline(self) -> bytes:
        """The next line, its end included (b"" at the end of the file)."""
        if not self.cr_only:
            return self.fh.readline()
        while True:
            i = self._buf.find(b"\r", self._at)
            if i >= 0:
                line, self._at = self._buf[self._at:i + 1], i + 1
                return line
            chunk = self.fh.read(1 << 16)
            if not chunk:
                line, self._buf, self._at = self._buf[self._at:], b"", 0
                return line
            self._buf, self._at = self._buf[self._at:] + chunk, 0

    def seek(self, pos: int) -> None:
        self.fh.seek(pos)
        self._buf, self._at = b"", 0

    def line_time(self, line: bytes, current: float) -> float:
        raise NotImplementedError

    def state(self):
        """What :meth:`line_time` carries from line to line (restored when a line proves out of place)."""
        return None

    def restore(self, state) -> None:
        pass

    def write(self, d: Path, lo: float, hi: float, next_lo: float) -> dict:
        self.seek(self.resume)
        pos, t = self.resume, self.resume_t
        marked = False
        ahead: collections.deque = collections.deque()     # lines read to look past one, not yet cut
        bracket = self.bracket_gap_s is not None
        before_lo, self.before_resume = self.before_resume, None
        # (line, t) of the rows before the one read: at the cut's start, those before it (a cut inside a hole
        # hands them on to the next)
        last_lines: collections.deque = collections.deque(before_lo or (), maxlen=BRACKET_ROWS)
        written_t = -math.inf
        with open(d / self.path.name, "wb") as out:
            out.write(self.head)
            while True:
                line = ahead.popleft() if ahead else self.readline()
                if not line:
                    break
                before = self.state()
                t_line = self.line_time(line, t)
                if t_line >= hi > t:
                    after = self.state()
                    if self._out_of_place(t, before, hi, ahead):
                        self.restore(before)
                        t_line = t
                    else:
                        self.restore(after)
                if not marked and t_line >= next_lo:
                    self.resume, self.resume_t, marked = pos, self.resume_before(t_line), True
                    if bracket:
                        self.before_resume = list(last_lines)
                t = t_line
                pos += len(line)
                if t >= hi:
                    if before_lo and t - before_lo[-1][1] > self.bracket_gap_s:
                        # a cut inside a hole: the rows before it, then those after
                        out.writelines(row for row, _ in before_lo)
                        written_t = before_lo[-1][1]
                    if bracket and math.isfinite(written_t) and t - written_t > self.bracket_gap_s:
                        # the rows after a hole across the cut's end
                        out.write(line)
                        out.writelines(ahead.popleft() if ahead else self.readline()
                                       for _ in range(BRACKET_ROWS - 1))
                    break
                if t >= lo:
                    if before_lo and t - before_lo[-1][1] > self.bracket_gap_s:
                        # the rows before a hole across the cut's start
                        out.writelines(row for row, _ in before_lo)
                    before_lo = None
                    out.write(line)
                    written_t = t
                last_lines.append((line, t))
        if not marked:
            self.resume, self.resume_t = pos, t
        return {}

    def _out_of_place(self, t: float, before, hi: float, ahead: collections.deque) -> bool:
        """Whether a line at or past ``hi``, read at stream time ``t`` from state ``before``, is followed, within
        :data:`LOOKAHEAD_LINES` lines, by one before ``hi`` (those lines kept in ``ahead`` to be cut in turn)."""
        while len(ahead) < LOOKAHEAD_LINES:
            line = self.readline()
            if not line:
                break
            ahead.append(line)
        self.restore(before)
        found = False
        for line in ahead:
            t = self.line_time(line, t)
            if t < hi:
                found = True
                break
        self.restore(before)
        return found

    def resume_before(self, t: float) -> float:
        return -math.inf

    def close(self) -> None:
        self.fh.close()


class _CsvCutter(_LineCutter):
    """A CSV with a ``t_s`` column (found by name, as the readers find it) on the walk's time base (IMU, foot IMU, UWB, truth): its header (and the comment
    lines before it) in every cut, each row by its ``t_s``; a row without a readable ``t_s`` goes with the row
    before it (the reader judges it)."""

    def __init__(self, path: Path, stream: str | None):
        super().__init__(path)
        if stream in ("imu", "imu_foot"):
            # the IMU reader fills a hole on its uniform grid between the rows around it: a cut whose start (or
            # end) lies in a hole holds the row before (after) it too, so its read fills the hole as the whole
            # walk's does and the heading filter runs through the same samples (features.imu.reader)
            self.bracket_gap_s = RepairConfig().max_gap_s
        elif stream is None and path.name == "truth.csv":
            # the truth is interpolated between its rows (features.walk.Truth.at): every cut holds those either
            # side of it, so an epoch in a hole of the truth is scored as in the whole walk
            self.bracket_gap_s = 0.0
        head = _csv_header(self)
        self.head = b"".join(head)
        self.resume = len(self.head)
        self.col = _time_column(head)       # the readers find t_s by name: it need not come first

    def line_time(self, line: bytes, current: float) -> float:
        t = _csv_time(line, self.col)
        return current if t is None or not math.isfinite(t) else t


class _NmeaCutter(_LineCutter):
    """NMEA sentences by the walk time of the epoch they belong to (the last sentence carrying a time): its time of
    day less ``start_utc``'s plus a whole number of days, the number that puts it within 12 h of the sentence
    before (the first: of the start), so a fall of more than 12 h, 23:59:59 → 00:00:00, is a midnight crossing,
    one second on; a walk of any length is unwrapped day by day. Each time is formed from the start and its day
    count, not from the time before, so no round-off accumulates over a long log.

    (Before, a midnight crossing was counted twice, by the fold to ±12 h around the start's time of day and by a
    day count on top: every epoch after midnight was put a day late, so each cut after it held no NMEA and the
    last cut all of it, from midnight to the end.)"""

    def __init__(self, path: Path, walk: WalkInfo):
        super().__init__(path)
        s = walk.start_utc
        self.start_tod = s.hour * 3600 + s.minute * 60 + s.second + s.microsecond * 1e-6
        self.start_ordinal = s.date().toordinal()
        self.prev = None        # (days, walk time) of the last timed sentence
        self.date_offset_s = self._date_offset_s()

    def _date_offset_s(self) -> float | None:
        """The log's dates against its times of day, as the whole walk's reader weighs them: each epoch (each
        new time) takes the date of the last dated sentence (RMC, ZDA; checksum good) up to its end, as the
        reader's clock carries a date on; the offset of an epoch is (its date − start_utc's date − the days its
        walk time was unwrapped by)·86,400 s, 0 when its date agrees with start_utc and the times of day; the
        median_low over the dated epochs, the reader's estimator (:func:`features.gnss.nmea.epochs_on_time_base`:
        a receiver's bogus dates after a cold start, a minority, move nothing). None without any date. One pass
        over the file before the first cut, a line at a time (1.6 s for a 4-hour walk's 5 Hz log of 53 MB)."""
        counts: collections.Counter = collections.Counter()
        t, epoch_days, last_days = -math.inf, None, None
        stats = ReadStats()         # what the reader would count; not reported (the cuts' reads report theirs)
        self.seek(0)
        self.prev = None
        while True:
            line = self.readline()
            if not line:
                break
            t_new = self.line_time(line, t)
            if t_new != t:
                if epoch_days is not None:
                    counts[epoch_days] += 1
                epoch_days = last_days
            t = t_new
            date = _sentence_date(line, stats)
            if date is not None and self.prev is not None:
                last_days = epoch_days = date.toordinal() - self.start_ordinal - self.prev[0]
        if epoch_days is not None:
            counts[epoch_days] += 1
        self.seek(0)
        self.prev = None
        if not counts:
            return None
        at, seen = (sum(counts.values()) - 1) // 2, 0
        for days in sorted(counts):
            seen += counts[days]
            if seen > at:
                return 86400.0 * days
        raise AssertionError("unreachable")

    def line_time(self, line: bytes, current: float) -> float:
        if not line.startswith(b"$"):
            at = line.find(b"$")        # a logger's prefix before the sentence (a time stamp), as the reader skips it
            if at < 0:
                return current
            line = line[at:]
        if len(line) < 7:
            return current
        fields = line.split(b"*", 1)[0].split(b",")
        i = _TIME_FIELD.get(fields[0][3:].decode("ascii", "replace"))
        if i is None or len(fields) <= i or len(fields[i]) < 6:
            return current
        try:
            f = fields[i]
            tod = int(f[0:2]) * 3600 + int(f[2:4]) * 60 + float(f[4:])
        except ValueError:
            return current
        if not math.isfinite(tod):
            return current
        days, rel = _unwrapped_day(tod - self.start_tod, self.prev)
        self.prev = (days, rel)
        return rel

    def state(self):
        return self.prev

    def restore(self, state) -> None:
        self.prev = state

    def write(self, d: Path, lo: float, hi: float, next_lo: float) -> dict:
        # unwrap from the state saved at the resume position (the sentence there is read again)
        self.prev = getattr(self, "_resume_state", None)
        out = super().write(d, lo, hi, next_lo)
        if self.date_offset_s is not None:
            # the cut's reader places its epochs by their times of day and the whole log's date offset, not by
            # the cut's own dates (walks.reader.read_gnss_stream): a cut whose dates are mostly a cold start's
            # bogus ones, or that holds none, is placed where the whole walk's reader places it
            out.update(gnss_cut_from_s=lo, gnss_date_offset_s=self.date_offset_s)
        return out

    def resume_before(self, t: float) -> float:
        self._resume_state = self.prev
        return -math.inf


def _sentence_date(line: bytes, stats: ReadStats) -> dt.date | None:
    """The date an RMC or ZDA sentence states, as the NMEA reader takes it: checked by the reader's own
    :func:`~features.gnss.tokens.parse_sentence` (checksum, address), RMC's ddmmyy whatever its status, ZDA's day,
    month and year from 1980 on; None for any other line, a sentence the reader refuses or a date that does not
    parse."""
    at = line.find(b"$")
    if at < 0 or line[at + 3:at + 7] not in (b"RMC,", b"ZDA,"):
        return None
    fields = parse_sentence(line[at + 1:].decode("latin-1").split("$", 1)[0].strip(), stats)
    if fields is None:
        return None
    try:
        if fields[0][2:] == "RMC":
            return parse_ddmmyy(fields[9]) if len(fields) > 9 else None
        if len(fields) > 4 and fields[2] and fields[3] and fields[4]:
            date = dt.date(int(fields[4]), int(fields[3]), int(fields[2]))
            return date if date.year >= 1980 else None
    except ValueError:
        return None
    return None


def _unwrapped_day(since_start_tod_s: float, prev: tuple[int, float] | None) -> tuple[int, float]:
    """(days, walk time) of a time of day ``since_start_tod_s`` after the start's (−86,400 … 86,400 s): walk time
    = that + 86,400·days, the days chosen to put it within 12 h of the previous sentence's walk time ``prev`` =
    (its days, its walk time), or of the start (0) for the first.

    From 22:20 UTC (80,400 s), 23:59:59 is 5,999 s on; 00:00:00 a day later 6,000 s; a first sentence a second
    before the start, −1 s:

    >>> _unwrapped_day(86399.0 - 80400.0, None), _unwrapped_day(0.0 - 80400.0, (0, 5999.0))
    ((0, 5999.0), (1, 6000.0))
    >>> _unwrapped_day(80399.0 - 80400.0, None)
    (0, -1.0)
    """
    days, ref = (0, 0.0) if prev is None else prev
    rel = since_start_tod_s + 86400.0 * days
    while rel < ref - 43200.0:
        days += 1
        rel = since_start_tod_s + 86400.0 * days
    while rel >= ref + 43200.0:
        days -= 1
        rel = since_start_tod_s + 86400.0 * days
    return days, rel


class _AudioCutter:
    """The WAV's samples of walk times [lo, hi), copied block by block (``soundfile``), its format kept (RF64
    past 4 GiB); the cut's ``[audio] start_s`` is its first sample's walk time. At the acoustic reader's rate
    (48 kHz) the cut also states its first sample's index in the walk's WAV, ``first_sample``, and the walk
    time of the WAV's first sample, ``recording_start_s`` (the walk's ``start_s``): the reader aligns its
    receiver on the whole recording from them (:func:`walks.reader.read_acoustic_stream`)."""

    BLOCK = 1 << 18

    def __init__(self, path: Path, start_s: float):
        self.path, self.start_s = path, start_s
        info = sf.info(str(path))
        self.fs, self.n, self.subtype, self.channels = info.samplerate, info.frames, info.subtype, info.channels

    def write(self, d: Path, lo: float, hi: float, next_lo: float) -> dict:
        a0 = 0 if lo == -math.inf else min(self.n, max(0, round((lo - self.start_s) * self.fs)))
        a1 = self.n if hi == math.inf else min(self.n, max(a0, round((hi - self.start_s) * self.fs)))
        dtype = {"PCM_16": "int16", "PCM_32": "int32"}.get(self.subtype, "float32")
        size = (a1 - a0) * self.channels * 4
        with sf.SoundFile(str(self.path)) as src, \
                sf.SoundFile(str(d / self.path.name), "w", samplerate=self.fs, channels=self.channels,
                             subtype=self.subtype, format="WAV" if size < 2 ** 31 else "RF64") as out:
            src.seek(a0)
            left = a1 - a0
            while left > 0:
                x = src.read(min(self.BLOCK, left), dtype=dtype, always_2d=True)
                if not len(x):
                    break
                out.write(x)
                left -= len(x)
        out = {"audio_start_s": self.start_s + a0 / self.fs}
        if audio_cut_step(self.fs) != audio_cut_period(self.fs):      # aligned by index (48 kHz)
            out.update(audio_first_sample=int(a0), audio_recording_start_s=self.start_s)
        return out

    def close(self) -> None:
        pass
