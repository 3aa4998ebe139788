"""A walk folder's raw GNSS and odometry as CSV: ``gnss_pseudoranges.csv`` and ``odometry.csv``.

A vehicle's drive (``envfuse convert smartloc``) keeps what its receiver and its wheels measured, not
positions: the reader of the walk (:mod:`walks.reader`) solves the fixes
(:mod:`features.gnss.wls`) and integrates the odometry (:mod:`features.vehicle.odometry`) itself,
exactly as for any other log.

``gnss_pseudoranges.csv`` — one row per satellite and epoch, rows in non-decreasing ``t_s``
(:class:`~features.gnss.pseudorange.PseudorangeTable`):

==========================  ==========================================================================
``t_s``                     receive time, s, on the walk's time base
``system``                  RINEX 3 system letter (G, R, E, C, J, S, I; RINEX 3.05 §3.5)
``svid``                    satellite number within its system (integer ≥ 0)
``pseudorange_m``           with the ``corrections`` of ``walk.toml`` removed
``pseudorange_var_m2``      its variance as the source states it (> 0; empty when it states none)
``sat_x_m``, ``sat_y_m``,   satellite position at emission, ECEF (WGS-84), m
``sat_z_m``
``elevation_deg``           as the receiver computed it, in [−90, 90] (empty when absent)
``cn0_dbhz``                in (0, 100) (empty when absent)
==========================  ==========================================================================

``walk.toml``'s ``[gnss_pseudoranges]`` table names the ``file`` and lists ``corrections``, what the
pseudoranges already have removed (a subset of :data:`CORRECTIONS`); Earth rotation is applied by the
solver unless listed.

``odometry.csv`` — one row per sample, strictly increasing ``t_s``: ``t_s``, ``speed_m_s`` (forward,
body x), ``yaw_rate_rad_s`` (about body z, up: counter-clockwise positive), ``speed_var_m2_s2``,
``yaw_rate_var_rad2_s2`` (≥ 0, the source's own variances; the dead-reckoning noise comes from them).

Numbers are written with Python's shortest round-trip form (``repr``), so a table read back is the
table written, bit for bit. A file that does not parse raises one
:class:`~features.errors.DataError` naming the file, the line and the column; nothing is skipped
(no checksum tells a damaged row from an edited one, as for the smartLoc text,
:mod:`features.gnss.pseudorange`).
"""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path

import numpy as np

from features.errors import DataError
from features.gnss.pseudorange import SYSTEM_LETTER_BY_RTKLIB_CODE, OdometryTable, PseudorangeTable

__all__ = ["PSEUDORANGE_COLUMNS", "ODOMETRY_COLUMNS", "CORRECTIONS", "pseudorange_csv_text", "read_pseudorange_csv",
           "odometry_csv_text", "read_odometry_csv"]

PSEUDORANGE_COLUMNS = ("t_s", "system", "svid", "pseudorange_m", "pseudorange_var_m2", "sat_x_m", "sat_y_m",
                       "sat_z_m", "elevation_deg", "cn0_dbhz")
"""Columns of ``gnss_pseudoranges.csv``, in order."""

ODOMETRY_COLUMNS = ("t_s", "speed_m_s", "yaw_rate_rad_s", "speed_var_m2_s2", "yaw_rate_var_rad2_s2")
"""Columns of ``odometry.csv``, in order."""

CORRECTIONS = frozenset({"satellite_clock", "ionosphere", "troposphere", "earth_rotation"})
"""What a pseudorange table may state as already removed (:class:`~features.gnss.pseudorange.PseudorangeTable`)."""

_SAT_RADIUS_M = (1.0e7, 1.0e8)
"""Distance of a GNSS satellite from Earth's centre, m (MEO ≈ 2.6e7, GEO/IGSO ≈ 4.2e7)."""

_SYSTEMS = frozenset(SYSTEM_LETTER_BY_RTKLIB_CODE.values())


def _num(v) -> str:
    """Shortest round-trip text of a number; empty for NaN."""
    v = float(v)
    return "" if math.isnan(v) else repr(v)


def _text(columns: tuple, rows) -> str:
    buf = io.StringIO()
    buf.write(",".join(columns) + "\n")
    for r in rows:
        buf.write(",".join(r) + "\n")
    return buf.getvalue()


def pseudorange_csv_text(table: PseudorangeTable) -> str:
    """``gnss_pseudoranges.csv`` of ``table`` (module docstring)."""
    s = table.sat_ecef_m
    rows = ((_num(table.t_s[i]), str(table.system[i]), str(int(table.svid[i])), _num(table.pseudorange_m[i]),
             _num(table.pseudorange_var_m2[i]), _num(s[i, 0]), _num(s[i, 1]), _num(s[i, 2]),
             _num(table.elevation_deg[i]), _num(table.cn0_dbhz[i])) for i in range(len(table)))
    return _text(PSEUDORANGE_COLUMNS, rows)


def odometry_csv_text(odometry: OdometryTable) -> str:
    """``odometry.csv`` of ``odometry``: forward speed and yaw rate with their variances (module docstring)."""
    v, w = odometry.speed_m_s, odometry.yaw_rate_rad_s
    vv, vw = odometry.velocity_var_m2_s2[:, 0], odometry.rate_var_rad2_s2[:, 2]
    rows = ((_num(odometry.t_s[i]), _num(v[i]), _num(w[i]), _num(vv[i]), _num(vw[i])) for i in range(len(odometry)))
    return _text(ODOMETRY_COLUMNS, rows)


class _Rows:
    """The data rows of a CSV with exactly ``columns``, and the messages naming file, line and column."""

    def __init__(self, path: Path, columns: tuple):
        self.path = path
        try:
            with open(path, newline="", encoding="utf-8") as fh:
                lines = list(csv.reader(fh))
        except FileNotFoundError:
            raise DataError(f"{path}: file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise DataError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
        if not lines or [c.strip() for c in lines[0]] != list(columns):
            got = ",".join(lines[0]) if lines else "an empty file"
            raise DataError(f"{path}: line 1 must be the header {','.join(columns)}; got {got[:120]!r}")
        self.lines = [(k + 2, r) for k, r in enumerate(lines[1:]) if any(c.strip() for c in r)]
        for lineno, r in self.lines:
            if len(r) != len(columns):
                raise DataError(f"{path}:{lineno}: {len(r)} fields, expected {len(columns)} ({','.join(columns)})")
        if not self.lines:
            raise DataError(f"{path}: no data rows")
        self.columns = columns

    def fail(self, k: int, column: str, why: str):
        lineno, r = self.lines[k]
        raise DataError(f"{self.path}:{lineno}: {column} {why} (line: {','.join(r)[:120]!r})")

    def numbers(self, column: str, *, optional: bool = False) -> np.ndarray:
        """The column as floats; empty → NaN where ``optional``; any other non-finite value refused."""
        j = self.columns.index(column)
        out = np.empty(len(self.lines))
        for k, (_, r) in enumerate(self.lines):
            text = r[j].strip()
            if not text and optional:
                out[k] = np.nan
                continue
            try:
                v = float(text)
            except ValueError:
                self.fail(k, column, f"is not a number: {text!r}")
            if not math.isfinite(v):
                self.fail(k, column, f"is not finite: {text!r}")
            out[k] = v
        return out

    def check(self, column: str, ok: np.ndarray, why: str) -> None:
        """Refuse the first row where ``ok`` is False."""
        bad = np.flatnonzero(~np.asarray(ok, bool))
        if bad.size:
            self.fail(int(bad[0]), column, why)


def read_pseudorange_csv(path: str | os.PathLike, corrections=frozenset({"satellite_clock", "ionosphere",
                                                                           "troposphere"})) -> PseudorangeTable:
    """Read ``gnss_pseudoranges.csv`` (module docstring); ``corrections``: what the pseudoranges have removed
    (from ``walk.toml``). Raises :class:`~features.errors.DataError` naming the first bad line."""
    path = Path(path)
    corrections = frozenset(corrections)
    unknown = sorted(corrections - CORRECTIONS)
    if unknown:
        raise DataError(f"{path}: unknown corrections {unknown}; known: {sorted(CORRECTIONS)}")
    rows = _Rows(path, PSEUDORANGE_COLUMNS)
    t = rows.numbers("t_s")
    rows.check("t_s", np.r_[True, np.diff(t) >= 0], "runs backwards (rows must be in non-decreasing t_s)")
    system = np.array([r[1].strip() for _, r in rows.lines], dtype="<U2")
    rows.check("system", np.isin(system, sorted(_SYSTEMS)), f"must be one of {sorted(_SYSTEMS)}")
    svid = rows.numbers("svid")
    rows.check("svid", (svid == np.round(svid)) & (svid >= 0), "must be an integer >= 0")
    pr = rows.numbers("pseudorange_m")
    var = rows.numbers("pseudorange_var_m2", optional=True)
    rows.check("pseudorange_var_m2", ~(var <= 0), "must be > 0 m² (or empty)")
    sat = np.column_stack([rows.numbers(c) for c in ("sat_x_m", "sat_y_m", "sat_z_m")])
    radius = np.linalg.norm(sat, axis=1)
    rows.check("sat_x_m", (radius >= _SAT_RADIUS_M[0]) & (radius <= _SAT_RADIUS_M[1]),
               "and sat_y_m, sat_z_m put the satellite off any orbit (ECEF metres expected)")
    el = rows.numbers("elevation_deg", optional=True)
    rows.check("elevation_deg", ~((el < -90) | (el > 90)), "must lie in [-90, 90] deg (or be empty)")
    cn0 = rows.numbers("cn0_dbhz", optional=True)
    rows.check("cn0_dbhz", ~((cn0 <= 0) | (cn0 >= 100)), "must lie in (0, 100) dB-Hz (or be empty)")
    key = np.char.add(np.char.add(system.astype(str), ":"), svid.astype(int).astype(str))
    order = np.lexsort((key, t))
    dup = np.zeros(len(t), bool)
    dup[order[1:]] = (t[order][1:] == t[order][:-1]) & (key[order][1:] == key[order][:-1])
    rows.check("svid", ~dup, "repeats a satellite already listed at this t_s")
    return PseudorangeTable(t_s=t, pseudorange_m=pr, pseudorange_var_m2=var, sat_ecef_m=sat,
                            svid=svid.astype(np.int64), system=system.astype("<U1"), elevation_deg=el, cn0_dbhz=cn0,
                            corrections=corrections, source=str(path))


def read_odometry_csv(path: str | os.PathLike) -> OdometryTable:
    """Read ``odometry.csv`` (module docstring) as an :class:`~features.gnss.pseudorange.OdometryTable` (forward
    speed on body x, yaw rate on body z; the other axes zero). Raises
    :class:`~features.errors.DataError` naming the first bad line."""
    path = Path(path)
    rows = _Rows(path, ODOMETRY_COLUMNS)
    t = rows.numbers("t_s")
    rows.check("t_s", np.r_[True, np.diff(t) > 0], "does not increase (rows must be in strictly increasing t_s)")
    v, w = rows.numbers("speed_m_s"), rows.numbers("yaw_rate_rad_s")
    vv, vw = rows.numbers("speed_var_m2_s2"), rows.numbers("yaw_rate_var_rad2_s2")
    rows.check("speed_var_m2_s2", vv >= 0, "must be >= 0")
    rows.check("yaw_rate_var_rad2_s2", vw >= 0, "must be >= 0")
    z = np.zeros(len(t))
    return OdometryTable(t_s=t, velocity_body_m_s=np.column_stack([v, z, z]), rate_body_rad_s=np.column_stack([z, z, w]),
                         velocity_var_m2_s2=np.column_stack([vv, z, z]), rate_var_rad2_s2=np.column_stack([z, z, vw]),
                         source=str(path))
