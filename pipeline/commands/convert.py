"""``envfuse convert smartloc``: a smartLoc drive (pseudoranges, odometry, reference) → a walk folder."""

from __future__ import annotations

from pathlib import Path

from pipeline.args import UsageError, check_outputs, finite

GROUP = "convert"


def register(sub) -> None:
    p = sub.add_parser(
        "smartloc", help="a smartLoc drive (TU Chemnitz text files) as a walk folder",
        description="Convert a smartLoc drive — the *_Input.txt (pseudorange3: pseudoranges with C/N0 and "
                    "satellite positions; odom3: speed and yaw rate) and its *_GT.txt (point3: the reference "
                    "trajectory) — into a walk folder that run, evaluate and train fusion read like any walk: "
                    "site.toml (origin at the median per-epoch fix, never the reference), walk.toml, "
                    "gnss_pseudoranges.csv, odometry.csv and truth.csv (the reference in site ENU, env_class "
                    "'unknown'). The reader solves the fixes (weighted least squares, one clock per system, "
                    "Sagnac, RAIM) and integrates the odometry itself.",
        epilog="Example: envfuse convert smartloc Berlin_Potsdamer_Platz_Input.txt Berlin_Potsdamer_Platz_GT.txt "
               "--out drive --end-s 85")
    p.add_argument("input", type=Path, help="smartLoc *_Input.txt (pseudorange3 and odom3 lines)")
    p.add_argument("gt", type=Path, help="smartLoc *_GT.txt (point3 lines: the reference)")
    p.add_argument("--out", type=Path, required=True, help="walk folder to write (must not exist, or be empty)")
    p.add_argument("--start-s", type=finite, default=None,
                   help="convert from this time on, s on the files' own time base (default: the first record); "
                        "the walk's t_s counts from here")
    p.add_argument("--end-s", type=finite, default=None,
                   help="convert up to (not including) this time, s on the files' time base (default: all)")
    p.add_argument("--name", default=None, help="the walk's name (default: the folder's name)")
    p.add_argument("--site-name", default=None,
                   help="the site's name (default: the input's file name without _Input.txt); walks of one drive "
                        "converted in parts share it, so a model trained on one part applies to the others")
    p.add_argument("--start-utc", default=None,
                   help="UTC of the span's start, ISO 8601, when known (smartLoc's files state relative times "
                        "only; without it the tables' time_utc stays empty)")
    p.add_argument("--force", action="store_true", help="replace an existing walk folder")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from features.walk import parse_utc
    from walks.convert import convert_smartloc

    check_outputs({"INPUT": args.input, "GT": args.gt}, {}, {"--out": args.out})
    for label, path in (("INPUT", args.input), ("GT", args.gt)):
        if not path.is_file():
            raise UsageError(f"{label} {path}: no such file")
    if args.start_s is not None and args.end_s is not None and not args.start_s < args.end_s:
        raise UsageError(f"--start-s ({args.start_s:g}) must be below --end-s ({args.end_s:g})")
    start_utc = None if args.start_utc is None else parse_utc(args.start_utc, "--start-utc")
    done = convert_smartloc(args.input, args.gt, args.out, start_s=args.start_s, end_s=args.end_s, name=args.name,
                            site_name=args.site_name, start_utc=start_utc, overwrite=args.force)
    print(done.summary())
    return 0
