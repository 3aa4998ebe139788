"""Model bundles: JSON + safetensors, atomic, versioned, damage detected, never pickle."""

import json
import pickle

import numpy as np
import pytest

from models.bundle import FORMAT_VERSION, BundleError, load_bundle, save_bundle
from models.environment import EnvironmentClassifier


def _arrays():
    return {"net": {"w": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.array([1, 2], dtype=np.int64)}}


def test_round_trip(tmp_path):
    p = save_bundle(tmp_path / "m", "fusion", {"hidden": 8}, _arrays(), meta={"walks": ["a", "b"]})
    b = load_bundle(p, "fusion")
    assert b.params == {"hidden": 8} and b.meta == {"walks": ["a", "b"]}
    assert np.array_equal(b.arrays["net"]["w"], _arrays()["net"]["w"]) and b.arrays["net"]["b"].dtype == np.int64
    assert not list(tmp_path.glob(".*partial"))           # no temporary left behind


def test_existing_bundle_kept_unless_overwrite(tmp_path):
    save_bundle(tmp_path / "m", "fusion", {"v": 1}, _arrays())
    with pytest.raises(BundleError, match="exists"):
        save_bundle(tmp_path / "m", "fusion", {"v": 2}, _arrays())
    save_bundle(tmp_path / "m", "fusion", {"v": 2}, _arrays(), overwrite=True)
    assert load_bundle(tmp_path / "m", "fusion").params == {"v": 2}


def test_newer_wrong_kind_damaged_missing(tmp_path):
    p = save_bundle(tmp_path / "m", "environment", {}, _arrays())
    with pytest.raises(BundleError, match="holds a 'environment' model, expected 'fusion'"):
        load_bundle(p, "fusion")
    doc = json.loads((p / "bundle.json").read_text())
    (p / "bundle.json").write_text(json.dumps(dict(doc, format_version=FORMAT_VERSION + 1)))
    with pytest.raises(BundleError, match="newer envfuse"):
        load_bundle(p, "environment")
    (p / "bundle.json").write_text(json.dumps(doc))
    raw = bytearray((p / "net.safetensors").read_bytes())
    raw[-1] ^= 0xFF
    (p / "net.safetensors").write_bytes(bytes(raw))
    with pytest.raises(BundleError, match="net.safetensors is damaged"):
        load_bundle(p, "environment")
    (p / "net.safetensors").unlink()
    with pytest.raises(BundleError, match="net.safetensors is missing"):
        load_bundle(p, "environment")
    (p / "bundle.json").write_text("{not json")
    with pytest.raises(BundleError, match="damaged"):
        load_bundle(p, "environment")
    with pytest.raises(BundleError, match="not a model directory"):
        load_bundle(tmp_path / "nope", "environment")


class _Boom:
    def __reduce__(self):
        return (open, (str(self.target), "w"))


def test_a_crafted_pickle_never_runs(tmp_path):
    """A bundle whose array file is a pickle that would create a file when unpickled: refused, nothing runs."""
    p = save_bundle(tmp_path / "m", "environment", {}, _arrays())
    boom = _Boom()
    boom.target = tmp_path / "pwned"
    payload = pickle.dumps(boom)
    (p / "net.safetensors").write_bytes(payload)
    doc = json.loads((p / "bundle.json").read_text())
    import hashlib
    doc["files"]["net.safetensors"] = hashlib.sha256(payload).hexdigest()   # the attacker fixes the hash too
    (p / "bundle.json").write_text(json.dumps(doc))
    with pytest.raises(BundleError, match="cannot be read"):
        load_bundle(p, "environment")
    assert not boom.target.exists()


def test_environment_classifier_through_a_bundle(tmp_path):
    rng = np.random.default_rng(0)
    X = np.vstack([rng.normal(c, 1.0, size=(60, 14)) for c in range(3)])
    y = np.repeat([0, 1, 2], 60)
    clf = EnvironmentClassifier(degree=1).fit(X, y)
    params, arrays = clf.get_state()
    save_bundle(tmp_path / "env", "environment", params, {"classifier": arrays})
    b = load_bundle(tmp_path / "env", "environment")
    again = EnvironmentClassifier.from_state(b.params, b.arrays["classifier"])
    assert np.array_equal(again.predict_proba(X), clf.predict_proba(X))
    assert np.array_equal(again.is_ood(X + 3.0), clf.is_ood(X + 3.0)) and clf.is_ood(X + 30.0).all()


def test_overwrite_through_a_link_replaces_its_target_and_keeps_the_link(tmp_path):
    """(The bad-input tour: overwriting through a link wrote the model, then failed on rmtree of the link and
    left every later overwrite of that name failing.)"""
    real = save_bundle(tmp_path / "real", "fusion", {"v": 1}, _arrays())
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    for v in (2, 3):
        assert save_bundle(link, "fusion", {"v": v}, _arrays(), overwrite=True) == link
        assert link.is_symlink() and load_bundle(real, "fusion").params == {"v": v}
    # a link left as '.link.old' by the older code does not block the next overwrite
    (tmp_path / ".real.old").symlink_to(real, target_is_directory=True)
    save_bundle(link, "fusion", {"v": 4}, _arrays(), overwrite=True)
    assert load_bundle(link, "fusion").params == {"v": 4}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]


def test_unwritable_folder_is_one_line_naming_the_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(BundleError, match=r"^cannot write .*file/m: ") as err:
        save_bundle(blocker / "m", "fusion", {}, _arrays())
    assert ".partial" not in str(err.value)


def test_default_as_a_fusion_model_says_what_default_is(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(BundleError, match="names the environment model shipped in envfuse, not a fusion model"):
        load_bundle("default", "fusion")
