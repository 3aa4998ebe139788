"""Issue 23: tightly coupled acoustic ranges, IMU preintegration, and the graph methods in the registry on a
simulated walk (training, the graph model in the fusion bundle, evaluate)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from features.constants import GRAVITY_M_S2
from features.imu.reader import ImuData
from models.fusion.ekf import EkfConfig
from models.fusion.events import GNSS, GnssEvents, StepEvents, merge_events
from models.graph import FixNoise, GraphConfig, GraphError, solve_fixed_lag
from models.graph.ins import attitude_from_down_heading, solve_ins
from models.graph.model import GraphModel, attach_graph_model, graph_model_of
from models.graph.tight import RangeRows, range_error, solve_tight
from tests.fusion_synth import synth_walk


def test_range_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 3, 2), rng.normal(0, 3, 2)
    beacon, k, alpha = np.array([10.0, -4.0, 2.8]), 1.3, 0.37
    e, Ja, Jb, Jk = range_error(a, b, k, alpha, beacon, 1.0, 12.0)
    eps = 1e-7
    for i in range(2):
        d = np.eye(2)[i] * eps
        assert Ja[i] == pytest.approx((range_error(a + d, b, k, alpha, beacon, 1.0, 12.0)[0]
                                       - range_error(a - d, b, k, alpha, beacon, 1.0, 12.0)[0]) / (2 * eps), abs=1e-6)
        assert Jb[i] == pytest.approx((range_error(a, b + d, k, alpha, beacon, 1.0, 12.0)[0]
                                       - range_error(a, b - d, k, alpha, beacon, 1.0, 12.0)[0]) / (2 * eps), abs=1e-6)
    assert Jk == 1.0


def _synthetic_ranges(s, beacons, per_frame=2, frame_s=1.2, sigma=0.05, seed=0):
    """Ranges of the synthetic truth to ``per_frame`` beacons per frame, a clock random walk per frame."""
    rng = np.random.default_rng(seed)
    st = s.stream
    t_end = st.t_s[-1]
    rows = []
    clock = 3.0
    for j, t0 in enumerate(np.arange(0.5, t_end - frame_s, frame_s)):
        clock += rng.normal(0, 0.01)
        for i in rng.choice(len(beacons), per_frame, replace=False):
            t = t0 + 0.1 * i
            e, n = np.interp(t, st.t_s, s.truth[:, 0]), np.interp(t, st.t_s, s.truth[:, 1])
            b = beacons[i]
            rho = math.dist((e, n, 1.0), b) + clock + rng.normal(0, sigma)
            rows.append((j - 3, t, *b, rho, sigma, np.nan))     # frame numbers start below 0, as a receiver's can
    a = np.array(rows)
    return RangeRows(a[:, 0].astype(int), a[:, 1], a[:, 2:5], a[:, 5], a[:, 6], a[:, 7], 1.0)


def test_tight_ranges_of_two_beacon_frames_hold_the_track_where_loose_has_no_fix():
    """GNSS only for the first 15 s, then frames of two beacons (never a fix: a fix needs three). Loosely
    coupled the graph dead-reckons; tightly coupled the ranges and the frames' linked clocks keep it.
    Catches a wrong clock sign, a range placed at the wrong time on the track, or a wrong Jacobian
    (measured: tight 0.10 m, loose 1.96 m over the last 65 s)."""
    cfg = EkfConfig()
    s = synth_walk(2, duration_s=90.0, cfg=cfg, gnss_hz=5.0, heading_offset_rad=0.15, scale_error=0.08)
    st = s.stream
    late = (st.kind == GNSS) & (st.t_s > 15.0)
    st = type(st)(**{**st.__dict__, "available": st.available & ~late})
    r = np.full((len(st), 2, 2), np.nan)
    r[st.kind == GNSS] = np.eye(2) * 1.5 ** 2
    beacons = [(-20.0, -20.0, 2.8), (25.0, -15.0, 2.6), (20.0, 30.0, 3.0), (-25.0, 25.0, 2.7), (0.0, 40.0, 2.9)]
    ranges = _synthetic_ranges(s, beacons)
    gc = GraphConfig.from_ekf(cfg, lag_s=4.0)
    noise = FixNoise.from_cov(st, r)
    loose = solve_fixed_lag(st, noise, gc, covariance=False)
    tight = solve_tight(st, noise, ranges, gc, covariance=False)
    after = st.t_s > 25.0
    err = lambda run: np.hypot(run.east_m - s.truth[:, 0], run.north_m - s.truth[:, 1])[after].mean()
    assert tight.info["ranges_used"] == len(ranges)
    assert err(tight) < 0.15 and err(tight) < 0.4 * err(loose)


def _imu_straight(duration_s=30.0, speed=1.4, heading=0.0, rate=100.0, seed=0):
    """A level device walking straight at constant speed: specific force −g along body down, no rotation."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1 / rate)
    acc = np.tile([0.0, 0.0, -GRAVITY_M_S2], (t.size, 1)) + rng.normal(0, 0.02, (t.size, 3))
    gyro = rng.normal(0, 0.001, (t.size, 3))
    imu = ImuData(t, acc, gyro, None, np.ones(t.size, bool), np.zeros(t.size, bool), rate)
    east, north = speed * t * math.sin(heading), speed * t * math.cos(heading)
    return imu, t, east, north


def test_attitude_maps_body_forward_to_the_heading_and_down_to_down():
    for heading in (0.0, math.pi / 2, -2.0):
        R = attitude_from_down_heading(np.array([0.0, 0.0, 1.0]), heading)
        assert R @ [1.0, 0.0, 0.0] == pytest.approx([math.sin(heading), math.cos(heading), 0.0], abs=1e-12)
        assert R @ [0.0, 0.0, 1.0] == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
        assert R @ R.T == pytest.approx(np.eye(3), abs=1e-12) and np.linalg.det(R) == pytest.approx(1.0)


def test_ins_graph_follows_a_straight_walk_and_bridges_an_outage():
    """IMU preintegration + GNSS on a straight level walk heading east: the keyframes lie on the truth, and a
    3 s GNSS outage is bridged by the IMU. Catches a body/nav frame mix-up (gravity leaking into the
    horizontal), a wrong gravity sign, or the preintegration interval off by a sample."""
    imu, t, east, north = _imu_straight(heading=math.pi / 2)
    rng = np.random.default_rng(1)
    tg = np.arange(0.0, 29.0, 0.2)
    gap = (tg > 12.0) & (tg < 15.0)
    tg = tg[~gap]
    e_fix = np.interp(tg, t, east) + rng.normal(0, 0.05, tg.size)
    n_fix = np.interp(tg, t, north) + rng.normal(0, 0.05, tg.size)
    gnss = GnssEvents.from_sigma(tg, e_fix, n_fix, np.full(tg.size, 0.05))
    steps = StepEvents(np.arange(0.5, 29.0, 0.5), np.full(57, 0.7), np.full(57, math.pi / 2))
    st = merge_events(steps, gnss)
    r = np.full((len(st), 2, 2), np.nan)
    r[st.kind == GNSS] = np.eye(2) * 0.05 ** 2
    run = solve_ins(imu, st, FixNoise.from_cov(st, r), (tg, e_fix, n_fix), steps.t_s, steps.heading_rad)
    te, tn = np.interp(run.t_s, t, east), np.interp(run.t_s, t, north)
    err = np.hypot(run.east_m - te, run.north_m - tn)
    assert np.median(err) < 0.05
    inside = (run.t_s > 12.0) & (run.t_s < 15.0)
    assert inside.sum() >= 2 and err[inside].max() < 0.3
    assert np.all(np.isfinite(run.cov_m2))


def test_ins_refuses_an_imu_without_gyro():
    imu, *_ = _imu_straight(duration_s=5.0)
    no_gyro = ImuData(imu.t_s, imu.acc_m_s2, None, None, imu.valid, imu.saturated, imu.rate_hz)
    st = merge_events(gnss=GnssEvents.from_sigma(np.array([1.0, 2.0]), np.zeros(2), np.zeros(2), np.ones(2)))
    with pytest.raises(GraphError, match="gyro"):
        solve_ins(no_gyro, st, FixNoise.from_cov(st, np.tile(np.eye(2), (2, 1, 1))), ([0.0], [0.0], [0.0]),
                  np.array([1.0]), np.array([0.0]))


def test_graph_model_state_round_trips_and_refuses_damage():
    gm = GraphModel(None, None, 0.45, 0.1, 5.0, {"x": 1})
    assert GraphModel.from_state(gm.get_state()) == gm
    with pytest.raises(GraphError):
        GraphModel(step_k=0.4)
    with pytest.raises(GraphError, match="heading_tau_s"):
        GraphModel(heading_tau_s=-1.0)
    with pytest.raises(GraphError, match="malformed|newer"):
        GraphModel.from_state({"format_version": 99})


def _trained_graph(walk_dir):
    """A fusion model (no BP) and its graph model fitted on the 60 s simulated walk (read once)."""
    from models.environment import EnvironmentClassifier
    from training.filters import DEFAULT_EKF, fit_fusion_model, training_rows
    from training.graph_fit import fit_graph_model
    from walks.inputs import walk_inputs, window_features
    from walks.reader import read_walk

    data = read_walk(walk_dir)
    t, X = window_features(data)
    clf = EnvironmentClassifier(min_samples=5).fit(X, data.truth.class_at(t - 1.0))
    inputs = walk_inputs(data, clf)
    model = fit_fusion_model([training_rows(data, inputs, "w11")], clf, None, ekf=DEFAULT_EKF)
    gm = fit_graph_model([(data, inputs)], model, min_samples=10)
    attach_graph_model(model, gm)
    return data, model, gm


def test_graph_methods_end_to_end_on_a_simulated_walk(walk_dir, tmp_path):
    """One test (one read and one training of the walk, not one per xdist worker):

    1. from a model saved and loaded (the graph model travels as JSON in its meta), every graph method
       gives a track through the registry, after the built-in methods; on this mostly-RTK walk the graphs
       stay at the fixes' level;
    2. without a graph model fg_env / fg_blind skip saying why; without the IMU fg_ins and the seed EKF do;
    3. the improved step model reproduces the walk's truth distance within 5 % (fitted on it: a check of
       the segment bookkeeping), and τ comes from the grid.
    """
    import dataclasses

    from features.imu.steps import StepLengthModel
    from models.fusion.model import load_fusion_model, save_fusion_model
    from training.graph_fit import TAU_GRID_S
    from walks.graph_methods import GRAPH_METHODS
    from walks.inputs import walk_inputs
    from walks.methods import method_names, run_methods
    from walks.score import score

    data, model, gm = _trained_graph(walk_dir)
    save_fusion_model(model, tmp_path / "m")
    again = load_fusion_model(tmp_path / "m")
    assert graph_model_of(again).get_state() == gm.get_state()
    names = method_names()
    at = names.index(GRAPH_METHODS[0])
    assert names[at: at + len(GRAPH_METHODS)] == GRAPH_METHODS      # one block, after the Kalman methods
    assert at > names.index("adaptive_correction")
    tracks, skipped = run_methods(again, walk_inputs(data, again.classifier), ("gnss",) + GRAPH_METHODS)
    assert skipped == {}
    assert "ekf_rtk_pdr+rts" in tracks
    rows = {(r["method"], r["env_class"]): r for r in score(tracks, data, "w")}
    g = rows[("gnss", "all")]["median_m"]
    for m in ("fg_batch", "fg_dcs", "fg_env", "fg_blind", "fg_isam2", "fg_lag", "fg_tight"):
        assert rows[(m, "all")]["median_m"] < 3 * max(g, 0.01), m
    for m in GRAPH_METHODS:
        assert np.isfinite(rows[(m, "all")]["mean_m"]), m
    assert gm.kernels_env.blind_ is False and gm.kernels_blind.blind_ is True
    # 2. skips with a reason
    bare = dataclasses.replace(model, meta={k: v for k, v in model.meta.items() if k != "graph_model"})
    _, skipped = run_methods(bare, walk_inputs(data, bare.classifier), ("fg_env", "fg_blind"))
    assert set(skipped) == {"fg_env", "fg_blind"} and "graph kernel table" in skipped["fg_env"]
    no_imu = dataclasses.replace(data, pdr=dataclasses.replace(data.pdr, imu=None))
    _, skipped = run_methods(model, walk_inputs(no_imu, model.classifier), ("fg_ins", "ekf_rtk_pdr"))
    assert set(skipped) == {"fg_ins", "ekf_rtk_pdr"} and "IMU" in skipped["fg_ins"]
    # 3. the seed's step model and τ
    assert gm.heading_tau_s in TAU_GRID_S
    steps = data.pdr.result.steps
    L = StepLengthModel(k=gm.step_k, beta=gm.step_beta).predict(steps)
    te, tn = data.truth.at(steps.t_s)
    d = np.hypot(np.diff(te), np.diff(tn))
    keep = ~steps.bout_start[1:]
    assert L[1:][keep].sum() == pytest.approx(d[keep].sum(), rel=0.05)


def test_a_solver_that_gives_up_skips_its_method_and_keeps_the_others(walk_dir, monkeypatch):
    """GTSAM raising on one walk (its IndeterminateSystemException arrives as RuntimeError) skips that graph
    method with GTSAM's first line as the reason; the walk's other methods still give their tracks. Before the
    guard, 205/w1 of the standard split lost every method to fg_isam2's Cholesky failure."""
    import models.graph.solve as solve
    from walks.inputs import walk_inputs
    from walks.methods import run_methods

    data, model, _ = _trained_graph(walk_dir)

    def indeterminate(*a, **k):
        raise RuntimeError("\nIndeterminate linear system detected while working near variable\n7 (Symbol: x7).")

    monkeypatch.setattr(solve, "solve_isam2", indeterminate)
    tracks, skipped = run_methods(model, walk_inputs(data, model.classifier), ("kf_quality", "fg_batch", "fg_isam2"),
                                  smooth=False)
    assert set(skipped) == {"fg_isam2"}
    assert skipped["fg_isam2"].startswith("GTSAM could not solve this walk (Indeterminate linear system")
    assert {"kf_quality", "fg_batch"} <= set(tracks) and len(tracks["fg_batch"].t_s) > 100


def test_isam2_factors_by_qr():
    """iSAM2 and the incremental fixed-lag smoother factor by QR (Cholesky declared a held-out walk's system
    indeterminate; see models.graph.solve._isam2_params)."""
    import gtsam

    from models.graph.config import GraphConfig
    from models.graph.solve import _isam2_params

    p = _isam2_params(GraphConfig())
    assert p.getFactorization() == "QR"
    assert gtsam.ISAM2Params().getFactorization() == "CHOLESKY"      # what it would be by default
