"""The semi-supervised survey mode (issue 27 item 4): labelled cells name and shape the clusters."""

import shutil
import sqlite3

import numpy as np
import pytest

from features.errors import DataError
from features.schema import ENV_CLASSES
from pipeline.cli import main
from training.semisup import ALPHA, N_NEIGHBORS, name_by_seeds, propagate_labels, seeded_labels

from .env_synth import synthetic_library


def _training_set(X, label):
    from training.env import TrainingSet

    n = len(X)
    rank = np.empty(n, int)
    rank[np.argsort(label, kind="stable")] = np.arange(n)
    cell = np.array([f"c{r // 5:04d}" for r in rank])               # five windows of one class per cell
    return TrainingSet(X, np.full(n, "synth"), cell, np.asarray(label, int), np.full(n, np.nan),
                       np.arange(n, dtype=float))


def test_labelled_cells_name_clusters_where_severity_naming_is_wrong():
    """Three well-separated blobs whose true classes run against the severity features (the most attenuated
    blob is 'open' here, as a site with a strong but harmless attenuator would be): severity names them upside
    down, a few labelled windows per blob name them right, with a warning for each renamed cluster."""
    from training.clustering import cluster_windows

    X, sev = synthetic_library(450, seed=3)
    truth = 2 - sev                                    # the severity order reversed: open <-> heavy
    clusters = cluster_windows(X, random_state=0)
    assert np.mean(clusters.labels == truth) < 0.4     # severity naming: light right, open and heavy swapped
    rng = np.random.default_rng(0)
    seed_label = np.full(len(X), -1)
    for c in range(3):
        pick = rng.choice(np.flatnonzero(truth == c), 4, replace=False)
        seed_label[pick] = c
    named, warnings = name_by_seeds(clusters.clusters, clusters.labels, seed_label)
    assert np.mean(named == truth) > 0.95
    assert sum("named 'open' by the labelled cells" in w for w in warnings) >= 1
    assert sum("named 'heavy' by the labelled cells" in w for w in warnings) >= 1
    # a cluster without labelled windows keeps its severity name
    only_open = np.where(truth == 0, seed_label, -1)
    named, warnings = name_by_seeds(clusters.clusters, clusters.labels, only_open)
    heavy_blob = truth == 2
    assert np.mean(named[heavy_blob] == clusters.labels[heavy_blob]) > 0.95


def test_name_by_seeds_hand_case():
    cluster = np.array([0, 0, 0, 1, 1, 1, -1])
    severity = np.array([0, 0, 0, 2, 2, 2, -1])
    seeds = np.array([2, 2, 0, -1, -1, -1, 1])        # cluster 0: two heavy, one open → heavy; cluster 1: none
    named, warnings = name_by_seeds(cluster, severity, seeds)
    assert named.tolist() == [2, 2, 2, 2, 2, 2, -1]
    assert len(warnings) == 1 and warnings[0].startswith("cluster 0 (3 windows)")


def test_propagation_on_a_line_splits_at_the_midpoint():
    """Hand case: ten points on a line, seeds at the two ends; by symmetry of the kNN graph, each half takes
    its end's class."""
    Z = np.arange(10.0)[:, None]
    y = np.full(10, -1)
    y[0], y[9] = 0, 2
    labels, proba = propagate_labels(Z, y, n_neighbors=3)   # itself and both neighbours: a symmetric graph
    assert labels.tolist() == [0] * 5 + [2] * 5
    assert np.allclose(proba.sum(axis=1), 1.0) and np.all(proba[:, 1] == 0)


def _bridge(seed):
    """Open and heavy: dense Gaussian blobs at 0 and 10 on the first axis; light: uniform over [3, 7] between
    them, with no density peak of its own (its density, 120/4 per unit, is below each blob's peak, 300/√(2π))."""
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.normal(0, 1, 300), rng.uniform(3, 7, 120), rng.normal(10, 1, 300)])
    Z = np.column_stack([x, rng.normal(0, 0.5, len(x))])
    truth = np.repeat([0, 1, 2], [300, 120, 300])
    return Z, truth


def test_propagation_recovers_a_class_without_a_density_peak():
    from sklearn.semi_supervised import LabelSpreading

    from models.dpc import DensityPeakClustering

    Z, truth = _bridge(1)
    # density peaks find the two blobs only (the decision graph's γ gap): light is no cluster of its own
    dpc = DensityPeakClustering(kernel="gaussian").fit(Z)
    assert dpc.n_clusters_ == 2
    rng = np.random.default_rng(2)
    y = np.full(len(Z), -1)
    for c in range(3):
        y[rng.choice(np.flatnonzero(truth == c), 5, replace=False)] = c
    labels, _ = propagate_labels(Z, y)
    recall = [np.mean(labels[truth == c] == c) for c in range(3)]
    assert recall[1] > 0.8 and min(recall) > 0.8
    # the same as scikit-learn's LabelSpreading called directly (same parameters; this data has no kNN ties)
    ref = LabelSpreading(kernel="knn", n_neighbors=N_NEIGHBORS, alpha=ALPHA, max_iter=1000, tol=1e-6).fit(Z, y)
    assert np.mean(ref.transduction_ == labels) > 0.99
    # independent of the row order
    perm = np.random.default_rng(3).permutation(len(Z))
    again, _ = propagate_labels(Z[perm], y[perm])
    assert np.array_equal(again, labels[perm])


def test_seeded_labels_refuse_one_class_and_fit_env_model_semisupervised():
    from training.clustering import cluster_windows
    from training.env import fit_env_model

    X, sev = synthetic_library(300, seed=4)
    clusters = cluster_windows(X, random_state=0)
    one = np.full(len(X), -1)
    one[np.flatnonzero(sev == 0)[:10]] = 0
    with pytest.raises(DataError, match="all of one class"):
        seeded_labels(X, one, clusters)
    data = _training_set(X, sev)
    seeds = np.isin(data.cell, ["c0000", "c0001", "c0010", "c0030", "c0031", "c0050", "c0051", "c0058"])
    assert np.unique(sev[seeds]).size == 3
    clf, info = fit_env_model(data, "survey", seeds=seeds)
    assert info["labels"] == "propagated from labelled cells" and info["seed_cells"] == 8
    assert np.mean(clf.predict(X) == sev) > 0.9     # independent truth: the classes the windows were drawn from
    with pytest.raises(Exception, match="mode 'survey' only"):
        fit_env_model(data, "supervised", seeds=seeds)


@pytest.fixture(scope="module")
def library(site_dir, tmp_path_factory):
    from fingerprints.survey import build_library
    from simulation.survey import simulate_survey

    d = tmp_path_factory.mktemp("semisup")
    survey = simulate_survey(site_dir, d / "survey", seed=10, cell_size_m=20.0, capture_s=4.0, progress=False)
    build_library(survey, d / "fp.sqlite", progress=False)
    return survey, d / "fp.sqlite"


def _cells_by_class(lib):
    from training.env import training_set

    ts = training_set(lib)
    out = {}
    for cell, label in sorted(set(zip(ts.cell.tolist(), ts.label.tolist()))):
        out.setdefault(int(label), []).append(cell)
    return out


def test_cli_semisupervised_survey(library, tmp_path, capsys):
    import json

    survey, lib = library
    by_class = _cells_by_class(lib)
    held = [c for c in range(3) if c in by_class]
    assert len(held) >= 2
    cells = [cell for c in held for cell in by_class[c][:2]]
    argv = ["train", "env", "--library", str(lib), "--mode", "survey", "--out", str(tmp_path / "m")]
    for cell in cells:
        argv += ["--cell", cell]
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert f"semi-supervised: {len(cells)} labelled cells" in captured.out
    assert "environment model (survey)" in captured.out
    meta = json.loads((tmp_path / "m" / "bundle.json").read_text())["meta"]
    assert meta["seed_cells"] == len(cells) and meta["labels"] == "propagated from labelled cells"
    # deterministic: the same cells given in another order give the same weights
    argv2 = ["train", "env", "--library", str(lib), "--mode", "survey", "--out", str(tmp_path / "m2")]
    for cell in reversed(cells):
        argv2 += ["--cell", cell]
    assert main(argv2) == 0
    capsys.readouterr()
    weights = sorted(p.name for p in (tmp_path / "m").glob("*.safetensors"))
    assert weights and all((tmp_path / "m" / w).read_bytes() == (tmp_path / "m2" / w).read_bytes() for w in weights)


def test_cli_semisupervised_bad_inputs(library, tmp_path, capsys):
    survey, lib = library
    by_class = _cells_by_class(lib)
    base = ["train", "env", "--library", str(lib), "--mode", "survey", "--out", str(tmp_path / "m")]
    assert main(base + ["--cell", "E999N999"]) == 1
    err = capsys.readouterr().err
    assert "no such cell" in err and "Traceback" not in err
    some = max(by_class.values(), key=len)
    assert main(base + ["--cell", some[0], "--cell", some[1]]) == 1
    err = capsys.readouterr().err
    assert "all of one class" in err and "Traceback" not in err
    # a cell without a map label
    lib2 = tmp_path / "fp.sqlite"
    shutil.copy(lib, lib2)
    other = next(v for k, v in by_class.items() if v is not some)
    with sqlite3.connect(lib2) as con:
        con.execute("UPDATE cells SET map_label = NULL WHERE cell_id = ?", (other[0],))
    code = main(["train", "env", "--library", str(lib2), "--mode", "survey", "--out", str(tmp_path / "m"),
                 "--cell", some[0], "--cell", other[0]])
    err = capsys.readouterr().err
    assert code == 1 and f"--cell {other[0]}: no map label" in err and "Traceback" not in err
    assert main(["train", "env", "--library", str(lib), "--mode", "supervised", "--cell", some[0],
                 "--out", str(tmp_path / "m")]) == 2
    assert "--cell applies to --mode finetune and --mode survey only" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()
    assert ENV_CLASSES == ("open", "light", "heavy")


def test_a_class_no_labelled_cell_holds_is_seeded_by_its_severity_named_cluster():
    """Seeds of open and light only: the unlabelled cluster the severity order names heavy seeds heavy (the
    fallback of the naming); without the fallback no window can be heavy."""
    from training.clustering import cluster_windows

    X, truth = synthetic_library(450, seed=3)
    clusters = cluster_windows(X, random_state=0)
    rng = np.random.default_rng(1)
    seed_label = np.full(len(X), -1)
    for c in (0, 1):
        seed_label[rng.choice(np.flatnonzero(truth == c), 5, replace=False)] = c
    labels, _, warnings = seeded_labels(X, seed_label, clusters)
    assert np.mean(labels[truth == 2] == 2) > 0.9 and np.mean(labels == truth) > 0.9
    assert any("named 'heavy' by severity seed that class" in w for w in warnings)
    labels, _, warnings = seeded_labels(X, seed_label, clusters, fallback=False)
    assert not np.any(labels == 2)
    assert any("no labelled cell is heavy: the model cannot learn that class" in w for w in warnings)
