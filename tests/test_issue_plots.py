"""Issue 12 item 21: the site plot tells transformers from equipment, lists EMI zones, has a colour bar of
the blocked-sky share; the walk plot keeps its legends off the track, zooms to the walk, explains the class
background, shows acoustic fixes on every background, and draws no "against truth" panel without truth."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from matplotlib.colors import to_rgb

import pipeline.plots as plots
import pipeline.walk_report as walk_report


def _capture(monkeypatch):
    figs = []

    def fake_save(fig, path, dpi=130):
        figs.append(fig)
        return path

    monkeypatch.setattr(plots, "save_figure", fake_save)
    return figs


def _dist(a, b) -> float:
    return float(np.linalg.norm(np.subtract(to_rgb(a), to_rgb(b))))


def test_site_plot_legend_colours_and_colour_bar(site_dir, tmp_path, monkeypatch):
    from features.site import load_site

    site = load_site(site_dir)
    assert site.emi_zones
    figs = _capture(monkeypatch)
    plots.plot_site(site, tmp_path / "s.png", resolution_m=2.0)
    fig = figs[0]
    main_ax = fig.axes[0]
    labels = [t.get_text() for t in main_ax.get_legend().get_texts()]
    assert any(lab.startswith("EMI zone") for lab in labels)
    k = plots._KIND_COLOURS
    assert _dist(k["transformer"], k["equipment"]) > 0.3            # was 0.17 (two dark slates), now 0.64
    for kind, colour in k.items():
        assert min(_dist(colour, c) for c in plots.CLASS_COLOURS.values()) > 0.2, kind
    assert len(fig.axes) == 2                                       # the map and its colour bar
    bar_labels = [t.get_text() for t in fig.axes[1].get_xticklabels()]
    assert bar_labels == ["0 %", "10 %", "40 %", "100 %"]
    assert "blocked sky share" in fig.axes[1].get_xlabel()


@pytest.fixture(scope="module")
def sources(walk_dir):
    return walk_report.walk_sources(walk_dir)


def _outside(legend, ax, fig) -> bool:
    fig.canvas.draw()
    lb = legend.get_window_extent()
    ab = ax.get_window_extent()
    return lb.y1 <= ab.y0 or lb.x0 >= ab.x1 or lb.y0 >= ab.y1 or lb.x1 <= ab.x0


def test_walk_plot_with_truth(sources, tmp_path, monkeypatch):
    figs = _capture(monkeypatch)
    walk_report.plot_walk(sources, tmp_path / "w.png")
    fig = figs[0]
    ax, ax2 = fig.axes
    assert _outside(ax.get_legend(), ax, fig) and _outside(ax2.get_legend(), ax2, fig)
    # zoomed to the walk: the truth and the tracks fill the map within the 5 m margin, the truth is
    # inside it, the site is larger (a float GNSS stretch 0.5 m off the truth widens it by that much)
    e0, e1 = ax.get_xlim()
    n0, n1 = ax.get_ylim()
    te, tn = sources.truth.east_m, sources.truth.north_m
    ae = np.concatenate([te] + [np.asarray(t.east_m, float) for t in sources.tracks.values()])
    an = np.concatenate([tn] + [np.asarray(t.north_m, float) for t in sources.tracks.values()])
    ae, an = ae[np.isfinite(ae)], an[np.isfinite(an)]
    assert e0 >= ae.min() - 5.5 and e1 <= ae.max() + 5.5 and n0 >= an.min() - 5.5 and n1 <= an.max() + 5.5
    assert e0 <= te.min() and e1 >= te.max() and n0 <= tn.min() and n1 >= tn.max()
    g = sources.site.grid
    assert (e1 - e0) * (n1 - n0) < (g.east_max_m - g.east_min_m) * (g.north_max_m - g.north_min_m)
    labels = [t.get_text() for t in ax2.get_legend().get_texts()]
    present = {f"truth class: {c}" for i, c in enumerate(("open", "light", "heavy"))
               if np.any(sources.truth.env_class == i)}
    assert present == {t for t in labels if t.startswith("truth class")}      # the classes of this walk, no more
    acoustic = walk_report._SRC_STYLE["acoustic"]
    assert min(_dist(acoustic["color"], c) for c in plots.CLASS_COLOURS.values()) > 0.5
    assert acoustic["edgecolors"] == "black"


def test_walk_plot_without_truth_has_only_the_map(walk_dir, tmp_path, monkeypatch, capsys):
    from pipeline.cli import main

    bare = tmp_path / "bare"
    shutil.copytree(walk_dir, bare)
    (bare / "truth.csv").unlink()
    figs = _capture(monkeypatch)
    assert main(["report", "walk", str(bare), "--out", str(tmp_path / "w.png")]) == 0
    fig = figs[0]
    assert len(fig.axes) == 1
    assert "against truth" not in fig.axes[0].get_title() and "no truth.csv" in fig.axes[0].get_title()
    assert "no truth.csv" in capsys.readouterr().out
