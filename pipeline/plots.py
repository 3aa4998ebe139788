"""Figures people look at (PNG, matplotlib's Agg backend: no display needed)."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402

from features.errors import ConfigError  # noqa: E402
from features.fileio import atomic_path  # noqa: E402
from features.site import ENV_CLASSES, Site  # noqa: E402

__all__ = ["CLASS_COLOURS", "PLOT_FORMATS", "plot_format", "plot_site", "save_figure", "EMI_COLOUR", "KIND_COLOURS",
           "draw_structures"]

PLOT_FORMATS = ("png", "pdf", "svg")
"""Figure formats written, chosen by the output's suffix (``-``, standard output, is PNG)."""


def plot_format(path: str | os.PathLike) -> str:
    """The format a plot path asks for, or ValueError naming the suffixes accepted.

    >>> plot_format("walk.PDF"), plot_format("-"), plot_format("map.svg")
    ('pdf', 'png', 'svg')
    """
    if str(path) == "-":
        return "png"
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in PLOT_FORMATS:
        raise ValueError(f"{path}: a plot is written as .png, .pdf or .svg (by its suffix), "
                         f"not {'.' + suffix if suffix else 'a name without a suffix'}")
    return suffix

CLASS_COLOURS = {"open": "#cfe8cf", "light": "#f6d98b", "heavy": "#e58a7a"}
_KIND_COLOURS = {"transformer": "#151515", "firewall": "#8b8b8b", "building": "#a06a4a", "gantry": "#5b7fa6",
                 "equipment": "#2f7f8f"}
"""Structure colours, distinct from each other and from the class colours (transformers near-black,
switchyard equipment teal)."""
KIND_COLOURS = _KIND_COLOURS
"""Public name of the structure colours: every plot that draws a site's layout uses them."""
EMI_COLOUR = "purple"


def draw_structures(ax, site: Site, alpha: float = 1.0, zorder: float = 1, extent=None) -> list:
    """Draw ``site``'s layout as every plot does: solid structures filled in their kind's colour
    (:data:`KIND_COLOURS`), porous ones (lattice gantries) hatched in it; ``alpha`` < 1 fades them under data.
    Returns legend handles for the kinds drawn (porous ones marked "hatched: porous, attenuates only"); with
    ``extent`` (east0, east1, north0, north1) only for the kinds seen inside it."""
    kinds = {}
    for b in site.layout:
        if extent is not None and (b.east_max_m < extent[0] or b.east_min_m > extent[1]
                                   or b.north_max_m < extent[2] or b.north_min_m > extent[3]):
            continue
        colour = _KIND_COLOURS.get(b.kind, "#777777")
        ax.add_patch(Rectangle((b.east_min_m, b.north_min_m), b.east_max_m - b.east_min_m,
                               b.north_max_m - b.north_min_m, facecolor="none" if b.porous else colour,
                               edgecolor=colour, hatch="////" if b.porous else None, lw=1.0, alpha=alpha,
                               zorder=zorder))
        kinds[b.kind] = kinds.get(b.kind, False) or b.porous
    handles = []
    for kind, porous in kinds.items():
        colour = _KIND_COLOURS.get(kind, "#777777")
        if porous:
            handles.append(Patch(facecolor="none", edgecolor=colour, hatch="////", alpha=alpha,
                                 label=f"{kind} (hatched: porous lattice, attenuates only)"))
        else:
            handles.append(Patch(facecolor=colour, edgecolor=colour, alpha=alpha, label=kind))
    return handles


def save_figure(fig, path: str | os.PathLike, dpi: int = 130) -> Path:
    """Save a figure atomically in the format of the path's suffix (PNG, PDF, SVG) and close it."""
    try:
        fmt = plot_format(path)
    except ValueError as exc:
        plt.close(fig)
        raise ConfigError(str(exc)) from None
    path = Path(path)
    try:
        with atomic_path(path, suffix="." + fmt) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=fmt)
    finally:
        plt.close(fig)
    return path


def plot_site(site: Site, path: str | os.PathLike, resolution_m: float = 0.5, title: str | None = None) -> Path:
    """Layout, beacons (with TDMA slot) and the ground-truth environment class map."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm

    from pipeline.site_map import classify, share_grid

    east, north, share, open_max, light_max = share_grid(site, resolution_m=resolution_m, n_az=120)
    cls = np.where(np.isfinite(share), classify(np.nan_to_num(share)), -1).astype(float)
    cls[cls < 0] = np.nan
    shares = [np.mean(cls[np.isfinite(cls)] == k) for k in range(3)]
    fig, ax = plt.subplots(figsize=(10, 10 * (north[-1] - north[0] + 1) / (east[-1] - east[0] + 1) + 0.8))
    cmap = ListedColormap([CLASS_COLOURS[c] for c in ENV_CLASSES])
    ax.imshow(cls, origin="lower", extent=(site.grid.east_min_m, site.grid.east_max_m, site.grid.north_min_m,
                                           site.grid.north_max_m), cmap=cmap, vmin=0, vmax=2, interpolation="nearest")
    for b in site.layout:
        ax.add_patch(Rectangle((b.east_min_m, b.north_min_m), b.east_max_m - b.east_min_m, b.north_max_m - b.north_min_m,
                               facecolor="none" if b.porous else _KIND_COLOURS[b.kind],
                               edgecolor=_KIND_COLOURS[b.kind], hatch="////" if b.porous else None, lw=1.0))
    for z in site.emi_zones:
        ax.add_patch(plt.Circle((z.east_m, z.north_m), z.radius_m, fill=False, ls=":", color=EMI_COLOUR, lw=1.0))
    for bc in site.beacons:
        ax.plot(bc.east_m, bc.north_m, marker="^", color="black", ms=7)
        ax.annotate(f"{bc.id}/s{bc.slot}", (bc.east_m, bc.north_m), xytext=(3, 3), textcoords="offset points",
                    fontsize=7)
    handles = [Patch(color=CLASS_COLOURS[c], label=f"{c} ({100 * s:.0f} %)") for c, s in zip(ENV_CLASSES, shares)]
    handles += [Patch(color=_KIND_COLOURS[k], label=k) for k in _KIND_COLOURS]
    handles += [plt.Line2D([], [], marker="^", color="black", ls="", label="beacon id/slot")]
    if site.emi_zones:
        handles += [plt.Line2D([], [], ls=":", color=EMI_COLOUR, lw=1.0, label="EMI zone (C/N0 loss)")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    # colour bar of the blocked-sky share with the class thresholds (the map shows the class of each share)
    norm = BoundaryNorm([0.0, open_max, light_max, 1.0], cmap.N)
    bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, location="bottom", fraction=0.04, pad=0.08,
                       aspect=40, ticks=[0.0, open_max, light_max, 1.0], spacing="proportional")
    bar.ax.set_xticklabels(["0 %", f"{100 * open_max:.0f} %", f"{100 * light_max:.0f} %", "100 %"])
    bar.set_label("blocked sky share above 10° elevation, weighted by the satellites' passes over a day: "
                  "open < 10 % <= light <= 40 % < heavy", fontsize=8)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.set_title(title or f"{site.name}: layout, beacons and environment class (blocked sky share)")
    return save_figure(fig, path)
