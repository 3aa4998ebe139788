"""One walk from its files to its fused tracks: the path ``envfuse run`` and every ``evaluate`` task share.

:func:`fuse_walk` reads the walk (:func:`walks.reader.read_walk`), checks
that the model was trained for the walk's site (:func:`check_site`; a model
that names no sites applies anywhere), builds the filter inputs
(:func:`walks.inputs.walk_inputs`) and runs the requested methods
(:func:`walks.methods.run_methods`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from features.errors import ConfigError
from models.fusion.model import FusionModel
from walks.inputs import WalkInputs, walk_inputs
from walks.methods import LAG_S, run_methods
from walks.reader import WalkData, read_walk

__all__ = ["FusedWalk", "fuse_walk", "check_site", "walk_name"]


@dataclass
class FusedWalk:
    """A walk's ``name`` (``<parent>/<dir>``), its ``data`` and ``inputs``, the ``tracks`` by method and the
    methods ``skipped`` with their reasons."""

    name: str
    data: WalkData
    inputs: WalkInputs
    tracks: dict
    skipped: dict


def walk_name(walk_dir: str | os.PathLike) -> str:
    """``<parent>/<dir>`` of a walk directory, e.g. ``201/w0``."""
    p = Path(walk_dir).resolve()
    return f"{p.parent.name}/{p.name}"


def check_site(model: FusionModel, site_name: str, walk: str, force: bool = False) -> None:
    """Refuse (:class:`~features.errors.ConfigError`) a walk of a site the model was not trained for, unless
    ``force``; a model whose metadata names no sites (e.g. one fitted for held-out sites) applies anywhere."""
    sites = model.meta.get("sites", [])
    if sites and site_name not in sites and not force:
        raise ConfigError(f"{walk}: site {site_name!r} is not one the model was trained on ({', '.join(sites)}); "
                          "pass --force to fuse it anyway")


def fuse_walk(walk_dir: str | os.PathLike, model: FusionModel, methods=None, *, smooth: bool = True,
              lag_s: float | None = LAG_S, class_map_for: Callable | None = None, force: bool = False) -> FusedWalk:
    """Read ``walk_dir`` and run ``methods`` (default: all) on it with ``model``.

    ``class_map_for``: callable site → :class:`~models.fusion.events.ClassMap` or None, the site map of the
    map baseline (``kf_map``), called only when that method is asked for. ``smooth``: the filters' RTS tracks
    too; ``lag_s``: their fixed-lag tracks with that lag (None: none).
    """
    name = walk_name(walk_dir)
    data = read_walk(walk_dir)
    check_site(model, data.site.name, str(walk_dir), force)
    inputs = walk_inputs(data, model.classifier)
    want = methods
    class_at = None
    if class_map_for is not None and (want is None or "kf_map" in want):
        class_at = class_map_for(data.site)
    tracks, skipped = run_methods(model, inputs, want, smooth=smooth, class_at=class_at, lag_s=lag_s)
    return FusedWalk(name, data, inputs, tracks, skipped)
