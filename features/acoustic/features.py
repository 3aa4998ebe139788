"""Acoustic feature windows and positions from one recording, in one streaming pass.

Each analysis window (default 2 s, hop 1 s, docs/design.md §5) reports the nine
CIR features of :mod:`features.acoustic.cir` averaged over the beacon chirps whose first
arrival falls inside it (NaN-aware mean: a statistic undefined for one chirp
does not void the others), the counts behind them, and flags:

* ``no_chirp`` — no chirp detected; the nine features are empty (NaN) and
  ``acoustic_available`` is 0;
* ``clipped`` — more than :data:`CLIP_FRACTION_FLAG` of its samples at full scale;
* ``silent`` — RMS below :data:`SILENCE_RMS` of full scale (a dead microphone);
* ``truncated`` — the file's data ends before its header says and this is the last window;
* ``partial`` — the recording ends inside the window.

Flags join with ``+`` in one column. Positions come per TDMA frame from
:mod:`features.acoustic.positions`.

Windows lie on the walk's time base (``t_s`` the window centre, the same grid
whatever the clock); a chirp goes to the window of its true arrival time, its
stated arrival less the receiver clock offset of the latest fix (before the
first fix: none). The stated audio start is off by up to its uncertainty
(tens of ms), which otherwise moved the chirps near a window edge into the
wrong window (issue 11).

Memory: detections are folded into per-hop accumulators and per-frame groups
as they stream past; nothing grows with the file but a few numbers per second.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass

import numpy as np

from features.acoustic.positions import AcousticFix, PositionConfig
from features.acoustic.detection import AudioStats, AudioTiming, DetectorConfig, detect_frames
from features.acoustic.cir import FEATURE_NAMES
from features.errors import ConfigError
from features.site import Site

__all__ = ["WindowConfig", "AudioAnalysis", "analyse_audio", "FEATURE_COLUMNS", "CLIP_FRACTION_FLAG",
           "SILENCE_RMS"]

CLIP_FRACTION_FLAG = 1e-3
"""A window is flagged ``clipped`` above this fraction of full-scale samples."""

SILENCE_RMS = 1e-6
"""A window is flagged ``silent`` below this RMS (full scale = 1; int16 LSB ≈ 3e-5)."""

FEATURE_COLUMNS = ("t_s",) + FEATURE_NAMES + ("n_chirps", "n_beacons", "snr_db_mean", "clipped_fraction",
                                              "acoustic_available", "flags")
"""Columns of an acoustic feature table, one row per analysis window."""


@dataclass(frozen=True)
class WindowConfig:
    """Analysis windows: ``window_s`` long every ``hop_s`` (window a whole multiple of hop)."""

    window_s: float = 2.0
    hop_s: float = 1.0

    def __post_init__(self):
        if not (self.hop_s > 0 and self.window_s > 0):
            raise ConfigError(f"window_s and hop_s must be positive, got {self.window_s}, {self.hop_s}")
        ratio = self.window_s / self.hop_s
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(f"window_s ({self.window_s}) must be a whole multiple of hop_s ({self.hop_s})")

    @property
    def hops_per_window(self) -> int:
        return int(round(self.window_s / self.hop_s))


class _HopBins:
    """Per-hop sums of the features of the chirps arriving in it.

    Chirps are queued by :meth:`add` and folded in by :meth:`flush`, a few hundred
    at a time with :func:`numpy.add.at` (NaN and inf features skipped): a handful of
    numpy calls per batch instead of several per chirp.
    """

    _FLUSH_AT = 512

    def __init__(self):
        n = len(FEATURE_NAMES)
        self.sums = np.zeros((0, n))
        self.counts = np.zeros((0, n))
        self.n_chirps = np.zeros(0, dtype=int)
        self.snr_sum = np.zeros(0)
        self.beacons: list[set] = []
        self._queue: tuple[list, list, list, list] = ([], [], [], [])

    def add(self, k: int, values, snr_db: float, beacon_id: int) -> None:
        """Queue one chirp's nine features (a sequence of floats) for hop ``k``."""
        hops, feats, snrs, ids = self._queue
        hops.append(k)
        feats.append(values)
        snrs.append(snr_db)
        ids.append(beacon_id)
        if len(hops) >= self._FLUSH_AT:
            self.flush()

    def flush(self) -> None:
        """Fold the queued chirps into the per-hop sums."""
        ks, values, snrs, ids = self._queue
        if not ks:
            return
        hops = np.array(ks)
        need = int(hops.max()) + 1
        if need > len(self.sums):
            grow = need - len(self.sums)
            self.sums = np.concatenate([self.sums, np.zeros((grow, self.sums.shape[1]))])
            self.counts = np.concatenate([self.counts, np.zeros((grow, self.counts.shape[1]))])
            self.n_chirps = np.concatenate([self.n_chirps, np.zeros(grow, dtype=int)])
            self.snr_sum = np.concatenate([self.snr_sum, np.zeros(grow)])
            self.beacons.extend(set() for _ in range(grow))
        f = np.array(values, dtype=float)
        ok = np.isfinite(f)
        np.add.at(self.sums, hops, np.where(ok, f, 0.0))
        np.add.at(self.counts, hops, ok)
        np.add.at(self.n_chirps, hops, 1)
        np.add.at(self.snr_sum, hops, np.array(snrs, dtype=float))
        for k, b in zip(ks, ids):
            self.beacons[k].add(b)
        self._queue = ([], [], [], [])


@dataclass(frozen=True)
class AudioAnalysis:
    """Result of :func:`analyse_audio`: feature rows (dicts keyed by FEATURE_COLUMNS) and fixes."""

    rows: list
    fixes: list
    n_detections: int
    duration_s: float
    truncated: bool
    frames: list | None = None
    receiver_state: object = None
    """The receiver's state kept for a later cut of the recording (``keep_state_from_s``), else None."""


def analyse_audio(path: str | os.PathLike, site: Site, timing: AudioTiming,
                  detector: DetectorConfig = DetectorConfig(), windows: WindowConfig = WindowConfig(),
                  positions: PositionConfig | None = None, keep_frames: bool = False, resume=None,
                  keep_state_from_s: float = math.inf, first_sample: int = 0) -> AudioAnalysis:
    """Stream ``path`` once: feature windows and per-frame acoustic positions.

    ``positions``: solver settings (default: see :func:`features.acoustic.detection.detect_frames`).
    ``keep_frames`` also returns every :class:`~features.acoustic.detection.FrameResult`
    (for evaluation; memory then grows with the file). ``resume``, ``keep_state_from_s``: a recording read in
    cuts (:func:`~features.acoustic.detection.detect_frames`); the state kept is the result's ``receiver_state``.
    ``first_sample``: the file is a cut of a longer recording starting at that sample of it, and ``timing`` the
    whole recording's (:func:`~features.acoustic.detection.detect_frames`); the feature windows start at the
    cut's first sample.
    """
    stats = AudioStats(bin_s=0.1, n_samples=[], n_clipped=[], sum_sq=[])
    bins = _HopBins()
    fixes: list[AcousticFix] = []
    n_det = 0
    kept = [] if keep_frames else None
    clock_s = 0.0          # the receiver clock offset (stated − true) of the latest fix: chirps go to windows by true time
    receiver_state = None
    first_s = timing.start_s + first_sample / detector.fs_hz      # the file's first sample
    for frame in detect_frames(path, site, timing, detector, stats, positions, resume, keep_state_from_s,
                               first_sample):
        if resume is not None and frame.frame == resume.frame:
            clock_s = resume.window_clock_s       # the whole recording's, not this cut's warm-up fixes'
        if frame.receiver_state is not None:
            receiver_state = dataclasses.replace(frame.receiver_state, window_clock_s=clock_s)
        if kept is not None:
            kept.append(frame)
        if frame.fix is not None:
            clock_s = frame.fix.clock_offset_s
        for det in frame.detections:
            n_det += 1
            k = math.floor((det.arrival_s - clock_s - first_s) / windows.hop_s)
            if k >= 0:
                bins.add(k, det.features, det.snr_db, det.beacon_id)
        if frame.fix is not None:
            fixes.append(frame.fix)
    bins.flush()
    rows = _window_rows(bins, stats, first_s, windows)
    return AudioAnalysis(rows, fixes, n_det, stats.duration_s, stats.truncated, kept, receiver_state)


def _window_rows(bins: _HopBins, stats: AudioStats, first_s: float, cfg: WindowConfig) -> list[dict]:
    duration = stats.duration_s
    if duration <= 0:
        return []
    m = cfg.hops_per_window
    n_windows = max(1, math.floor((duration - cfg.window_s) / cfg.hop_s + 1e-9) + 1)
    per_stat_bin = cfg.hop_s / stats.bin_s
    n_samples = np.asarray(stats.n_samples, dtype=float)
    n_clipped = np.asarray(stats.n_clipped, dtype=float)
    sum_sq = np.asarray(stats.sum_sq, dtype=float)
    rows = []
    for w in range(n_windows):
        sums = np.zeros(len(FEATURE_NAMES))
        counts = np.zeros(len(FEATURE_NAMES))
        n_chirps, snr_sum, beacons = 0, 0.0, set()
        for k in range(w, w + m):
            if k < len(bins.sums):
                sums += bins.sums[k]
                counts += bins.counts[k]
                n_chirps += int(bins.n_chirps[k])
                snr_sum += float(bins.snr_sum[k])
                beacons |= bins.beacons[k]
        with np.errstate(invalid="ignore", divide="ignore"):
            means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        a = int(round(w * per_stat_bin))
        b = int(round((w + m) * per_stat_bin))
        ns = float(n_samples[a:b].sum())
        clipped_fraction = float(n_clipped[a:b].sum()) / ns if ns else 0.0
        rms = math.sqrt(float(sum_sq[a:b].sum()) / ns) if ns else 0.0
        flags = []
        if n_chirps == 0:
            flags.append("no_chirp")
        if clipped_fraction > CLIP_FRACTION_FLAG:
            flags.append("clipped")
        if rms < SILENCE_RMS:
            flags.append("silent")
        if w * cfg.hop_s + cfg.window_s > duration + 1e-9:
            flags.append("partial")
        if stats.truncated and w == n_windows - 1:
            flags.append("truncated")
        row = {"t_s": first_s + w * cfg.hop_s + cfg.window_s / 2}
        row.update({name: (float(v) if n_chirps else float("nan")) for name, v in zip(FEATURE_NAMES, means)})
        row.update({"n_chirps": n_chirps, "n_beacons": len(beacons),
                    "snr_db_mean": snr_sum / n_chirps if n_chirps else float("nan"),
                    "clipped_fraction": clipped_fraction, "acoustic_available": int(n_chirps > 0),
                    "flags": "+".join(flags)})
        rows.append(row)
    return rows
