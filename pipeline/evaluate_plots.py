"""Plots of an evaluation: trajectories over the site, error over time with the class band, error CDFs,
error by class (PNG, matplotlib's Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from features.site import ENV_CLASSES
from pipeline.plots import CLASS_COLOURS, save_figure

__all__ = ["plot_report", "FOCUS"]

FOCUS = ("gnss", "acoustic", "pdr", "kf", "kf_quality", "aekf", "imm", "adaptive_nobp", "adaptive")
"""Methods drawn in the trajectory and time plots (every method is in the CDF and the class bars)."""

_COLOURS = {"gnss": "#d62728", "acoustic": "#ff7f0e", "pdr": "#1f77b4", "kf": "#7f7f7f", "kf_quality": "#8c564b",
            "kf_map": "#bcbd22", "aekf": "#17becf", "imm": "#9467bd", "adaptive_nobp": "#2ca02c",
            "adaptive": "#006400", "adaptive_closed": "#e377c2"}


def _colour(m: str):
    return _COLOURS.get(m.split("+")[0])


def _style(m: str) -> dict:
    return {"color": _colour(m), "ls": "--" if m.endswith("+rts") else "-"}


def plot_report(results: list[dict], pooled: list[dict], out_dir: Path) -> list[Path]:
    """Write ``trajectory_<walk>.png`` (first walk of each site), ``error_time_<walk>.png``, ``classes_<walk>.png``
    (the environment model's classes along the track), ``error_cdf.png``
    and ``error_by_class.png`` (not when no epoch has a known truth class); returns their paths."""
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    paths = []
    seen_sites = set()
    for res in results:
        if res["site"] in seen_sites or "_truth" not in res["series"]:
            continue
        seen_sites.add(res["site"])
        tag = res["walk"].replace("/", "_")
        paths.append(_trajectory(res, out_dir / f"trajectory_{tag}.png"))
        paths.append(_error_time(res, out_dir / f"error_time_{tag}.png"))
        if "_windows" in res["series"]:
            paths.append(_classes(res, out_dir / f"classes_{tag}.png"))
    fig, ax = plt.subplots(figsize=(8, 5.5))
    pools: dict = {}
    for res in results:
        for m, s in res["series"].items():
            if not m.startswith("_"):
                pools.setdefault(m, []).append(s["err_m"])
    for m in sorted(pools, key=lambda k: (k.endswith("+rts"), k)):
        e = np.sort(np.concatenate(pools[m]))
        ax.plot(e, np.arange(1, len(e) + 1) / len(e), label=m, lw=1.2 if not m.endswith("+rts") else 0.8,
                **_style(m))
    ax.set_xscale("log")
    ax.set_xlim(1e-3, None)
    ax.set_xlabel("horizontal error (m)")
    ax.set_ylabel("share of epochs")
    ax.set_title(f"error CDF per method, {len(results)} walks pooled (dashed: RTS-smoothed)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="lower right")
    paths.append(save_figure(fig, out_dir / "error_cdf.png"))

    methods = [m for m in dict.fromkeys(r["method"] for r in pooled) if not m.endswith("+rts")]
    by = {(r["method"], r["env_class"]): r for r in pooled}
    if not any(c in ENV_CLASSES for _, c in by):
        return paths            # no epoch of a known class (a drive's reference): no bars to draw
    fig, ax = plt.subplots(figsize=(max(8, 0.9 * len(methods) + 2), 5))
    width = 0.8 / len(ENV_CLASSES)
    for k, c in enumerate(ENV_CLASSES):
        vals = [by[(m, c)]["mean_m"] if (m, c) in by else np.nan for m in methods]
        p95 = [by[(m, c)]["p95_m"] if (m, c) in by else np.nan for m in methods]
        x = np.arange(len(methods)) + (k - 1) * width
        ax.bar(x, vals, width, color=CLASS_COLOURS[c], edgecolor="k", lw=0.4, label=f"{c}: mean")
        ax.plot(x, p95, "v", color="k", ms=4, label="p95" if k == 0 else None)
    ax.set_xticks(np.arange(len(methods)))
    ax.set_xticklabels(methods, rotation=30, ha="right", fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("horizontal error (m)")
    ax.set_title("error by environment class (truth class at each epoch); bars = mean, ▼ = p95")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    paths.append(save_figure(fig, out_dir / "error_by_class.png"))
    return paths


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


def _class_band(ax, truth: dict) -> None:
    """Shade the time axis by the truth class; epochs of unknown class (code < 0, a drive's reference) stay white."""
    t, c = truth["t_s"], truth["cls"]
    edges = np.flatnonzero(np.diff(c)) + 1
    for a, b in zip(np.r_[0, edges], np.r_[edges, len(t)]):
        if c[a] >= 0:
            ax.axvspan(t[a], t[min(b, len(t) - 1)], color=CLASS_COLOURS[ENV_CLASSES[c[a]]], lw=0)


def _trajectory(res: dict, path: Path) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch, Rectangle

    from features.walk import load_walk

    site = None
    try:
        site = load_walk(res["walk_dir"]).load_site() if "walk_dir" in res else None
    except Exception:  # noqa: BLE001 - the layout is decoration; a walk without its site still plots
        site = None
    fig, ax = plt.subplots(figsize=(10, 7))
    if site is not None:
        for b in site.layout:
            ax.add_patch(Rectangle((b.east_min_m, b.north_min_m), b.east_max_m - b.east_min_m,
                                   b.north_max_m - b.north_min_m, facecolor="none" if b.porous else "#dddddd",
                                   edgecolor="#999999", hatch="//" if b.porous else None, lw=0.5))
    tr = res["series"]["_truth"]
    ax.plot(tr["east_m"], tr["north_m"], "k-", lw=2.0, label="truth", zorder=5)
    for m in FOCUS:
        s = res["series"].get(m)
        if s is None:
            continue
        if m in ("gnss", "acoustic"):
            ax.plot(s["east_m"], s["north_m"], ".", ms=2, color=_colour(m), label=m, alpha=0.6)
        else:
            ax.plot(s["east_m"], s["north_m"], "-", lw=0.9, color=_colour(m), label=m)
    pad = 8.0
    ax.set_xlim(float(np.min(tr["east_m"])) - pad, float(np.max(tr["east_m"])) + pad)
    ax.set_ylim(float(np.min(tr["north_m"])) - pad, float(np.max(tr["north_m"])) + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    handles, labels = ax.get_legend_handles_labels()
    if site is not None and site.layout:
        handles.append(Patch(facecolor="#dddddd", edgecolor="#999999", label="solid structure"))
    ax.legend(handles=handles, fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.set_title(f"{res['walk']}: trajectories against truth")
    return save_figure(fig, path)


def _error_time(res: dict, path: Path) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    fig, ax = plt.subplots(figsize=(12, 5))
    _class_band(ax, res["series"]["_truth"])
    for m in FOCUS:
        s = res["series"].get(m)
        if s is None:
            continue
        ax.semilogy(s["t_s"], np.maximum(s["err_m"], 1e-3), "-" if m not in ("gnss", "acoustic") else ".",
                    ms=2, lw=0.8, color=_colour(m), label=m)
    ax.set_xlabel("walk time (s)")
    ax.set_ylabel("horizontal error (m)")
    handles, _ = ax.get_legend_handles_labels()
    known = np.asarray(res["series"]["_truth"]["cls"]) >= 0
    handles += [Patch(color=CLASS_COLOURS[c], label=f"truth: {c}") for c in ENV_CLASSES]
    if not known.all():
        handles.append(Patch(facecolor="white", edgecolor="0.6", label="truth class unknown"))
    ax.legend(handles=handles, fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.set_title(f"{res['walk']}: error over time, background = truth class"
                 + ("" if known.any() else " (none known: white)"))
    return save_figure(fig, path)
