"""Real channels (issue 13): the measured UWB CIRs of ../shared/data/cir_uwb clustered without labels.

``bench/uwb_clustering.py`` on a seeded subsample (40 valid packets of each of the 22 logs, seed 0,
880 packets) so that the test stays near 20 s; its module docstring has the full-data tables.
The figures are pinned from the code's own output (change detectors, two-sided bands), beside
the findings they carry: the forest on an unseen anchor is no better than that anchor's own
majority share, each anchor clustered alone beats the pooled clustering, and the severity score
orders the logs within an anchor almost exactly as their labels (35 of 36 pairs), across anchors
less well.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import SHARED_DATA

DATA = SHARED_DATA / "cir_uwb"
PACKETS_PER_FILE = 40


@pytest.fixture(scope="module")
def res():
    if not (DATA / "labels.csv").is_file() or not (DATA / "pairs.csv").is_file():
        pytest.skip(f"real UWB CIR data not found at {DATA} (../shared/data/cir_uwb)")
    from bench.uwb_clustering import run

    return run(packets_per_file=PACKETS_PER_FILE, seed=0, folder=DATA, groupings=("anchor",))


def test_subsample_is_seeded_and_balanced(res):
    data = res["data"]
    assert len(data.label) == 22 * PACKETS_PER_FILE
    assert np.all(np.bincount(data.file_id)[np.unique(data.file_id)] == PACKETS_PER_FILE)
    assert data.n_dropped == 89          # packets without a finite feature in the full logs
    assert sorted(np.unique(data.anchor).tolist()) == [1, 2, 3, 4]


def test_pooled_clustering_scores(res):
    runs = res["scopes"][0].runs
    assert res["scopes"][0].name == "pooled"
    pinned = {"dpc": (2, 0.198, 0.550), "tsne_dpc": (3, 0.065, 0.320), "kmeans": (3, 0.335, 0.655)}
    for method, (k, ari, acc) in pinned.items():
        assert runs[method].n_clusters == k, method
        assert runs[method].ari == pytest.approx(ari, abs=0.02), method
        assert runs[method].accuracy == pytest.approx(acc, abs=0.02), method


def test_per_site_clustering_scores(res):
    per = res["per_site"]
    pinned = {"dpc": (0.523, 0.292), "tsne_dpc": (0.673, 0.529), "kmeans": (0.555, 0.431)}
    for method, (acc, ari) in pinned.items():
        assert per[method]["accuracy"] == pytest.approx(acc, abs=0.02), method
        assert per[method]["ari_mean"] == pytest.approx(ari, abs=0.02), method
    assert per["tsne_dpc"]["files_right"] == 15
    # The paper's route on each anchor's own survey beats the same route pooled over anchors.
    assert per["tsne_dpc"]["accuracy"] > res["scopes"][0].runs["tsne_dpc"].accuracy + 0.2
    # Per anchor the t-SNE clusters are the logs (one geometry each) far more than the classes.
    for s in res["scopes"][1:]:
        assert s.runs["tsne_dpc"].ari_file > s.runs["tsne_dpc"].ari


def test_forest_on_unseen_anchors_is_at_the_majority_rate(res):
    f = res["forests"]["anchor"]
    assert f["accuracy"] == pytest.approx(0.506, abs=0.02)
    assert f["own_majority"] == pytest.approx(0.545, abs=0.005)
    assert f["train_majority"] == pytest.approx(0.273, abs=0.005)
    # No better than guessing each unseen anchor's own majority class, and anchor 4 falls below
    # even the training folds' majority rule.
    assert f["accuracy"] < f["own_majority"]
    a4 = next(x for x in f["folds"] if x["group"] == 4)
    assert a4["accuracy"] == pytest.approx(0.271, abs=0.03)
    assert a4["accuracy"] < a4["train_majority"]
    # The per-site unsupervised way beats it on the same packets.
    assert res["per_site"]["tsne_dpc"]["accuracy"] > f["accuracy"] + 0.1


def test_severity_order_of_logs(res):
    assert res["concordance"]["per site"] == (35, 36)
    assert res["concordance"]["pooled"] == (144, 159)


def test_same_seed_same_clusters(res):
    from bench.uwb_clustering import cluster_scope

    data = res["data"]
    m = data.anchor == 3
    a = cluster_scope(data.features[m], data.label[m], data.file_id[m], seed=0)
    b = cluster_scope(data.features[m], data.label[m], data.file_id[m], seed=0)
    s = res["scopes"][3]
    assert s.name == "anchor 3"
    for method in a:
        np.testing.assert_array_equal(a[method].labels, b[method].labels)
        np.testing.assert_array_equal(a[method].labels, s.runs[method].labels)


def test_labelled_reader_names_what_is_missing(tmp_path):
    from features.acoustic.uwb import read_labelled_uwb
    from features.errors import DataError

    with pytest.raises(DataError, match="labels.csv does not exist"):
        read_labelled_uwb(tmp_path)
    (tmp_path / "labels.csv").write_text("file_id,label\n1,LOS\n")
    (tmp_path / "pairs.csv").write_text("file_number,anchor_location,tag_location\n1,1,1\n")
    with pytest.raises(DataError, match="no <id>.log.gz"):
        read_labelled_uwb(tmp_path)
    (tmp_path / "7.log.gz").write_bytes(b"")
    with pytest.raises(DataError, match="file id 7 missing"):
        read_labelled_uwb(tmp_path)
    (tmp_path / "pairs.csv").write_text("file,anchor\n1,1\n")
    with pytest.raises(DataError, match="expected columns"):
        read_labelled_uwb(tmp_path)
