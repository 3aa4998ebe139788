"""Issue 12 item 5: the survey grid covers the whole walkable yard at any cell size."""

import numpy as np
import pytest

from simulation.site.environment import blocked_share, classify_share
from simulation.site.layout import generate_site
from simulation.survey import survey_cells


@pytest.mark.parametrize("cell_size_m", [5.0, 10.0, 30.0])
def test_grid_reaches_every_edge_of_the_yard(cell_size_m):
    site = generate_site(3)
    g = site.grid
    cells = survey_cells(site, cell_size_m)
    e = np.array([c[1] for c in cells])
    n = np.array([c[2] for c in cells])
    assert np.all((e >= g.east_min_m) & (e <= g.east_max_m) & (n >= g.north_min_m) & (n <= g.north_max_m))
    # Every point of the yard lies within one cell diagonal of a capture point, edges included.
    assert n.max() > g.north_max_m - cell_size_m and e.max() > g.east_max_m - cell_size_m
    assert len({c[0] for c in cells}) == len(cells)


def test_thirty_metre_cells_include_heavy_ones():
    site = generate_site(3)
    cells = survey_cells(site, 30.0)
    labels = classify_share(blocked_share(site, [c[1] for c in cells], [c[2] for c in cells]))
    counts = np.bincount(labels, minlength=3)
    print("cells per class (open, light, heavy) at 30 m:", counts.tolist())
    assert len(cells) == int(np.ceil(site.grid.east_max_m / 30.0 - 1e-9) * np.ceil(site.grid.north_max_m / 30.0 - 1e-9)) \
        or len(cells) >= 0.8 * np.ceil(site.grid.east_max_m / 30.0) * np.ceil(site.grid.north_max_m / 30.0)
    assert counts[2] >= 1
