"""Batch evaluation: every method on every walk, metrics, summary, plots (``envfuse evaluate``).

:func:`evaluate_walk` is the per-walk task — :func:`walks.fuse.fuse_walk`, the
path ``envfuse run`` takes, then the walk's metric rows and the per-epoch
series the plots draw. It is a pure function of the walk's files and the model
bundle's path, so it runs the same serially or on a Dask worker
(:mod:`pipeline.parallel`); the model is loaded once per process and content
(:func:`load_model`). :func:`evaluate` maps it over the walks, writes
``metrics.csv`` (:data:`walks.score.METRIC_COLUMNS`) and the PNGs, and returns
the rows.
"""

from __future__ import annotations

import contextlib
import csv
import io
import os
from pathlib import Path

import numpy as np

from features.errors import ConfigError
from features.fileio import atomic_write_text
from pipeline.parallel import TaskFailure, map_walks
from walks.inputs import CLASS_SMOOTHING, WINDOW_S
from walks.methods import method_names
from walks.score import METRIC_COLUMNS, metric_rows, score, track_errors
from walks.segments import SEGMENT_S

__all__ = ["evaluate_walk", "evaluate", "summary_table", "pooled_rows", "load_model", "method_order", "NEES_NOTE",
           "bp_guard_line", "REPORT_PLOT_PREFIXES", "model_loads"]

_MODELS: dict = {}
"""This process's model cache: {resolved model folder: (its :func:`~models.bundle.bundle_digest`, the model)}."""
_LOADS = {"n": 0}


def load_model(model_dir: str | os.PathLike):
    """The fusion model of ``model_dir``, read once per process and kept while the folder's content is unchanged.

    The cache is keyed by the folder's resolved path AND its content hash (:func:`models.bundle.bundle_digest`,
    every file's SHA-256), checked on every call: a Dask worker keeps its model across the walks it is given
    and, on a long-lived cluster (``evaluate --scheduler``), across runs, yet a folder replaced by another model
    (even one with the same modification times) is read again, never served stale. One model is kept: a
    different path or content replaces it."""
    from models.bundle import bundle_digest
    from models.fusion.model import load_fusion_model

    path = Path(model_dir).resolve()
    digest = bundle_digest(path)
    key = str(path)
    hit = _MODELS.get(key)
    if hit is None or digest is None or hit[0] != digest:
        _MODELS.clear()
        model = load_fusion_model(path)      # an unreadable or damaged folder raises BundleError here
        _LOADS["n"] += 1
        _MODELS[key] = (digest, model)
    return _MODELS[key][1]


def model_loads() -> int:
    """How many times this process has read a model bundle through :func:`load_model` (a worker's count tells
    whether it kept its model: one per model, not one per walk)."""
    return _LOADS["n"]


def evaluate_walk(walk, model_dir: str, methods: tuple, force: bool = False, segment_s: float = SEGMENT_S,
                  class_smoothing: str = "forward") -> dict:
    """Run ``methods`` on one walk; returns {'walk', 'rows', 'skipped', 'series', ...} (series: per method the
    error over time, for plots; kept small: every event of a filter, every fix of a source). A walk longer than
    ``segment_s`` is fused segment by segment (:mod:`pipeline.evaluate_segments`, causal classes only).
    ``class_smoothing``: the classes handed to the filters (:data:`walks.inputs.CLASS_SMOOTHING`; ``"forward"``,
    what ``run`` gives them, unless a study measures another)."""
    from pipeline.site_map import class_map_for
    from walks.fuse import fuse_walk, walk_name
    from walks.segments import plan_segments

    from features.errors import DataError

    n_segments = plan_segments(walk, segment_s)[0]
    if n_segments > 1:   # a long walk: segment by segment, memory bounded (pipeline.evaluate_segments)
        from pipeline.evaluate_segments import evaluate_segmented
        from pipeline.parallel import task_progress

        if class_smoothing != "forward":
            raise ConfigError(f"{walk}: a walk longer than {segment_s:g} s is evaluated segment by segment, with the "
                              f"causal ('forward') classes only, not {class_smoothing!r}")

        # its segments' progress to the bar of the evaluate running it (a shift is minutes of work)
        return evaluate_segmented(walk, load_model(model_dir), methods, class_map_for, force, walk_name(walk),
                                  segment_s, progress=lambda k: task_progress(k, n_segments))
    # by default the filters get the causal (forward) classes run gives them, not the HMM's forward-backward ones:
    # evaluate scores the tracks run would write (a zero-latency filter fed classes from its future is flattered)
    fused = fuse_walk(walk, load_model(model_dir), methods, class_map_for=class_map_for, force=force,
                      class_smoothing=class_smoothing)
    data, tracks = fused.data, fused.tracks
    if data.truth is None:
        raise DataError(f"{walk}: no truth.csv, so no error to measure (evaluate scores tracks against truth; "
                        "'envfuse run' writes a walk's track without one)")
    rows = score(tracks, data, fused.name)
    if not rows:
        why = "; ".join(f"{m}: {r}" for m, r in fused.skipped.items()) or "no track overlaps the truth in time"
        raise DataError(f"{walk}: no method gave a track to score ({why})")
    series = {}
    if data.truth is not None:
        for m, tr in tracks.items():
            te = track_errors(tr, data.truth)
            ok = te["ok"]
            series[m] = {"t_s": te["t_s"].astype(np.float32), "err_m": te["err_m"].astype(np.float32),
                         "east_m": tr.east_m[ok].astype(np.float32), "north_m": tr.north_m[ok].astype(np.float32),
                         "cls": te["cls"].astype(np.int8), "nees": te["nees"].astype(np.float32)}
        series["_truth"] = {"t_s": data.truth.t_s.astype(np.float32), "cls": data.truth.env_class.astype(np.int8),
                            "east_m": data.truth.east_m.astype(np.float32),
                            "north_m": data.truth.north_m.astype(np.float32)}
    inputs = fused.inputs
    if len(inputs.window_t_s):
        # the classifier's answer per window (the first row of the class track is the prior before any window)
        series["_windows"] = {"t_s": (inputs.window_t_s - WINDOW_S / 2.0).astype(np.float32),
                              "proba": inputs.classes.proba[1:].astype(np.float32)}
    bp_off = (tracks["adaptive_correction"].info.get("bp_disabled_share")
              if "adaptive_correction" in tracks else None)
    guard = tracks["adaptive"].info["run"].info.get("bp_guard_share") if "adaptive" in tracks else None
    return {"walk": fused.name, "walk_dir": str(walk), "rows": rows, "skipped": fused.skipped, "series": series,
            "bp_disabled_share": bp_off, "bp_guard_share": guard, "site": data.site.name,
            "notes": list(data.notes)}


def pooled_rows(results: list[dict]) -> list[dict]:
    """Per method and class over all walks, every epoch of every walk pooled (walk = 'all')."""
    pools: dict = {}
    for res in results:
        for m, s in res["series"].items():
            if not m.startswith("_"):
                pools.setdefault(m, []).append(s)
    rows = []
    for m in method_order(pools):
        err = np.concatenate([s["err_m"] for s in pools[m]]).astype(float)
        cls = np.concatenate([s["cls"] for s in pools[m]])
        nees = np.concatenate([s["nees"] for s in pools[m]]).astype(float)
        rows += metric_rows(err, nees, cls, "all", m)
    return rows


def method_order(names) -> list[str]:
    """``names`` in report order: the registry's order, each filter's ``+rts`` after it, unknown names last."""
    order = method_names(smoothed=True)
    known = [m for m in order if m in names]
    return known + sorted(n for n in names if n not in order)


NEES_NOTE = ("NEES ok: share of epochs whose normalised error e'P^-1e (e: error, P: the track's own covariance) "
             "lies inside the two-sided 95 % chi-square(2) interval [0.05, 7.38]; a filter whose covariance "
             "matches its errors scores about 0.95, lower means it is over- or under-confident "
             "(metrics.csv: nees_in_bounds; empty for a source without a covariance)")
"""The footnote printed under :func:`summary_table`."""


def summary_table(rows: list[dict]) -> str:
    """Plain-text table of pooled rows: method, then mean / median / p95 / max per class and the NEES share
    (:data:`NEES_NOTE` says what it is)."""
    classes = ("all", "open", "light", "heavy")
    by = {(r["method"], r["env_class"]): r for r in rows}
    methods = method_order({r["method"] for r in rows})
    w = max([18] + [len(m) for m in methods])
    head = f"{'method':{w}s} " + " ".join(f"{c + ' mean/med/p95 m':>21s}" for c in classes) + "  max_m NEES ok"
    lines = [head, "-" * len(head)]
    for m in methods:
        cells = []
        for c in classes:
            r = by.get((m, c))
            cells.append(f"{r['mean_m']:6.2f}/{r['median_m']:5.2f}/{r['p95_m']:5.2f}   " if r else " " * 21)
        a = by.get((m, "all"))
        nib = "" if a is None or not np.isfinite(a["nees_in_bounds"]) else f"{a['nees_in_bounds']:.2f}"
        lines.append(f"{m:{w}s} " + " ".join(f"{x:>21s}" for x in cells) + f" {a['max_m'] if a else float('nan'):6.2f}"
                     f"  {nib:>6s}")
    return "\n".join(lines + [NEES_NOTE])


def _csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items() if k in METRIC_COLUMNS})
    return buf.getvalue()


def evaluate(walks: list, model_dir: str | os.PathLike, report_dir: str | os.PathLike, methods=None,
             workers: int | None = None, scheduler: str | None = None, force: bool = False,
             progress: bool = True, plots: bool = True, class_smoothing: str = "forward",
             segment_s: float = SEGMENT_S) -> dict:
    """Evaluate ``methods`` (default: every registered one) on ``walks``; writes ``metrics.csv`` and the plots
    into ``report_dir``. ``class_smoothing``: the window classes the filters get (:func:`evaluate_walk`); a walk
    longer than ``segment_s`` is fused in segments of that length (:mod:`walks.segments`), its progress shown
    segment by segment.

    A walk whose task fails (any error, here or on a worker) is named in ``failures`` and left out; the
    others' report is written. An existing report is replaced consistently: its ``metrics.csv`` is removed
    first, the plots written, plots of walks no longer in the report removed, and the new ``metrics.csv``
    written last (atomically) — so a report with a ``metrics.csv`` is always a complete one.
    """
    methods = method_names() if methods is None else tuple(methods)
    if class_smoothing not in CLASS_SMOOTHING:
        raise ConfigError(f"class smoothing must be one of {', '.join(CLASS_SMOOTHING)}, got {class_smoothing!r}")
    load_model(model_dir)                  # a damaged model fails here, once, before any worker starts
    report = Path(report_dir)
    if report.exists() and not report.is_dir():
        raise ConfigError(f"--report {report} exists and is not a directory")
    results = map_walks(evaluate_walk, [str(w) for w in walks], str(model_dir), tuple(methods), force, segment_s,
                        class_smoothing, workers=workers, scheduler=scheduler, progress=progress, desc="evaluate")
    failures = [r for r in results if isinstance(r, TaskFailure)]
    ok = [r for r in results if not isinstance(r, TaskFailure)]
    report.mkdir(parents=True, exist_ok=True)
    per_walk = [row for r in ok for row in r["rows"]]
    pooled = pooled_rows(ok) if ok else []
    with contextlib.suppress(FileNotFoundError):
        (report / "metrics.csv").unlink()       # from here until the new one lands, the report is incomplete
    pngs = []
    if plots and ok:
        from pipeline.evaluate_plots import plot_report

        pngs = plot_report(ok, pooled, report)
    keep = {Path(p).name for p in pngs}
    for old in report.glob("*.png"):
        if old.name not in keep and old.name.startswith(REPORT_PLOT_PREFIXES):
            old.unlink()
    atomic_write_text(report / "metrics.csv", _csv_text(per_walk + pooled))
    return {"results": ok, "failures": failures, "pooled": pooled, "pngs": pngs}


REPORT_PLOT_PREFIXES = ("trajectory_", "error_time_", "error_cdf", "error_by_class")
"""Names of the plots an evaluation writes; older ones not written again are removed from the report."""


def bp_guard_line(share: float) -> str:
    """What the BP guards did, in words a reader of the summary can use."""
    text = (f"BP correction (method adaptive): applied on {100 * (1 - share):.1f} % of epochs; withheld on "
            f"{100 * share:.1f} % by its guards (input outside the network's training range, correction smaller "
            "than its own uncertainty, or the next fixes fitting worse with it), where adaptive equals adaptive_nobp")
    if share >= 0.999:
        text += "; here the network never acted, so adaptive is adaptive_nobp"
    return text
