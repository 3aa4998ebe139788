"""Issue 19: a method is one function and one registry line, and reaches ``run`` and ``evaluate`` from there.

Also the metric rows every report is made of, against hand-computed values (issue 20 item 3).
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

from features.walk import Truth
from models.fusion import EventEKF
from walks.methods import Method, MethodSkipped, method_names, register, run_methods, unregister
from walks.score import metric_rows, track_errors
from walks.track import Track


def _shifted_gnss(ctx):
    """A toy method: the GGA fixes moved 1 m east."""
    p = ctx.inputs.data.gnss.positions
    return Track("toy_shift", p.t_s, p.east_m + 1.0, p.north_m, None)


def _toy_filter(ctx):
    """A toy filter method: kf_quality's filter under another name (so it is smoothed too)."""
    return EventEKF(ctx.model.ekf, ctx.model.quality, "toy_filter").run(ctx.events())


def _never(ctx):
    raise MethodSkipped("toy reason")


@pytest.fixture
def toys():
    names = ("toy_shift", "toy_filter", "toy_never")
    register(Method("toy_shift", _shifted_gnss, "GGA fixes moved 1 m east"))
    register(Method("toy_filter", _toy_filter, "kf_quality again", filter=True))
    register(Method("toy_never", _never, "always skipped"))
    yield names
    for n in names:
        unregister(n)


def test_a_registered_method_runs_through_evaluate(toys, walk_dir, tmp_path):
    from models.environment import EnvironmentClassifier
    from models.fusion.model import save_fusion_model
    from pipeline.evaluate import evaluate
    from training.filters import train_fusion
    from walks.inputs import window_features
    from walks.reader import read_walk

    data = read_walk(walk_dir)
    t, X = window_features(data)
    clf = EnvironmentClassifier(min_samples=5).fit(X, data.truth.class_at(t - 1.0))
    save_fusion_model(train_fusion([walk_dir], clf, bp=False, tune=False), tmp_path / "m")
    assert method_names()[-3:] == toys
    assert {"toy_filter+rts", "toy_filter+lag"} <= set(method_names(smoothed=True))
    out = evaluate([walk_dir], tmp_path / "m", tmp_path / "rep", methods=("gnss", "kf_quality") + toys,
                   workers=1, progress=False, plots=False)
    assert out["results"][0]["skipped"] == {"toy_never": "toy reason"}
    rows = {(r["method"], r["env_class"]): r for r in csv.DictReader(open(tmp_path / "rep" / "metrics.csv"))
            if r["walk"] != "all"}
    # the toy filter is kf_quality under another name: the same numbers, and its +rts
    for k in ("n", "mean_m", "p95_m", "max_m"):
        assert rows[("toy_filter", "all")][k] == rows[("kf_quality", "all")][k]
    assert ("toy_filter+rts", "all") in rows
    # the shifted GNSS: the same epochs, errors by hand from the fixes against the interpolated truth
    p = data.gnss.positions
    inside = (p.t_s >= data.truth.t_s[0]) & (p.t_s <= data.truth.t_s[-1]) & np.isfinite(p.east_m)
    te, tn = np.interp(p.t_s[inside], data.truth.t_s, data.truth.east_m), np.interp(p.t_s[inside], data.truth.t_s,
                                                                                    data.truth.north_m)
    err = np.hypot(p.east_m[inside] + 1.0 - te, p.north_m[inside] - tn)
    assert int(rows[("toy_shift", "all")]["n"]) == inside.sum()
    assert float(rows[("toy_shift", "all")]["mean_m"]) == pytest.approx(err.mean(), rel=1e-5)


def test_registry_refuses_duplicates_and_unknown_names():
    with pytest.raises(ValueError, match="already registered"):
        register(Method("kf", _never, "a second kf"))
    with pytest.raises(ValueError, match="without"):
        register(Method("kf+rts", _never, "a smoothed name"))
    with pytest.raises(ValueError, match="unknown method"):
        run_methods(None, None, ("no_such_method",))


def test_metric_rows_by_hand():
    """Five epochs against a straight-line truth: errors 0.3, 0.4, 1.0, 2.0, 5.0 m, all northward; classes open,
    open, light, heavy, heavy; covariance diag(1, 0.25) m². NEES = e'P⁻¹e = 4e²: 0.36, 0.64, 4, 16, 100 (e'Pe
    would be 0.25e²); the 95 % χ²₂ region is [0.0506, 7.378], so 3 of 5 inside overall, 2/2 open, 1/1 light,
    0/2 heavy. The 95th percentile by linear interpolation (numpy's default, R type 7): rank 0.95·4 = 3.8,
    between 2.0 and 5.0 → 4.4."""
    t = np.arange(5.0)
    truth = Truth(t_s=t, east_m=t.copy(), north_m=np.zeros(5), env_class=np.array([0, 0, 1, 2, 2]))
    err = np.array([0.3, 0.4, 1.0, 2.0, 5.0])
    tr = Track("x", t, t.copy(), err.copy(), np.broadcast_to(np.diag([1.0, 0.25]), (5, 2, 2)).copy())
    te = track_errors(tr, truth)
    np.testing.assert_allclose(te["err_m"], err)
    np.testing.assert_allclose(te["nees"], 4 * err ** 2)
    rows = {r["env_class"]: r for r in metric_rows(te["err_m"], te["nees"], te["cls"], "w", "x")}
    assert list(rows) == ["all", "open", "light", "heavy"]
    assert [rows[c]["n"] for c in rows] == [5, 2, 1, 2]
    assert rows["all"]["mean_m"] == pytest.approx(8.7 / 5)
    assert rows["all"]["median_m"] == pytest.approx(1.0)
    assert rows["all"]["p95_m"] == pytest.approx(4.4)
    assert rows["all"]["max_m"] == 5.0
    assert rows["all"]["nees_in_bounds"] == pytest.approx(0.6)
    assert rows["open"]["nees_in_bounds"] == 1.0 and rows["light"]["nees_in_bounds"] == 1.0
    assert rows["heavy"]["nees_in_bounds"] == 0.0 and rows["heavy"]["mean_m"] == pytest.approx(3.5)
    # a track without covariance: no NEES share rather than a made-up one
    bare = track_errors(Track("y", t, t.copy(), err.copy(), None), truth)
    assert np.isnan(metric_rows(bare["err_m"], bare["nees"], bare["cls"], "w", "y")[0]["nees_in_bounds"])


def test_nees_in_bounds_counts_the_lower_tail_by_hand():
    """The NEES region is two-sided: χ²₂ is exponential with mean 2, so its 2.5 % and 97.5 % points are
    −2 ln 0.975 = 0.0506 and −2 ln 0.025 = 7.378 in closed form. Errors 0.1, 0.2, 0.5, 1, 3 m north under
    P = I give NEES 0.01, 0.04, 0.25, 1, 9: two below the region (too small an error for P — a filter that
    overstates its uncertainty), one above, so 2/5 inside. A one-sided test (upper bound only) would say 4/5."""
    t = np.arange(5.0)
    truth = Truth(t_s=t, east_m=t.copy(), north_m=np.zeros(5), env_class=np.zeros(5, int))
    err = np.array([0.1, 0.2, 0.5, 1.0, 3.0])
    te = track_errors(Track("x", t, t.copy(), err.copy(), np.broadcast_to(np.eye(2), (5, 2, 2)).copy()), truth)
    np.testing.assert_allclose(te["nees"], [0.01, 0.04, 0.25, 1.0, 9.0], rtol=1e-12)
    assert -2 * np.log(0.975) == pytest.approx(0.0506, abs=1e-4) and -2 * np.log(0.025) == pytest.approx(7.378, abs=1e-3)
    rows = metric_rows(te["err_m"], te["nees"], te["cls"], "w", "x")
    assert [r["env_class"] for r in rows] == ["all", "open"]
    assert rows[0]["nees_in_bounds"] == pytest.approx(0.4) and rows[1]["nees_in_bounds"] == pytest.approx(0.4)
