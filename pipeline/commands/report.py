"""``envfuse report walk``: every raw position source of a walk against its truth, as a table and a PNG."""

from __future__ import annotations

import sys
from pathlib import Path

from features.errors import ConfigError, DataError
from pipeline.args import bounded, check_outputs, plot_path

GROUP = "report"


def register(sub) -> None:
    p = sub.add_parser("walk", help="sources of one walk against truth: error table and PNG",
                       description="Read a walk directory's files (NMEA, audio, IMU, truth.csv), extract GNSS "
                                   "fixes, acoustic positions and the PDR track, print the horizontal error per "
                                   "source and environment class, and draw the map and errors over time.",
                       epilog="Example: envfuse report walk walk7 --out walk7.png")
    p.add_argument("walk", type=Path, help="walk directory (walk.toml, streams, truth.csv)")
    p.add_argument("--out", type=plot_path, default=None,
                   help="plot to write, format by suffix: .png, .pdf or .svg; - for PNG on stdout "
                        "(default: WALK/sources.png)")
    p.add_argument("--k", type=bounded(0.05, 3.0), default=None,
                   help="Weinberg K for PDR, 0.05 to 3 (default: calibrated on RTK-fixed GNSS steps of the walk)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    from pipeline.walk_report import error_table, plot_walk, walk_sources

    if not (args.walk / "walk.toml").is_file():
        raise ConfigError(f"{args.walk}: no walk.toml (expected a walk directory)")
    if args.out is not None:
        check_outputs({f"WALK file {f.name}": f for f in args.walk.iterdir() if f.is_file()}, {"--out": args.out})
    src = walk_sources(args.walk, pdr_k=args.k)
    if not src.tracks:
        why = "; ".join(src.notes) if src.notes else "walk.toml names no gnss, audio or imu stream"
        raise DataError(f"{args.walk}: no usable stream ({why})")
    for note in src.notes:
        print(f"envfuse: note: {args.walk}: {note}", file=sys.stderr)
    table = error_table(src)
    if table:
        print("horizontal error, m: n / mean / median / p95 per class")
        for name, row in table.items():
            parts = [f"{c} {n} / {m:.2f} / {md:.2f} / {p95:.2f}" for c, (n, m, md, p95) in row.items()]
            print(f"  {name:8s} " + "; ".join(parts))
    else:
        print("no truth.csv: positions only, no errors")
    for name, tr in src.tracks.items():
        extra = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in tr.info.items())
        print(f"  {name}: {len(tr.t_s)} positions" + (f" ({extra})" if extra else ""))
    out = args.out or args.walk / "sources.png"
    plot_walk(src, out, title=f"{args.walk.name}: sources" + (" against truth" if src.truth is not None else
                                                               " (no truth.csv)"))
    print(f"plot -> {out}")
    return 0
