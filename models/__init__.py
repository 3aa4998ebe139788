"""Estimators: pure maths on in-memory arrays; no file I/O except explicit model bundles.

Which module to open for what:

* ``models.dpc`` — density-peak clustering (Rodriguez & Laio 2014) as a scikit-learn estimator,
  ``DensityPeakClustering`` / ``fit_dpc``: ρ, δ, upslope neighbours, decision-graph centres,
  halo; KD-tree queries, matched bit for bit by the dense oracle in ``tests/dpc_reference.py``.
* ``models.embedding`` — standardise → t-SNE 2-D → DPC (``EnvironmentEmbedding``), and the
  severity naming of clusters as open / light / heavy (``severity_scores``, ``name_clusters``).
* ``models.environment`` — the online classifier (``EnvironmentClassifier``): one logistic
  sub-model per available modality, OOD flag, occlusion estimate, cell combination.
* ``models.fusion`` — the event-driven filter core: event streams (steps, GNSS, acoustic,
  standing), the EKF with heading-offset and step-scale states (optional GNSS Gauss–Markov
  bias), noise policies (fixed, quality, per class, VB-AKF, Sage–Husa), the IMM over
  environment classes, the RTS smoother and NEES/NIS consistency.
* ``models.graph`` — factor-graph fusion on GTSAM: the walk as a graph of PDR, GNSS and acoustic
  factors (batch Levenberg–Marquardt, iSAM2, fixed-lag), robust and class-aware kernels, tightly
  coupled acoustic ranges, IMU preintegration; ``models.rtkpdr`` — the RTK/PDR EKF of Zhang et al.
  2023 on the fusion core's kernels.
* ``models.adaptive_noise`` — the adaptive method's R per (class, GGA quality).
* ``models.bp`` — the BP corrector (ensemble with variance heads) and its guards.
* ``models.fusion_model`` / ``models.bundle`` — the fusion model and pickle-free bundles
  (JSON + safetensors).
"""
