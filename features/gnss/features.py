"""The five GNSS environment features of docs/design.md §5, vectorised over epochs.

Per analysis window (default 2 s, hop 1 s), over satellites at or above the
elevation mask (default 10°):

1. ``att_mean_db`` μ — mean attenuation of tracked satellites,
   attenuation = max(0, C_ref(el) − C/N0) (Xue, Han & Wang 2023, §2.1);
2. ``att_std_db`` σ — its (population) standard deviation;
3. ``fluct_per_s`` β — local extrema of each tracked satellite's C/N0 series
   whose swing from the previous extremum is ≥ 2 dB-Hz, per second of
   tracking: the extrema of all satellites over their tracked satellite-seconds
   in the window (the per-satellite rates weighted by tracked time; equal to
   their plain mean when every satellite is tracked throughout). docs/design.md says 1 dB-Hz, but NMEA
   reports C/N0 in whole dB-Hz, so a 1 dB-Hz swing is a single quantisation
   step: it counts the estimator flicker of strong line-of-sight signals and
   the feature then orders the classes backwards (open > heavy on simulated
   surveys). 2 dB-Hz, the smallest swing above one step, restores
   heavy > light > open; ``fluct_threshold_dbhz`` sets it;
4. ``invisible_ratio`` ζ — in-view-but-untracked (satellite, epoch) pairs over
   all in-view pairs;
5. ``dop_growth`` λ — HDOP of the tracked satellites over HDOP of all in-view
   satellites, minus 1, averaged over the window's epochs; 10 when fewer than
   4 are tracked (or their geometry is singular).

HDOP from azimuth/elevation only, with one receiver clock per GNSS system (as
the receivers' own HDOP: GPS and BeiDou time differ): rows
``[cos el sin az, cos el cos az, sin el, 1_sys]`` of the geometry matrix G,
Q = (GᵀG)⁻¹, HDOP = sqrt(Q_EE + Q_NN) — the textbook definition (Kaplan &
Hegarty, *Understanding GPS*, 2nd ed. 2006, ch. 7, dilution of precision)
with the inter-system clock of multi-GNSS solutions. A satellite listed without
azimuth or elevation has no line of sight and stays out of G (it was read as
north before).

The open-sky reference C_ref(el) = a + b·sin(el) defaults to ≈ 38 dB-Hz at 5°
and 50 dB-Hz at zenith (docs/design.md §6). The linear form in sin(el) is an
engineering choice, not a published model: it follows the monotone rise of
C/N0 with elevation seen in real data (smartLoc bins 29.9 / 35.8 / 38.8 /
46.6 dB-Hz for 0-15 / 15-30 / 30-60 / 60-90°, docs/design.md §6) with two
parameters that :func:`fit_cn0_reference` can fit to open-sky epochs (an
upper quantile per elevation bin, then a count-weighted least-squares line in
sin(el)); a median fit on simulated open cells recovers the simulator's
open-sky line within 1.5 dB (tests).

A satellite listed on several signals (NMEA 4.10+) is read on one stated
signal, its primary one (:attr:`features.gnss.nmea.Epoch.primary_satellites`:
GPS/QZSS L1 C/A, GLONASS G1 C/A, Galileo E1-B/C, BeiDou B1I by the NMEA 4.11
signal ids of :data:`features.gnss.quirks.PRIMARY_SIGNAL_IDS`, else an entry
that states no signal, as pre-4.10 receivers write): "tracked" means tracked on
that signal, and its C/N0 is compared with an L1-band reference. Mixing bands
would not be: L5/E5a C/N0 sits several dB from L1's on the same satellite and
the secondary entries of real receivers often carry no elevation or azimuth.
A satellite listed only on secondary signals is left out.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from features.constants import ELEVATION_MASK_DEG
from features.errors import ConfigError, DataError

__all__ = [
    "FEATURE_COLUMNS", "COUNT_COLUMNS", "GnssFeatureConfig", "Cn0Reference", "SkyArrays",
    "sky_arrays", "gnss_features", "fit_cn0_reference", "epoch_dop_growth", "fluctuation_extrema",
    "FluctuationState", "fluctuation_state",
]

FEATURE_COLUMNS = ("att_mean_db", "att_std_db", "fluct_per_s", "invisible_ratio", "dop_growth")
"""The five GNSS feature names, in docs/design.md §5 order."""

COUNT_COLUMNS = ("n_epochs", "n_in_view", "n_tracked", "n_pairs_in_view", "n_pairs_tracked")
"""Counts behind each window: epochs with a reported sky; distinct satellites above the mask in
view and tracked; (satellite, epoch) pairs in view and tracked."""


MAX_WINDOWS = 20_000_000
"""Largest number of windows computed in one call (≈ 230 days at the default 1 s hop)."""


@dataclass(frozen=True)
class GnssFeatureConfig:
    """Window and feature parameters (docs/design.md §5 defaults)."""

    window_s: float = 2.0
    hop_s: float = 1.0
    elevation_mask_deg: float = ELEVATION_MASK_DEG
    fluct_threshold_dbhz: float = 2.0  # not DESIGN's 1.0: see the module docstring (integer C/N0)
    dop_growth_cap: float = 10.0

    def __post_init__(self):
        for name in ("window_s", "hop_s", "fluct_threshold_dbhz", "dop_growth_cap"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ConfigError(f"GnssFeatureConfig.{name} must be a positive number, got {value!r}")
        if not 0.0 <= self.elevation_mask_deg < 90.0:
            raise ConfigError("GnssFeatureConfig.elevation_mask_deg must lie in [0, 90), "
                              f"got {self.elevation_mask_deg}")


@dataclass(frozen=True)
class Cn0Reference:
    """Open-sky C/N0 model C_ref(el) = intercept_dbhz + slope_dbhz · sin(el).

    >>> ref = Cn0Reference()
    >>> round(float(ref.cref_dbhz(5.0)), 2), round(float(ref.cref_dbhz(90.0)), 2)
    (38.0, 50.0)
    >>> Cn0Reference.from_dict(ref.to_dict()) == ref
    True
    """

    intercept_dbhz: float = 38.0 - 12.0 * math.sin(math.radians(5.0)) / (1.0 - math.sin(math.radians(5.0)))
    slope_dbhz: float = 12.0 / (1.0 - math.sin(math.radians(5.0)))
    source: str = "default: 38 dB-Hz at 5 deg, 50 dB-Hz at zenith (docs/design.md 6)"

    def __post_init__(self):
        for name in ("intercept_dbhz", "slope_dbhz"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"Cn0Reference.{name} must be a finite number, got {value!r}")
        if not 0.0 < self.intercept_dbhz + max(self.slope_dbhz, 0.0) < 80.0:
            raise ConfigError(f"Cn0Reference gives an implausible zenith C/N0 "
                              f"{self.intercept_dbhz + self.slope_dbhz:.1f} dB-Hz")

    def cref_dbhz(self, el_deg):
        """C_ref at elevation(s) ``el_deg`` (array-like, degrees) in dB-Hz."""
        return self.intercept_dbhz + self.slope_dbhz * np.sin(np.radians(np.asarray(el_deg, dtype=float)))

    def to_dict(self) -> dict:
        """JSON-serialisable parameters (model bundles store these)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "Cn0Reference":
        try:
            return cls(float(data["intercept_dbhz"]), float(data["slope_dbhz"]), str(data.get("source", "")))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"C/N0 reference needs numeric intercept_dbhz and slope_dbhz: {exc}") from None


@dataclass(frozen=True)
class SkyArrays:
    """Epochs with a reported sky, as arrays over (epoch, satellite).

    t_s : (n,) seconds; sat_keys : m tuples (system, prn);
    el_deg, az_deg, cn0_dbhz : (n, m), NaN when not listed / not tracked;
    in_view, used : (n, m) bool; hdop : (n,) receiver HDOP (NaN when absent);
    interval_s : the receiver's epoch interval (median step of all its epochs, sky or not; NaN:
    take it from ``t_s``).
    """

    t_s: np.ndarray
    sat_keys: tuple
    el_deg: np.ndarray
    az_deg: np.ndarray
    cn0_dbhz: np.ndarray
    in_view: np.ndarray
    used: np.ndarray
    hdop: np.ndarray
    interval_s: float = float("nan")

    @property
    def n_epochs(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def epoch_interval_s(self) -> float:
        """The epoch interval: :attr:`interval_s` when known, else the median step of ``t_s`` (0 for one epoch)."""
        if math.isfinite(self.interval_s) and self.interval_s >= 0:
            return float(self.interval_s)
        return _median_step(self.t_s)


def _median_step(t_s) -> float:
    """Median positive step of a time series, s (0 when it has none)."""
    d = np.diff(np.asarray(t_s, dtype=float))
    d = d[d > 0]
    return float(np.median(d)) if d.size else 0.0


def sky_arrays(epochs) -> SkyArrays:
    """Stack the epochs that reported a sky into :class:`SkyArrays` (one column per satellite, in order
    of first appearance), each satellite read on its primary signal (module docstring).

    ``epochs``: a list of :class:`~features.gnss.nmea.Epoch` or their
    :class:`~features.gnss.assemble.EpochColumns` (the reader's columns: no object per satellite).
    """
    from features.gnss.assemble import SYSTEM_CODES, primary_rows
    from features.gnss.nmea import epoch_columns

    cols = epoch_columns(epochs)
    rows, counts = primary_rows(cols)        # Epoch.primary_satellites, in its order
    is_sky = cols.col("sky_reported") != 0
    sky = np.flatnonzero(is_sky)
    rows, counts = rows[np.repeat(is_sky, counts)], counts[sky]
    n = sky.size
    sat_i, sat_f = cols.sat_i[rows], cols.sat_f[rows]
    if rows.size:
        r = np.repeat(np.arange(n, dtype=np.intp), counts)
        key = sat_i[:, 0] * 100_000 + sat_i[:, 1]
        uniq, first, inv = np.unique(key, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")          # columns in order of first appearance
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        c = rank[inv.ravel()]
        m = uniq.size
        index = tuple((SYSTEM_CODES[k // 100_000], k % 100_000) for k in uniq[order].tolist())
    else:
        m, index = 0, ()
    el = np.full((n, m), np.nan)
    az = np.full((n, m), np.nan)
    cn0 = np.full((n, m), np.nan)
    in_view = np.zeros((n, m), dtype=bool)
    used = np.zeros((n, m), dtype=bool)
    if rows.size:
        el_v, az_v, cn0_v = sat_f[:, 0], sat_f[:, 1], sat_f[:, 2]
        used_v = sat_i[:, 3] != 0
        # One entry per (epoch, satellite): its primary signal's (a repeated GSV within one epoch
        # was already merged by the reader).
        np.fmax.at(cn0, (r, c), cn0_v)
        has_el = ~np.isnan(el_v)
        el[r[has_el], c[has_el]] = el_v[has_el]
        has_az = ~np.isnan(az_v)
        az[r[has_az], c[has_az]] = az_v[has_az]
        in_view[r, c] = True
        np.logical_or.at(used, (r, c), used_v)
    hdop = cols.col("hdop")[sky]
    t_all = cols.col("t_s")
    interval = _median_step(t_all.tolist()) if len(cols) > 1 else float("nan")
    return SkyArrays(t_all[sky], index, el, az, cn0, in_view, used, hdop, interval)


def _hdop(el_rad: np.ndarray, az_rad: np.ndarray, weight: np.ndarray, system_index: np.ndarray | None = None
          ) -> np.ndarray:
    """HDOP per epoch from the satellites where ``weight`` is True; NaN if too few or singular. Shapes (n, m) → (n,).

    One receiver clock column per GNSS system (``system_index`` (m,) ints; default one clock):
    GPS and BeiDou time differ, and receivers solve a clock per system, so their own HDOP
    does. A system with no satellite in an epoch gets a unit diagonal (its clock decoupled),
    and an epoch needs 3 + (systems present) satellites. Satellites without an elevation or
    azimuth have no line of sight to put in G and are left out.
    """
    if system_index is None:
        system_index = np.zeros(el_rad.shape[1], dtype=int)
    n_sys = int(system_index.max()) + 1 if system_index.size else 1
    weight = weight & np.isfinite(el_rad) & np.isfinite(az_rad)
    ce = np.cos(el_rad)
    clocks = np.broadcast_to((system_index[None, :, None] == np.arange(n_sys)[None, None, :]).astype(float),
                             el_rad.shape + (n_sys,))
    g = np.concatenate([np.stack([ce * np.sin(az_rad), ce * np.cos(az_rad), np.sin(el_rad)], axis=-1), clocks],
                       axis=-1)
    g = np.where(weight[..., None], np.nan_to_num(g), 0.0)
    # A = GᵀG per epoch, shape (n, 3 + n_sys, 3 + n_sys)
    a = np.matmul(g.transpose(0, 2, 1), g)  # batched GᵀG (matmul: several times faster than einsum here)
    present = (weight.astype(float) @ (system_index[:, None] == np.arange(n_sys)).astype(float)) > 0
    idx = 3 + np.arange(n_sys)
    a[:, idx, idx] += ~present                     # an absent system's clock: unit diagonal, no coupling
    count = weight.sum(axis=1)
    out = np.full(a.shape[0], np.nan)
    ok = count >= 3 + present.sum(axis=1)
    if ok.any():
        sub = a[ok]
        # singular geometry (e.g. all satellites on one cone): |det(GᵀG)| negligible against its scale
        # count⁴ (entries are O(count)); LU determinant, cheaper than an SVD condition number
        det = np.linalg.det(sub)
        good = np.isfinite(det) & (np.abs(det) > 1e-10 * count[ok].astype(float) ** sub.shape[1])
        q = np.full_like(sub, np.nan)
        if good.any():
            q[good] = np.linalg.inv(sub[good])
        h = np.sqrt(q[:, 0, 0] + q[:, 1, 1])
        out[ok] = h
    return out


def epoch_dop_growth(el_deg: np.ndarray, az_deg: np.ndarray, in_view: np.ndarray, tracked: np.ndarray,
                     cap: float = 10.0, system_index: np.ndarray | None = None) -> np.ndarray:
    """λ per epoch: HDOP(tracked) / HDOP(in view) − 1, in [0, cap]; cap when too few are tracked
    (4 with one system) or the geometry is singular; NaN when none in view.

    All inputs of shape (n, m); ``tracked`` ⊆ ``in_view``; ``system_index`` (m,): one clock per
    system (see :func:`_hdop`; default one clock for all).

    >>> el = np.array([[80.0, 30, 30, 30, 30]]); az = np.array([[0.0, 0, 90, 180, 270]])
    >>> view = np.ones((1, 5), bool)
    >>> [round(float(epoch_dop_growth(el, az, view, view & keep)[0]), 4)
    ...  for keep in (az >= 0, az != 90, az < 180)]  # all; without the east one (σ_E² doubles); only 3
    [0.0, 0.4142, 10.0]
    """
    el_rad, az_rad = np.radians(el_deg), np.radians(az_deg)
    h_view = _hdop(el_rad, az_rad, in_view, system_index)
    h_trk = _hdop(el_rad, az_rad, tracked, system_index)
    with np.errstate(invalid="ignore", divide="ignore"):
        growth = h_trk / h_view - 1.0
    n_trk = tracked.sum(axis=1)
    n_view = in_view.sum(axis=1)
    growth = np.where((n_trk < 4) | ~np.isfinite(growth), cap, growth)
    growth = np.clip(growth, 0.0, cap)
    return np.where(n_view > 0, growth, np.nan)


def _ffill_rows(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Forward-fill x (n, m) along axis 0 from the rows where ``valid``; NaN before the first valid row."""
    n = x.shape[0]
    idx = np.where(valid, np.arange(n)[:, None], -1)
    np.maximum.accumulate(idx, axis=0, out=idx)
    out = np.take_along_axis(x, np.maximum(idx, 0), axis=0)
    return np.where(idx >= 0, out, np.nan)


@dataclass(frozen=True)
class FluctuationState:
    """The memory :func:`fluctuation_extrema` carries into epoch ``t_s`` of a C/N0 series, per satellite
    ``sat_keys`` (m tuples (system, prn)), each array of shape (m,): ``last_dbhz`` the C/N0 of its last tracked
    epoch before (NaN: none yet), ``direction`` the sign (±1) of the last change of its tracked C/N0 before
    that epoch (NaN: none yet), ``extremum_dbhz`` the value the next extremum's swing is measured from (the
    previous extremum's C/N0, else the first tracked value; NaN: none yet) and ``tracked`` whether the epoch
    before was tracked. A run over a later piece of the series resumed from it (``resume``) marks every
    extremum from ``t_s`` on as the run over the whole series does: the memory outlasts any fixed span while a
    satellite's C/N0 holds still (a long walk's cut, ``walks/segments.py``)."""

    t_s: float
    sat_keys: tuple
    last_dbhz: np.ndarray
    direction: np.ndarray
    extremum_dbhz: np.ndarray
    tracked: np.ndarray
    window_origin_s: float = math.nan
    """Start of the whole log's first feature window (a whole multiple of the hop; NaN: not stated): a later cut
    whose first epoch follows a gap in the log holds the windows of the whole log's grid that reach back over
    it to that epoch, not only those starting at or after it (:func:`gnss_features`)."""

    def columns(self, sat_keys) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(last_dbhz, direction, extremum_dbhz, tracked) for the columns ``sat_keys`` (each (m',)): NaN and
        False for a satellite the state does not hold (none of its epochs before ``t_s`` were seen)."""
        where = {k: i for i, k in enumerate(self.sat_keys)}
        idx = np.array([where.get(tuple(k), -1) for k in sat_keys], dtype=np.intp)
        have = idx >= 0

        def take(a, fill):
            out = np.full(idx.shape, fill, dtype=np.asarray(a).dtype)
            out[have] = np.asarray(a)[idx[have]]
            return out
        return (take(self.last_dbhz, np.nan), take(self.direction, np.nan), take(self.extremum_dbhz, np.nan),
                take(self.tracked, False))


def fluctuation_extrema(cn0_dbhz: np.ndarray, tracked: np.ndarray, threshold_dbhz: float = 1.0,
                        resume: tuple | None = None) -> np.ndarray:
    """Mark C/N0 local extrema whose swing from the previous extremum is ≥ ``threshold_dbhz``.

    Per column (satellite) of ``cn0_dbhz`` (n, m), over the epochs where
    ``tracked`` (gaps bridged by the last value): an extremum is a tracked
    epoch where the direction of change reverses (plateaus count once, at
    their end); its swing is the difference to the previous extremum (or to
    the first tracked value). Returns a bool array (n, m).

    ``resume``: the series' memory before its first row, (last_dbhz, direction, extremum_dbhz, tracked), each
    (m,) (:meth:`FluctuationState.columns`; :func:`_extrema_memory`): the rows are then marked as in the run
    over the series they continue (the memory's epoch is prepended, its own mark decided by the first row).

    >>> x = np.array([40, 42, 40, 40, 43, 43.5, 43], float)[:, None]
    >>> fluctuation_extrema(x, np.ones_like(x, bool))[:, 0].astype(int).tolist()
    [0, 1, 0, 1, 0, 1, 0]
    >>> fluctuation_extrema(x, np.ones_like(x, bool), 2.5)[:, 0].astype(int).tolist()
    [0, 0, 0, 0, 0, 1, 0]
    >>> m = _extrema_memory(x[:4], np.ones((4, 1), bool), 2.5, 4)   # before the 5th epoch: 40 after 40
    >>> fluctuation_extrema(x[4:], np.ones((3, 1), bool), 2.5, m)[:, 0].astype(int).tolist()
    [0, 1, 0]
    """
    return _extrema(cn0_dbhz, tracked, threshold_dbhz, resume)[0]


def _extrema(cn0_dbhz: np.ndarray, tracked: np.ndarray, threshold_dbhz: float, resume: tuple | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(marks (n, m), y (n, m) the bridged series, direction (n, m) the sign of the last change before each
    row, reference (n, m) the value each row's swing is measured from): :func:`fluctuation_extrema` with what
    :func:`_extrema_memory` reads its memory from."""
    n, m = cn0_dbhz.shape
    tracked = np.asarray(tracked, bool)
    if resume is not None:
        last, direction, ref, was_tracked = (np.asarray(a) for a in resume)
        # the memory's epoch as row 0: its bridged value, tracked as it was; its direction and reference given
        cn0_dbhz = np.vstack([np.where(np.isfinite(last), last, np.nan)[None, :], cn0_dbhz])
        valid = np.vstack([np.isfinite(last)[None, :], tracked])
        tracked = np.vstack([np.asarray(was_tracked, bool)[None, :], tracked])
        n += 1
    else:
        valid = tracked
    if n == 0:
        return np.zeros((0, m), dtype=bool), *(np.zeros((0, m)),) * 3
    y = _ffill_rows(cn0_dbhz, valid)
    d = np.nan_to_num(np.diff(y, axis=0))  # (n-1, m); d[i] = y[i+1] − y[i]
    sgn = np.sign(d)
    # last non-zero direction before point i (from d[0..i-1])
    last = _ffill_rows(sgn, sgn != 0)  # last[i] = last non-zero sign among d[0..i]
    start = np.full((1, m), np.nan) if resume is None else np.asarray(direction, float)[None, :]
    last = np.where(np.isnan(last), start, last)
    before = np.vstack([start, last])  # for point i: direction into it (n, m)
    is_ext = np.zeros((n, m), dtype=bool)
    is_ext[:-1] = (sgn != 0) & np.isfinite(before[:-1]) & (before[:-1] != sgn) & tracked[:-1]
    # swing from the previous (unfiltered) extremum, or from the first tracked value
    first = _ffill_rows(y, np.isfinite(y))
    first_val = np.take_along_axis(first, np.argmax(np.isfinite(y), axis=0)[None, :], axis=0)
    ext_val = np.where(is_ext, y, np.nan)
    prev = _ffill_rows(ext_val, is_ext)
    prev = np.vstack([np.full((1, m), np.nan) if resume is None else np.asarray(ref, float)[None, :], prev[:-1]])
    if resume is not None:
        prev = np.where(np.isnan(prev), np.asarray(ref, float)[None, :], prev)
    prev = np.where(np.isfinite(prev), prev, first_val)
    with np.errstate(invalid="ignore"):
        marks = is_ext & (np.abs(y - prev) >= threshold_dbhz)
    if resume is not None:
        return marks[1:], y[1:], before[1:], prev[1:]
    return marks, y, before, prev


def _extrema_memory(cn0_dbhz: np.ndarray, tracked: np.ndarray, threshold_dbhz: float, i: int,
                    resume: tuple | None = None) -> tuple:
    """The memory of :func:`fluctuation_extrema` (run from ``resume``) before row ``i`` of the series, as its
    ``resume`` argument takes it: the memory given (or none) for ``i`` = 0."""
    n, m = cn0_dbhz.shape
    if i <= 0:
        return resume if resume is not None else (np.full(m, np.nan), np.full(m, np.nan), np.full(m, np.nan),
                                                  np.zeros(m, bool))
    # the rows up to i only: row i−1's own mark needs row i, which the resumed run decides
    _, y, before, prev = _extrema(cn0_dbhz[:i], tracked[:i], threshold_dbhz, resume)
    return y[i - 1].copy(), before[i - 1].copy(), prev[i - 1].copy(), np.asarray(tracked, bool)[i - 1].copy()


def _window_sums(cum: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sums over epochs [lo, hi) from a cumulative array with a leading zero row."""
    return cum[hi] - cum[lo]


def _view_tracked(sky: SkyArrays, config: GnssFeatureConfig) -> tuple[np.ndarray, np.ndarray]:
    """(in view above the mask, tracked there), each (n, m)."""
    with np.errstate(invalid="ignore"):
        view = sky.in_view & (sky.el_deg >= config.elevation_mask_deg)
    return view, view & np.isfinite(sky.cn0_dbhz)


def _sky_extrema(sky: SkyArrays, config: GnssFeatureConfig, tracked: np.ndarray,
                 resume: FluctuationState | None) -> np.ndarray:
    """:func:`fluctuation_extrema` of the sky's tracked C/N0, its epochs from ``resume.t_s`` on resumed from it
    (the earlier ones, a cut's warm-up, from scratch)."""
    cn0 = np.where(tracked, sky.cn0_dbhz, np.nan)
    thr = config.fluct_threshold_dbhz
    if resume is None:
        return fluctuation_extrema(cn0, tracked, thr)
    b = _resume_row(sky.t_s, resume.t_s)
    return np.vstack([fluctuation_extrema(cn0[:b], tracked[:b], thr),
                      fluctuation_extrema(cn0[b:], tracked[b:], thr, resume.columns(sky.sat_keys))])


RESUME_MATCH_S = 1e-6
"""Tolerance of an epoch's time against a handed state's (:class:`FluctuationState`), s: a cut's NMEA epochs lie
where the whole log's do (the same times of day), up to the round-off of placing them on the walk's time base."""


def _resume_row(t_s: np.ndarray, at_s: float) -> int:
    """Index of the first epoch at or after ``at_s`` (within :data:`RESUME_MATCH_S`)."""
    return int(np.searchsorted(np.asarray(t_s, float), at_s - RESUME_MATCH_S, side="left"))


def fluctuation_state(sky: SkyArrays, t_s: float, config: GnssFeatureConfig | None = None,
                      resume: FluctuationState | None = None) -> FluctuationState:
    """The memory :func:`gnss_features`' extremum detector (``fluct_per_s``) carries into the first epoch of
    ``sky`` at or after walk time ``t_s`` (:class:`FluctuationState`; the read run from ``resume`` as
    :func:`gnss_features` runs it): what a later cut of the same log resumes from (``walks/segments.py``)."""
    config = config or GnssFeatureConfig()
    _, tracked = _view_tracked(sky, config)
    cn0 = np.where(tracked, sky.cn0_dbhz, np.nan)
    thr = config.fluct_threshold_dbhz
    i = _resume_row(sky.t_s, t_s)
    keys = tuple(tuple(k) for k in sky.sat_keys)
    if resume is None:
        memory = _extrema_memory(cn0, tracked, thr, i)
    else:
        b = min(_resume_row(sky.t_s, resume.t_s), i)
        memory = _extrema_memory(cn0[b:], tracked[b:], thr, i - b, resume.columns(sky.sat_keys))
        # A satellite of the handed state that no epoch of this cut lists (blocked for longer than a cut, or a
        # receiver listing only tracked satellites): the whole log's column keeps its memory through the gap
        # (its last C/N0 bridged, its direction and extremum as they were), untracked once any epoch passed.
        have = set(keys)
        gone = [j for j, k in enumerate(resume.sat_keys) if tuple(k) not in have]
        if gone:
            g = np.array(gone, dtype=np.intp)
            was = np.asarray(resume.tracked, bool)[g] if i == b else np.zeros(len(g), bool)
            memory = tuple(np.concatenate([a, extra]) for a, extra in zip(memory, (
                np.asarray(resume.last_dbhz, float)[g], np.asarray(resume.direction, float)[g],
                np.asarray(resume.extremum_dbhz, float)[g], was)))
            keys = keys + tuple(tuple(resume.sat_keys[j]) for j in gone)
    at = float(sky.t_s[i]) if i < sky.n_epochs else float(t_s)
    origin = resume.window_origin_s if resume is not None and math.isfinite(resume.window_origin_s) else \
        _first_window_start(sky, config)
    return FluctuationState(at, keys, *memory, origin)


def _first_window_start(sky: SkyArrays, config: GnssFeatureConfig) -> float:
    """The first feature window's start of a log read from its first epoch: the hop multiple at or before the
    first epoch's tag (:func:`gnss_features`)."""
    tag0 = float(sky.t_s[0]) - 0.5 * sky.epoch_interval_s
    return config.hop_s * math.floor(tag0 / config.hop_s + 1e-9)


def gnss_features(sky: SkyArrays, config: GnssFeatureConfig | None = None,
                  reference: Cn0Reference | None = None, resume: FluctuationState | None = None
                  ) -> dict[str, np.ndarray]:
    """The five features and their counts per window.

    Returns a dict of arrays of shape (n_windows,): ``t_s`` (window centre),
    ``FEATURE_COLUMNS`` and ``COUNT_COLUMNS``. Windows start at whole multiples
    of ``hop_s`` on the epochs' time base (the walk's, the grid of the audio
    windows), the first at or before the first epoch; windows holding no epoch
    are omitted.

    An epoch goes to a window by its true tag, the middle of the interval it
    measured: a receiver's C/N0 at fix time t is its estimate over the epoch
    interval ending at t, (t − Δt, t] (the tracking loops integrate up to the
    measurement epoch; the simulator averages power over that interval,
    ``simulation/gnss/stream.py``), so the tag is t − Δt/2, Δt the receiver's
    epoch interval (:attr:`SkyArrays.epoch_interval_s`). Taken at t instead, a
    window's epochs covered [start − Δt, start + window − Δt): centred Δt/2
    early, 0.1 s at 5 Hz and 0.5 s at 1 Hz (issue 11). A
    feature is NaN when its inputs are absent (no tracked satellite above the
    mask for μ, σ, β; none in view for ζ, λ).

    ``resume``: the log is a later cut of a longer one (``walks/segments.py``) and ``fluct_per_s``'s extremum
    detector resumes, at its first epoch at or after ``resume.t_s``, the memory the read of the log before
    reached there (:func:`fluctuation_state`); from the window holding no earlier epoch on, every feature is
    then the whole log's.
    """
    config = config or GnssFeatureConfig()
    reference = reference or Cn0Reference()
    names = ("t_s",) + FEATURE_COLUMNS + COUNT_COLUMNS
    if sky.n_epochs == 0:
        return {k: np.zeros(0) for k in names}
    t = sky.t_s
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise DataError("GNSS epochs must have finite, strictly increasing t_s")
    view, tracked = _view_tracked(sky, config)
    att = np.where(tracked, np.maximum(0.0, reference.cref_dbhz(sky.el_deg) - sky.cn0_dbhz), 0.0)
    ext = _sky_extrema(sky, config, tracked, resume)
    systems = sorted({k[0] for k in sky.sat_keys})
    system_index = np.array([systems.index(k[0]) for k in sky.sat_keys], dtype=int)
    lam = epoch_dop_growth(sky.el_deg, sky.az_deg, view, tracked, config.dop_growth_cap, system_index)

    def cum(a):
        a = np.asarray(a, dtype=float)
        return np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])

    c_att, c_att2 = cum(att.sum(axis=1)), cum((att ** 2).sum(axis=1))
    c_trk, c_view = cum(tracked.sum(axis=1)), cum(view.sum(axis=1))
    c_ext = cum(ext.sum(axis=1))
    c_lam, c_lam_n = cum(np.nan_to_num(lam)), cum(np.isfinite(lam))
    c_trk_sat, c_view_sat = cum(tracked), cum(view)

    # One window grid on the walk's time base: windows start at whole multiples of hop_s (as the
    # audio windows do from the audio's start, t = 0 on a walk), not at the first epoch.
    tag = t - 0.5 * sky.epoch_interval_s   # the middle of the interval each epoch measured (docstring)
    first = _first_window_start(sky, config)
    if resume is not None and math.isfinite(resume.window_origin_s):
        # a later cut of the log: the whole log's windows that hold its first epoch, the ones starting before it
        # included (after a gap in the log the whole read has them), none before the log's first window
        reach = config.hop_s * (math.ceil(config.window_s / config.hop_s - 1e-9) - 1)
        first = max(resume.window_origin_s, first - reach)
    span = tag[-1] - first
    n_win = 1 if span < config.window_s else int(math.floor((span - config.window_s) / config.hop_s + 1e-9)) + 2
    if n_win > MAX_WINDOWS:
        raise DataError(f"{n_win} windows ({span:.0f} s of epochs at hop {config.hop_s:g} s) exceed the "
                        f"{MAX_WINDOWS} a feature table may hold; use a larger hop_s")
    starts = first + config.hop_s * np.arange(n_win)
    lo = np.searchsorted(tag, starts - 1e-9, side="left")
    hi = np.searchsorted(tag, starts + config.window_s - 1e-9, side="left")
    keep = hi > lo
    lo, hi, starts = lo[keep], hi[keep], starts[keep]

    n_pairs_trk = _window_sums(c_trk, lo, hi)
    n_pairs_view = _window_sums(c_view, lo, hi)
    n_sat_trk = (_window_sums(c_trk_sat, lo, hi) > 0).sum(axis=1)
    n_sat_view = (_window_sums(c_view_sat, lo, hi) > 0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = _window_sums(c_att, lo, hi) / n_pairs_trk
        var = _window_sums(c_att2, lo, hi) / n_pairs_trk - mu ** 2
        sigma = np.sqrt(np.maximum(var, 0.0))
        # Extrema per second of tracking: Σ extrema / Σ tracked satellite-seconds, each epoch standing for
        # window_s / n_epochs of the window (a satellite tracked for a moment no longer counts as a whole one).
        beta = _window_sums(c_ext, lo, hi) * (hi - lo) / (n_pairs_trk * config.window_s)
        zeta = 1.0 - n_pairs_trk / n_pairs_view
        lam_w = np.clip(_window_sums(c_lam, lo, hi) / _window_sums(c_lam_n, lo, hi), 0.0, config.dop_growth_cap)
    no_trk = n_pairs_trk == 0
    for arr in (mu, sigma, beta):
        arr[no_trk] = np.nan
    zeta[n_pairs_view == 0] = np.nan
    return {
        "t_s": starts + 0.5 * config.window_s,
        "att_mean_db": mu, "att_std_db": sigma, "fluct_per_s": beta, "invisible_ratio": zeta,
        "dop_growth": lam_w,
        "n_epochs": (hi - lo).astype(int), "n_in_view": n_sat_view.astype(int), "n_tracked": n_sat_trk.astype(int),
        "n_pairs_in_view": n_pairs_view.astype(int), "n_pairs_tracked": n_pairs_trk.astype(int),
    }


def fit_cn0_reference(el_deg, cn0_dbhz, *, quantile: float = 0.8, bin_width_deg: float = 10.0,
                      min_per_bin: int = 20, elevation_mask_deg: float = 5.0) -> Cn0Reference:
    """Fit C_ref(el) = a + b·sin(el) to open-sky C/N0 samples.

    Per elevation bin (``bin_width_deg`` from the mask to 90°) with at least
    ``min_per_bin`` tracked samples, the ``quantile`` of C/N0 (an upper
    quantile: the unobstructed line-of-sight level, robust to the multipath
    fades that open sky has too) at the bin's mean sin(el); then a
    count-weighted least-squares line through the bin points. Raises
    DataError when fewer than two bins qualify or the line is implausible (zenith C/N0 outside 0-80 dB-Hz).

    el_deg, cn0_dbhz : array-like of the same shape (NaN C/N0 = untracked, ignored).
    """
    el = np.asarray(el_deg, dtype=float).ravel()
    cn0 = np.asarray(cn0_dbhz, dtype=float).ravel()
    if el.shape != cn0.shape:
        raise DataError(f"el_deg and cn0_dbhz differ in size: {el.size} vs {cn0.size}")
    if not 0.0 < quantile < 1.0:
        raise ConfigError(f"quantile must lie in (0, 1), got {quantile}")
    ok = np.isfinite(el) & np.isfinite(cn0) & (el >= elevation_mask_deg) & (el <= 90.0)
    el, cn0 = el[ok], cn0[ok]
    edges = np.arange(elevation_mask_deg, 90.0 + bin_width_deg, bin_width_deg)
    which = np.clip(np.digitize(el, edges) - 1, 0, len(edges) - 2)
    xs, ys, ws = [], [], []
    for b in range(len(edges) - 1):
        sel = which == b
        if sel.sum() >= min_per_bin:
            xs.append(np.sin(np.radians(el[sel])).mean())
            ys.append(np.quantile(cn0[sel], quantile))
            ws.append(sel.sum())
    if len(xs) < 2:
        raise DataError(f"fitting C_ref needs >= 2 elevation bins with >= {min_per_bin} tracked samples "
                        f"above {elevation_mask_deg} deg; got {len(xs)} from {el.size} samples")
    x, y, w = np.asarray(xs), np.asarray(ys), np.asarray(ws, dtype=float)
    # weighted least squares: minimise Σ w (y − a − b x)²
    design = np.stack([np.ones_like(x), x], axis=1) * np.sqrt(w)[:, None]
    (a, b), *_ = np.linalg.lstsq(design, y * np.sqrt(w), rcond=None)
    try:
        return Cn0Reference(float(a), float(b), f"fit: q{quantile:g} per {bin_width_deg:g} deg bin, "
                                                f"{el.size} samples, {len(xs)} bins")
    except ConfigError as exc:  # the data, not a setting, gave an impossible line: a data error
        raise DataError(f"the C/N0 reference fitted from {el.size} samples is implausible ({exc}); "
                        "these data cannot calibrate it") from None
