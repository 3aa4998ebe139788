"""``envfuse run`` (fuse one walk into a track) and ``envfuse evaluate`` (every method on many walks)."""

from __future__ import annotations

import sys
from pathlib import Path

from features.errors import ConfigError
from features.fileio import atomic_write_text
from pipeline.args import LazyChoices, UsageError, bounded, lazy_help

GROUP = None  # top-level commands, registered by register_top


DEFAULT_METHOD = "kf_quality+lag"
"""run's method when none is named: the quality-aware EKF (each fix's R from what the device reports: GGA quality,
GST, the acoustic fix's covariance) as its fixed-lag track (:data:`walks.methods.LAG_S` late). Chosen on held-out
evidence (``bench/fusion_study.py``, 5 sites × 3 walks × 3 model seeds per split, scored one row per instant;
2026-12-03), the rule being that a fused track must not be worse than its best single input:

- it is better than the best single input in every class on both splits (Δ of the pooled mean, 95 % site-bootstrap
  interval; new sites: open −54 % [−58, −36] against the RTK fixes, light −48 % [−70, −25], heavy −27 % [−65, +24]
  against the acoustic fixes; the same sites four weeks later: open −31 % [−52, −10], light −17 % [−34, −2], heavy
  −63 % [−69, −42]);
- the context error model without the class, ``adaptive_blind+lag`` (the default until 2026-12-03), ties it (new
  sites −7.3 % [−29, +16], four weeks later +1.1 % [−16, +17]) but was worse than the RTK fixes in light windows
  four weeks later (+7.1 % [−41, +41]; 0.203 against 0.189 m), and its worst walk reaches 20.4 m (this one
  15.9 m; both on one long heavy stretch of standard 203/w0); the class-aware ``adaptive+lag`` was worse than
  the fixes in the open four weeks later (+42 % [−36, +97]) and worse than this filter there overall (+9.0 %
  [+4.4, +18]), though it stays within 7.5 m on that heavy walk (``--method adaptive+lag`` for a site known to
  be mostly heavy);
- the zero-latency filters trail the RTK fixes in the open for a few seconds after each outage; the lag smooths
  that out. A patrol track is rarely needed with zero latency (``--method kf_quality``).

The environment class is still computed and written with every position (``env_class``, its probability)."""


MIN_SEGMENT_S = 60.0
"""Shortest ``--segment-s``, s: every cut holds :data:`walks.segments.WARMUP_S` of warm-up (a method that starts
afresh on each cut :data:`walks.segments.FRESH_WARMUP_S`; and the cuts holding
the walk's start at least the heading gate's reference span), so shorter segments only multiply the reads
without lowering the peak memory."""

MAX_SEGMENT_S = 1e6
"""Longest ``--segment-s``, s (11.6 days: longer than any walk, i.e. the whole walk as one segment)."""

MAX_LAG_S = 3600.0
"""Longest ``--lag-s``, s: a fixed-lag track an hour late is the RTS track of any patrol's hour (``+rts``)."""


def _method_names(smoothed: bool = False) -> tuple[str, ...]:
    from walks.methods import method_names

    return method_names(smoothed=smoothed)


def _method_help() -> str:
    from walks.methods import method, method_names

    names = method_names()
    return (f"fusion method (default {DEFAULT_METHOD}): one of {', '.join(names)}; a filter's name with +rts is its "
            f"RTS-smoothed track, with +lag its fixed-lag track, --lag-s late (the filters: "
            f"{', '.join(n for n in names if method(n).filter)})")


def _segment_help() -> str:
    from walks.segments import FRESH_WARMUP_S, SEGMENT_S, WARMUP_S

    return (f"a longer walk is fused in segments of this much walk time, each with {WARMUP_S:g} s of warm-up "
            f"({FRESH_WARMUP_S:g} s for fg_*, ekf_rtk_pdr and foot_ins_fkf, which start afresh on each, and "
            f"adaptive_correction), so memory does not grow with the walk (default {SEGMENT_S:g}, "
            f"{MIN_SEGMENT_S:g} to {MAX_SEGMENT_S:g}; walks.segments)")


def register_top(sub) -> None:
    # The method names and the segments' constants are read when a value is checked or a help page printed
    # (pipeline.args.LazyChoices, lazy_help): the registry's import is most of a second.
    p = sub.add_parser(
        "run", help="fuse one walk into a track (CSV or GeoJSON)",
        description="Read a walk directory (NMEA, audio, IMU), classify its environment window by window and "
                    "fuse GNSS, acoustic positions and PDR with the chosen method.",
        epilog="Example: envfuse run walk7 --model fusion_model --out track.csv  (the context filter, 3 s late; "
               "--method adaptive_blind for zero latency, --method adaptive+lag for the class-aware one)")
    p.add_argument("walk", type=Path, help="walk directory")
    p.add_argument("--model", type=Path, required=True, help="fusion model directory (train fusion)")
    p.add_argument("--out", type=Path, required=True, help="track file to write (CSV, or GeoJSON with --format)")
    lazy_help(p.add_argument("--method", choices=LazyChoices(lambda: _method_names(smoothed=True)),
                             default=DEFAULT_METHOD, metavar="METHOD", help="fusion method"), _method_help)
    p.add_argument("--lag-s", type=bounded(0, MAX_LAG_S, "s"), default=None,
                   help="lag of a +lag track, s (default 3: the track a few seconds late, most of the smoother's gain)")
    p.add_argument("--format", choices=("csv", "geojson"), default=None,
                   help="output format (default: from the suffix, .geojson or .json → GeoJSON, else CSV)")
    p.add_argument("--force", action="store_true", help="fuse a walk of a site the model was not trained on")
    lazy_help(p.add_argument("--segment-s", type=bounded(MIN_SEGMENT_S, MAX_SEGMENT_S, "s"), default=None,
                             help="segment length, s"), _segment_help)
    p.set_defaults(func=_run)

    p = sub.add_parser(
        "evaluate", help="every fusion method on many walks: metrics.csv, summary, plots",
        description="Run every method on every walk (one task per walk, on Dask: a LocalCluster with one worker "
                    "per core by default), write metrics.csv (walk, method, env_class, n, mean_m, median_m, "
                    "p95_m, max_m, nees_in_bounds: the share of epochs whose normalised error lies inside the 95 %% "
                    "chi-square interval, about 0.95 for a consistent filter), print a summary and draw, for every "
                    "walk, its trajectories and error over time, and the error CDFs and error by class. Each walk "
                    "needs truth.csv; a walk that fails is named and skipped (exit 1).",
        epilog="Example: envfuse evaluate split/walks/201/w0 split/walks/201/w1 --model fusion_model "
               "--report report --workers 2")
    p.add_argument("walks", type=Path, nargs="+", help="walk directories (with truth.csv for errors)")
    p.add_argument("--model", type=Path, required=True, help="fusion model directory")
    p.add_argument("--report", type=Path, required=True,
                   help="directory for metrics.csv and the PNGs: new, empty or an earlier report (its plots of "
                        "walks no longer evaluated are removed)")
    lazy_help(p.add_argument("--methods", nargs="+", choices=LazyChoices(_method_names), default=None,
                             metavar="METHOD", help="methods (default all)"),
              lambda: f"methods (default all: {', '.join(_method_names())})")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default one per core; "
                                                                "1 = serial, no Dask)")
    p.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler (tcp://host:8786)")
    p.add_argument("--force", action="store_true", help="evaluate walks of sites the model was not trained on")
    p.add_argument("--no-plots", action="store_true", help="metrics only")
    lazy_help(p.add_argument("--segment-s", type=bounded(MIN_SEGMENT_S, MAX_SEGMENT_S, "s"), default=None,
                             help="segment length, s"), _segment_help)
    p.set_defaults(func=_evaluate)


def _run(args) -> int:
    from features.fileio import atomic_path
    from pipeline.evaluate import load_model
    from pipeline.outputs import check_outputs, model_inputs, walk_files
    from pipeline.site_map import class_map_for
    from simulation.progress import Progress
    from walks.fuse import fuse_to_file

    check_outputs(walk_files(args.walk), {"--out": args.out}, sealed=model_inputs(args.model, "--model"))
    if not (args.walk / "walk.toml").is_file():
        raise ConfigError(f"{args.walk}: no walk.toml (expected a walk directory)")
    from walks.methods import LAG_S
    from walks.segments import SEGMENT_S, plan_segments

    lag = LAG_S if args.lag_s is None else args.lag_s
    if args.segment_s is None:
        args.segment_s = SEGMENT_S
    fmt = args.format or ("geojson" if args.out.suffix.lower() in (".geojson", ".json") else "csv")
    # a walk of several segments (a shift: minutes of work) shows its progress segment by segment on stderr: a
    # bar on a terminal, a line per tenth in a log
    n_segments = plan_segments(args.walk, args.segment_s)[0]
    with atomic_path(args.out) as tmp, Progress(n_segments, f"run {args.walk.name}", unit="segments",
                                                enabled=n_segments > 1) as bar:
        done = fuse_to_file(args.walk, load_model(args.model), args.method, tmp, fmt,
                            properties={"walk": str(args.walk), "method": args.method}, lag_s=lag,
                            class_map_for=class_map_for, force=args.force, segment_s=args.segment_s,
                            progress=bar.set)
        for note in done.notes:
            print(f"envfuse: note: {args.walk}: {note}", file=sys.stderr)
        if done.n == 0 and done.skipped:
            why = "; ".join(dict.fromkeys(why for _, why in done.skipped))
            raise ConfigError(f"{args.walk}: method {args.method} cannot run: {why}")
    for where, why in done.skipped:
        print(f"envfuse: note: {where}: {args.method} cannot run there ({why}); its epochs are left out",
              file=sys.stderr)
    n, placed, ood = done.n, done.placed, done.ood
    parts = [f"{n} epochs"]
    if placed < n:
        parts.append(f"{n - placed} without a position")
    parts.append(ood_text(ood, n))
    if done.segments > 1:
        parts.append(f"fused in {done.segments} segments of {args.segment_s:g} s")
    print(f"{args.walk}: {args.method}, {', '.join(parts)} -> {args.out}")
    if n and ood / n > 0.5:
        print(f"envfuse: warning: {args.walk}: {100 * ood / n:.0f} % of the track's epochs fall outside what the "
              "environment model was trained on (column ood): its classes, and the noise they set, are unreliable "
              "here; train on surveys of this kind of site", file=sys.stderr)
    if placed == 0:
        raise ConfigError(f"{args.walk}: {args.method} gave no position at any of its {n} epochs")
    return 0


def _evaluate(args) -> int:
    from pipeline.evaluate import bp_guard_line, evaluate, summary_table
    from pipeline.outputs import check_outputs, directory_kind, model_inputs, refuse_repeated, walk_files

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1, got {args.workers}")
    refuse_repeated(args.walks, "WALKS")
    inputs = {}
    for w in args.walks:
        inputs.update(walk_files(w, f"walk {Path(w).name}"))
    check_outputs(inputs, {}, {"--report": args.report}, model_inputs(args.model, "--model"))
    if args.report.exists():
        if not args.report.is_dir():
            raise UsageError(f"--report {args.report} exists and is not a directory")
        if directory_kind(args.report) not in ("empty", "report"):
            raise UsageError(f"--report {args.report} holds other files than a report (metrics.csv and PNGs): "
                             "its plots are replaced, so name a new or empty directory")
    if args.scheduler is not None:
        from pipeline.parallel import check_scheduler

        check_scheduler(args.scheduler)
    for w in args.walks:
        if not (w / "walk.toml").is_file():
            raise ConfigError(f"{w}: no walk.toml (expected a walk directory)")
    methods = None if args.methods is None else tuple(args.methods)
    from walks.segments import SEGMENT_S

    out = evaluate(args.walks, args.model, args.report, methods=methods, workers=args.workers,
                   scheduler=args.scheduler, force=args.force, progress=True, plots=not args.no_plots,
                   segment_s=SEGMENT_S if args.segment_s is None else args.segment_s)
    for f in out["failures"]:
        text = f.message if f.message.startswith(f.walk) else f"{f.walk}: {f.message}"
        print(f"envfuse: warning: {text} (walk skipped)", file=sys.stderr)
    for r in out["results"]:
        for note in r.get("notes", []):
            print(f"envfuse: note: {r['walk_dir']}: {note}", file=sys.stderr)
        for m, why in r["skipped"].items():
            print(f"envfuse: note: {r['walk_dir']}: {m} skipped: {why}", file=sys.stderr)
    if not out["results"]:
        raise ConfigError(f"no walk could be evaluated ({len(out['failures'])} failed, named above)")
    print(summary_table(out["pooled"]))
    shares = [r["bp_disabled_share"] for r in out["results"] if r["bp_disabled_share"] is not None]
    if shares:
        print(bp_guard_line(sum(shares) / len(shares)))
    n = len(out["results"])
    print(f"{n} walk{'s' if n != 1 else ''} -> {args.report / 'metrics.csv'}"
          + (f", {len(out['pngs'])} plots" if out["pngs"] else "")
          + (f"; {len(out['failures'])} skipped (named above)" if out["failures"] else ""))
    return 1 if out["failures"] else 0


def ood_text(ood: int, n: int) -> str:
    """The run summary's share of epochs out of the environment model's training distribution: a few read
    "<1 %", not "0 %" beside "their class is a guess"."""
    share = 100 * ood / max(n, 1)
    return (("<1" if 0 < share < 0.5 else f"{share:.0f}") + " % out of the environment model's training distribution"
            + (" (their class is a guess)" if ood else ""))
