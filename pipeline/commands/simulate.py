"""``envfuse simulate site|walk|survey``: synthetic substations in device formats."""

from __future__ import annotations

from pathlib import Path

from features.errors import ConfigError
from pipeline.args import bounded, check_outputs, seed
from pipeline.outputs import check_replaceable

GROUP = "simulate"

SURVEY_BYTES_PER_CELL_S = 96_000 + 3_600 + 1_100
"""Bytes a simulated survey cell writes per second of capture: 48 kHz int16 audio (96 kB/s), NMEA at 5 Hz
(≈ 3.6 kB/s), the per-emission audio truth (≈ 1.1 kB/s); measured on a 4-s capture of site seed 3."""
SIZE_WARN_GB = 0.25
"""Above this estimated size a survey prints a warning before it starts."""


def register(sub) -> None:
    p = sub.add_parser("site", help="generate a substation layout (site.toml)",
                       description="Generate a 220 kV-class substation: layout, beacons, environment truth.",
                       epilog="Example: envfuse simulate site --seed 1 --out site1 --plot")
    p.add_argument("--seed", type=seed, required=True, help="layout seed (same seed, same site)")
    p.add_argument("--out", type=Path, required=True, help="output directory (gets site.toml)")
    p.add_argument("--plot", action="store_true", help="also write site.png (layout, beacons, class map)")
    p.add_argument("--no-emi", action="store_true", help="no EMI zones round the transformers")
    p.add_argument("--force", action="store_true", help="replace a non-empty output directory")
    p.set_defaults(func=_site)

    p = sub.add_parser("walk", help="simulate a walk log (walk.toml, gnss.nmea, truth.csv, ...)",
                       description="Simulate a person walking the site's aisles, writing every device stream.",
                       epilog="Example: envfuse simulate walk site1 --seed 7 --duration-s 300 --out walk7")
    p.add_argument("site", type=Path, help="site directory or site.toml")
    p.add_argument("--seed", type=seed, required=True, help="walk seed")
    p.add_argument("--duration-s", "--duration", dest="duration", type=bounded(1.0, 21_600.0, "s"), default=300.0,
                   help="walk length, s, 1 to 21600 (default 300; --duration is the old name)")
    p.add_argument("--person", type=seed, default=None, help="walker identity: same person, same gait (default: seed)")
    p.add_argument("--start-utc", "--start", dest="start", default=None,
                   help="start time, ISO 8601 UTC (default: a day of 2026 and an hour drawn from the seed)")
    p.add_argument("--no-corrections", action="store_true", help="GNSS without RTK/DGNSS corrections")
    p.add_argument("--out", type=Path, required=True, help="output walk directory")
    p.add_argument("--force", action="store_true", help="replace a non-empty output directory")
    p.set_defaults(func=_walk)

    p = sub.add_parser("survey", help="simulate a grid fingerprint survey (cells/<id>/...)",
                       description="Simulate a crew's static captures on a grid of cells over the site.",
                       epilog="Example: envfuse simulate survey site1 --out survey1 --cell-size-m 5 --capture-s 30")
    p.add_argument("site", type=Path, help="site directory or site.toml")
    p.add_argument("--out", type=Path, required=True, help="output survey directory")
    p.add_argument("--cell-size-m", "--cell-size", dest="cell_size", type=bounded(0.5, 50.0, "m"), default=None,
                   help="cell size, m, 0.5 to 50 (default: the site's grid, 5; --cell-size is the old name)")
    p.add_argument("--capture-s", type=bounded(1.0, 3600.0, "s"), default=30.0, help="capture length per cell, s, 1 to 3600 (default 30)")
    p.add_argument("--max-size-gb", type=bounded(0.001, 10_000.0, "GB"), default=2.0,
                   help="refuse to write more than this, GB (default 2; the estimate is printed first and a "
                        f"warning given above {SIZE_WARN_GB:g} GB)")
    p.add_argument("--seed", type=seed, default=0, help="survey seed (default 0)")
    p.add_argument("--start-utc", "--start", dest="start", default=None,
                   help="start time of the first capture, ISO 8601 UTC (default: a day of 2026 and an hour "
                        "drawn from the seed, so sites differ in constellation too)")
    p.add_argument("--no-corrections", action="store_true", help="GNSS without RTK/DGNSS corrections")
    p.add_argument("--force", action="store_true", help="replace a non-empty output directory")
    p.set_defaults(func=_survey)


def _site(args) -> int:
    from features.fileio import atomic_directory
    from features.site import save_site
    from simulation.site.layout import LayoutConfig, class_shares, generate_site

    check_outputs({}, {}, {"--out": args.out})
    if args.force:
        check_replaceable(args.out, "site", flag="--force")
    site = generate_site(args.seed, LayoutConfig(emi_zones=not args.no_emi))
    with atomic_directory(args.out, overwrite=args.force) as tmp:
        save_site(site, tmp / "site.toml")
        if args.plot:
            from pipeline.plots import plot_site
            plot_site(site, tmp / "site.png")
    shares = class_shares(site)
    kinds = {}
    for b in site.layout:
        kinds[b.kind] = kinds.get(b.kind, 0) + 1
    print(f"site {site.name}: {site.grid.east_max_m:.0f} x {site.grid.north_max_m:.0f} m, "
          + ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
          + f"; {len(site.beacons)} beacons in {site.acoustic.n_slots} slots; "
          f"area open {100 * shares[0]:.0f} % / light {100 * shares[1]:.0f} % / heavy {100 * shares[2]:.0f} %")
    print(f"wrote {args.out / 'site.toml'}" + (f" and {args.out / 'site.png'}" if args.plot else ""))
    return 0


def _start(text: str | None):
    """--start as a UTC datetime within the GNSS era the orbit model serves (1980-2100)."""
    if not text:
        return None
    from features.walk import parse_utc
    t = parse_utc(text, "--start-utc")
    if not 1980 <= t.year <= 2099:
        raise ConfigError(f"--start-utc {text!r} lies outside 1980-2099")
    return t


def _options(args) -> dict:
    return {"gnss_corrections": not args.no_corrections}


def _walk(args) -> int:
    from simulation.walk import simulate_walk

    check_outputs({"SITE": args.site}, {}, {"--out": args.out})
    if args.force:
        check_replaceable(args.out, "walk", flag="--force")
    start = _start(args.start)
    out = simulate_walk(args.site, args.out, seed=args.seed, duration_s=args.duration, person=args.person,
                        start_utc=start, overwrite=args.force, options=_options(args))
    files = sorted(p.name for p in out.iterdir())
    print(f"walk {out}: {args.duration:.0f} s, files: {', '.join(files)}")
    return 0


def survey_size_bytes(site_path, cell_size_m: float | None, capture_s: float) -> tuple[int, int]:
    """(cells, estimated bytes) a simulated survey of the site would write."""
    from features.site import load_site
    from simulation.survey import survey_cells

    site = load_site(site_path)
    n = len(survey_cells(site, float(cell_size_m or site.grid.cell_size_m)))
    return n, int(n * capture_s * SURVEY_BYTES_PER_CELL_S)


def _check_survey_size(args, n_cells: int, size: int) -> None:
    import shutil
    import sys

    gb = size / 1e9
    what = f"about {gb:.2f} GB ({n_cells} cells x {args.capture_s:g} s of 48 kHz audio and NMEA)"
    if gb > args.max_size_gb:
        raise ConfigError(f"the survey would write {what}, more than --max-size-gb {args.max_size_gb:g}: "
                          f"raise --max-size-gb, or use a larger --cell-size-m or a shorter --capture-s")
    parent = Path(args.out).resolve().parent
    while not parent.exists():
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if size > free:
        raise ConfigError(f"the survey would write {what}, but {parent} has only {free / 1e9:.2f} GB free")
    if gb > SIZE_WARN_GB:
        print(f"envfuse: warning: the survey will write {what}", file=sys.stderr)


def _survey(args) -> int:
    from simulation.survey import simulate_survey

    check_outputs({"SITE": args.site}, {}, {"--out": args.out})
    if args.force:
        check_replaceable(args.out, "survey", flag="--force")
    n_cells, size = survey_size_bytes(args.site, args.cell_size, args.capture_s)
    _check_survey_size(args, n_cells, size)
    start = _start(args.start)
    out = simulate_survey(args.site, args.out, seed=args.seed, cell_size_m=args.cell_size, capture_s=args.capture_s,
                          start_utc=start, overwrite=args.force, options=_options(args))
    n = len(list((out / "cells").iterdir()))
    print(f"survey {out}: {n} cells")
    return 0
