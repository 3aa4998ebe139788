"""Read a walk directory once, every source on the walk's time base.

:func:`read_walk` is what every command that reads a walk stands on
(``run``, ``evaluate``, ``train fusion``, ``report walk``, the demo). It reads
only the walk's files (as for a real device's log) and returns, per source:

- GNSS: the NMEA fixes in the site's ENU frame with their per-axis σ, fix
  quality and HDOP, and the five GNSS feature windows;
- acoustic: the beacon fixes with their (east, north, clock) covariance and the
  nine CIR feature windows, on the audio time base stated in ``walk.toml``
  (:func:`features.acoustic.timing.timing_from_walk`);
- PDR: the detected steps (time, length, heading) and the dead-reckoned track;
- UWB (``uwb.csv`` on a site with ``[[uwb_anchors]]``): the tag's ranging log and a position per ranging
  round with its covariance (:class:`UwbStream`);
- truth, when ``truth.csv`` is present (evaluation only: nothing above reads
  it; the PDR start comes from the first good GNSS fix, see :func:`pdr_start_from_gnss`).

A vehicle's drive (``envfuse convert smartloc``) holds raw measurements in their place, and the
reader turns them into the same streams:

- ``gnss_pseudoranges.csv`` → per-epoch weighted least squares with one clock per system, Sagnac
  and RAIM (:func:`features.gnss.wls.solve_epochs`, default :class:`~features.gnss.wls.WlsConfig`)
  → the same :class:`GnssStream`: fixes in the site's ENU frame with their covariance
  (:func:`~features.gnss.wls.wls_positions`) and the five features from the per-satellite data
  (:func:`~features.gnss.sat_features.pseudorange_features`);
- ``odometry.csv`` → speed × yaw rate integrated into displacement events with their own noise
  from the file's variances, the initial heading and start fitted to the first GNSS fixes
  (:func:`~features.vehicle.odometry.odometry_dead_reckoning`; it looks ahead, so offline) →
  :class:`OdometryStream`, in the PDR stream's place (``WalkData.pdr``): the filters take its events
  as steps.

A stream the walk does not have is ``None``; so is one whose file is named but absent, empty (0 bytes, a
WAV without samples, an IMU header without rows) or unusable (its reader refuses it): the walk is read
without it, exactly as without the file, and :attr:`WalkData.notes` says which and why, so ``run``,
``evaluate`` and ``train fusion`` behave the same for all of these and say so.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from features.acoustic.audio import require_beacon_band
from features.acoustic.features import AudioAnalysis, analyse_audio
from features.acoustic.positions import PositionConfig
from features.acoustic.timing import AudioTiming, timing_from_walk
from features.gnss.features import FluctuationState, fluctuation_state, gnss_features, sky_arrays
from features.gnss.nmea import epochs_on_time_base, read_nmea_columns
from features.gnss.positions import GnssPositions, fixes_to_enu
from features.gnss.sat_features import pseudorange_features
from features.gnss.wls import WlsConfig, solve_epochs, wls_positions
from features.acoustic.tracking import ReceiverState
from features.imu.heading import HeadingConfig, HeadingState
from features.imu.pdr import PdrConfig, PdrResult, run_pdr
from features.imu.reader import ImuData, read_imu_csv
from features.imu.steps import StepLengthModel
from features.raw_tables import read_odometry_csv, read_pseudorange_csv
from features.site import Site
from features.errors import DataError
from features.uwb.position import UwbFixes, UwbSolveConfig, uwb_positions
from features.uwb.reader import UwbLog, read_uwb
from features.vehicle.odometry import DeadReckoning, HeadingAlignment, OdometryConfig, odometry_dead_reckoning
from features.walk import STREAMS, Truth, WalkInfo, load_walk, read_truth
from models.graph.tight import RangeRows
from walks.acoustic_ranges import range_rows

__all__ = ["ReaderStates", "GnssStream", "AcousticStream", "PdrStream", "OdometryStream", "UwbStream", "WalkData", "read_walk",
           "WALK_SPEED_PRIOR_M_S", "walk_has", "pdr_start_from_gnss", "pdr_position_at", "read_gnss_stream",
           "read_pseudorange_stream", "read_acoustic_stream", "read_pdr_stream", "read_odometry_stream",
           "read_uwb_stream"]

SKIPPED_NOTE_SHARE = 0.05
"""A walk's note names the NMEA reader's skips when they exceed this share of the file's sentences."""

WALK_SPEED_PRIOR_M_S = 1.4
"""Walking-speed prior of the acoustic solver on a walk, m/s (a survey cell is static: 0)."""


@dataclass(frozen=True)
class GnssStream:
    """GNSS of a walk: ``positions`` (fixes with σ, quality, HDOP; arrays of shape (n_fixes,)),
    ``features`` (the five feature windows, dict of arrays of shape (n_windows,)), and the
    reader's summary (the NMEA reader's, or the pseudorange solver's counts); ``solution``
    the per-epoch solution (:class:`~features.gnss.wls.WlsSolution`) when the fixes were solved
    from pseudoranges, else None."""

    positions: GnssPositions
    features: dict
    nmea_summary: dict
    solution: object = None
    skipped_share: float = 0.0
    """Share of the file's sentences the NMEA reader skipped (bad checksum, truncated, ...)."""
    fluct_state: FluctuationState | None = None
    """The ``fluct_per_s`` extremum detector's memory kept for a later cut of a long walk (:func:`read_walk`'s
    ``keep_states_from_s``), else None."""


@dataclass(frozen=True)
class AcousticStream:
    """Acoustic positions of a walk.

    ``t_s``, ``east_m``, ``north_m`` : ndarray of shape (n_fixes,);
    ``covariance_en_m2`` : ndarray of shape (n_fixes, 2, 2), the fixes' horizontal covariance;
    ``analysis`` : the receiver's full output (feature rows, fixes with clock offsets, counts);
    ``timing`` : the audio time base used;
    ``ranges`` : every associated beacon range of every frame (:func:`walks.acoustic_ranges.range_rows`),
    for tightly coupled fusion.
    """

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    covariance_en_m2: np.ndarray
    analysis: AudioAnalysis
    timing: AudioTiming
    ranges: RangeRows | None = None

    @property
    def feature_rows(self) -> list:
        """The nine CIR features per window (dicts keyed by FEATURE_COLUMNS)."""
        return self.analysis.rows


@dataclass(frozen=True)
class PdrStream:
    """PDR of a walk: ``result`` holds the steps (``t_s``, ``step_length_m``, ``heading_rad``) and
    the track dead-reckoned from ``start_en_m``; ``config`` the settings used; ``imu`` the repaired
    100 Hz samples PDR ran on (accelerometer, gyro, magnetometer: for the methods that integrate the
    IMU themselves, the seed's complementary heading and IMU preintegration; 72 bytes per sample,
    26 MB per hour at 100 Hz)."""

    result: PdrResult
    config: PdrConfig
    start_en_m: tuple[float, float]
    imu: ImuData | None = None
    repaired: str = ""
    """What the IMU reader repaired (its :meth:`~features.imu.reader.ImuRepairReport.summary`), empty if nothing."""


@dataclass(frozen=True)
class OdometryStream:
    """A vehicle's odometry in the PDR stream's place: ``result`` holds the displacement events with PDR's
    names (``t_s``, ``step_length_m``, ``heading_rad``, ``east_m``, ``north_m``) and their own noise
    (``sigma_step_length_m``, ``sigma_heading_increment_rad``, ``segment_s``:
    :class:`~features.vehicle.odometry.DeadReckoning`); ``alignment`` the initial heading and start fitted to
    the GNSS fixes; ``config`` the settings used."""

    result: DeadReckoning
    alignment: HeadingAlignment
    config: OdometryConfig

    @property
    def start_en_m(self) -> tuple[float, float]:
        return self.result.start_en_m


@dataclass(frozen=True)
class UwbStream:
    """UWB of a walk: the tag's ranging ``log`` (:class:`~features.uwb.reader.UwbLog`), the site's surveyed
    ``anchors``, the tag's height ``tag_up_m`` (the site's device height) and ``fixes``, each round solved by
    :func:`~features.uwb.position.uwb_positions` with the default settings (ranges where three or more
    anchors answered, ranges and PDoA angles where one or two did). :meth:`positions` solves again with
    other settings."""

    log: UwbLog
    anchors: tuple
    tag_up_m: float
    fixes: UwbFixes

    def positions(self, config: UwbSolveConfig) -> UwbFixes:
        """The rounds solved with ``config``."""
        return uwb_positions(self.log, self.anchors, self.tag_up_m, config)


@dataclass(frozen=True)
class ReaderStates:
    """The readers' states a cut of a long walk resumes from (:func:`read_walk`, :mod:`walks.segments`):
    ``heading``, the PDR heading filter's before the cut's first IMU sample; ``receiver``, the acoustic
    receiver's before one of its frames; ``gnss``, the GNSS ``fluct_per_s`` extremum detector's before one of
    the NMEA epochs (:class:`~features.gnss.features.FluctuationState`). None: that reader starts afresh."""

    heading: HeadingState | None = None
    receiver: ReceiverState | None = None
    gnss: FluctuationState | None = None


@dataclass(frozen=True)
class WalkData:
    """Every source of one walk; a stream the walk lacks is ``None``. ``pdr`` is a :class:`PdrStream` (IMU) or
    an :class:`OdometryStream` (a vehicle's odometry)."""

    walk: WalkInfo
    site: Site
    gnss: GnssStream | None
    acoustic: AcousticStream | None
    pdr: PdrStream | OdometryStream | None
    truth: Truth | None
    notes: tuple = ()
    """One line per stream the walk names but could not use (absent, empty or unusable file)."""
    uwb: UwbStream | None = None
    """The UWB tag's log and fixes (walks with ``uwb.csv`` on a site with ``[[uwb_anchors]]``), else None."""


def read_walk(walk_dir: str | os.PathLike, *, site: Site | None = None, pdr_k: float | None = None,
              audio_positions: PositionConfig | None = None, truth: bool = True,
              resume: "ReaderStates | None" = None, keep_states_from_s: float = math.inf) -> WalkData:
    """Read a walk directory once: GNSS, acoustic and PDR streams and the truth when present.

    ``site`` overrides the site named in ``walk.toml``; ``pdr_k`` the step-length
    constant (Weinberg K; default the model's); ``audio_positions`` the acoustic
    solver's settings (default: clock bound = stated start uncertainty + 50 ms,
    walking-speed prior :data:`WALK_SPEED_PRIOR_M_S`).

    The PDR track is anchored on data, never on truth: at the first good GNSS
    fix (:func:`pdr_start_from_gnss`), else at the origin. ``truth=False`` leaves ``truth.csv`` unread
    (``run`` needs none).

    A long walk read in cuts (:mod:`walks.segments`): ``resume``, the readers' states the read of the
    preceding cut kept (:class:`ReaderStates`), and ``keep_states_from_s``, the walk time from which this read
    keeps them for the next cut: the acoustic receiver's state before its first frame from then on
    (``acoustic.analysis.receiver_state``), the GNSS extremum detector's before its first epoch from then on
    (``gnss.fluct_state``; the PDR heading's is taken from its per-sample record).
    """
    walk = load_walk(walk_dir)
    site = walk.load_site() if site is None else site
    truth = read_truth(walk.directory) if truth and (walk.directory / "truth.csv").is_file() else None
    notes: list[str] = []
    gnss = _optional(walk, "gnss", lambda: read_gnss_stream(walk, site, resume and resume.gnss,
                                                            keep_states_from_s), notes)
    if gnss is None and not walk.streams.get("gnss"):
        gnss = _optional(walk, "gnss_pseudoranges", lambda: read_pseudorange_stream(walk, site), notes)
    acoustic = None
    if site.beacons:
        acoustic = _optional(walk, "audio", lambda: read_acoustic_stream(walk, site, audio_positions,
                                                                          resume and resume.receiver,
                                                                          keep_states_from_s), notes)
    elif walk.path("audio") is not None:
        notes.append("audio: the site has no beacons; the walk is read without acoustic positions")
    pdr = _optional(walk, "imu", lambda: read_pdr_stream(walk, (0.0, 0.0), pdr_k, resume and resume.heading), notes)
    if gnss is not None and gnss.skipped_share > SKIPPED_NOTE_SHARE:
        notes.append(f"gnss: {walk.streams['gnss']['file']}: {100 * gnss.skipped_share:.0f} % of the sentences "
                     f"skipped ({gnss.nmea_summary})")
    if pdr is not None and pdr.repaired:
        notes.append(f"imu: {walk.streams['imu']['file']} repaired by the reader ({pdr.repaired})")
    if pdr is not None:
        anchor = pdr_start_from_gnss(gnss.positions) if gnss is not None else None
        if anchor is not None:
            # Shift the track so that it passes through the fix at the fix's time. The dead-reckoned
            # track is start + Σ steps (features.imu.pdr.dead_reckon), so the shift is a translation of
            # the track computed once (the same numbers as rerunning PDR from the shifted start).
            t_fix, e_fix, n_fix = anchor
            e_p, n_p = pdr_position_at(pdr.result, t_fix, (0.0, 0.0))
            pdr = _shift_pdr(pdr, e_fix - e_p, n_fix - n_p)
    if pdr is None and not walk.streams.get("imu"):
        pdr = _optional(walk, "odometry",
                        lambda: read_odometry_stream(walk, gnss.positions if gnss is not None else None), notes)
    uwb = None
    if site.uwb_anchors:
        uwb = _optional(walk, "uwb", lambda: read_uwb_stream(walk, site), notes)
    elif walk.path("uwb") is not None:
        notes.append("uwb: the site lists no [[uwb_anchors]]; the walk is read without UWB")
    return WalkData(walk=walk, site=site, gnss=gnss, acoustic=acoustic, pdr=pdr, truth=truth, notes=tuple(notes),
                    uwb=uwb)


_WHAT = {"gnss": "GNSS", "gnss_pseudoranges": "GNSS", "audio": "acoustic positions", "imu": "PDR",
         "odometry": "odometry", "uwb": "UWB"}


def _optional(walk: WalkInfo, stream: str, read, notes: list):
    """``read()`` of a stream the walk names, or None with a note when its file is absent, empty or refused."""
    table = walk.streams.get(stream)
    if not table:
        return None
    name = str(table.get("file", ""))
    path = walk.directory / name
    without = f"the walk is read without {_WHAT[stream]}"
    if not path.is_file():
        notes.append(f"{stream}: walk.toml names {name}, which is absent; {without}")
        return None
    if path.stat().st_size == 0:
        notes.append(f"{stream}: {name} is empty (0 bytes); {without}")
        return None
    try:
        return read()
    except DataError as exc:
        text = str(exc)
        prefix = f"{path}: "
        notes.append(f"{stream}: {name} is unusable ({text[len(prefix):] if text.startswith(prefix) else text}); "
                     f"{without}")
        return None


def pdr_start_from_gnss(positions: GnssPositions, window_s: float = 60.0) -> tuple[float, float, float] | None:
    """The first good GNSS fix as (t_s, east_m, north_m), or None without any fix.

    Good, in order of preference within the first ``window_s`` of fixes: RTK
    fixed (quality 4); RTK float (5) or DGNSS (2) with HDOP ≤ 2; then any fix.
    Only what the receiver wrote is read (issue 10 item 6: never the truth).
    """
    if positions is None or len(positions.t_s) == 0:
        return None
    t = np.asarray(positions.t_s, float)
    q = np.asarray(positions.quality)
    ok = np.isfinite(positions.east_m) & np.isfinite(positions.north_m) & (q > 0)
    if not ok.any():
        return None
    early = ok & (t <= t[ok][0] + window_s)
    hdop = np.nan_to_num(np.asarray(positions.hdop, float), nan=99.0)
    for sel in (early & (q == 4), early & np.isin(q, (2, 5)) & (hdop <= 2.0), ok):
        if sel.any():
            i = int(np.flatnonzero(sel)[0])
            return float(t[i]), float(positions.east_m[i]), float(positions.north_m[i])
    return None


def pdr_position_at(res: PdrResult, t_s: float, start_en: tuple[float, float]) -> tuple[float, float]:
    """Dead-reckoned position at ``t_s`` (the start before the first step, then the last step's end)."""
    if len(res.t_s) == 0 or not np.isfinite(res.east_m).any():
        return start_en
    i = int(np.searchsorted(res.t_s, t_s, side="right")) - 1
    if i < 0:
        return start_en
    return float(res.east_m[i]), float(res.north_m[i])


def _shift_pdr(pdr: PdrStream, d_east_m: float, d_north_m: float) -> PdrStream:
    """The PDR stream started (d_east_m, d_north_m) away: its track translated."""
    r = pdr.result
    moved = dataclasses.replace(r, east_m=d_east_m + r.east_m, north_m=d_north_m + r.north_m)
    start = (pdr.start_en_m[0] + d_east_m, pdr.start_en_m[1] + d_north_m)
    return PdrStream(result=moved, config=pdr.config, start_en_m=start, imu=pdr.imu, repaired=pdr.repaired)


def read_gnss_stream(walk: WalkInfo, site: Site, resume: FluctuationState | None = None,
                     keep_state_from_s: float = math.inf) -> GnssStream:
    """The walk's NMEA: fixes in the site's ENU frame with σ, quality and HDOP, and the five GNSS windows
    (``resume``, ``keep_state_from_s``: the ``fluct_per_s`` memory of a long walk's cut, :func:`read_walk`)."""
    epochs, stats = placed_nmea_epochs(walk)
    o = site.origin
    sky = sky_arrays(epochs)  # once, for both the positions' sigma and the features
    positions = fixes_to_enu(epochs, o.lat_deg, o.lon_deg, o.alt_m, sky=sky)
    share = stats.skipped / max(stats.sentences + stats.non_nmea_lines, 1)
    kept = fluctuation_state(sky, keep_state_from_s, resume=resume) if math.isfinite(keep_state_from_s) else None
    return GnssStream(positions=positions, features=gnss_features(sky, resume=resume), nmea_summary=stats.summary(),
                      skipped_share=float(share), fluct_state=kept)


def placed_nmea_epochs(walk: WalkInfo):
    """(epochs as :class:`~features.gnss.assemble.EpochColumns`, read statistics) of the walk's NMEA, on the walk's
    time base (:func:`features.gnss.nmea.epochs_on_time_base`; a long walk's cut by :func:`_on_cut_time_base`)
    and its microsecond grid (:func:`on_time_grid`)."""
    epochs, stats = read_nmea_columns(walk.path("gnss"))  # the epochs as columns: no object per satellite
    table = walk.streams.get("gnss", {})
    if "date_offset_s" in table and "cut_from_s" in table:     # a long walk's cut (walks.segments): placed as the
        cut_from, offset = _cut_number(walk, "gnss", table, "cut_from_s"), \
            _cut_number(walk, "gnss", table, "date_offset_s")           # whole walk's reader places it
        epochs = _on_cut_time_base(epochs, walk.start_utc, cut_from, offset)
    else:
        epochs = epochs_on_time_base(epochs, walk.start_utc)
    _check_overlap(walk, epochs.col("t_s"))
    return epochs.with_t_s(on_time_grid(epochs.col("t_s"))), stats


PLACE_MARGIN_S = 60.0
"""How far outside the walk's span (0 to ``duration_s``) an NMEA log's epochs may all lie before the log is refused as
not this walk's, s: a receiver started a minute early or stopped a minute late is still the walk's."""


def _check_overlap(walk: WalkInfo, t_s: np.ndarray) -> None:
    """Refuse (:class:`DataError`) an NMEA log none of whose epochs, placed by its dates against ``start_utc``, lies
    within the walk's span: ``start_utc`` or the receiver's dates are wrong (a day off: a local date taken for
    UTC's; the log of another day). Before, such a log was fused a day away from the other streams, silently."""
    if not len(t_s):
        return
    end = walk.duration_s if walk.duration_s is not None else math.inf
    inside = (t_s >= -PLACE_MARGIN_S) & (t_s <= end + PLACE_MARGIN_S)
    if inside.any():
        return
    off = float(np.median(t_s))
    days = off / 86400.0
    hint = (f" — {abs(round(days)):.0f} whole day{'s' if abs(round(days)) != 1 else ''} "
            f"{'before' if off < 0 else 'after'} it: a date taken in local time, or the log of another day"
            if abs(round(days)) >= 1 and abs(days - round(days)) < 0.05 else "")
    raise DataError(f"{walk.path('gnss')}: its epochs, placed by their own dates, lie {off:+,.0f} s (median) from the "
                    f"walk's start_utc {walk.start_utc:%Y-%m-%dT%H:%M:%SZ}{hint}; none within the walk "
                    f"(0 to {end:g} s): start_utc in walk.toml or the receiver's dates are wrong")


def _cut_number(walk: WalkInfo, stream: str, table: dict, key: str) -> float:
    """A number a long walk's cut states in its ``[stream]`` table (:mod:`walks.segments`), or one clear error."""
    try:
        return float(table[key])
    except (TypeError, ValueError):
        raise DataError(f"{walk.directory / 'walk.toml'}: [{stream}] {key} must be a number, got {table[key]!r} "
                        f"(a long walk's cut states it)") from None


def _on_cut_time_base(epochs, start_utc, cut_from_s: float, date_offset_s: float):
    """A long walk's cut of the NMEA (:mod:`walks.segments`) on the walk's time base: its first epoch at its time
    of day less ``start_utc``'s plus the whole days that put it within 12 h of ``cut_from_s`` (the cut's first walk
    time; of the start for the first cut), plus ``date_offset_s``, the whole log's median offset of its dates
    against its times of day (0 when they agree with ``start_utc``), and every epoch after it as the reader spaces
    them. The whole walk's reader places each epoch the same way, through the median over the whole log's dated
    epochs (:func:`features.gnss.nmea.epochs_on_time_base`); a cut's own dates may not say it: a cold start's
    bogus dates can be most of one cut, and a log whose RMC stopped leaves later cuts without any (until
    2026-12-03 such cuts were placed years off, or fused without GNSS)."""
    s = start_utc
    start_tod = s.hour * 3600 + s.minute * 60 + s.second + s.microsecond * 1e-6
    base = float(epochs.col("time_of_day_s")[0]) - start_tod
    ref = cut_from_s if math.isfinite(cut_from_s) else 0.0
    first = base + 86400.0 * round((ref - base) / 86400.0)
    return epochs.with_t_s(epochs.col("t_s") + (first + date_offset_s - float(epochs.col("t_s")[0])))


NMEA_TIME_GRID_S = 1e-6
"""Grid the NMEA epochs' and the IMU samples' walk times are rounded to, s: every time an NMEA log and
``start_utc`` can state lies on it (times of day to 0.01 or 0.001 s, ``start_utc`` to the microsecond), as do
the samples of an IMU log written to the microsecond at a rate whose period is a whole number of them (100 Hz)."""


def on_time_grid(t_s: np.ndarray) -> np.ndarray:
    """Walk times (n,) rounded to :data:`NMEA_TIME_GRID_S` (the nearest double to the decimal time): the same
    epoch then has the same time whichever epoch the log starts with. The reader places epochs on the walk's
    time base as (time since the file's first epoch) + (the median offset of the dated ones)
    (:func:`features.gnss.nmea.epochs_on_time_base`), whose round-off (~1e-11 s) depends on that first epoch:
    a long walk's cut (:mod:`walks.segments`) then put a fix a few ulps from the whole walk's. Likewise the IMU
    reader's uniform time base, first sample + k / (1 / median interval) (:func:`features.imu.reader.read_imu_csv`),
    moves with the cut's first sample and median. Where a step ends at a fix's time (IMU samples and fixes share
    the 10 ms grid) a cut and the whole walk then read the step and the fix in opposite orders (measured: 0.7-28
    mm on a 300 s walk in 60 s segments). A walk read whole changes too, where a fix lay a few ulps before a
    step's end: the step is no longer split there, and the fix follows it (``run`` on a 21-minute simulated
    walk, seed 77: 11,309 → 11,266 epochs, positions within 0.013 m of before, median 7e-7 m; 10 minutes,
    seed 79: 5,224 → 5,195, 0.008 m)."""
    return np.round(np.asarray(t_s, float) * (1.0 / NMEA_TIME_GRID_S)) / (1.0 / NMEA_TIME_GRID_S)


def read_pseudorange_stream(walk: WalkInfo, site: Site, config: WlsConfig | None = None) -> GnssStream:
    """The walk's pseudoranges solved epoch by epoch (``config``, default :class:`~features.gnss.wls.WlsConfig`:
    RTKLIB weights, Sagnac, RAIM): fixes in the site's ENU frame with their covariance and quality text, and
    the five GNSS windows from the per-satellite data (ζ, λ with the untracked satellites predicted from
    their own tracked positions: :mod:`features.gnss.sat_features`)."""
    table = read_pseudorange_csv(walk.path("gnss_pseudoranges"),
                                 walk.streams["gnss_pseudoranges"].get("corrections",
                                                                       ["satellite_clock", "ionosphere",
                                                                        "troposphere"]))
    sol = solve_epochs(table, config or WlsConfig())
    o = site.origin
    positions = wls_positions(sol, o.lat_deg, o.lon_deg, o.alt_m, table=table)
    summary = {"source": "pseudoranges", "weights": sol.weight_model, "epochs": len(sol),
               "fixes": int(sol.has_fix.sum()), "mean_used": float(np.mean(sol.n_used[sol.has_fix]))
               if sol.has_fix.any() else 0.0, "excluded": int(sol.n_excluded.sum()),
               "raim_alarms": int(np.sum(sol.integrity[sol.has_fix] == 1))}
    return GnssStream(positions=positions, features=pseudorange_features(table, sol), nmea_summary=summary,
                      solution=sol)


def read_odometry_stream(walk: WalkInfo, fixes: GnssPositions | None,
                         config: OdometryConfig | None = None) -> OdometryStream:
    """The walk's odometry integrated into displacement events (:mod:`features.vehicle.odometry`), its heading
    and start fitted to the GNSS ``fixes`` (never to the truth). Raises DataError without fixes to fit."""
    table = read_odometry_csv(walk.path("odometry"))
    if fixes is None or len(fixes.t_s) < 3:
        raise DataError(f"{walk.path('odometry')}: odometry needs >= 3 GNSS fixes in the walk to fit its initial "
                        "heading and start")
    cfg = config or OdometryConfig()
    dr, align = odometry_dead_reckoning(table, fixes.t_s, fixes.east_m, fixes.north_m, cfg)
    return OdometryStream(result=dr, alignment=align, config=cfg)


def read_acoustic_stream(walk: WalkInfo, site: Site, positions: PositionConfig | None,
                         resume: ReceiverState | None = None, keep_state_from_s: float = math.inf) -> AcousticStream:
    """The walk's audio through the acoustic receiver: fixes with covariance and the nine CIR windows
    (``resume``, ``keep_state_from_s``: :func:`read_walk`)."""
    require_beacon_band(walk.path("audio"), min(b.f0_hz if b.f0_hz is not None else site.acoustic.f0_hz
                                                for b in site.beacons))
    timing = timing_from_walk(walk, site)
    first_sample, timing = _cut_alignment(walk, timing)
    if positions is None:
        positions = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05,
                                   motion_speed_m_s=WALK_SPEED_PRIOR_M_S)
    res = analyse_audio(walk.path("audio"), site, timing, positions=positions, keep_frames=True, resume=resume,
                        keep_state_from_s=keep_state_from_s, first_sample=first_sample)
    # the frames' ranges kept compactly (56 bytes per range), the frames themselves dropped
    ranges = range_rows(res.frames, res.fixes, site, positions)
    res = dataclasses.replace(res, frames=None)
    arr = np.array([[f.t_s, f.east_m, f.north_m] for f in res.fixes]).reshape(-1, 3)
    cov = np.array([f.covariance[:2, :2] for f in res.fixes]).reshape(-1, 2, 2)
    return AcousticStream(t_s=arr[:, 0], east_m=arr[:, 1], north_m=arr[:, 2], covariance_en_m2=cov,
                          analysis=res, timing=timing, ranges=ranges)


def _cut_alignment(walk: WalkInfo, timing: AudioTiming) -> tuple[int, AudioTiming]:
    """(first_sample, timing) the receiver reads the walk's audio with: a long walk's cut
    (:mod:`walks.segments`) whose ``[audio]`` states ``first_sample``, its first sample's index in the walk's
    recording, and ``recording_start_s``, the walk time of that recording's first sample, is read aligned on
    the recording (:func:`features.acoustic.features.analyse_audio`'s ``first_sample``, with the recording's
    timing); any other audio from its own first sample (0, ``timing``)."""
    table = walk.streams.get("audio", {})
    first, start = table.get("first_sample"), table.get("recording_start_s")
    if first is None and start is None:
        return 0, timing
    where = walk.directory / "walk.toml"
    if not (isinstance(first, int) and not isinstance(first, bool) and first >= 0):
        raise DataError(f"{where}: [audio] first_sample must be a sample index >= 0, got {first!r}")
    if not (isinstance(start, (int, float)) and not isinstance(start, bool) and math.isfinite(start)):
        raise DataError(f"{where}: [audio] recording_start_s must be a finite number of seconds, got {start!r}")
    return first, dataclasses.replace(timing, start_s=float(start))


def read_pdr_stream(walk: WalkInfo, start_en: tuple[float, float], k: float | None,
                    heading_start: HeadingState | None = None) -> PdrStream:
    """The walk's IMU through PDR from ``start_en`` (m); ``k`` the Weinberg constant (None: the default);
    ``heading_start``: the heading filter's state before the first sample (:func:`read_walk`)."""
    imu = read_imu_csv(walk.path("imu"))
    imu = dataclasses.replace(imu, t_s=on_time_grid(imu.t_s))    # the same sample, the same time in any cut
    decl = float(walk.streams["imu"].get("declination_deg", 0.0))
    heading = HeadingConfig(declination_rad=np.radians(decl))
    cfg = PdrConfig(heading=heading) if k is None else PdrConfig(length=StepLengthModel(k=k), heading=heading)
    return PdrStream(result=run_pdr(imu, start_en[0], start_en[1], cfg, heading_start), config=cfg, start_en_m=start_en, imu=imu,
                     repaired=imu.report.summary() if imu.report.n_defects else "")


def read_uwb_stream(walk: WalkInfo, site: Site, config: UwbSolveConfig | None = None) -> UwbStream:
    """The walk's ``uwb.csv`` and its rounds solved against the site's surveyed anchors (one
    :class:`~features.errors.UwbError` when the log names an anchor the site does not list)."""
    log = read_uwb(walk.path("uwb"))
    anchors = tuple(site.uwb_anchors)
    fixes = uwb_positions(log, anchors, site.device_height_m, config or UwbSolveConfig())
    return UwbStream(log=log, anchors=anchors, tag_up_m=site.device_height_m, fixes=fixes)


def walk_has(walk_dir: str | os.PathLike) -> dict:
    """Which streams a walk directory holds, without reading them: {'gnss': bool, 'audio': ..., 'imu': ...,
    'gnss_pseudoranges': ..., 'odometry': ..., 'truth': ...}."""
    walk = load_walk(walk_dir)
    return {s: walk.path(s) is not None for s in STREAMS} | {
        "truth": (Path(walk.directory) / "truth.csv").is_file()}
