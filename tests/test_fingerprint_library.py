"""The fingerprint library file: schema version, WAL and foreign keys, idempotent ingest, clustering runs, CSV.

Synthetic rows only (no survey): every expected value is written by the test itself.
"""

from __future__ import annotations

import csv
import math
import sqlite3

import numpy as np
import pytest

from fingerprints.library import EXPORT_COLUMNS, CellCapture, FingerprintLibrary, LibraryError, feature_matrix
from fingerprints.sql import APPLICATION_ID, FEATURES, SCHEMA_VERSION

SHA_SITE = "a" * 64
REF = {"intercept_dbhz": 37.0, "slope_dbhz": 13.0, "source": "test"}


def _cell(cell_id="E000N000", gnss="1" * 64, audio="2" * 64, **kw) -> CellCapture:
    meta = {"duration_s": 4.0, "map_label": "light", "map_share": 0.25, **kw}
    return CellCapture(cell_id, 5.0, 15.0, "2026-06-01T08:00:00Z", gnss_sha256=gnss, audio_sha256=audio, **meta)


def _rows(n=3, offset=0.0) -> dict:
    """n windows: feature k of window i = 10 k + i + offset; acoustic missing in window 0."""
    rows = {"t_s": [1.0 + i for i in range(n)], "gnss_available": [1] * n,
            "acoustic_available": [0] + [1] * (n - 1), "n_epochs": [10] * n, "n_chirps": [0] + [5] * (n - 1),
            "acoustic_flags": ["no_chirp"] + [""] * (n - 1)}
    for k, name in enumerate(FEATURES):
        rows[name] = [10.0 * k + i + offset for i in range(n)]
        if k >= 5:
            rows[name][0] = math.nan
    return rows


@pytest.fixture
def lib(tmp_path):
    with FingerprintLibrary.open(tmp_path / "fp.sqlite") as lib:
        lib.add_site("s1", lat_deg=30.5, lon_deg=114.3, alt_m=25.0, site_toml_sha256=SHA_SITE)
        lib.add_receiver("s1", "rx", REF, calibrated=True)
        yield lib


def test_feature_order_is_fixed():
    assert FEATURES == ("att_mean_db", "att_std_db", "fluct_per_s", "invisible_ratio", "dop_growth",
                        "mean_excess_delay_ms", "rms_delay_ms", "delay_kurtosis", "delay_skewness", "rician_k_db",
                        "gain_mean_db", "gain_rms_db", "gain_kurtosis", "gain_skewness")


def test_new_library_is_wal_with_foreign_keys_and_version(tmp_path):
    path = tmp_path / "fp.sqlite"
    with FingerprintLibrary.open(path) as lib:
        conn = lib._conn
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert conn.execute("PRAGMA foreign_keys").fetchone()[0] == 1
        assert conn.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
        assert lib.schema_version == SCHEMA_VERSION == 1
        with pytest.raises(sqlite3.IntegrityError):
            conn.execute("INSERT INTO cells (site_id, cell_id, east_m, north_m, start_utc, capture_sha256, "
                         "feature_params_json, n_samples, ingested_utc) VALUES (99, 'x', 0, 0, 't', 'h', '{}', 0, 't')")
    raw = sqlite3.connect(path)
    assert raw.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
    assert {r[0] for r in raw.execute("SELECT name FROM sqlite_master WHERE type = 'table'")} == {
        "sites", "receivers", "cells", "samples", "clustering_runs", "run_samples"}
    raw.close()


def _set_pragma(path, **pragmas):
    raw = sqlite3.connect(path)
    for k, v in pragmas.items():
        raw.execute(f"PRAGMA {k}={v}")
    raw.commit()
    raw.close()


@pytest.mark.parametrize("pragmas,needle", [
    ({"user_version": 2}, "newer envfuse (library schema version 2"),
    ({"user_version": 0}, "unknown library schema version 0"),
    ({"application_id": 7}, "not an envfuse fingerprint library"),
])
def test_other_versions_and_applications_refused(tmp_path, pragmas, needle):
    path = tmp_path / "fp.sqlite"
    FingerprintLibrary.open(path).close()
    _set_pragma(path, **pragmas)
    before = path.read_bytes()
    with pytest.raises(LibraryError, match=needle.replace("(", r"\(")):
        FingerprintLibrary.open(path)
    assert path.read_bytes() == before


def test_not_a_library(tmp_path):
    text = tmp_path / "notes.sqlite"
    text.write_text("cell_id,east_m\n")
    with pytest.raises(LibraryError, match="not an SQLite database"):
        FingerprintLibrary.open(text)
    assert text.read_text() == "cell_id,east_m\n"
    other = tmp_path / "other.db"
    raw = sqlite3.connect(other)
    raw.execute("CREATE TABLE t (x)")
    raw.commit()
    raw.close()
    with pytest.raises(LibraryError, match="not an envfuse fingerprint library"):
        FingerprintLibrary.open(other)
    with pytest.raises(LibraryError, match="no fingerprint library there"):
        FingerprintLibrary.open(tmp_path / "absent.sqlite", create=False)
    assert not (tmp_path / "absent.sqlite").exists()
    with pytest.raises(LibraryError, match="is a directory"):
        FingerprintLibrary.open(tmp_path)


def test_ingest_round_trip_and_nan_as_null(lib):
    res = lib.ingest_cell("s1", _cell(), _rows(), receiver="rx")
    assert (res.status, res.n_samples) == ("added", 3)
    s = lib.samples()
    assert len(s) == 3 and s["t_s"].tolist() == [1.0, 2.0, 3.0]
    x = feature_matrix(s)
    assert x.shape == (3, 14)
    expected = np.array(_rows()[FEATURES[0]])
    assert x[:, 0].tolist() == expected.tolist()
    assert x[1].tolist() == [10.0 * k + 1 for k in range(14)]
    assert np.isnan(x[0, 5:]).all() and np.isfinite(x[0, :5]).all()
    assert s["acoustic_available"].tolist() == [False, True, True] and s["n_chirps"].tolist() == [0, 5, 5]
    # NaN is stored as SQL NULL, so plain sqlite3 users see NULL
    nulls = lib._conn.execute("SELECT count(*) FROM samples WHERE rms_delay_ms IS NULL").fetchone()[0]
    assert nulls == 1
    t_utc = [r[0] for r in lib._conn.execute("SELECT t_utc FROM samples ORDER BY t_s")]
    assert t_utc == ["2026-06-01T08:00:01.000Z", "2026-06-01T08:00:02.000Z", "2026-06-01T08:00:03.000Z"]
    c = lib.cells()
    assert c["cell_id"].tolist() == ["E000N000"] and c["receiver"].tolist() == ["rx"]
    assert c["map_label"].tolist() == ["light"] and c["map_share"].tolist() == [0.25] and c["n_samples"][0] == 3


def test_same_capture_twice_adds_nothing_other_capture_refused_or_replaced(lib):
    lib.ingest_cell("s1", _cell(), _rows())
    again = lib.ingest_cell("s1", _cell(), _rows(offset=100.0))
    assert (again.status, again.n_samples) == ("unchanged", 3)
    assert len(lib.samples()) == 3 and feature_matrix(lib.samples())[0, 0] == 0.0
    with pytest.raises(LibraryError, match="another capture; pass --replace"):
        lib.ingest_cell("s1", _cell(audio="3" * 64), _rows(5))
    assert len(lib.samples()) == 3
    new = lib.ingest_cell("s1", _cell(audio="3" * 64), _rows(5, offset=0.5), replace=True)
    assert (new.status, new.n_samples) == ("replaced", 5)
    s = lib.samples()
    assert len(s) == 5 and feature_matrix(s)[0, 0] == 0.5
    assert lib._conn.execute("SELECT count(*) FROM cells").fetchone()[0] == 1
    assert lib.has_capture("s1", "E000N000", _cell(audio="3" * 64).capture_sha256)
    assert not lib.has_capture("s1", "E000N000", _cell().capture_sha256)


def test_same_capture_other_feature_parameters_is_stale(lib):
    lib.ingest_cell("s1", _cell(feature_params={"window_s": 2.0}), _rows(3))
    assert lib.has_capture("s1", "E000N000", _cell().capture_sha256, {"window_s": 2.0})
    assert not lib.has_capture("s1", "E000N000", _cell().capture_sha256, {"window_s": 4.0})
    with pytest.raises(LibraryError, match="other feature parameters; pass --replace"):
        lib.ingest_cell("s1", _cell(feature_params={"window_s": 4.0}), _rows(2))
    res = lib.ingest_cell("s1", _cell(feature_params={"window_s": 4.0}), _rows(2), replace=True)
    assert (res.status, res.n_samples, len(lib.samples())) == ("replaced", 2, 2)


def test_failed_ingest_leaves_nothing(lib):
    rows = _rows()
    rows["gnss_available"] = [1, 2, 1]
    with pytest.raises(LibraryError, match="gnss_available must be 0 or 1"):
        lib.ingest_cell("s1", _cell(), rows)
    with pytest.raises(LibraryError, match="has no receiver 'nope'"):
        lib.ingest_cell("s1", _cell(), _rows(), receiver="nope")
    rows = _rows()
    rows["t_s"] = [1.0, 1.0, 2.0]
    with pytest.raises(LibraryError, match="distinct"):
        lib.ingest_cell("s1", _cell(), rows)
    assert lib._conn.execute("SELECT count(*) FROM cells").fetchone()[0] == 0
    assert lib._conn.execute("SELECT count(*) FROM samples").fetchone()[0] == 0


def test_sites_and_receivers(lib):
    assert lib.add_site("s1", lat_deg=30.5, lon_deg=114.3, alt_m=25.0, site_toml_sha256=SHA_SITE) == 1
    with pytest.raises(LibraryError, match="another site.toml"):
        lib.add_site("s1", lat_deg=30.5, lon_deg=114.3, alt_m=25.0, site_toml_sha256="b" * 64)
    rx = lib.receiver("s1", "rx")
    assert rx.calibrated and rx.reference.intercept_dbhz == 37.0 and rx.reference.slope_dbhz == 13.0
    assert lib.receiver("s1", "absent") is None
    assert lib.add_receiver("s1", "rx", REF, calibrated=True) == 1
    with pytest.raises(LibraryError, match="another C/N0 reference"):
        lib.add_receiver("s1", "rx", dict(REF, slope_dbhz=12.0), calibrated=True)
    with pytest.raises(LibraryError, match="no site named 'nope'"):
        lib.samples(site="nope")


def test_samples_filtered_by_site(lib):
    lib.add_site("s2", lat_deg=31.0, lon_deg=115.0, alt_m=0.0, site_toml_sha256="c" * 64)
    lib.ingest_cell("s1", _cell(), _rows(3))
    lib.ingest_cell("s2", _cell(), _rows(2))
    assert len(lib.samples()) == 5 and len(lib.samples("s1")) == 3 and len(lib.samples("s2")) == 2
    assert lib.samples("s2")["site"].tolist() == ["s2", "s2"]
    assert lib.sites() == ["s1", "s2"]


def test_clustering_run_round_trip(lib):
    lib.ingest_cell("s1", _cell(), _rows(4))
    ids = lib.samples()["sample_id"]
    emb = np.array([[0.0, 1.0], [2.0, 3.0], [4.0, 5.0], [6.0, 7.0]])
    run = lib.save_clustering_run(ids, [0, 0, 1, -1], [3.0, 1.0, 2.0, 0.5], [np.inf, 1.5, 2.5, 0.25],
                                  embedding=emb, is_center=[True, False, True, False],
                                  is_halo=[False, False, False, True], parameters={"dc_percent": 2.0},
                                  model_version="dpc-0.1", site="s1", cluster_names={0: "open", 1: "heavy"})
    info, rs = lib.clustering_run(run)
    assert info["n_clusters"] == 2 and info["parameters"] == {"dc_percent": 2.0}
    assert info["cluster_names"] == {"0": "open", "1": "heavy"} and info["model_version"] == "dpc-0.1"
    assert rs["sample_id"].tolist() == ids.tolist() and rs["cluster"].tolist() == [0, 0, 1, -1]
    assert rs["x"].tolist() == [0.0, 2.0, 4.0, 6.0] and rs["delta"].tolist() == [np.inf, 1.5, 2.5, 0.25]
    assert rs["is_center"].tolist() == [True, False, True, False] and rs["is_halo"].tolist()[-1]
    with pytest.raises(LibraryError, match="not in the library"):
        lib.save_clustering_run([ids[0], 9999], [0, 0], [1.0, 1.0], [1.0, 1.0], parameters={}, model_version="x")
    with pytest.raises(LibraryError, match=r"rho must have shape \(2,\)"):
        lib.save_clustering_run(ids[:2], [0, 0], [1.0], [1.0, 1.0], parameters={}, model_version="x")
    assert lib._conn.execute("SELECT count(*) FROM clustering_runs").fetchone()[0] == 1
    # samples used by a run are not silently deleted by replacing their cell
    with pytest.raises(LibraryError, match="belong to clustering runs"):
        lib.ingest_cell("s1", _cell(gnss="9" * 64), _rows(2), replace=True)
    assert len(lib.samples()) == 4


def test_export_csv_round_trip_and_atomic(lib, tmp_path):
    lib.ingest_cell("s1", _cell(), _rows(3), receiver="rx")
    lib.ingest_cell("s1", _cell("E001N000", map_label=None, map_share=None), _rows(2, offset=0.1))
    out = tmp_path / "samples.csv"
    assert lib.export_csv(out) == 5
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == EXPORT_COLUMNS and len(rows) == 5
    s = lib.samples()
    for name in FEATURES + ("t_s",):
        back = np.array([float(r[name]) if r[name] else np.nan for r in rows])
        np.testing.assert_array_equal(back, s[name])  # exact: shortest round-trip floats, NULL as empty
    assert [r["cell_id"] for r in rows] == ["E000N000"] * 3 + ["E001N000"] * 2
    assert [r["receiver"] for r in rows] == ["rx"] * 3 + [""] * 2
    assert rows[0]["acoustic_flags"] == "no_chirp" and rows[0]["rms_delay_ms"] == ""
    assert [r["map_label"] for r in rows] == ["light"] * 3 + [""] * 2 and rows[3]["map_share"] == ""
    # a failed export leaves the previous file as it was and no temporary file behind
    before = out.read_bytes()
    with pytest.raises(LibraryError, match="no site named"):
        lib.export_csv(out, site="nope")
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir() if "samples" in p.name) == [
        "samples.csv"]
    assert lib.export_csv(tmp_path / "s1.csv", site="s1") == 5
    with pytest.raises(LibraryError, match="is the library itself"):
        lib.export_csv(lib.path)
    assert lib.path.read_bytes()[:16] == b"SQLite format 3\x00"


def test_plain_sqlite_users_can_query(lib):
    lib.ingest_cell("s1", _cell(), _rows(3))
    raw = sqlite3.connect(lib.path)
    got = raw.execute("SELECT c.cell_id, c.map_label, count(*), avg(s.att_mean_db) FROM samples s "
                      "JOIN cells c USING (cell_pk) GROUP BY c.cell_pk").fetchall()
    view = raw.execute("SELECT site, cell_id, map_label, t_s, att_mean_db FROM cell_samples ORDER BY t_s").fetchall()
    raw.close()
    assert got == [("E000N000", "light", 3, 1.0)]
    assert view == [("s1", "E000N000", "light", 1.0, 0.0), ("s1", "E000N000", "light", 2.0, 1.0),
                    ("s1", "E000N000", "light", 3.0, 2.0)]


def test_fingerprints_imports_only_features():
    """Layering (docs/design.md §2): fingerprints imports features and third-party libraries, nothing else of ours."""
    import ast
    from pathlib import Path

    ours = {"simulation", "models", "training", "pipeline", "fingerprints", "features"}
    pkg = Path(__file__).resolve().parents[1] / "fingerprints"
    seen = set()
    for path in pkg.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else []
            seen |= {n.split(".")[0] for n in names if n.split(".")[0] in ours}
    assert seen == {"features", "fingerprints"}


def test_feature_parameters_compare_as_json_objects_not_text(lib):
    """Issue 20: the resume test must not depend on key order. Parameters given in another insertion order
    (nested too) are the same parameters; so is a stored JSON text whose keys are not sorted (written by an
    older version or by hand); a changed value is not."""
    params = {"window_s": 2.0, "hop_s": 1.0, "receiver": "rx", "cn0_reference": {"slope_dbhz": 12.5,
                                                                                   "intercept_dbhz": 36.9}}
    lib.ingest_cell("s1", _cell(feature_params=params), _rows(3))
    reordered = {"cn0_reference": {"intercept_dbhz": 36.9, "slope_dbhz": 12.5}, "receiver": "rx", "hop_s": 1.0,
                 "window_s": 2.0}
    sha = _cell().capture_sha256
    assert lib.has_capture("s1", "E000N000", sha, reordered)
    assert lib.ingest_cell("s1", _cell(feature_params=reordered), _rows(3)).status == "unchanged"
    lib._conn.execute("UPDATE cells SET feature_params_json = ?",
                      ('{"window_s": 2.0, "receiver": "rx", "hop_s": 1.0, '
                       '"cn0_reference": {"slope_dbhz": 12.5, "intercept_dbhz": 36.9}}',))
    lib._conn.commit()
    assert lib.has_capture("s1", "E000N000", sha, params) and lib.has_capture("s1", "E000N000", sha, reordered)
    assert lib.ingest_cell("s1", _cell(feature_params=params), _rows(3)).status == "unchanged"
    assert not lib.has_capture("s1", "E000N000", sha, {**params, "hop_s": 0.5})
    assert not lib.has_capture("s1", "E000N000", sha, {k: v for k, v in params.items() if k != "receiver"})
