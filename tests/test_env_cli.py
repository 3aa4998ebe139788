"""train env (every mode, plots) and survey map through the CLI on a small simulated survey."""

import csv

import pytest

from pipeline.cli import main


@pytest.fixture(scope="module")
def library(site_dir, tmp_path_factory):
    from fingerprints.survey import build_library
    from simulation.survey import simulate_survey

    d = tmp_path_factory.mktemp("envcli")
    # Re-pinned seed 9 → 10 (issue 21 item 6): the survey mode clusters this 35-cell survey's 105 windows without
    # labels and needs two classes among the clusters; removing the 33 discharge pulses of seed 9's audio before
    # the matched filter moved 17 windows' CIR features by at most 0.03 ms / 0.9 dB, and its clustering from
    # three clusters to one ("no sub-model could be fitted"). The test is about the CLI's plumbing in every
    # mode, not clustering quality (bench/env_study.py measures that); seeds 10 and 11 pass in every mode.
    survey = simulate_survey(site_dir, d / "survey", seed=10, cell_size_m=20.0, capture_s=4.0, progress=False)
    build_library(survey, d / "fp.sqlite", progress=False)
    return survey, d / "fp.sqlite"


@pytest.mark.parametrize("mode", ["supervised", "survey"])
def test_train_env_and_survey_map(library, tmp_path, capsys, mode):
    survey, lib = library
    code = main(["train", "env", "--library", str(lib), "--mode", mode, "--out", str(tmp_path / "m"),
                 "--plots", str(tmp_path / "plots")])
    assert code == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert f"environment model ({mode})" in out
    pngs = {p.name for p in (tmp_path / "plots").glob("*.png")}
    assert "confusion.png" in pngs and (mode == "supervised" or {"decision_graph.png", "tsne_map.png"} <= pngs)
    code = main(["survey", "map", str(survey), "--library", str(lib), "--model", str(tmp_path / "m"),
                 "--out", str(tmp_path / "map.png"), "--csv", str(tmp_path / "cells.csv")])
    assert code == 0
    out = capsys.readouterr().out
    assert "per-class accuracy against map labels" in out and "confusion" in out
    rows = list(csv.DictReader(open(tmp_path / "cells.csv")))
    assert len(rows) == len(list((survey / "cells").iterdir()))
    assert set(rows[0]) == {"cell_id", "east_m", "north_m", "predicted", "probability", "occlusion_estimate", "ood",
                            "map_label", "map_share"}
    assert all(r["predicted"] in ("open", "light", "heavy") and 0 < float(r["probability"]) <= 1 for r in rows)
    if mode == "supervised":
        agree = sum(r["predicted"] == r["map_label"] for r in rows) / len(rows)
        assert agree > 0.5                  # in-sample: the labels it was fitted on (change detector)
    assert (tmp_path / "map.png").stat().st_size > 20_000


def test_env_cli_bad_input(library, tmp_path, capsys):
    survey, lib = library
    assert main(["train", "env", "--library", str(tmp_path / "none.sqlite"), "--out", str(tmp_path / "m")]) == 1
    assert "no such file" in capsys.readouterr().err
    assert main(["train", "env", "--library", str(lib), "--site", "nowhere", "--out", str(tmp_path / "m")]) == 1
    assert "no site ['nowhere']" in capsys.readouterr().err
    assert main(["survey", "map", str(survey), "--library", str(lib), "--model", str(tmp_path / "nomodel"),
                 "--out", str(tmp_path / "map.png")]) == 1
    assert "not a model directory" in capsys.readouterr().err
    assert not (tmp_path / "map.png").exists()


def test_survey_map_checks_both_outputs_before_writing_either(library, tmp_path, capsys):
    """(Bad-input tour: with ``--csv`` under a file, the map was drawn and written, then the CSV failed.) Neither
    output is written when one cannot be: one line naming the option, exit 1."""
    survey, lib = library
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["survey", "map", str(survey), "--library", str(lib), "--model", "default",
                 "--out", str(tmp_path / "map.png"), "--csv", str(blocker / "cells.csv")]) == 1
    err = capsys.readouterr().err
    assert "cannot write --csv" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]
