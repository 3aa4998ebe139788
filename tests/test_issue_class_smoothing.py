"""Issue 27 item 3: the class HMM between the online classifier and the fusion methods — fitted on training walks,
saved in the fusion bundle (old bundles still load), causal for ``run``, smoothed for ``evaluate``."""

import json

import numpy as np
import pytest

from models.bundle import BundleError
from models.fusion.model import load_fusion_model, save_fusion_model
from models.temporal import ClassHMM
from walks.inputs import smooth_classes, walk_inputs


class _Stub:
    """A classifier's two answers smooth_classes needs: its fit prior (frequencies: not class-balanced)."""

    def fit_prior(self):
        return np.array([0.5, 0.25, 0.25])


def test_smooth_classes_divides_by_the_prior_joins_gaps_and_skips_unanswered_windows():
    h = ClassHMM().fit([[0, 0, 0, 1, 1, 2, 2, 2, 1, 0]], hop_s=1.0)
    proba = np.array([[0.5, 0.25, 0.25], [0.2, 0.6, 0.2], [0.5, 0.25, 0.25], [0.1, 0.1, 0.8]])
    t_end = np.array([1.0, 2.0, 3.0, 6.0])                  # a gap of three hops before the last window
    answered = np.array([True, True, False, True])
    out = smooth_classes(proba, t_end, answered, _Stub(), h, "forward")
    # by hand: the first window equals the prior (no evidence), the second favours light by 0.6/0.25 vs 0.2/0.5
    # and 0.2/0.25, the third is unanswered: all three are evidence (1, 1, 1)
    b = np.array([[1.0, 1.0, 1.0], [0.4 / 2.4, 1.0, 0.8 / 2.4], [1.0, 1.0, 1.0], [0.2 / 3.2, 0.4 / 3.2, 1.0]])
    assert out == pytest.approx(h.forward(b, np.array([1, 1, 1, 3])), abs=1e-9)
    assert np.array_equal(smooth_classes(proba, t_end, answered, _Stub(), None, "forward"), proba)
    assert np.array_equal(smooth_classes(proba, t_end, answered, _Stub(), h, "none"), proba)
    from features.errors import ConfigError

    with pytest.raises(ConfigError, match="class smoothing must be one of"):
        smooth_classes(proba, t_end, answered, _Stub(), h, "viterbi")


def test_fit_class_hmm_counts_the_walks_truth_classes(model_and_walk):
    from training.temporal import fit_class_hmm, window_labels

    model, data = model_and_walk
    label, steps = window_labels(data)
    h = model.temporal
    assert h is not None and h.counts_.sum() == np.sum((label[:-1] >= 0) & (label[1:] >= 0) & (steps[1:] == 1))
    changes = np.sum(np.diff(label) != 0)
    assert h.counts_.sum() - np.trace(h.counts_) == changes
    # too little walking, or a single class (a drive without classes): no HMM, the windows one by one
    import dataclasses

    short = dataclasses.replace(data, truth=dataclasses.replace(data.truth, env_class=np.zeros_like(
        data.truth.env_class)))
    assert fit_class_hmm([short], 3) is None


def test_bundle_keeps_the_hmm_and_an_old_bundle_loads_without_it(model_and_walk, tmp_path):
    model, data = model_and_walk
    save_fusion_model(model, tmp_path / "m")
    again = load_fusion_model(tmp_path / "m")
    assert np.array_equal(again.temporal.transmat_, model.temporal.transmat_)
    a = walk_inputs(data, model.classifier, model.temporal, "forward_backward").classes.proba
    b = walk_inputs(data, again.classifier, again.temporal, "forward_backward").classes.proba
    assert np.array_equal(a, b)
    # an old bundle: no "temporal" entry in bundle.json, no temporal.safetensors — it loads, without smoothing
    doc = json.loads((tmp_path / "m" / "bundle.json").read_text())
    del doc["params"]["temporal"], doc["files"]["temporal.safetensors"]
    (tmp_path / "m" / "temporal.safetensors").unlink()
    (tmp_path / "m" / "bundle.json").write_text(json.dumps(doc))
    old = load_fusion_model(tmp_path / "m")
    assert old.temporal is None
    raw = walk_inputs(data, old.classifier, old.temporal, "forward").classes.proba
    assert np.array_equal(raw, walk_inputs(data, model.classifier).classes.proba)
    # a class HMM whose numbers are not a chain: one clear message
    from models.bundle import save_bundle

    params, arrays = model.temporal.get_state()
    doc["params"]["temporal"] = params
    save_bundle(tmp_path / "bad", "fusion", doc["params"], {
        "classifier": model.classifier.get_state()[1], "noise": _noise(model),
        "temporal": dict(arrays, transmat=np.full((3, 3), 0.5))}, meta=doc["meta"])
    with pytest.raises(BundleError, match="inconsistent .*class HMM transmat"):
        load_fusion_model(tmp_path / "bad")


def _noise(model):
    from models.fusion.model import _noise_arrays

    return _noise_arrays(model)


def test_run_and_evaluate_give_the_filters_causal_classes(model_and_walk, walk_dir, tmp_path, monkeypatch):
    model, data = model_and_walk
    fwd = walk_inputs(data, model.classifier, model.temporal, "forward").classes.proba
    fb = walk_inputs(data, model.classifier, model.temporal, "forward_backward").classes.proba
    raw = walk_inputs(data, model.classifier).classes.proba
    assert not np.allclose(fwd, raw) and not np.allclose(fwd, fb)
    assert np.allclose(fwd[-1], fb[-1])              # at the last window both have seen the same windows
    # run's path (fuse_walk's default) is the causal one, and evaluate scores what run gives (forward classes;
    # forward_backward would feed a zero-latency filter classes from its future)
    from walks.fuse import fuse_walk

    fused = fuse_walk(walk_dir, model, ("kf",), smooth=False, lag_s=None)
    assert np.array_equal(fused.inputs.classes.proba, fwd)
    import walks.fuse as wf
    from pipeline import evaluate as ev

    seen = {}

    def spy(*a, **k):
        seen.update(k)
        return fuse_walk(*a, **k)

    monkeypatch.setattr(wf, "fuse_walk", spy)
    save_fusion_model(model, tmp_path / "fm")
    ev._MODELS.clear()
    ev.evaluate_walk(walk_dir, str(tmp_path / "fm"), ("kf",))
    assert seen["class_smoothing"] == "forward"
