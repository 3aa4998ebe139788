"""The shared smartLoc drive end to end (issue 24 item 5): convert → read → run / evaluate, on slices of the drive.

Data: ../shared/data/gnss_urban_smartloc (the first 170 s of smartLoc's Berlin Potsdamer Platz drive, TU Chemnitz,
Reisdorf et al.; CC BY-SA 4.0). Every expected value is computed here from the source text by another route
(pymap3d on the raw ECEF, the solver called on the raw table, the odometry's variances by hand), or pinned
two-sided from a measured run (the figures in bench/bench_smartloc.py).
"""

from __future__ import annotations

import csv

import numpy as np
import pymap3d
import pytest

from tests.conftest import shared_data

SPLIT_S = 40.0
END_S = 75.0


@pytest.fixture(scope="module")
def source():
    folder = shared_data("gnss_urban_smartloc")
    return folder / "Berlin_Potsdamer_Platz_Input.txt", folder / "Berlin_Potsdamer_Platz_GT.txt"


@pytest.fixture(scope="module")
def slices(source, tmp_path_factory):
    """Two slices converted by the CLI: [0, 40) s for training, [40, 75) s for testing; one site name."""
    from pipeline.cli import main

    root = tmp_path_factory.mktemp("drive")
    for name, a, b in (("train", "0", str(SPLIT_S)), ("test", str(SPLIT_S), str(END_S))):
        code = main(["convert", "smartloc", str(source[0]), str(source[1]), "--out", str(root / name),
                     "--start-s", a, "--end-s", b, "--site-name", "potsdamer"])
        assert code == 0
    return root


@pytest.fixture(scope="module")
def whole(source, tmp_path_factory):
    from walks.convert import convert_smartloc
    from walks.reader import read_walk

    d = tmp_path_factory.mktemp("whole") / "drive"
    convert_smartloc(*source, d)
    return read_walk(d)


def test_the_folder_says_which_streams_it_holds(slices):
    from features.walk import load_walk
    from walks.reader import walk_has

    w = load_walk(slices / "test")
    assert walk_has(slices / "test") == {"gnss": False, "audio": False, "imu": False, "gnss_pseudoranges": True,
                                         "odometry": True, "uwb": False, "imu_foot": False, "truth": True}
    assert w.start_utc is None and w.extra["source_t0_s"] == SPLIT_S
    assert sorted(w.streams["gnss_pseudoranges"]["corrections"]) == ["ionosphere", "satellite_clock", "troposphere"]
    assert w.load_site().name == "potsdamer" and not w.load_site().beacons


def test_truth_is_the_reference_in_site_enu_from_the_slice_start(slices, source):
    """Distances between reference points survive the ECEF → ENU conversion (a rigid motion up to the
    vertical), and the walk's time counts from the slice start."""
    from features.gnss.pseudorange import read_smartloc
    from features.walk import read_truth

    ref = read_smartloc(source[1]).reference
    sel = (ref.t_s >= SPLIT_S) & (ref.t_s < END_S)
    xyz = ref.ecef_m[sel]
    tr = read_truth(slices / "test")
    np.testing.assert_allclose(tr.t_s, ref.t_s[sel] - SPLIT_S, atol=1e-9)
    d_ecef = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    d_enu = np.hypot(np.diff(tr.east_m), np.diff(tr.north_m))
    np.testing.assert_allclose(d_enu, d_ecef, atol=0.02)        # the car's climb between 0.3 s points is cm
    assert np.all(tr.env_class == -1)


def test_site_origin_is_the_median_fix_not_the_reference(slices):
    from walks.reader import read_walk

    data = read_walk(slices / "train")
    p = data.gnss.positions
    assert abs(np.median(p.east_m)) < 0.05 and abs(np.median(p.north_m)) < 0.05
    # the reference's own median is elsewhere: tens of metres away in this canyon
    assert np.hypot(np.median(data.truth.east_m), np.median(data.truth.north_m)) > 5.0


def test_the_solver_through_the_walk_folder_equals_the_solver_on_the_text(slices, source):
    """Horizontal error of the read walk's GNSS fixes against its truth, and of the solver run straight on the
    smartLoc text against the raw reference (pymap3d at each reference point): the same to 1 cm."""
    from features.gnss.pseudorange import read_smartloc
    from features.gnss.wls import solve_epochs
    from walks.reader import read_walk
    from walks.score import track_errors
    from walks.methods import run_methods
    from walks.inputs import walk_inputs

    data = read_walk(slices / "test")
    log = read_smartloc(source[0])
    tab = log.pseudoranges
    sel = (tab.t_s >= SPLIT_S) & (tab.t_s < END_S)
    from dataclasses import replace

    sub = replace(tab, t_s=tab.t_s[sel], pseudorange_m=tab.pseudorange_m[sel],
                  pseudorange_var_m2=tab.pseudorange_var_m2[sel], sat_ecef_m=tab.sat_ecef_m[sel], svid=tab.svid[sel],
                  system=tab.system[sel], elevation_deg=tab.elevation_deg[sel], cn0_dbhz=tab.cn0_dbhz[sel])
    sol = solve_epochs(sub)
    ref = read_smartloc(source[1]).reference
    k = np.searchsorted(ref.t_s, sol.t_s)
    lat, lon, h = pymap3d.ecef2geodetic(*ref.ecef_m[k].T)
    e, n, _ = pymap3d.ecef2enu(*sol.ecef_m.T, lat, lon, h)
    direct = np.hypot(e, n)
    clf = _toy_classifier()
    tracks, _ = run_methods(None, walk_inputs(data, clf), ("gnss",), smooth=False, lag_s=None)
    via_folder = track_errors(tracks["gnss"], data.truth)["err_m"]
    assert len(via_folder) == len(direct) == 168
    np.testing.assert_allclose(via_folder, direct, atol=0.01)


def test_odometry_steps_carry_the_files_own_noise(slices):
    """σ_L = ½Δt·sqrt(σ_v,k² + σ_v,k+1²) and σ_ψ = ½·½Δt·sqrt(σ_ω,k² + σ_ω,k+1²) from odometry.csv by hand; the
    filter takes their mean squares, not the walker's 0.05 m / 0.03 rad."""
    from models.fusion.ekf import EkfConfig, step_variances
    from walks.inputs import walk_inputs
    from walks.reader import read_walk

    with open(slices / "train" / "odometry.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["t_s"]) for r in rows])
    v = np.array([float(r["speed_m_s"]) for r in rows])
    var_v = np.array([float(r["speed_var_m2_s2"]) for r in rows])
    var_w = np.array([float(r["yaw_rate_var_rad2_s2"]) for r in rows])
    dt = np.diff(t)
    moving = 0.5 * (v[1:] + v[:-1]) * dt > 0.05 * dt
    s_len = (0.5 * dt * np.sqrt(var_v[1:] + var_v[:-1]))[moving]
    s_head = (0.25 * dt * np.sqrt(var_w[1:] + var_w[:-1]))[moving]
    ev = walk_inputs(read_walk(slices / "train"), _toy_classifier()).events
    assert ev.n_steps == int(moving.sum()) > 100               # GNSS and odometry share epochs: no split
    np.testing.assert_allclose(ev.steps.sigma_length_m, s_len, rtol=1e-9)
    np.testing.assert_allclose(ev.steps.sigma_heading_rad, s_head, rtol=1e-9)
    sl2, sp2 = step_variances(ev, EkfConfig())
    assert sl2 == pytest.approx(np.mean(s_len ** 2), rel=1e-12) and sp2 == pytest.approx(np.mean(s_head ** 2),
                                                                                          rel=1e-12)
    assert 5e-5 < sl2 < 1.2e-4 and sl2 < 0.05 ** 2 / 20


def test_drive_figures_pinned(whole):
    """The per-epoch solver (RTKLIB weights, Sagnac, RAIM) and the aligned odometry over the whole shared drive,
    read as a walk: median / p95 horizontal error as bench/bench_smartloc.py measured them (20.59 / 65.9 m;
    15.1 m), two-sided."""
    from walks.score import track_errors
    from walks.track import Track

    p = whole.gnss.positions
    g = track_errors(Track("gnss", p.t_s, p.east_m, p.north_m, None), whole.truth)["err_m"]
    assert len(g) == 823
    assert 20.3 < np.median(g) < 20.9 and 64.5 < np.percentile(g, 95) < 67.3
    r = whole.pdr.result
    o = track_errors(Track("odometry", r.t_s, r.east_m, r.north_m, None), whole.truth)["err_m"]
    assert 14.5 < np.median(o) < 15.8
    assert whole.gnss.nmea_summary["fixes"] == 823 and whole.gnss.nmea_summary["raim_alarms"] == 0


def _toy_classifier():
    """An environment classifier fitted on the synthetic library (tests/env_synth.py), GNSS and acoustic."""
    from models.environment import EnvironmentClassifier
    from tests.env_synth import synthetic_library

    X, y = synthetic_library(600, seed=1)
    return EnvironmentClassifier().fit(X, y)


def test_convert_run_evaluate_end_to_end(slices, tmp_path):
    """A fusion model fitted on the first slice (no tuning, no BP: fast), then the CLI's run and evaluate on the
    second: every method runs, the metrics have the 'all' row only (the reference has no class), and the solver's
    row equals the errors computed here."""
    from models.fusion.model import save_fusion_model
    from pipeline.cli import main
    from training.filters import train_fusion
    from walks.reader import read_walk

    model = train_fusion([slices / "train"], _toy_classifier(), bp=False, tune=False)
    assert model.meta["sites"] == ["potsdamer"]
    save_fusion_model(model, tmp_path / "model")
    out = tmp_path / "track.csv"
    assert main(["run", str(slices / "test"), "--model", str(tmp_path / "model"), "--out", str(out),
                 "--method", "adaptive_nobp"]) == 0
    with open(out, newline="") as fh:
        track = list(csv.DictReader(fh))
    data = read_walk(slices / "test")
    assert all(r["time_utc"] == "" for r in track)
    # one row per instant of the filter's events (an odometry piece and a fix at one time are one row)
    t_rows = np.array([float(r["t_s"]) for r in track])
    assert np.all(np.diff(t_rows) > 0)
    fixes = data.gnss.positions.t_s
    assert len(track) >= np.count_nonzero((fixes >= t_rows[0]) & (fixes <= t_rows[-1])) > 100
    te, tn = data.truth.at(np.array([float(r["t_s"]) for r in track]))
    err = np.hypot(np.array([float(r["east_m"]) for r in track]) - te, np.array([float(r["north_m"]) for r in track])
                   - tn)
    assert np.median(err) < 25.0                                  # the fused track stays on the street
    rep = tmp_path / "report"
    assert main(["evaluate", str(slices / "test"), "--model", str(tmp_path / "model"), "--report", str(rep),
                 "--workers", "1"]) == 0
    with open(rep / "metrics.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["walk"] != "all"]
    assert {r["env_class"] for r in rows} == {"all"}
    methods = {r["method"] for r in rows}
    assert {"gnss", "pdr", "kf", "kf_quality", "aekf", "imm", "adaptive_nobp", "adaptive_nobp_blind",
            "kf+rts"} <= methods and "acoustic" not in methods and "kf_map" not in methods
    p = data.gnss.positions
    tg_e, tg_n = data.truth.at(p.t_s)
    g = next(r for r in rows if r["method"] == "gnss")
    assert float(g["mean_m"]) == pytest.approx(np.mean(np.hypot(p.east_m - tg_e, p.north_m - tg_n)), rel=1e-5)
    assert len(list(rep.glob("classes_*.png"))) == 1
    assert not (rep / "error_by_class.png").exists()              # no epoch of a known class


def test_readme_drive_commands_parse():
    """The README's drive block names options that exist (bench/smartloc_study.py does the same through the
    library; here each line must parse as written, so the block cannot drift from the CLI)."""
    import re
    import shlex
    from pathlib import Path

    from pipeline.cli import build_parser

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = re.search(r"```\n(.*?)```", readme.split("## A real drive: smartLoc", 1)[1], re.S).group(1)
    lines = [line for line in block.splitlines() if line.strip()]
    assert len(lines) == 7 and lines[0].startswith("envfuse convert smartloc")
    parser = build_parser()
    for line in lines:
        argv = shlex.split(line)
        assert argv[0] == "envfuse"
        args = parser.parse_args(argv[1:])
        assert callable(args.func)
