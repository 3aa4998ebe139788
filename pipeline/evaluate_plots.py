"""Plots of an evaluation: trajectories over the site, error over time with the class band, error CDFs,
error by class (PNG, matplotlib's Agg backend).

Every method keeps one colour in every plot (:data:`METHOD_COLOURS`; a filter's ``+rts`` track is its
colour dashed) and methods are listed in report order (the registry's, :func:`pipeline.evaluate.method_order`),
as in ``metrics.csv`` and the summary. The site's structures are drawn as in the site plot
(:func:`pipeline.plots.draw_structures`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from features.site import ENV_CLASSES
from pipeline.plots import CLASS_COLOURS, draw_structures, save_figure

__all__ = ["plot_report", "FOCUS", "METHOD_COLOURS"]

FOCUS = ("gnss", "acoustic", "pdr", "kf", "kf_quality", "aekf", "imm", "adaptive_nobp", "adaptive")
"""Methods drawn in the trajectory and time plots (every method is in the CDF and the class bars)."""

METHOD_COLOURS = {"gnss": "#e41a1c", "acoustic": "#ff7f00", "pdr": "#377eb8", "kf": "#555555",
                  "kf_quality": "#a65628", "kf_map": "#b3a100", "aekf": "#17becf", "imm": "#984ea3",
                  "adaptive_nobp": "#4daf4a", "adaptive_nobp_blind": "#a1d99b", "adaptive": "#00441b",
                  "adaptive_blind": "#74c476", "adaptive_correction": "#e7298a"}
"""One colour per method, chosen to stay apart from each other (ColorBrewer Set1 and a few more)."""

_FALLBACK = ("#1f77b4", "#bcbd22", "#8c564b", "#f781bf", "#999999")


def _colour(m: str):
    base = m.split("+")[0]
    if base in METHOD_COLOURS:
        return METHOD_COLOURS[base]
    return _FALLBACK[sum(map(ord, base)) % len(_FALLBACK)]


def _style(m: str) -> dict:
    return {"color": _colour(m), "ls": "--" if m.endswith("+rts") else "-"}


def _walks(n: int) -> str:
    return f"{n} walk" + ("" if n == 1 else "s")


def plot_report(results: list[dict], pooled: list[dict], out_dir: Path) -> list[Path]:
    """Write ``trajectory_<walk>.png``, ``error_time_<walk>.png`` and ``classes_<walk>.png`` (the environment
    model's classes along the track) for every walk with truth, ``error_cdf.png`` and ``error_by_class.png`` (not
    when no epoch has a known truth class); returns their paths."""
    from pipeline.evaluate import method_order

    out_dir = Path(out_dir)
    paths = []
    tags: set = set()
    for res in results:
        if "_truth" not in res["series"]:
            continue
        tag = res["walk"].replace("/", "_")
        k = 2
        while tag in tags:
            tag = f"{res['walk'].replace('/', '_')}_{k}"
            k += 1
        tags.add(tag)
        paths.append(_trajectory(res, out_dir / f"trajectory_{tag}.png"))
        paths.append(_error_time(res, out_dir / f"error_time_{tag}.png"))
        if "_windows" in res["series"]:
            paths.append(_classes(res, out_dir / f"classes_{tag}.png"))
    paths.append(_cdf(results, out_dir / "error_cdf.png", method_order))
    if any(r["env_class"] in ENV_CLASSES for r in pooled):
        paths.append(_by_class(pooled, out_dir / "error_by_class.png", method_order))
    return paths


def _cdf(results: list[dict], path: Path, method_order) -> Path:
    import matplotlib.pyplot as plt

    pools: dict = {}
    for res in results:
        for m, s in res["series"].items():
            if not m.startswith("_"):
                pools.setdefault(m, []).append(s["err_m"])
    fig, ax = plt.subplots(figsize=(9, 5.8))
    for m in method_order(pools):
        e = np.sort(np.concatenate(pools[m]))
        if e.size == 0:
            continue
        ax.plot(np.maximum(e, 1e-3), np.arange(1, len(e) + 1) / len(e), label=m,
                lw=1.6 if not m.endswith("+rts") else 1.0, **_style(m))
    ax.set_xscale("log")
    ax.set_xlim(1e-3, None)
    ax.set_xlabel("horizontal error (m; below 1 mm drawn at 1 mm)")
    ax.set_ylabel("share of epochs")
    ax.set_title(f"error CDF per method, {_walks(len(results))} pooled (dashed: the filter's RTS-smoothed track)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), title="report order", title_fontsize=7)
    return save_figure(fig, path)


def _by_class(pooled: list[dict], path: Path, method_order) -> Path:
    """Mean error per method and truth class as bars (linear axis), p95 as markers, epoch counts under
    the bars; only the classes present are in the legend. A bar beyond the axis (a source that drifts,
    e.g. PDR alone) is cut at the top and labelled with its value."""
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    methods = [m for m in method_order({r["method"] for r in pooled}) if not m.endswith("+rts")]
    by = {(r["method"], r["env_class"]): r for r in pooled}
    present = [c for c in ENV_CLASSES if any((m, c) in by for m in methods)]
    fig, ax = plt.subplots(figsize=(max(8.0, 0.95 * len(methods) + 2.5), 5.2))
    width = 0.8 / max(len(present), 1)
    p95_all = [by[(m, c)]["p95_m"] for m in methods for c in present if (m, c) in by]
    # the axis shows the filters: its top is the 3rd-largest p95 (a drifting source or two stays cut)
    top = 1.15 * (sorted(p95_all)[-3] if len(p95_all) >= 3 else max(p95_all, default=1.0))
    top = max(top, 1e-3)
    for k, c in enumerate(present):
        x = np.arange(len(methods)) + (k - (len(present) - 1) / 2) * width
        for xi, m in zip(x, methods):
            r = by.get((m, c))
            if r is None:
                continue
            mean, p95 = r["mean_m"], r["p95_m"]
            ax.bar(xi, min(mean, top), width, color=CLASS_COLOURS[c], edgecolor="k", lw=0.4,
                   hatch="/" if mean > top else None)
            if mean > top:
                ax.text(xi, top * 0.5, f"mean {mean:.2g} m", ha="center", va="center", fontsize=6.5, rotation=90,
                        bbox={"facecolor": "white", "edgecolor": "none", "pad": 1.0})
            if p95 <= top:
                ax.plot(xi, p95, "v", color="k", ms=4)
            else:
                ax.plot(xi, top, "^", color="k", ms=5, clip_on=False)
            ax.text(xi, 0.005 * top, f"{r['n']}", ha="center", va="bottom", fontsize=6, rotation=90, color="#333333")
    ax.set_ylim(0, top)
    ax.set_xticks(np.arange(len(methods)))
    ax.set_xticklabels(methods, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("horizontal error (m)")
    ax.set_title("error by environment class (truth class at each epoch): bars = mean, ▼ = p95, "
                 "numbers at the foot = epochs", fontsize=10)
    ax.grid(True, axis="y", alpha=0.3)
    handles = [Patch(facecolor=CLASS_COLOURS[c], edgecolor="k", lw=0.4, label=f"{c}: mean") for c in present]
    handles += [Line2D([], [], marker="v", color="k", ls="", ms=4, label="p95"),
                Line2D([], [], marker="^", color="k", ls="", ms=5, label="p95 above the axis"),
                Patch(facecolor="white", edgecolor="k", hatch="/", lw=0.4, label="mean above the axis (printed)")]
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(fig, path)


def _classes(res: dict, path: Path) -> Path:
    """The classifier's classes along the truth track, with the GNSS fixes' error per window beside them."""
    from pipeline.env_error import window_error
    from pipeline.env_plots import plot_class_track

    w = res["series"]["_windows"]
    err = None
    g = res["series"].get("gnss")
    if g is not None:
        t_end = np.asarray(w["t_s"], float) + 1.0
        err = {"t_s": w["t_s"], "err_m": window_error(t_end, g["t_s"], g["err_m"]),
               "label": "GNSS fixes: mean error per window"}
    return plot_class_track(res["series"]["_truth"], w["t_s"], {"environment model": w["proba"]}, path, err,
                            f"{res['walk']}: environment classes along the truth track")


def _class_band(ax, truth: dict) -> list:
    """The truth class as background spans (epochs of unknown class, code < 0 as on a drive's reference, stay
    white); returns legend handles for the classes that occur."""
    from matplotlib.patches import Patch

    t, c = truth["t_s"], truth["cls"]
    edges = np.flatnonzero(np.diff(c)) + 1
    for a, b in zip(np.r_[0, edges], np.r_[edges, len(t)]):
        if c[a] >= 0:
            ax.axvspan(t[a], t[min(b, len(t) - 1)], color=CLASS_COLOURS[ENV_CLASSES[c[a]]], lw=0)
    handles = [Patch(color=CLASS_COLOURS[k], label=f"truth: {k}") for i, k in enumerate(ENV_CLASSES) if np.any(c == i)]
    if np.any(np.asarray(c) < 0):
        handles.append(Patch(facecolor="white", edgecolor="0.6", label="truth class unknown"))
    return handles


def _trajectory(res: dict, path: Path) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from features.walk import load_walk

    site = None
    try:
        site = load_walk(res["walk_dir"]).load_site() if "walk_dir" in res else None
    except Exception:  # noqa: BLE001 - the layout is decoration; a walk without its site still plots
        site = None
    fig, ax = plt.subplots(figsize=(10, 7))
    tr = res["series"]["_truth"]
    pad = 8.0
    extent = (float(np.min(tr["east_m"])) - pad, float(np.max(tr["east_m"])) + pad,
              float(np.min(tr["north_m"])) - pad, float(np.max(tr["north_m"])) + pad)
    structure_handles = draw_structures(ax, site, alpha=0.45, zorder=1, extent=extent) if site is not None else []
    # truth thin and under the tracks, so a track lying on it stays visible
    ax.plot(tr["east_m"], tr["north_m"], "-", color="black", lw=0.8, label="truth", zorder=2)
    for m in FOCUS:
        s = res["series"].get(m)
        if s is None:
            continue
        if m in ("gnss", "acoustic"):
            ax.plot(s["east_m"], s["north_m"], ".", ms=2.5, color=_colour(m), label=m, alpha=0.7, zorder=3)
        else:
            ax.plot(s["east_m"], s["north_m"], "-", lw=1.1, color=_colour(m), label=m, alpha=0.9, zorder=4)
    ax.plot(tr["east_m"][0], tr["north_m"][0], "o", ms=9, mfc="white", mec="black", mew=1.5, zorder=6)
    ax.plot(tr["east_m"][-1], tr["north_m"][-1], "s", ms=8, mfc="black", mec="black", zorder=6)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    handles, _ = ax.get_legend_handles_labels()
    handles += [Line2D([], [], marker="o", ms=8, mfc="white", mec="black", ls="", label="start"),
                Line2D([], [], marker="s", ms=7, mfc="black", mec="black", ls="", label="end")]
    handles += structure_handles
    ax.legend(handles=handles, fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.set_title(f"{res['walk']}: trajectories against truth")
    return save_figure(fig, path)


def _error_time(res: dict, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 5))
    band = _class_band(ax, res["series"]["_truth"])
    for m in FOCUS:
        s = res["series"].get(m)
        if s is None:
            continue
        ax.semilogy(s["t_s"], np.maximum(s["err_m"], 1e-3), "-" if m not in ("gnss", "acoustic") else ".",
                    ms=2, lw=0.8, color=_colour(m), label=m)
    ax.set_xlabel("walk time (s)")
    ax.set_ylabel("horizontal error (m; below 1 mm drawn at 1 mm)")
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(handles=handles + band, fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    known = np.asarray(res["series"]["_truth"]["cls"]) >= 0
    ax.set_title(f"{res['walk']}: error over time, background = truth class"
                 + ("" if known.any() else " (none known: white)"))
    return save_figure(fig, path)
