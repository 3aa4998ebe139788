"""Estimators: pure maths on in-memory arrays; no file I/O except explicit model bundles.

Which module to open for what:

* ``models.dpc`` — density-peak clustering (Rodriguez & Laio 2014) as a scikit-learn estimator,
  ``DensityPeakClustering`` / ``fit_dpc``: ρ, δ, upslope neighbours, decision-graph centres,
  halo; KD-tree queries, matched bit for bit by the dense oracle in ``tests/dpc_reference.py``.
* ``models.embedding`` — standardise → t-SNE 2-D → DPC (``EnvironmentEmbedding``), and the
  severity naming of clusters as open / light / heavy (``severity_scores``, ``name_clusters``).
* ``models.environment`` — the online classifier (``EnvironmentClassifier``): one logistic
  sub-model per available modality, OOD flag, occlusion estimate, cell combination.
* ``models.occlusion`` — the continuous blocked-sky share (``OcclusionRegressor``): fractional logit
  through a small tanh network, averaged over initialisations; the classifier fits one per sub-model.
* ``models.temporal`` — the environment class along a walk (``ClassHMM``): transitions counted on
  training walks, causal forward and smoothed forward–backward recursions over the window classes.
* ``models.fusion`` — event-driven fusion: event streams (steps, GNSS, acoustic, standing), the one
  compiled Kalman filter core, the EKF with heading-offset, step-scale and GNSS Gauss–Markov bias
  states, noise policies (fixed, quality, per class, VB-AKF) and the error model in context
  (white scale, bias and outlier prior per class and GGA quality), the IMM over environment
  classes, RTS and fixed-lag smoothing, NEES/NIS consistency.
* ``models.graph`` — factor-graph fusion on GTSAM: the walk as a graph of PDR, GNSS and acoustic
  factors (batch Levenberg–Marquardt, iSAM2, fixed-lag), robust and class-aware kernels, tightly
  coupled acoustic ranges, IMU preintegration; ``models.rtkpdr`` — the RTK/PDR EKF of Zhang et al.
  2023 on the fusion core's kernels.
* ``models.bp`` — the BP position corrector of the seed's section 2.2 (ensemble with variance heads)
  and its guards.
* ``models.bp_params`` — the BP network that maps the environment and the filter's state to each fix's R.
* ``models.fusion.model`` / ``models.bundle`` — the fusion model and pickle-free bundles
  (JSON + safetensors).
"""
