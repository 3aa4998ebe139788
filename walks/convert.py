"""A smartLoc drive as a walk folder: what ``envfuse convert smartloc`` writes.

:func:`convert_smartloc` reads a smartLoc ``*_Input.txt`` (pseudoranges and odometry) and its
``*_GT.txt`` (the reference) with :func:`features.gnss.pseudorange.read_smartloc` and writes a walk
folder that ``run``, ``evaluate`` and ``train fusion`` read like any walk (:mod:`walks.reader`):

- ``site.toml``: the site's name and origin. The origin is the **median per-epoch fix** of the
  converted span (:func:`features.gnss.wls.solve_epochs`; median east, north, up in the local frame,
  :func:`site_origin_from_fixes`) — never the reference, which a device would not have; no beacons.
  The grid spans the fixes.
- ``walk.toml``: ``name``, ``site``, ``duration_s``, ``[gnss_pseudoranges]`` (file, corrections),
  ``[odometry]`` (file), the source files, and ``source_t0_s``, the source's time of the walk's
  ``t_s = 0`` (the start of the converted span). smartLoc states only relative times, so
  ``start_utc`` is written only when given (``time_utc`` columns stay empty otherwise).
- ``gnss_pseudoranges.csv``, ``odometry.csv`` (:mod:`features.raw_tables`).
- ``truth.csv``: the reference in the site's ENU frame (pymap3d, WGS-84), ``env_class`` ``unknown``:
  a NovAtel trajectory says where the car was, not how much of its sky was blocked, and a class
  derived from the solver's own error would make the comparison of the environment model with that
  error circular. Per-class metrics therefore have nothing to report on a drive; ``all`` holds
  every epoch (:mod:`walks.score`).

The folder is built under a temporary name and renamed into place when complete
(:func:`features.fileio.atomic_directory`): an interrupted conversion leaves nothing.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path

import numpy as np
import pymap3d

from features.errors import ConfigError, DataError
from features.fileio import atomic_directory, atomic_write_text, write_toml
from features.gnss.pseudorange import OdometryTable, PseudorangeTable, ReferenceTrack, read_smartloc
from features.gnss.wls import solve_epochs
from features.raw_tables import odometry_csv_text, pseudorange_csv_text
from features.site import Grid, Origin, Site, save_site
from features.walk import UNKNOWN_CLASS_NAME

__all__ = ["ConvertedWalk", "convert_smartloc", "site_origin_from_fixes"]

_GRID_MARGIN_M = 20.0
"""Margin of the site grid around the fixes, m."""


@dataclass(frozen=True)
class ConvertedWalk:
    """What :func:`convert_smartloc` wrote: the folder, the span (source times), the counts, the origin."""

    directory: Path
    span_s: tuple[float, float]
    n_epochs: int
    n_fixes: int
    n_odometry: int
    n_truth: int
    origin: Origin

    def summary(self) -> str:
        return (f"{self.directory}: {self.span_s[1] - self.span_s[0]:.1f} s of drive, {self.n_epochs} GNSS epochs "
                f"({self.n_fixes} solved), {self.n_odometry} odometry samples, {self.n_truth} reference points; "
                f"site origin {self.origin.lat_deg:.6f}, {self.origin.lon_deg:.6f} (median fix)")


def site_origin_from_fixes(ecef_m: np.ndarray) -> Origin:
    """The median fix of ``ecef_m`` (n, 3) as a geodetic origin (NaN rows ignored): the median east, north and up
    of the fixes in the local frame at their mean, so that the fixes' median is the origin of the site's ENU
    frame (a median per ECEF axis is not: ECEF axes are tilted against the local ones)."""
    ok = np.all(np.isfinite(ecef_m), axis=1)
    if not ok.any():
        raise DataError("no epoch could be solved, so the site has no origin (need >= 4 satellites at one epoch)")
    x = ecef_m[ok]
    lat0, lon0, alt0 = pymap3d.ecef2geodetic(*np.mean(x, axis=0))
    e, n, u = pymap3d.ecef2enu(x[:, 0], x[:, 1], x[:, 2], lat0, lon0, alt0)
    lat, lon, alt = pymap3d.enu2geodetic(np.median(e), np.median(n), np.median(u), lat0, lon0, alt0)
    return Origin(lat_deg=float(lat), lon_deg=float(lon), alt_m=float(alt))


def _span(table, t0: float, t1: float):
    """Rows of a table with t0 ≤ t_s < t1."""
    sel = (table.t_s >= t0) & (table.t_s < t1)
    if isinstance(table, PseudorangeTable):
        return replace(table, t_s=table.t_s[sel], pseudorange_m=table.pseudorange_m[sel],
                       pseudorange_var_m2=table.pseudorange_var_m2[sel], sat_ecef_m=table.sat_ecef_m[sel],
                       svid=table.svid[sel], system=table.system[sel], elevation_deg=table.elevation_deg[sel],
                       cn0_dbhz=table.cn0_dbhz[sel])
    if isinstance(table, OdometryTable):
        return replace(table, t_s=table.t_s[sel], velocity_body_m_s=table.velocity_body_m_s[sel],
                       rate_body_rad_s=table.rate_body_rad_s[sel], velocity_var_m2_s2=table.velocity_var_m2_s2[sel],
                       rate_var_rad2_s2=table.rate_var_rad2_s2[sel])
    return ReferenceTrack(t_s=table.t_s[sel], ecef_m=table.ecef_m[sel], cov_ecef_m2=table.cov_ecef_m2[sel],
                          source=table.source)


def _shift(table, dt: float):
    return replace(table, t_s=table.t_s - dt)


def _truth_text(ref: ReferenceTrack, origin: Origin) -> str:
    e, n, _ = pymap3d.ecef2enu(ref.ecef_m[:, 0], ref.ecef_m[:, 1], ref.ecef_m[:, 2], origin.lat_deg,
                               origin.lon_deg, origin.alt_m)
    lines = ["t_s,east_m,north_m,env_class"]
    lines += [f"{t!r},{float(a)!r},{float(b)!r},{UNKNOWN_CLASS_NAME}" for t, a, b in zip(ref.t_s.tolist(), e, n)]
    return "\n".join(lines) + "\n"


def _grid(e: np.ndarray, n: np.ndarray) -> Grid:
    lo_e, hi_e = math.floor(np.min(e) - _GRID_MARGIN_M), math.ceil(np.max(e) + _GRID_MARGIN_M)
    lo_n, hi_n = math.floor(np.min(n) - _GRID_MARGIN_M), math.ceil(np.max(n) + _GRID_MARGIN_M)
    return Grid(cell_size_m=10.0, east_min_m=float(lo_e), east_max_m=float(hi_e), north_min_m=float(lo_n),
                north_max_m=float(hi_n))


def _read(input_txt: Path, gt_txt: Path):
    log = read_smartloc(input_txt)
    if log.pseudoranges is None:
        raise DataError(f"{input_txt}: no pseudorange3 record (is it the *_Input.txt of a smartLoc drive?)")
    ref = read_smartloc(gt_txt).reference
    if ref is None:
        raise DataError(f"{gt_txt}: no point3 record (is it the *_GT.txt of a smartLoc drive?)")
    return log, ref


def convert_smartloc(input_txt: str | os.PathLike, gt_txt: str | os.PathLike, out_dir: str | os.PathLike, *,
                     start_s: float | None = None, end_s: float | None = None, name: str | None = None,
                     site_name: str | None = None, start_utc: datetime | None = None,
                     overwrite: bool = False) -> ConvertedWalk:
    """Write the walk folder ``out_dir`` from a smartLoc drive (module docstring).

    ``start_s`` / ``end_s``: the span to convert, on the source's time base (default: all of it;
    the walk's ``t_s`` then counts from ``start_s``); ``name`` the walk's name (default the folder's);
    ``site_name`` (default the input's file name without ``_Input.txt``); ``start_utc`` the UTC of the
    span's start when known. Raises :class:`~features.errors.PseudorangeError` (bad line),
    :class:`~features.errors.DataError` (nothing to convert) or
    :class:`~features.errors.ConfigError` (a bad span).
    """
    input_txt, gt_txt, out_dir = Path(input_txt), Path(gt_txt), Path(out_dir)
    log, ref = _read(input_txt, gt_txt)
    first = min(float(tab.t_s[0]) for tab in (log.pseudoranges, log.odometry, ref) if tab is not None)
    last = max(float(tab.t_s[-1]) for tab in (log.pseudoranges, log.odometry, ref) if tab is not None)
    t0 = first if start_s is None else float(start_s)
    t1 = math.inf if end_s is None else float(end_s)
    if not (math.isfinite(t0) and t0 < t1):
        raise ConfigError(f"the span must satisfy start < end, got {t0:g} .. {t1:g} s")
    pr, ref = _span(log.pseudoranges, t0, t1), _span(ref, t0, t1)
    odo = _span(log.odometry, t0, t1) if log.odometry is not None else None
    if len(pr) == 0 or len(ref) == 0:
        raise ConfigError(f"the span {t0:g} .. {t1:g} s holds no pseudorange or no reference point "
                          f"(the drive runs from {first:g} to {last:g} s)")
    pr, ref = _shift(pr, t0), _shift(ref, t0)
    odo = _shift(odo, t0) if odo is not None and len(odo) >= 2 else None
    sol = solve_epochs(pr)
    origin = site_origin_from_fixes(sol.ecef_m)
    k = sol.has_fix
    fe, fn, _ = pymap3d.ecef2enu(sol.ecef_m[k, 0], sol.ecef_m[k, 1], sol.ecef_m[k, 2], origin.lat_deg,
                                 origin.lon_deg, origin.alt_m)
    stem = input_txt.name.removesuffix(".txt").removesuffix("_Input")
    site = Site(name=site_name or stem, origin=origin, grid=_grid(np.asarray(fe), np.asarray(fn)))
    end = max(float(pr.t_s[-1]), float(ref.t_s[-1]), float(odo.t_s[-1]) if odo is not None else 0.0)
    walk = {"name": name or out_dir.name, "site": "site.toml", "duration_s": max(end, 1e-3),
            "source": f"smartLoc (TU Chemnitz, CC BY-SA 4.0): {input_txt.name}, {gt_txt.name}",
            "source_t0_s": t0, "vehicle": "car",
            "gnss_pseudoranges": {"file": "gnss_pseudoranges.csv", "corrections": sorted(pr.corrections)}}
    if start_utc is not None:
        walk["start_utc"] = start_utc.isoformat().replace("+00:00", "Z")
    if odo is not None:
        walk["odometry"] = {"file": "odometry.csv"}
    with atomic_directory(out_dir, overwrite=overwrite) as tmp:
        save_site(site, tmp / "site.toml")
        write_toml(tmp / "walk.toml", walk)
        atomic_write_text(tmp / "gnss_pseudoranges.csv", pseudorange_csv_text(pr))
        if odo is not None:
            atomic_write_text(tmp / "odometry.csv", odometry_csv_text(odo))
        atomic_write_text(tmp / "truth.csv", _truth_text(ref, origin))
    return ConvertedWalk(out_dir, (t0, t0 + end), len(sol), int(k.sum()), 0 if odo is None else len(odo), len(ref),
                         origin)
