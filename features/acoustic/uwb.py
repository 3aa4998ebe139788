"""Reading DecaWave DecaRanging accumulator logs: measured UWB channel impulse responses.

The DW1000's accumulator holds the complex CIR estimated from the preamble,
sampled at 2 × 499.2 MHz, i.e. every 1.0016 ns (DW1000 User Manual v2.17,
§4.7.1, "Accumulator"). DecaRanging logs each received packet as an
``RX OK`` header, whose ``HLP(…)`` field is the hardware leading-edge
(first-path) index in taps, then ``Accum Len N`` and N lines ``re, im``.

These CIRs go through :func:`features.acoustic.cir.analyse_cirs` unchanged; only the tap
spacing differs from the acoustic CIRs (tests/test_uwb_cir.py).
"""

from __future__ import annotations

import gzip
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from features.errors import DataError

__all__ = ["UwbCirs", "read_decawave_log", "DW1000_TAP_S", "DW1000_PULSE_WIDTH_S"]

DW1000_TAP_S = 1.0 / (2 * 499.2e6)
"""Accumulator tap spacing, s (DW1000 User Manual §4.7.1: two samples per 499.2 MHz chip clock)."""

DW1000_PULSE_WIDTH_S = 2.0e-9
"""Width of one path's lobe for a 499.2 MHz channel (≈ 1/bandwidth), s (channels 1–3, 5)."""

_HLP = re.compile(r"HLP\((\d+(?:\.\d+)?)\)")
_ACCUM = re.compile(r"Accum Len (\d+)")


@dataclass(frozen=True)
class UwbCirs:
    """CIRs of one log: ``cir`` complex (n_packets, n_taps); ``first_path_index`` (n_packets,) from the chip."""

    cir: np.ndarray
    first_path_index: np.ndarray

    @property
    def amplitude(self) -> np.ndarray:
        return np.abs(self.cir)


def read_decawave_log(path: str | os.PathLike, max_packets: int | None = None, every: int = 1) -> UwbCirs:
    """Parse a DecaRanging log (plain or ``.gz``); keep every ``every``-th packet, at most ``max_packets``.

    Packets whose accumulator is cut short are skipped; a file without any
    complete accumulator raises :class:`DataError`.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"UWB log {path} does not exist")
    opener = gzip.open if path.suffix == ".gz" else open
    cirs, fps = [], []
    hlp = None
    packet = 0
    try:
        with opener(path, "rt", errors="replace") as fh:
            for line in fh:
                if line.startswith("RX OK"):
                    m = _HLP.search(line)
                    hlp = float(m.group(1)) if m else None
                    continue
                m = _ACCUM.match(line)
                if m is None:
                    continue
                n = int(m.group(1))
                take = hlp is not None and packet % every == 0
                packet += 1
                rows = [next(fh, "") for _ in range(n)]
                if not take:
                    continue
                try:
                    values = np.array([r.split(",") for r in rows], dtype=float)
                except ValueError:
                    continue
                if values.shape != (n, 2):
                    continue
                cirs.append(values[:, 0] + 1j * values[:, 1])
                fps.append(hlp)
                if max_packets is not None and len(cirs) >= max_packets:
                    break
    except (OSError, EOFError) as exc:
        raise DataError(f"{path}: cannot be read ({exc})") from None
    if not cirs:
        raise DataError(f"{path}: no complete accumulator (CIR) found")
    length = min(len(c) for c in cirs)
    return UwbCirs(np.array([c[:length] for c in cirs]), np.array(fps))
