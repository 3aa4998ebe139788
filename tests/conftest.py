"""Shared fixtures: small simulated sites, walks and surveys (built once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _shared_data_root() -> Path:
    """../shared/data beside the repo; from a git worktree (``wt/<name>``) the one beside the main checkout;
    ``ENVFUSE_SHARED_DATA`` overrides both."""
    import os

    if os.environ.get("ENVFUSE_SHARED_DATA"):
        return Path(os.environ["ENVFUSE_SHARED_DATA"])
    candidates = [REPO.parent / "shared" / "data", REPO.parent.parent / "shared" / "data"]
    return next((c for c in candidates if c.is_dir()), candidates[0])


SHARED_DATA = _shared_data_root()


def shared_data(*parts: str) -> Path:
    """Path into ../shared/data, skipping the test with a reason when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real-data folder {p} is absent (tests read ../shared/data beside the repo)")
    return p


@pytest.fixture(scope="session")
def site_dir(tmp_path_factory) -> Path:
    """A generated site (seed 3) written as site.toml."""
    from features.site import save_site
    from simulation.site.layout import generate_site

    d = tmp_path_factory.mktemp("site3")
    save_site(generate_site(3), d / "site.toml")
    return d


@pytest.fixture(scope="session")
def walk_dir(site_dir, tmp_path_factory) -> Path:
    """A 60 s walk with every registered stream."""
    from simulation.walk import simulate_walk

    return simulate_walk(site_dir, tmp_path_factory.mktemp("walks") / "w11", seed=11, duration_s=60.0)


@pytest.fixture(scope="session")
def model_and_walk(walk_dir):
    """A fusion model fitted on ``walk_dir`` with its class HMM (the classifier on the walk's truth classes, the
    filters on the HMM's forward classes), and the read walk; shared by the class-smoothing tests, which do not
    change it."""
    from models.environment import EnvironmentClassifier
    from training.filters import DEFAULT_EKF, fit_fusion_model, training_rows
    from training.temporal import fit_class_hmm
    from walks.inputs import walk_inputs, window_features
    from walks.reader import read_walk

    data = read_walk(walk_dir)
    t, X = window_features(data)
    clf = EnvironmentClassifier(min_samples=5).fit(X, data.truth.class_at(t - 1.0))
    hmm = fit_class_hmm([data], clf.n_classes_)
    inputs = walk_inputs(data, clf, hmm, "forward")
    model = fit_fusion_model([training_rows(data, inputs, "w11")], clf, None, ekf=DEFAULT_EKF)
    model.temporal = hmm
    return model, data


@pytest.fixture(scope="session")
def survey_dir(site_dir, tmp_path_factory) -> Path:
    """A coarse survey: 10 m cells, 10 s captures, every registered stream."""
    from simulation.survey import simulate_survey

    return simulate_survey(site_dir, tmp_path_factory.mktemp("surveys") / "s3", seed=5, cell_size_m=10.0,
                           capture_s=10.0, progress=False)


@pytest.fixture(scope="session")
def gnss_survey_dir(site_dir, tmp_path_factory) -> Path:
    """A GNSS-only survey (10 m cells, 10 s captures): cheap enough for GNSS statistics by class."""
    from simulation.survey import simulate_survey

    return simulate_survey(site_dir, tmp_path_factory.mktemp("gsurveys") / "g3", seed=5, cell_size_m=10.0,
                           capture_s=10.0, progress=False, writers=("simulation.gnss.stream:write_gnss",))


@pytest.fixture(scope="session")
def bad_input_world(site_dir, walk_dir, tmp_path_factory):
    """The bad-input corpus's world (tests/bad_inputs.py): three short walks cut from ``walk_dir``, a synthetic
    library, environment and fusion models, a three-cell survey; built once per test process."""
    from tests.bad_inputs import build_world

    return build_world(tmp_path_factory.mktemp("bad_inputs") / "world", site_dir, walk_dir)
