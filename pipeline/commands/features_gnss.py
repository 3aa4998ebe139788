"""``envfuse features gnss``: NMEA → GNSS feature windows (CSV), decoded epochs (JSON lines), ENU fixes (CSV)."""

from __future__ import annotations

import io
import json
import math
import sys
from pathlib import Path

from features.errors import ConfigError, NmeaError
from pipeline.args import bounded, check_outputs, resolve_site
from pipeline.tables import with_geodetic, with_time_utc

GROUP = "features"


def register(sub) -> None:
    p = sub.add_parser(
        "gnss", help="GNSS features per window from an NMEA file",
        description="Read an NMEA 0183 file into epochs and write the five GNSS environment features "
                    "(att_mean_db, att_std_db, fluct_per_s, invisible_ratio, dop_growth) per window, "
                    "optionally the decoded epochs (JSON lines) and the fixes in site ENU (CSV).",
        epilog="Example: envfuse features gnss walk7/gnss.nmea --site site1 --out gnss_features.csv "
               "--epochs epochs.jsonl --positions fixes.csv")
    p.add_argument("nmea", type=Path, help="NMEA 0183 file")
    p.add_argument("--out", type=Path, required=True, help="feature CSV, one row per window; - for stdout")
    p.add_argument("--site", type=Path, default=None, help="site directory or site.toml (for --positions; default: the site named by walk.toml beside the file)")
    p.add_argument("--window-s", type=bounded(0.2, 3600.0, "s"), default=2.0, help="window length, s (default 2)")
    p.add_argument("--hop-s", type=bounded(0.05, 3600.0, "s"), default=1.0, help="window hop, s (default 1)")
    p.add_argument("--elevation-mask-deg", type=bounded(0.0, 89.9, "deg"), default=10.0,
                   help="elevation mask, degrees, 0 to 89.9 (default 10)")
    p.add_argument("--fluct-threshold-dbhz", type=bounded(0.1, 30.0, "dB-Hz"), default=2.0,
                   help="smallest C/N0 swing counted as a fluctuation, dB-Hz (default 2: NMEA C/N0 is in whole dB-Hz)")
    p.add_argument("--cn0-reference", type=Path, default=None,
                   help="JSON file with a fitted C_ref model {intercept_dbhz, slope_dbhz} (default: built-in)")
    p.add_argument("--fit-cn0-reference", type=Path, default=None, metavar="JSON",
                   help="fit C_ref(el) to this file's tracked satellites (use an open-sky log) and write it as JSON")
    p.add_argument("--start-utc", default=None,
                   help="t_s origin, ISO 8601 UTC; default: start_utc of the walk.toml/cell.toml beside the file, "
                        "else the first epoch")
    p.add_argument("--allow-missing-checksum", action="store_true",
                   help="use sentences that carry no *hh checksum (some phone logs); a wrong checksum is "
                        "still skipped")
    p.add_argument("--epochs", type=Path, default=None, help="also write each decoded epoch as a JSON line")
    p.add_argument("--positions", type=Path, default=None, help="also write fixes in site ENU with sigma, and lat/lon/ellipsoidal height (CSV)")
    p.add_argument("--fit-uere", type=Path, default=None, metavar="JSON",
                   help="fit the UERE table (per fix quality and C/N0 attenuation) to the fixes' errors against "
                        "the truth.csv beside the file (a simulated walk) and write it as JSON")
    p.add_argument("--gpsd-json", type=Path, default=None, metavar="JSONL",
                   help="also write the epochs as gpsd's JSON (TPV and SKY objects, one per line)")
    p.set_defaults(func=_run)


def _fmt(value) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.10g}"
    return str(value)


def _csv(columns: dict, names) -> str:
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    arrays = [columns[n] for n in names]
    for row in zip(*arrays):
        buf.write(",".join(_fmt(v.item() if hasattr(v, "item") else v) for v in row) + "\n")
    return buf.getvalue()


def _walk_beside(nmea: Path):
    """The walk.toml / cell.toml in the NMEA file's directory, if any (its start time and site)."""
    from features.walk import load_walk
    d = Path(nmea).parent
    if (d / "walk.toml").is_file() or (d / "cell.toml").is_file():
        return load_walk(d)
    return None


def _on_time_base(epochs, start_utc: str | None):
    """Epochs with t_s re-based to ``start_utc`` (ISO 8601); unchanged when None."""
    if start_utc is None:
        return epochs
    from features.gnss.nmea import epochs_on_time_base
    from features.walk import parse_utc
    return epochs_on_time_base(epochs, parse_utc(start_utc, "--start-utc"))


def _fit_uere(args, epochs, site) -> str:
    """--fit-uere: the UERE table fitted against truth.csv beside the NMEA file, as JSON text."""
    from features.gnss.positions import fit_uere, fixes_to_enu
    from features.walk import read_truth

    truth_path = Path(args.nmea).parent / "truth.csv"
    if site is None or not truth_path.is_file():
        raise ConfigError(f"--fit-uere needs truth.csv beside {args.nmea} and the site (--site or walk.toml)")
    truth = read_truth(truth_path)
    o = site.origin
    table = fit_uere([fixes_to_enu(epochs, o.lat_deg, o.lon_deg, o.alt_m)], [(truth.t_s, truth.east_m, truth.north_m)],
                     source=f"fitted to {args.nmea}")
    return json.dumps(table.to_dict(), indent=2) + "\n"


def _utc_of_t0(epochs):
    """The UTC time of t_s = 0, from the first epoch that carries a date (None without any)."""
    import datetime as dt

    dated = next((e for e in epochs if e.time_utc is not None), None)
    return None if dated is None else dated.time_utc - dt.timedelta(seconds=dated.t_s)


def _beside(path) -> dict:
    """The walk.toml / cell.toml beside a recording (read for its time base and site): inputs too."""
    from pathlib import Path

    parent = Path(path).parent
    return {f"{n} beside it": parent / n for n in ("walk.toml", "cell.toml")}


def _run(args) -> int:
    from features.fileio import atomic_write_many
    from features.gnss.features import (
        COUNT_COLUMNS, FEATURE_COLUMNS, Cn0Reference, GnssFeatureConfig, fit_cn0_reference, gnss_features, sky_arrays,
    )
    from features.gnss.nmea import read_nmea

    check_outputs({"NMEA": args.nmea, "--site": args.site, "--cn0-reference": args.cn0_reference,
                   **_beside(args.nmea)},
                  {"--out": args.out, "--epochs": args.epochs, "--positions": args.positions,
                   "--fit-cn0-reference": args.fit_cn0_reference, "--gpsd-json": args.gpsd_json,
                   "--fit-uere": args.fit_uere})
    config = GnssFeatureConfig(window_s=args.window_s, hop_s=args.hop_s, elevation_mask_deg=args.elevation_mask_deg,
                               fluct_threshold_dbhz=args.fluct_threshold_dbhz)
    reference = Cn0Reference()
    if args.cn0_reference is not None:
        try:
            reference = Cn0Reference.from_dict(json.loads(args.cn0_reference.read_text()))
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError) as exc:
            detail = str(exc)[:200].replace("Cn0Reference.", "")
            raise ConfigError(f"--cn0-reference {args.cn0_reference}: cannot read it as a C/N0 reference "
                              f"({type(exc).__name__}: {detail})") from None
    walk = _walk_beside(args.nmea)
    site = None
    if args.site is None and args.positions is not None and walk is None:
        raise ConfigError("--positions needs --site (the ENU origin; no walk.toml or cell.toml beside the file)")
    if args.site is not None or args.positions is not None:
        try:
            site = resolve_site(walk, args.site)
        except ConfigError as exc:
            raise ConfigError(f"--positions needs --site (the ENU origin): {exc}") from None
    if args.start_utc is None and walk is not None and walk.start_utc is not None:
        args.start_utc = walk.start_utc.isoformat()  # t_s on the walk's time base
    try:
        epochs, stats = read_nmea(args.nmea, require_checksum=not args.allow_missing_checksum)
    except NmeaError as exc:
        hint = ("; the sentences carry no checksum: if that is how the device writes them, pass "
                "--allow-missing-checksum") if "no checksum" in str(exc) and not args.allow_missing_checksum else ""
        raise NmeaError(f"{exc}{hint}") from None
    epochs = _on_time_base(epochs, args.start_utc)
    sky = sky_arrays(epochs)
    table = gnss_features(sky, config, reference)
    names = ("t_s",) + FEATURE_COLUMNS + COUNT_COLUMNS
    origin_utc = _utc_of_t0(epochs)
    outputs = {args.out: _csv(*reversed(with_time_utc(names, table, origin_utc)))}
    if args.epochs is not None:
        outputs[args.epochs] = "".join(json.dumps(e.to_json_dict()) + "\n" for e in epochs)
    if args.gpsd_json is not None:
        from features.gnss.gpsd import gpsd_json_lines
        outputs[args.gpsd_json] = gpsd_json_lines(epochs)
    if args.fit_cn0_reference is not None:
        fitted = fit_cn0_reference(sky.el_deg, sky.cn0_dbhz)
        outputs[args.fit_cn0_reference] = json.dumps(fitted.to_dict(), indent=2) + "\n"
    n_pos = None
    if args.positions is not None:
        from features.gnss.positions import fixes_to_enu
        o = site.origin
        pos = fixes_to_enu(epochs, o.lat_deg, o.lon_deg, o.alt_m)
        names, cols = with_time_utc(pos.COLUMNS, {n: getattr(pos, n) for n in pos.COLUMNS}, origin_utc)
        names, cols = with_geodetic(names, cols, o)
        outputs[args.positions] = _csv(cols, names)
        n_pos = len(pos)
    if args.fit_uere is not None:
        outputs[args.fit_uere] = _fit_uere(args, epochs, site if site is not None else (
            walk.load_site() if walk is not None and walk.site_ref is not None else None))
    atomic_write_many(outputs)
    n_with_sky = int(sky.n_epochs)
    msg = (f"{args.nmea}: {len(epochs)} epochs ({n_with_sky} with satellites, "
           f"{sum(e.fix.has_position for e in epochs)} with a fix); {stats.summary()}; "
           f"{len(table['t_s'])} windows -> {args.out}")
    if n_pos is not None:
        msg += f"; {n_pos} positions -> {args.positions}"
    if args.fit_cn0_reference is not None:
        msg += (f"; C_ref fitted: {fitted.intercept_dbhz:.2f} + {fitted.slope_dbhz:.2f}*sin(el) dB-Hz "
                f"-> {args.fit_cn0_reference}")
    if n_with_sky == 0:
        msg += "; no GSV in the file, so every feature is empty"
    print(msg)
    if args.cn0_reference is None:
        # Issue 12 item 6: a real receiver's C/N0 sits dB away from the built-in curve (a ZED-F9P log reads
        # 20.5 dB "attenuated" under it, 9.3 dB under its own calibrated reference).
        print("envfuse: warning: att_mean_db / att_std_db use the built-in open-sky C/N0 reference, not one "
              "calibrated for this receiver; fit one with --fit-cn0-reference on open-sky data and pass it with "
              "--cn0-reference ('survey build' calibrates every receiver of a survey itself)", file=sys.stderr)
    return 0
