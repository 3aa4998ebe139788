"""Issue 22 item 6: the site-level bootstrap of paired per-walk differences, on cases worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.compare import compare, walk_scores


def _results(errors: dict, sites: list[str], n: int = 100) -> list[dict]:
    """evaluate()-shaped results: one walk per entry of ``sites``, per method the walk's mean error."""
    out = []
    for i, site in enumerate(sites):
        rows = [{"method": m, "env_class": "all", "mean_m": float(v[i]), "n": n} for m, v in errors.items()]
        out.append({"walk": f"{site}/w{i}", "site": site, "rows": rows})
    return out


def test_a_uniform_gain_has_a_degenerate_interval():
    sites = ["s1", "s1", "s2", "s2", "s3", "s3"]
    b = np.array([0.3, 0.5, 0.2, 0.4, 0.6, 0.1])
    c = compare(walk_scores([_results({"A": 0.8 * b, "B": b}, sites)]), "A", "B")
    assert c.delta == pytest.approx(-0.2) and c.lo == pytest.approx(-0.2) and c.hi == pytest.approx(-0.2)
    assert c.n_walks == 6 and c.n_sites == 3 and c.excludes_zero


def test_a_gain_on_one_site_of_three_is_not_significant():
    """A halves the error on site 1 and ties on sites 2 and 3 (equal errors and epochs everywhere): over a
    resample with k copies of site 1, Δ = −k/6, k ~ Binomial(3, 1/3): P(k=3) = 1/27 > 2.5 % and
    P(k=0) = 8/27 > 2.5 %, so the 95 % percentile interval is exactly [−0.5, 0]; the estimate −1/6."""
    sites = ["s1", "s2", "s3"]
    b = np.array([0.4, 0.4, 0.4])
    c = compare(walk_scores([_results({"A": np.array([0.2, 0.4, 0.4]), "B": b}, sites)]), "A", "B", n_boot=8000)
    assert c.delta == pytest.approx(-1 / 6)
    assert c.lo == pytest.approx(-0.5) and c.hi == pytest.approx(0.0)
    assert not c.excludes_zero


def test_seeds_are_averaged_per_walk_and_epochs_weight_walks():
    sites = ["s1", "s2"]
    r1 = _results({"A": np.array([0.2, 0.4]), "B": np.array([0.4, 0.4])}, sites)
    r2 = _results({"A": np.array([0.4, 0.4]), "B": np.array([0.4, 0.4])}, sites)
    s = walk_scores([r1, r2])
    np.testing.assert_allclose(s.mean_m[("A", "all")], [0.3, 0.4])
    r3 = _results({"A": np.array([0.2, 0.4]), "B": np.array([0.4, 0.4])}, sites)
    r3[0]["rows"] = [dict(r, n=300) for r in r3[0]["rows"]]          # walk 1 has three times the epochs
    c = compare(walk_scores([r3]), "A", "B")
    assert c.delta == pytest.approx((300 * 0.2 + 100 * 0.4) / (300 * 0.4 + 100 * 0.4) - 1)
    assert compare(s, "A", "no_such") is None
