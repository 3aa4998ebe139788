"""The ceiling of environment-aware noise (issue 14): ``adaptive_nobp`` fed the *true* class vs the classifier's.

On the held-out walks of a built split, with a trained fusion model, three runs of the same filter:

- ``kf_quality``  noise from the GGA quality and HDOP (the UERE table), no environment;
- ``classifier``  noise per (class, quality), class probabilities from the online classifier (``adaptive_nobp``);
- ``oracle``      the same noise with the truth's class one-hot (no classifier error at all).

If ``oracle`` is no better than ``kf_quality``, knowing the environment cannot help through the
measurement noise, whatever the classifier's accuracy: the reported fix quality already carries what
the class would say about R, and what remains is error R cannot describe (biases correlated over
seconds). Also prints the classifier's window recall on the walks.

Usage: ``python bench/fusion_oracle.py SPLIT_DIR/data MODEL_DIR``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(split_dir: str, model_dir: str) -> None:
    from features.schema import ENV_CLASSES
    from models.fusion.ekf import EventEKF
    from models.fusion.events import ClassTrack
    from models.fusion.model import load_fusion_model
    from simulation.split import split_layout
    from walks.inputs import walk_inputs
    from walks.reader import read_walk
    from walks.score import track_errors
    from walks.track import Track

    lay = split_layout(split_dir)
    model = load_fusion_model(model_dir)
    acc = {k: [] for k in ("kf_quality", "classifier", "oracle")}
    pcs, tcs = [], []
    for w in lay.test_walks:
        data = read_walk(w)
        inp = walk_inputs(data, model.classifier)
        truth_cls = ClassTrack.from_labels(data.truth.t_s, data.truth.env_class, len(ENV_CLASSES))
        runs = {"kf_quality": EventEKF(model.ekf, model.quality, "kf_quality").run(inp.events),
                "classifier": EventEKF(model.ekf, model.adaptive_policy(), "classifier").run(inp.events,
                                                                                          classes=inp.classes),
                "oracle": EventEKF(model.ekf, model.adaptive_policy(), "oracle").run(inp.events, classes=truth_cls)}
        for k, r in runs.items():
            te = track_errors(Track(k, r.t_s, r.x[:, 0], r.x[:, 1], r.P[:, :2, :2]), data.truth)
            acc[k].append((te["err_m"], te["cls"]))
        pcs.append(inp.classes.proba.argmax(1))
        tcs.append(data.truth.class_at(inp.classes.t_s))
        print(f"  {w}", file=sys.stderr, flush=True)
    print(f"{len(lay.test_walks)} held-out walks; mean horizontal error, m")
    print(f"{'run':12s} {'all':>7s} " + " ".join(f"{c:>7s}" for c in ENV_CLASSES))
    for k, v in acc.items():
        e = np.concatenate([a for a, _ in v])
        c = np.concatenate([b for _, b in v])
        print(f"{k:12s} {e.mean():7.3f} " + " ".join(f"{e[c == i].mean():7.3f}" for i in range(len(ENV_CLASSES))))
    pc, tc = np.concatenate(pcs), np.concatenate(tcs)
    print("classifier window recall on the walks: "
          + " / ".join(f"{c} {100 * np.mean(pc[tc == i] == i):.1f} %" for i, c in enumerate(ENV_CLASSES)))


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__.strip().splitlines()[-1])
    main(sys.argv[1], sys.argv[2])
