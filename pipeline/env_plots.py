"""Figures of the environment model: the survey map, the DPC decision graph, the t-SNE map, the confusion matrix."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from features.site import ENV_CLASSES, Site
from pipeline.plots import CLASS_COLOURS, save_figure

__all__ = ["plot_survey_map", "plot_decision_graph", "plot_embedding", "plot_confusion", "confusion"]


def confusion(y_true: np.ndarray, y_pred: np.ndarray, n: int = 3) -> np.ndarray:
    """Counts [true, predicted], shape (n, n), of codes 0..n-1 (others ignored).

    >>> confusion(np.array([0, 0, 1, 2]), np.array([0, 1, 1, 2])).tolist()
    [[1, 1, 0], [0, 1, 0], [0, 0, 1]]
    """
    out = np.zeros((n, n), int)
    ok = (y_true >= 0) & (y_true < n) & (y_pred >= 0) & (y_pred < n)
    np.add.at(out, (y_true[ok], y_pred[ok]), 1)
    return out


def plot_survey_map(site: Site, cells: list[dict], cell_size_m: float, path: str | os.PathLike) -> Path:
    """Each cell a square coloured by predicted class (hatched when OOD), the site outline, beacons;
    cells whose map label disagrees are outlined in black."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch, Rectangle

    g = site.grid
    fig, ax = plt.subplots(figsize=(10, 10 * (g.north_max_m - g.north_min_m) / (g.east_max_m - g.east_min_m) + 1))
    h = cell_size_m / 2
    for c in cells:
        colour = CLASS_COLOURS[c["predicted"]]
        wrong = c.get("map_label") in ENV_CLASSES and c["map_label"] != c["predicted"]
        ax.add_patch(Rectangle((c["east_m"] - h, c["north_m"] - h), 2 * h, 2 * h, facecolor=colour,
                               alpha=0.35 + 0.6 * float(c["probability"]), hatch="xx" if c["ood"] else None,
                               edgecolor="black" if wrong else "white", lw=1.4 if wrong else 0.5))
    for b in site.layout:
        ax.add_patch(Rectangle((b.east_min_m, b.north_min_m), b.east_max_m - b.east_min_m, b.north_max_m - b.north_min_m,
                               facecolor="none", edgecolor="#333333", hatch="//" if b.porous else None, lw=0.9))
    for bc in site.beacons:
        ax.plot(bc.east_m, bc.north_m, "k^", ms=6)
    ax.set_xlim(g.east_min_m, g.east_max_m)
    ax.set_ylim(g.north_min_m, g.north_max_m)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    handles = [Patch(facecolor=CLASS_COLOURS[k], label=f"predicted {k}") for k in ENV_CLASSES]
    handles += [Patch(facecolor="white", edgecolor="black", lw=1.4, label="map label differs"),
                Patch(facecolor="white", hatch="xx", edgecolor="grey", label="out of distribution"),
                Patch(facecolor="none", edgecolor="#333333", label="structure (hatched: porous)"),
                plt.Line2D([], [], marker="^", color="k", ls="", label="beacon")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    ax.set_title(f"{site.name}: environment map from the survey (shade = class probability)")
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
