"""The fingerprint library: one SQLite file of sites, receivers, cells, samples and clustering runs.

Schema and feature order: :mod:`fingerprints.sql`. Guarantees:

* **WAL mode, foreign keys on, synchronous=FULL**: a committed cell survives a
  killed process (and a power cut); readers never block the writer.
* **Schema version checked on open**: a file that is not an SQLite database,
  an SQLite file of another application, or a library of another schema
  version is refused with :class:`LibraryError` — never modified.
* **One transaction per cell** in :meth:`FingerprintLibrary.ingest_cell`:
  a cell and all its samples are committed together or not at all; ingesting
  the same capture (same ``capture_sha256``) again adds nothing.

>>> import tempfile, os
>>> path = os.path.join(tempfile.mkdtemp(), "fp.sqlite")
>>> with FingerprintLibrary.open(path) as lib:
...     _ = lib.add_site("demo", lat_deg=30.0, lon_deg=114.0, alt_m=20.0, site_toml_sha256="0" * 64)
...     lib.ingest_cell("demo", CellCapture("E000N000", 5.0, 5.0, "2026-06-01T08:00:00Z", gnss_sha256="1" * 64),
...                     {"t_s": [1.0, 2.0], "att_mean_db": [3.5, 4.0], "gnss_available": [1, 1]}).status
'added'
>>> with FingerprintLibrary.open(path, create=False) as lib:
...     s = lib.samples()
...     s["cell_id"].tolist(), s["att_mean_db"].tolist(), bool(np.isnan(s["rms_delay_ms"]).all())
(['E000N000', 'E000N000'], [3.5, 4.0], True)
"""

from __future__ import annotations

import contextlib
import csv
import functools
import json
import os
import sqlite3
from datetime import timedelta
from pathlib import Path
from typing import Iterator, Mapping, Sequence

import numpy as np

from features.fileio import atomic_path
from features.gnss.features import Cn0Reference

from fingerprints.records import (
    CellCapture, IngestResult, LibraryError, ReceiverRecord, capture_sha256, feature_matrix, now_utc, parse_iso_utc,
    sql_number, structured_rows,
)
from fingerprints.runs import ClusteringRunsMixin
from fingerprints.sql import (
    ACOUSTIC_COUNTS, APPLICATION_ID, DDL, FEATURES, GNSS_COUNTS, SAMPLE_COLUMNS, SCHEMA_VERSION,
)

__all__ = ["LibraryError", "CellCapture", "IngestResult", "ReceiverRecord", "FingerprintLibrary",
           "feature_matrix", "capture_sha256", "EXPORT_COLUMNS"]

EXPORT_COLUMNS = (("site", "receiver", "cell_id", "east_m", "north_m", "map_label", "map_share", "sample_id")
                  + SAMPLE_COLUMNS)
"""Columns of :meth:`FingerprintLibrary.export_csv`, in order (one row per sample)."""

_SQLITE_MAGIC = b"SQLite format 3\x00"


def _same_params(stored_json: str, params: Mapping) -> bool:
    """Whether the feature parameters stored as JSON are ``params``: compared as parsed JSON objects, so the
    text's key order (an older writer, another tool, a hand edit) and spacing do not matter."""
    try:
        stored = json.loads(stored_json)
    except (TypeError, ValueError):
        return False
    return stored == json.loads(json.dumps(dict(params)))


def _reads(method):
    """A read of the library: an SQLite error (a damaged file) becomes one :class:`LibraryError` naming it."""
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except sqlite3.DatabaseError as exc:
            raise LibraryError(f"{self.path}: cannot read the library ({exc}); the file is damaged") from None
    return wrapper


class FingerprintLibrary(ClusteringRunsMixin):
    """A fingerprint library file. Open with :meth:`open` (a context manager); never construct directly."""

    def __init__(self, conn: sqlite3.Connection, path: Path):
        self._conn = conn
        self.path = path

    # ---------------------------------------------------------------- opening
    @classmethod
    def open(cls, path: str | os.PathLike, *, create: bool = True) -> "FingerprintLibrary":
        """Open (or, with ``create``, make) the library at ``path``; use as ``with FingerprintLibrary.open(p) as lib``.

        Raises :class:`LibraryError` for a directory, a missing file when not
        ``create``, a file that is not an envfuse library, or a schema version
        other than :data:`~fingerprints.sql.SCHEMA_VERSION`.
        """
        path = Path(path)
        if path.is_dir():
            raise LibraryError(f"{path}: is a directory, expected a fingerprint library file")
        exists = path.exists() and path.stat().st_size > 0
        if not exists and not create:
            raise LibraryError(f"{path}: no fingerprint library there (build one with 'envfuse survey build')")
        if exists:
            try:
                with open(path, "rb") as fh:
                    head = fh.read(len(_SQLITE_MAGIC))
            except OSError as exc:
                raise LibraryError(f"{path}: cannot read ({exc.strerror or exc})") from None
            if head != _SQLITE_MAGIC:
                raise LibraryError(f"{path}: is not a fingerprint library (not an SQLite database)")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            conn = sqlite3.connect(path, isolation_level=None, timeout=30.0)
        except (OSError, sqlite3.Error) as exc:
            raise LibraryError(f"{path}: cannot open ({exc})") from None
        try:
            cls._prepare(conn, path)
        except BaseException:
            conn.close()
            raise
        return cls(conn, path)

    @staticmethod
    def _prepare(conn: sqlite3.Connection, path: Path) -> None:
        try:
            app_id = conn.execute("PRAGMA application_id").fetchone()[0]
            version = conn.execute("PRAGMA user_version").fetchone()[0]
            n_objects = conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            raise LibraryError(f"{path}: is not a readable fingerprint library ({exc})") from None
        fresh = app_id == 0 and version == 0 and n_objects == 0
        if not fresh:
            if app_id != APPLICATION_ID:
                raise LibraryError(f"{path}: is an SQLite database but not an envfuse fingerprint library "
                                   f"(application_id {app_id:#x}, expected {APPLICATION_ID:#x})")
            if version > SCHEMA_VERSION:
                raise LibraryError(f"{path}: written by a newer envfuse (library schema version {version}; this "
                                   f"version reads {SCHEMA_VERSION}); upgrade envfuse to use it")
            if version != SCHEMA_VERSION:
                raise LibraryError(f"{path}: unknown library schema version {version} (this envfuse reads "
                                   f"version {SCHEMA_VERSION})")
        try:
            mode = conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise LibraryError(f"{path}: cannot switch the library to WAL mode (got {mode!r}); "
                                   "is it on a network file system?")
            conn.execute("PRAGMA synchronous=FULL")
            conn.execute("PRAGMA foreign_keys=ON")
            if fresh:
                conn.execute("BEGIN IMMEDIATE")
                try:
                    # another process may have created the library while this one waited for the lock
                    if conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0] == 0:
                        for statement in DDL.split(";"):
                            if statement.strip():
                                conn.execute(statement)
                        conn.execute(f"PRAGMA application_id={APPLICATION_ID}")
                        conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
                    conn.execute("COMMIT")
                except BaseException:
                    conn.execute("ROLLBACK")
                    raise
        except sqlite3.Error as exc:
            raise LibraryError(f"{path}: cannot prepare the library ({exc})") from None
        if fresh and conn.execute("PRAGMA user_version").fetchone()[0] != SCHEMA_VERSION:
            FingerprintLibrary._prepare(conn, path)  # created by another process meanwhile: check it as found

    def close(self) -> None:
        """Close the connection (committed data is already on disk)."""
        self._conn.close()

    def __enter__(self) -> "FingerprintLibrary":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE … COMMIT, rolled back on any error; SQLite errors become :class:`LibraryError`."""
        try:
            self._conn.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise LibraryError(f"{self.path}: cannot start a transaction ({exc})") from None
        try:
            yield self._conn
        except BaseException as exc:
            self._conn.execute("ROLLBACK")
            if isinstance(exc, sqlite3.Error):
                raise LibraryError(f"{self.path}: {exc}") from None
            raise
        else:
            try:
                self._conn.execute("COMMIT")
            except sqlite3.Error as exc:
                self._conn.execute("ROLLBACK")
                raise LibraryError(f"{self.path}: commit failed ({exc})") from None

    # ---------------------------------------------------------------- sites, receivers
    @property
    def schema_version(self) -> int:
        return int(self._conn.execute("PRAGMA user_version").fetchone()[0])

    @_reads
    def sites(self) -> list[str]:
        """Names of the sites in the library, sorted."""
        return [r[0] for r in self._conn.execute("SELECT name FROM sites ORDER BY name")]

    def _site_id(self, site: str) -> int:
        row = self._conn.execute("SELECT site_id FROM sites WHERE name = ?", (site,)).fetchone()
        if row is None:
            known = ", ".join(self.sites()) or "none"
            raise LibraryError(f"{self.path}: no site named {site!r} (sites: {known})")
        return int(row[0])

    def add_site(self, name: str, *, lat_deg: float, lon_deg: float, alt_m: float, site_toml_sha256: str) -> int:
        """Add a site (or find it: same name and same ``site.toml`` hash); returns its ``site_id``.

        The same name with another ``site.toml`` hash is refused: its cells'
        positions would refer to another layout or origin.
        """
        with self._transaction() as conn:
            row = conn.execute("SELECT site_id, site_toml_sha256 FROM sites WHERE name = ?", (name,)).fetchone()
            if row is not None:
                if row[1] != site_toml_sha256:
                    raise LibraryError(f"{self.path}: site {name!r} is already in the library from another "
                                       f"site.toml (sha256 {row[1][:12]}..., now {site_toml_sha256[:12]}...)")
                return int(row[0])
            cur = conn.execute("INSERT INTO sites (name, lat_deg, lon_deg, alt_m, site_toml_sha256, created_utc) "
                               "VALUES (?, ?, ?, ?, ?, ?)",
                               (name, float(lat_deg), float(lon_deg), float(alt_m), site_toml_sha256, now_utc()))
            return int(cur.lastrowid)

    def add_receiver(self, site: str, name: str, cn0_reference: Mapping, *, calibrated: bool,
                     description: str = "") -> int:
        """Add a receiver of ``site`` with its C/N0 reference (or find the identical one); returns its id.

        ``cn0_reference``: a JSON-serialisable mapping holding at least
        ``intercept_dbhz`` and ``slope_dbhz`` (:class:`Cn0Reference` fields) and,
        from a calibration, the per-bin values and the rule. A receiver already
        stored with a different reference is refused (its samples were computed
        with the stored one).
        """
        Cn0Reference.from_dict(dict(cn0_reference))  # validates the line parameters
        try:
            text = json.dumps(dict(cn0_reference), sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise LibraryError(f"receiver {name!r}: C/N0 reference is not plain JSON ({exc})") from None
        with self._transaction() as conn:
            site_id = self._site_id(site)
            row = conn.execute("SELECT receiver_id, cn0_reference_json FROM receivers WHERE site_id = ? AND name = ?",
                               (site_id, name)).fetchone()
            if row is not None:
                if row[1] != text:
                    raise LibraryError(f"{self.path}: receiver {name!r} of site {site!r} is already stored with "
                                       "another C/N0 reference; use a new receiver name or a new library")
                return int(row[0])
            cur = conn.execute("INSERT INTO receivers (site_id, name, description, cn0_reference_json, "
                               "cn0_calibrated, created_utc) VALUES (?, ?, ?, ?, ?, ?)",
                               (site_id, name, description, text, int(bool(calibrated)), now_utc()))
            return int(cur.lastrowid)

    def recalibrate_receiver(self, site: str, name: str, cn0_reference: Mapping) -> None:
        """Store a calibrated C/N0 reference for receiver ``name`` of ``site``, stored until now with the
        uncalibrated default (a calibrated one is never changed: its cells were computed with it). The
        cells computed with the old reference keep it in their feature parameters, so the next build sees
        them as stale and recomputes them (``--replace``)."""
        Cn0Reference.from_dict(dict(cn0_reference))
        try:
            text = json.dumps(dict(cn0_reference), sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise LibraryError(f"receiver {name!r}: C/N0 reference is not plain JSON ({exc})") from None
        with self._transaction() as conn:
            site_id = self._site_id(site)
            row = conn.execute("SELECT receiver_id, cn0_calibrated FROM receivers WHERE site_id = ? AND name = ?",
                               (site_id, name)).fetchone()
            if row is None:
                raise LibraryError(f"{self.path}: site {site!r} has no receiver {name!r}")
            if row[1]:
                raise LibraryError(f"{self.path}: receiver {name!r} of site {site!r} is already calibrated")
            conn.execute("UPDATE receivers SET cn0_reference_json = ?, cn0_calibrated = 1 WHERE receiver_id = ?",
                         (text, int(row[0])))

    @_reads
    def receiver(self, site: str, name: str) -> ReceiverRecord | None:
        """The stored receiver ``name`` of ``site``, or None."""
        row = self._conn.execute(
            "SELECT r.name, r.description, r.cn0_reference_json, r.cn0_calibrated FROM receivers r "
            "JOIN sites s USING (site_id) WHERE s.name = ? AND r.name = ?", (site, name)).fetchone()
        if row is None:
            return None
        info = json.loads(row[2])
        return ReceiverRecord(row[0], row[1], Cn0Reference.from_dict(info), info, bool(row[3]))

    # ---------------------------------------------------------------- cells and samples
    def has_capture(self, site: str, cell_id: str, capture_sha256: str, feature_params: Mapping | None = None) -> bool:
        """True when ``cell_id`` of ``site`` is stored from exactly this capture (and, if given, these
        feature parameters): the resume test, made before any feature is computed."""
        row = self._conn.execute("SELECT c.capture_sha256, c.feature_params_json FROM cells c "
                                 "JOIN sites s USING (site_id) WHERE s.name = ? AND c.cell_id = ?",
                                 (site, cell_id)).fetchone()
        if row is None or row[0] != capture_sha256:
            return False
        return feature_params is None or _same_params(row[1], feature_params)

    def ingest_cell(self, site: str, cell: CellCapture, rows: Mapping[str, Sequence], *,
                    receiver: str | None = None, replace: bool = False) -> IngestResult:
        """Store one cell and its samples in one transaction.

        ``rows`` maps column names of :data:`~fingerprints.sql.SAMPLE_COLUMNS`
        to sequences of one length (one entry per window); ``t_s`` is required;
        an absent feature column, or NaN/inf in it, is stored as NULL; absent
        flags and counts are 0, ``t_utc`` and the hashes are filled in from
        ``cell``. The same capture with the same ``feature_params`` again is
        ``unchanged`` (nothing written); another capture, or other parameters,
        of a stored cell is refused unless ``replace``.
        """
        table = self._sample_rows(cell, rows)
        with self._transaction() as conn:
            site_id = self._site_id(site)
            receiver_id = None
            if receiver is not None:
                r = conn.execute("SELECT receiver_id FROM receivers WHERE site_id = ? AND name = ?",
                                 (site_id, receiver)).fetchone()
                if r is None:
                    raise LibraryError(f"{self.path}: site {site!r} has no receiver {receiver!r}; add it first")
                receiver_id = int(r[0])
            old = conn.execute("SELECT cell_pk, capture_sha256, feature_params_json FROM cells "
                               "WHERE site_id = ? AND cell_id = ?", (site_id, cell.cell_id)).fetchone()
            status = "added"
            params = json.dumps(cell.feature_params, sort_keys=True)
            if old is not None:
                if old[1] == cell.capture_sha256 and _same_params(old[2], cell.feature_params):
                    n_old = conn.execute("SELECT count(*) FROM samples WHERE cell_pk = ?", (old[0],)).fetchone()[0]
                    return IngestResult(cell.cell_id, "unchanged", int(n_old))
                if not replace:
                    what = "another capture" if old[1] != cell.capture_sha256 else "other feature parameters"
                    raise LibraryError(f"{self.path}: cell {cell.cell_id} of site {site!r} is already stored from "
                                       f"{what}; pass --replace to swap it")
                used = conn.execute("SELECT count(*) FROM run_samples rs JOIN samples s USING (sample_id) "
                                    "WHERE s.cell_pk = ?", (old[0],)).fetchone()[0]
                if used:
                    raise LibraryError(f"{self.path}: cell {cell.cell_id} cannot be replaced: {used} of its samples "
                                       "belong to clustering runs")
                conn.execute("DELETE FROM cells WHERE cell_pk = ?", (old[0],))
                status = "replaced"
            cur = conn.execute(
                "INSERT INTO cells (site_id, receiver_id, cell_id, east_m, north_m, start_utc, duration_s, map_label, "
                "map_share, missing_streams, stream_notes, gnss_sha256, audio_sha256, capture_sha256, "
                "feature_params_json, n_samples, ingested_utc) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (site_id, receiver_id, cell.cell_id, float(cell.east_m), float(cell.north_m), cell.start_utc,
                 sql_number(cell.duration_s), cell.map_label, sql_number(cell.map_share), "+".join(cell.missing_streams),
                 cell.stream_notes, cell.gnss_sha256, cell.audio_sha256, cell.capture_sha256,
                 params, len(table), now_utc()))
            self._insert_samples(conn, int(cur.lastrowid), table)
        return IngestResult(cell.cell_id, status, len(table))

    @staticmethod
    def _sample_rows(cell: CellCapture, rows: Mapping[str, Sequence]) -> list[tuple]:
        unknown = set(rows) - set(SAMPLE_COLUMNS)
        if unknown:
            raise LibraryError(f"cell {cell.cell_id}: unknown sample columns {sorted(unknown)}")
        if "t_s" not in rows:
            raise LibraryError(f"cell {cell.cell_id}: sample rows need t_s")
        t = np.asarray(rows["t_s"], dtype=float)
        n = t.shape[0]
        cols = {k: list(v) for k, v in rows.items()}
        for k, v in cols.items():
            if len(v) != n:
                raise LibraryError(f"cell {cell.cell_id}: column {k} has {len(v)} values, t_s has {n}")
        if not np.all(np.isfinite(t)) or len(np.unique(t)) != n:
            raise LibraryError(f"cell {cell.cell_id}: t_s must be finite and distinct")
        start = parse_iso_utc(cell.start_utc, f"cell {cell.cell_id} start_utc")
        out = []
        for i in range(n):
            def get(k, default=None):
                return cols[k][i] if k in cols else default
            rec = [float(t[i]),
                   (start + timedelta(seconds=float(t[i]))).isoformat(timespec="milliseconds").replace("+00:00", "Z")]
            rec += [sql_number(get(k)) for k in FEATURES]
            for k in ("gnss_available", "acoustic_available"):
                v = int(get(k, 0))
                if v not in (0, 1):
                    raise LibraryError(f"cell {cell.cell_id}: {k} must be 0 or 1, got {v}")
                rec.append(v)
            for k in GNSS_COUNTS + ACOUSTIC_COUNTS:
                v = int(get(k, 0))
                if v < 0:
                    raise LibraryError(f"cell {cell.cell_id}: {k} must be >= 0, got {v}")
                rec.append(v)
            rec += [sql_number(get("snr_db_mean")), str(get("acoustic_flags", "") or ""),
                    get("gnss_sha256", cell.gnss_sha256), get("audio_sha256", cell.audio_sha256)]
            out.append(tuple(rec))
        return out

    def _insert_samples(self, conn: sqlite3.Connection, cell_pk: int, table: list[tuple]) -> None:
        names = ("cell_pk",) + SAMPLE_COLUMNS
        sql = f"INSERT INTO samples ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})"
        conn.executemany(sql, [(cell_pk,) + r for r in table])

    def _where_site(self, site: str | None, alias: str = "s") -> tuple[str, tuple]:
        if site is None:
            return "", ()
        self._site_id(site)
        return f" WHERE {alias}.name = ?", (site,)

    @_reads
    def cells(self, site: str | None = None) -> np.ndarray:
        """Stored cells as a structured array, ordered by site and cell id.

        Fields: ``site, receiver, cell_id`` (str), ``east_m, north_m, duration_s,
        map_share`` (float, NaN = NULL), ``start_utc, map_label, missing_streams``
        (str, '' = NULL), ``n_samples`` (int).
        """
        where, args = self._where_site(site)
        rows = self._conn.execute(
            "SELECT s.name, coalesce(r.name, ''), c.cell_id, c.east_m, c.north_m, c.start_utc, c.duration_s, "
            "coalesce(c.map_label, ''), c.map_share, c.missing_streams, c.n_samples FROM cells c "
            "JOIN sites s USING (site_id) LEFT JOIN receivers r ON r.receiver_id = c.receiver_id"
            + where + " ORDER BY s.name, c.cell_id", args).fetchall()
        names = ("site", "receiver", "cell_id", "east_m", "north_m", "start_utc", "duration_s", "map_label",
                 "map_share", "missing_streams", "n_samples")
        kinds = "UUUffUfUfUi"
        return structured_rows(rows, names, kinds)

    @_reads
    def cell_feature_params(self, site: str | None = None) -> dict:
        """The feature parameters each stored cell was computed with (window, hop, receiver, C/N0 reference),
        keyed by (site, cell_id)."""
        where, args = self._where_site(site)
        rows = self._conn.execute("SELECT s.name, c.cell_id, c.feature_params_json FROM cells c JOIN sites s "
                                  "USING (site_id)" + where, args).fetchall()
        out = {}
        for name, cell_id, text in rows:
            try:
                out[(str(name), str(cell_id))] = json.loads(text) if text else {}
            except ValueError:
                out[(str(name), str(cell_id))] = {}
        return out

    @_reads
    def samples(self, site: str | None = None) -> np.ndarray:
        """Stored samples as a structured array (n_samples,), ordered by site, cell id and t_s.

        Fields: ``sample_id`` (int), ``site, cell_id`` (str), ``t_s`` (float),
        the 14 :data:`~fingerprints.sql.FEATURES` (float, NaN = missing),
        ``gnss_available, acoustic_available`` (bool), the counts (int) and
        ``snr_db_mean`` (float). :func:`feature_matrix` gives the (n, 14) array.
        """
        where, args = self._where_site(site)
        counts = GNSS_COUNTS + ACOUSTIC_COUNTS
        cols = ", ".join(f"x.{k}" for k in ("t_s",) + FEATURES + ("gnss_available", "acoustic_available") + counts
                         + ("snr_db_mean",))
        rows = self._conn.execute(
            f"SELECT x.sample_id, s.name, c.cell_id, {cols} FROM samples x JOIN cells c USING (cell_pk) "
            "JOIN sites s USING (site_id)" + where + " ORDER BY s.name, c.cell_id, x.t_s", args).fetchall()
        names = ("sample_id", "site", "cell_id", "t_s") + FEATURES + ("gnss_available", "acoustic_available") \
            + counts + ("snr_db_mean",)
        kinds = "iUUf" + "f" * len(FEATURES) + "bb" + "i" * len(counts) + "f"
        return structured_rows(rows, names, kinds)

    # ---------------------------------------------------------------- export
    @_reads
    def export_csv(self, out, site: str | None = None) -> int:
        """Write every sample (of ``site``) as CSV with :data:`EXPORT_COLUMNS`; returns the number of rows.

        ``out``: a path, written atomically (temporary file + rename: a failed
        export leaves any previous file untouched), or an open text stream.
        Floats are written in shortest round-trip form; NULL as an empty field.
        """
        where, args = self._where_site(site)
        sql = ("SELECT s.name, coalesce(r.name, ''), c.cell_id, c.east_m, c.north_m, c.map_label, c.map_share, "
               "x.sample_id, " + ", ".join(f"x.{k}" for k in SAMPLE_COLUMNS) +
               " FROM samples x JOIN cells c USING (cell_pk) JOIN sites s USING (site_id) "
               "LEFT JOIN receivers r ON r.receiver_id = c.receiver_id" + where +
               " ORDER BY s.name, c.cell_id, x.t_s")

        def write(fh) -> int:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(EXPORT_COLUMNS)
            n = 0
            for row in self._conn.execute(sql, args):
                w.writerow(["" if v is None else repr(v) if isinstance(v, float) else v for v in row])
                n += 1
            return n

        if hasattr(out, "write"):
            return write(out)
        if Path(out).resolve() in {Path(str(self.path) + x).resolve() for x in ("", "-wal", "-shm")}:
            raise LibraryError(f"{out}: is the library itself; choose another output file")
        with atomic_path(out) as tmp:
            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                return write(fh)
