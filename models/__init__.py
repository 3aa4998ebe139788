"""envfuse models package (see DESIGN.md §2).

Which module to open for what:

* ``models.dpc`` — density-peak clustering (Rodriguez & Laio 2014) as a scikit-learn estimator,
  ``DensityPeakClustering`` / ``fit_dpc``: ρ, δ, upslope neighbours, decision-graph centres,
  halo; KD-tree queries, matched bit for bit by the dense oracle in ``tests/dpc_reference.py``.
* ``models.embedding`` — standardise → t-SNE 2-D → DPC (``EnvironmentEmbedding``), the 14-feature
  order ``ENV_FEATURES``, and the severity naming of clusters as open / light / heavy
  (``severity_scores``, ``name_clusters``).
"""
