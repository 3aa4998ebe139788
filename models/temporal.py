"""Environment class along a walk: a hidden Markov model over the online classifier's window probabilities.

A walker's environment class persists over metres and seconds — a crew stands
30–300 s beside a transformer — while the classifier answers each 2 s window
alone, so one misread window in the middle of a transformer row flips the
filter's trust decision. :class:`ClassHMM` treats the true class as the
hidden state of a first-order Markov chain over the windows (one step per hop)
and the classifier's output as its evidence:

* **transitions** ``transmat_[i, j]`` = P(class j at the next window | class i
  now), the counts of class changes between consecutive labelled windows of the
  training walks with ``pseudo_count`` added to every entry (the maximum a
  posteriori estimate under a symmetric Dirichlet prior; Rabiner 1989, eq. 40b,
  from labelled sequences instead of expected counts). The mean dwell in class
  i is ``hop_s / (1 − a_ii)`` seconds (the geometric dwell of an HMM state;
  Rabiner 1989, eq. 5);
* **start** ``startprob_`` = the training walks' class shares (a walk's first
  window is a draw from where crews are; a handful of walk starts would be a
  poor estimate of π);
* **evidence** the scaled likelihood b_j(x) ∝ p(j | x) / p(j): the classifier's
  posterior divided by the class prior it was fitted under (the hybrid
  HMM/network recognisers of Bourlard & Morgan, *Connectionist Speech
  Recognition*, 1994, §7.3; :func:`scaled_likelihood`).

Two recursions, both with Rabiner's per-step scaling (1989, §V.A, eqs. 91–92
with the forward and backward variables of eqs. 19–20 and 24–25):

* :meth:`ClassHMM.forward` — P(q_t | x_1..x_t), the filtered class: causal, what
  ``envfuse run`` hands the fusion (a window's output never depends on a later
  window);
* :meth:`ClassHMM.forward_backward` — P(q_t | x_1..x_T), the smoothed class
  (eq. 27: γ_t ∝ α_t β_t), for ``evaluate`` and offline use.

Windows need not be contiguous: ``steps[t]`` hops between window t − 1 and t
use the transition matrix to that power (a window without features in
between is simply a longer step).

Hand-written rather than hmmlearn's ``CategoricalHMM``/``GaussianHMM``: those
take discrete or Gaussian emissions, not a discriminative classifier's
posteriors, and their fit is Baum–Welch on unlabelled data where the labelled
walks give the counts directly. The tests compare the recursions with
hmmlearn's on the same model (an independent reference) and with a hand
computation.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ClassHMM", "scaled_likelihood", "LIKELIHOOD_FLOOR"]

LIKELIHOOD_FLOOR = 1e-6
"""Smallest scaled likelihood a class keeps (relative to the window's largest): a classifier that is certain
and wrong must not make the true class impossible, or no amount of persistence could bring it back."""


def scaled_likelihood(proba: np.ndarray, prior: np.ndarray, floor: float = LIKELIHOOD_FLOOR) -> np.ndarray:
    """Scaled likelihoods b_j(x) ∝ p(j | x) / p(j) of each window, normalised so each row's largest is 1.

    Bourlard & Morgan (1994), *Connectionist Speech Recognition*, §7.3: a classifier trained with class
    prior p(j) gives p(x | j) / p(x) = p(j | x) / p(j); the common factor p(x) cancels in the HMM's
    normalised recursions. Entries below ``floor`` × the row's largest are raised to it.

    Parameters
    ----------
    proba : ndarray of shape (n_windows, n_classes)
        The classifier's posteriors.
    prior : ndarray of shape (n_classes,)
        The class prior the classifier was fitted under (uniform for a class-balanced fit).

    >>> scaled_likelihood(np.array([[0.5, 0.3, 0.2]]), np.array([0.5, 0.25, 0.25])).round(3).tolist()
    [[0.833, 1.0, 0.667]]
    """
    proba = np.asarray(proba, float)
    prior = np.asarray(prior, float)
    if proba.ndim != 2 or prior.shape != (proba.shape[1],):
        raise ValueError(f"proba must be (n, k) and prior (k,), got {proba.shape} and {prior.shape}")
    if np.any(prior <= 0) or not np.all(np.isfinite(prior)):
        raise ValueError(f"prior must be positive and finite, got {prior}")
    b = np.clip(np.nan_to_num(proba, nan=0.0), 0.0, None) / prior
    top = b.max(axis=1, keepdims=True)
    b = np.divide(b, top, out=np.ones_like(b), where=top > 0)       # a row without evidence: uniform
    return np.maximum(b, floor)


class ClassHMM:
    """Hidden Markov model of the environment class along a walk (see the module docstring).

    Parameters
    ----------
    n_classes : int
        Number of classes (states).
    pseudo_count : float
        Added to every transition count (and to every class count of the start distribution) before
        normalising: a change never seen in training stays possible.

    Attributes
    ----------
    counts_ : ndarray of shape (n_classes, n_classes)
        Transitions counted between consecutive labelled windows (from row class to column class).
    transmat_ : ndarray of shape (n_classes, n_classes)
        Row-stochastic transition matrix per hop.
    startprob_ : ndarray of shape (n_classes,)
        Class distribution of a walk's first window.
    hop_s_ : float
        Seconds per step of ``transmat_``.
    """

    def __init__(self, *, n_classes: int = 3, pseudo_count: float = 1.0):
        self.n_classes = n_classes
        self.pseudo_count = pseudo_count

    def _validate(self) -> None:
        if not (isinstance(self.n_classes, (int, np.integer)) and self.n_classes >= 2):
            raise ValueError(f"n_classes must be an integer >= 2, got {self.n_classes!r}")
        if not (isinstance(self.pseudo_count, (int, float)) and self.pseudo_count > 0):
            raise ValueError(f"pseudo_count must be a positive number, got {self.pseudo_count!r}")

    def fit(self, sequences, hop_s: float = 1.0, steps=None) -> "ClassHMM":
        """Count the class changes along labelled walks.

        Parameters
        ----------
        sequences : list of array-like of shape (n_windows_i,)
            Class code per window of each walk, in time order; −1 where unknown (no transition counted
            into or out of it).
        hop_s : float
            Seconds between consecutive windows.
        steps : list of array-like of shape (n_windows_i,), optional
            Hops between window t − 1 and t of each walk (entry 0 unused); only one-hop pairs are counted.
            Default: all windows one hop apart.
        """
        self._validate()
        if not (isinstance(hop_s, (int, float)) and hop_s > 0):
            raise ValueError(f"hop_s must be positive, got {hop_s!r}")
        k = int(self.n_classes)
        counts = np.zeros((k, k))
        occupancy = np.zeros(k)
        for i, seq in enumerate(sequences):
            seq = np.asarray(seq, int)
            if seq.size and seq.max() >= k:
                raise ValueError(f"class codes must lie in [-1, {k - 1}], got {seq.max()}")
            occupancy += np.bincount(seq[seq >= 0], minlength=k)
            if seq.size < 2:
                continue
            one_hop = np.ones(seq.size - 1, bool) if steps is None else np.asarray(steps[i], int)[1:] == 1
            a, b = seq[:-1], seq[1:]
            ok = (a >= 0) & (b >= 0) & one_hop
            np.add.at(counts, (a[ok], b[ok]), 1.0)
        if counts.sum() == 0:
            raise ValueError("no pair of consecutive labelled windows: the transitions cannot be counted")
        self.counts_ = counts
        self.transmat_ = (counts + self.pseudo_count) / (counts + self.pseudo_count).sum(axis=1, keepdims=True)
        self.startprob_ = (occupancy + self.pseudo_count) / (occupancy + self.pseudo_count).sum()
        self.hop_s_ = float(hop_s)
        return self

    @property
    def dwell_s_(self) -> np.ndarray:
        """Mean dwell per class, s: hop / (1 − a_ii) (Rabiner 1989, eq. 5: a state's duration is geometric)."""
        return self.hop_s_ / (1.0 - np.diag(self.transmat_))

    # -- recursions ------------------------------------------------------------------------------

    def _powers(self, steps, n: int) -> tuple[np.ndarray, dict]:
        steps = np.ones(n, int) if steps is None else np.asarray(steps, int)
        if steps.shape != (n,):
            raise ValueError(f"steps must have shape ({n},), got {steps.shape}")
        if n > 1 and steps[1:].min() < 1:
            raise ValueError("steps between windows must be >= 1 hop")
        mats = {int(s): np.linalg.matrix_power(self.transmat_, int(s)) for s in np.unique(steps[1:])}
        return steps, mats

    def _check(self, likelihood) -> np.ndarray:
        b = np.asarray(likelihood, float)
        if b.ndim != 2 or b.shape[1] != self.transmat_.shape[0]:
            raise ValueError(f"likelihood must have shape (n_windows, {self.transmat_.shape[0]}), got {b.shape}")
        if np.any(~np.isfinite(b)) or np.any(b < 0):
            raise ValueError("likelihood must be finite and non-negative")
        return b

    def forward(self, likelihood, steps=None, prev=None) -> np.ndarray:
        """Filtered class probabilities P(q_t | x_1..x_t), shape (n_windows, n_classes).

        Rabiner (1989) eqs. 19–20 with the scaling of eq. 91: α̂_1 ∝ π ⊙ b_1,
        α̂_t ∝ (α̂_{t−1} A^{steps_t}) ⊙ b_t, each row normalised (the normaliser is c_t).

        Parameters
        ----------
        likelihood : ndarray of shape (n_windows, n_classes)
            Scaled likelihoods per window (:func:`scaled_likelihood`).
        steps : ndarray of shape (n_windows,), optional
            Hops from window t − 1 to t (entry 0 unused unless ``prev`` is given); default 1.
        prev : ndarray of shape (n_classes,), optional
            The filtered probabilities of the window before the first (the last row of the previous call):
            a walk read in pieces is filtered piece by piece with the same result as at once; ``steps[0]``
            is then the hops from that window to the first.
        """
        return self._forward(self._check(likelihood), steps, prev)[0]

    def _forward(self, b: np.ndarray, steps, prev=None) -> tuple[np.ndarray, np.ndarray]:
        n = len(b)
        steps, mats = self._powers(steps, n)
        if prev is not None:
            prev = np.asarray(prev, float)
            if prev.shape != self.startprob_.shape or not np.isclose(prev.sum(), 1.0) or np.any(prev < 0):
                raise ValueError(f"prev must be a probability vector of {len(self.startprob_)} classes")
            if n and steps[0] < 1:
                raise ValueError("steps between windows must be >= 1 hop")
            if n:
                mats.setdefault(int(steps[0]), np.linalg.matrix_power(self.transmat_, int(steps[0])))
        alpha = np.empty_like(b)
        c = np.empty(n)
        first = prev is None
        prev = self.startprob_ if first else prev
        for t in range(n):
            # α_t(j) = [Σ_i α̂_{t−1}(i) a_ij] b_j(x_t)   (eq. 20; π for t = 1, eq. 19)
            a = (prev if (t == 0 and first) else prev @ mats[int(steps[t])]) * b[t]
            c[t] = a.sum()
            alpha[t] = a / c[t]                             # α̂_t = α_t / c_t (eq. 91)
            prev = alpha[t]
        return alpha, c

    def forward_backward(self, likelihood, steps=None) -> np.ndarray:
        """Smoothed class probabilities P(q_t | x_1..x_T), shape (n_windows, n_classes).

        Rabiner (1989) eq. 27, γ_t(i) ∝ α_t(i) β_t(i), with the backward variable of eqs. 24–25 scaled by
        the forward pass's c_{t+1} (eq. 92): β̂_T = 1, β̂_t = A^{steps_{t+1}} (b_{t+1} ⊙ β̂_{t+1}) / c_{t+1}.
        Arguments as :meth:`forward`.
        """
        b = self._check(likelihood)
        alpha, c = self._forward(b, steps)
        n = len(b)
        steps, mats = self._powers(steps, n)
        gamma = np.empty_like(b)
        beta = np.ones(b.shape[1])
        for t in range(n - 1, -1, -1):
            g = alpha[t] * beta
            gamma[t] = g / g.sum()
            if t > 0:
                # β_{t−1}(i) = Σ_j a_ij b_j(x_t) β_t(j)   (eq. 25), scaled by c_t (eq. 92)
                beta = mats[int(steps[t])] @ (b[t] * beta) / c[t]
        return gamma

    def log_likelihood(self, likelihood, steps=None) -> float:
        """log P(x_1..x_T | model) up to the scaled likelihoods' common factor: Σ_t log c_t (Rabiner 1989, eq. 103)."""
        return float(np.log(self._forward(self._check(likelihood), steps)[1]).sum())

    # -- state for bundles (no pickle) -----------------------------------------------------------

    def get_state(self) -> tuple[dict, dict]:
        """(JSON-able parameters, arrays) for a model bundle."""
        params = {"n_classes": int(self.n_classes), "pseudo_count": float(self.pseudo_count), "hop_s": self.hop_s_,
                  "dwell_s": [float(v) for v in self.dwell_s_]}
        return params, {"transmat": self.transmat_, "startprob": self.startprob_, "counts": self.counts_}

    @classmethod
    def from_state(cls, params: dict, arrays: dict) -> "ClassHMM":
        """Rebuild a fitted model from :meth:`get_state`; raises ValueError when its numbers are not a valid
        HMM (shapes, finite, non-negative, rows summing to 1)."""
        self = cls(n_classes=int(params["n_classes"]), pseudo_count=float(params["pseudo_count"]))
        self._validate()
        k = self.n_classes
        self.transmat_ = np.asarray(arrays["transmat"], float)
        self.startprob_ = np.asarray(arrays["startprob"], float)
        self.counts_ = np.asarray(arrays["counts"], float)
        self.hop_s_ = float(params["hop_s"])
        if self.transmat_.shape != (k, k) or self.startprob_.shape != (k,) or self.counts_.shape != (k, k):
            raise ValueError(f"class HMM arrays do not match {k} classes")
        for name, v in (("transmat", self.transmat_), ("startprob", self.startprob_)):
            if not np.all(np.isfinite(v)) or np.any(v <= 0) or not np.allclose(v.sum(axis=-1), 1.0, atol=1e-9):
                raise ValueError(f"class HMM {name} is not a positive probability distribution per row")
        if not (np.isfinite(self.hop_s_) and self.hop_s_ > 0):
            raise ValueError(f"class HMM hop_s must be positive, got {self.hop_s_}")
        return self
