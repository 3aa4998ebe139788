"""One walk from its files to its fused tracks: the path ``envfuse run`` and every ``evaluate`` task share.

:func:`fuse_walk` reads the walk (:func:`walks.reader.read_walk`), checks
that the model was trained for the walk's site (:func:`check_site`; a model
that names no sites applies anywhere), builds the filter inputs
(:func:`walks.inputs.walk_inputs`) and runs the requested methods
(:func:`walks.methods.run_methods`).
"""

from __future__ import annotations

import math
import os
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from features.errors import ConfigError, DataError, EnvfuseError
from models.fusion.calibration import NIS_WINDOWS_S
from models.fusion.ekf import FilterRun
from models.fusion.model import FusionModel
from walks.inputs import (HOP_S, WINDOW_S, ClassResume, EventsResume, SilentCut, WalkInputs, class_state_before,
                          events_state_before, walk_inputs)
from walks.methods import LAG_S, run_methods, track_state_before
from walks.reader import ReaderStates, WalkData, read_walk
from walks.segment_rts import SegmentedRts, add_rts_track, rts_rows
from walks.segments import SEGMENT_S, walk_cuts
from walks.track import TrackWriter, latest_per_time, track_rows

__all__ = ["FusedWalk", "fuse_walk", "check_site", "check_windows", "walk_name", "RunSummary", "fuse_to_file",
           "fuse_in_segments", "segmented_tracks", "RESUMED_METHODS", "warmup_for"]

RESUMED_METHODS = frozenset((
    "gnss", "acoustic", "uwb", "pdr", "kf", "kf_quality", "kf_map", "aekf", "imm", "adaptive", "adaptive_blind",
    "adaptive_nobp", "adaptive_nobp_blind", "uwb_aoa_pdr", "uwb_aoa_pdr_env", "uwb_aoa_pdr_blind"))
"""Methods whose track at a long walk's segment is the whole walk's with a short warm-up
(:data:`walks.segments.WARMUP_S`): the fixes' own tracks (``gnss``, ``acoustic``, ``uwb``: no state), ``pdr``, the
event filters and the UWB/PDR filters, which resume what the previous segment handed over
(:meth:`FusedWalk.handover`). Any other takes :data:`walks.segments.FRESH_WARMUP_S`: the factor graphs ``fg_*``
and ``ekf_rtk_pdr`` (:mod:`walks.graph_methods`) and ``foot_ins_fkf`` start afresh on each cut; a method
registered later, too; and ``adaptive_correction``, whose base filter resumes but whose BP correction reads the
filter's last update however long ago (its gain, innovation and the time since it, :func:`models.bp.bp_inputs`) and
whose innovation guard the last ten fixes (:func:`models.bp._innovation_off`), none handed over: after 20 s without
a fix before a seam the cut would feed it other inputs than the whole walk does. (The UWB/PDR filters took the
long warm-up until a resumed run fused its cut's first UWB fix and the steps before it,
:meth:`models.uwb_pdr.UwbPdrFilter.run`: a 600 s walk of seed 21 standing 37-218 s in a UWB gap, 60 s segments, 20 s
of warm-up: ``uwb_aoa_pdr`` 0.056 → 2.8e-7 m from the whole walk's, ``uwb_aoa_pdr_env`` 0.026 → 5.5e-7 m,
``uwb_aoa_pdr_blind`` 0.019 → 5.1e-7 m, ``bench/seam_identity.py``.)"""


def warmup_for(methods) -> float:
    """The warm-up a long walk's cuts need to fuse ``methods`` (None: every registered one), s:
    :data:`walks.segments.WARMUP_S` (read when called) when each is in :data:`RESUMED_METHODS` (its ``+lag`` /
    ``+rts`` tracks too), else :data:`walks.segments.FRESH_WARMUP_S` (measured on a 21-minute walk with 20 s:
    ``ekf_rtk_pdr`` 1.2 m and ``fg_isam2`` 0.7 m from the whole walk's, against 1e-9 and 0.11 m with 120 s)."""
    from walks import segments

    if methods is None:
        from walks.methods import method_names
        methods = method_names()
    bases = {str(m).split("+")[0] for m in methods}
    return segments.WARMUP_S if bases <= RESUMED_METHODS else max(segments.WARMUP_S, segments.FRESH_WARMUP_S)


NIS_HISTORY_S = max(NIS_WINDOWS_S)
"""How far back a handed-over filter state carries its run's NIS (:meth:`~models.fusion.ekf.FilterRun.state_before`):
the covariance calibrator's longest running mean (:data:`models.fusion.calibration.NIS_WINDOWS_S`), so that a
segment's calibrated covariance reads the whole walk's NIS, not its warm-up's (:func:`walks.calibrate.track_inputs`)."""

ROWS_PER_WRITE = 20_000
"""Track rows turned into text and written at a time by :func:`fuse_to_file`."""


@dataclass
class FusedWalk:
    """A walk's ``name`` (``<parent>/<dir>``), its ``data`` and ``inputs``, the ``tracks`` by method and the
    methods ``skipped`` with their reasons."""

    name: str
    data: WalkData
    inputs: WalkInputs | None
    """None for a long walk's later cut without an event (:class:`walks.inputs.SilentCut`): no track, and the
    hand-over is what the segment was handed."""
    tracks: dict
    skipped: dict
    results: dict = field(default_factory=dict)
    """Every method's raw result by name, the first passes included (:func:`walks.methods.run_methods`)."""

    resumed: "Handover | None" = None
    """What the previous segment of a long walk handed this one (None for a walk fused whole or a first segment)."""

    def handover(self, t_s: float, states_from_s: float) -> "Handover":
        """What the next segment of a long walk resumes from (``fuse_walk(resume=...)``): each filter's state
        before walk time ``t_s`` (the next segment's start; :meth:`~models.fusion.ekf.FilterRun.state_before`),
        the heading filter's after the last IMU sample before ``states_from_s`` and the acoustic receiver's that
        the read kept from then on (``fuse_walk(keep_states_from_s=states_from_s)``;
        :attr:`walks.segments.Segment.states_from_s`); ``states_from_s`` not finite: no reader state (the next
        cut reads from the walk's start, as the whole walk's read does).

        What this segment was handed goes on where its own run has nothing newer: a filter (or ``pdr``) without
        an event between the state it resumed from and ``t_s`` (the walker stood through the segment, or the
        method could not run on the cut) hands that state on, as does the class HMM without a window ending in
        that span, and the heading filter when the next cut resumes it no later than this cut did (a cut period
        of the audio grid longer than a segment: the two cuts start together). Otherwise the cut's warm-up
        epochs, filtered without the hand-over, would be handed as the whole walk's."""
        got = self.resumed if self.resumed is not None else Handover()
        filters = {}
        for name, res in self.results.items():
            state = res.state_before(t_s, NIS_HISTORY_S) if isinstance(res, FilterRun) else \
                track_state_before(name, res, t_s)
            if state is not None:
                filters[name] = _join_nis(state, got.filters.get(name), t_s)
        for name, old in got.filters.items():
            new = filters.get(name)
            if new is None or _event_time(new) < old.t_s:
                filters[name] = replace(old, t_s=float(t_s))
        if self.inputs is None:                      # a silent cut: nothing newer than what it was handed
            events, classes = got.events, None
        else:
            events = events_state_before(self.inputs, t_s, got.events if self.resumed is not None else None)
            classes = class_state_before(self.inputs, t_s)
        if got.classes is not None and (classes is None or classes.t_end_s < got.classes.t_end_s):
            classes = got.classes
        if not math.isfinite(states_from_s):
            return Handover(filters, ReaderStates(), classes, events)
        heading = None
        pdr = self.data.pdr
        if getattr(pdr, "imu", None) is not None and pdr.result.heading is not None:
            i = int(np.searchsorted(pdr.imu.t_s, states_from_s, side="left")) - 1
            if i >= 0:
                heading = pdr.result.heading.state_at(i, float(pdr.imu.t_s[i]))
        old = got.readers.heading
        if old is not None and (heading is None or not heading.t_s > old.t_s):
            heading = old
        receiver = self.data.acoustic.analysis.receiver_state if self.data.acoustic is not None else None
        gnss = self.data.gnss.fluct_state if self.data.gnss is not None else None
        if got.readers.gnss is not None and (gnss is None or not gnss.t_s > got.readers.gnss.t_s):
            gnss = got.readers.gnss
        return Handover(filters, ReaderStates(heading, receiver, gnss), classes, events)


def _join_nis(state, resumed, t_s: float):
    """``state``'s NIS history with its events before the state this run ``resumed`` from (the cut's warm-up,
    filtered without it: a segment shorter than :data:`NIS_HISTORY_S`) replaced by that state's own history."""
    if resumed is None or resumed.nis_t_s is None or state.nis_t_s is None:
        return state
    old = (resumed.nis_t_s >= t_s - NIS_HISTORY_S) & (resumed.nis_t_s < resumed.t_s)
    mine = state.nis_t_s >= resumed.t_s
    if mine.all() and not old.any():
        return state
    return replace(state, nis_t_s=np.concatenate([resumed.nis_t_s[old], state.nis_t_s[mine]]),
                   nis=np.concatenate([resumed.nis[old], state.nis[mine]]))


def _event_time(state) -> float:
    """Walk time of the event a handed filter state follows (its hand-over time when it does not say)."""
    return state.event_t_s if math.isfinite(state.event_t_s) else state.t_s


@dataclass(frozen=True)
class Handover:
    """What a segment of a long walk hands the next (:mod:`walks.segments`): ``filters``, by filter method name,
    the state (:class:`~models.fusion.ekf.FilterResume`) each resumes from at the segment's start, and
    ``readers``, the readers' states the cut is read from (:class:`~walks.reader.ReaderStates`); ``classes``,
    the class HMM's forward state (:class:`~walks.inputs.ClassResume`, None without a window); ``events``, what
    the walk's event stream held before the segment (:class:`~walks.inputs.EventsResume`, None: not known)."""

    filters: dict = field(default_factory=dict)
    readers: ReaderStates = ReaderStates()
    classes: ClassResume | None = None
    events: EventsResume | None = None


def walk_name(walk_dir: str | os.PathLike) -> str:
    """``<parent>/<dir>`` of a walk directory, e.g. ``201/w0``."""
    p = Path(walk_dir).resolve()
    return f"{p.parent.name}/{p.name}"


def check_site(model: FusionModel, site_name: str, walk: str, force: bool = False) -> None:
    """Refuse (:class:`~features.errors.ConfigError`) a walk of a site the model was not trained for, unless
    ``force``; a model whose metadata names no sites (e.g. one fitted for held-out sites) applies anywhere."""
    sites = model.meta.get("sites", [])
    if sites and site_name not in sites and not force:
        raise ConfigError(f"{walk}: site {site_name!r} is not one the model was trained on ({', '.join(sites)}); "
                          "pass --force to fuse it anyway")


def check_windows(env_meta: dict, where: str) -> None:
    """Refuse (:class:`~features.errors.ConfigError`) an environment model fitted on feature windows other
    than those a walk is classified on (:data:`walks.inputs.WINDOW_S`, hop :data:`walks.inputs.HOP_S`): its class
    probabilities would describe another statistic. A model that states no window predates the check and was
    fitted on the only windows there were then (2 s, hop 1 s)."""
    window, hop = env_meta.get("window_s"), env_meta.get("hop_s")
    if window is None and hop is None:
        return
    if abs(float(window) - WINDOW_S) > 1e-9 or abs(float(hop) - HOP_S) > 1e-9:
        raise ConfigError(f"{where} was fitted on {float(window):g} s windows (hop {float(hop):g} s) but walks are "
                          f"classified on {WINDOW_S:g} s windows (hop {HOP_S:g} s): rebuild the library with "
                          f"'survey build --window-s {WINDOW_S:g} --hop-s {HOP_S:g} --replace' and refit")



def fuse_walk(walk_dir: str | os.PathLike, model: FusionModel, methods=None, *, smooth: bool = True,
              lag_s: float | None = LAG_S, class_map_for: Callable | None = None, force: bool = False,
              truth: bool = True, class_smoothing: str = "forward", resume: "Handover | None" = None,
              keep_states_from_s: float = math.inf) -> FusedWalk:
    """Read ``walk_dir`` and run ``methods`` (default: all) on it with ``model``.

    ``class_map_for``: callable site → :class:`~models.fusion.events.ClassMap` or None, the site map of the
    map baseline (``kf_map``), called only when that method is asked for. ``smooth``: the filters' RTS tracks
    too; ``lag_s``: their fixed-lag tracks with that lag (None: none). ``truth=False``: leave ``truth.csv``
    unread (``run``). ``class_smoothing``: how the model's class HMM smooths the window classes
    (:data:`walks.inputs.CLASS_SMOOTHING`; ``"forward"``, causal, as ``run`` needs). ``resume``: the filter and reader
    states the previous segment of a long walk handed over (:meth:`FusedWalk.handover`; :mod:`walks.segments`);
    ``keep_states_from_s``: the next segment's cut's start (:func:`walks.reader.read_walk`). A domain
    error raised past the read names the walk.
    """
    name = walk_name(walk_dir)
    data = read_walk(walk_dir, truth=truth, resume=None if resume is None else resume.readers,
                     keep_states_from_s=keep_states_from_s)
    check_site(model, data.site.name, str(walk_dir), force)
    check_windows(model.meta.get("env_meta", {}), "the model's environment classifier")
    if data.gnss is None and data.acoustic is None and data.pdr is None:
        if resume is not None:          # a later cut of a long walk, every stream silent through it
            return FusedWalk(name, data, None, {}, {}, {}, resume)
        why = "; ".join(data.notes) if data.notes else "walk.toml names no gnss, audio or imu stream"
        raise DataError(f"{walk_dir}: no usable stream to fuse ({why})")
    try:
        try:
            inputs = walk_inputs(data, model.classifier, model.temporal, class_smoothing,
                                 None if resume is None else resume.classes, resumed=resume is not None,
                                 events_resume=None if resume is None else resume.events)
        except SilentCut:
            return FusedWalk(name, data, None, {}, {}, {}, resume)
        if resume is not None and resume.filters:
            inputs = replace(inputs, resume=dict(resume.filters))
        want = methods
        class_at = None
        if class_map_for is not None and (want is None or "kf_map" in want):
            class_at = class_map_for(data.site)
        results: dict = {}
        tracks, skipped = run_methods(model, inputs, want, smooth=smooth, class_at=class_at, lag_s=lag_s,
                                      results=results)
    except EnvfuseError as exc:
        if str(walk_dir) in str(exc):
            raise
        raise DataError(f"{walk_dir}: {exc}") from None
    return FusedWalk(name, data, inputs, tracks, skipped, results, resume)


def fuse_in_segments(walk_dir: str | os.PathLike, model: FusionModel, methods=None, segment_s: float = SEGMENT_S,
                     *, workdir: str | os.PathLike | None = None, **fuse_kw):
    """The segments of a long walk fused one after the other, each resuming what the previous one handed over
    (:mod:`walks.segments`, :meth:`FusedWalk.handover`): yields (:class:`~walks.segments.Segment`,
    :class:`FusedWalk`) in time order, the cut deleted once the next is asked for. ``fuse_kw``: as
    :func:`fuse_walk`. A walk of one segment yields its whole-walk fusion."""
    resume = None
    for seg in walk_cuts(walk_dir, segment_s, workdir=workdir, warmup_s=warmup_for(methods)):
        fused = fuse_walk(seg.directory, model, methods, resume=resume, keep_states_from_s=seg.states_from_s,
                          **fuse_kw)
        resume = fused.handover(seg.own_to_s, seg.states_from_s)
        yield seg, fused
        del fused        # one segment's pipeline at a time (the caller drops its reference too)


def segmented_tracks(walk_dir: str | os.PathLike, model: FusionModel, methods=None, segment_s: float = SEGMENT_S,
                     **fuse_kw) -> dict:
    """Every track of a walk fused in segments (:func:`fuse_in_segments`) as ``{name: (t_s, east_m, north_m)}``,
    each the concatenation of the epochs its segments own (a ``+rts`` track the whole walk's smoother over them,
    :mod:`walks.segment_rts`, as ``run`` and ``evaluate`` give it): what the whole walk's ``fuse_walk(...).tracks``
    give, for comparing the two (bench/seam_identity.py). Holds every epoch: for measuring, not for long runs."""
    parts: dict = {}
    with ExitStack() as stack:
        smoothers: dict = {}        # the +rts tracks: the whole walk's smoother, as run and evaluate give them
        for seg, fused in fuse_in_segments(walk_dir, model, methods, segment_s, **fuse_kw):
            for name, tr in fused.tracks.items():
                k = seg.owns(tr.t_s)
                if name.endswith("+rts") and not seg.whole:
                    if name not in smoothers:
                        smoothers[name] = stack.enter_context(SegmentedRts())
                    if add_rts_track(smoothers[name], fused, name, k, rows=False):
                        parts.setdefault(name, [])
                        continue
                parts.setdefault(name, []).append((tr.t_s[k], tr.east_m[k], tr.north_m[k]))
            del fused
        for name, store in smoothers.items():
            store.smooth()
            parts[name] += [(p["t_s"], p["east_m"], p["north_m"]) for p in store.segments()]
    return {name: tuple(np.concatenate(c) for c in zip(*p)) for name, p in parts.items() if p}


@dataclass
class RunSummary:
    """What :func:`fuse_to_file` wrote: ``n`` epochs, ``placed`` with a position, ``ood`` out of the classifier's
    distribution, the readers' ``notes`` (each once), the ``segments`` fused and those ``skipped`` (why)."""

    n: int = 0
    placed: int = 0
    ood: int = 0
    notes: list = field(default_factory=list)
    segments: int = 0
    skipped: list = field(default_factory=list)


def fuse_to_file(walk_dir: str | os.PathLike, model: FusionModel, method: str, path, fmt: str, *,
                 properties: dict | None = None, lag_s: float | None = LAG_S, class_map_for: Callable | None = None,
                 force: bool = False, segment_s: float = SEGMENT_S,
                 progress: Callable[[int], None] | None = None) -> RunSummary:
    """``envfuse run``: one method's track of a walk written to ``path`` (the output's temporary file) in
    ``fmt`` (``csv`` / ``geojson``), segment by segment (:mod:`walks.segments`) and a block of rows at a time,
    so that memory does not grow with the walk. ``method``: a registered name, ``+rts`` / ``+lag`` for its
    smoothed tracks (``lag_s``). A walk of one segment gives the bytes its whole-walk track gives; a ``+rts`` track of
    a longer walk is the whole walk's smoother (:mod:`walks.segment_rts`), its rows written once every segment is
    filtered.

    A segment where the method cannot run (no fix in it, ...) is left out with its reason in ``skipped``
    (``n`` is 0 when it ran on none). ``progress``: called with the number of segments fused so far after each
    (:func:`walks.segments.plan_segments` says how many there will be).
    """
    base = method.split("+")[0]
    out = RunSummary()
    writer = TrackWriter(path, fmt, properties)
    workdir = os.path.dirname(os.path.abspath(path))
    resume = None
    try:
        with ExitStack() as stack:
            # a +rts track of a walk in several segments: the whole walk's smoother (walks.segment_rts), its
            # rows written once the backward pass is done
            rts = stack.enter_context(SegmentedRts(workdir)) if method.endswith("+rts") else None
            origin = None
            for seg in walk_cuts(walk_dir, segment_s, workdir=workdir, warmup_s=warmup_for((base,))):
                where = str(walk_dir) if seg.whole else \
                    f"{walk_dir} (segment {seg.index}: {seg.span_text})"
                try:
                    fused = fuse_walk(seg.directory, model, (base,), smooth=method.endswith("+rts"),
                                      lag_s=lag_s if method.endswith("+lag") else None, class_map_for=class_map_for,
                                      force=force, truth=False, resume=resume,
                                      keep_states_from_s=seg.states_from_s)
                except EnvfuseError as exc:
                    raise type(exc)(str(exc).replace(str(seg.directory), where)) from None
                resume = fused.handover(seg.own_to_s, seg.states_from_s)
                out.segments += 1
                if progress is not None:
                    progress(out.segments)
                out.notes += [n for n in fused.data.notes if n not in out.notes]
                if fused.inputs is None:
                    out.notes.append(f"{seg.span_text}: no event in any stream (no step, GNSS or acoustic fix), "
                                     "so no epoch there")
                    continue
                if method not in fused.tracks:
                    out.skipped.append((where, fused.skipped.get(base, "no output")))
                    continue
                note = fused.tracks[method].info.get("note")
                if note and f"{method}: {note}" not in out.notes:
                    out.notes.append(f"{method}: {note}")
                if rts is not None and not seg.whole and \
                        add_rts_track(rts, fused, method, seg.owns(fused.tracks[method].t_s)):
                    origin = fused.data.site.origin
                else:
                    _write_owned(writer, fused, fused.tracks[method], seg, out)
                del fused
            if rts is not None and len(rts):
                rts.smooth()
                calibrator = (getattr(model, "calibration", None) or {}).get(method)
                for part in rts.segments():
                    last = latest_per_time(part["t_s"])
                    part = {k: v[last] for k, v in part.items()}
                    for lo in range(0, len(part["t_s"]), ROWS_PER_WRITE):
                        _write_rows(writer, rts_rows({k: v[lo:lo + ROWS_PER_WRITE] for k, v in part.items()},
                                                     calibrator, origin), out)
    finally:
        writer.close()
    return out


def _write_owned(writer: TrackWriter, fused: FusedWalk, track, seg, out: RunSummary) -> None:
    """Write the epochs of ``track`` that ``seg`` owns, ROWS_PER_WRITE at a time; count them into ``out``."""

    own = np.flatnonzero(seg.owns(track.t_s) & latest_per_time(track.t_s))
    for lo in range(0, own.size, ROWS_PER_WRITE):
        keep = np.zeros(len(track), bool)
        keep[own[lo:lo + ROWS_PER_WRITE]] = True
        part = track if own.size == len(track) <= ROWS_PER_WRITE else track.take(keep)
        _write_rows(writer, track_rows(part, fused.inputs), out)


def _write_rows(writer: TrackWriter, rows: list[dict], out: RunSummary) -> None:
    """Write ``rows``; count them, those with a position and those out of distribution into ``out``."""
    writer.write(rows)
    out.n += len(rows)
    out.placed += sum(math.isfinite(r["east_m"]) and math.isfinite(r["north_m"]) for r in rows)
    out.ood += sum(r["ood"] for r in rows)
