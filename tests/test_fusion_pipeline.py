"""Fusion on one code path: step splitting, every method on a simulated walk, bundles, the CLI end to end."""

import csv
import json

import numpy as np
import pytest

from models.environment import EnvironmentClassifier
from models.fusion.model import load_fusion_model, save_fusion_model
from pipeline.cli import main
from training.filters import train_fusion
from walks.inputs import split_steps, walk_inputs, window_features
from walks.methods import method_names, run_methods
from walks.reader import read_walk
from walks.score import score


def test_split_steps_keeps_each_step_and_cuts_at_fixes():
    t = np.array([1.0, 1.5, 5.0])
    length = np.array([0.7, 0.6, 0.8])
    heading = np.array([0.0, 0.1, 0.2])
    fixes = np.array([0.6, 1.2, 1.4, 4.6, 4.8, 7.0])
    ts, ls, hs = split_steps(t, length, heading, fixes)
    # step 1 follows a stop: it lasted 0.55 s (0.45 → 1.0), cut at the fix at 0.6
    assert ts[:2].tolist() == [0.6, 1.0] and ls[:2] == pytest.approx([0.7 * 0.15 / 0.55, 0.7 * 0.4 / 0.55])
    # step 2 (1.0 → 1.5) is cut at 1.2 and 1.4; step 3 follows a 3.5 s stop: 4.45 → 5.0, cut at 4.6 and 4.8
    assert ts[2:].tolist() == [1.2, 1.4, 1.5, 4.6, 4.8, 5.0]
    assert ls[2:5].sum() == pytest.approx(0.6) and ls[5:].sum() == pytest.approx(0.8)
    assert hs.tolist() == [0.0] * 2 + [0.1] * 3 + [0.2] * 3
    assert np.all(np.diff(ts) > 0)


@pytest.fixture(scope="module")
def trained(walk_dir):
    data = read_walk(walk_dir)
    t, X = window_features(data)
    y = data.truth.class_at(t - 1.0)
    clf = EnvironmentClassifier(min_samples=5).fit(X, y)
    from models.bp import BPConfig

    model = train_fusion([walk_dir], clf, bp_config=BPConfig(n_members=2, epochs=60))
    return data, model


def test_every_method_runs_and_the_device_aware_filter_follows_rtk(trained):
    data, model = trained
    inputs = walk_inputs(data, model.classifier)
    tracks, skipped = run_methods(model, inputs)
    # no site map given here; the graph kernel tables (fg_env, fg_blind) are fitted by training.graph_fit,
    # which train_fusion does not run (issue 23)
    assert set(skipped) == {"kf_map", "fg_env", "fg_blind"}
    assert set(method_names()) - set(skipped) <= set(tracks)
    assert {m + "+rts" for m in ("kf", "kf_quality", "aekf", "imm", "adaptive_nobp")} <= set(tracks)
    rows = {(r["method"], r["env_class"]): r for r in score(tracks, data, "w")}
    gnss, kfq, pdr = rows[("gnss", "all")], rows[("kf_quality", "all")], rows[("pdr", "all")]
    # Fused with what the receiver reports (mostly RTK fixed on this site), the filter stays at the
    # fixes' level; PDR alone drifts by metres. Change detectors on one simulated walk (site 3, seed 11):
    assert kfq["median_m"] < 3 * max(gnss["median_m"], 0.01)
    assert kfq["p95_m"] < pdr["p95_m"]
    assert rows[("adaptive_nobp", "all")]["median_m"] < 3 * max(gnss["median_m"], 0.01)
    for m in ("kf", "kf_quality", "adaptive_nobp"):
        assert 0.0 <= rows[(m, "all")]["nees_in_bounds"] <= 1.0
    # train_fusion counted the class changes of its walk (issue 27): run's classes are the HMM's causal ones
    assert model.temporal is not None and model.temporal.counts_.sum() >= 30
    # The class evidence is causal: nothing before the first window's end but the prior.
    assert np.allclose(inputs.classes.at(np.array([inputs.window_t_s[0] - 0.01]))[0], model.classifier.prior_)


def test_bundle_round_trip_gives_the_same_track(trained, tmp_path):
    data, model = trained
    save_fusion_model(model, tmp_path / "m")
    again = load_fusion_model(tmp_path / "m")
    a, _ = run_methods(model, walk_inputs(data, model.classifier), ("adaptive", "kf_quality"), smooth=False)
    b, _ = run_methods(again, walk_inputs(data, again.classifier), ("adaptive", "kf_quality"), smooth=False)
    for m in ("adaptive", "kf_quality"):
        assert np.array_equal(a[m].east_m, b[m].east_m) and np.array_equal(a[m].north_m, b[m].north_m)
        # the covariance calibrators survive the bundle: the same scale, so the same reported covariance
        assert "cov_scale" in a[m].info and np.allclose(a[m].info["cov_scale"], b[m].info["cov_scale"], rtol=1e-12)
        assert np.allclose(a[m].cov_m2, b[m].cov_m2, rtol=1e-12)


def test_cli_train_run_evaluate(trained, walk_dir, tmp_path, capsys):
    _, model = trained
    save_fusion_model(model, tmp_path / "fm")
    assert main(["run", str(walk_dir), "--model", str(tmp_path / "fm"), "--out", str(tmp_path / "t.csv")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "t.csv")))
    assert len(rows) > 100 and rows[0]["time_utc"].endswith("Z") and rows[0]["env_class"] in ("open", "light", "heavy")
    assert abs(float(rows[0]["lat_deg"])) > 1 and float(rows[10]["var_east_m2"]) > 0
    # run's default is the quality-aware filter's fixed-lag track: not its zero-latency one, not the context
    # model's (the default until 2026-12-03)
    for m in ("kf_quality+lag", "kf_quality", "adaptive_blind+lag"):
        assert main(["run", str(walk_dir), "--model", str(tmp_path / "fm"), "--out", str(tmp_path / f"{m}.csv"),
                     "--method", m]) == 0
    text = (tmp_path / "t.csv").read_text()
    assert text == (tmp_path / "kf_quality+lag.csv").read_text()
    assert text != (tmp_path / "kf_quality.csv").read_text() and text != (tmp_path / "adaptive_blind+lag.csv").read_text()
    assert main(["run", str(walk_dir), "--model", str(tmp_path / "fm"), "--out", str(tmp_path / "t.geojson"),
                 "--method", "kf+rts"]) == 0
    gj = json.loads((tmp_path / "t.geojson").read_text())
    assert gj["type"] == "FeatureCollection" and gj["features"][0]["geometry"]["type"] == "LineString"
    code = main(["evaluate", str(walk_dir), "--model", str(tmp_path / "fm"), "--report", str(tmp_path / "rep"),
                 "--workers", "1", "--methods", "gnss", "kf", "adaptive"])
    assert code == 0
    out = capsys.readouterr().out
    assert "adaptive" in out and "kf" in out
    metrics = list(csv.DictReader(open(tmp_path / "rep" / "metrics.csv")))
    assert {r["method"] for r in metrics} == {"gnss", "kf", "kf+rts", "kf+lag", "adaptive", "adaptive+rts",
                                              "adaptive+lag"}
    assert {r["env_class"] for r in metrics} >= {"all"}
    assert {p.name for p in (tmp_path / "rep").glob("*.png")} >= {"error_cdf.png", "error_by_class.png"}


def test_cli_refuses_bad_models_and_walks(walk_dir, tmp_path, capsys):
    (tmp_path / "bad").mkdir()
    assert main(["run", str(walk_dir), "--model", str(tmp_path / "bad"), "--out", str(tmp_path / "t.csv")]) == 1
    assert "no bundle.json" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path), "--model", str(tmp_path / "bad"), "--report", str(tmp_path / "r")]) == 1
    assert "no walk.toml" in capsys.readouterr().err
    assert not (tmp_path / "t.csv").exists()


def test_evaluate_on_dask_equals_serial(trained, walk_dir, site_dir, tmp_path):
    """Each walk is a pure task of its files and the bundle: two local workers give the serial metrics, in the
    input order — on distinct walks (the whole walk, then its first 20 s without audio, which finishes first),
    so that results put in completion order would show."""
    from pipeline.evaluate import evaluate
    from tests.bad_inputs import _trim_walk

    _, model = trained
    save_fusion_model(model, tmp_path / "fm")
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "site.toml").write_bytes((site_dir / "site.toml").read_bytes())
    _trim_walk(walk_dir, tmp_path / "walks" / "short", 20.0, "../../site/site.toml", audio=False)
    walks = [walk_dir, tmp_path / "walks" / "short"]
    a = evaluate(walks, tmp_path / "fm", tmp_path / "r1", methods=("kf", "adaptive"), workers=1, progress=False,
                 plots=False)
    b = evaluate(walks, tmp_path / "fm", tmp_path / "r2", methods=("kf", "adaptive"), workers=2, progress=False,
                 plots=False)
    assert [r["walk_dir"] for r in b["results"]] == [str(w) for w in walks]
    assert a["results"][0]["rows"] != a["results"][1]["rows"]           # distinct walks, distinct metrics
    assert (tmp_path / "r1" / "metrics.csv").read_text() == (tmp_path / "r2" / "metrics.csv").read_text()
    assert [r["rows"] for r in a["results"]] == [r["rows"] for r in b["results"]]
