"""Plain records of the fingerprint library: its error type, a cell's capture, ingest results, receivers.

Kept apart from :mod:`fingerprints.library` (the SQLite access) so that they can be
built and checked without a database.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Sequence

import numpy as np

from features.errors import EnvfuseError
from features.gnss.features import Cn0Reference
from features.site import ENV_CLASSES

from fingerprints.sql import FEATURES

__all__ = ["LibraryError", "CellCapture", "IngestResult", "ReceiverRecord", "capture_sha256", "feature_matrix", "now_utc",
           "parse_iso_utc", "sql_number", "structured_rows"]


class LibraryError(EnvfuseError):
    """A fingerprint library cannot be opened or an operation on it is refused."""


def now_utc() -> str:
    """The current UTC time, ISO 8601 to the second: 2026-12-02T02:08:07Z."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def capture_sha256(gnss_sha256: str | None, audio_sha256: str | None) -> str:
    """Identity of a capture: SHA-256 over its streams' SHA-256s (an absent stream hashes as ``-``)."""
    text = f"gnss:{gnss_sha256 or '-'}\naudio:{audio_sha256 or '-'}\n"
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class CellCapture:
    """One survey cell's metadata, as :meth:`FingerprintLibrary.ingest_cell` stores it.

    ``start_utc`` ISO 8601; ``missing_streams`` names of the absent or unusable
    streams (``"gnss"``, ``"audio"``), ``stream_notes`` why; ``*_sha256`` of the
    stream files (None when missing).
    """

    cell_id: str
    east_m: float
    north_m: float
    start_utc: str
    duration_s: float | None = None
    map_label: str | None = None
    map_share: float | None = None
    missing_streams: tuple[str, ...] = ()
    stream_notes: str = ""
    gnss_sha256: str | None = None
    audio_sha256: str | None = None
    feature_params: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.cell_id, str) or not self.cell_id:
            raise LibraryError(f"cell id must be a non-empty string, got {self.cell_id!r}")
        for name in ("east_m", "north_m"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise LibraryError(f"cell {self.cell_id}: {name} must be a finite number, got {value!r}")
        if self.map_label is not None and self.map_label not in ENV_CLASSES:
            raise LibraryError(f"cell {self.cell_id}: map_label must be one of {ENV_CLASSES}, got {self.map_label!r}")
        if self.map_share is not None and not (isinstance(self.map_share, (int, float))
                                               and 0.0 <= self.map_share <= 1.0):
            raise LibraryError(f"cell {self.cell_id}: map_share must lie in [0, 1], got {self.map_share!r}")
        bad = set(self.missing_streams) - {"gnss", "audio"}
        if bad:
            raise LibraryError(f"cell {self.cell_id}: unknown stream names in missing_streams: {sorted(bad)}")
        parse_iso_utc(self.start_utc, f"cell {self.cell_id} start_utc")

    @property
    def capture_sha256(self) -> str:
        return capture_sha256(self.gnss_sha256, self.audio_sha256)


@dataclass(frozen=True)
class IngestResult:
    """What :meth:`FingerprintLibrary.ingest_cell` did: ``status`` is ``added``, ``unchanged`` or ``replaced``."""

    cell_id: str
    status: str
    n_samples: int


@dataclass(frozen=True)
class ReceiverRecord:
    """A stored receiver: its open-sky C/N0 model and the record of how it was obtained."""

    name: str
    description: str
    reference: Cn0Reference
    reference_info: dict
    calibrated: bool


def parse_iso_utc(text: str, where: str) -> datetime:
    """An ISO 8601 time (``Z`` or an offset) as an aware UTC datetime; LibraryError naming ``where`` if not one."""
    try:
        t = datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    except ValueError:
        raise LibraryError(f"{where} {text!r} is not ISO 8601") from None
    return t if t.tzinfo else t.replace(tzinfo=timezone.utc)


def sql_number(v) -> float | None:
    """A float for SQLite: NaN and ±inf become NULL (a missing feature)."""
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def feature_matrix(samples: np.ndarray) -> np.ndarray:
    """The 14 features of :meth:`FingerprintLibrary.samples` as a float array (n_samples, 14), NaN = missing."""
    if len(samples) == 0:
        return np.zeros((0, len(FEATURES)))
    return np.column_stack([np.asarray(samples[name], dtype=float) for name in FEATURES])


def structured_rows(rows: list[tuple], names: Sequence[str], kinds: str) -> np.ndarray:
    """A structured array from SQL rows; kinds per field: i int64, f float64 (NULL → NaN), b bool, U str (NULL → '')."""
    cols = list(zip(*rows)) if rows else [()] * len(names)
    fields, data = [], []
    for name, kind, col in zip(names, kinds, cols):
        if kind == "f":
            a = np.array([np.nan if v is None else v for v in col], dtype=float)
        elif kind == "i":
            a = np.array(col, dtype=np.int64)
        elif kind == "b":
            a = np.array(col, dtype=bool)
        else:
            a = np.array(["" if v is None else str(v) for v in col], dtype=str)
            if a.dtype.itemsize == 0:
                a = a.astype("U1")
        fields.append((name, a.dtype))
        data.append(a)
    out = np.empty(len(rows), dtype=fields)
    for (name, _), a in zip(fields, data):
        out[name] = a
    return out
