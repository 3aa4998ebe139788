"""Clustering runs in the fingerprint library: per-sample embedding, ρ, δ, cluster and centre flag.

:class:`ClusteringRunsMixin` is part of :class:`fingerprints.library.FingerprintLibrary`;
its methods run on the library's connection.
"""

from __future__ import annotations

import json
import sqlite3
from typing import Mapping

import numpy as np

from fingerprints.records import LibraryError, now_utc, sql_number, structured_rows

__all__ = ["ClusteringRunsMixin"]


class ClusteringRunsMixin:
    """``save_clustering_run`` and ``clustering_run`` of :class:`~fingerprints.library.FingerprintLibrary`."""

    def save_clustering_run(self, sample_ids, labels, rho, delta, *, parameters: Mapping, model_version: str,
                            embedding=None, is_center=None, is_halo=None, site: str | None = None,
                            cluster_names: Mapping | None = None, note: str = "") -> int:
        """Store a clustering of samples in one transaction; returns its ``run_id``.

        sample_ids, labels (int, −1 = none), rho, delta : shape (n,);
        embedding : (n, 2) or None; is_center, is_halo : bool (n,) or None;
        parameters : JSON-serialisable; cluster_names : {cluster: name}.
        """
        ids = np.asarray(sample_ids, dtype=np.int64)
        n = ids.shape[0]
        lab = np.asarray(labels)
        arrays = {"labels": lab, "rho": np.asarray(rho, dtype=float), "delta": np.asarray(delta, dtype=float)}
        emb = None if embedding is None else np.asarray(embedding, dtype=float)
        if emb is not None and emb.shape != (n, 2):
            raise LibraryError(f"embedding must have shape ({n}, 2), got {emb.shape}")
        for name, flag in (("is_center", is_center), ("is_halo", is_halo)):
            arrays[name] = np.zeros(n, dtype=bool) if flag is None else np.asarray(flag, dtype=bool)
        for name, a in arrays.items():
            if a.shape != (n,):
                raise LibraryError(f"{name} must have shape ({n},), got {a.shape}")
        if not np.issubdtype(lab.dtype, np.integer):
            raise LibraryError(f"labels must be integers, got dtype {lab.dtype}")
        if not (np.all(~np.isnan(arrays["rho"])) and np.all(~np.isnan(arrays["delta"]))):
            raise LibraryError("rho and delta must not hold NaN")
        if len(np.unique(ids)) != n:
            raise LibraryError("sample_ids must be distinct")
        try:
            params = json.dumps(dict(parameters), sort_keys=True, allow_nan=False)
            names = None if cluster_names is None else json.dumps({str(k): str(v) for k, v in cluster_names.items()})
        except (TypeError, ValueError) as exc:
            raise LibraryError(f"clustering parameters are not plain JSON ({exc})") from None
        n_clusters = int(len(np.unique(lab[lab >= 0])))
        with self._transaction() as conn:
            site_id = None if site is None else self._site_id(site)
            cur = conn.execute("INSERT INTO clustering_runs (site_id, created_utc, model_version, parameters_json, "
                               "n_clusters, cluster_names_json, note) VALUES (?, ?, ?, ?, ?, ?, ?)",
                               (site_id, now_utc(), str(model_version), params, n_clusters, names, note))
            run_id = int(cur.lastrowid)
            xs = [None] * n if emb is None else [sql_number(v) for v in emb[:, 0]]
            ys = [None] * n if emb is None else [sql_number(v) for v in emb[:, 1]]
            try:
                conn.executemany(
                    "INSERT INTO run_samples (run_id, sample_id, x, y, rho, delta, cluster, is_center, is_halo) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    zip([run_id] * n, ids.tolist(), xs, ys, arrays["rho"].tolist(), arrays["delta"].tolist(),
                        lab.astype(int).tolist(), arrays["is_center"].astype(int).tolist(),
                        arrays["is_halo"].astype(int).tolist()))
            except sqlite3.IntegrityError as exc:
                raise LibraryError(f"clustering run refers to samples not in the library ({exc})") from None
        return run_id

    def clustering_run(self, run_id: int) -> tuple[dict, np.ndarray]:
        """A stored run: its metadata and a structured array (sample_id, x, y, rho, delta, cluster, is_center, is_halo)."""
        meta = self._conn.execute("SELECT created_utc, model_version, parameters_json, n_clusters, "
                                  "cluster_names_json, note FROM clustering_runs WHERE run_id = ?",
                                  (int(run_id),)).fetchone()
        if meta is None:
            raise LibraryError(f"{self.path}: no clustering run {run_id}")
        info = {"run_id": int(run_id), "created_utc": meta[0], "model_version": meta[1],
                "parameters": json.loads(meta[2]), "n_clusters": meta[3],
                "cluster_names": None if meta[4] is None else json.loads(meta[4]), "note": meta[5]}
        rows = self._conn.execute("SELECT sample_id, x, y, rho, delta, cluster, is_center, is_halo FROM run_samples "
                                  "WHERE run_id = ? ORDER BY sample_id", (int(run_id),)).fetchall()
        return info, structured_rows(rows, ("sample_id", "x", "y", "rho", "delta", "cluster", "is_center", "is_halo"),
                                 "iffffibb")
