"""The whole walk's RTS smoother over a walk fused in segments (walks/segment_rts.py), and the calibrated
covariance of a segment reading the whole walk's NIS (FilterRun.state_before's history, walks/calibrate.py)."""

from __future__ import annotations

import copy
import csv
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from models.fusion.ekf import FilterRun
from models.fusion.smoother import rts_smooth
from walks.segment_rts import SegmentedRts


def _cv_run(seed: int, m: int = 240):
    """A constant-velocity Kalman filter (east, north, v_e, v_n) over ``m`` events at irregular intervals, run
    by filterpy: its priors, posteriors and transition matrices, and filterpy's own RTS smoother of them."""
    from filterpy.kalman import KalmanFilter, rts_smoother

    rng = np.random.default_rng(seed)
    dts = rng.uniform(0.05, 1.5, m)
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.x = np.array([0.0, 0.0, 1.0, 0.5])
    kf.P = np.diag([4.0, 4.0, 1.0, 1.0])
    kf.H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    kf.R = np.eye(2) * 0.3
    truth = np.zeros(4)
    xs, Ps, xp, Pp, Fs, Qs = [], [], [], [], [], []
    for dt in dts:
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        Q = np.diag([0.01 * dt, 0.01 * dt, 0.05 * dt, 0.05 * dt])
        truth = F @ truth + rng.normal(0.0, 0.1, 4)
        kf.predict(F=F, Q=Q)
        xp.append(kf.x.copy())
        Pp.append(kf.P.copy())
        kf.update(truth[:2] + rng.normal(0.0, 0.5, 2))
        xs.append(kf.x.copy())
        Ps.append(kf.P.copy())
        Fs.append(F)
        Qs.append(Q)
    run = SimpleNamespace(method="cv", t_s=np.cumsum(dts), kind=np.zeros(m, int), x=np.array(xs), P=np.array(Ps),
                          x_prior=np.array(xp), P_prior=np.array(Pp), F=np.array(Fs))
    # filterpy's smoother forms each prior again from F and Q (P⁻_{k+1} = F P_k F' + Q): an independent
    # computation of the same recursion. Its module-level function takes at k the F and Q from k to k + 1.
    ref_x, ref_P, _, _ = rts_smoother(run.x, run.P, np.array(Fs[1:] + [np.eye(4)]), np.array(Qs[1:] + [Qs[0]]))
    return run, ref_x, ref_P


@pytest.mark.parametrize("cuts", [(60, 120, 180), (1, 2, 239), (100,), (0, 0, 239, 240)])
def test_pieces_give_the_whole_run_s_smoother(tmp_path, cuts):
    """Pieces of one run (one of a single event, empty ones) smoothed as segments: filterpy's RTS over the
    whole run within 1e-9, and envfuse's own over the whole run to the bit."""
    run, ref_x, ref_P = _cv_run(3)
    whole = rts_smooth(run)
    bounds = [0, *cuts, len(run.t_s)]
    with SegmentedRts(tmp_path) as store:
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            keep = np.zeros(len(run.t_s), bool)
            keep[lo:hi] = True
            store.add(run, keep, {"row": np.arange(lo, hi)})
        store.smooth()
        parts = list(store.segments())
        tmp = store._dir
        assert tmp.parent == tmp_path and tmp.is_dir()
    assert not tmp.exists()
    assert len(parts) == sum(hi > lo for lo, hi in zip(bounds[:-1], bounds[1:]))
    east = np.concatenate([p["east_m"] for p in parts])
    north = np.concatenate([p["north_m"] for p in parts])
    cov = np.concatenate([p["cov_m2"] for p in parts])
    assert np.concatenate([p["row"] for p in parts]).tolist() == list(range(len(run.t_s)))
    assert np.concatenate([p["t_s"] for p in parts]).tolist() == run.t_s.tolist()
    np.testing.assert_allclose(east, ref_x[:, 0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(north, ref_x[:, 1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(cov, ref_P[:, :2, :2], rtol=0, atol=1e-9)
    assert np.array_equal(east, whole.x[:, 0]) and np.array_equal(cov, whole.P[:, :2, :2])


def test_bad_use_is_refused_and_the_folder_removed(tmp_path):
    run, _, _ = _cv_run(4, 50)
    first, second = np.arange(50) < 25, np.arange(50) >= 25
    with pytest.raises(ValueError, match="time order"):
        with SegmentedRts(tmp_path) as store:
            store.add(run, second)
            store.add(run, first)
    assert list(tmp_path.iterdir()) == []
    with SegmentedRts(tmp_path) as store:
        with pytest.raises(ValueError, match="one row per kept event"):
            store.add(run, first, {"row": np.arange(3)})
        with pytest.raises(RuntimeError, match="before smooth"):
            next(store.segments())


def test_state_before_carries_the_nis_history():
    m = 7
    t = np.array([0.0, 1.0, 2.0, 2.0, 5.0, 9.0, 20.0])
    nis = np.array([1.0, np.nan, 3.0, 4.0, 5.0, 6.0, 7.0])
    x = np.arange(m * 2, dtype=float).reshape(m, 2)
    P = np.broadcast_to(np.eye(2), (m, 2, 2)).copy()
    run = FilterRun("kf", t, np.zeros(m, int), x[0], P[0], x, P, P, x, P, np.full((m, 2), np.nan),
                    np.full((m, 2, 2), np.nan), np.full((m, 2, 2), np.nan), np.full((m, 2, 2), np.nan), nis,
                    np.ones(m), np.ones(m, bool), np.ones(m, bool), np.ones(m, bool))
    s = run.state_before(9.5, history_s=8.0)       # events in [1.5, 9.5): at 2, 2, 5, 9
    assert s.x.tolist() == x[5].tolist() and s.nis_t_s.tolist() == [2.0, 2.0, 5.0, 9.0]
    assert s.nis.tolist() == [3.0, 4.0, 5.0, 6.0]
    assert run.state_before(9.0).nis_t_s.tolist() == []   # no history asked: none (the event at 9 is not before)


# -- end to end: `envfuse run` of a walk in segments against the walk whole --------------------------------------

class _NisScale:
    """A stand-in calibrator whose scale is the 2 s running-mean NIS times the track's own trace (columns 1 and 0
    of models.fusion.calibration.calibration_inputs): any difference in either input shows in the covariance."""

    def scale(self, X):
        return np.exp(X[:, 1]) * np.exp(0.5 * X[:, 0])


def _read(path: Path) -> dict:
    rows = list(csv.DictReader(open(path)))
    return {k: np.array([float(r[k]) if r[k] else np.nan for r in rows]) for k in ("t_s", "east_m", "north_m",
                                                                                   "var_east_m2", "var_north_m2")}


@pytest.fixture(scope="module")
def looped(walk_dir, tmp_path_factory):
    """The 60 s session walk looped 4 times (4 minutes): 60 s segments cut it at 3 seams."""
    from tests.long_walk import loop_walk

    return loop_walk(walk_dir, tmp_path_factory.mktemp("segment_rts") / "x4", 4)


def test_a_walk_in_segments_gives_the_whole_walk_s_rts_track_and_covariance(model_and_walk, looped, tmp_path,
                                                                            monkeypatch):
    """``run`` at 60 s segments against the unsegmented run: ``kf_quality+rts`` (positions and calibrated
    covariance) and ``kf_quality`` (calibrated covariance) at every epoch. Then the same with each piece of this
    change removed: the segment's RTS alone (the cut smoothed by itself, as before) moves the ``+rts`` track by
    centimetres to metres; the NIS history dropped from the hand-over moves the covariance after each seam."""
    from walks import fuse as wf
    from walks.fuse import FusedWalk, fuse_to_file

    model = copy.copy(model_and_walk[0])
    model.calibration = {"kf_quality": _NisScale(), "kf_quality+rts": _NisScale()}

    def run(method: str, segment_s: float, name: str) -> dict:
        out = tmp_path / f"{name}.csv"
        done = fuse_to_file(looped, model, method, out, "csv", force=True, segment_s=segment_s)
        assert done.n > 0 and done.segments == (1 if segment_s > 1e3 else 4)
        return _read(out)

    def worst(a: dict, b: dict) -> tuple[float, float]:
        assert np.array_equal(a["t_s"], b["t_s"])
        d = np.hypot(a["east_m"] - b["east_m"], a["north_m"] - b["north_m"])
        rel = np.abs(a["var_east_m2"] / b["var_east_m2"] - 1.0)
        return float(np.nanmax(d)), float(np.nanmax(rel))

    whole = {m: run(m, 1e6, m + "_whole") for m in ("kf_quality+rts", "kf_quality")}
    seg = {m: run(m, 60.0, m + "_seg") for m in whole}
    d, rel = worst(whole["kf_quality+rts"], seg["kf_quality+rts"])
    assert d < 1e-5 and rel < 1e-3, (d, rel)
    d, rel = worst(whole["kf_quality"], seg["kf_quality"])
    assert d < 1e-5 and rel < 1e-3, (d, rel)

    # the cut smoothed alone (the rows of the cut's own +rts track)
    monkeypatch.setattr(wf, "add_rts_track", lambda *a: False)
    d_old, _ = worst(whole["kf_quality+rts"], run("kf_quality+rts", 60.0, "old_rts"))
    monkeypatch.undo()
    # the hand-over without the NIS history
    handover = FusedWalk.handover

    def no_history(self, t_s, states_from_s):
        h = handover(self, t_s, states_from_s)
        return type(h)({k: v.__class__(**{**v.__dict__, "nis_t_s": None, "nis": None}) for k, v in h.filters.items()},
                       h.readers, h.classes)

    monkeypatch.setattr(FusedWalk, "handover", no_history)
    _, rel_old = worst(whole["kf_quality"], run("kf_quality", 60.0, "old_nis"))
    print(f"segmented vs whole: +rts {d_old:.3g} m before, covariance {rel_old:.3g} relative before")
    assert d_old > 1e-3 and rel_old > 0.05, (d_old, rel_old)


def test_evaluate_scores_the_whole_walk_s_rts_track(model_and_walk, looped):
    """evaluate's per-walk result of the walk in 60 s segments (pipeline/evaluate_segments.py) against the
    whole walk's tracks scored directly (walks.score.track_errors): ``kf_quality+rts``'s errors and NEES epoch
    by epoch (the series are float32), and its metric row's count; ``kf_quality`` alike."""
    from pipeline.evaluate_segments import evaluate_segmented
    from walks.fuse import fuse_walk
    from walks.score import track_errors

    model = copy.copy(model_and_walk[0])
    model.calibration = {"kf_quality": _NisScale(), "kf_quality+rts": _NisScale()}
    seg = evaluate_segmented(looped, model, ("kf_quality",), None, True, "x4", 60.0)
    whole = fuse_walk(looped, model, ("kf_quality",), force=True)
    order = [r["method"] for r in seg["rows"] if r["env_class"] == "all"]
    assert order == ["kf_quality", "kf_quality+rts", "kf_quality+lag"]
    for m in order:
        ref = track_errors(whole.tracks[m], whole.data.truth)
        s = seg["series"][m]
        assert len(s["err_m"]) == len(ref["err_m"]) > 1000
        np.testing.assert_allclose(s["t_s"], ref["t_s"], rtol=0, atol=1e-4)
        np.testing.assert_allclose(s["err_m"], ref["err_m"], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(s["nees"], ref["nees"], rtol=1e-3)
        row = next(r for r in seg["rows"] if r["method"] == m and r["env_class"] == "all")
        assert row["n"] == len(ref["err_m"]) and row["mean_m"] == pytest.approx(ref["err_m"].mean(), rel=1e-5)


def test_the_handed_nis_history_skips_a_short_segment_s_warm_up():
    """A segment shorter than the calibrator's 15 s window hands on, before its own resume time (100 s), the
    history it was handed, not its warm-up's NIS (walks.fuse._join_nis). By hand: handed [88, 95, 99] at 100 s;
    this run's events before the 110 s hand-over [96 (warm-up), 101, 105] → [95, 99, 101, 105] (88 is older
    than 110 − 15)."""
    from models.fusion.ekf import FilterResume
    from walks.fuse import _join_nis

    got = FilterResume(100.0, np.zeros(2), np.eye(2), nis_t_s=np.array([88.0, 95.0, 99.0]),
                       nis=np.array([1.0, 2.0, 3.0]))
    mine = FilterResume(110.0, np.ones(2), np.eye(2), nis_t_s=np.array([96.0, 101.0, 105.0]),
                        nis=np.array([40.0, 5.0, 6.0]))
    joined = _join_nis(mine, got, 110.0)
    assert joined.nis_t_s.tolist() == [95.0, 99.0, 101.0, 105.0] and joined.nis.tolist() == [2.0, 3.0, 5.0, 6.0]
    assert joined.x.tolist() == [1.0, 1.0]
    assert _join_nis(mine, None, 110.0) is mine


def test_a_filter_that_starts_afresh_on_each_cut_keeps_its_cut_s_smoother(tmp_path):
    """ekf_rtk_pdr's cuts are separate runs (walks.fuse.RESUMED_METHODS): chaining their smoothers would join
    unrelated states, so add_rts_track declines it (the caller writes each cut's own +rts) and stores nothing."""
    from walks.segment_rts import add_rts_track

    run, _, _ = _cv_run(5, 20)
    fused = SimpleNamespace(results={"ekf_rtk_pdr": run}, tracks={"ekf_rtk_pdr+rts": None})
    with SegmentedRts(tmp_path) as store:
        assert add_rts_track(store, fused, "ekf_rtk_pdr+rts", np.ones(20, bool)) is False
        assert len(store) == 0
