"""Batch evaluation: every method on every walk, metrics, summary, plots (``envfuse evaluate``).

:func:`evaluate_walk` is the per-walk task — a pure function of the walk's
files and the model bundle's path, so it runs the same serially or on a Dask
worker (:mod:`pipeline.parallel`). :func:`evaluate` maps it over the walks,
writes ``metrics.csv`` (:data:`pipeline.fusion.METRIC_COLUMNS`) and the PNGs,
and returns the rows.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from features.errors import ConfigError
from features.fileio import atomic_write_text
from pipeline.fusion import METHODS, METRIC_COLUMNS, metric_rows, run_methods, score, track_errors, walk_inputs
from pipeline.parallel import TaskFailure, map_walks
from pipeline.walk_data import read_walk

__all__ = ["evaluate_walk", "evaluate", "summary_table", "pooled_rows"]


def evaluate_walk(walk, model_dir: str, methods: tuple, force: bool = False) -> dict:
    """Run ``methods`` on one walk; returns {'walk', 'rows', 'skipped', 'series'} (series: per method the
    error over time, for plots; kept small: every event of a filter, every fix of a source)."""
    from models.fusion_model import load_fusion_model

    model = load_fusion_model(model_dir)
    data = read_walk(walk)
    sites = model.meta.get("sites", [])
    if sites and data.site.name not in sites and not force:
        raise ConfigError(f"{walk}: site {data.site.name!r} is not one the model was trained on ({sites}); "
                          "pass --force to evaluate anyway")
    inputs = walk_inputs(data, model)
    tracks, skipped = run_methods(model, inputs, methods)
    resolved = Path(walk).resolve()
    name = f"{resolved.parent.name}/{resolved.name}"
    rows = score(tracks, data, name)
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
    bp_off = tracks["adaptive"].info.get("bp_disabled_share") if "adaptive" in tracks else None
    return {"walk": name, "walk_dir": str(walk), "rows": rows, "skipped": skipped, "series": series,
            "bp_disabled_share": bp_off,
            "site": data.site.name}


def pooled_rows(results: list[dict]) -> list[dict]:
    """Per method and class over all walks, every epoch of every walk pooled (walk = 'all')."""
    pools: dict = {}
    for res in results:
        for m, s in res["series"].items():
            if not m.startswith("_"):
                pools.setdefault(m, []).append(s)
    rows = []
    for m in _method_order(sorted(pools)):
        err = np.concatenate([s["err_m"] for s in pools[m]]).astype(float)
        cls = np.concatenate([s["cls"] for s in pools[m]])
        nees = np.concatenate([s["nees"] for s in pools[m]]).astype(float)
        rows += metric_rows(err, nees, cls, "all", m)
    return rows


def _method_order(names):
    base = [m for m in METHODS for v in (m, m + "+rts") if v in names]
    seen, out = set(), []
    for m in METHODS:
        for v in (m, m + "+rts"):
            if v in names and v not in seen:
                seen.add(v)
                out.append(v)
    return out + [n for n in names if n not in seen and n not in base]


def summary_table(rows: list[dict]) -> str:
    """Plain-text table of pooled rows: method, then mean / median / p95 / max per class and NEES share."""
    classes = ("all", "open", "light", "heavy")
    by = {(r["method"], r["env_class"]): r for r in rows}
    methods = _method_order(sorted({r["method"] for r in rows}))
    head = f"{'method':18s} " + " ".join(f"{c + ' mean/med/p95':>21s}" for c in classes) + "  max_m  NEES95"
    lines = [head, "-" * len(head)]
    for m in methods:
        cells = []
        for c in classes:
            r = by.get((m, c))
            cells.append(f"{r['mean_m']:6.2f}/{r['median_m']:5.2f}/{r['p95_m']:5.2f}   " if r else " " * 21)
        a = by.get((m, "all"))
        nib = "" if a is None or not np.isfinite(a["nees_in_bounds"]) else f"{a['nees_in_bounds']:.2f}"
        lines.append(f"{m:18s} " + " ".join(f"{x:>21s}" for x in cells) + f" {a['max_m'] if a else float('nan'):6.2f}"
                     f"  {nib:>6s}")
    return "\n".join(lines)


def _csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=METRIC_COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items() if k in METRIC_COLUMNS})
    return buf.getvalue()


def evaluate(walks: list, model_dir: str | os.PathLike, report_dir: str | os.PathLike, methods=METHODS,
             workers: int | None = None, scheduler: str | None = None, force: bool = False,
             progress: bool = True, plots: bool = True) -> dict:
    """Evaluate ``methods`` on ``walks``; writes ``metrics.csv`` and the plots into ``report_dir``."""
    from models.fusion_model import load_fusion_model

    load_fusion_model(model_dir)           # a damaged model fails here, once, before any worker starts
    report = Path(report_dir)
    if report.exists() and not report.is_dir():
        raise ConfigError(f"--report {report} exists and is not a directory")
    results = map_walks(evaluate_walk, [str(w) for w in walks], str(model_dir), tuple(methods), force,
                        workers=workers, scheduler=scheduler, progress=progress, desc="evaluate")
    failures = [r for r in results if isinstance(r, TaskFailure)]
    ok = [r for r in results if not isinstance(r, TaskFailure)]
    report.mkdir(parents=True, exist_ok=True)
    per_walk = [row for r in ok for row in r["rows"]]
    pooled = pooled_rows(ok) if ok else []
    atomic_write_text(report / "metrics.csv", _csv_text(per_walk + pooled))
    pngs = []
    if plots and ok:
        from pipeline.evaluate_plots import plot_report

        pngs = plot_report(ok, pooled, report)
    return {"results": ok, "failures": failures, "pooled": pooled, "pngs": pngs}
