"""Columns that let other tools join envfuse's tables: UTC time beside ``t_s``, geodetic beside ENU.

Every table the CLI writes has ``time_utc`` (ISO 8601, UTC, milliseconds,
``Z``) right after ``t_s`` — empty when the file's start in UTC is unknown —
and every position file has ``lat_deg``, ``lon_deg`` (WGS-84) and ``h_ell_m``
(ellipsoidal height, m) right after its ENU columns.
"""

from __future__ import annotations

import datetime as dt
import math

import numpy as np

from features.geodesy import enu_to_geodetic
from features.gnss.gpsd import iso_utc_ms

__all__ = ["utc_strings", "with_time_utc", "with_geodetic", "csv_text"]


def utc_strings(t_s, origin_utc: dt.datetime | None) -> list[str]:
    """``origin_utc + t_s`` as ISO 8601 UTC strings with milliseconds ("" where unknown or NaN).

    >>> utc_strings([0.0, 1.5], dt.datetime(2024, 6, 15, 12, tzinfo=dt.timezone.utc))
    ['2024-06-15T12:00:00.000Z', '2024-06-15T12:00:01.500Z']
    >>> utc_strings([3.0], None)
    ['']
    """
    out = []
    for t in np.asarray(t_s, dtype=float).ravel().tolist():
        if origin_utc is None or not math.isfinite(t):
            out.append("")
        else:
            out.append(iso_utc_ms(origin_utc + dt.timedelta(milliseconds=round(t * 1000.0))))
    return out


def _insert_after(names: tuple, after: str, new: tuple) -> tuple:
    i = names.index(after) + 1
    return names[:i] + new + names[i:]


def with_time_utc(names: tuple, columns: dict, origin_utc: dt.datetime | None) -> tuple[tuple, dict]:
    """``names`` and ``columns`` (name → sequence) with ``time_utc`` after ``t_s``."""
    columns = dict(columns)
    columns["time_utc"] = utc_strings(columns["t_s"], origin_utc)
    return _insert_after(tuple(names), "t_s", ("time_utc",)), columns


def with_geodetic(names: tuple, columns: dict, origin, up_m=None) -> tuple[tuple, dict]:
    """Add ``lat_deg``, ``lon_deg``, ``h_ell_m`` after the ENU columns (``up_m`` if present, else
    ``north_m``); ``origin`` is the site origin (lat_deg, lon_deg, alt_m ellipsoidal); ``up_m`` overrides
    the up coordinate (e.g. the device height for a 2-D acoustic fix)."""
    columns = dict(columns)
    after = "up_m" if "up_m" in names else "north_m"
    new = ("lat_deg", "lon_deg", "h_ell_m")
    if origin is None:  # no site: the columns are there, empty
        n = len(columns["east_m"])
        columns.update({k: [""] * n for k in new})
        return _insert_after(tuple(names), after, new), columns
    east = np.asarray(columns["east_m"], dtype=float)
    north = np.asarray(columns["north_m"], dtype=float)
    if up_m is None:
        up = np.asarray(columns["up_m"], dtype=float) if "up_m" in columns else np.zeros_like(east)
    else:
        up = np.broadcast_to(np.asarray(up_m, dtype=float), east.shape)
    if east.size:
        lat, lon, h = enu_to_geodetic(east, north, up, origin.lat_deg, origin.lon_deg, origin.alt_m)
        lat, lon, h = (np.asarray(x, dtype=float).reshape(east.shape) for x in (lat, lon, h))
    else:
        lat = lon = h = np.zeros(0)
    def fmt(x, decimals):  # fixed decimals: 1e-9 deg is 0.1 mm, whatever the longitude's magnitude
        return [f"{v:.{decimals}f}" if math.isfinite(v) else "" for v in x.tolist()]

    columns["lat_deg"], columns["lon_deg"], columns["h_ell_m"] = fmt(lat, 9), fmt(lon, 9), fmt(h, 4)
    return _insert_after(tuple(names), after, new), columns


def _fmt(value, spec: str | None) -> str:
    if isinstance(value, str):
        return value
    if hasattr(value, "item"):
        value = value.item()
    if isinstance(value, float):
        if not math.isfinite(value):
            return ""
        return format(value, spec) if spec else f"{value:.10g}"
    return str(value)


def csv_text(names, columns: dict, formats: dict | None = None) -> str:
    """CSV text of ``columns`` (name → sequence, all one length) in the order ``names``; floats as
    ``formats[name]`` (a format spec) or ``.10g``, NaN/inf as empty, strings as given.

    >>> print(csv_text(("t_s", "x"), {"t_s": [0.5], "x": [float("nan")]}), end="")
    t_s,x
    0.5,
    """
    formats = formats or {}
    lines = [",".join(names)]
    cols = [columns[n] for n in names]
    specs = [formats.get(n) for n in names]
    for row in zip(*cols):
        lines.append(",".join(_fmt(v, f) for v, f in zip(row, specs)))
    return "\n".join(lines) + "\n"
