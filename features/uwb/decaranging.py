"""Ranges and line-of-sight levels from DecaWave DecaRanging logs (EVK1000, DW1000; gzip or plain text).

DecaRanging writes, per two-way ranging exchange, a line
``Anchor ToF: 8.986 ns Dist: 2.693148 m DistRaw: 2.603148 m ... Bias: -0.090 m ...`` (``Dist`` the range it
reports, ``DistRaw`` before its range-bias correction for the received level, DW1000 APS011), and per
received packet an ``RX OK ... RSL(-078.9641), FSL(-081.7507) ...`` header: the received and first-path
signal levels in dBm (DW1000 User Manual §4.7.1–4.7.2). ``FSL − RSL`` is the same first-path/received
ratio ``uwb.csv`` carries as ``quality`` (:mod:`features.uwb.reader`).
"""

from __future__ import annotations

import gzip
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from features.errors import UwbError

__all__ = ["DecaRangingLog", "read_decaranging"]

_DIST = re.compile(rb"Dist:\s*(-?[0-9.]+)\s*m\s+DistRaw:\s*(-?[0-9.]+)\s*m")
_LEVELS = re.compile(rb"RSL\((-?[0-9.]+)\),\s*FSL\((-?[0-9.]+)\)")


@dataclass(frozen=True)
class DecaRangingLog:
    """``dist_m``, ``dist_raw_m``: the ranges, shape (n,); ``rsl_dbm``, ``fsl_dbm``: received and first-path
    levels per packet, shape (m,)."""

    dist_m: np.ndarray
    dist_raw_m: np.ndarray
    rsl_dbm: np.ndarray
    fsl_dbm: np.ndarray

    @property
    def fp_minus_rx_db(self) -> np.ndarray:
        """First-path minus received level, dB, shape (m,) (``quality`` of ``uwb.csv``)."""
        return self.fsl_dbm - self.rsl_dbm


def read_decaranging(path: str | os.PathLike) -> DecaRangingLog:
    """Read the ranges and levels of a DecaRanging log (``.gz`` read compressed); a log without a single
    ``Dist:`` line raises :class:`~features.errors.UwbError`.

    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "x.log"
    >>> _ = p.write_bytes(b"RX OK WInd(0735), RSL(-078.96), FSL(-081.75), RSMPL(31)\\n"
    ...                   b"Anchor ToF: 8.986 ns Dist: 2.693148 m DistRaw: 2.603148 m Bias: -0.090 m\\n")
    >>> log = read_decaranging(p)
    >>> float(log.dist_m[0]), round(float(log.fp_minus_rx_db[0]), 2)
    (2.693148, -2.79)
    """
    path = Path(path)
    try:
        opener = gzip.open if path.suffix == ".gz" else open
        with opener(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise UwbError(f"{path}: file not found") from None
    except (OSError, EOFError) as exc:
        raise UwbError(f"{path}: cannot be read ({exc})") from None
    dist = np.array([[float(a), float(b)] for a, b in _DIST.findall(data)]).reshape(-1, 2)
    if not len(dist):
        raise UwbError(f"{path}: no 'Dist: … m DistRaw: … m' ranging line; not a DecaRanging log")
    lv = np.array([[float(a), float(b)] for a, b in _LEVELS.findall(data)]).reshape(-1, 2)
    return DecaRangingLog(dist_m=dist[:, 0], dist_raw_m=dist[:, 1], rsl_dbm=lv[:, 0], fsl_dbm=lv[:, 1])
