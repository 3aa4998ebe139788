"""Reading DecaWave DecaRanging accumulator logs: measured UWB channel impulse responses.

The DW1000's accumulator holds the complex CIR estimated from the preamble,
sampled at 2 × 499.2 MHz, i.e. every 1.0016 ns (DW1000 User Manual v2.17,
§4.7.1, "Accumulator"). DecaRanging logs each received packet as an
``RX OK`` header, whose ``HLP(…)`` field is the hardware leading-edge
(first-path) index in taps, then ``Accum Len N`` and N lines ``re, im``.

These CIRs go through :func:`features.acoustic.cir.analyse_cirs` unchanged; only the tap
spacing differs from the acoustic CIRs (tests/test_uwb_cir.py): :func:`uwb_cir_features`.
:func:`read_labelled_uwb` reads a labelled folder (``labels.csv``, ``pairs.csv``, as in the
Kolakowski & Modelski dataset) into one feature row per packet (bench/uwb_clustering.py).
"""

from __future__ import annotations

import gzip
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from features.acoustic.cir import CirBatch, analyse_cirs
from features.errors import DataError

__all__ = ["UwbCirs", "read_decawave_log", "DW1000_TAP_S", "DW1000_PULSE_WIDTH_S", "UWB_MAX_LEAD_S",
           "uwb_cir_features", "LabelledUwbFeatures", "read_labelled_uwb"]

DW1000_TAP_S = 1.0 / (2 * 499.2e6)
"""Accumulator tap spacing, s (DW1000 User Manual §4.7.1: two samples per 499.2 MHz chip clock)."""

DW1000_PULSE_WIDTH_S = 2.0e-9
"""Width of one path's lobe for a 499.2 MHz channel (≈ 1/bandwidth), s (channels 1–3, 5)."""

UWB_MAX_LEAD_S = 20e-9
"""How far before the strongest tap the leading edge is sought, s (20 taps, 6 m of excess path): the
setting under which our first arrival lands within 1–2 taps of the chip's own HLP (tests/test_uwb_cir.py)."""

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


def uwb_cir_features(cirs: UwbCirs) -> CirBatch:
    """The nine CIR features (:data:`features.acoustic.cir.FEATURE_NAMES`) of every packet of ``cirs``:
    :func:`features.acoustic.cir.analyse_cirs` with the DW1000 tap spacing, lobe width and
    :data:`UWB_MAX_LEAD_S`, the same definitions as the acoustic CIR features."""
    return analyse_cirs(cirs.amplitude, DW1000_TAP_S, max_lead_s=UWB_MAX_LEAD_S, pulse_width_s=DW1000_PULSE_WIDTH_S)


@dataclass(frozen=True)
class LabelledUwbFeatures:
    """CIR features of a labelled UWB log folder, one row per packet.

    ``features`` (n, 9) in :data:`features.acoustic.cir.FEATURE_NAMES` order (all finite);
    ``label`` (n,) str (LOS / NLOS / NDP NLOS); ``file_id``, ``anchor``, ``tag`` (n,) int, the log,
    anchor location and tag location of each packet; ``n_dropped``: packets read but left out
    because the CIR gave no valid arrival or a NaN feature (a single selected tap has no spread).
    """

    features: np.ndarray
    label: np.ndarray
    file_id: np.ndarray
    anchor: np.ndarray
    tag: np.ndarray
    n_dropped: int


def _csv_map(path: Path, key: str, *values: str) -> dict[int, tuple[str, ...]]:
    import csv

    if not path.is_file():
        raise DataError(f"{path} does not exist")
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    try:
        return {int(r[key]): tuple(r[v] for v in values) for r in rows}
    except (KeyError, ValueError) as exc:
        raise DataError(f"{path}: expected columns {key}, {', '.join(values)} ({exc})") from None


def read_labelled_uwb(folder: str | os.PathLike, packets_per_file: int | None = None,
                      random_state: int | None = 0) -> LabelledUwbFeatures:
    """Features of every ``<id>.log.gz`` in ``folder`` with its label (``labels.csv``: file_id, label)
    and geometry (``pairs.csv``: file_number, anchor_location, tag_location), as in the
    Kolakowski & Modelski (MIKON 2018) dataset layout.

    ``packets_per_file``: keep at most this many valid packets of each log, drawn without
    replacement by ``numpy.random.default_rng(random_state)`` (files in id order); None keeps all.
    """
    folder = Path(folder)
    labels = _csv_map(folder / "labels.csv", "file_id", "label")
    pairs = _csv_map(folder / "pairs.csv", "file_number", "anchor_location", "tag_location")
    logs = sorted(folder.glob("*.log.gz"), key=lambda p: int(p.name.split(".")[0]))
    if not logs:
        raise DataError(f"{folder}: no <id>.log.gz UWB logs")
    rng = np.random.default_rng(random_state)
    feats, lab, fid, anc, tag = [], [], [], [], []
    dropped = 0
    for path in logs:
        i = int(path.name.split(".")[0])
        if i not in labels or i not in pairs:
            raise DataError(f"{path.name}: file id {i} missing from labels.csv or pairs.csv")
        batch = uwb_cir_features(read_decawave_log(path))
        ok = np.flatnonzero(batch.valid & np.all(np.isfinite(batch.features), axis=1))
        dropped += len(batch.valid) - len(ok)
        if packets_per_file is not None and len(ok) > packets_per_file:
            ok = np.sort(rng.choice(ok, packets_per_file, replace=False))
        feats.append(batch.features[ok])
        lab += [labels[i][0]] * len(ok)
        fid += [i] * len(ok)
        anc += [int(pairs[i][0])] * len(ok)
        tag += [int(pairs[i][1])] * len(ok)
    return LabelledUwbFeatures(np.concatenate(feats), np.array(lab), np.array(fid), np.array(anc), np.array(tag),
                               dropped)
