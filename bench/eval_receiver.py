"""Receiver consistency on simulated walks: acoustic NEES, errors and fix shares per class; GNSS NEES.

For each walk directory given (``envfuse simulate walk`` output, with truth.csv),
runs the receiver exactly as ``envfuse report walk`` does (:func:`walks.reader.read_walk`)
and prints, per environment class of the truth at each fix:

* acoustic: number of fixes, NEES mean and median (2 degrees of freedom: expected
  mean 2, median 1.39 for a consistent estimator; Bar-Shalom, Li & Kirubarajan 2001,
  §5.4.2), rms and p95 horizontal error, and the share of TDMA frames with a fix;
* GNSS: NEES mean per fix quality and class (σ per axis as reported).

Run: ``.venv/bin/python bench/eval_receiver.py WALK_DIR [WALK_DIR ...] [--json OUT]``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from features.site import ENV_CLASSES


def _class_at(truth, t):
    i = np.clip(np.searchsorted(truth.t_s, t), 0, len(truth.t_s) - 1)
    return truth.env_class[i]


def _truth_at(truth, t):
    return np.interp(t, truth.t_s, truth.east_m), np.interp(t, truth.t_s, truth.north_m)


def evaluate(walk_dirs: list[Path], uere_json: Path | None = None, acoustic: bool = True) -> dict:
    from features.acoustic.positions import PositionConfig
    from features.acoustic.features import analyse_audio
    from features.acoustic.timing import timing_from_walk
    from features.walk import load_walk, read_truth
    from features.gnss.nmea import epochs_on_time_base, read_nmea
    from features.gnss.positions import fixes_to_enu
    from walks.reader import WALK_SPEED_PRIOR_M_S

    uere = None
    if uere_json is not None:
        from features.gnss.positions import UereTable

        uere = UereTable.from_dict(json.loads(Path(uere_json).read_text()))

    ac = {k: {"nees": [], "err": [], "frames": 0, "fixed": 0, "along": [], "lag": []} for k in ENV_CLASSES}
    gn: dict = {}
    for d in walk_dirs:
        walk = load_walk(d)
        site = walk.load_site()
        truth = read_truth(walk.directory)
        timing = timing_from_walk(walk, site)
        pos = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05,
                             motion_speed_m_s=WALK_SPEED_PRIOR_M_S)
        res = analyse_audio(walk.path("audio"), site, timing, positions=pos, keep_frames=True) if acoustic else None
        frames = res.frames if acoustic else []
        fixes = res.fixes if acoustic else []
        frame_s = site.acoustic.frame_s
        for fr in frames:
            mid = fr.frame_start_s + 0.5 * frame_s
            if mid < truth.t_s[0] or mid > truth.t_s[-1]:
                continue
            k = ENV_CLASSES[int(_class_at(truth, mid))]
            ac[k]["frames"] += 1
            ac[k]["fixed"] += fr.fix is not None
        for f in fixes:
            if f.t_s < truth.t_s[0] or f.t_s > truth.t_s[-1]:
                continue
            te, tn = _truth_at(truth, f.t_s)
            e = np.array([f.east_m - te, f.north_m - tn])
            p = np.asarray(f.covariance)[:2, :2]
            k = ENV_CLASSES[int(_class_at(truth, f.t_s))]
            ac[k]["nees"].append(float(e @ np.linalg.solve(p, e)))
            ac[k]["err"].append(float(np.hypot(*e)))
            # Along-track error while walking (> 0.5 m/s): a time-tag error shows as error/speed.
            ve = (np.interp(f.t_s + 0.25, truth.t_s, truth.east_m) - np.interp(f.t_s - 0.25, truth.t_s, truth.east_m)) / 0.5
            vn = (np.interp(f.t_s + 0.25, truth.t_s, truth.north_m) - np.interp(f.t_s - 0.25, truth.t_s, truth.north_m)) / 0.5
            speed = float(np.hypot(ve, vn))
            if speed > 0.5:
                along = float((e[0] * ve + e[1] * vn) / speed)
                ac[k]["along"].append(along)
                ac[k]["lag"].append(along / speed)
        epochs, _ = read_nmea(walk.path("gnss"))
        epochs = epochs_on_time_base(epochs, walk.start_utc)
        o = site.origin
        kw = {"uere": uere} if uere is not None else {}
        g = fixes_to_enu(epochs, o.lat_deg, o.lon_deg, o.alt_m, **kw)
        for i in range(len(g.t_s)):
            t = float(g.t_s[i])
            if t < truth.t_s[0] or t > truth.t_s[-1]:
                continue
            te, tn = _truth_at(truth, t)
            se = float(g.sigma_en_m[i] if getattr(g, "sigma_east_m", None) is None else g.sigma_east_m[i])
            sn = float(g.sigma_en_m[i] if getattr(g, "sigma_north_m", None) is None else g.sigma_north_m[i])
            nees = ((g.east_m[i] - te) / se) ** 2 + ((g.north_m[i] - tn) / sn) ** 2
            key = (int(g.quality[i]), ENV_CLASSES[int(_class_at(truth, t))])
            gn.setdefault(key, []).append(float(nees))
    out = {"acoustic": {}, "gnss": {}}
    tot = {"nees": [], "err": [], "frames": 0, "fixed": 0, "along": [], "lag": []}
    for k, v in ac.items():
        for key in tot:
            tot[key] += v[key]
        out["acoustic"][k] = _summary(v)
    out["acoustic"]["all"] = _summary(tot)
    for (q, k), v in sorted(gn.items()):
        out["gnss"][f"q{q}/{k}"] = {"n": len(v), "nees_mean": float(np.mean(v)), "nees_median": float(np.median(v))}
    return out


def _summary(v):
    nees, err, frames, fixed = v["nees"], v["err"], v["frames"], v["fixed"]
    n = len(nees)
    return {"n_fixes": n, "nees_mean": float(np.mean(nees)) if n else float("nan"),
            "nees_median": float(np.median(nees)) if n else float("nan"),
            "rms_m": float(np.sqrt(np.mean(np.square(err)))) if n else float("nan"),
            "p95_m": float(np.percentile(err, 95)) if n else float("nan"),
            "frames": frames, "fix_share": fixed / frames if frames else float("nan"),
            "along_median_m": float(np.median(v["along"])) if v["along"] else float("nan"),
            "tag_lag_median_s": float(np.median(v["lag"])) if v["lag"] else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("walks", nargs="+", type=Path)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--uere", type=Path, default=None, help="fitted UERE table (JSON) for the GNSS σ")
    ap.add_argument("--gnss-only", action="store_true")
    args = ap.parse_args(argv)
    out = evaluate(args.walks, args.uere, acoustic=not args.gnss_only)
    print(f"{'acoustic':8s} {'fixes':>6s} {'NEES mean':>9s} {'median':>7s} {'rms m':>7s} {'p95 m':>7s} {'fix share':>9s}"
          f" {'along m':>8s} {'lag s':>7s}")
    for k, s in out["acoustic"].items():
        print(f"{k:8s} {s['n_fixes']:6d} {s['nees_mean']:9.2f} {s['nees_median']:7.2f} {s['rms_m']:7.3f} "
              f"{s['p95_m']:7.3f} {s['fix_share']:9.2f} {s['along_median_m']:8.3f} {s['tag_lag_median_s']:7.3f}"
              f"  ({s['frames']} frames)")
    print(f"\n{'GNSS q/class':14s} {'n':>6s} {'NEES mean':>9s} {'median':>7s}")
    for k, s in out["gnss"].items():
        print(f"{k:14s} {s['n']:6d} {s['nees_mean']:9.2f} {s['nees_median']:7.2f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
