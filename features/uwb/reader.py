"""Reading a UWB tag's ranging log ``uwb.csv``: one row per anchor measurement.

Columns (header required, any order; extra columns ignored)::

    t_s,anchor,range_m,azimuth_deg,quality

- ``t_s``: seconds since the walk's start (the walk's time base), non-decreasing;
- ``anchor``: the anchor's integer id, as in ``site.toml``'s ``[[uwb_anchors]]``;
- ``range_m``: the two-way-ranging (DS-TWR) distance anchor–tag, metres (slant range, 3-D);
- ``azimuth_deg``: the tag's angle of arrival **measured at the anchor** by phase difference of arrival
  (PDoA) across the anchor's antenna pair, degrees, relative to the anchor's boresight
  (``boresight_deg`` in ``site.toml``), **positive clockwise seen from above** (towards the anchor's right
  when looking along its boresight). The tag's bearing from the anchor is therefore
  ``boresight_deg + azimuth_deg``, clockwise from north. This is how DW3000 PDoA systems work: the
  anchor (e.g. Qorvo's DWM3000 PDoA node, two receive antennas) holds the array and reports the angle in
  its own frame, unambiguous over its front half-plane (−90°..+90°); a tag behind the array is reported at
  its mirror image. Empty when the anchor has no array or the angle was not measured;
- ``quality``: the device's own line-of-sight indicator, dB: first-path power minus total received
  power (DW3000 User Manual §4.7.1–4.7.2, "first path power level" and "RX level" from the CIR; Qorvo
  application note APS006 Part 2: a difference under 6 dB suggests LOS, over 10 dB NLOS). It is ≤ 0;
  near 0 in line of sight. Empty when the device does not report it.

A line that does not parse (wrong field count, a non-number, a range that is not finite and positive)
is skipped and counted in :attr:`UwbLog.n_bad_lines`; a file that cannot be used at all (missing,
not text, without the columns, with no usable row, with times going backwards) raises one
:class:`~features.errors.UwbError` naming the file (and the line).
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from features.errors import UwbError
from features.fileio import atomic_write_text

__all__ = ["UwbLog", "read_uwb", "write_uwb", "UWB_COLUMNS"]

UWB_COLUMNS = ("t_s", "anchor", "range_m", "azimuth_deg", "quality")
"""The columns of ``uwb.csv``, in the order the simulator writes them."""

_REQUIRED = ("t_s", "anchor", "range_m")
"""Columns without which a row is no measurement; ``azimuth_deg`` and ``quality`` may be absent."""


@dataclass(frozen=True)
class UwbLog:
    """A UWB ranging log: arrays of shape (n,), sorted by time.

    ``azimuth_deg`` and ``quality`` are NaN where the row has none (module docstring for their meaning).
    """

    t_s: np.ndarray
    anchor: np.ndarray
    range_m: np.ndarray
    azimuth_deg: np.ndarray
    quality: np.ndarray
    n_bad_lines: int = 0

    def __len__(self) -> int:
        return int(self.t_s.size)

    @property
    def anchors(self) -> np.ndarray:
        """The anchor ids heard, sorted, shape (n_anchors,)."""
        return np.unique(self.anchor)


def _number(text: str | None) -> float:
    if text is None:
        raise ValueError("missing field")
    text = text.strip()
    return math.nan if text == "" else float(text)


def read_uwb(path: str | os.PathLike) -> UwbLog:
    """Read ``uwb.csv`` (or a walk directory holding one) into a :class:`UwbLog`."""
    path = Path(path)
    if path.is_dir():
        path = path / "uwb.csv"
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise UwbError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise UwbError(f"{path}: is a directory, expected a UWB CSV file") from None
    except UnicodeDecodeError:
        raise UwbError(f"{path}: not a text CSV file (not UTF-8)") from None
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None:
        raise UwbError(f"{path}: empty file; need columns {', '.join(UWB_COLUMNS)}")
    header = [h.strip().lower() for h in header]
    missing = [c for c in _REQUIRED if c not in header]
    if missing:
        raise UwbError(f"{path}: missing required column(s) {', '.join(missing)} (have: "
                       f"{', '.join(header)[:120] or 'none'}; need {', '.join(UWB_COLUMNS)})")
    col = {name: i for i, name in enumerate(header)}
    rows, n_bad = [], 0
    for line_no, parts in enumerate(reader, start=2):
        if not parts or (len(parts) == 1 and not parts[0].strip()) or parts[0].lstrip().startswith("#"):
            continue
        if len(parts) != len(header):
            n_bad += 1
            continue
        try:
            t, a, r = (_number(parts[col[c]]) for c in _REQUIRED)
            az = _number(parts[col["azimuth_deg"]]) if "azimuth_deg" in col else math.nan
            q = _number(parts[col["quality"]]) if "quality" in col else math.nan
        except ValueError:
            n_bad += 1
            continue
        if not (math.isfinite(t) and math.isfinite(a) and a == int(a) and a >= 0 and math.isfinite(r) and r > 0
                and not math.isinf(az) and not math.isinf(q)):
            n_bad += 1
            continue
        rows.append((line_no, t, a, r, az, q))
    if not rows:
        raise UwbError(f"{path}: no usable row ({n_bad} malformed line(s)); need {', '.join(UWB_COLUMNS)} "
                       f"with a finite time, an integer anchor id and a positive range")
    data = np.asarray(rows, dtype=float)
    back = np.flatnonzero(np.diff(data[:, 1]) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise UwbError(f"{path}: line {int(data[i, 0])}: t_s {data[i, 1]:g} goes back in time (previous "
                       f"{data[i - 1, 1]:g}); a UWB log is written in time order")
    return UwbLog(t_s=data[:, 1], anchor=data[:, 2].astype(int), range_m=data[:, 3], azimuth_deg=data[:, 4],
                  quality=data[:, 5], n_bad_lines=n_bad)


def _field(x: float, fmt: str) -> str:
    return "" if not math.isfinite(x) else format(x, fmt)


def write_uwb(path: str | os.PathLike, log: UwbLog) -> None:
    """Write ``log`` as ``uwb.csv`` (ranges to the mm, angles to 0.1°, quality to 0.1 dB), atomically."""
    lines = [",".join(UWB_COLUMNS)]
    lines += [f"{t:.3f},{int(a)},{r:.3f},{_field(az, '.1f')},{_field(q, '.1f')}"
              for t, a, r, az, q in zip(log.t_s, log.anchor, log.range_m, log.azimuth_deg, log.quality)]
    atomic_write_text(path, "\n".join(lines) + "\n")
