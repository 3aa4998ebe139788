"""``envfuse run`` (fuse one walk into a track) and ``envfuse evaluate`` (every method on many walks)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from features.errors import ConfigError

GROUP = None  # top-level commands, registered by register_top

TRACK_COLUMNS = ("t_s", "utc", "east_m", "north_m", "lat_deg", "lon_deg", "var_east_m2", "cov_en_m2",
                 "var_north_m2", "env_class", "class_probability", "ood", "nis", "bp_correction_m")


def register_top(sub) -> None:
    from pipeline.fusion import METHODS

    p = sub.add_parser(
        "run", help="fuse one walk into a track (CSV or GeoJSON)",
        description="Read a walk directory (NMEA, audio, IMU), classify its environment window by window and "
                    "fuse GNSS, acoustic positions and PDR with the chosen method.",
        epilog="Example: envfuse run walk7 --model fusion_model --out track.csv --method adaptive")
    p.add_argument("walk", type=Path, help="walk directory")
    p.add_argument("--model", type=Path, required=True, help="fusion model directory (train fusion)")
    p.add_argument("--out", type=Path, required=True, help="track file to write (CSV, or GeoJSON with --format)")
    p.add_argument("--method", choices=METHODS + tuple(m + "+rts" for m in METHODS[3:9]), default="adaptive",
                   help="fusion method (default adaptive)")
    p.add_argument("--format", choices=("csv", "geojson"), default=None,
                   help="output format (default: from the suffix, .geojson or .json → GeoJSON, else CSV)")
    p.set_defaults(func=_run)

    p = sub.add_parser(
        "evaluate", help="every fusion method on many walks: metrics.csv, summary, plots",
        description="Run every method on every walk (one task per walk, on Dask: a LocalCluster with one worker "
                    "per core by default), write metrics.csv (walk, method, env_class, n, mean_m, median_m, "
                    "p95_m, max_m, nees_in_bounds), print a summary and draw trajectories, error over time, "
                    "error CDFs and error by class.",
        epilog="Example: envfuse evaluate split/walks/201/w0 split/walks/201/w1 --model fusion_model "
               "--report report --workers 2")
    p.add_argument("walks", type=Path, nargs="+", help="walk directories (with truth.csv for errors)")
    p.add_argument("--model", type=Path, required=True, help="fusion model directory")
    p.add_argument("--report", type=Path, required=True, help="directory for metrics.csv and the PNGs")
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS), help="methods (default all)")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default one per core; "
                                                                "1 = serial, no Dask)")
    p.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler (tcp://host:8786)")
    p.add_argument("--force", action="store_true", help="evaluate walks of sites the model was not trained on")
    p.add_argument("--no-plots", action="store_true", help="metrics only")
    p.set_defaults(func=_evaluate)


def _fmt(v) -> str:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.10g}"
    return str(v)


def _run(args) -> int:
    import numpy as np

    from features.fileio import atomic_write_text
    from features.geodesy import enu_to_geodetic
    from features.site import ENV_CLASSES
    from models.fusion_model import load_fusion_model
    from pipeline.fusion import run_methods, walk_inputs
    from pipeline.walk_data import read_walk

    if not (args.walk / "walk.toml").is_file():
        raise ConfigError(f"{args.walk}: no walk.toml (expected a walk directory)")
    model = load_fusion_model(args.model)
    data = read_walk(args.walk)
    inputs = walk_inputs(data, model)
    base = args.method.split("+")[0]
    tracks, skipped = run_methods(model, inputs, (base,), smooth=args.method.endswith("+rts"))
    if args.method not in tracks:
        raise ConfigError(f"{args.walk}: method {args.method} cannot run: {skipped.get(base, 'no output')}")
    tr = tracks[args.method]
    o = data.site.origin
    lat, lon, _ = enu_to_geodetic(tr.east_m, tr.north_m, np.zeros_like(tr.east_m), o.lat_deg, o.lon_deg, o.alt_m)
    proba = inputs.classes.at(tr.t_s)
    ood_t = np.concatenate([[False], inputs.window_ood])
    rows_ood = ood_t[np.clip(np.searchsorted(inputs.classes.t_s, tr.t_s, side="right") - 1, 0, len(ood_t) - 1)]
    start = data.walk.start_utc
    from datetime import timedelta

    cov = tr.cov_m2 if tr.cov_m2 is not None else np.full((len(tr.t_s), 2, 2), np.nan)
    nis = tr.info.get("nis", np.full(len(tr.t_s), np.nan))
    bp = tr.info.get("bp_delta_m")
    bpn = np.hypot(bp[:, 0], bp[:, 1]) if bp is not None else np.zeros(len(tr.t_s))
    rows = []
    for i in range(len(tr.t_s)):
        c = int(np.argmax(proba[i]))
        rows.append({"t_s": float(tr.t_s[i]),
                     "utc": (start + timedelta(seconds=float(tr.t_s[i]))).strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
                     "east_m": float(tr.east_m[i]), "north_m": float(tr.north_m[i]), "lat_deg": float(lat[i]),
                     "lon_deg": float(lon[i]), "var_east_m2": float(cov[i, 0, 0]), "cov_en_m2": float(cov[i, 0, 1]),
                     "var_north_m2": float(cov[i, 1, 1]), "env_class": ENV_CLASSES[c],
                     "class_probability": float(proba[i, c]), "ood": bool(rows_ood[i]), "nis": float(nis[i]),
                     "bp_correction_m": float(bpn[i])})
    fmt = args.format or ("geojson" if args.out.suffix.lower() in (".geojson", ".json") else "csv")
    if fmt == "csv":
        text = ",".join(TRACK_COLUMNS) + "\n" + "".join(",".join(_fmt(r[k]) for k in TRACK_COLUMNS) + "\n"
                                                        for r in rows)
    else:
        feats = [{"type": "Feature", "geometry": {"type": "LineString",
                                                  "coordinates": [[round(r["lon_deg"], 9), round(r["lat_deg"], 9)]
                                                                  for r in rows]},
                  "properties": {"walk": str(args.walk), "method": args.method, "start_utc": rows[0]["utc"] if rows
                                 else None}}]
        feats += [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [round(r["lon_deg"], 9),
                                                                                   round(r["lat_deg"], 9)]},
                   "properties": {k: (None if isinstance(r[k], float) and math.isnan(r[k]) else r[k])
                                  for k in TRACK_COLUMNS if k not in ("lat_deg", "lon_deg")}} for r in rows]
        text = json.dumps({"type": "FeatureCollection", "features": feats}, allow_nan=False) + "\n"
    atomic_write_text(args.out, text)
    print(f"{args.walk}: {args.method}, {len(rows)} positions -> {args.out}")
    return 0


def _evaluate(args) -> int:
    from pipeline.evaluate import evaluate, summary_table

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    for w in args.walks:
        if not (w / "walk.toml").is_file():
            raise ConfigError(f"{w}: no walk.toml (expected a walk directory)")
    out = evaluate(args.walks, args.model, args.report, methods=tuple(args.methods), workers=args.workers,
                   scheduler=args.scheduler, force=args.force, progress=True, plots=not args.no_plots)
    for f in out["failures"]:
        print(f"envfuse: warning: {f.walk}: {f.message} (walk skipped)", file=sys.stderr)
    for r in out["results"]:
        for m, why in r["skipped"].items():
            print(f"envfuse: note: {r['walk']}: {m} skipped: {why}", file=sys.stderr)
    if not out["results"]:
        raise ConfigError("no walk could be evaluated")
    print(summary_table(out["pooled"]))
    shares = [r["bp_disabled_share"] for r in out["results"] if r["bp_disabled_share"] is not None]
    if shares:
        print(f"BP correction withheld by its guards on {100 * sum(shares) / len(shares):.1f} % of epochs")
    print(f"{len(out['results'])} walks -> {args.report / 'metrics.csv'}"
          + (f", {len(out['pngs'])} plots" if out["pngs"] else ""))
    return 1 if out["failures"] else 0
