"""Every method's track on given walks, saved, or checked against a saved set: a refactor must not move a track.

``--save FILE`` writes each method's (and each ``+rts``'s) times, positions and
covariances on the walks; ``--check FILE`` recomputes them and prints, per
method, the largest difference in position (m) and covariance (m²) from the
saved ones, failing (exit 1) above ``--tol-m`` (default 1e-9 m) or when a
method's set of epochs changed.

Issue 19 (the walk floor and the one compiled filter core) was checked this way
on the demo split's held-out walks 201/w0 and 201/w1 with the demo's model: the
reference was saved by the code before the change (commit 5999b0c, the same
tracks through its ``pipeline.fusion.run_methods``), and checked after it::

    .venv/bin/python bench/track_identity.py --check ref.npz --model demo_out/fusion_model \\
        demo_out/data/walks/201/w0 demo_out/data/walks/201/w1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np


def tracks_of(walks: list[str], model_dir: str) -> dict:
    """{'<walk>|<method>|t|e|n|cov': array} of every registered method (and +rts) on ``walks``."""
    from pipeline.evaluate import load_model
    from pipeline.site_map import class_map_for
    from walks.fuse import fuse_walk

    out = {}
    model = load_model(model_dir)
    for w in walks:
        fused = fuse_walk(w, model, class_map_for=class_map_for, force=True)
        for name, tr in fused.tracks.items():
            key = f"{fused.name}|{name}"
            out[key + "|t"], out[key + "|e"], out[key + "|n"] = tr.t_s, tr.east_m, tr.north_m
            if tr.cov_m2 is not None:
                out[key + "|cov"] = tr.cov_m2
    return out


def compare(ref: dict, new: dict, tol_m: float) -> bool:
    """Print the largest differences per method; True when every track agrees within ``tol_m``."""
    ok = True
    methods = sorted({k.rsplit("|", 1)[0] for k in ref} | {k.rsplit("|", 1)[0] for k in new})
    print(f"{'walk|method':34s} {'epochs':>7s} {'max |d pos| m':>14s} {'max |d cov| m2':>15s}")
    for m in methods:
        if m + "|t" not in ref or m + "|t" not in new:
            print(f"{m:34s} only in the {'new' if m + '|t' in new else 'saved'} set")
            ok = False
            continue
        if ref[m + "|t"].shape != new[m + "|t"].shape or not np.array_equal(ref[m + "|t"], new[m + "|t"]):
            print(f"{m:34s} epochs differ")
            ok = False
            continue
        dp = max(float(np.nanmax(np.abs(ref[m + f"|{c}"] - new[m + f"|{c}"]), initial=0.0)) for c in "en")
        dc = (float(np.nanmax(np.abs(ref[m + "|cov"] - new[m + "|cov"]), initial=0.0))
              if m + "|cov" in ref and m + "|cov" in new else float("nan"))
        flag = "" if dp <= tol_m else "  <-- above tolerance"
        ok &= dp <= tol_m
        print(f"{m:34s} {ref[m + '|t'].size:7d} {dp:14.3g} {dc:15.3g}{flag}")
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", type=Path, help="write the tracks to this .npz")
    g.add_argument("--check", type=Path, help="compare with the tracks saved in this .npz")
    ap.add_argument("--model", required=True, help="fusion model directory")
    ap.add_argument("--tol-m", type=float, default=1e-9, help="largest position difference allowed (m)")
    ap.add_argument("walks", nargs="+", help="walk directories")
    args = ap.parse_args()
    new = tracks_of(args.walks, args.model)
    if args.save:
        np.savez(args.save, **new)
        print(f"saved {len(new)} arrays -> {args.save}")
        return 0
    ref = dict(np.load(args.check))
    ok = compare(ref, new, args.tol_m)
    print("every track within tolerance" if ok else "TRACKS DIFFER")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
