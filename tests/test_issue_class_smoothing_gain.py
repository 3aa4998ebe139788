"""Issue 27, the fusion gain of the smoothed classes: the ``class_smoothing`` option reaches the filters in training
and evaluation (``bench/env_fusion_gain.py`` compares ``forward`` with ``none``), leaves the class-blind twins
untouched, and a bad value is refused with one clear message."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from features.errors import ConfigError
from models.fusion.model import save_fusion_model
from walks.inputs import window_features

ROOT = Path(__file__).resolve().parents[1]


def test_evaluate_hands_the_filters_the_classes_asked_for_and_the_blind_twin_ignores_them(model_and_walk, walk_dir,
                                                                                        tmp_path):
    from pipeline import evaluate as ev

    model, data = model_and_walk
    save_fusion_model(model, tmp_path / "fm")
    ev._MODELS.clear()
    methods = ("adaptive_nobp", "adaptive_nobp_blind")
    runs = {s: ev.evaluate_walk(walk_dir, str(tmp_path / "fm"), methods, class_smoothing=s)
            for s in ("none", "forward")}
    # the classes the filters got: "none" is the classifier's own answer per window (independent reference:
    # predict_proba on the window features), "forward" the HMM's filtered ones, which differ
    t, X = window_features(data)
    raw = model.classifier.predict_proba(X)
    assert np.allclose(runs["none"]["series"]["_windows"]["proba"], raw, atol=1e-6)
    assert not np.allclose(runs["forward"]["series"]["_windows"]["proba"], raw, atol=1e-3)
    # so the class-aware filter's track changes while its blind twin's is the same to the bit
    aware = [runs[s]["series"]["adaptive_nobp"]["err_m"] for s in ("none", "forward")]
    blind = [runs[s]["series"]["adaptive_nobp_blind"]["err_m"] for s in ("none", "forward")]
    assert np.array_equal(blind[0], blind[1])
    assert aware[0].shape == aware[1].shape and not np.array_equal(aware[0], aware[1])


def test_train_fusion_fits_on_the_classes_asked_for(model_and_walk, walk_dir, monkeypatch):
    import training.filters as tf

    model, data = model_and_walk
    seen = []
    real = tf.walk_inputs

    def spy(data, classifier, temporal=None, smoothing="forward"):
        out = real(data, classifier, temporal, smoothing)
        seen.append((temporal is not None, smoothing, out.classes.proba[1:]))
        return out

    monkeypatch.setattr(tf, "walk_inputs", spy)
    fitted = {}
    for s in ("none", "forward"):
        fitted[s] = tf.train_fusion([walk_dir], model.classifier, bp=False, tune=False, calibrate=False,
                                    class_smoothing=s)
    assert [x[:2] for x in seen] == [(True, "none"), (True, "forward")]   # the HMM fitted in both, used in one
    # what the noise fit, the tuning, BP and calibration are given: the classifier's answer per window with
    # "none" (independent reference: predict_proba on the window features), the HMM's filtered classes otherwise
    _, X = window_features(data)
    raw = model.classifier.predict_proba(X)
    assert np.allclose(seen[0][2], raw) and not np.allclose(seen[1][2], raw, atol=1e-3)
    assert fitted["none"].meta["class_smoothing"] == "none"
    assert fitted["forward"].meta["class_smoothing"] == "forward"


def test_a_bad_class_smoothing_is_refused_with_one_message(model_and_walk, walk_dir, tmp_path):
    from pipeline.evaluate import evaluate
    from training.filters import train_fusion

    model, _ = model_and_walk
    with pytest.raises(ConfigError, match="class smoothing must be one of none, forward, forward_backward, got 'hmm'"):
        train_fusion([walk_dir], model.classifier, class_smoothing="hmm")
    save_fusion_model(model, tmp_path / "fm")
    with pytest.raises(ConfigError, match="class smoothing must be one of .*'smoothed'"):
        evaluate([walk_dir], tmp_path / "fm", tmp_path / "report", class_smoothing="smoothed")
    assert not (tmp_path / "report").exists()            # refused before any walk ran or any file was written
    r = subprocess.run([sys.executable, str(ROOT / "bench" / "fusion_study.py"), "--out", str(tmp_path / "s"),
                        "--class-smoothing", "both"], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "--class-smoothing: invalid choice: 'both'" in r.stderr
