"""Fitting the class HMM (:class:`models.temporal.ClassHMM`) on labelled walks: how long a walker stays in each
environment class and how often it changes, counted per feature window.

The sequences are the truth classes of each walk at its feature windows' centres — the very windows the online
classifier answers on (:func:`walks.inputs.window_features`, 2 s, hop 1 s) — so one step of the learnt chain
is one hop, as it is when :func:`walks.inputs.smooth_classes` runs it. A window outside the truth's time span
or of an ``unknown`` class counts no transition; windows further apart than one hop count none either.
"""

from __future__ import annotations

import numpy as np

from models.temporal import ClassHMM
from walks.inputs import HOP_S, WINDOW_S, window_features

__all__ = ["window_labels", "fit_class_hmm", "MIN_TRANSITIONS"]

MIN_TRANSITIONS = 30
"""Fewest labelled one-hop window pairs (half a minute of walking) for which a class HMM is fitted at all."""


def window_labels(data) -> tuple[np.ndarray, np.ndarray]:
    """(truth class code per feature window (n,), −1 where unknown or outside the truth; hops from the
    previous window (n,)) of a :class:`~walks.reader.WalkData`."""
    t_end, _ = window_features(data)
    steps = np.ones(len(t_end), int)
    if len(t_end) > 1:
        steps[1:] = np.maximum(np.rint(np.diff(t_end) / HOP_S).astype(int), 1)
    if data.truth is None or len(t_end) == 0:
        return np.full(len(t_end), -1), steps
    t = t_end - WINDOW_S / 2.0
    label = np.asarray(data.truth.class_at(t), int)
    label[(t < data.truth.t_s[0]) | (t > data.truth.t_s[-1])] = -1
    return label, steps


def fit_class_hmm(walks, n_classes: int, pseudo_count: float = 1.0) -> ClassHMM | None:
    """The class HMM counted on ``walks`` (:class:`~walks.reader.WalkData` with truth); None when they hold
    fewer than :data:`MIN_TRANSITIONS` labelled one-hop pairs or fewer than two classes (a drive whose
    reference states no class, say): the windows are then taken one by one."""
    seqs, steps = zip(*(window_labels(d) for d in walks)) if walks else ((), ())
    pairs = sum(int(np.sum((s[:-1] >= 0) & (s[1:] >= 0) & (k[1:] == 1))) for s, k in zip(seqs, steps))
    seen = np.unique(np.concatenate([s[s >= 0] for s in seqs])) if seqs else np.zeros(0)
    if pairs < MIN_TRANSITIONS or seen.size < 2:
        return None
    return ClassHMM(n_classes=n_classes, pseudo_count=pseudo_count).fit(list(seqs), hop_s=HOP_S, steps=list(steps))
