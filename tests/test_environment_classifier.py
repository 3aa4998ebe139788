"""Online environment classifier: sub-models per modality, OOD flag, occlusion estimate, state round trip."""

import numpy as np
import pytest

from features.schema import ACOUSTIC_FEATURES, FEATURES, GNSS_FEATURES
from models.environment import EnvironmentClassifier, availability, combine_windows


def _library(rng, n_per_class=300, separation=1.5):
    """Three Gaussian classes in 14-D whose means step by ``separation`` σ along every feature."""
    X, y, share = [], [], []
    for c in range(3):
        X.append(rng.normal(c * separation, 1.0, size=(n_per_class, len(FEATURES))))
        y.append(np.full(n_per_class, c))
        share.append(np.clip(0.05 + 0.2 * c + 0.05 * X[-1][:, 0] / separation, 0, 1))
    return np.vstack(X), np.concatenate(y), np.concatenate(share)


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(1)
    X, y, share = _library(rng)
    return EnvironmentClassifier().fit(X, y, share=share), rng


def test_schema_matches_the_feature_modules():
    from features.acoustic.cir import FEATURE_NAMES
    from features.gnss.features import FEATURE_COLUMNS

    assert GNSS_FEATURES == FEATURE_COLUMNS and ACOUSTIC_FEATURES == tuple(FEATURE_NAMES)


def test_accuracy_on_fresh_windows_with_each_modality(fitted):
    clf, _ = fitted
    Xt, yt, _ = _library(np.random.default_rng(2))
    acc_both = np.mean(clf.predict(Xt) == yt)
    g_only, a_only = Xt.copy(), Xt.copy()
    g_only[:, len(GNSS_FEATURES):] = np.nan
    a_only[:, :len(GNSS_FEATURES)] = np.nan
    acc_g, acc_a = np.mean(clf.predict(g_only) == yt), np.mean(clf.predict(a_only) == yt)
    # Bayes accuracy, neighbouring means 1.5·sqrt(d) σ apart with d features (one boundary for open and
    # heavy, two for light): 14 → 99.7 %, 9 → 98.4 %, 5 → 93.8 %.
    assert 0.985 <= acc_both <= 1.0 and 0.965 <= acc_a <= 0.995 and 0.90 <= acc_g <= 0.96
    assert acc_g < acc_both                    # fewer features, more errors
    g, a = availability(g_only)
    assert g.all() and not a.any()


def test_no_features_gives_the_prior_and_is_ood(fitted):
    clf, _ = fitted
    X = np.full((2, len(FEATURES)), np.nan)
    assert np.allclose(clf.predict_proba(X), clf.prior_)
    assert clf.is_ood(X).all()


def test_ood_share_small_in_distribution_large_outside(fitted):
    clf, _ = fitted
    Xt, _, _ = _library(np.random.default_rng(3))
    inside = clf.is_ood(Xt).mean()
    shifted = clf.is_ood(Xt + 6.0).mean()
    assert inside < 0.03                       # the 99.5 % training quantile, plus sampling noise
    assert shifted > 0.9


def test_occlusion_estimate_tracks_the_share(fitted):
    clf, _ = fitted
    Xt, _, share = _library(np.random.default_rng(4))
    est = clf.occlusion(Xt)
    resid = est - share
    assert np.all((est >= 0) & (est <= 1))
    assert abs(resid.mean()) < 0.01 and 0.02 < resid.std() < 0.045   # the class step is read from noisy features


def test_state_round_trip_gives_identical_answers(fitted):
    clf, _ = fitted
    params, arrays = clf.get_state()
    again = EnvironmentClassifier.from_state(params, arrays)
    Xt, _, _ = _library(np.random.default_rng(5), n_per_class=50)
    Xt[::3, :5] = np.nan
    assert np.array_equal(clf.predict_proba(Xt), again.predict_proba(Xt))
    assert np.array_equal(clf.is_ood(Xt), again.is_ood(Xt))
    bad = dict(params, features=list(reversed(FEATURES)))
    with pytest.raises(ValueError, match="feature order"):
        EnvironmentClassifier.from_state(bad, arrays)
    arrays_bad = dict(arrays)
    arrays_bad["both.coef"] = arrays_bad["both.coef"][:, :3]
    with pytest.raises(ValueError, match="do not match"):
        EnvironmentClassifier.from_state(params, arrays_bad)


def test_bad_input_is_named():
    X, y, _ = _library(np.random.default_rng(6), n_per_class=20)
    with pytest.raises(ValueError, match="degree must be 1 or 2"):
        EnvironmentClassifier(degree=3).fit(X, y)
    with pytest.raises(ValueError, match=r"shape \(n_windows, 14\)"):
        EnvironmentClassifier().fit(X[:, :5], y)
    with pytest.raises(ValueError, match="unknown class names"):
        EnvironmentClassifier().fit(X, np.array(["open", "dark", "heavy"] * 20))
    with pytest.raises(ValueError, match="no sub-model could be fitted"):
        EnvironmentClassifier().fit(np.full_like(X, np.nan), y)
    names = np.array(["open", "light", "heavy"])[y]
    p1 = EnvironmentClassifier().fit(X, names).predict_proba(X)
    p2 = EnvironmentClassifier().fit(X, y).predict_proba(X)
    assert np.array_equal(p1, p2)              # names and codes are the same labels; fitting is deterministic


def test_combine_windows_prefers_the_consistent_class():
    p = combine_windows(np.array([[0.4, 0.35, 0.25]] * 5))
    assert p[0] > 0.55 and abs(p.sum() - 1) < 1e-12

