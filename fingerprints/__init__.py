"""The fingerprint library and survey ingestion (docs/design.md §2, §4). Imports only :mod:`features`.

Which module to open for what:

* :mod:`fingerprints.library` — :class:`~fingerprints.library.FingerprintLibrary`: open a
  library file (``with FingerprintLibrary.open(path) as lib``), add sites and
  receivers, ``ingest_cell``, read ``samples()`` / ``cells()`` as numpy
  structured arrays, ``export_csv``.
* :mod:`fingerprints.sql` — the SQLite tables, the fixed order of the 14
  features (:data:`~fingerprints.sql.FEATURES`) and the schema version.
* :mod:`fingerprints.survey` — :func:`~fingerprints.survey.build_library`: a survey
  directory into a library (features per window, per-receiver C/N0 calibration,
  missing streams, resume); what ``envfuse survey build`` runs.
* :mod:`fingerprints.records` — plain records (``CellCapture``, ``LibraryError``, ...).
* :mod:`fingerprints.runs` — storing and reading clustering runs (ρ, δ, clusters, centres).
"""
