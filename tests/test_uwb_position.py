"""features.uwb.position against hand computations: trilateration, covariance, the PDoA sign convention."""

import math

import numpy as np
import pytest

from features.errors import ConfigError, UwbError
from features.site import UwbAnchor
from features.uwb.position import UwbSolveConfig, uwb_epochs, uwb_positions
from features.uwb.reader import UwbLog

SQUARE = (UwbAnchor(1, 0.0, 0.0, 2.5, 0.0), UwbAnchor(2, 10.0, 0.0, 2.5, 0.0), UwbAnchor(3, 0.0, 10.0, 2.5, 0.0))


def _log(t, a, r, az=None, q=None):
    n = len(t)
    return UwbLog(t_s=np.asarray(t, float), anchor=np.asarray(a, int), range_m=np.asarray(r, float),
                  azimuth_deg=np.full(n, np.nan) if az is None else np.asarray(az, float),
                  quality=np.full(n, np.nan) if q is None else np.asarray(q, float))


def test_trilateration_matches_the_hand_closed_form():
    # Tag (3, 4) at 1.0 m, anchors at 2.5 m (dz = 1.5 m): slant ranges by hand sqrt(9 + 16 + 2.25) = 5.220153,
    # sqrt(49 + 16 + 2.25) = 8.200610, sqrt(9 + 36 + 2.25) = 6.873864. Closed form on the horizontal ranges
    # h² = r² − 2.25: e = (h1² − h2² + 100) / 20 = (25 − 65 + 100) / 20 = 3, n = (h1² − h3² + 100) / 20 = (25 − 45 + 100) / 20 = 4.
    log = _log([0.0, 0.01, 0.02], [1, 2, 3], [5.220153, 8.200610, 6.873864])
    fix = uwb_positions(log, SQUARE, tag_up_m=1.0, config=UwbSolveConfig(use_aoa="never"))
    assert len(fix) == 1 and fix.n_anchors[0] == 3 and not fix.used_aoa[0]
    assert fix.east_m[0] == pytest.approx(3.0, abs=2e-5) and fix.north_m[0] == pytest.approx(4.0, abs=2e-5)
    assert fix.t_s[0] == pytest.approx(0.01)


def test_covariance_of_a_symmetric_round_is_sigma_squared_over_two():
    # Tag at the centre of four anchors 10 m away at its own height: J rows (±1, 0), (0, ±1), JᵀJ = 2·I,
    # so P = σ²/2 · I = 0.01 / 2 = 0.005 m² (exact ranges: χ² = 0, no scaling).
    anchors = tuple(UwbAnchor(i, e, n, 1.2) for i, (e, n) in enumerate([(10, 0), (-10, 0), (0, 10), (0, -10)]))
    fix = uwb_positions(_log([0, 0.01, 0.02, 0.03], [0, 1, 2, 3], [10.0] * 4), anchors, 1.2,
                        UwbSolveConfig(range_sigma_m=0.1, use_aoa="never"))
    np.testing.assert_allclose(fix.cov_en[0], [[0.005, 0.0], [0.0, 0.005]], atol=1e-9)
    np.testing.assert_allclose([fix.east_m[0], fix.north_m[0]], [0.0, 0.0], atol=1e-6)


def test_redundant_round_with_a_bad_range_inflates_the_covariance():
    anchors = tuple(UwbAnchor(i, e, n, 1.2) for i, (e, n) in enumerate([(10, 0), (-10, 0), (0, 10), (0, -10)]))
    good = uwb_positions(_log([0, 0.01, 0.02, 0.03], [0, 1, 2, 3], [10.0] * 4), anchors, 1.2,
                         UwbSolveConfig(use_aoa="never"))
    bad = uwb_positions(_log([0, 0.01, 0.02, 0.03], [0, 1, 2, 3], [10.0, 10.0, 11.0, 10.0]), anchors, 1.2,
                        UwbSolveConfig(use_aoa="never"))
    assert bad.rms_residual[0] > 3.0 and np.trace(bad.cov_en[0]) > 5 * np.trace(good.cov_en[0])


def test_pdoa_sign_convention_single_anchor():
    # Anchor at (10, 20) facing east (boresight 90°). The tag at (15, 25) lies north-east of it, bearing 45°,
    # i.e. 45° to the anchor's LEFT: azimuth −45° (positive is clockwise). Horizontal range √50 = 7.071068 m.
    anchor = (UwbAnchor(7, 10.0, 20.0, 1.0, 90.0),)
    cfg = UwbSolveConfig(azimuth_sigma_deg=5.0, range_sigma_m=0.1)
    left = uwb_positions(_log([0.0], [7], [math.sqrt(50.0)], az=[-45.0]), anchor, 1.0, cfg)
    assert left.used_aoa[0] and left.n_anchors[0] == 1
    np.testing.assert_allclose([left.east_m[0], left.north_m[0]], [15.0, 25.0], atol=1e-6)
    right = uwb_positions(_log([0.0], [7], [math.sqrt(50.0)], az=[45.0]), anchor, 1.0, cfg)
    np.testing.assert_allclose([right.east_m[0], right.north_m[0]], [15.0, 15.0], atol=1e-6)
    # Covariance: radial σ_r² = 0.01 m², tangential (r·σ_φ)² with σ_φ = 5° / cos 45° (off boresight):
    # (7.071068 · 0.0872665 / 0.7071068)² = 0.7615435 m²; the radial direction is the bearing 45°.
    w, v = np.linalg.eigh(left.cov_en[0])
    np.testing.assert_allclose(w, [0.01, 0.7615435], rtol=1e-5)
    assert abs(abs(v[:, 0] @ np.array([math.sin(math.pi / 4), math.cos(math.pi / 4)])) - 1.0) < 1e-6


def test_rounds_with_fewer_than_three_anchors_are_dropped_range_only():
    t = [0.0, 0.01, 0.5, 0.51, 0.52]
    log = _log(t, [1, 2, 1, 2, 3], [5.220153, 8.200610, 5.220153, 8.200610, 6.873864], az=[0.0] * 5)
    assert [list(r) for r in uwb_epochs(log, 0.05)] == [[0, 1], [2, 3, 4]]
    never = uwb_positions(log, SQUARE, 1.0, UwbSolveConfig(use_aoa="never"))
    assert len(never) == 1 and never.n_rounds == 2 and never.t_s[0] == pytest.approx(0.51)
    fallback = uwb_positions(log, SQUARE, 1.0, UwbSolveConfig(use_aoa="fallback"))
    assert len(fallback) == 2 and list(fallback.used_aoa) == [True, False]


def test_an_anchor_repeating_closes_the_round():
    log = _log([0.0, 0.01, 0.02], [1, 1, 2], [5.0, 5.0, 5.0])
    assert [list(r) for r in uwb_epochs(log, 1.0)] == [[0], [1, 2]]


def test_nlos_quality_weights_a_range_down():
    anchors = tuple(UwbAnchor(i, e, n, 1.2) for i, (e, n) in enumerate([(10, 0), (-10, 0), (0, 10), (0, -10)]))
    r = [10.0, 10.0, 10.8, 10.0]  # anchor 2 (north) NLOS +0.8 m
    plain = uwb_positions(_log([0, .01, .02, .03], [0, 1, 2, 3], r), anchors, 1.2, UwbSolveConfig(use_aoa="never"))
    flagged = uwb_positions(_log([0, .01, .02, .03], [0, 1, 2, 3], r, q=[-1.0, -1.0, -12.0, -1.0]), anchors, 1.2,
                            UwbSolveConfig(use_aoa="never"))
    assert abs(flagged.north_m[0]) < 0.25 * abs(plain.north_m[0])


def test_unknown_anchor_and_bad_config():
    with pytest.raises(UwbError, match=r"anchor\(s\) \[9\]"):
        uwb_positions(_log([0.0], [9], [3.0]), SQUARE, 1.0)
    with pytest.raises(ConfigError, match="use_aoa"):
        UwbSolveConfig(use_aoa="sometimes")
    with pytest.raises(ConfigError, match="min_range_anchors"):
        UwbSolveConfig(min_range_anchors=2)


def test_site_toml_round_trips_uwb_anchors(tmp_path):
    from features.site import load_site, save_site, site_from_dict

    site = site_from_dict({"name": "u", "origin": {"lat_deg": 30.0, "lon_deg": 114.0},
                           "uwb_anchors": [{"id": 3, "east_m": 1.5, "north_m": 2.0, "up_m": 3.0, "boresight_deg": -90.0}]})
    save_site(site, tmp_path / "site.toml")
    assert load_site(tmp_path).uwb_anchors == (UwbAnchor(3, 1.5, 2.0, 3.0, -90.0),)
    with pytest.raises(ConfigError, match="uwb anchor ids must be unique"):
        site_from_dict({"name": "u", "origin": {"lat_deg": 30.0, "lon_deg": 114.0},
                        "uwb_anchors": [{"id": 1, "east_m": 0, "north_m": 0, "up_m": 3}] * 2})
