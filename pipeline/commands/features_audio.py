"""``envfuse features audio``: beacon recording → acoustic feature windows (CSV) and positions (CSV)."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from features.errors import AudioError, ConfigError
from pipeline.args import (UsageError, bounded, check_outputs, non_negative, open_interval, positive,
                           resolve_site)
from pipeline.tables import csv_text, with_geodetic, with_time_utc

GROUP = "features"


def register(sub) -> None:
    p = sub.add_parser(
        "audio", help="acoustic CIR features per window and beacon positions from a WAV file",
        description="Band-pass and matched-filter a beacon recording (48 kHz; other rates are resampled with "
                    "a warning), detect each beacon chirp in its TDMA slot, and write the nine CIR features "
                    "per window (windows without a chirp flagged 'no_chirp'); optionally the acoustic "
                    "position, clock offset and covariance per frame.",
        epilog="Example: envfuse features audio walk7/audio.wav --site site1 --walk walk7/walk.toml "
               "--out audio_features.csv --positions audio_positions.csv")
    p.add_argument("wav", type=Path, help="audio file (WAV; mono or first channel)")
    p.add_argument("--site", type=Path, default=None,
                   help="site directory or site.toml (beacons, chirps, frames); default: the site named by --walk")
    p.add_argument("--walk", type=Path, default=None,
                   help="walk.toml or cell.toml: [audio] start_s / start_uncertainty_s and start_utc place the "
                        "samples on the walk time base and the beacon frames (default: the first sample at t=0 "
                        "on a frame boundary, see --start-uncertainty-s); a walk.toml/cell.toml beside the WAV is used "
                        "when --walk is not given")
    p.add_argument("--start-uncertainty-s", type=bounded(0.0, 2.0, "s"), default=None,
                   help="stated uncertainty of the audio start, s (default: from --walk, else 0.05)")
    p.add_argument("--out", type=Path, required=True, help="feature CSV, one row per window; - for stdout")
    p.add_argument("--positions", type=Path, default=None, help="also write one position row per frame (CSV)")
    p.add_argument("--window-s", type=bounded(0.2, 3600.0, "s"), default=2.0, help="window length, s (default 2)")
    p.add_argument("--hop-s", type=bounded(0.05, 3600.0, "s"), default=1.0, help="window hop, s (default 1)")
    p.add_argument("--max-range-m", type=positive, default=None,
                   help="largest range at which a beacon is searched, m (default: the site's extent)")
    p.add_argument("--p-fa", type=open_interval(0.0, 1.0), default=1e-6,
                   help="false-alarm probability per search window, in (0, 1) (default 1e-6)")
    p.add_argument("--motion-speed-m-s", type=non_negative, default=None,
                   help="walking-speed prior for positions, m/s (default: 0 for a survey cell.toml, whose capture "
                        "is static, else 1.4)")
    p.set_defaults(func=_run)


def _columns(rows: list[dict], names) -> dict:
    return {n: [r[n] for r in rows] for n in names}


def _check_audio(wav: Path, site) -> None:
    """Refuse audio that cannot hold a beacon chirp at all: no samples, or a Nyquist below every band."""
    from features.acoustic.audio import audio_info, require_beacon_band
    from features.errors import AudioError

    if not site.beacons:
        if audio_info(wav).n_frames == 0:
            raise AudioError(f"{wav}: holds no audio samples")
        return
    require_beacon_band(wav, min(b.f0_hz if b.f0_hz is not None else site.acoustic.f0_hz for b in site.beacons))


def _print_warnings(caught) -> None:
    from features.acoustic.audio import AudioWarning

    for w in caught:
        if issubclass(w.category, AudioWarning):
            print(f"envfuse: warning: {w.message}", file=sys.stderr)


def _run(args) -> int:
    from features.acoustic.features import FEATURE_COLUMNS, WindowConfig, analyse_audio
    from features.acoustic.positions import POSITION_COLUMNS, PositionConfig
    from features.acoustic.audio import AudioWarning
    from features.acoustic.detection import DetectorConfig
    from features.fileio import atomic_write_many
    from features.acoustic.timing import timing_from_walk

    from features.walk import load_walk

    check_outputs({"WAV": args.wav, "--site": args.site, "--walk": args.walk,
                   **{f"{n} beside it": args.wav.parent / n for n in ("walk.toml", "cell.toml")}},
                  {"--out": args.out, "--positions": args.positions})
    if args.walk is None:
        beside = [args.wav.parent / n for n in ("walk.toml", "cell.toml") if (args.wav.parent / n).is_file()]
        args.walk = beside[0] if beside else None
    if args.wav.is_dir():
        raise AudioError(f"{args.wav}: is a directory, expected a WAV file")
    if not args.wav.exists():
        raise AudioError(f"{args.wav}: does not exist")
    site = resolve_site(None if args.walk is None else load_walk(args.walk), args.site)
    if not site.beacons:
        raise ConfigError(f"{args.site or args.walk}: the site lists no [[beacons]]")
    _check_audio(args.wav, site)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AudioWarning)
        timing = timing_from_walk(None if args.walk is None else load_walk(args.walk), site,
                                  args.start_uncertainty_s, where=args.walk)
    _print_warnings(caught)
    detector = DetectorConfig(p_fa=args.p_fa, max_range_m=args.max_range_m)
    motion = args.motion_speed_m_s
    if motion is None:
        static = args.walk is not None and (args.walk.name == "cell.toml" or (args.walk / "cell.toml").is_file())
        motion = 0.0 if static else 1.4
    positions = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05, motion_speed_m_s=motion)
    try:
        windows = WindowConfig(window_s=args.window_s, hop_s=args.hop_s)
    except ConfigError as exc:  # name the options, not the config fields
        raise UsageError(str(exc).replace("window_s", "--window-s").replace("hop_s", "--hop-s")) from None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AudioWarning)
        result = analyse_audio(args.wav, site, timing, detector, windows, positions)
    _print_warnings(caught)
    walk = None if args.walk is None else load_walk(args.walk)
    origin_utc = None if walk is None else walk.start_utc  # t_s counts from the walk's start_utc
    names, cols = with_time_utc(FEATURE_COLUMNS, _columns(result.rows, FEATURE_COLUMNS), origin_utc)
    outputs = {args.out: csv_text(names, cols)}
    if args.positions is not None:
        rows = [f.as_row() for f in result.fixes]
        names, cols = with_time_utc(POSITION_COLUMNS, _columns(rows, POSITION_COLUMNS), origin_utc)
        names, cols = with_geodetic(names, cols, site.origin, up_m=site.device_height_m)
        outputs[args.positions] = csv_text(names, cols)
    atomic_write_many(outputs)
    msg = (f"{args.wav}: {result.duration_s:.1f} s, {result.n_detections} chirps detected, "
           f"{sum(r['acoustic_available'] for r in result.rows)}/{len(result.rows)} windows with a chirp "
           f"-> {args.out}")
    if args.positions is not None:
        msg += f"; {len(result.fixes)} positions -> {args.positions}"
    print(msg)
    return 0
