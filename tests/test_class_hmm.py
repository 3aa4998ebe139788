"""The class HMM along a walk (issue 27 item 3): recursions against a hand computation and hmmlearn, causality,
gaps, the transition counts, the scaled likelihoods, the bundle state."""

import numpy as np
import pytest

from models.environment import EnvironmentClassifier
from models.temporal import ClassHMM, scaled_likelihood


def _hmm(transmat, startprob, hop_s=1.0):
    """A ClassHMM with given parameters (as a fitted one would hold them)."""
    h = ClassHMM(n_classes=len(startprob))
    h.transmat_, h.startprob_ = np.asarray(transmat, float), np.asarray(startprob, float)
    h.counts_, h.hop_s_ = np.zeros_like(h.transmat_), hop_s
    return h


# Two states, three windows, by hand (Rabiner 1989 eqs. 19-20, 24-25, 27), π = (½, ½), A = [[.8, .2], [.2, .8]],
# b = (.9, .1), (.2, .6), (.9, .1):
#   α1 = (.45, .05);  α2 = ((.45·.8 + .05·.2)·.2, (.45·.2 + .05·.8)·.6) = (.074, .078);
#   α3 = ((.074·.8 + .078·.2)·.9, (.074·.2 + .078·.8)·.1) = (.06732, .00772);  P(O) = .07504
#   β3 = (1, 1);  β2 = (.8·.9 + .2·.1, .2·.9 + .8·.1) = (.74, .26);
#   β1 = (.8·.148 + .2·.156, .2·.148 + .8·.156) = (.1496, .1544)   with b2 ⊙ β2 = (.148, .156)
#   γ1 = (.45·.1496, .05·.1544) / P(O) = (.06732, .00772) / .07504;  γ2 = (.074·.74, .078·.26) / P(O)
HAND_B = np.array([[0.9, 0.1], [0.2, 0.6], [0.9, 0.1]])
HAND_FILTERED = np.array([[0.9, 0.1], [0.074 / 0.152, 0.078 / 0.152], [0.06732 / 0.07504, 0.00772 / 0.07504]])
HAND_SMOOTHED = np.array([[0.06732 / 0.07504, 0.00772 / 0.07504], [0.05476 / 0.07504, 0.02028 / 0.07504],
                          [0.06732 / 0.07504, 0.00772 / 0.07504]])


def test_recursions_match_the_hand_computation():
    h = _hmm([[0.8, 0.2], [0.2, 0.8]], [0.5, 0.5])
    assert h.forward(HAND_B) == pytest.approx(HAND_FILTERED, abs=1e-12)
    assert h.forward_backward(HAND_B) == pytest.approx(HAND_SMOOTHED, abs=1e-12)
    assert h.log_likelihood(HAND_B) == pytest.approx(np.log(0.07504), abs=1e-12)
    # the point of smoothing: the lone second window, read as class 1 by itself and by the causal filter
    # (0.513), is class 0 once the third window is seen (0.730)
    assert h.forward(HAND_B)[1].argmax() == 1 and h.forward_backward(HAND_B)[1].argmax() == 0


def _as_categorical(h, b, scale=1e-3):
    """hmmlearn's CategoricalHMM with the same chain, where window t emits its own symbol t with probability
    scale·b_t(j) (one spare symbol takes the rest of each row): the same posteriors, computed by other code."""
    from hmmlearn.hmm import CategoricalHMM

    n, k = b.shape
    m = CategoricalHMM(n_components=k, init_params="", params="")
    m.startprob_, m.transmat_ = h.startprob_, h.transmat_
    e = np.zeros((k, n + 1))
    e[:, :n] = scale * b.T
    e[:, n] = 1.0 - e[:, :n].sum(axis=1)
    m.emissionprob_ = e
    return m, np.arange(n).reshape(-1, 1)


def test_recursions_match_hmmlearn_on_a_random_three_class_walk():
    rng = np.random.default_rng(4)
    A = rng.random((3, 3)) + np.eye(3) * 5
    A /= A.sum(axis=1, keepdims=True)
    h = _hmm(A, rng.dirichlet(np.ones(3)))
    b = rng.random((40, 3)) ** 3
    m, obs = _as_categorical(h, b)
    assert h.forward_backward(b) == pytest.approx(m.predict_proba(obs), abs=1e-10)
    assert h.log_likelihood(b) + 40 * np.log(1e-3) == pytest.approx(m.score(obs), abs=1e-8)
    # the filtered class at t is the smoothed class of the walk cut at t (nothing later seen)
    filtered = np.array([m.predict_proba(obs[: t + 1])[-1] for t in range(40)])
    assert h.forward(b) == pytest.approx(filtered, abs=1e-10)


def test_forward_is_causal_and_forward_backward_is_not():
    rng = np.random.default_rng(1)
    h = _hmm([[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]], [0.4, 0.3, 0.3])
    b = rng.random((30, 3))
    later = b.copy()
    later[20:] = rng.random((10, 3))          # the future changes
    assert np.array_equal(h.forward(b)[:20], h.forward(later)[:20])
    assert np.array_equal(h.forward(b)[:20], h.forward(b[:20]))
    assert not np.allclose(h.forward_backward(b)[:20], h.forward_backward(later)[:20], atol=1e-6)


def test_a_gap_of_two_hops_is_a_window_without_evidence_between():
    rng = np.random.default_rng(2)
    h = _hmm([[0.7, 0.2, 0.1], [0.1, 0.8, 0.1], [0.2, 0.2, 0.6]], [0.5, 0.3, 0.2])
    b = rng.random((6, 3))
    filled = np.insert(b, 3, np.ones(3), axis=0)           # an uninformative window where the hop is missing
    steps = np.array([1, 1, 1, 2, 1, 1])
    keep = np.r_[0:3, 4:7]
    assert h.forward(b, steps) == pytest.approx(h.forward(filled)[keep], abs=1e-12)
    assert h.forward_backward(b, steps) == pytest.approx(h.forward_backward(filled)[keep], abs=1e-12)
    with pytest.raises(ValueError, match=">= 1 hop"):
        h.forward(b, np.array([1, 0, 1, 1, 1, 1]))


def test_fit_counts_the_class_changes_between_consecutive_labelled_windows():
    # pairs: (0,0) (0,1) (1,1) (1,1) (1,-1)✗ (-1,2)✗ (2,2); a second walk (2,2) (2,0) whose second hop is a gap✗
    h = ClassHMM(n_classes=3, pseudo_count=1.0).fit([[0, 0, 1, 1, 1, -1, 2, 2], [2, 2, 0, 0]], hop_s=1.0,
                                                    steps=[np.ones(8, int), np.array([1, 1, 1, 3])])
    assert h.counts_.tolist() == [[1, 1, 0], [0, 2, 0], [1, 0, 2]]
    # (counts + 1) / row sums: rows (2,2,1)/5, (1,3,1)/5, (2,1,3)/6
    assert h.transmat_ == pytest.approx(np.array([[2, 2, 1], [1, 3, 1], [2, 1, 3]]) / np.array([[5], [5], [6]]))
    # occupancy (4, 3, 4) + 1 over 14
    assert h.startprob_ == pytest.approx(np.array([5, 4, 5]) / 14)
    # mean dwell hop / (1 − a_ii): 1/(1 − 0.4), 1/(1 − 0.6), 1/(1 − 0.5) s
    assert h.dwell_s_ == pytest.approx([1 / 0.6, 2.5, 2.0])
    with pytest.raises(ValueError, match="no pair"):
        ClassHMM().fit([[0, -1, 1]])
    with pytest.raises(ValueError, match="pseudo_count"):
        ClassHMM(pseudo_count=0).fit([[0, 1]])


def test_state_round_trip_and_refusals():
    h = ClassHMM().fit([[0, 0, 1, 1, 2, 2, 2]], hop_s=1.0)
    params, arrays = h.get_state()
    again = ClassHMM.from_state(params, arrays)
    assert np.array_equal(again.transmat_, h.transmat_) and again.hop_s_ == 1.0
    assert params["dwell_s"] == pytest.approx(h.dwell_s_.tolist())
    bad = dict(arrays, transmat=arrays["transmat"] * 1.1)
    with pytest.raises(ValueError, match="transmat is not a positive probability"):
        ClassHMM.from_state(params, bad)
    with pytest.raises(ValueError, match="do not match"):
        ClassHMM.from_state(params, dict(arrays, startprob=np.ones(2) / 2))
    with pytest.raises(ValueError, match="likelihood must have shape"):
        h.forward(np.ones((4, 2)))


def test_scaled_likelihood_divides_by_the_fit_prior_and_keeps_a_floor():
    p = np.array([[0.6, 0.3, 0.1], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b = scaled_likelihood(p, np.array([0.6, 0.3, 0.1]))
    assert b[0] == pytest.approx([1.0, 1.0, 1.0])           # the posterior equals the prior: no evidence
    assert b[1] == pytest.approx([1.0, 1e-6, 1e-6])          # certain, but the others stay possible
    assert b[2] == pytest.approx([1.0, 1.0, 1.0])            # no answer at all: uniform
    with pytest.raises(ValueError, match="positive"):
        scaled_likelihood(p, np.array([0.5, 0.5, 0.0]))


def test_fit_prior_is_flat_for_a_balanced_classifier_and_the_frequencies_otherwise():
    from tests.env_synth import synthetic_library

    X, y = synthetic_library(600, seed=3, shares=(0.6, 0.3, 0.1))
    bal = EnvironmentClassifier(degree=1).fit(X, y)
    raw = EnvironmentClassifier(degree=1, class_weight=None).fit(X, y)
    assert bal.fit_prior() == pytest.approx([1 / 3] * 3)
    assert raw.fit_prior() == pytest.approx(np.bincount(y) / len(y))
    # the reason: on features that say nothing of the class, a balanced fit answers flat and an unweighted
    # one the class frequencies — the prior each was fitted under
    noise = np.random.default_rng(0).normal(size=X.shape)
    flat = EnvironmentClassifier(degree=1).fit(noise, y).predict_proba(noise).mean(axis=0)
    freq = EnvironmentClassifier(degree=1, class_weight=None).fit(noise, y).predict_proba(noise).mean(axis=0)
    assert flat == pytest.approx([1 / 3] * 3, abs=0.03)
    assert freq == pytest.approx(np.bincount(y) / len(y), abs=0.03)
    Xn = X[:3].copy()
    Xn[1] = np.nan
    assert bal.answers(Xn).tolist() == [True, False, True]


def test_forward_in_pieces_equals_forward_at_once():
    """A long walk read in chunks: the last filtered row of one chunk carries the state into the next."""
    rng = np.random.default_rng(5)
    h = _hmm([[0.9, 0.08, 0.02], [0.05, 0.9, 0.05], [0.02, 0.08, 0.9]], [0.5, 0.3, 0.2])
    b = rng.random((25, 3))
    steps = np.ones(25, int)
    steps[12] = 3
    whole = h.forward(b, steps)
    first = h.forward(b[:10], steps[:10])
    rest = h.forward(b[10:], steps[10:], prev=first[-1])
    assert np.allclose(np.vstack([first, rest]), whole, atol=1e-14)
    with pytest.raises(ValueError, match="probability vector"):
        h.forward(b[10:], steps[10:], prev=np.array([1.0, 1.0, 0.0]))
