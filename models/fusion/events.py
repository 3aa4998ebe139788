"""Event streams for the event-driven filter: PDR steps, GNSS fixes, acoustic fixes, standing intervals.

The pipeline fills one frozen dataclass of columns per source from the readers
(every array of shape (n,) unless stated; SI units, walk time in seconds, site
ENU metres, heading from north, clockwise) and merges them with
:func:`merge_events` into one time-ordered :class:`EventStream`. The filter
walks that stream once: a step predicts, a fix updates, and the time between
events feeds a stationary random-walk model, so sources of any rate fuse
without resampling (docs/design.md §7).

Ties in time are broken by kind — step, then GNSS, then acoustic — and then by
the order within each source, so a merge is deterministic.

>>> import numpy as np
>>> steps = StepEvents(np.array([0.5, 1.0]), np.array([0.7, 0.7]), np.array([0.0, 0.1]))
>>> gnss = GnssEvents.from_sigma(np.array([1.0]), np.array([0.0]), np.array([1.4]), np.array([1.5]))
>>> ev = merge_events(steps=steps, gnss=gnss)
>>> ev.kind.tolist(), ev.index.tolist()
([0, 0, 1], [0, 1, 0])
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from features.errors import DataError

__all__ = ["STEP", "GNSS", "ACOUSTIC", "KIND_NAMES", "StepEvents", "GnssEvents", "AcousticEvents",
           "StandIntervals", "ClassTrack", "ClassMap", "EventStream", "merge_events", "EventError"]

STEP, GNSS, ACOUSTIC = 0, 1, 2
"""Event kind codes of :attr:`EventStream.kind`."""

KIND_NAMES = ("step", "gnss", "acoustic")
"""Names of the kind codes, by code."""


class EventError(DataError):
    """An event array has the wrong shape, is not finite where it must be, or is out of time order."""


def _col(name: str, a, n: int | None = None, dtype=float) -> np.ndarray:
    a = np.asarray(a, dtype=dtype)
    if a.ndim != 1:
        raise EventError(f"{name} must be 1-D, got shape {a.shape}")
    if n is not None and a.shape[0] != n:
        raise EventError(f"{name} must have length {n}, got {a.shape[0]}")
    return a


def _finite(name: str, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        raise EventError(f"{name} must be finite, got {int(np.sum(~np.isfinite(a)))} non-finite value(s)")


def _iso_cov(sigma_m) -> np.ndarray:
    """(n, 2, 2) covariances σ²·I from one σ per fix, ``sigma_m`` of shape (n,)."""
    s = np.asarray(sigma_m, float)
    cov = np.zeros((s.shape[0], 2, 2))
    cov[:, 0, 0] = cov[:, 1, 1] = s * s
    return cov


def _cov(name: str, cov, n: int) -> np.ndarray:
    c = np.asarray(cov, dtype=float)
    if c.shape != (n, 2, 2):
        raise EventError(f"{name} must have shape ({n}, 2, 2), got {c.shape}")
    return c


@dataclass(frozen=True)
class StepEvents:
    """PDR steps: heel-strike time ``t_s``, ``step_length_m``, ``heading_rad`` (0 = north, clockwise).

    Steps without a heading (NaN) are kept by the readers but dropped here: the
    filter cannot move the walker without a direction.

    ``sigma_length_m``, ``sigma_heading_rad`` (n,), optional: each step's own noise (σ of its length and
    of the white part of its heading), when the source states it (a vehicle's odometry from its
    variances); None: the filter's configured per-step σ (:class:`~models.fusion.ekf.EkfConfig`).
    """

    t_s: np.ndarray
    step_length_m: np.ndarray
    heading_rad: np.ndarray
    sigma_length_m: np.ndarray | None = None
    sigma_heading_rad: np.ndarray | None = None

    def __post_init__(self):
        t = _col("steps.t_s", self.t_s)
        n = t.shape[0]
        length = _col("steps.step_length_m", self.step_length_m, n)
        heading = _col("steps.heading_rad", self.heading_rad, n)
        keep = np.isfinite(t) & np.isfinite(length) & np.isfinite(heading)
        if np.any(length[keep] < 0):
            raise EventError("steps.step_length_m must be >= 0")
        for name in ("sigma_length_m", "sigma_heading_rad"):
            v = getattr(self, name)
            if v is not None:
                v = _col(f"steps.{name}", v, n)
                if not np.all(np.isfinite(v[keep]) & (v[keep] >= 0)):
                    raise EventError(f"steps.{name} must be finite and >= 0")
                object.__setattr__(self, name, v[keep])
        object.__setattr__(self, "t_s", t[keep])
        object.__setattr__(self, "step_length_m", length[keep])
        object.__setattr__(self, "heading_rad", heading[keep])

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class GnssEvents:
    """GNSS fixes on the site frame.

    ``cov_m2`` : (n, 2, 2) east/north covariance the receiver model assigns
    (e.g. UERE·HDOP/√2 per axis, :mod:`features.gnss.positions`);
    ``quality`` : (n,) GGA fix quality; ``hdop`` : (n,) (NaN when unknown);
    ``gst_sigma_m`` : (n, 2) GST σ east, north (NaN when the receiver sends no GST);
    ``available`` : (n,) bool, False rows are carried (for the availability
    flags a corrector takes) but never update the filter.
    """

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    cov_m2: np.ndarray
    quality: np.ndarray = None
    hdop: np.ndarray = None
    gst_sigma_m: np.ndarray = None
    available: np.ndarray = None

    def __post_init__(self):
        t = _col("gnss.t_s", self.t_s)
        n = t.shape[0]
        _finite("gnss.t_s", t)
        east = _col("gnss.east_m", self.east_m, n)
        north = _col("gnss.north_m", self.north_m, n)
        cov = _cov("gnss.cov_m2", self.cov_m2, n)
        quality = np.ones(n, int) if self.quality is None else _col("gnss.quality", self.quality, n, int)
        hdop = np.full(n, np.nan) if self.hdop is None else _col("gnss.hdop", self.hdop, n)
        gst = np.full((n, 2), np.nan) if self.gst_sigma_m is None else np.asarray(self.gst_sigma_m, float)
        if gst.shape != (n, 2):
            raise EventError(f"gnss.gst_sigma_m must have shape ({n}, 2), got {gst.shape}")
        avail = np.ones(n, bool) if self.available is None else _col("gnss.available", self.available, n, bool)
        avail = avail & np.isfinite(east) & np.isfinite(north) & np.all(np.isfinite(cov), axis=(1, 2))
        for k, v in (("t_s", t), ("east_m", east), ("north_m", north), ("cov_m2", cov), ("quality", quality),
                     ("hdop", hdop), ("gst_sigma_m", gst), ("available", avail)):
            object.__setattr__(self, k, v)

    @classmethod
    def from_sigma(cls, t_s, east_m, north_m, sigma_m, **kw) -> "GnssEvents":
        """Fixes with one σ per axis (east and north alike), ``sigma_m`` of shape (n,)."""
        return cls(t_s, east_m, north_m, _iso_cov(sigma_m), **kw)

    @classmethod
    def from_positions(cls, positions, gst_sigma_m=None, available=None) -> "GnssEvents":
        """From the reader's :class:`features.gnss.positions.GnssPositions` (its ``sigma_en_m`` as the
        reported covariance; HDOP the reader only assumed becomes NaN, so a quality policy applies its own
        assumption)."""
        hdop = np.where(np.asarray(positions.hdop_assumed, bool), np.nan, np.asarray(positions.hdop, float))
        return cls.from_sigma(positions.t_s, positions.east_m, positions.north_m, positions.sigma_en_m,
                              quality=positions.quality, hdop=hdop, gst_sigma_m=gst_sigma_m, available=available)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class AcousticEvents:
    """Acoustic fixes: ``t_s``, ``east_m``, ``north_m`` and the solver's (n, 2, 2) ``cov_m2``
    (var_east, cov_en, var_north of the positions CSV)."""

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    cov_m2: np.ndarray
    available: np.ndarray = None

    def __post_init__(self):
        t = _col("acoustic.t_s", self.t_s)
        n = t.shape[0]
        _finite("acoustic.t_s", t)
        east = _col("acoustic.east_m", self.east_m, n)
        north = _col("acoustic.north_m", self.north_m, n)
        cov = _cov("acoustic.cov_m2", self.cov_m2, n)
        avail = np.ones(n, bool) if self.available is None else _col("acoustic.available", self.available, n, bool)
        avail = avail & np.isfinite(east) & np.isfinite(north) & np.all(np.isfinite(cov), axis=(1, 2))
        for k, v in (("t_s", t), ("east_m", east), ("north_m", north), ("cov_m2", cov), ("available", avail)):
            object.__setattr__(self, k, v)

    @classmethod
    def from_sigma(cls, t_s, east_m, north_m, sigma_m, **kw) -> "AcousticEvents":
        """Fixes with one σ per axis, ``sigma_m`` of shape (n,)."""
        return cls(t_s, east_m, north_m, _iso_cov(sigma_m), **kw)

    @classmethod
    def from_columns(cls, t_s, east_m, north_m, var_east_m2, cov_en_m2, var_north_m2, **kw) -> "AcousticEvents":
        """From the columns of an acoustic positions CSV (:data:`features.acoustic.positions.POSITION_COLUMNS`).

        >>> a = AcousticEvents.from_columns([1.0], [2.0], [3.0], [0.04], [0.01], [0.09])
        >>> a.cov_m2[0].tolist()
        [[0.04, 0.01], [0.01, 0.09]]
        """
        ve, c, vn = (np.asarray(v, float) for v in (var_east_m2, cov_en_m2, var_north_m2))
        cov = np.stack([np.stack([ve, c], axis=-1), np.stack([c, vn], axis=-1)], axis=-2)
        return cls(t_s, east_m, north_m, cov, **kw)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


@dataclass(frozen=True)
class StandIntervals:
    """Intervals ``[start_s, end_s)`` in which the walker stands still (zero-velocity detector)."""

    start_s: np.ndarray
    end_s: np.ndarray

    def __post_init__(self):
        a = _col("stand.start_s", self.start_s)
        b = _col("stand.end_s", self.end_s, a.shape[0])
        _finite("stand.start_s", a)
        _finite("stand.end_s", b)
        if np.any(b < a):
            raise EventError("stand.end_s must be >= stand.start_s")
        order = np.argsort(a, kind="stable")
        a, b = a[order], b[order]
        if np.any(a[1:] < b[:-1]):
            raise EventError("stand intervals must not overlap")
        object.__setattr__(self, "start_s", a)
        object.__setattr__(self, "end_s", b)

    def standing_time(self, t_s: np.ndarray) -> np.ndarray:
        """Total standing time before each ``t_s``, s, shape of ``t_s`` (piecewise linear, non-decreasing)."""
        if self.start_s.shape[0] == 0:
            return np.zeros_like(np.asarray(t_s, float))
        knots = np.column_stack([self.start_s, self.end_s]).ravel()
        acc = np.column_stack([np.zeros_like(self.start_s), self.end_s - self.start_s])
        acc = np.cumsum(acc.ravel())
        return np.interp(np.asarray(t_s, float), knots, acc, left=0.0, right=acc[-1])


@dataclass(frozen=True)
class ClassTrack:
    """Environment class evidence over time: at ``t_s`` (k,) the probabilities ``proba`` (k, n_classes),
    held until the next row (the online classifier's latest window)."""

    t_s: np.ndarray
    proba: np.ndarray

    def __post_init__(self):
        t = _col("classes.t_s", self.t_s)
        p = np.asarray(self.proba, float)
        if p.ndim != 2 or p.shape[0] != t.shape[0]:
            raise EventError(f"classes.proba must have shape ({t.shape[0]}, n_classes), got {p.shape}")
        if np.any(np.diff(t) < 0):
            raise EventError("classes.t_s must be non-decreasing")
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "proba", p)

    @classmethod
    def from_labels(cls, t_s, labels, n_classes: int) -> "ClassTrack":
        """One-hot evidence from integer class labels (k,)."""
        lab = np.asarray(labels, int)
        if np.any((lab < 0) | (lab >= n_classes)):
            raise EventError(f"class labels must lie in [0, {n_classes}), got {lab.min()}..{lab.max()}")
        return cls(t_s, np.eye(n_classes)[lab])

    @property
    def n_classes(self) -> int:
        return int(self.proba.shape[1])

    def row_at(self, t_s: np.ndarray) -> np.ndarray:
        """Index of the row in force at each time (the last at or before it; the first before the track starts)."""
        return np.clip(np.searchsorted(self.t_s, np.asarray(t_s, float), side="right") - 1, 0, None)

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """Probabilities in force at each of ``t_s`` (m,) → (m, n_classes)."""
        return self.proba[self.row_at(t_s)]


@dataclass(frozen=True)
class ClassMap:
    """Environment class over a site on a regular grid — the map baseline's ``class_at(east_m, north_m)``.

    ``classes`` (n_north, n_east) int class codes; ``east0_m`` / ``north0_m`` the centre of cell (0, 0);
    ``de_m`` / ``dn_m`` the spacing. A query takes the nearest cell (half-way between two centres: the east /
    north one), clipped at the map's edge; the filter core (:func:`models.fusion.core.map_class`) does the
    same lookup in compiled code.

    >>> m = ClassMap.from_axes(np.array([0.0, 2.0, 4.0]), np.array([10.0, 12.0]), np.array([[0, 1, 2], [2, 2, 2]]))
    >>> m(3.1, 10.4), m(-50.0, 10.4), m(0.0, 99.0), m(1.0, 10.0)
    (2, 0, 2, 1)
    """

    east0_m: float
    north0_m: float
    de_m: float
    dn_m: float
    classes: np.ndarray

    def __post_init__(self):
        c = np.asarray(self.classes)
        if c.ndim != 2 or c.size == 0 or not np.issubdtype(c.dtype, np.integer):
            raise EventError(f"ClassMap.classes must be a non-empty 2-D integer grid, got {c.dtype} {c.shape}")
        if not (self.de_m > 0 and self.dn_m > 0):
            raise EventError(f"ClassMap spacing must be positive, got {self.de_m}, {self.dn_m}")
        object.__setattr__(self, "classes", np.ascontiguousarray(c, np.int64))

    @classmethod
    def from_axes(cls, east_m: np.ndarray, north_m: np.ndarray, classes: np.ndarray) -> "ClassMap":
        """From the grid's cell centres ``east_m`` (n_east,), ``north_m`` (n_north,) (evenly spaced)."""
        e, n = np.asarray(east_m, float), np.asarray(north_m, float)
        de = float(e[1] - e[0]) if e.size > 1 else 1.0
        dn = float(n[1] - n[0]) if n.size > 1 else 1.0
        return cls(float(e[0]), float(n[0]), de, dn, np.asarray(classes))

    def __call__(self, east_m: float, north_m: float) -> int:
        ni, nj = self.classes.shape
        i = min(max(math.floor((north_m - self.north0_m) / self.dn_m + 0.5), 0), ni - 1)
        j = min(max(math.floor((east_m - self.east0_m) / self.de_m + 0.5), 0), nj - 1)
        return int(self.classes[i, j])


@dataclass(frozen=True)
class EventStream:
    """All events of one walk in time order.

    ``t_s``, ``kind`` (STEP/GNSS/ACOUSTIC), ``index`` (row in that source): (m,).
    ``dt_s`` (m,): time since the previous event (0 for the first), and
    ``dt_stand_s`` (m,) the part of it spent standing.
    Measurement columns, aligned with the events (NaN on steps): ``z_m`` (m, 2)
    east/north, ``cov_m2`` (m, 2, 2) reported covariance, ``available`` (m,).
    """

    t_s: np.ndarray
    kind: np.ndarray
    index: np.ndarray
    dt_s: np.ndarray
    dt_stand_s: np.ndarray
    z_m: np.ndarray
    cov_m2: np.ndarray
    available: np.ndarray
    steps: StepEvents | None = None
    gnss: GnssEvents | None = None
    acoustic: AcousticEvents | None = None
    stands: StandIntervals | None = None
    step_length_m: np.ndarray = field(default=None, repr=False)
    heading_rad: np.ndarray = field(default=None, repr=False)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def n_steps(self) -> int:
        return int(np.sum(self.kind == STEP))

    def mask(self, kind: int) -> np.ndarray:
        """Boolean (m,) of the events of one kind."""
        return self.kind == kind


def merge_events(steps: StepEvents | None = None, gnss: GnssEvents | None = None,
                 acoustic: AcousticEvents | None = None, stands: StandIntervals | None = None,
                 t0_s: float | None = None) -> EventStream:
    """Merge the sources into one :class:`EventStream` (stable: time, then kind, then source order).

    ``t0_s``: the time of the filter's initial state (default: the first event's).
    """
    parts = []
    for code, src in ((STEP, steps), (GNSS, gnss), (ACOUSTIC, acoustic)):
        if src is not None and len(src):
            parts.append((code, src))
    if not parts:
        raise EventError("no events: give at least one of steps, gnss, acoustic")
    t = np.concatenate([p.t_s for _, p in parts])
    kind = np.concatenate([np.full(len(p), c, np.int8) for c, p in parts])
    index = np.concatenate([np.arange(len(p)) for _, p in parts])
    order = np.lexsort((index, kind, t))
    t, kind, index = t[order], kind[order], index[order]
    m = t.shape[0]
    z = np.full((m, 2), np.nan)
    cov = np.full((m, 2, 2), np.nan)
    avail = np.zeros(m, bool)
    length = np.full(m, np.nan)
    heading = np.full(m, np.nan)
    for code, src in parts:
        sel = kind == code
        i = index[sel]
        if code == STEP:
            length[sel] = src.step_length_m[i]
            heading[sel] = src.heading_rad[i]
        else:
            z[sel, 0] = src.east_m[i]
            z[sel, 1] = src.north_m[i]
            cov[sel] = src.cov_m2[i]
            avail[sel] = src.available[i]
    start = t[0] if t0_s is None else float(t0_s)
    if start > t[0]:
        raise EventError(f"t0_s must not be after the first event ({t[0]}), got {start}")
    prev = np.concatenate([[start], t[:-1]])
    dt = t - prev
    if stands is not None:
        st = stands.standing_time(t) - stands.standing_time(prev)
    else:
        st = np.zeros(m)
    return EventStream(t, kind, index, dt, st, z, cov, avail, steps, gnss, acoustic, stands, length, heading)
