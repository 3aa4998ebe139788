"""Issue 20: the map baseline (``kf_map``) looks its class up east as east and north as north.

Reference: the class at a point from the blocked-sky share computed *at that point*
(:func:`simulation.site.environment.blocked_share`, :func:`classify_share`) — no grid, no ClassMap. The
site is 122.6 × 86.9 m, so its class grid is not square, and the points are chosen where the class at
(east, north) differs from the class at (north, east): a lookup that swaps the axes (in the site map's
grid, in :class:`ClassMap`, in the compiled :func:`models.fusion.core.map_class` or where the filter calls it)
reads another class there.
"""

from __future__ import annotations

import numpy as np
import pytest

from features.site import load_site
from models.fusion import EkfConfig, EventEKF, PerClassNoise
from models.fusion.core import map_class
from models.fusion.noise import NoiseSpec
from pipeline.site_map import MAP_RESOLUTION_M, class_map_for
from simulation.site.environment import blocked_share, classify_share
from tests.fusion_synth import synth_walk


def _reference(site, east, north):
    """Class codes at the points themselves; inside a solid structure (share NaN) counts as heavy, as the map."""
    share = blocked_share(site, np.asarray(east, float), np.asarray(north, float), n_az=180)
    return np.where(np.isfinite(share), classify_share(np.nan_to_num(share)), 2)


def _stable_points(site, n: int, seed: int):
    """Points whose reference class is the same a map cell away in every direction (so grid quantisation
    cannot change it) and differs at the swapped point (north, east)."""
    g = site.grid
    rng = np.random.default_rng(seed)
    e = rng.uniform(g.east_min_m + 3, g.east_max_m - 3, n)
    nn = rng.uniform(g.north_min_m + 3, g.north_max_m - 3, n)
    ref = _reference(site, e, nn)
    same = np.ones(n, bool)
    for de, dn in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1), (1, -1), (-1, 1)):
        same &= _reference(site, e + de * MAP_RESOLUTION_M, nn + dn * MAP_RESOLUTION_M) == ref
    swapped = _reference(site, np.clip(nn, g.east_min_m, g.east_max_m), np.clip(e, g.north_min_m, g.north_max_m))
    keep = same & (swapped != ref)
    return e[keep], nn[keep], ref[keep]


@pytest.fixture(scope="module")
def site(site_dir):
    return load_site(site_dir / "site.toml")


def test_the_site_map_is_not_square_and_reads_each_point_as_the_reference(site):
    cm = class_map_for(site)
    assert cm.classes.shape[0] != cm.classes.shape[1]           # north rows ≠ east columns
    e, n, ref = _stable_points(site, 1500, seed=4)
    assert len(e) >= 40 and len(np.unique(ref)) >= 2            # enough asymmetric points of several classes
    got = np.array([cm(a, b) for a, b in zip(e, n)])
    assert np.mean(got == ref) >= 0.97, np.mean(got == ref)
    spec = NoiseSpec.by_map(np.eye(2), np.eye(2), cm)
    compiled = np.array([map_class(spec.map_grid, np.asarray(spec.map_geo, float), a, b) for a, b in zip(e, n)])
    assert np.array_equal(compiled, got)


def test_the_filter_takes_r_of_the_class_at_its_prior_position(site):
    """Through the filter: each GNSS update's R is the R of the reference class at the prior position."""
    r_class = np.array([np.eye(2) * 1.0, np.eye(2) * 4.0, np.eye(2) * 9.0])
    pc = PerClassNoise(3)
    pc.R_gnss_, pc.R_acoustic_ = r_class.copy(), r_class.copy()
    g = site.grid
    s = synth_walk(7, duration_s=120.0, start_en=(0.55 * g.east_max_m, 0.5 * g.north_max_m), turn_every_s=15.0)
    run = EventEKF(EkfConfig(), pc).run(s.stream, class_at=class_map_for(site))
    upd = np.flatnonzero(run.updated)
    pos = run.x_prior[upd, :2]
    ref = _reference(site, pos[:, 0], pos[:, 1])
    stable = np.ones(len(upd), bool)
    for de, dn in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        stable &= _reference(site, pos[:, 0] + de * MAP_RESOLUTION_M, pos[:, 1] + dn * MAP_RESOLUTION_M) == ref
    swapped = _reference(site, np.clip(pos[:, 1], g.east_min_m, g.east_max_m),
                         np.clip(pos[:, 0], g.north_min_m, g.north_max_m))
    assert np.sum(stable & (swapped != ref)) >= 20               # the walk crosses asymmetric ground
    used = run.R[upd][stable, 0, 0]
    assert np.mean(used == r_class[ref[stable], 0, 0]) >= 0.97
