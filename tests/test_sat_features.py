"""The five GNSS features from per-satellite pseudorange data (smartLoc drive), and what the format lacks (ζ).

Real data: ../shared/data/gnss_urban_smartloc (smartLoc, TU Chemnitz, CC BY-SA 4.0).
"""

from __future__ import annotations

import numpy as np
import pytest

from features.errors import DataError
from features.gnss.features import Cn0Reference, GnssFeatureConfig
from features.gnss.positions import sky_attenuation
from features.gnss.pseudorange import PseudorangeTable, read_smartloc
from features.gnss.sat_features import predict_untracked_positions, pseudorange_features, sky_from_pseudoranges
from features.gnss.wls import solve_epochs
from tests.conftest import shared_data


@pytest.fixture(scope="module")
def drive():
    table = read_smartloc(shared_data("gnss_urban_smartloc", "Berlin_Potsdamer_Platz_Input.txt")).pseudoranges
    return table, solve_epochs(table)


def _rows_of(table, key):
    return (table.system == key[0]) & (table.svid == key[1])


def test_untracked_positions_predicted_from_the_satellites_own_track(drive):
    """Hide G12's positions over a 30 s gap and the last 30 s; the cubic recovers the file's positions."""
    table, _ = drive
    t, start, stop = table.epochs()
    rows = np.flatnonzero(_rows_of(table, ("G", 12)))
    assert len(rows) == len(t)                       # tracked at every epoch
    pos = table.sat_ecef_m[rows][:, None, :]
    hide = ((t > 60) & (t < 90)) | (t > t[-1] - 30)
    pred = predict_untracked_positions(t, np.where(hide[:, None, None], np.nan, pos), ~hide[:, None])
    err = np.linalg.norm(pred[hide, 0] - pos[hide, 0], axis=1)
    assert err.max() < 50.0                          # < 0.0002 deg seen from 20,000 km
    assert np.array_equal(pred[~hide], pos[~hide])


def test_a_satellite_lost_in_view_counts_as_invisible(drive):
    """Delete R320 (58 deg up, tracked throughout) over t in [80, 100) s: each of those epochs gains exactly
    one in-view-untracked satellite above the mask, so its ζ rises by 1 / n_in_view."""
    table, sol = drive
    gap = _rows_of(table, ("R", 320)) & (table.t_s >= 80) & (table.t_s < 100)
    cut = PseudorangeTable(**{**table.__dict__, **{k: getattr(table, k)[~gap] for k in (
        "t_s", "pseudorange_m", "pseudorange_var_m2", "sat_ecef_m", "svid", "system", "elevation_deg", "cn0_dbhz")}})
    sky0, sky1 = sky_from_pseudoranges(table, sol), sky_from_pseudoranges(cut, solve_epochs(cut))
    _, _, z0 = sky_attenuation(sky0)
    _, _, z1 = sky_attenuation(sky1)
    in_gap = (sky0.t_s >= 80) & (sky0.t_s < 100)
    n_view = (sky0.in_view & (sky0.el_deg >= 10)).sum(axis=1)
    assert np.allclose(z1[in_gap] - z0[in_gap], 1.0 / n_view[in_gap])
    assert np.allclose(z1[~in_gap], z0[~in_gap], atol=1e-12)
    j = sky1.sat_keys.index(("R", 320))
    assert np.all(sky1.in_view[in_gap, j]) and np.all(np.isnan(sky1.cn0_dbhz[in_gap, j]))


def test_mean_attenuation_by_hand_for_one_window(drive):
    """μ of the window [40, 42) s: attenuation max(0, C_ref(el) − C/N0) averaged over the tracked rows above
    10 deg whose epoch tag t − Δt/2 falls in the window (Δt the median epoch step), elevations the solver's."""
    table, sol = drive
    out = pseudorange_features(table, sol)
    w = int(np.flatnonzero(np.isclose(out["t_s"], 41.0))[0])
    dt = float(np.median(np.diff(table.epochs()[0])))
    tag = table.t_s - dt / 2
    rows = (tag >= 40.0 - 1e-9) & (tag < 42.0 - 1e-9) & (sol.elevation_deg >= 10.0)
    att = np.maximum(0.0, Cn0Reference().cref_dbhz(sol.elevation_deg[rows]) - table.cn0_dbhz[rows])
    assert abs(out["att_mean_db"][w] - att.mean()) < 1e-9
    assert abs(out["att_std_db"][w] - att.std()) < 1e-9
    assert out["n_pairs_tracked"][w] == rows.sum()


def test_features_on_the_drive_and_what_is_missing_without_predictions(drive):
    table, sol = drive
    out = pseudorange_features(table, sol, GnssFeatureConfig())
    assert len(out["t_s"]) == 170
    for name in ("att_mean_db", "att_std_db", "fluct_per_s", "invisible_ratio", "dop_growth"):
        assert np.all(np.isfinite(out[name])), name
    # 16 satellites rise above 10 deg during the drive; up to 5 of them are lost at once in the canyon
    assert set(out["n_in_view"].tolist()) == {16}
    assert 0.05 < out["invisible_ratio"].mean() < 0.2 and out["invisible_ratio"].max() < 0.5
    assert np.all(out["dop_growth"] >= 0) and out["dop_growth"].max() > 0.5
    bare = pseudorange_features(table, sol, predict_untracked=False)
    assert np.all(np.isnan(bare["invisible_ratio"])) and np.all(np.isnan(bare["dop_growth"]))
    assert np.allclose(bare["att_mean_db"], out["att_mean_db"])


def test_a_solution_of_other_epochs_is_refused(drive):
    table, sol = drive
    first = table.t_s < 10
    part = PseudorangeTable(**{**table.__dict__, **{k: getattr(table, k)[first] for k in (
        "t_s", "pseudorange_m", "pseudorange_var_m2", "sat_ecef_m", "svid", "system", "elevation_deg", "cn0_dbhz")}})
    with pytest.raises(DataError, match="not that of this table"):
        sky_from_pseudoranges(part, sol)
