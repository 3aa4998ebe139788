"""Figures of the environment model: the survey map, the DPC decision graph, the t-SNE map, the confusion matrix."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from features.site import ENV_CLASSES, Site
from pipeline.plots import CLASS_COLOURS, save_figure

__all__ = ["plot_survey_map", "plot_decision_graph", "plot_embedding", "plot_confusion", "confusion",
           "cell_rectangles", "plot_class_track"]


def confusion(y_true: np.ndarray, y_pred: np.ndarray, n: int = 3) -> np.ndarray:
    """Counts [true, predicted], shape (n, n), of codes 0..n-1 (others ignored).

    >>> confusion(np.array([0, 0, 1, 2]), np.array([0, 1, 1, 2])).tolist()
    [[1, 1, 0], [0, 1, 0], [0, 0, 1]]
    """
    out = np.zeros((n, n), int)
    ok = (y_true >= 0) & (y_true < n) & (y_pred >= 0) & (y_pred < n)
    np.add.at(out, (y_true[ok], y_pred[ok]), 1)
    return out


def cell_rectangles(cells: list[dict], site: Site, pitch_m: float | None = None) -> list[tuple] | None:
    """Each cell's grid square (east0, north0, width, height), or None when the captures do not sit one per
    square of a grid.

    A survey is laid on a square grid from the site grid's south-west corner (``simulate survey`` does so;
    a crew with a tape would too); a capture may be moved off its square's centre, out of equipment, but
    stays inside its square. The pitch is ``pitch_m`` or, from the captures alone, the largest multiple of
    0.5 m up to twice the largest nearest-neighbour spacing that puts every capture in a square of its own
    (a larger pitch would merge two captures' squares, a smaller one leave gaps between them). Squares are
    clipped to the site's extent, as the survey clips its last row and column.
    """
    g = site.grid
    pts = np.array([[c["east_m"], c["north_m"]] for c in cells], float).reshape(-1, 2)
    if len(pts) == 0:
        return []
    if pitch_m:
        cands = [float(pitch_m)]
    elif len(pts) > 1:
        d = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        cands = list(np.arange(0.5, min(2.0 * float(d.min(axis=1).max()), 100.0) + 0.25, 0.5))
    else:
        cands = [g.cell_size_m]
    for pitch in sorted({c for c in cands if c and c > 0}, reverse=True):
        col = np.floor((pts[:, 0] - g.east_min_m) / pitch + 1e-9).astype(int)
        row = np.floor((pts[:, 1] - g.north_min_m) / pitch + 1e-9).astype(int)
        if len(set(zip(col.tolist(), row.tolist()))) != len(pts):
            continue
        rects = []
        for c, r in zip(col, row):
            e0, n0 = g.east_min_m + c * pitch, g.north_min_m + r * pitch
            e1, n1 = min(e0 + pitch, g.east_max_m), min(n0 + pitch, g.north_max_m)
            rects.append((e0, n0, max(e1 - e0, 1e-3), max(n1 - n0, 1e-3)))
        return rects
    return None


def _shade(colour: str, probability: float, n_classes: int = 3) -> tuple:
    """The class colour by the probability of the class: near-white at chance (1/n_classes), the class hue
    darker and more saturated at certainty, so the shading shows on the pale class colours."""
    import colorsys

    from matplotlib.colors import to_rgb

    hue, light, sat = colorsys.rgb_to_hls(*to_rgb(colour))
    w = float(np.clip((probability - 1.0 / n_classes) / (1 - 1.0 / n_classes), 0.0, 1.0))
    return colorsys.hls_to_rgb(hue, (1 - w) * 0.95 + w * max(light - 0.12, 0.35), min(1.0, sat * (0.6 + 0.6 * w)))


def plot_survey_map(site: Site, cells: list[dict], cell_size_m: float | None, path: str | os.PathLike) -> Path:
    """Each cell drawn as its grid square (:func:`cell_rectangles`; squares around the captures when they do
    not fit a grid), filled with the predicted class in a shade that deepens with its probability (chance
    pale, certain deep; the colour bars give the scale) and the probability written in it, hatched when out of
    distribution, outlined in black where the map label disagrees; structures as in the site plot; beacons;
    the capture points."""
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import ListedColormap, Normalize
    from matplotlib.patches import Patch, Rectangle

    from pipeline.plots import draw_structures

    g = site.grid
    rects = cell_rectangles(cells, site, cell_size_m)
    fitted = rects is not None
    if not fitted:
        h = 0.5 * (cell_size_m or g.cell_size_m)
        rects = [(c["east_m"] - h, c["north_m"] - h, 2 * h, 2 * h) for c in cells]
    fig, ax = plt.subplots(figsize=(11, 10 * (g.north_max_m - g.north_min_m) / (g.east_max_m - g.east_min_m) + 1.8))
    size = float(np.median([r[2] for r in rects])) if rects else 10.0
    for c, (e0, n0, w, hgt) in zip(cells, rects):
        wrong = c.get("map_label") in ENV_CLASSES and c["map_label"] != c["predicted"]
        ax.add_patch(Rectangle((e0, n0), w, hgt, facecolor=_shade(CLASS_COLOURS[c["predicted"]], c["probability"]),
                               hatch="xx" if c["ood"] else None, edgecolor="black" if wrong else "white",
                               lw=1.6 if wrong else 0.6, zorder=1 if not wrong else 1.5))
        if size >= 6.0 and w >= 4.0:
            ax.text(e0 + 0.06 * w, n0 + 0.94 * hgt, f"{c['probability']:.2f}", ha="left", va="top", fontsize=6,
                    color="#222222", zorder=4)
    handles = draw_structures(ax, site, alpha=0.55, zorder=2)
    for bc in site.beacons:
        ax.plot(bc.east_m, bc.north_m, "k^", ms=6, zorder=3)
    ax.plot([c["east_m"] for c in cells], [c["north_m"] for c in cells], ".", color="#444444", ms=2.5, zorder=3)
    ax.set_xlim(g.east_min_m, g.east_max_m)
    ax.set_ylim(g.north_min_m, g.north_max_m)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    handles = [Patch(facecolor=_shade(CLASS_COLOURS[k], 1.0), label=f"predicted {k}") for k in ENV_CLASSES] + [
        Patch(facecolor="white", edgecolor="black", lw=1.6, label="map label differs"),
        Patch(facecolor="white", hatch="xx", edgecolor="grey", label="out of distribution"),
        plt.Line2D([], [], marker=".", color="#444444", ls="", label="capture point"),
        plt.Line2D([], [], marker="^", color="k", ls="", label="beacon")] + handles
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    # the shade scale: one thin bar per class, right of the map under the legend
    for k, name in enumerate(reversed(ENV_CLASSES)):
        ramp = ListedColormap([_shade(CLASS_COLOURS[name], p) for p in np.linspace(1 / 3, 1, 32)])
        cax = ax.inset_axes([1.04, 0.03 + 0.11 * k, 0.3, 0.025])
        bar = fig.colorbar(ScalarMappable(Normalize(1 / 3, 1), ramp), cax=cax, orientation="horizontal",
                           ticks=[1 / 3, 0.5, 0.75, 1.0])
        bar.ax.set_xticklabels(["1/3 (chance)", "0.5", "0.75", "1"], fontsize=6)
        bar.ax.set_title(f"probability, predicted {name}", fontsize=7, loc="left")
    how = "grid squares" if fitted else "squares round the captures (they fit no grid)"
    ax.set_title(f"{site.name}: environment map from the survey ({how}; shade and number = class probability)",
                 fontsize=10)
    return save_figure(fig, path)


def plot_decision_graph(rho: np.ndarray, delta: np.ndarray, centers: np.ndarray, path) -> Path:
    """ρ against δ of the density-peak clustering, the chosen centres marked."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 5))
    ax.scatter(rho, delta, s=4, color="#777777", label="windows")
    ax.scatter(rho[centers], delta[centers], s=60, facecolor="none", edgecolor="red", lw=1.5,
               label=f"chosen centres ({len(centers)})")
    ax.set_xlabel("local density ρ")
    ax.set_ylabel("distance to a denser point δ")
    ax.set_yscale("log")
    ax.set_title("DPC decision graph (t-SNE plane)")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_embedding(embedding: np.ndarray, clusters: np.ndarray, labels: np.ndarray, path) -> Path:
    """The t-SNE plane twice: coloured by the severity-named cluster and by the cells' map label."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    ok = np.isfinite(embedding).all(axis=1)
    size = float(np.clip(4000.0 / max(ok.sum(), 1), 2.0, 25.0))      # visible for 100 windows, not a blot for 100k
    fig, axes = plt.subplots(1, 2, figsize=(13, 6))
    for ax, codes, title in ((axes[0], clusters, "clusters (named by severity)"), (axes[1], labels, "map label")):
        for k, c in enumerate(ENV_CLASSES):
            sel = ok & (codes == k)
            ax.scatter(embedding[sel, 0], embedding[sel, 1], s=size, color=CLASS_COLOURS[c], edgecolor="none")
        sel = ok & (codes < 0)
        ax.scatter(embedding[sel, 0], embedding[sel, 1], s=size, color="#bbbbbb", edgecolor="none")
        ax.set_title(f"t-SNE map coloured by {title}")
        ax.set_xticks([])
        ax.set_yticks([])
    axes[1].legend(handles=[Patch(color=CLASS_COLOURS[c], label=c) for c in ENV_CLASSES]
                   + [Patch(color="#bbbbbb", label="none")], fontsize=8, loc="best")
    return save_figure(fig, path)


def plot_confusion(matrix: np.ndarray, path, title: str = "confusion matrix") -> Path:
    """Counts with row-normalised shading: rows true class, columns predicted."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4.4))
    norm = matrix / np.maximum(matrix.sum(axis=1, keepdims=True), 1)
    ax.imshow(norm, cmap="Blues", vmin=0, vmax=1)
    for i in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            ax.text(j, i, f"{matrix[i, j]}\n{100 * norm[i, j]:.0f} %", ha="center", va="center",
                    color="white" if norm[i, j] > 0.6 else "black", fontsize=9)
    ax.set_xticks(range(3))
    ax.set_xticklabels(ENV_CLASSES)
    ax.set_yticks(range(3))
    ax.set_yticklabels(ENV_CLASSES)
    ax.set_xlabel("predicted")
    ax.set_ylabel("map label")
    ax.set_title(title)
    return save_figure(fig, path)


_CLASS_MARKERS = {"open": "#3a9a3a", "light": "#e0a100", "heavy": "#c8321e"}
"""Saturated class colours for points on a track (the pale :data:`CLASS_COLOURS` are for background shading)."""


def plot_class_track(track: dict, window_t_s: np.ndarray, proba: dict, path, error: dict | None = None,
                     title: str = "") -> Path:
    """The environment model's classes along a track: per model a map of the track with each window's class at
    the window's centre (``track``: {"t_s", "east_m", "north_m"} (n,), the reference or any position
    track); below, on one time axis, every model's class band and ``error`` ({"t_s", "err_m", "label"}: e.g.
    the per-epoch solver's error per window) on a log scale.

    ``window_t_s`` (k,) window centres; ``proba``: {model name: (k, 3) class probabilities}.
    """
    import matplotlib.pyplot as plt
    from matplotlib.gridspec import GridSpec
    from matplotlib.patches import Patch

    names = list(proba)
    t = np.asarray(window_t_s, float)
    e = np.interp(t, track["t_s"], track["east_m"])
    n = np.interp(t, track["t_s"], track["north_m"])
    span_e = float(np.ptp(track["east_m"])) or 1.0
    span_n = float(np.ptp(track["north_m"])) or 1.0
    map_w = float(np.clip(5.0 * span_e / span_n, 2.5, 7.0))
    rows = [2.8, 0.25 + 0.22 * len(names)] + ([1.1] if error is not None else [])
    fig = plt.figure(figsize=(max(9.0, (map_w + 1.2) * len(names) + 1.0), 7.0 + 2.2 * (len(rows) - 1)))
    gs = GridSpec(len(rows), len(names), height_ratios=rows, figure=fig, hspace=0.35)
    for j, name in enumerate(names):
        ax = fig.add_subplot(gs[0, j])
        ax.plot(track["east_m"], track["north_m"], "-", color="0.75", lw=2.5, zorder=1)
        cls = np.argmax(proba[name], axis=1)
        conf = np.max(proba[name], axis=1)
        for k, c in enumerate(ENV_CLASSES):
            sel = cls == k
            ax.scatter(e[sel], n[sel], s=8 + 30 * conf[sel], color=_CLASS_MARKERS[c], edgecolor="k", lw=0.3,
                       zorder=2, label=f"{c} ({int(sel.sum())} windows)")
        ax.plot(e[0], n[0], "k>", ms=8, zorder=3)
        ax.set_aspect("equal")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)" if j == 0 else "")
        ax.set_title(name, fontsize=10)
        ax.legend(fontsize=7, loc="best", framealpha=0.8)
    band = fig.add_subplot(gs[1, :])
    for i, name in enumerate(names):
        cls = np.argmax(proba[name], axis=1)
        for k, c in enumerate(ENV_CLASSES):
            sel = cls == k
            band.bar(t[sel], 0.8, width=1.0, bottom=len(names) - 1 - i - 0.4, color=_CLASS_MARKERS[c], lw=0)
    band.set_yticks(range(len(names)))
    band.set_yticklabels([s if len(s) < 30 else s[:28] + "…" for s in names[::-1]], fontsize=8)
    band.set_ylim(-0.5, len(names) - 0.5)
    band.legend(handles=[Patch(color=_CLASS_MARKERS[c], label=c) for c in ENV_CLASSES], fontsize=8, ncol=3,
                loc="lower left", bbox_to_anchor=(0.0, 1.0), frameon=False)
    band.set_title("class per window", fontsize=9, loc="right")
    if error is not None:
        ax = fig.add_subplot(gs[2, :], sharex=band)
        ok = np.isfinite(error["err_m"])
        ax.semilogy(np.asarray(error["t_s"])[ok], np.asarray(error["err_m"])[ok], "k-", lw=1.0)
        ax.set_ylabel("error (m)")
        ax.set_title(error.get("label", "error"), fontsize=9, loc="right")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_xlabel("time (s)")
    else:
        band.set_xlabel("time (s)")
    fig.suptitle(title or "environment classes along the track (marker size = class probability; ▶ start)")
    return save_figure(fig, path)
