"""A fused track: one method's positions over a walk, and how it is written (CSV or GeoJSON).

The track file has one row per instant of the filter's events, the state after the last event at that
time (:func:`latest_per_time`; one row per fix for a single source),
columns :data:`TRACK_COLUMNS`: walk time ``t_s``, ``time_utc`` (ISO 8601,
milliseconds), site ENU, WGS-84 latitude / longitude and ellipsoidal height,
the position covariance, the environment class the classifier gave and its
probability, whether that window was out of the classifier's distribution,
the NIS of the fix and the BP correction applied. GeoJSON carries the same as
a LineString of the whole track plus one Point per row.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from datetime import timedelta

import numpy as np

from features.geodesy import enu_to_geodetic
from features.schema import ENV_CLASSES

__all__ = ["Track", "TRACK_COLUMNS", "POSITION_COLUMNS", "latest_per_time", "track_rows", "track_columns", "rows_from_columns",
           "position_columns", "track_text", "TrackWriter"]

TRACK_COLUMNS = ("t_s", "time_utc", "east_m", "north_m", "lat_deg", "lon_deg", "h_ell_m", "var_east_m2",
                 "cov_en_m2", "var_north_m2", "env_class", "class_probability", "ood", "nis", "bp_correction_m")
"""Columns of a written track, in order."""


@dataclass
class Track:
    """One method's output: positions at ``t_s`` (m,), covariance ``cov_m2`` (m, 2, 2) or None, and per-epoch
    extras in ``info`` (``nis``, ``bp_delta_m``, ``class_proba``, ``run``, ...)."""

    method: str
    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    cov_m2: np.ndarray | None
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def take(self, keep: np.ndarray) -> "Track":
        """The epochs where ``keep`` (bool, (m,)) holds, with the per-epoch arrays of ``info`` (``nis``,
        ``bp_delta_m``, ``class_proba``, ...) cut alike; ``info`` entries that are not per-epoch (the filter
        ``run``, shares) are dropped."""
        keep = np.asarray(keep, bool)
        n = len(self)
        info = {k: v[keep] for k, v in self.info.items() if isinstance(v, np.ndarray) and v.shape[:1] == (n,)}
        return Track(self.method, self.t_s[keep], self.east_m[keep], self.north_m[keep],
                     None if self.cov_m2 is None else self.cov_m2[keep], info)


def latest_per_time(t_s: np.ndarray) -> np.ndarray:
    """Which epochs of a track (time-ordered ``t_s`` (m,)) are the last at their instant, bool (m,).

    A filter run has a state after every event, and a step's piece ending at a fix (:func:`walks.inputs.split_steps`)
    and the fix are two events at one instant: the first state is superseded before the instant is over. A track
    is written and scored at the last state of each instant only. Before 2026-12-03 it kept both: a third of a
    filter's rows repeated a time, and its errors at fix instants (the lowest, a fix just fused) counted twice, which
    flattered the filters against the single sources (one row per fix): on a 200 s walk ``adaptive``'s mean error
    0.098 m with the repeats, 0.115 m without; ``adaptive+lag`` (two equal rows) 0.086 → 0.108 m."""
    t = np.asarray(t_s, float)
    return np.r_[t[1:] != t[:-1], True] if t.size else np.zeros(0, bool)


def track_rows(track: Track, inputs, up_m: float = 0.0) -> list[dict]:
    """Rows of :data:`TRACK_COLUMNS` for ``track`` of the walk behind ``inputs`` (:class:`walks.inputs.WalkInputs`).

    Heights: the track is horizontal; ``h_ell_m`` is the site origin's height plus ``up_m`` (the device
    height above the origin is not estimated).
    """
    return rows_from_columns(track_columns(track, inputs, up_m))


def track_columns(track: Track, inputs, up_m: float = 0.0) -> dict:
    """:func:`track_rows`'s values column by column: (m,) arrays, the text columns as (m,) lists."""
    data = inputs.data
    n = len(track.t_s)
    proba = np.asarray(inputs.classes.at(track.t_s))
    c = np.argmax(proba, axis=1)
    bp = track.info.get("bp_delta_m")
    start = data.walk.start_utc
    return {"t_s": track.t_s,
            "time_utc": [""] * n if start is None else
            [_iso_ms(start + timedelta(seconds=t)) for t in np.asarray(track.t_s, float).tolist()],
            **position_columns(track.east_m, track.north_m, track.cov_m2, data.site.origin, up_m),
            "env_class": [ENV_CLASSES[k] for k in c.tolist()],
            "class_probability": proba[np.arange(n), c],
            "ood": np.asarray(inputs.ood_at(track.t_s), bool),
            "nis": track.info.get("nis", np.full(n, np.nan)),
            "bp_correction_m": np.hypot(bp[:, 0], bp[:, 1]) if bp is not None else np.zeros(n)}


def rows_from_columns(columns: dict) -> list[dict]:
    """Rows (dicts in :data:`TRACK_COLUMNS` order, Python values) of :func:`track_columns`' columns, or of any
    arrays of those columns (numbers as floats, ``ood`` as bool, text as text)."""
    def values(k):
        v = columns[k]
        if isinstance(v, list):
            return v
        v = np.asarray(v)
        return v.astype(bool).tolist() if k == "ood" else v.tolist() if v.dtype.kind == "U" else \
            v.astype(float).tolist()

    return [dict(zip(TRACK_COLUMNS, row)) for row in zip(*(values(k) for k in TRACK_COLUMNS))]


POSITION_COLUMNS = ("east_m", "north_m", "lat_deg", "lon_deg", "h_ell_m", "var_east_m2", "cov_en_m2", "var_north_m2")
"""The columns of :data:`TRACK_COLUMNS` a track's position and covariance give (:func:`position_columns`)."""


def position_columns(east_m: np.ndarray, north_m: np.ndarray, cov_m2: np.ndarray | None, origin,
                     up_m: float = 0.0) -> dict:
    """:data:`POSITION_COLUMNS` of track rows, (m,) each: site ENU, WGS-84 at the site ``origin`` (its
    ``lat_deg``, ``lon_deg``, ``alt_m``; ``up_m`` above it) and the covariance's entries (NaN without one)."""
    n = len(east_m)
    lat, lon, h = enu_to_geodetic(east_m, north_m, np.full(n, float(up_m)), origin.lat_deg, origin.lon_deg,
                                  origin.alt_m)
    cov = cov_m2 if cov_m2 is not None else np.full((n, 2, 2), np.nan)
    return dict(zip(POSITION_COLUMNS, (east_m, north_m, lat, lon, h, cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1])))


def _iso_ms(t) -> str:
    """ISO 8601 UTC with milliseconds: 2024-05-01T08:00:00.200Z."""
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v + 0.0:.10g}"       # (+ 0.0: −0.0, a time rounded to 0, reads "0")
    return str(v)


def track_text(rows: list[dict], fmt: str, properties: dict | None = None) -> str:
    """The track as ``"csv"`` (header + one line per row; booleans ``true``/``false``, NaN empty) or
    ``"geojson"`` (a FeatureCollection: the LineString with ``properties``, then one Point per row)."""
    if fmt == "csv":
        return ",".join(TRACK_COLUMNS) + "\n" + "".join(",".join(_fmt(r[k]) for k in TRACK_COLUMNS) + "\n"
                                                        for r in rows)
    if fmt != "geojson":
        raise ValueError(f"track format must be 'csv' or 'geojson', got {fmt!r}")
    line = {"type": "Feature",
            "geometry": {"type": "LineString",
                         "coordinates": [[round(r["lon_deg"], 9), round(r["lat_deg"], 9)] for r in rows]},
            "properties": dict(properties or {}, start_utc=rows[0]["time_utc"] if rows else None)}
    points = [_point(r) for r in rows]
    return json.dumps({"type": "FeatureCollection", "features": [line] + points}, allow_nan=False) + "\n"


class TrackWriter:
    """:func:`track_text` written a block of rows at a time to ``path`` (the caller's temporary file): the same
    bytes as ``track_text`` of all the rows at once, holding none of them. GeoJSON's LineString, which comes
    before the points, is gathered in a side file beside ``path`` and the two joined by :meth:`close`.

    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
    >>> w = TrackWriter(p, "csv"); w.close(); p.read_text() == track_text([], "csv")
    True
    """

    def __init__(self, path, fmt: str, properties: dict | None = None):
        if fmt not in ("csv", "geojson"):
            raise ValueError(f"track format must be 'csv' or 'geojson', got {fmt!r}")
        self.path, self.fmt, self.properties = path, fmt, dict(properties or {})
        self.n = 0
        self._first_utc = None
        self._fh = open(path, "w", encoding="utf-8")
        if fmt == "csv":
            self._fh.write(",".join(TRACK_COLUMNS) + "\n")
        else:
            self._line = open(f"{path}.line", "w+", encoding="utf-8")

    def write(self, rows: list[dict]) -> None:
        """Append ``rows`` (:func:`track_rows`)."""
        if not rows:
            return
        if self.fmt == "csv":
            self._fh.write("".join(",".join(_fmt(r[k]) for k in TRACK_COLUMNS) + "\n" for r in rows))
        else:
            if self.n == 0:
                self._first_utc = rows[0]["time_utc"]
            sep = ", " if self.n else ""
            self._line.write(sep + ", ".join(json.dumps([round(r["lon_deg"], 9), round(r["lat_deg"], 9)])
                                             for r in rows))
            self._fh.write(", " + ", ".join(json.dumps(_point(r), allow_nan=False) for r in rows))
        self.n += len(rows)

    def close(self) -> None:
        """Finish the file (GeoJSON: the LineString, then the points)."""
        self._fh.close()
        if self.fmt == "csv":
            return
        line = {"type": "Feature", "geometry": {"type": "LineString", "coordinates": []},
                "properties": dict(self.properties, start_utc=self._first_utc)}
        head, tail = json.dumps(line, allow_nan=False).split('"coordinates": []', 1)
        points = f"{self.path}.points"
        os.replace(self.path, points)
        try:
            with open(self.path, "w", encoding="utf-8") as out:
                out.write('{"type": "FeatureCollection", "features": [' + head + '"coordinates": [')
                self._line.seek(0)
                _copy(self._line, out)
                out.write("]" + tail)
                with open(points, encoding="utf-8") as fh:
                    _copy(fh, out)
                out.write("]}\n")
        finally:
            self._line.close()
            os.unlink(f"{self.path}.line")
            os.unlink(points)


def _copy(src, dst, block: int = 1 << 20) -> None:
    while chunk := src.read(block):
        dst.write(chunk)


def _point(r: dict) -> dict:
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [round(r["lon_deg"], 9),
                                                                             round(r["lat_deg"], 9)]},
            "properties": {k: (None if isinstance(r[k], float) and math.isnan(r[k]) else r[k])
                           for k in TRACK_COLUMNS if k not in ("lat_deg", "lon_deg")}}
