"""Fitting the environment model from a fingerprint library (``envfuse train env``).

Modes (docs/design.md §1, issue 13):

``supervised``
    the classifier learns the map labels of the training sites' cells — what
    a utility with surveyed, mapped substations would do;
``survey``
    the site's own library is clustered without labels (standardise → t-SNE →
    density-peak clustering, clusters named by severity) and the classifier
    learns those clusters — the paper's way of meeting a new substation; with a few labelled cells
    (``seeds``, ``--cell``) semi-supervised: their map labels name the clusters and are spread to the other
    windows before the classifier learns them (:mod:`training.semisup`);
``transfer``
    the same clustering on the training sites' libraries, the classifier then
    applied to a new site.

The windows come from a fingerprint library (:func:`training_set`) or straight from walks
(:func:`walk_training_set`: every 2 s window of each walk, as the filters see them; labels from
``truth.csv`` where its class is known) — the clustering modes need no label, so a drive with an
unlabelled reference can be clustered on its own windows.

Every mode ends in an :class:`models.environment.EnvironmentClassifier`
saved as an ``environment`` bundle with its mode, feature order, class names,
the library's hash and the sites and sample counts it was fitted on.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from features.errors import ConfigError, DataError
from features.fileio import sha256_file
from features.schema import ENV_CLASSES, FEATURES
from fingerprints.library import FingerprintLibrary
from fingerprints.records import feature_matrix
from models.bundle import load_bundle, save_bundle
from models.environment import EnvironmentClassifier

__all__ = ["MODES", "TrainingSet", "training_set", "walk_training_set", "fit_env_model", "save_env_model",
           "load_env_model", "naming_warnings", "SMALL_LIBRARY_WINDOWS"]

MODES = ("supervised", "survey", "transfer")


@dataclass(frozen=True)
class TrainingSet:
    """Windows of a library: ``X`` (n, 14), ``site`` / ``cell`` (n,) str, ``label`` (n,) class code from the
    cell's map label (−1 without one), ``share`` (n,) map share (NaN without one), ``t_s`` (n,)."""

    X: np.ndarray
    site: np.ndarray
    cell: np.ndarray
    label: np.ndarray
    share: np.ndarray
    t_s: np.ndarray
    window_s: float = 2.0
    hop_s: float = 1.0

    def __len__(self) -> int:
        return int(self.X.shape[0])

    def subset(self, keep: np.ndarray) -> "TrainingSet":
        return TrainingSet(self.X[keep], self.site[keep], self.cell[keep], self.label[keep], self.share[keep],
                           self.t_s[keep], self.window_s, self.hop_s)


def _windows(params: dict, library) -> tuple[float, float]:
    """The one (window_s, hop_s) every chosen cell was computed with; a library mixing them is refused."""
    seen: dict = {}
    for key, p in params.items():
        w = (float(p.get("window_s", 2.0)), float(p.get("hop_s", 1.0)))
        seen.setdefault(w, []).append(key)
    if len(seen) > 1:
        parts = ", ".join(f"{w:g} s / hop {h:g} s ({len(v)} cells, e.g. {v[0][0]}:{v[0][1]})"
                          for (w, h), v in sorted(seen.items()))
        raise DataError(f"{library}: the cells were computed with different windows ({parts}); a model learns "
                        "one window length: rebuild them with one --window-s/--hop-s (survey build --replace)")
    return next(iter(seen)) if seen else (2.0, 1.0)


def training_set(library: str | os.PathLike, sites=None) -> TrainingSet:
    """Every window of ``library`` (of ``sites`` when given), with its cell's map label and share."""
    with FingerprintLibrary.open(library, create=False) as lib:
        known = lib.sites()
        chosen = list(known) if not sites else list(sites)
        missing = sorted(set(chosen) - set(known))
        if missing:
            raise ConfigError(f"{library}: no site {missing} (the library holds {known})")
        parts_s, parts_c, params = [], [], {}
        for site in chosen:
            parts_s.append(lib.samples(site))
            parts_c.append(lib.cells(site))
            params.update(lib.cell_feature_params(site))
    samples = np.concatenate(parts_s) if parts_s else np.zeros(0)
    cells = np.concatenate(parts_c) if parts_c else np.zeros(0)
    if len(samples) == 0:
        raise DataError(f"{library}: no samples for sites {chosen}")
    key = {(str(c["site"]), str(c["cell_id"])): c for c in cells}
    label = np.full(len(samples), -1)
    share = np.full(len(samples), np.nan)
    for i, s in enumerate(samples):
        c = key[(str(s["site"]), str(s["cell_id"]))]
        if c["map_label"] in ENV_CLASSES:
            label[i] = ENV_CLASSES.index(str(c["map_label"]))
        share[i] = float(c["map_share"])
    with_samples = {(str(s["site"]), str(s["cell_id"])) for s in samples}
    window_s, hop_s = _windows({k: v for k, v in params.items() if k in with_samples}, library)
    return TrainingSet(feature_matrix(samples), np.asarray(samples["site"], str), np.asarray(samples["cell_id"], str),
                       label, share, np.asarray(samples["t_s"], float), window_s, hop_s)


def walk_training_set(walk_dirs, t_range_s: tuple[float, float] | None = None) -> TrainingSet:
    """Every feature window of the walks (:func:`walks.inputs.window_features`, as the filters see them): ``site``
    the walk's site, ``cell`` the walk's folder, ``label`` the truth class at the window's centre (−1 where
    unknown or without ``truth.csv``), ``share`` the truth's blocked-sky share there (NaN without one), ``t_s``
    the window centre; ``t_range_s``: only windows whose whole span lies in [t0, t1]."""
    from walks.inputs import HOP_S, WINDOW_S, window_features
    from walks.reader import read_walk

    parts = []
    for w in walk_dirs:
        data = read_walk(w)
        t_end, X = window_features(data)
        t = t_end - WINDOW_S / 2.0
        keep = np.ones(len(t), bool) if t_range_s is None else ((t_end - WINDOW_S >= t_range_s[0])
                                                               & (t_end <= t_range_s[1]))
        t, X = t[keep], X[keep]
        label, share = np.full(len(t), -1), np.full(len(t), np.nan)
        if data.truth is not None and len(t):
            label = np.asarray(data.truth.class_at(t), int)
            if data.truth.blocked_share is not None:
                share = np.interp(t, data.truth.t_s, data.truth.blocked_share)
        parts.append((X, np.full(len(t), data.site.name), np.full(len(t), str(w)), label, share, t))
    if not parts or sum(len(p[0]) for p in parts) == 0:
        raise DataError("the walks hold no feature window")
    X, site, cell, label, share, t = (np.concatenate(c) for c in zip(*parts))
    return TrainingSet(X.reshape(-1, len(FEATURES)), site.astype(str), cell.astype(str), label.astype(int), share,
                       t.astype(float), WINDOW_S, HOP_S)


def fit_env_model(data: TrainingSet, mode: str = "supervised", *, random_state: int = 0,
                  classifier: EnvironmentClassifier | None = None,
                  diagnostics: dict | None = None, seeds: np.ndarray | None = None,
                  space: str = "features") -> tuple[EnvironmentClassifier, dict]:
    """Fit the classifier of ``mode`` on ``data``; returns it and a summary of what it was fitted on.

    ``seeds`` (bool, shape (len(data),), ``mode="survey"`` only): the windows whose map labels name and shape
    the clusters — the semi-supervised survey mode (:mod:`training.semisup`; ``space``: where the labels are
    propagated, ``"features"`` or ``"embedding"``); the classifier then learns the propagated labels.

    ``diagnostics`` (a dict, optional) receives ``data`` (the windows used) and, in the clustering
    modes, ``clusters`` (:class:`training.clustering.ClusterResult`) — for the plots.
    """
    if mode not in MODES:
        raise ConfigError(f"mode must be one of {MODES}, got {mode!r}")
    if seeds is not None:
        seeds = np.asarray(seeds, bool)
        if mode != "survey":
            raise ConfigError(f"labelled seed cells apply to mode 'survey' only, not {mode!r}")
        if seeds.shape != (len(data),):
            raise ConfigError(f"seeds must have shape ({len(data)},), got {seeds.shape}")
    usable = np.isfinite(data.X).any(axis=1)
    if usable.sum() < 30:
        raise DataError(f"only {int(usable.sum())} windows have any feature; the environment model needs at least 30")
    data = data.subset(usable)
    if seeds is not None:
        seeds = seeds[usable]
    const = [FEATURES[j] for j in range(len(FEATURES))
             if np.isfinite(data.X[:, j]).any() and np.nanstd(data.X[:, j]) < 1e-12]
    clf = classifier or EnvironmentClassifier()
    if mode == "supervised":
        ok = data.label >= 0
        if ok.sum() < 30:
            raise DataError("supervised mode needs map labels: fewer than 30 windows lie in labelled cells")
        labels, X = data.label[ok], data.X[ok]
        present = np.unique(labels)
        if present.size < 2:
            raise DataError(f"every labelled window is {ENV_CLASSES[int(present[0])]!r}: an environment model needs "
                            "windows of at least two classes (survey more of the site, or other sites)")
        share = data.share[ok] if np.isfinite(data.share[ok]).all() else None
        info = {"labels": "map"}
    else:
        from training.clustering import cluster_windows

        result = cluster_windows(data.X, random_state=random_state)
        if diagnostics is not None:
            diagnostics["clusters"] = result
        info = {}
        if seeds is None:
            classes = result.labels
        else:
            from training.semisup import seeded_labels

            seed_label = np.where(seeds, data.label, -1)
            classes, named, seed_warn = seeded_labels(data.X, seed_label, result, space=space)
            info = {"seed_cells": int(len(set(zip(data.site[seeds].tolist(), data.cell[seeds].tolist())))),
                    "seed_windows": int(np.sum(seed_label >= 0)),
                    "seed_class_counts": np.bincount(seed_label[seed_label >= 0], minlength=len(ENV_CLASSES)).tolist(),
                    "propagation": f"label spreading (kNN) on the {space}", "seed_warnings": seed_warn}
            if diagnostics is not None:
                diagnostics["named_clusters"] = named
        ok = classes >= 0
        labels, X = classes[ok], data.X[ok]
        if np.unique(labels).size < 2:
            raise DataError(f"the clustering found {np.unique(labels).size} cluster in {len(data)} windows: an "
                            "environment model needs at least two classes (a larger or more varied library, or "
                            "--mode supervised with map labels)")
        share = None            # map shares are for evaluation only in the unsupervised modes
        info.update({"labels": "clusters" if seeds is None else "propagated from labelled cells",
                     "n_clusters": int(result.n_clusters), "embedding": result.method})
        if seeds is None:
            info["warnings"] = naming_warnings(labels, data.share[ok], data.label[ok], len(data))
        else:
            info["warnings"] = info.pop("seed_warnings")
    clf.fit(X, labels, share=share)
    if diagnostics is not None:
        diagnostics["data"] = data
    info.update({"mode": mode, "n_windows": int(len(X)), "sites": sorted(set(data.site.tolist())),
                 "n_cells": int(len(set(zip(data.site.tolist(), data.cell.tolist())))),
                 "class_counts": np.bincount(labels, minlength=len(ENV_CLASSES)).tolist(),
                 "constant_features": const, "random_state": int(random_state),
                 "window_s": float(data.window_s), "hop_s": float(data.hop_s)})
    info.setdefault("warnings", [])
    return clf, info


SMALL_LIBRARY_WINDOWS = 300
"""Below this many windows a clustering mode's severity naming is warned about as fragile."""


def naming_warnings(names: np.ndarray, share: np.ndarray, label: np.ndarray, n_windows: int) -> list[str]:
    """Warnings about the severity naming of clusters (open / light / heavy by signed feature means).

    Where the cells carry map shares (evaluation data, never used to fit), a naming whose clusters' mean
    blocked share does not grow from open to heavy is upside down somewhere; where they carry map labels,
    a naming that agrees with them less often than a constant answer would is too. On a small library
    (fewer than :data:`SMALL_LIBRARY_WINDOWS` windows) the naming is fragile either way.
    """
    out = []
    names = np.asarray(names, int)
    share = np.asarray(share, float)
    present = [c for c in range(len(ENV_CLASSES)) if np.any((names == c) & np.isfinite(share))]
    means = {c: float(np.nanmean(share[names == c])) for c in present}
    order = [means[c] for c in present]
    if len(order) >= 2 and any(b <= a for a, b in zip(order, order[1:])):
        text = ", ".join(f"{ENV_CLASSES[c]} {100 * means[c]:.0f} %" for c in present)
        out.append(f"the clusters named by severity disagree with the cells' map shares (mean blocked sky: {text}; "
                   "it should grow from open to heavy): the naming is upside down on this library; do not use "
                   "this model, or use --mode supervised")
    lab = np.asarray(label, int)
    known = lab >= 0
    if known.sum() >= 10:
        agree = float(np.mean(names[known] == lab[known]))
        constant = float(np.max(np.bincount(lab[known], minlength=len(ENV_CLASSES))) / known.sum())
        if agree < constant:
            out.append(f"the cluster names agree with the cells' map labels on {100 * agree:.0f} % of windows, less "
                       f"than naming every window the most common class ({100 * constant:.0f} %)")
        out.extend(_class_warnings(names[known], lab[known]))
    if n_windows < SMALL_LIBRARY_WINDOWS:
        out.append(f"only {n_windows} windows: clusters and their severity names are fragile on a library this "
                   f"small (fewer than {SMALL_LIBRARY_WINDOWS}); check them with --plots")
    return out


def _class_warnings(names: np.ndarray, label: np.ndarray, min_windows: int = 10) -> list[str]:
    """Per class, where the labelled windows disagree with the naming: a class named for windows that the labels
    put mostly in another class, and classes the labels hold (at least ``min_windows`` windows) that no cluster
    was named — too few clusters, or two named alike."""
    out = []
    for c in range(len(ENV_CLASSES)):
        mine = label[names == c]
        if mine.size >= min_windows:
            counts = np.bincount(mine, minlength=len(ENV_CLASSES))
            top = int(np.argmax(counts))
            if top != c:
                out.append(f"the windows named {ENV_CLASSES[c]!r} are {100 * counts[top] / mine.size:.0f} % "
                           f"{ENV_CLASSES[top]!r} by the cells' map labels ({mine.size} labelled windows)")
    held = [c for c in range(len(ENV_CLASSES)) if np.sum(label == c) >= min_windows]
    missing = [ENV_CLASSES[c] for c in held if not np.any(names == c)]
    if missing:
        out.append(f"the labelled cells hold {', '.join(ENV_CLASSES[c] for c in held)} windows but no cluster was "
                   f"named {' or '.join(missing)}: the clustering found fewer classes than the labels show")
    return out


def save_env_model(clf: EnvironmentClassifier, path, info: dict, library: str | os.PathLike | None = None,
                   overwrite: bool = False) -> Path:
    """Save the classifier as an ``environment`` bundle with what it was fitted on."""
    params, arrays = clf.get_state()
    meta = dict(info)
    meta["cn0_reference"] = "per receiver, calibrated from the survey's own data (stored in the library)"
    if library is not None:
        meta["library"] = str(library)
        meta["library_sha256"] = sha256_file(Path(library))
    return save_bundle(path, "environment", params, {"classifier": arrays}, meta=meta, overwrite=overwrite)


def load_env_model(path) -> tuple[EnvironmentClassifier, dict]:
    """The classifier of an ``environment`` bundle and its metadata; beyond the bundle's hashes its numbers are
    checked (:func:`models.checks.check_classifier`: finite, of the expected shapes, a usable precision)."""
    from models.bundle import BundleError
    from models.checks import check_classifier

    b = load_bundle(path, "environment")
    try:
        clf = EnvironmentClassifier.from_state(b.params, b.arrays["classifier"])
        check_classifier(clf)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise BundleError(f"{path}: the environment model is inconsistent ({exc})") from None
    return clf, b.meta
