"""Simulated fingerprint surveys: one static capture per grid cell (docs/design.md §4).

The crew walks the grid row by row (boustrophedon), standing ``capture_s`` in
each cell at its centre — or, when the centre lies inside a structure, at the
free point of the cell nearest to it — and takes ``move_s`` to reach the next.
"""

from __future__ import annotations

import os
import shutil
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from features.errors import ConfigError
from features.fileio import atomic_directory, write_toml
from features.site import ENV_CLASSES, load_site

from simulation.site.environment import blocked_share, classify_share
from simulation.site.geometry import boxes_array, inside_boxes
from simulation.progress import Progress
from simulation.rng import stream_seed
from simulation.site.route import static_trajectory
from simulation.streams import STREAM_WRITERS, StreamContext, run_stream_writers
from simulation.walk import default_start_utc, format_utc

__all__ = ["survey_cells", "simulate_survey"]


def survey_cells(site, cell_size_m: float, clearance_m: float = 0.5):
    """Capture points of a grid survey covering the whole yard at any cell size.

    Returns a list of (cell_id, east_m, north_m) in walking order; cells with
    no free point are left out. Cell ids are ``E{col:03d}N{row:03d}``. The grid
    starts at the site grid's south-west corner; a last column or row that
    does not fit whole is kept, clipped to the site's extent, and captured at
    the centre of its clipped part (issue 12 item 5: with 30 m cells on a
    126 × 83 m site the northern 23 m were left out).
    """
    g = site.grid
    solid = boxes_array([b for b in site.layout if not b.porous])
    n_col = max(1, int(np.ceil((g.east_max_m - g.east_min_m) / cell_size_m - 1e-9)))
    n_row = max(1, int(np.ceil((g.north_max_m - g.north_min_m) / cell_size_m - 1e-9)))
    frac = np.linspace(-0.5, 0.5, 11)[1:-1]
    cells = []
    for row in range(n_row):
        n0 = g.north_min_m + row * cell_size_m
        n1 = min(n0 + cell_size_m, g.north_max_m)
        cols = range(n_col) if row % 2 == 0 else range(n_col - 1, -1, -1)
        for col in cols:
            e0 = g.east_min_m + col * cell_size_m
            e1 = min(e0 + cell_size_m, g.east_max_m)
            ce, cn = 0.5 * (e0 + e1), 0.5 * (n0 + n1)
            su, sv = np.meshgrid(frac * (e1 - e0), frac * (n1 - n0))
            offsets = np.column_stack([su.ravel(), sv.ravel()])
            offsets = offsets[np.argsort(np.hypot(offsets[:, 0], offsets[:, 1]), kind="stable")]
            cand = np.array([[ce, cn]]) + np.vstack([[0.0, 0.0], offsets])
            ok = ~inside_boxes(cand, solid, margin_m=clearance_m)
            if ok.any():
                p = cand[np.flatnonzero(ok)[0]]
                cells.append((f"E{col:03d}N{row:03d}", round(float(p[0]), 3), round(float(p[1]), 3)))
    return cells


def simulate_survey(site_path: str | os.PathLike, out_dir: str | os.PathLike, seed: int = 0,
                    cell_size_m: float | None = None, capture_s: float = 30.0, move_s: float = 20.0,
                    start_utc: datetime | None = None, overwrite: bool = False, options: dict | None = None,
                    writers: tuple[str, ...] = STREAM_WRITERS, progress: bool = True) -> Path:
    """Simulate a grid survey of the site into ``out_dir`` (site.toml + cells/<id>/...)."""
    if not (capture_s > 0 and np.isfinite(capture_s)):
        raise ConfigError(f"--capture-s must be positive, got {capture_s}")
    site_path = Path(site_path)
    site_file = site_path / "site.toml" if site_path.is_dir() else site_path
    site = load_site(site_file)
    if not site.layout:
        raise ConfigError(f"{site_file}: has no [[layout]]; surveys can only be simulated on a simulated site")
    cell_size_m = float(cell_size_m or site.grid.cell_size_m)
    if not 0.5 <= cell_size_m <= 50:
        raise ConfigError(f"--cell-size must lie in [0.5, 50] m, got {cell_size_m}")
    cells = survey_cells(site, cell_size_m)
    if not cells:
        raise ConfigError("no survey cell has a free capture point")
    share = blocked_share(site, [c[1] for c in cells], [c[2] for c in cells])
    labels = classify_share(share)
    start = start_utc or default_start_utc(seed)
    with atomic_directory(Path(out_dir), overwrite=overwrite) as tmp, \
            Progress(len(cells), "survey cells", unit="cell", enabled=progress) as bar:
        shutil.copyfile(site_file, tmp / "site.toml")
        for i, ((cid, e, n), lab, sh) in enumerate(zip(cells, labels, share)):
            t0 = start + timedelta(seconds=i * (capture_s + move_s))
            cell_dir = tmp / "cells" / cid
            cell_dir.mkdir(parents=True)
            traj = static_trajectory(e, n, site.device_height_m, capture_s, t0)
            cell_seed = int(stream_seed(seed, "cell", cid).generate_state(1)[0])
            ctx = StreamContext(site=site, trajectory=traj, out_dir=cell_dir, seed=cell_seed, kind="survey",
                                person_seed=seed, options=dict(options or {}))
            meta = run_stream_writers(ctx, writers)
            cell = {"id": cid, "east_m": e, "north_m": n, "start_utc": format_utc(t0), "duration_s": float(capture_s),
                    "map_label": ENV_CLASSES[int(lab)], "blocked_sky_share": round(float(sh), 4)}
            cell.update(meta)
            write_toml(cell_dir / "cell.toml", cell)
            bar.update(1)
        write_toml(tmp / "survey.toml", {"site_name": site.name, "seed": int(seed), "cell_size_m": cell_size_m,
                                         "capture_s": float(capture_s), "n_cells": len(cells),
                                         "start_utc": format_utc(start)})
    return Path(out_dir)
