"""Ingest a survey directory into a fingerprint library (docs/design.md §4, §5).

A survey is ``site.toml`` plus ``cells/<cell_id>/{gnss.nmea, audio.wav,
cell.toml}``. :func:`build_library` computes, for every cell, the 14 features
per analysis window (default 2 s, hop 1 s, exactly as ``envfuse features gnss``
and ``envfuse features audio`` compute them) and stores the cell and its
windows in one transaction.

Windows. GNSS windows start at the first epoch, acoustic windows at the audio
start (:mod:`features.gnss.features`, :mod:`features.acoustic.features`); a
GNSS and an acoustic window whose centres lie within half a hop of each other
form one sample (at the acoustic centre); an unmatched window is a sample with
the other modality missing. Only windows lying wholly inside the capture
(``[0, duration_s]`` of ``cell.toml``, when given) are kept, so a trailing
half-filled GNSS window does not enter the library.

Missing streams. A stream that is absent (no file) or unusable (the reader
refuses it) is recorded in ``cells.missing_streams`` with the reason in
``cells.stream_notes``, warned about (:class:`SurveyWarning`) and its features
stored as NULL with the availability flag 0; the cell is never skipped.

C/N0 reference per receiver (issue 12 item 6). Each receiver (``[gnss]
receiver`` in ``cell.toml``, else the ``receiver`` argument) gets an open-sky
model calibrated from the survey's own data before any cell is ingested.
Rule: pool every tracked (satellite, epoch) C/N0 at or above the elevation
mask over **all cells** of that receiver; per 10° elevation bin from the mask
with at least ``cn0_min_per_bin`` samples take the ``cn0_quantile`` (default
the 90th percentile: the unobstructed line-of-sight level, reached in the open
cells and by unblocked satellites everywhere); fit C_ref(el) = a + b·sin(el)
through the bin values, count-weighted least squares
(:func:`features.gnss.features.fit_cn0_reference`). The line, the bin values
and the rule are stored with the receiver and used for that receiver's
attenuation features. With fewer than two qualifying bins (or an implausible
fit) the built-in default is used, stored with ``cn0_calibrated = 0`` and a
:class:`SurveyWarning`. A receiver already in the library keeps its stored
reference, so a resumed build computes every cell with the same one.
Measured on a simulated survey (site seed 3, 94 cells of 10 m, 10 s): the
all-cells 90th-percentile line lies within 0.6 dB of the same rule applied to
the open cells alone (the occlusion mix barely moves it) and 3.6–4.1 dB above
the simulator's median open-sky line (the built-in default), so open-sky
attenuation reads about 4 dB rather than 0 — a constant offset shared by every
receiver calibrated this way, which is what makes libraries comparable.

Resuming. A cell already stored from the same capture (same file hashes) is
skipped before any feature is computed; a run killed midway therefore resumes
where it stopped and the rerun adds nothing twice.
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from features.acoustic.features import WindowConfig, analyse_audio
from features.acoustic.timing import timing_from_walk
from features.constants import ELEVATION_MASK_DEG
from features.errors import ConfigError, DataError
from features.fileio import sha256_file
from features.gnss.features import Cn0Reference, GnssFeatureConfig, fit_cn0_reference, gnss_features, sky_arrays
from features.gnss.nmea import epochs_on_time_base, read_nmea
from features.site import load_site
from features.walk import WalkInfo, load_walk

from fingerprints.library import CellCapture, FingerprintLibrary
from fingerprints.sql import ACOUSTIC_FEATURES, GNSS_COUNTS, GNSS_FEATURES

__all__ = ["SurveyConfig", "SurveyWarning", "BuildReport", "build_library", "calibrate_cn0_reference",
           "survey_cell_dirs"]

_DEFAULT_FILES = {"gnss": "gnss.nmea", "audio": "audio.wav"}

MIN_GNSS_EPOCHS = 2
"""Fewest NMEA epochs in a window for its GNSS features to count as available: one epoch has no C/N0 series,
so no fluctuation rate β and no time spread (a capture of one epoch is recorded as a missing GNSS stream)."""


class SurveyWarning(UserWarning):
    """Something a survey build did that the user should know: a missing stream, an uncalibrated C/N0 reference."""


@dataclass(frozen=True)
class SurveyConfig:
    """Window, feature and calibration parameters of a survey build (defaults as the ``features`` CLIs)."""

    window_s: float = 2.0
    hop_s: float = 1.0
    elevation_mask_deg: float = ELEVATION_MASK_DEG
    fluct_threshold_dbhz: float = 2.0
    p_fa: float = 1e-6
    cn0_quantile: float = 0.9
    cn0_bin_width_deg: float = 10.0
    cn0_min_per_bin: int = 20

    def __post_init__(self):
        GnssFeatureConfig(self.window_s, self.hop_s, self.elevation_mask_deg, self.fluct_threshold_dbhz)
        WindowConfig(self.window_s, self.hop_s)
        if not 0.5 <= self.cn0_quantile < 1.0:
            raise ConfigError(f"--cn0-quantile must lie in [0.5, 1), got {self.cn0_quantile}")
        if not 0 < self.p_fa < 1:
            raise ConfigError(f"--p-fa must lie in (0, 1), got {self.p_fa}")
        if not (1.0 <= self.cn0_bin_width_deg <= 40.0 and self.cn0_min_per_bin >= 1):
            raise ConfigError("cn0_bin_width_deg must lie in [1, 40] and cn0_min_per_bin be >= 1")


@dataclass(frozen=True)
class BuildReport:
    """Outcome of :func:`build_library`."""

    site: str
    n_cells: int
    added: int
    unchanged: int
    replaced: int
    n_samples: int
    missing: dict = field(default_factory=dict)
    receivers: dict = field(default_factory=dict)
    empty: tuple = ()

    def summary(self) -> str:
        rx = ", ".join(f"{k} ({'calibrated' if v else 'DEFAULT C/N0 reference'})" for k, v in self.receivers.items())
        text = (f"site {self.site}: {self.n_cells} cells ({self.added} added, {self.replaced} replaced, "
                f"{self.unchanged} already stored), {self.n_samples} samples; receivers: {rx or 'none'}")
        if self.missing:
            items = [f"{c} {'+'.join(s)}" for c, s in self.missing.items()]
            more = f" and {len(items) - 10} more cells" if len(items) > 10 else ""
            text += f"; missing streams in {len(items)} cells: " + ", ".join(items[:10]) + more
        if self.empty:
            more = f" and {len(self.empty) - 10} more" if len(self.empty) > 10 else ""
            text += f"; {len(self.empty)} cells stored without any window: " + ", ".join(self.empty[:10]) + more
        return text


@dataclass(frozen=True)
class _CellPlan:
    walk: WalkInfo
    capture: CellCapture
    receiver: str
    paths: dict


def survey_cell_dirs(survey_dir: str | os.PathLike) -> list[Path]:
    """The cell directories of a survey, sorted by name (hidden names, e.g. partial outputs, ignored)."""
    cells = Path(survey_dir) / "cells"
    if not cells.is_dir():
        raise ConfigError(f"{survey_dir}: not a survey directory (no cells/ folder)")
    dirs = sorted(p for p in cells.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not dirs:
        raise ConfigError(f"{cells}: holds no cell directories")
    return dirs


def _number(data: dict, key: str, where: Path, required: bool = True) -> float | None:
    value = data.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def _plan_cell(cell_dir: Path, default_receiver: str) -> _CellPlan:
    """Read cell.toml, find and hash the streams (absent ones named with the reason)."""
    walk = load_walk(cell_dir)
    where = cell_dir / "cell.toml"
    extra = walk.extra
    paths, notes, hashes = {}, [], {}
    for stream, default in _DEFAULT_FILES.items():
        table = walk.streams.get(stream)
        name = table["file"] if table else default
        p = cell_dir / str(name)
        if p.is_file():
            paths[stream] = p
            hashes[stream] = sha256_file(p)
        elif table:
            notes.append(f"{stream}: {name} not found")
        else:
            notes.append(f"{stream}: no [{stream}] table in cell.toml and no {default}")
    label = extra.get("map_label")
    share = extra.get("map_share", extra.get("blocked_sky_share"))
    capture = CellCapture(
        cell_id=str(extra.get("id", cell_dir.name)), east_m=_number(extra, "east_m", where),
        north_m=_number(extra, "north_m", where), start_utc=walk.start_utc.isoformat().replace("+00:00", "Z"),
        duration_s=walk.duration_s, map_label=None if label is None else str(label),
        map_share=None if share is None else _number(extra, "map_share" if "map_share" in extra
                                                     else "blocked_sky_share", where),
        missing_streams=tuple(s for s in _DEFAULT_FILES if s not in paths), stream_notes="; ".join(notes),
        gnss_sha256=hashes.get("gnss"), audio_sha256=hashes.get("audio"))
    receiver = str(walk.streams.get("gnss", {}).get("receiver") or default_receiver)
    return _CellPlan(walk, capture, receiver, paths)


def _check_window(plans: list, config: SurveyConfig, survey_dir) -> None:
    """Refuse a window longer than every capture (no cell would get a sample); warn for the cells it exceeds."""
    durations = {p.capture.cell_id: p.capture.duration_s for p in plans if p.capture.duration_s is not None}
    if not durations:
        return
    short = sorted(c for c, d in durations.items() if d < config.window_s)
    if len(short) == len(plans):
        raise ConfigError(f"{survey_dir}: --window-s {config.window_s:g} is longer than every capture (the longest "
                          f"lasts {max(durations.values()):g} s): no window would fit in any cell; use a window no "
                          "longer than the captures")
    if short:
        warnings.warn(f"{len(short)} cells are captured for less than one {config.window_s:g} s window and get no "
                      f"sample: {', '.join(short[:10])}{' ...' if len(short) > 10 else ''}", SurveyWarning,
                      stacklevel=3)


def _tracked_samples(sky, mask_deg: float) -> tuple[np.ndarray, np.ndarray]:
    with np.errstate(invalid="ignore"):
        ok = sky.in_view & np.isfinite(sky.cn0_dbhz) & (sky.el_deg >= mask_deg)
    return sky.el_deg[ok], sky.cn0_dbhz[ok]


def calibrate_cn0_reference(el_deg, cn0_dbhz, config: SurveyConfig = SurveyConfig(),
                            n_cells: int | None = None) -> tuple[Cn0Reference, dict, bool]:
    """The receiver's open-sky C/N0 reference by the module docstring's rule.

    el_deg, cn0_dbhz : (n,) tracked samples pooled over all cells of one receiver.
    Returns (reference, the JSON record stored with the receiver, calibrated).
    Falls back to the built-in default (calibrated False, with a
    :class:`SurveyWarning`) when the data cannot support a fit.
    """
    el = np.asarray(el_deg, dtype=float).ravel()
    cn0 = np.asarray(cn0_dbhz, dtype=float).ravel()
    mask, width = config.elevation_mask_deg, config.cn0_bin_width_deg
    rule = {"statistic": "quantile", "quantile": config.cn0_quantile, "bin_width_deg": width,
            "min_per_bin": config.cn0_min_per_bin, "elevation_mask_deg": mask,
            "fit": "count-weighted least squares of the bin values on mean sin(el)", "pooled_over": "all cells"}
    # The bin values fit_cn0_reference fits (same edges), kept so the record shows what the line rests on.
    edges = np.arange(mask, 90.0 + width, width)
    which = np.clip(np.digitize(el, edges) - 1, 0, len(edges) - 2)
    bins = []
    for b in range(len(edges) - 1):
        sel = which == b
        if sel.sum() >= config.cn0_min_per_bin:
            bins.append({"el_lo_deg": float(edges[b]), "el_hi_deg": float(min(edges[b + 1], 90.0)),
                         "n": int(sel.sum()), "mean_sin_el": float(np.sin(np.radians(el[sel])).mean()),
                         "cn0_dbhz": float(np.quantile(cn0[sel], config.cn0_quantile))})
    record = {"model": "C_ref(el) = intercept_dbhz + slope_dbhz * sin(el)", "rule": rule, "bins": bins,
              "n_samples": int(el.size), "n_cells": n_cells}
    try:
        ref = fit_cn0_reference(el, cn0, quantile=config.cn0_quantile, bin_width_deg=width,
                                min_per_bin=config.cn0_min_per_bin, elevation_mask_deg=mask)
        calibrated = True
    except (DataError, ConfigError) as exc:
        ref, calibrated = Cn0Reference(), False
        record["fallback_reason"] = str(exc)
        warnings.warn(f"C/N0 reference not calibrated ({exc}); the attenuation features use the built-in "
                      f"default ({ref.source}), which may be dB off for this receiver", SurveyWarning, stacklevel=2)
    record.update(ref.to_dict())
    record["calibrated"] = calibrated
    return ref, record, calibrated


def _calibrate(plans: list[_CellPlan], receiver: str, config: SurveyConfig):
    els, cn0s, n_cells = [], [], 0
    for plan in plans:
        p = plan.paths.get("gnss")
        if plan.receiver != receiver or p is None:
            continue
        try:
            epochs, _ = read_nmea(p)
        except DataError:
            continue  # recorded as unusable when the cell is ingested
        el, cn0 = _tracked_samples(sky_arrays(epochs), config.elevation_mask_deg)
        if el.size:
            els.append(el)
            cn0s.append(cn0)
            n_cells += 1
    el = np.concatenate(els) if els else np.zeros(0)
    cn0 = np.concatenate(cn0s) if cn0s else np.zeros(0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SurveyWarning)
        ref, record, ok = calibrate_cn0_reference(el, cn0, config, n_cells=n_cells)
    for w in caught:
        warnings.warn(f"receiver {receiver!r}: {w.message}", SurveyWarning, stacklevel=3)
    return ref, record, ok


def _gnss_table(plan: _CellPlan, reference: Cn0Reference, config: SurveyConfig):
    epochs, _ = read_nmea(plan.paths["gnss"])
    sky = sky_arrays(epochs_on_time_base(epochs, plan.walk.start_utc))
    if sky.n_epochs == 0:
        raise DataError("no satellites reported (no GSV)")
    cfg = GnssFeatureConfig(config.window_s, config.hop_s, config.elevation_mask_deg, config.fluct_threshold_dbhz)
    return gnss_features(sky, cfg, reference)


def _audio_rows(plan: _CellPlan, site, config: SurveyConfig) -> list[dict]:
    from features.acoustic.audio import audio_info, require_beacon_band
    from features.acoustic.detection import DetectorConfig
    from features.acoustic.positions import PositionConfig

    if not site.beacons:
        if audio_info(plan.paths["audio"]).n_frames == 0:
            raise DataError("holds no audio samples")
    else:
        require_beacon_band(plan.paths["audio"], min(b.f0_hz if b.f0_hz is not None else site.acoustic.f0_hz
                                                     for b in site.beacons))
    timing = timing_from_walk(plan.walk, site, where=plan.walk.directory / "cell.toml")
    # a survey capture is static: no walking-speed prior (as the CLI does for a cell.toml)
    positions = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05, motion_speed_m_s=0.0)
    result = analyse_audio(plan.paths["audio"], site, timing, DetectorConfig(p_fa=config.p_fa),
                           WindowConfig(config.window_s, config.hop_s), positions)
    return result.rows


def _merge(gnss: dict | None, audio: list[dict] | None, config: SurveyConfig, duration_s: float | None) -> dict:
    """Pair GNSS and acoustic windows by centre (within hop/2) into sample columns."""
    g_t = np.asarray(gnss["t_s"], dtype=float) if gnss is not None else np.zeros(0)
    a_t = np.array([r["t_s"] for r in audio], dtype=float) if audio else np.zeros(0)
    pair_of_g = np.full(g_t.size, -1)
    taken = np.zeros(a_t.size, dtype=bool)
    if a_t.size:
        for i, t in enumerate(g_t):
            j = int(np.argmin(np.abs(a_t - t)))
            if abs(a_t[j] - t) < 0.5 * config.hop_s and not taken[j]:
                pair_of_g[i], taken[j] = j, True
    entries = [(a_t[pair_of_g[i]] if pair_of_g[i] >= 0 else g_t[i], i, pair_of_g[i]) for i in range(g_t.size)]
    entries += [(a_t[j], -1, j) for j in np.flatnonzero(~taken)]
    half = 0.5 * config.window_s
    if duration_s is not None:
        entries = [e for e in entries if e[0] - half >= -1e-6 and e[0] + half <= duration_s + 1e-6]
    entries.sort(key=lambda e: e[0])
    cols: dict[str, list] = {k: [] for k in ("t_s", "gnss_available", "acoustic_available", "n_chirps", "n_beacons",
                                             "snr_db_mean", "acoustic_flags") + GNSS_FEATURES + ACOUSTIC_FEATURES
                             + GNSS_COUNTS}
    for t, i, j in entries:
        cols["t_s"].append(float(t))
        for k in GNSS_FEATURES:
            cols[k].append(float(gnss[k][i]) if i >= 0 else math.nan)
        for k in GNSS_COUNTS:
            cols[k].append(int(gnss[k][i]) if i >= 0 else 0)
        cols["gnss_available"].append(int(i >= 0 and gnss["n_pairs_in_view"][i] > 0
                                          and gnss["n_epochs"][i] >= MIN_GNSS_EPOCHS))
        row = audio[j] if j >= 0 else None
        for k in ACOUSTIC_FEATURES:
            cols[k].append(row[k] if row else math.nan)
        cols["acoustic_available"].append(int(row["acoustic_available"]) if row else 0)
        cols["n_chirps"].append(int(row["n_chirps"]) if row else 0)
        cols["n_beacons"].append(int(row["n_beacons"]) if row else 0)
        cols["snr_db_mean"].append(row["snr_db_mean"] if row else math.nan)
        cols["acoustic_flags"].append(row["flags"] if row else "no_audio" if audio is None else "no_window")
    return cols


class _Progress:
    """tqdm bar on a terminal; otherwise plain lines (at most about 100), never ``\\r`` frames in a log."""

    def __init__(self, total: int, enabled: bool, stream=None):
        self.stream = stream or sys.stderr
        self.total, self.done, self.enabled = total, 0, enabled
        self.every = max(1, math.ceil(total / 100))
        self.bar = None
        if enabled and hasattr(self.stream, "isatty") and self.stream.isatty():
            from tqdm import tqdm
            self.bar = tqdm(total=total, desc="survey cells", unit="cell", file=self.stream)

    def line(self, text: str) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.write(text, file=self.stream)
        else:
            print(text, file=self.stream, flush=True)

    def step(self, text: str) -> None:
        self.done += 1
        if self.bar is not None:
            self.bar.set_postfix_str(text, refresh=False)
            self.bar.update()
        elif self.enabled and (self.done % self.every == 0 or self.done == self.total):
            self.line(f"survey build: {self.done}/{self.total} cells ({text})")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def build_library(survey_dir: str | os.PathLike, library: str | os.PathLike, config: SurveyConfig = SurveyConfig(),
                  *, receiver: str = "default", replace: bool = False, progress: bool = True) -> BuildReport:
    """Compute the 14 features of every cell of ``survey_dir`` and store them in the library file ``library``.

    ``receiver``: name of the GNSS receiver for cells whose ``cell.toml`` names
    none. ``replace``: swap cells stored from another capture or computed with
    other feature parameters (default: refuse).
    Raises :class:`~features.errors.ConfigError` for a malformed survey and
    :class:`~fingerprints.library.LibraryError` for a library it cannot use;
    cells committed before an error (or a kill) stay, and a rerun resumes.
    """
    survey_dir = Path(survey_dir)
    site_file = survey_dir / "site.toml"
    if not site_file.is_file():
        raise ConfigError(f"{survey_dir}: not a survey directory (no site.toml)")
    site = load_site(site_file)
    site_sha = sha256_file(site_file)
    plans = [_plan_cell(d, receiver) for d in survey_cell_dirs(survey_dir)]
    ids = [p.capture.cell_id for p in plans]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise ConfigError(f"{survey_dir}: cell ids occur twice: {', '.join(dup)}")
    _check_window(plans, config, survey_dir)
    out = _Progress(len(plans), progress)
    counts = {"added": 0, "unchanged": 0, "replaced": 0}
    with FingerprintLibrary.open(library) as lib:
        lib.add_site(site.name, lat_deg=site.origin.lat_deg, lon_deg=site.origin.lon_deg, alt_m=site.origin.alt_m,
                     site_toml_sha256=site_sha)
        refs, calibrated = {}, {}
        for name in sorted({p.receiver for p in plans}):
            stored = lib.receiver(site.name, name)
            if stored is None:
                out.line(f"survey build: calibrating the C/N0 reference of receiver {name!r}")
                ref, record, ok = _calibrate(plans, name, config)
                lib.add_receiver(site.name, name, record, calibrated=ok)
                stored = lib.receiver(site.name, name)
            elif not stored.calibrated:
                stored = _recalibrate(lib, site.name, plans, name, config, replace, out) or stored
            refs[name], calibrated[name] = stored.reference, stored.calibrated
        try:
            for plan in plans:
                cap = plan.capture
                params = _feature_params(config, plan.receiver, refs[plan.receiver])
                if lib.has_capture(site.name, cap.cell_id, cap.capture_sha256, params):
                    counts["unchanged"] += 1
                    out.step(f"{cap.cell_id} already stored")
                    continue
                result = _ingest(lib, site, plan, refs[plan.receiver], config, replace)
                counts[result.status] += 1
                out.step(f"{cap.cell_id} {result.status}, {result.n_samples} windows")
        finally:
            out.close()
        cells = [c for c in lib.cells(site.name) if c["cell_id"] in set(ids)]
    n_samples = int(sum(int(c["n_samples"]) for c in cells))
    # as stored, so a resumed build reports the streams found unusable in an earlier run too
    missing = {str(c["cell_id"]): tuple(str(c["missing_streams"]).split("+")) for c in cells if c["missing_streams"]}
    empty = tuple(str(c["cell_id"]) for c in cells if int(c["n_samples"]) == 0)
    return BuildReport(site.name, len(plans), counts["added"], counts["unchanged"], counts["replaced"], n_samples,
                       missing, calibrated, empty)


def _recalibrate(lib: FingerprintLibrary, site: str, plans: list, name: str, config: SurveyConfig, replace: bool,
                 out) -> object | None:
    """A receiver stored with the uncalibrated default: calibrate it again from this survey's data. When that
    now succeeds, store the calibrated reference with ``replace`` (its cells are then recomputed: their
    feature parameters name the old reference) and return the new record; without ``replace`` say how."""
    out.line(f"survey build: receiver {name!r} is stored uncalibrated; trying to calibrate it from this survey")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SurveyWarning)
        ref, record, ok = _calibrate(plans, name, config)
    if not ok:
        warnings.warn(f"receiver {name!r}: stored with the uncalibrated default C/N0 reference, and this survey "
                      "still cannot calibrate it", SurveyWarning, stacklevel=3)
        return None
    if not replace:
        warnings.warn(f"receiver {name!r}: stored with the uncalibrated default C/N0 reference, which this "
                      f"survey can now calibrate ({ref.intercept_dbhz:.1f} + {ref.slope_dbhz:.1f}·sin(el) dB-Hz); "
                      "pass --replace to store it and recompute the receiver's cells", SurveyWarning, stacklevel=3)
        return None
    lib.recalibrate_receiver(site, name, record)
    out.line(f"survey build: receiver {name!r} calibrated; its cells are recomputed")
    return lib.receiver(site, name)


def _feature_params(config: SurveyConfig, receiver: str, reference: Cn0Reference) -> dict:
    """What a cell's features were computed with (stored per cell; a change makes the cell stale)."""
    return {"window_s": config.window_s, "hop_s": config.hop_s, "elevation_mask_deg": config.elevation_mask_deg,
            "fluct_threshold_dbhz": config.fluct_threshold_dbhz, "p_fa": config.p_fa, "receiver": receiver,
            "cn0_reference": reference.to_dict()}


def _ingest(lib: FingerprintLibrary, site, plan: _CellPlan, reference: Cn0Reference, config: SurveyConfig,
            replace: bool):
    cap = plan.capture
    notes = [cap.stream_notes] if cap.stream_notes else []
    unusable = []
    gnss = audio = None
    if "gnss" in plan.paths:
        try:
            gnss = _gnss_table(plan, reference, config)
        except DataError as exc:
            unusable.append("gnss")
            notes.append(f"gnss: {plan.paths['gnss'].name} unusable: {exc}")
    if "audio" in plan.paths:
        try:
            audio = _audio_rows(plan, site, config)
        except DataError as exc:
            unusable.append("audio")
            notes.append(f"audio: {plan.paths['audio'].name} unusable: {exc}")
    rows = _merge(gnss, audio, config, cap.duration_s)
    if gnss is not None and not any(rows["gnss_available"]):
        # e.g. an NMEA file of one epoch: read, but no window of it can be used; as unusable as no file
        unusable.append("gnss")
        notes.append(f"gnss: {plan.paths['gnss'].name} gives no complete {config.window_s:g} s window with "
                     "satellites in view inside the capture")
        rows = _merge(None, audio, config, cap.duration_s)
    missing = tuple(s for s in _DEFAULT_FILES if s in cap.missing_streams or s in unusable)
    params = _feature_params(config, plan.receiver, reference)
    cap = CellCapture(cap.cell_id, cap.east_m, cap.north_m, cap.start_utc, cap.duration_s, cap.map_label,
                      cap.map_share, missing, "; ".join(notes), cap.gnss_sha256, cap.audio_sha256, params)
    if missing:
        warnings.warn(f"cell {cap.cell_id}: stream{'s' if len(missing) > 1 else ''} {' and '.join(missing)} "
                      f"missing ({cap.stream_notes}); recorded as missing", SurveyWarning, stacklevel=3)
    return lib.ingest_cell(site.name, cap, rows, receiver=plan.receiver, replace=replace)
