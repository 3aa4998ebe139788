"""``envfuse survey build|export``: a survey's fingerprints into a library, and the library out as CSV.

Other ``survey`` sub-commands (``survey map``) register from their own module
with ``GROUP = "survey"``; :mod:`pipeline.cli` collects them into one group.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from features.errors import ConfigError
from pipeline.args import UsageError, bounded

GROUP = "survey"


def register(sub) -> None:
    p = sub.add_parser(
        "build", help="features of every survey cell into a fingerprint library (SQLite)",
        description="Compute the 14 features per window (GNSS from gnss.nmea, acoustic from audio.wav) for every "
                    "cell of a survey directory and store cells and windows in a fingerprint library, one "
                    "transaction per cell. The C/N0 reference of each receiver is calibrated from the survey's own "
                    "data (90th percentile of C/N0 per 10-degree elevation bin over all cells, a line in sin(el)) "
                    "and stored with it. A missing stream is recorded as missing and named. Rerunning adds "
                    "nothing twice; an interrupted build resumes where it stopped.",
        epilog="Example: envfuse survey build survey1 --library fp.sqlite")
    p.add_argument("survey", type=Path, metavar="SURVEY_DIR", help="survey directory (site.toml, cells/<id>/...)")
    p.add_argument("--library", type=Path, required=True, help="fingerprint library file (created when absent)")
    p.add_argument("--receiver", default="default",
                   help="receiver name for cells whose cell.toml names none under [gnss] receiver (default 'default')")
    p.add_argument("--window-s", type=bounded(0.2, 3600.0, "s"), default=2.0, help="window length, s (default 2)")
    p.add_argument("--hop-s", type=bounded(0.05, 3600.0, "s"), default=1.0, help="window hop, s (default 1)")
    p.add_argument("--cn0-quantile", type=bounded(0.5, 0.99), default=0.9,
                   help="C/N0 quantile per elevation bin for the receiver's open-sky reference (default 0.9)")
    p.add_argument("--replace", action="store_true",
                   help="replace cells stored from another capture or with other feature parameters (default: refuse)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_build)

    p = sub.add_parser(
        "export", help="write a library's samples as CSV",
        description="Write one CSV row per sample (window): site, receiver, cell, position, map label and share, "
                    "t_s and UTC time, the 14 features in library order, availability flags, counts and source "
                    "hashes. Empty fields are missing values.",
        epilog="Example: envfuse survey export --library fp.sqlite --out samples.csv --site sim-0003")
    p.add_argument("--library", type=Path, required=True, help="fingerprint library file")
    p.add_argument("--out", required=True, help="CSV file (written atomically), or - for standard output")
    p.add_argument("--site", default=None, help="only this site's samples (default: all)")
    p.set_defaults(func=_export)


def _print_warning(message, category, filename, lineno, file=None, line=None):
    print(f"envfuse: warning: {message}", file=sys.stderr, flush=True)


def _build(args) -> int:
    from features.acoustic.audio import AudioWarning
    from fingerprints.survey import SurveyConfig, SurveyWarning, build_library

    from pipeline.outputs import check_outputs, survey_inputs

    files, cells = survey_inputs(args.survey)
    check_outputs(files, {"--library": args.library}, sealed=cells)
    try:
        config = SurveyConfig(window_s=args.window_s, hop_s=args.hop_s, cn0_quantile=args.cn0_quantile)
    except ConfigError as exc:            # options that contradict each other: a usage error
        raise UsageError(f"--window-s {args.window_s:g} / --hop-s {args.hop_s:g}: {exc}") from None
    with warnings.catch_warnings():
        warnings.simplefilter("always", SurveyWarning)
        warnings.simplefilter("always", AudioWarning)
        warnings.showwarning = _print_warning
        report = build_library(args.survey, args.library, config, receiver=args.receiver, replace=args.replace,
                               progress=not args.quiet)
    print(f"{report.summary()} -> {args.library}")
    return 0


def _export(args) -> int:
    from fingerprints.library import FingerprintLibrary
    from pipeline.outputs import check_outputs

    check_outputs({"--library": args.library}, {"--out": args.out})
    with FingerprintLibrary.open(args.library, create=False) as lib:
        # "-" (or /dev/stdout) goes through the atomic writer to the real standard output; the CLI sends
        # this summary to stderr then.
        n = lib.export_csv(Path(args.out), site=args.site)
    print(f"{n} samples{' of site ' + args.site if args.site else ''} -> {args.out}")
    return 0
