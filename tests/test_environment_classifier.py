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



def _imbalanced(rng, n_open, n_heavy):
    """One informative feature (att_mean_db, column 0): open ~ N(0, 1), heavy ~ N(2, 1); the other 13 constant."""
    X = np.zeros((n_open + n_heavy, len(FEATURES)))
    X[:n_open, 0] = rng.normal(0.0, 1.0, n_open)
    X[n_open:, 0] = rng.normal(2.0, 1.0, n_heavy)
    return X, np.r_[np.zeros(n_open, int), np.full(n_heavy, 2)]


def test_class_weights_balance_an_imbalanced_library():
    """Issue 20: 900 open windows, 100 heavy, equal-variance Gaussians 2 σ apart. The log-odds are linear in
    x (Bishop 2006 §4.2.1): ln p(heavy|x)/p(open|x) = 2x − 2 + ln(π_heavy/π_open). Weighted to equal class
    totals ("balanced", the default) the prior term vanishes: boundary at x = 1, heavy recall
    P(N(2,1) > 1) = 84.1 %, open recall 84.1 %. Unweighted, ln(1/9) moves it to x = 1 + ln 9 / 2 = 2.10 and
    heavy recall falls to P(N(2,1) > 2.10) = 46 %."""
    X, y = _imbalanced(np.random.default_rng(5), 900, 100)
    clf = EnvironmentClassifier().fit(X, y)
    grid = np.zeros((3, len(FEATURES)))
    grid[:, 0] = [0.5, 1.0, 1.5]
    p_heavy = clf.predict_proba(grid)[:, 2]
    assert p_heavy[1] == pytest.approx(0.5, abs=0.1)           # the boundary at the midpoint
    assert p_heavy[0] < 0.35 and p_heavy[2] > 0.65
    Xt, yt = _imbalanced(np.random.default_rng(6), 9000, 1000)
    pred = clf.predict(Xt)
    recall_heavy, recall_open = np.mean(pred[yt == 2] == 2), np.mean(pred[yt == 0] == 0)
    assert recall_heavy == pytest.approx(0.841, abs=0.04) and recall_open == pytest.approx(0.841, abs=0.04)
    # unweighted, for contrast (the same model with class_weight=None): the boundary near 2.1
    plain = EnvironmentClassifier(class_weight=None).fit(X, y)
    assert np.mean(plain.predict(Xt)[yt == 2] == 2) == pytest.approx(0.46, abs=0.06)


def test_class_weights_equal_hand_computed_sample_weights():
    """The balanced weights are n / (k · n_c) per sample (King & Zeng 2001; scikit-learn's definition), so the
    classifier's probabilities equal a logistic regression fitted with those weights written out by hand on
    the same inputs (standardised x and x², the degree-2 expansion of the one informative feature)."""
    from sklearn.linear_model import LogisticRegression

    X, y = _imbalanced(np.random.default_rng(7), 300, 60)
    clf = EnvironmentClassifier().fit(X, y)
    z = (X[:, 0] - X[:, 0].mean()) / X[:, 0].std()
    w = np.where(y == 0, 360 / (2 * 300), 360 / (2 * 60))     # 0.6 and 3.0
    ref = LogisticRegression(C=1.0, max_iter=5000, tol=1e-10).fit(np.c_[z, z * z], y, sample_weight=w)
    zt = np.linspace(-2.5, 2.5, 11)
    grid = np.zeros((11, len(FEATURES)))
    grid[:, 0] = zt * X[:, 0].std() + X[:, 0].mean()
    np.testing.assert_allclose(clf.predict_proba(grid)[:, 2], ref.predict_proba(np.c_[zt, zt * zt])[:, 1], atol=2e-3)
