"""The RTS smoother over a whole long walk fused in segments, in memory bounded by one segment.

A long walk is filtered segment by segment (:mod:`walks.segments`), each segment's filters resuming where the
previous one's stopped, so the forward runs' owned events are the whole walk's filter run (to the resumption's
round-off, ~1e-7 m). Smoothing each cut alone, as the segments did before, leaves out every fix after the
cut's end: up to 1.8 m from the whole walk's ``+rts`` track at the seams of a 21-minute walk (``aekf+rts``, seed 78
in :mod:`walks.segments`), where near-constant states (the heading offset, the step scale, the GNSS bias) carry
later fixes' evidence back over the whole walk.

:class:`SegmentedRts` runs the one backward pass instead. Each segment's owned events of the filter run (x, P,
the priors x⁻, P⁻ and the Jacobian F; Rauch, Tung & Striebel 1965, AIAA J. 3(8); Särkkä 2013, *Bayesian Filtering
and Smoothing*, ch. 9) are written to a file as the segment is fused (:meth:`~SegmentedRts.add`); then
:meth:`~SegmentedRts.smooth` runs the recursion (:func:`models.fusion.core.rts_pass`) from the walk's last event
back to its first, a segment at a time, each one's last event taking its gain C_k = P_k F'_{k+1} (P⁻_{k+1})⁻¹
from the next segment's first event and its smoothed state from that event's, and replaces each file's filter
states by the smoothed position and covariance; :meth:`~SegmentedRts.segments` reads them back in time order.
Given the forward runs, the result is the RTS smoother over their concatenation to the bit (the same gains, the
same steps in the same order): ``tests/test_segment_rts.py``. A calibrated track's covariance is scaled after the
pass, by the calibrator at the inputs each segment stored, their covariance column computed from the smoothed
covariance (:func:`smoothed_covariance`).

What it costs: one file per segment in a temporary folder (beside the output for ``run``), (3n² + 2n + 1)
float64 per event for n filter states, and the caller's per-event columns; memory holds one segment's arrays.
Measured on a 600 s walk (6.7 events a second): n = 4 for ``kf_quality``, ``aekf``, ``imm`` (456 B an event,
88 MB for an 8-hour walk), n = 6 for the ``adaptive`` family (968 B, 188 MB), n = 2 for the UWB/PDR filters
(9.2 events a second, 36 MB); ``run``'s rows add ~0.2 KB an event (the UTC time and class as text). ``envfuse run
--method adaptive_blind+rts`` on an 8-hour walk (``bench/bench_pipeline.py --memory-only --method
adaptive_blind+rts``, 2026-12-03): the temporary files peaked at 290 MiB, the process at 283 MiB (278 MiB on the
10-minute walk: 1.016), 157 s wall (184× real time).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models.fusion.calibration import with_covariance
from models.fusion.core import rts_pass
from models.fusion.ekf import FilterRun
from models.fusion.smoother import smoother_gains
from walks.calibrate import CALIBRATED, track_inputs
from walks.track import POSITION_COLUMNS, TRACK_COLUMNS, position_columns, rows_from_columns, track_columns

__all__ = ["SegmentedRts", "add_rts_track", "smoothed_covariance", "rts_rows"]

_STATES = ("t_s", "x", "P", "x_prior", "P_prior", "F")
"""The filter run's per-event arrays the backward pass reads."""


@dataclass(frozen=True)
class _Events:
    """A piece of a filter run as :func:`models.fusion.smoother.smoother_gains` reads it."""

    x: np.ndarray
    P: np.ndarray
    x_prior: np.ndarray
    P_prior: np.ndarray
    F: np.ndarray


class SegmentedRts:
    """The RTS smoother of one filter over a walk fused in segments (module docstring).

    Use as a context manager: the temporary folder (in ``workdir``, e.g. the output's folder) and its files are
    removed on leaving, whatever happened. :meth:`add` each segment's run in time order, :meth:`smooth` once,
    then :meth:`segments`.
    """

    def __init__(self, workdir: str | os.PathLike | None = None):
        self._dir = Path(tempfile.mkdtemp(prefix=".envfuse-rts.", dir=workdir))
        self._files: list[Path] = []
        self._smoothed = False
        self._last_t = -np.inf

    def __enter__(self) -> "SegmentedRts":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Remove the temporary folder (also done on leaving the ``with`` block)."""
        shutil.rmtree(self._dir, ignore_errors=True)

    def __len__(self) -> int:
        return len(self._files)

    def add(self, run, keep: np.ndarray, extras: dict | None = None) -> None:
        """Store the events of ``run`` (a :class:`~models.fusion.ekf.FilterRun`, or any object with its arrays)
        where ``keep`` (bool, (m,)) holds — a segment's owned events, after every event stored before —, with
        ``extras``: per-event arrays of the caller (already cut to the kept events) handed back by
        :meth:`segments`. A segment without an event adds nothing."""
        if self._smoothed:
            raise RuntimeError("SegmentedRts.add after smooth")
        keep = np.asarray(keep, bool)
        if not keep.any():
            return
        arrays = {k: np.ascontiguousarray(np.asarray(getattr(run, k))[keep], dtype=float) for k in _STATES}
        t = arrays["t_s"]
        if not (np.all(np.diff(t) >= 0) and t[0] >= self._last_t):
            raise ValueError("SegmentedRts.add: events must come in time order across segments")
        if self._files and arrays["x"].shape[1] != self._n:
            raise ValueError(f"SegmentedRts.add: {arrays['x'].shape[1]} states, earlier segments had {self._n}")
        self._n = arrays["x"].shape[1]
        self._last_t = float(t[-1])
        for k, v in (extras or {}).items():
            v = np.asarray(v)
            if v.shape[:1] != t.shape or k in _STATES or k.startswith("_") or v.dtype == object:
                raise ValueError(f"SegmentedRts.add: extra {k!r} must be a new name with one row per kept event, "
                                 "of numbers, booleans or text (the files are read without pickle)")
            arrays[f"extra_{k}"] = v
        self._files.append(self._save(len(self._files), arrays))

    def _save(self, i: int, arrays: dict) -> Path:
        path = self._dir / f"segment{i:06d}.npz"
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
        return path

    def smooth(self) -> None:
        """The backward pass over every stored event, the walk's last first (module docstring); each file then
        holds the smoothed position ``east_m``, ``north_m`` and its covariance ``cov_m2`` (k, 2, 2) instead of
        the filter states."""
        if self._smoothed:
            raise RuntimeError("SegmentedRts.smooth called twice")
        nxt = None          # the next segment's first event: its smoothed x, P and its x⁻, P⁻, F
        for i in range(len(self._files) - 1, -1, -1):
            with np.load(self._files[i], allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            ev = [arrays[name] for name in ("x", "P", "x_prior", "P_prior", "F")]
            m = ev[0].shape[0]
            if nxt is not None:
                # the next segment's first event ends this piece: its smoothed state is the recursion's start
                # (rts_pass leaves the last row as given) and its prior and Jacobian give this piece's last gain
                ev = [np.concatenate([a, b[None]]) for a, b in zip(ev, nxt)]
            if len(ev[0]) > 1:
                xs, Ps = rts_pass(*ev[:4], smoother_gains(_Events(*ev)))
            else:
                xs, Ps = ev[0].copy(), ev[1].copy()
            xs, Ps = xs[:m], Ps[:m]
            nxt = (xs[0], Ps[0], arrays["x_prior"][0], arrays["P_prior"][0], arrays["F"][0])
            out = {name: v for name, v in arrays.items() if name.startswith("extra_")}
            out.update(t_s=arrays["t_s"], east_m=xs[:, 0].copy(), north_m=xs[:, 1].copy(),
                       cov_m2=Ps[:, :2, :2].copy())
            self._save(i, out)
        self._smoothed = True

    def segments(self):
        """Yield each stored segment's smoothed events in time order, as a dict: ``t_s``, ``east_m``,
        ``north_m`` (k,), ``cov_m2`` (k, 2, 2) and the caller's extras by name."""
        if not self._smoothed:
            raise RuntimeError("SegmentedRts.segments before smooth")
        for path in self._files:
            with np.load(path, allow_pickle=False) as z:
                yield {k.removeprefix("extra_"): z[k] for k in z.files}


# -- a +rts track written by ``envfuse run`` ------------------------------------------------------------------------

_ROW_COLUMNS = tuple(c for c in TRACK_COLUMNS if c != "t_s" and c not in POSITION_COLUMNS)
"""The columns of a track row besides ``t_s`` and :data:`walks.track.POSITION_COLUMNS`."""


def add_rts_track(store: SegmentedRts, fused, name: str, keep: np.ndarray, rows: bool = True,
                  extras: dict | None = None) -> bool:
    """Store in ``store`` the events of the filter run behind ``name`` (``<filter>+rts``) of a segment's
    ``fused`` walk (:class:`walks.fuse.FusedWalk`) where ``keep`` holds (the events the segment owns), with what
    the smoothed track needs besides the position: when the model calibrates that track's covariance, the
    calibrator's inputs (:func:`smoothed_covariance`); with ``rows``, the other columns of the cut's own ``+rts``
    track (:func:`rts_rows`); the caller's ``extras`` (per kept event). False (nothing stored) when the method's
    result is not a filter run, or not one that resumes across seams (a cut of ``ekf_rtk_pdr`` starts afresh:
    the cuts' runs are not one run, and each keeps its own smoother)."""
    from walks.fuse import RESUMED_METHODS       # walks.fuse imports this module

    base = name.removesuffix("+rts")
    if base not in RESUMED_METHODS:
        return False
    run = fused.results.get(base)
    track = fused.tracks.get(name)
    if not isinstance(run, FilterRun) or track is None:
        return False
    if not np.array_equal(track.t_s, run.t_s):
        raise ValueError(f"{name}: the track's epochs are not its filter run's events")
    keep = np.asarray(keep, bool)
    if not keep.any():
        return True
    out = dict(extras or {})
    if rows:
        columns = track_columns(track.take(keep), fused.inputs)
        out.update((f"row_{c}", np.asarray(columns[c])) for c in _ROW_COLUMNS)
    if "cov_scale" in track.info:
        resumed = (fused.inputs.resume or {}).get(base)
        out["calibration_x"] = track_inputs(track, run, fused.inputs, CALIBRATED.get(base, False), resumed)[keep]
    store.add(run, keep, out)
    return True


def smoothed_covariance(part: dict, calibrator) -> np.ndarray:
    """The covariance (k, 2, 2) of one segment of :meth:`SegmentedRts.segments` stored by :func:`add_rts_track`:
    the smoother's, times the ``calibrator``'s scale at it (a
    :class:`~models.fusion.calibration.CovarianceCalibrator`) when the segment stored the calibrator's inputs."""
    cov = part["cov_m2"]
    if "calibration_x" in part:
        cov = cov * calibrator.scale(with_covariance(part["calibration_x"], cov))[:, None, None]
    return cov


def rts_rows(part: dict, calibrator, origin) -> list[dict]:
    """Track rows (:data:`walks.track.TRACK_COLUMNS`) of one segment of :meth:`SegmentedRts.segments` stored by
    :func:`add_rts_track`: the smoothed position, its covariance times the ``calibrator``'s scale at it (a
    :class:`~models.fusion.calibration.CovarianceCalibrator`, used when the segment stored its inputs), WGS-84
    at the site ``origin``, and the cut's other columns."""
    columns = {c: part[f"row_{c}"] for c in _ROW_COLUMNS}
    columns.update(position_columns(part["east_m"], part["north_m"], smoothed_covariance(part, calibrator), origin),
                   t_s=part["t_s"])
    return rows_from_columns(columns)
