"""``evaluate`` of a walk longer than one segment: each segment fused alone (:mod:`walks.segments`), its own
epochs scored against the truth, nothing of it kept but its errors.

The per-walk result is what :func:`pipeline.evaluate.evaluate_walk` returns for a short walk — metric rows
and the per-epoch series the plots and the pooled metrics are made of — built from the segments' owned
epochs. What it keeps per epoch of each method's track is that series (time, error, east, north, NEES as
float32, the truth class as int8: 21 bytes) and the error and NEES as float64 for the walk's metric rows
(16 bytes): 37 bytes per epoch and track, about 1.3 MB per hour per track at ten epochs a second. That part
is O(walk length) by what ``evaluate`` reports (exact medians and 95th percentiles over every epoch, error
CDFs); everything else is bounded by one segment's pipeline.

Methods that are whole-walk by nature are run per segment here: a ``+rts`` track is the RTS smoother over
its segment's cut (warm-up and tail included), not over the whole walk: what that loses near a seam is measured
in :mod:`walks.segments`.
"""

from __future__ import annotations

import numpy as np

from features.errors import DataError
from walks.inputs import WINDOW_S
from walks.score import metric_rows, track_errors
from walks.segments import SEGMENT_S

__all__ = ["evaluate_segmented"]


def evaluate_segmented(walk, model, methods, class_map_for, force: bool, name: str,
                       segment_s: float = SEGMENT_S) -> dict:
    """:func:`pipeline.evaluate.evaluate_walk`'s result for a walk fused in segments of ``segment_s`` (module
    docstring); ``name``: the walk's report name."""
    from walks.fuse import fuse_in_segments

    parts: dict = {}
    truth_parts, window_parts, notes, skipped = [], [], [], {}
    shares = {"bp_disabled_share": [], "bp_guard_share": []}
    site = None
    for seg, fused in fuse_in_segments(walk, model, methods, segment_s, class_map_for=class_map_for, force=force):
        data = fused.data
        if data.truth is None:
            raise DataError(f"{walk}: no truth.csv, so no error to measure (evaluate scores tracks against truth; "
                            "'envfuse run' writes a walk's track without one)")
        site = data.site.name
        notes += [n for n in data.notes if n not in notes]
        for m, why in fused.skipped.items():
            skipped.setdefault(m, why)
        for m, tr in fused.tracks.items():
            own = tr.take(seg.owns(tr.t_s))
            te = track_errors(own, data.truth)
            parts.setdefault(m, []).append((te, own.east_m[te["ok"]], own.north_m[te["ok"]]))
        _shares(fused.tracks, shares)
        t = data.truth
        k = seg.owns(t.t_s)
        truth_parts.append((t.t_s[k], t.env_class[k], t.east_m[k], t.north_m[k]))
        w = fused.inputs
        if len(w.window_t_s):
            k = seg.owns(w.window_t_s)
            window_parts.append((w.window_t_s[k], w.classes.proba[1:][k]))
        del fused, data
    rows, series = [], {}
    for m, segs in parts.items():
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


def _shares(tracks: dict, shares: dict) -> None:
    """The BP guard shares of a segment's tracks (averaged over the segments by the caller)."""
    if "adaptive_correction" in tracks and tracks["adaptive_correction"].info.get("bp_disabled_share") is not None:
        shares["bp_disabled_share"].append(tracks["adaptive_correction"].info["bp_disabled_share"])
    if "adaptive" in tracks:
        g = tracks["adaptive"].info["run"].info.get("bp_guard_share")
        if g is not None:
            shares["bp_guard_share"].append(g)
