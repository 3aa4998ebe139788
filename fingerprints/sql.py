"""The fingerprint library's SQLite schema (docs/design.md §4): tables, feature order, version.

Plain tables and columns, so ``sqlite3 FP.sqlite`` and ``sqlite-utils`` users can
query a library without envfuse, e.g.::

    SELECT c.cell_id, c.map_label, avg(s.att_mean_db), avg(s.rms_delay_ms)
    FROM samples s JOIN cells c USING (cell_pk) GROUP BY c.cell_pk;

Tables
------
``sites``
    one row per substation: ``name`` (unique), origin ``lat_deg, lon_deg,
    alt_m`` (WGS-84), ``site_toml_sha256`` (of the ``site.toml`` the survey was
    read with).
``receivers``
    one row per GNSS receiver of a site: ``name`` (unique within the site),
    ``description``, ``cn0_reference_json`` (the open-sky C/N0 model the
    attenuation features were computed with: line parameters, the per-elevation
    bin values it was fitted to and the fitting rule) and ``cn0_calibrated``
    (1 = fitted to this receiver's own survey data, 0 = the built-in default).
``cells``
    one row per survey capture: ``cell_id`` (unique within the site),
    ``east_m, north_m`` (site ENU), ``start_utc``, ``duration_s``, ``map_label``
    (``open``/``light``/``heavy`` or NULL) and ``map_share`` (blocked-sky share
    behind the label, NULL when absent) — evaluation only; ``missing_streams``
    (``+``-joined names of the streams the capture lacks: ``gnss``, ``audio``;
    empty when complete) with ``stream_notes`` saying why; ``gnss_sha256``,
    ``audio_sha256`` (NULL when missing) and ``capture_sha256`` (of both: the
    identity of a capture for idempotent ingest); ``feature_params_json``;
    ``n_samples``.
``samples``
    one row per analysis window of a cell: ``t_s`` (window centre, seconds
    since the cell's ``start_utc``), ``t_utc``, the 14 features in
    :data:`FEATURES` order (NULL when unavailable), the availability flags
    (0/1) — ``gnss_available``: satellites in view above the mask in the
    window (ζ and λ defined; μ, σ, β also need a tracked satellite and may
    still be NULL), ``acoustic_available``: at least one beacon chirp
    detected — the counts behind them (:data:`GNSS_COUNTS`, ``n_chirps,
    n_beacons``), ``snr_db_mean``, ``acoustic_flags`` (``+``-joined:
    ``no_chirp``, ``clipped``, ``silent``, ``partial``, ``truncated``,
    ``no_audio`` when the cell has no usable audio, ``no_window`` when no
    acoustic window matched the GNSS one) and the SHA-256 of the source files
    the row came from.
``clustering_runs`` / ``run_samples``
    a clustering of (some) samples: ``parameters_json``, ``created_utc``,
    ``model_version``, ``n_clusters``, ``cluster_names_json``; per sample the
    embedding ``x, y``, ``rho``, ``delta``, ``cluster`` (−1 = none),
    ``is_center`` and ``is_halo``.

``cell_samples`` (a view)
    every sample with its site name, cell id, position and map label: the
    one table most ad-hoc queries want.

Every child row references its parent (``FOREIGN KEY ... ON DELETE CASCADE``);
foreign keys are switched on for every connection.
"""

from __future__ import annotations

from features.gnss.features import COUNT_COLUMNS as _GNSS_COUNTS
from features.schema import ACOUSTIC_FEATURES as _CIR_FEATURES
from features.schema import FEATURES as _ALL_FEATURES
from features.schema import GNSS_FEATURES as _GNSS_FEATURES

__all__ = ["SCHEMA_VERSION", "APPLICATION_ID", "GNSS_FEATURES", "ACOUSTIC_FEATURES", "FEATURES", "GNSS_COUNTS",
           "ACOUSTIC_COUNTS", "SAMPLE_COLUMNS", "DDL"]

SCHEMA_VERSION = 1
"""``PRAGMA user_version`` of libraries this code writes; a library with another version is refused."""

APPLICATION_ID = 0x45465031
"""``PRAGMA application_id`` marking an envfuse fingerprint library (ASCII ``EFP1``)."""

GNSS_FEATURES: tuple[str, ...] = tuple(_GNSS_FEATURES)
"""The five GNSS features, docs/design.md §5 order (from :mod:`features.schema`)."""

ACOUSTIC_FEATURES: tuple[str, ...] = tuple(_CIR_FEATURES)
"""The nine acoustic CIR features, docs/design.md §5 order (from :mod:`features.schema`)."""

FEATURES: tuple[str, ...] = tuple(_ALL_FEATURES)
"""The 14 features in the library's fixed order: the columns of ``samples`` and of every feature matrix.

>>> len(FEATURES), FEATURES[0], FEATURES[5], FEATURES[-1]
(14, 'att_mean_db', 'mean_excess_delay_ms', 'gain_skewness')
"""

GNSS_COUNTS: tuple[str, ...] = tuple(_GNSS_COUNTS)
"""Counts behind the GNSS features (integers; 0 when the stream is missing)."""

ACOUSTIC_COUNTS: tuple[str, ...] = ("n_chirps", "n_beacons")
"""Counts behind the acoustic features (integers; 0 when the stream is missing)."""

SAMPLE_COLUMNS: tuple[str, ...] = (("t_s", "t_utc") + FEATURES + ("gnss_available", "acoustic_available")
                                   + GNSS_COUNTS + ACOUSTIC_COUNTS
                                   + ("snr_db_mean", "acoustic_flags", "gnss_sha256", "audio_sha256"))
"""Columns of ``samples`` written by :meth:`~fingerprints.library.FingerprintLibrary.ingest_cell`, in order."""

_feature_cols = ",\n    ".join(f"{name} REAL" for name in FEATURES)
_gnss_counts = ",\n    ".join(f"{name} INTEGER NOT NULL CHECK ({name} >= 0)" for name in GNSS_COUNTS)
_ac_counts = ",\n    ".join(f"{name} INTEGER NOT NULL CHECK ({name} >= 0)" for name in ACOUSTIC_COUNTS)

DDL = f"""
CREATE TABLE sites (
    site_id INTEGER PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    lat_deg REAL NOT NULL,
    lon_deg REAL NOT NULL,
    alt_m REAL NOT NULL,
    site_toml_sha256 TEXT NOT NULL,
    created_utc TEXT NOT NULL
);
CREATE TABLE receivers (
    receiver_id INTEGER PRIMARY KEY,
    site_id INTEGER NOT NULL REFERENCES sites(site_id) ON DELETE CASCADE,
    name TEXT NOT NULL,
    description TEXT NOT NULL DEFAULT '',
    cn0_reference_json TEXT NOT NULL,
    cn0_calibrated INTEGER NOT NULL CHECK (cn0_calibrated IN (0, 1)),
    created_utc TEXT NOT NULL,
    UNIQUE (site_id, name)
);
CREATE TABLE cells (
    cell_pk INTEGER PRIMARY KEY,
    site_id INTEGER NOT NULL REFERENCES sites(site_id) ON DELETE CASCADE,
    receiver_id INTEGER REFERENCES receivers(receiver_id) ON DELETE RESTRICT,
    cell_id TEXT NOT NULL,
    east_m REAL NOT NULL,
    north_m REAL NOT NULL,
    start_utc TEXT NOT NULL,
    duration_s REAL,
    map_label TEXT CHECK (map_label IS NULL OR map_label IN ('open', 'light', 'heavy')),
    map_share REAL CHECK (map_share IS NULL OR (map_share >= 0 AND map_share <= 1)),
    missing_streams TEXT NOT NULL DEFAULT '',
    stream_notes TEXT NOT NULL DEFAULT '',
    gnss_sha256 TEXT,
    audio_sha256 TEXT,
    capture_sha256 TEXT NOT NULL,
    feature_params_json TEXT NOT NULL,
    n_samples INTEGER NOT NULL CHECK (n_samples >= 0),
    ingested_utc TEXT NOT NULL,
    UNIQUE (site_id, cell_id)
);
CREATE TABLE samples (
    sample_id INTEGER PRIMARY KEY,
    cell_pk INTEGER NOT NULL REFERENCES cells(cell_pk) ON DELETE CASCADE,
    t_s REAL NOT NULL,
    t_utc TEXT NOT NULL,
    {_feature_cols},
    gnss_available INTEGER NOT NULL CHECK (gnss_available IN (0, 1)),
    acoustic_available INTEGER NOT NULL CHECK (acoustic_available IN (0, 1)),
    {_gnss_counts},
    {_ac_counts},
    snr_db_mean REAL,
    acoustic_flags TEXT NOT NULL DEFAULT '',
    gnss_sha256 TEXT,
    audio_sha256 TEXT,
    UNIQUE (cell_pk, t_s)
);
CREATE INDEX samples_cell ON samples(cell_pk);
CREATE TABLE clustering_runs (
    run_id INTEGER PRIMARY KEY,
    site_id INTEGER REFERENCES sites(site_id) ON DELETE CASCADE,
    created_utc TEXT NOT NULL,
    model_version TEXT NOT NULL,
    parameters_json TEXT NOT NULL,
    n_clusters INTEGER NOT NULL CHECK (n_clusters >= 0),
    cluster_names_json TEXT,
    note TEXT NOT NULL DEFAULT ''
);
CREATE TABLE run_samples (
    run_id INTEGER NOT NULL REFERENCES clustering_runs(run_id) ON DELETE CASCADE,
    sample_id INTEGER NOT NULL REFERENCES samples(sample_id) ON DELETE CASCADE,
    x REAL,
    y REAL,
    rho REAL NOT NULL,
    delta REAL NOT NULL,
    cluster INTEGER NOT NULL,
    is_center INTEGER NOT NULL CHECK (is_center IN (0, 1)),
    is_halo INTEGER NOT NULL DEFAULT 0 CHECK (is_halo IN (0, 1)),
    PRIMARY KEY (run_id, sample_id)
) WITHOUT ROWID;
CREATE INDEX run_samples_sample ON run_samples(sample_id);
CREATE VIEW cell_samples AS
    SELECT st.name AS site, c.cell_id, c.east_m, c.north_m, c.map_label, c.map_share, c.missing_streams, x.*
    FROM samples x JOIN cells c USING (cell_pk) JOIN sites st USING (site_id);
"""
"""The schema of :data:`SCHEMA_VERSION`, run once when a new library is created."""
