"""``foot_ins_fkf`` through the method registry and ``run``: on a simulated walk with a foot IMU and UWB, on the
same walk without UWB (INS + heading, said in the note), and skipped with its reason where the walk has no foot
IMU, while every other method runs as before."""

from __future__ import annotations

import csv
import shutil

import numpy as np
import pytest


@pytest.fixture(scope="module")
def light_walk(walk_dir, tmp_path_factory):
    """The session walk without its audio (fast to read): every other stream, the foot IMU and UWB included."""
    from features.fileio import read_toml, write_toml

    d = tmp_path_factory.mktemp("foot") / "w"
    shutil.copytree(walk_dir, d, ignore=shutil.ignore_patterns("audio*"))
    doc = read_toml(d / "walk.toml")
    doc.pop("audio", None)
    doc["site"] = str((walk_dir / doc["site"]).resolve())
    write_toml(d / "walk.toml", doc)
    return d


@pytest.fixture(scope="module")
def model(light_walk):
    from models.environment import EnvironmentClassifier
    from training.filters import DEFAULT_EKF, fit_fusion_model, training_rows
    from walks.inputs import walk_inputs, window_features
    from walks.reader import read_walk

    data = read_walk(light_walk)
    t, X = window_features(data)
    clf = EnvironmentClassifier(min_samples=5).fit(X, data.truth.class_at(t - 1.0))
    return fit_fusion_model([training_rows(data, walk_inputs(data, clf), "w")], clf, None, ekf=DEFAULT_EKF)


def _run(walk, model, names=("gnss", "foot_ins_fkf")):
    from walks.inputs import walk_inputs
    from walks.methods import run_methods
    from walks.reader import read_walk

    data = read_walk(walk)
    tracks, skipped = run_methods(model, walk_inputs(data, model.classifier), names, smooth=False, lag_s=None)
    return data, tracks, skipped


def _errors(data, track):
    e, n = data.truth.at(track.t_s)
    return np.hypot(track.east_m - e, track.north_m - n)


def test_foot_ins_fkf_with_uwb_and_heading(light_walk, model):
    from walks.methods import method_names

    assert "foot_ins_fkf" in method_names()
    data, tracks, skipped = _run(light_walk, model)
    assert skipped == {}
    tr = tracks["foot_ins_fkf"]
    assert "ZUPT-INS + UWB + heading" in tr.info["note"] and "beta 0.33, 0.33, 0.33" in tr.info["note"]
    err = _errors(data, tr)
    # measured 0.2-0.3 m mean on the simulated site-3 walks (UWB fixes σ ≈ 0.1-0.3 m, the foot 0.3 m off the tag)
    assert np.mean(err) < 0.6 and np.percentile(err, 95) < 1.5
    assert np.all(np.isfinite(tr.cov_m2)) and np.all(tr.cov_m2[:, 0, 0] > 0)
    assert tr.info["strides"] > 10 and 0.5 < tr.info["uwb_accepted_share"] <= 1.0


def test_without_uwb_the_ins_and_heading_run_and_say_so(light_walk, model, tmp_path):
    from features.fileio import read_toml, write_toml

    d = tmp_path / "no_uwb"
    shutil.copytree(light_walk, d, ignore=shutil.ignore_patterns("uwb*"))
    doc = read_toml(d / "walk.toml")
    doc.pop("uwb")
    write_toml(d / "walk.toml", doc)
    data, tracks, skipped = _run(d, model)
    tr = tracks["foot_ins_fkf"]
    assert "ZUPT-INS + heading (beta 0.50, 0.50)" in tr.info["note"] and "no uwb.csv" in tr.info["note"]
    # anchored at the first good GNSS fix, then dead reckoning on the foot for the rest of the minute
    assert np.mean(_errors(data, tr)) < 3.0


def test_walk_without_a_foot_imu_skips_it_and_runs_the_rest(light_walk, model, tmp_path):
    from features.fileio import read_toml, write_toml

    d = tmp_path / "old"
    shutil.copytree(light_walk, d, ignore=shutil.ignore_patterns("imu_foot*", "uwb*"))
    doc = read_toml(d / "walk.toml")
    doc.pop("imu_foot")
    doc.pop("uwb")
    write_toml(d / "walk.toml", doc)               # a walk written before the foot IMU existed
    _, tracks, skipped = _run(d, model, ("gnss", "kf_quality", "foot_ins_fkf"))
    assert skipped == {"foot_ins_fkf": "no imu_foot.csv (a foot-mounted IMU) in this walk"}
    assert {"gnss", "kf_quality"} <= set(tracks)
    b = tmp_path / "broken"
    shutil.copytree(light_walk, b)
    (b / "imu_foot.csv").write_text("t_s,ax,ay,az\n")
    _, _, skipped = _run(b, model, ("foot_ins_fkf",))
    assert skipped["foot_ins_fkf"].startswith("imu_foot.csv unusable")


def test_cli_run_writes_the_foot_track_and_its_note(light_walk, model, tmp_path, capsys):
    from models.fusion.model import save_fusion_model
    from pipeline.cli import main

    save_fusion_model(model, tmp_path / "fm")
    out = tmp_path / "foot.csv"
    assert main(["run", str(light_walk), "--model", str(tmp_path / "fm"), "--out", str(out),
                 "--method", "foot_ins_fkf"]) == 0
    rows = list(csv.DictReader(open(out)))
    assert len(rows) > 300 and float(rows[5]["var_east_m2"]) > 0
    assert "foot_ins_fkf: local filters ZUPT-INS + UWB + heading" in capsys.readouterr().err
