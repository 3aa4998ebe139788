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

from features.errors import ConfigError, DataError, EnvfuseError
from models.fusion.model import FusionModel
from walks.inputs import HOP_S, WINDOW_S, WalkInputs, walk_inputs
from walks.methods import LAG_S, run_methods
from walks.reader import WalkData, read_walk

__all__ = ["FusedWalk", "fuse_walk", "check_site", "check_windows", "walk_name"]


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


def check_windows(env_meta: dict, where: str) -> None:
    """Refuse (:class:`~features.errors.ConfigError`) an environment model fitted on feature windows other
    than those a walk is classified on (:data:`walks.inputs.WINDOW_S`, hop :data:`walks.inputs.HOP_S`): its class
    probabilities would describe another statistic. A model that states no window predates the check and was
    fitted on the only windows there were then (2 s, hop 1 s)."""
    window, hop = env_meta.get("window_s"), env_meta.get("hop_s")
    if window is None and hop is None:
        return
    if abs(float(window) - WINDOW_S) > 1e-9 or abs(float(hop) - HOP_S) > 1e-9:
        raise ConfigError(f"{where} was fitted on {float(window):g} s windows (hop {float(hop):g} s) but walks are "
                          f"classified on {WINDOW_S:g} s windows (hop {HOP_S:g} s): rebuild the library with "
                          f"'survey build --window-s {WINDOW_S:g} --hop-s {HOP_S:g} --replace' and refit")



def fuse_walk(walk_dir: str | os.PathLike, model: FusionModel, methods=None, *, smooth: bool = True,
              lag_s: float | None = LAG_S, class_map_for: Callable | None = None, force: bool = False,
              truth: bool = True, class_smoothing: str = "forward") -> FusedWalk:
    """Read ``walk_dir`` and run ``methods`` (default: all) on it with ``model``.

    ``class_map_for``: callable site → :class:`~models.fusion.events.ClassMap` or None, the site map of the
    map baseline (``kf_map``), called only when that method is asked for. ``smooth``: the filters' RTS tracks
    too; ``lag_s``: their fixed-lag tracks with that lag (None: none). ``truth=False``: leave ``truth.csv``
    unread (``run``). ``class_smoothing``: how the model's class HMM smooths the window classes
    (:data:`walks.inputs.CLASS_SMOOTHING`; ``"forward"``, causal, as ``run`` needs). A domain error raised past the
    read names the walk.
    """
    name = walk_name(walk_dir)
    data = read_walk(walk_dir, truth=truth)
    check_site(model, data.site.name, str(walk_dir), force)
    check_windows(model.meta.get("env_meta", {}), "the model's environment classifier")
    if data.gnss is None and data.acoustic is None and data.pdr is None:
        why = "; ".join(data.notes) if data.notes else "walk.toml names no gnss, audio or imu stream"
        raise DataError(f"{walk_dir}: no usable stream to fuse ({why})")
    try:
        inputs = walk_inputs(data, model.classifier, model.temporal, class_smoothing)
        want = methods
        class_at = None
        if class_map_for is not None and (want is None or "kf_map" in want):
            class_at = class_map_for(data.site)
        tracks, skipped = run_methods(model, inputs, want, smooth=smooth, class_at=class_at, lag_s=lag_s)
    except EnvfuseError as exc:
        if str(walk_dir) in str(exc):
            raise
        raise DataError(f"{walk_dir}: {exc}") from None
    return FusedWalk(name, data, inputs, tracks, skipped)
