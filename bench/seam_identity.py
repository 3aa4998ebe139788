"""Every method's track of a walk fused in segments against the same walk fused whole (issue 25 item 3).

For each track (``<method>``, ``+lag``, ``+rts``) the epochs the segments own are matched to the whole walk's
by time (within 1 µs) and the largest and median horizontal distance between the two positions printed, with
the epochs only one side has. ``--no-handover`` drops what a segment hands the next (each segment started
afresh at its cut, the state before issue 25's hand-over); ``--warmup-s`` changes
:data:`walks.segments.WARMUP_S`, the warm-up of the methods that resume the previous segment
(:data:`walks.fuse.RESUMED_METHODS`); the others (factor graphs, ``ekf_rtk_pdr``, ``foot_ins_fkf``), which start
afresh on each cut, are fused in segments of their own warm-up, :data:`walks.segments.FRESH_WARMUP_S`
(``--fresh-warmup-s``), as ``envfuse run`` fuses them (:func:`walks.fuse.warmup_for`). On a checkout without
that split every method takes ``WARMUP_S``. The segment loop is written here (``walk_cuts`` → ``fuse_walk`` →
``handover``) rather than taken from :func:`walks.fuse.segmented_tracks`, so that the same script measures an
older checkout (``PYTHONPATH`` at it) for a before/after table::

    PYTHONPATH=$PWD .venv/bin/python bench/seam_identity.py --model demo_out/fusion_model \\
        --segment-s 300 /tmp/seams/w77 /tmp/seams/w78
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np


def segmented(walk: str, model, methods, segment_s: float, handover: bool, class_map_for) -> dict:
    """{track: (t, e, n)} of the epochs each segment owns."""
    from walks.fuse import fuse_walk
    from walks.segments import walk_cuts

    parts: dict = {}
    resume = None
    for seg in walk_cuts(walk, segment_s):
        fused = fuse_walk(seg.directory, model, methods, class_map_for=class_map_for, force=True,
                          resume=resume if handover else None, keep_states_from_s=seg.states_from_s)
        resume = fused.handover(seg.own_to_s, seg.states_from_s)
        for name, tr in fused.tracks.items():
            k = seg.owns(tr.t_s)
            parts.setdefault(name, []).append((tr.t_s[k], tr.east_m[k], tr.north_m[k]))
        del fused
    return {name: tuple(np.concatenate(c) for c in zip(*p)) for name, p in parts.items()}


def match_epochs(tw: np.ndarray, ts: np.ndarray, tol_s: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """(indices into ``ts``, indices into ``tw``) of the epochs both hold: equal times within ``tol_s``, the
    k-th of several epochs at one time (a step split at a fix, and the fix) matched to the k-th."""
    def keyed(t):
        key = np.rint(np.asarray(t, float) / tol_s).astype(np.int64)
        first = np.searchsorted(key, key, side="left")
        return list(zip(key.tolist(), (np.arange(len(key)) - first).tolist()))

    where = {k: i for i, k in enumerate(keyed(tw))}
    pairs = [(i, where[k]) for i, k in enumerate(keyed(ts)) if k in where]
    if not pairs:
        return np.zeros(0, int), np.zeros(0, int)
    a, b = np.array(pairs).T
    return a, b


def compare(whole: dict, seg: dict) -> list[dict]:
    """Per track: epochs matched, only-whole, only-segmented, max and median distance (m) where both are finite."""
    rows = []
    for name in sorted(set(whole) | set(seg)):
        if name not in whole or name not in seg:
            rows.append({"track": name, "note": "whole only" if name in whole else "segmented only"})
            continue
        tw, ew, nw = whole[name]
        ts, es, ns = seg[name]
        i, j = match_epochs(tw, ts)
        d = np.hypot(es[i] - ew[j], ns[i] - nw[j])
        fin = np.isfinite(d)
        both_nan = np.isnan(es[i]) & np.isnan(ew[j])
        rows.append({"track": name, "matched": len(i), "whole_only": len(tw) - len(j), "seg_only": len(ts) - len(i),
                     "nan_one_side": int((~fin & ~both_nan).sum()),
                     "max_m": float(d[fin].max()) if fin.any() else math.nan,
                     "median_m": float(np.median(d[fin])) if fin.any() else math.nan,
                     "worst_t_s": float(ts[i][fin][np.argmax(d[fin])]) if fin.any() else math.nan})
    return rows


def _warmup_groups(methods) -> list[tuple[float, tuple | None]]:
    """[(warm-up s, methods)]: the resumed methods at ``WARMUP_S``, the others at ``FRESH_WARMUP_S``
    (:func:`walks.fuse.warmup_for`); one group at ``WARMUP_S`` on a checkout without the split."""
    from walks import segments
    try:
        from walks.fuse import RESUMED_METHODS
    except ImportError:
        return [(segments.WARMUP_S, methods)]
    from walks.methods import method_names

    names = method_names() if methods is None else methods
    resumed = tuple(m for m in names if m.split("+")[0] in RESUMED_METHODS)
    fresh = tuple(m for m in names if m.split("+")[0] not in RESUMED_METHODS)
    out = [(segments.WARMUP_S, resumed)] if resumed else []
    return out + ([(max(segments.WARMUP_S, segments.FRESH_WARMUP_S), fresh)] if fresh else [])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("walks", nargs="+")
    ap.add_argument("--model", required=True)
    ap.add_argument("--segment-s", type=float, default=300.0)
    ap.add_argument("--warmup-s", type=float, default=None)
    ap.add_argument("--fresh-warmup-s", type=float, default=None, help="walks.segments.FRESH_WARMUP_S")
    ap.add_argument("--tail-s", type=float, default=None, help="walks.segments.TAIL_S")
    ap.add_argument("--resume-after-s", type=float, default=None, help="walks.segments.RESUME_AFTER_S")
    ap.add_argument("--methods", default=None, help="comma-separated (default: every registered one)")
    ap.add_argument("--no-handover", action="store_true")
    args = ap.parse_args(argv)

    from pipeline.evaluate import load_model
    from pipeline.site_map import class_map_for
    from walks import segments
    from walks.fuse import fuse_walk

    for name, v in (("WARMUP_S", args.warmup_s), ("TAIL_S", args.tail_s), ("RESUME_AFTER_S", args.resume_after_s),
                    ("FRESH_WARMUP_S", args.fresh_warmup_s)):
        if v is not None:
            setattr(segments, name, v)
    model = load_model(args.model)
    methods = None if args.methods is None else tuple(args.methods.split(","))
    groups = _warmup_groups(methods)
    for walk in args.walks:
        c0 = time.process_time()
        fused = fuse_walk(walk, model, methods, class_map_for=class_map_for, force=True)
        whole = {n: (tr.t_s, tr.east_m, tr.north_m) for n, tr in fused.tracks.items()}
        del fused
        c1 = time.process_time()
        seg = {}
        for warmup, group in groups:
            saved, segments.WARMUP_S = segments.WARMUP_S, warmup
            try:
                seg.update(segmented(walk, model, group, args.segment_s, not args.no_handover, class_map_for))
            finally:
                segments.WARMUP_S = saved
        c2 = time.process_time()
        warm = ", ".join(f"{w:g} s ({'all' if g is None else len(g)} methods)" for w, g in groups)
        print(f"\n{walk}: segments of {args.segment_s:g} s, warm-up {warm}, "
              f"tail {segments.TAIL_S:g} s, resume after {segments.RESUME_AFTER_S:g} s, "
              f"hand-over {'off' if args.no_handover else 'on'}; CPU whole {c1 - c0:.1f} s, segmented {c2 - c1:.1f} s")
        print(f"{'track':28s} {'matched':>8s} {'whole-only':>10s} {'seg-only':>9s} {'nan-1side':>9s} "
              f"{'max m':>10s} {'median m':>10s} {'worst at s':>10s}")
        for r in compare(whole, seg):
            if "note" in r:
                print(f"{r['track']:28s} {r['note']}")
                continue
            print(f"{r['track']:28s} {r['matched']:8d} {r['whole_only']:10d} {r['seg_only']:9d} {r['nan_one_side']:9d} "
                  f"{r['max_m']:10.3g} {r['median_m']:10.3g} {r['worst_t_s']:10.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
