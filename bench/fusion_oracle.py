"""Ceilings of environment-aware fusion (issue 22): what a method could gain if it knew what no device knows.

Run on held-out walks with a trained fusion model; each oracle is the
adaptive machinery fed one piece of truth:

- ``oracle_class``     the context error model (bias, outlier prior, white scale per class and quality)
                       refitted on the training walks with the *true* class of each fix, and run with the
                       truth's class one-hot: no classifier error at all;
- ``oracle_variance``  each fix's R set to the true local error variance (the mean squared error of the same
                       source's fixes within ±2.5 s), no bias states: more than any learnt R could know;
- ``oracle_debias``    the GNSS fixes with their true slowly varying error removed (the error's mean over
                       ±5 s within one quality run), run with ``adaptive_nobp_blind``'s model.

If ``oracle_class`` is no better than ``adaptive_nobp_blind``, knowing the environment cannot help through
this error model whatever the classifier's accuracy. :func:`oracle_results` returns evaluate-shaped rows so
``bench/fusion_study.py`` puts them beside every method with the same intervals.

Usage: ``python bench/fusion_oracle.py SPLIT_DIR/data MODEL_DIR`` (the split's training walks refit the
class oracle; its test walks are scored).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ORACLES = ("oracle_class", "oracle_variance", "oracle_debias")


class _PerEventR:
    """A noise policy of given per-event R (an oracle's)."""

    def __init__(self, r_m2):
        self.r_m2 = r_m2

    def measurement_noise(self, stream, classes=None, class_at=None):
        from models.fusion.noise import NoiseSpec

        return NoiseSpec.per_event(self.r_m2)


def _local_mean(t: np.ndarray, v: np.ndarray, half_s: float, seg: np.ndarray | None = None) -> np.ndarray:
    """Mean of ``v`` (n, d) over the samples within ±``half_s`` of each (and of the same segment), (n, d)."""
    out = np.empty_like(v, dtype=float)
    lo = np.searchsorted(t, t - half_s, side="left")
    hi = np.searchsorted(t, t + half_s, side="right")
    for i in range(len(t)):
        sel = slice(lo[i], hi[i])
        w = np.ones(hi[i] - lo[i], bool) if seg is None else seg[sel] == seg[i]
        out[i] = v[sel][w].mean(axis=0)
    return out


def oracle_class_model(model, train_dirs):
    """The fusion model with its context error model refitted on the training walks' *true* classes."""
    from dataclasses import replace

    from models.fusion.context import ContextNoise, ErrorSeries
    from training.filters import training_rows
    from walks.inputs import walk_inputs
    from walks.reader import read_walk

    g_series, a_series = [], []
    for w in train_dirs:
        data = read_walk(w)
        row = training_rows(data, walk_inputs(data, model.classifier), str(w))
        g_series.append(ErrorSeries(row.g_t, row.g_err, row.g_cov, row.g_quality, row.g_map_class))
        a_series.append(ErrorSeries(row.a_t, row.a_err, row.a_cov, np.zeros(len(row.a_t), int), row.a_map_class))
    ctx = ContextNoise(n_classes=model.classifier.n_classes_).fit([g for g in g_series if len(g.t_s)],
                                                                  [a for a in a_series if len(a.t_s)])
    return replace(model, context=ctx)


def oracle_tracks(model, oracle_model, walk_dir) -> tuple[dict, object]:
    """The three oracle tracks of one walk and its data."""
    from dataclasses import replace

    from features.schema import ENV_CLASSES
    from models.fusion import ClassTrack, EkfConfig, EventEKF, GnssEvents, merge_events
    from walks.inputs import walk_inputs
    from walks.methods import filter_track, tuned
    from walks.reader import read_walk

    data = read_walk(walk_dir)
    inputs = walk_inputs(data, model.classifier)
    ev = inputs.events
    truth = data.truth
    te, tn = truth.at(ev.t_s)
    err = ev.z_m - np.column_stack([te, tn])
    out = {}
    # the true class, one-hot, and the model refitted on true classes
    cfg, scales = tuned(model, "adaptive_nobp")
    track = ClassTrack.from_labels(truth.t_s, truth.env_class, len(ENV_CLASSES))
    run = EventEKF(replace(cfg, outlier="mixture"), oracle_model.context, "oracle_class", scales).run(
        ev, classes=track)
    out["oracle_class"] = filter_track(run, "oracle_class", inputs)
    # R = the true local error variance per axis (same source, ±2.5 s)
    r = np.full((len(ev), 2, 2), np.nan)
    for code in (1, 2):
        sel = np.flatnonzero((ev.kind == code) & ev.available)
        if sel.size:
            var = _local_mean(ev.t_s[sel], err[sel] ** 2, 2.5)
            r[sel] = 0.0
            r[sel, 0, 0], r[sel, 1, 1] = np.maximum(var[:, 0], 1e-6), np.maximum(var[:, 1], 1e-6)
    run = EventEKF(EkfConfig(outlier="none"), _PerEventR(r), "oracle_variance").run(ev)
    out["oracle_variance"] = filter_track(run, "oracle_variance", inputs)
    # GNSS fixes minus their true slowly varying error, with the blind twin's model
    if ev.gnss is not None and len(ev.gnss.t_s):
        g = ev.gnss
        gte, gtn = truth.at(g.t_s)
        ge = np.column_stack([g.east_m - gte, g.north_m - gtn])
        seg = np.concatenate([[0], np.cumsum(np.diff(g.quality) != 0)])
        ok = np.all(np.isfinite(ge), axis=1)
        bias = np.zeros_like(ge)
        bias[ok] = _local_mean(g.t_s[ok], ge[ok], 5.0, seg[ok])
        clean = GnssEvents(g.t_s, g.east_m - bias[:, 0], g.north_m - bias[:, 1], g.cov_m2, quality=g.quality,
                           hdop=g.hdop, gst_sigma_m=g.gst_sigma_m, available=g.available)
        ev2 = merge_events(ev.steps, clean, ev.acoustic, ev.stands, t0_s=ev.t_s[0])
        cfg_b, scales_b = tuned(model, "adaptive_nobp_blind")
        run = EventEKF(replace(cfg_b, outlier="mixture"), model.context_blind, "oracle_debias", scales_b).run(ev2)
        out["oracle_debias"] = filter_track(run, "oracle_debias", inputs)
    return out, data


def oracle_results(model, train_dirs, test_dirs) -> list[dict]:
    """evaluate-shaped results ({'walk', 'site', 'rows'}) of the oracles on ``test_dirs``."""
    from walks.fuse import walk_name
    from walks.score import score

    om = oracle_class_model(model, train_dirs)
    out = []
    for w in test_dirs:
        tracks, data = oracle_tracks(model, om, w)
        out.append({"walk": walk_name(w), "site": data.site.name, "rows": score(tracks, data, walk_name(w))})
    return out


def main(split_dir: str, model_dir: str) -> None:
    from pipeline.evaluate import load_model
    from simulation.split import split_layout

    lay = split_layout(split_dir)
    res = oracle_results(load_model(model_dir), lay.train_walks, lay.test_walks)
    print(f"{len(res)} held-out walks; mean horizontal error, m (walks pooled by epochs)")
    for name in ORACLES:
        rows = [r for x in res for r in x["rows"] if r["method"] == name and r["env_class"] == "all"]
        n = sum(r["n"] for r in rows)
        print(f"  {name:16s} {sum(r['mean_m'] * r['n'] for r in rows) / max(n, 1):.3f}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__.strip().splitlines()[-1])
    main(sys.argv[1], sys.argv[2])
