"""The environment class along held-out walks, with and without the class HMM (issue 27 item 3); prints tables.

On a built benchmark split (``--data``; built when missing): the online classifier is fitted on the map labels
of the surveys of some training sites and the class HMM (:class:`models.temporal.ClassHMM`) on the truth
classes of the same sites' walks; every window of every test-site walk (sites nobody tuned on) is then
classified

- ``window``   one by one (the classifier's argmax, what the fusion had before);
- ``forward``  the HMM's filtered class (causal: what ``envfuse run`` hands the filters);
- ``smoothed`` the HMM's forward–backward class (the whole walk: what ``evaluate`` hands them);

and scored against the walk's truth class at the window's centre: accuracy, recall per class, macro-F1, and
class changes per minute (the truth's own rate beside them). Seeds: seed s fits on a draw of
``--train-sites-per-seed`` of the split's training sites (``numpy.random.default_rng(s)``); a last row fits on
all of them. Mean ± SD over seeds, and the per-seed rows. ``--plot`` draws one test walk's classes over time.

Window features are read once per walk (:func:`walks.inputs.window_features`, the path the filters take) and
cached in ``--out/windows``.

Measured (standard split as built for the fusion study, 15 test walks of 300 s, 4,500 windows; seeds 0-4, two
training sites each; 46 s on 2 shared cores with the windows cached)::

    mode      accuracy   open       light      heavy      macro-F1   changes/min (truth 2.01)
    window    75.6±5.5   86.7±5.7   59.6±12.1  82.9±10.1  75.9±5.6   6.47±0.93
    forward   76.3±5.3   88.0±5.8   60.4±11.8  82.8±9.6   76.6±5.4   3.33±0.55
    smoothed  76.5±5.6   88.9±5.7   59.8±12.8  83.5±9.5   76.8±5.7   2.27±0.28

paired gain per seed, accuracy: forward +0.7 ± 0.3 points (min +0.4), smoothed +1.0 ± 0.4 (min +0.4); all six
training sites: 81.4 (window) / 81.5 (forward) / 83.4 % (smoothed). Mean dwell learnt: open 16 s, light 20 s,
heavy 51 s. The HMM removes flicker (changes per minute halved, near the truth's rate when smoothed) but most
wrong windows lie in long stretches the classifier reads wrongly (the plot's walk: 100 s of light read as heavy),
which no persistence model can repair.

Usage: ``python bench/env_along_walk.py --data /work/studies/standard/data --library
/work/studies/standard/fingerprints.sqlite --out /tmp/along --seeds 0 1 2 3 4 --plot /tmp/along/walk.png``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MODES = ("window", "forward", "smoothed")


def walk_windows(walk: Path, cache: Path) -> dict:
    """{'X' (n, 14), 'label' (n,), 'steps' (n,), 't_end' (n,), 'site'} of one walk, read once and cached."""
    from training.temporal import window_labels
    from walks.inputs import window_features
    from walks.reader import read_walk

    f = cache / (f"{walk.parent.name}_{walk.name}.npz")
    if not f.is_file():
        data = read_walk(walk)
        t_end, X = window_features(data)
        label, steps = window_labels(data)
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(f, X=X, label=label, steps=steps, t_end=t_end, site=data.site.name)
    return {k: (str(v) if k == "site" else v) for k, v in np.load(f).items()}


def classify(clf, hmm, w: dict) -> dict:
    """Class code per window of walk ``w`` in each mode."""
    from models.temporal import scaled_likelihood

    p = clf.predict_proba(w["X"])
    b = scaled_likelihood(p, clf.fit_prior())
    b[~clf.answers(w["X"])] = 1.0
    return {"window": p.argmax(1), "forward": hmm.forward(b, w["steps"]).argmax(1),
            "smoothed": hmm.forward_backward(b, w["steps"]).argmax(1),
            "proba": {"window": p, "forward": hmm.forward(b, w["steps"]),
                      "smoothed": hmm.forward_backward(b, w["steps"])}}


def scores(walks: list[dict], preds: list[dict], mode: str) -> list[float]:
    """[accuracy, recall open, light, heavy, macro-F1, changes per minute] over the walks' labelled windows."""
    from sklearn.metrics import f1_score

    y = np.concatenate([w["label"] for w in walks])
    yp = np.concatenate([p[mode] for p in preds])
    ok = y >= 0
    y, yp = y[ok], yp[ok]
    rec = [float(np.mean(yp[y == k] == k)) if np.any(y == k) else np.nan for k in range(3)]
    f1 = float(f1_score(y, yp, labels=[0, 1, 2], average="macro", zero_division=0))
    changes = sum(int(np.sum(np.diff(p[mode]) != 0)) for p in preds)
    minutes = sum(len(w["label"]) for w in walks) / 60.0        # one window per hop of 1 s
    return [float(np.mean(y == yp))] + rec + [f1, changes / minutes]


def truth_changes(walks: list[dict]) -> float:
    return sum(int(np.sum(np.diff(w["label"]) != 0)) for w in walks) / (sum(len(w["label"]) for w in walks) / 60.0)


def plot_walk(path: Path, w: dict, pred: dict, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from features.schema import ENV_CLASSES

    t = w["t_end"] - 1.0
    fig, axes = plt.subplots(4, 1, figsize=(10, 7), sharex=True, gridspec_kw={"height_ratios": [1, 1.4, 1.4, 1.4]})
    colours = ("#4daf4a", "#ff7f00", "#6a3d9a")
    axes[0].step(t, w["label"], where="mid", color="k")
    axes[0].set_yticks(range(3), ENV_CLASSES)
    axes[0].set_title(f"{name} (the test walk with most wrong windows): truth class at each window centre")
    titles = {"window": "classifier, each window alone", "forward": "class HMM, forward (causal: run)",
              "smoothed": "class HMM, forward–backward (evaluate)"}
    for ax, mode in zip(axes[1:], MODES):
        p = pred["proba"][mode]
        ax.stackplot(t, p.T, colors=colours, labels=ENV_CLASSES, alpha=0.85, step="mid")
        wrong = (pred[mode] != w["label"]) & (w["label"] >= 0)
        ax.plot(t[wrong], np.full(wrong.sum(), 1.04), "|", color="red", ms=6, label="wrong window")
        acc = np.mean(~wrong[w["label"] >= 0])
        ax.set_ylim(0, 1.08)
        ax.set_ylabel("P(class)")
        ax.set_title(f"{titles[mode]}: accuracy {100 * acc:.1f} %, {int(np.sum(np.diff(pred[mode]) != 0))} changes")
    axes[1].legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    axes[-1].set_xlabel("walk time, s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _gain(rows: dict, seeds: list, mode: str, col: int) -> str:
    g = 100 * np.array([rows[(s, mode)][col] - rows[(s, "window")][col] for s in seeds])
    return f"{g.mean():+.1f} ± {g.std():.1f} (min {g.min():+.1f}, max {g.max():+.1f})"


def main() -> None:
    from fingerprints.survey import build_library
    from models.environment import EnvironmentClassifier
    from simulation.split import SPLITS, build_split, split_layout
    from training.env import training_set
    from training.temporal import MIN_TRANSITIONS
    from models.temporal import ClassHMM

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a built split (built there when missing)")
    ap.add_argument("--split", default="standard", choices=sorted(SPLITS), help="split to build when --data is empty")
    ap.add_argument("--library", type=Path, default=None,
                    help="fingerprint library of the training sites (default: built in --out)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--train-sites-per-seed", type=int, default=2)
    ap.add_argument("--plot", type=Path, default=None)
    args = ap.parse_args()
    t0 = time.perf_counter()
    layout = split_layout(args.data) if (args.data / "split.toml").is_file() else build_split(args.split, args.data)
    sp = layout.split
    lib = args.library
    if lib is None:
        lib = args.out / "fingerprints_train.sqlite"
        for s in sp.train_sites:
            build_library(layout.survey_dir(s), lib, progress=False)
    ts = training_set(lib)
    cache = args.out / "windows"
    train = {s: [walk_windows(w, cache) for w in layout.walks([s])] for s in sp.train_sites}
    test = [walk_windows(w, cache) for w in layout.test_walks]
    name_of = {s: train[s][0]["site"] for s in sp.train_sites}
    draws = [(f"seed {s}", sorted(np.random.default_rng(s).choice(sp.train_sites, args.train_sites_per_seed,
                                                                  replace=False).tolist())) for s in args.seeds]
    draws.append(("all", list(sp.train_sites)))
    rows, dwell = {}, {}
    for label, sites in draws:
        sel = np.isin(ts.site, [name_of[s] for s in sites]) & (ts.label >= 0)
        clf = EnvironmentClassifier().fit(ts.X[sel], ts.label[sel], share=ts.share[sel])
        walks = [w for s in sites for w in train[s]]
        hmm = ClassHMM().fit([w["label"] for w in walks], hop_s=1.0, steps=[w["steps"] for w in walks])
        assert hmm.counts_.sum() >= MIN_TRANSITIONS
        dwell[label] = hmm.dwell_s_
        preds = [classify(clf, hmm, w) for w in test]
        for mode in MODES:
            rows[(label, mode)] = scores(test, preds, mode)
        if label == "all" and args.plot is not None:
            i = int(np.argmax([np.sum(p["window"] != w["label"]) for w, p in zip(test, preds)]))
            args.plot.parent.mkdir(parents=True, exist_ok=True)
            plot_walk(args.plot, test[i], preds[i], f"test walk {layout.test_walks[i].parent.name}/"
                                                    f"{layout.test_walks[i].name}")
    print(f"{len(test)} test walks of sites {list(sp.test_sites)} ({sum(len(w['label']) for w in test)} windows); "
          f"truth changes class {truth_changes(test):.2f} times a minute")
    head = f"{'fit on':30s} {'mode':9s} {'accuracy':>8s} {'open':>6s} {'light':>6s} {'heavy':>6s} {'mF1':>6s} {'chg/min':>7s}"
    print(head)
    for label, sites in draws:
        for mode in MODES:
            r = rows[(label, mode)]
            print(f"{label + ' ' + str(sites):30s} {mode:9s} " + " ".join(f"{100 * v:6.1f}" for v in r[:5])
                  + f"  {r[5]:6.2f}")
    seeds = [lab for lab, _ in draws if lab != "all"]
    print(f"\nmean ± SD over {len(seeds)} seeds ({args.train_sites_per_seed} training sites each), percent:")
    print(f"{'mode':9s} {'accuracy':>11s} {'open':>11s} {'light':>11s} {'heavy':>11s} {'macro-F1':>11s} {'chg/min':>11s}")
    for mode in MODES:
        v = np.array([rows[(s, mode)] for s in seeds])
        m, sd = v.mean(0), v.std(0)
        print(f"{mode:9s} " + " ".join(f"{100 * a:5.1f}±{100 * b:4.1f}" for a, b in zip(m[:5], sd[:5]))
              + f" {m[5]:5.2f}±{sd[5]:4.2f}")
    print("gain over 'window' (paired per seed), points: " + "; ".join(
        f"{mode} accuracy {_gain(rows, seeds, mode, 0)}, macro-F1 {_gain(rows, seeds, mode, 4)}"
        for mode in MODES[1:]))
    d = np.array([dwell[s] for s in seeds])
    print("\nmean dwell learnt (s), open / light / heavy: seeds " + " / ".join(f"{a:.0f}±{b:.0f}" for a, b in
          zip(d.mean(0), d.std(0))) + "; all sites " + " / ".join(f"{a:.0f}" for a in dwell["all"]))
    print(f"run time {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
