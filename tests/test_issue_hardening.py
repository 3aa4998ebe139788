"""Issue 20: behaviour the corpus cannot show in one command — recalibration across builds, cluster names that
disagree with the map, model folders readable by colleagues, links out of a bundle, a report that is complete
or visibly not, progress in a log, the summary's words."""

from __future__ import annotations

import os
import shutil
import stat
import warnings

import numpy as np
import pytest

from fingerprints.library import FingerprintLibrary
from fingerprints.survey import SurveyConfig, SurveyWarning, build_library


def test_a_receiver_stored_uncalibrated_is_recalibrated_with_replace(bad_input_world, tmp_path):
    survey = bad_input_world.survey
    lib = tmp_path / "fp.sqlite"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SurveyWarning)
        first = build_library(survey, lib, SurveyConfig(cn0_min_per_bin=10 ** 6), progress=False)
    assert first.receivers == {"default": False}
    with FingerprintLibrary.open(lib) as fp:
        before = fp.cell_feature_params()
    with pytest.warns(SurveyWarning, match="pass --replace"):
        again = build_library(survey, lib, progress=False)          # can calibrate now, but is not told to
    assert again.receivers == {"default": False} and again.unchanged == 3
    fixed = build_library(survey, lib, replace=True, progress=False)
    assert fixed.receivers == {"default": True} and fixed.replaced == 3
    with FingerprintLibrary.open(lib) as fp:
        rec = fp.receiver(first.site, "default")
        after = fp.cell_feature_params()
    assert rec.calibrated and rec.reference.to_dict() != before[(first.site, "c0")]["cn0_reference"]
    assert all(p["cn0_reference"] == rec.reference.to_dict() for p in after.values())


def test_cluster_names_against_the_map_shares_by_hand():
    from training.env import SMALL_LIBRARY_WINDOWS, naming_warnings

    names = np.array([0] * 10 + [1] * 10 + [2] * 10)
    right = np.array([0.05] * 10 + [0.25] * 10 + [0.6] * 10)
    labels = np.array([0] * 10 + [1] * 10 + [2] * 10)
    assert naming_warnings(names, right, labels, SMALL_LIBRARY_WINDOWS) == []
    upside_down = right[::-1]                 # the cells named heavy are the open ones
    w = naming_warnings(names, upside_down, np.full(30, -1), SMALL_LIBRARY_WINDOWS)
    assert len(w) == 1 and "upside down" in w[0] and "open 60 %" in w[0] and "heavy 5 %" in w[0]
    # labels only (no shares): named open/heavy, labelled heavy/open → 0 % agreement, below the 50 % of one answer
    w = naming_warnings(np.array([0] * 10 + [2] * 10), np.full(20, np.nan), np.array([2] * 10 + [0] * 10),
                        SMALL_LIBRARY_WINDOWS)
    assert w[0] == ("the cluster names agree with the cells' map labels on 0 % of windows, less than naming every "
                    "window the most common class (50 %)")
    # and per class (issue 27): what each name holds by the labels
    assert w[1:] == ["the windows named 'open' are 100 % 'heavy' by the cells' map labels (10 labelled windows)",
                     "the windows named 'heavy' are 100 % 'open' by the cells' map labels (10 labelled windows)"]
    assert "fragile" in naming_warnings(names, right, labels, 30)[0]


def test_model_folders_are_readable_by_colleagues_and_links_out_refused(tmp_path):
    from models.bundle import BundleError, load_bundle, save_bundle

    old = os.umask(0o022)
    try:
        p = save_bundle(tmp_path / "m", "test", {"a": 1}, {"w": {"x": np.arange(3.0)}})
    finally:
        os.umask(old)
    assert stat.S_IMODE(p.stat().st_mode) == 0o755
    assert {stat.S_IMODE(f.stat().st_mode) for f in p.iterdir()} == {0o644}
    outside = tmp_path / "elsewhere.safetensors"
    shutil.move(p / "w.safetensors", outside)
    (p / "w.safetensors").symlink_to(outside)
    with pytest.raises(BundleError, match="link out of the model folder"):
        load_bundle(p, "test")


def test_overwrite_replaces_only_a_model_of_the_same_kind(tmp_path):
    from models.bundle import BundleError, save_bundle

    save_bundle(tmp_path / "m", "fusion", {}, {"w": {"x": np.zeros(1)}})
    with pytest.raises(BundleError, match="holds a 'fusion' model"):
        save_bundle(tmp_path / "m", "environment", {}, {"w": {"x": np.zeros(1)}}, overwrite=True)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.txt").write_text("keep\n")
    with pytest.raises(BundleError, match="no envfuse model"):
        save_bundle(tmp_path / "notes", "fusion", {}, {"w": {"x": np.zeros(1)}}, overwrite=True)
    assert (tmp_path / "notes" / "a.txt").read_text() == "keep\n"
    save_bundle(tmp_path / "m", "fusion", {"v": 2}, {"w": {"x": np.ones(1)}}, overwrite=True)


def test_an_interrupted_evaluate_leaves_no_metrics_beside_new_plots(bad_input_world, tmp_path, monkeypatch):
    """metrics.csv goes first and comes back last: killed while plotting, a report has no metrics.csv (it is
    visibly incomplete) rather than old metrics beside new plots."""
    import pipeline.evaluate_plots as ep
    from pipeline.evaluate import evaluate

    W = bad_input_world
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "metrics.csv").write_text("walk,method\nold,old\n")

    def killed(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(ep, "plot_report", killed)
    with pytest.raises(KeyboardInterrupt):
        evaluate([W.w], W.fm, rep, methods=("kf",), workers=1, progress=False)
    assert not (rep / "metrics.csv").exists()


def test_progress_in_a_log_is_one_plain_line_per_walk(capsys):
    from pipeline.parallel import map_walks

    assert map_walks(len, ["a", "bb", "ccc"], workers=1, progress=True, desc="evaluate") == [1, 2, 3]
    err = capsys.readouterr().err
    assert "\r" not in err
    assert err.splitlines() == ["evaluate: 1/3 walks (33 %)", "evaluate: 2/3 walks (67 %)",
                                "evaluate: 3/3 walks (100 %)"]


def test_the_summary_explains_its_words():
    from pipeline.evaluate import bp_guard_line, summary_table

    row = {"walk": "all", "method": "kf", "env_class": "all", "n": 3, "mean_m": 1.0, "median_m": 1.0, "p95_m": 2.0,
           "max_m": 3.0, "nees_in_bounds": 0.9}
    text = summary_table([row])
    assert "NEES ok" in text and "chi-square(2) interval [0.05, 7.38]" in text and "about 0.95" in text
    line = bp_guard_line(1.0)
    assert "withheld on 100.0 %" in line and "adaptive is adaptive_nobp" in line and "guards (" in line


def test_walk_simulation_progress_names_the_walk_once_and_force_replaces_a_walk(site_dir, tmp_path, capsys):
    from pipeline.cli import main
    from simulation.walk import simulate_walk

    simulate_walk(site_dir, tmp_path / "walk", seed=2, duration_s=2.0, progress=True)
    err = capsys.readouterr().err
    assert "walk walk" not in err and "simulate walk 'walk': streams written" in err
    # --force replaces what simulate walk wrote (truth_steps.csv, audio_truth.csv included), nothing else
    argv = ["simulate", "walk", str(site_dir), "--seed", "3", "--duration-s", "2", "--out", str(tmp_path / "walk")]
    assert main(argv + ["--force"]) == 0
    (tmp_path / "walk" / "notes.txt").write_text("mine\n")
    assert main(argv + ["--force"]) == 2
    assert "holds other files" in capsys.readouterr().err and (tmp_path / "walk" / "notes.txt").is_file()
