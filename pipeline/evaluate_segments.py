"""``evaluate`` of a walk longer than one segment: each segment fused alone (:mod:`walks.segments`), its own
epochs scored against the truth, nothing of it kept but its errors.

The per-walk result is what :func:`pipeline.evaluate.evaluate_walk` returns for a short walk — metric rows
and the per-epoch series the plots and the pooled metrics are made of — built from the segments' owned
epochs. What it keeps per epoch of each method's track is that series (time, error, east, north, NEES as
float32, the truth class as int8: 21 bytes) and the error and NEES as float64 for the walk's metric rows
(16 bytes): 37 bytes per epoch and track, about 1.3 MB per hour per track at ten epochs a second. That part
is O(walk length) by what ``evaluate`` reports (exact medians and 95th percentiles over every epoch, error
CDFs); everything else is bounded by one segment's pipeline.

A ``+rts`` track is the whole walk's RTS smoother (:class:`walks.segment_rts.SegmentedRts`: each segment's
owned filter events stored in a temporary folder, one backward pass once the walk is read), scored against the
truth each segment kept at its epochs. The factor graphs (``fg_*``) and ``ekf_rtk_pdr+rts`` are still each cut's
own (their cuts start afresh, :data:`walks.fuse.RESUMED_METHODS`). The stores take temporary disk (``$TMPDIR``)
in proportion to the walk: about 0.1-1 KB per filter event for each filter's ``+rts`` (walks/segment_rts.py), about
1.3 GB for an 8-hour walk when every method is evaluated; evaluating fewer methods (``--methods``) takes less.
"""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import numpy as np

from features.errors import DataError
from walks.inputs import WINDOW_S
from walks.score import errors_at, metric_rows, track_errors
from walks.segment_rts import SegmentedRts, add_rts_track, smoothed_covariance
from walks.segments import SEGMENT_S
from walks.track import Track, latest_per_time

__all__ = ["evaluate_segmented"]


def evaluate_segmented(walk, model, methods, class_map_for, force: bool, name: str,
                       segment_s: float = SEGMENT_S, progress=None) -> dict:
    """:func:`pipeline.evaluate.evaluate_walk`'s result for a walk fused in segments of ``segment_s`` (module
    docstring); ``name``: the walk's report name; ``progress(k)``, if given, is called once the walk's k-th segment
    is scored."""
    from walks.fuse import fuse_in_segments

    parts: dict = {}
    truth_parts, window_parts, notes, skipped = [], [], [], {}
    shares = {"bp_disabled_share": [], "bp_guard_share": []}
    site = None
    smoothers: dict = {}        # +rts track name → its SegmentedRts
    with ExitStack() as stack:
        for k, (seg, fused) in enumerate(fuse_in_segments(walk, model, methods, segment_s,
                                                          class_map_for=class_map_for, force=force), 1):
            site = _score_segment(walk, seg, fused, parts, smoothers, stack, truth_parts, window_parts, notes,
                                  skipped, shares)
            del fused
            if progress is not None:
                progress(k)
        for m, store in smoothers.items():
            _score_smoothed(m, store, (getattr(model, "calibration", None) or {}).get(m), parts)
    rows, series = [], {}
    for m, segs in parts.items():
        if not segs:            # a +rts track whose filter owned no event in any segment
            continue
        err = np.concatenate([te["err_m"] for te, _, _ in segs])
        nees = np.concatenate([te["nees"] for te, _, _ in segs])
        cls = np.concatenate([te["cls"] for te, _, _ in segs])
        if len(err):
            rows += metric_rows(err, nees, cls, name, m)
        series[m] = {"t_s": np.concatenate([te["t_s"] for te, _, _ in segs]).astype(np.float32),
                     "err_m": err.astype(np.float32), "east_m": np.concatenate([e for _, e, _ in segs]).astype(np.float32),
                     "north_m": np.concatenate([n for _, _, n in segs]).astype(np.float32),
                     "cls": cls.astype(np.int8), "nees": nees.astype(np.float32)}
    if not rows:
        why = "; ".join(f"{m}: {r}" for m, r in skipped.items()) or "no track overlaps the truth in time"
        raise DataError(f"{walk}: no method gave a track to score ({why})")
    cat = [np.concatenate(c) for c in zip(*truth_parts)]
    series["_truth"] = {"t_s": cat[0].astype(np.float32), "cls": cat[1].astype(np.int8),
                        "east_m": cat[2].astype(np.float32), "north_m": cat[3].astype(np.float32)}
    if window_parts:
        t_w, p_w = (np.concatenate(c) for c in zip(*window_parts))
        series["_windows"] = {"t_s": (t_w - WINDOW_S / 2.0).astype(np.float32), "proba": p_w.astype(np.float32)}
    return {"walk": name, "walk_dir": str(walk), "rows": rows, "skipped": {m: w for m, w in skipped.items()
                                                                          if m not in parts},
            "series": series, "site": site, "notes": notes,
            **{k: (float(np.mean(v)) if v else None) for k, v in shares.items()}}


def _score_segment(walk, seg, fused, parts, smoothers, stack, truth_parts, window_parts, notes, skipped,
                   shares) -> str:
    """Score one segment's owned epochs into ``parts`` (a ``+rts`` track's events into its smoother in
    ``smoothers``, scored by :func:`_score_smoothed` once the walk is read); returns the walk's site."""
    data = fused.data
    outside = data.truth is None and not seg.whole and (Path(walk) / "truth.csv").is_file()
    if data.truth is None and not outside:
        raise DataError(f"{walk}: no truth.csv, so no error to measure (evaluate scores tracks against truth; "
                        "'envfuse run' writes a walk's track without one)")
    notes += [n for n in data.notes if n not in notes]
    if outside:
        # a cut outside the truth's span (walks.segments drops its truth): its epochs are not scored, as the
        # whole walk scores none outside its truth's span; a +rts track still takes its events
        notes.append(f"{seg.span_text}: no truth there, so their epochs are not scored")
    for m, why in fused.skipped.items():
        skipped.setdefault(m, why)
    truth = data.truth
    for m, tr in fused.tracks.items():
        keep = seg.owns(tr.t_s)
        if m.endswith("+rts"):
            if m not in smoothers:
                smoothers[m] = stack.enter_context(SegmentedRts())
            # the truth at the owned epochs inside its span, for scoring the whole walk's smoothed track
            t = tr.t_s[keep]
            in_span = np.zeros(len(t), bool) if truth is None else (t >= truth.t_s[0]) & (t <= truth.t_s[-1])
            te, tn = np.full(len(t), np.nan), np.full(len(t), np.nan)
            cls = np.full(len(t), -1)
            if in_span.any():
                te[in_span], tn[in_span] = truth.at(t[in_span])
                cls[in_span] = truth.class_at(t[in_span])
            extras = {"in_span": in_span, "truth_east": te, "truth_north": tn, "truth_cls": cls}
            if add_rts_track(smoothers[m], fused, m, keep, rows=False, extras=extras):
                parts.setdefault(m, [])         # the report's order of methods: the first segment's
                continue
        if truth is None:
            continue
        own = tr.take(keep)
        te = track_errors(own, truth)
        parts.setdefault(m, []).append((te, own.east_m[te["ok"]], own.north_m[te["ok"]]))
    _shares(fused.tracks, shares)
    if truth is not None:
        k = seg.owns(truth.t_s)
        truth_parts.append((truth.t_s[k], truth.env_class[k], truth.east_m[k], truth.north_m[k]))
    w = fused.inputs
    if w is not None and len(w.window_t_s):        # (None: a cut without an event, walks.inputs.SilentCut)
        k = seg.owns(w.window_t_s)
        window_parts.append((w.window_t_s[k], w.classes.proba[1:][k]))
    return data.site.name


def _score_smoothed(m: str, store: SegmentedRts, calibrator, parts: dict) -> None:
    """The whole walk's ``+rts`` track ``m`` (the backward pass over ``store``) scored into ``parts``."""
    store.smooth()
    for part in store.segments():
        tr = Track(m, part["t_s"], part["east_m"], part["north_m"], smoothed_covariance(part, calibrator))
        ok = part["in_span"] & np.isfinite(tr.east_m) & latest_per_time(tr.t_s)
        te = errors_at(tr, ok, part["truth_east"][ok], part["truth_north"][ok], part["truth_cls"][ok])
        parts.setdefault(m, []).append((te, tr.east_m[ok], tr.north_m[ok]))


def _shares(tracks: dict, shares: dict) -> None:
    """The BP guard shares of a segment's tracks (averaged over the segments by the caller)."""
    if "adaptive_correction" in tracks and tracks["adaptive_correction"].info.get("bp_disabled_share") is not None:
        shares["bp_disabled_share"].append(tracks["adaptive_correction"].info["bp_disabled_share"])
    if "adaptive" in tracks:
        g = tracks["adaptive"].info["run"].info.get("bp_guard_share")
        if g is not None:
            shares["bp_guard_share"].append(g)
