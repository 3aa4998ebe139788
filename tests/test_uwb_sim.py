"""simulation.uwb against hand computations: slab excess path and loss (ITU-R P.2040-1), the NLOS bias growing
with the walls crossed, the PDoA sign and mirror, determinism, and the writer's contract."""

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from features.errors import ConfigError
from features.site import Box, Grid, Origin, Site, UwbAnchor
from simulation.streams import StreamContext, Trajectory
from simulation.uwb.channel import PATH_BENT, PATH_DIRECT, PATH_THROUGH, build_uwb_scene, uwb_paths
from simulation.uwb.radio import MATERIALS, knife_edge_loss_db, slab_excess_path_m, slab_loss_db
from simulation.uwb.stream import UwbSimConfig, simulate_uwb, write_uwb_stream

ORIGIN = Origin(31.2, 118.8, 20.0)


def _wall(e0, material="brick", kind="firewall", thick=0.24, n0=-5.0, n1=5.0, h=4.0):
    return Box(kind, material, False, e0, e0 + thick, n0, n1, h)


def _site(layout, anchors=(UwbAnchor(1, 0.0, 0.0, 1.0, 90.0),)):
    return Site(name="u", origin=ORIGIN, grid=Grid(1.0, -20.0, 40.0, -20.0, 40.0), layout=tuple(layout),
                uwb_anchors=tuple(anchors), seed=1)


def test_slab_formulas_by_hand():
    brick = MATERIALS["brick"]                       # ε' = 3.91 at any f (b = 0)
    assert float(slab_excess_path_m(brick, 0.24)) == pytest.approx(0.24 * (math.sqrt(3.91) - 1.0), rel=1e-12)
    # loss = α·t + 2 interfaces, by hand: σ = 0.0238·6.4896^0.16 = 0.032102 S/m; ωε0ε' = 4.07757e10·8.854188e-12·3.91
    # = 1.411651, tan δ = 0.022741; α = (ω/c)·sqrt(ε'/2)·sqrt(sqrt(1 + tan²δ) − 1) = 190.176·0.016080 = 3.0580 Np/m
    # = 26.562 dB/m. Interface: Γ = (1 − 1.977372)/(1 + 1.977372) = −0.328266, −10·log10(1 − Γ²) = 0.49518 dB.
    assert float(slab_loss_db(brick, 0.24)) == pytest.approx(0.24 * 26.562 + 2 * 0.49518, abs=0.01)
    assert math.isinf(float(slab_loss_db(MATERIALS["steel"], 0.01)))
    # knife edge, ν = 2·sqrt(δ/λ): δ = λ/4 → ν = 1, J = 6.9 + 20·log10(sqrt(0.81 + 1) + 0.9) = 13.0 dB (P.526 Fig. 7)
    lam = 299_792_458.0 / 6489.6e6
    assert float(knife_edge_loss_db(lam / 4)) == pytest.approx(6.9 + 20 * math.log10(math.sqrt(1.81) + 0.9), abs=1e-9)


def test_nlos_bias_grows_with_the_walls_crossed():
    excess = 0.24 * (math.sqrt(3.91) - 1.0)                                      # 0.23457 m per brick wall
    anchor, tag = (0.0, 0.0, 1.0), (10.0, 0.0, 1.0)
    got = []
    for walls in ([], [_wall(4.0)], [_wall(3.0), _wall(6.0)]):
        p = uwb_paths(build_uwb_scene(_site(walls)), anchor, math.radians(90.0), tag)
        got.append((int(p.kind[0]), float(p.excess_m[0]), float(p.power_dbm[0])))
    assert [g[0] for g in got] == [PATH_DIRECT, PATH_THROUGH, PATH_THROUGH]
    np.testing.assert_allclose([g[1] for g in got], [0.0, excess, 2 * excess], atol=1e-9)
    assert got[0][2] > got[1][2] > got[2][2]
    # steel (e 4–5, n ±1, 6 m tall) is not crossed: the first path bends round a vertical edge, by hand
    # √(4² + 1) + 1 + √(5² + 1) − 10 = 0.22213 m longer, and weaker than through a brick wall (knife-edge loss)
    steel = uwb_paths(build_uwb_scene(_site([_wall(4.0, "steel", "equipment", 1.0, -1.0, 1.0, 6.0)])), anchor,
                      math.radians(90.0), tag)
    assert PATH_THROUGH not in steel.kind and steel.kind[0] == PATH_BENT
    assert steel.excess_m[0] == pytest.approx(math.sqrt(17) + 1 + math.sqrt(26) - 10, abs=2e-3)
    assert steel.power_dbm[0] < got[1][2] - 3.0


def _line_trajectory(e0, e1, n, duration_s=20.0):
    t = np.arange(0.0, duration_s + 1e-9, 0.01)
    e = np.linspace(e0, e1, t.size)
    return Trajectory(t, e, np.full(t.size, n), np.full(t.size, 1.0), np.full(t.size, math.pi / 2),
                      np.full(t.size, abs(e1 - e0) / duration_s), datetime(2026, 1, 1, tzinfo=timezone.utc), 100.0)


EXACT = UwbSimConfig(survey_sigma_m=0.0, boresight_sigma_deg=0.0, antenna_delay_sigma_m=0.0, pdoa_offset_sigma_deg=0.0)


def test_simulated_ranges_by_path_kind_and_pdoa_sign():
    # the tag walks east 5 → 25 m along n = +6 m; a brick wall at e = 10–10.24 covers n ∈ [2, 10]. The anchor at
    # the origin faces east (boresight 90°): the tag is to its LEFT, so its angles are negative.
    site = _site([_wall(10.0, n0=2.0, n1=10.0)])
    ctx = StreamContext(site=site, trajectory=_line_trajectory(5.0, 25.0, 6.0), out_dir=Path("."), seed=4, kind="walk")
    log, truth = simulate_uwb(ctx, EXACT)
    err = log.range_m - truth.true_range_m
    los, through = truth.first_kind == PATH_DIRECT, truth.first_kind == PATH_THROUGH
    assert los.sum() > 20 and through.sum() > 20
    assert abs(np.mean(err[los])) < 0.04 and 0.04 < np.std(err[los]) < 0.2
    assert np.mean(err[through]) == pytest.approx(0.2346, abs=0.05)
    expected = np.degrees(np.arctan2(np.interp(log.t_s, [0.0, 20.0], [5.0, 25.0]), 6.0)) - 90.0   # atan2(Δe, Δn) − 90°
    np.testing.assert_allclose(truth.true_azimuth_deg, expected, atol=0.5)
    assert np.median(np.abs(log.azimuth_deg[los] - expected[los])) < 6.0 and np.all(log.azimuth_deg[los] < 20.0)
    assert np.all(np.isfinite(log.quality)) and np.median(log.quality[los]) > np.median(log.quality[through]) - 6.0


def test_a_tag_behind_the_array_is_reported_at_its_mirror():
    # anchor faces north; the tag walks along n = −8 (behind): true relative angles ≈ ±(180 − x), reported ±x
    site = _site([], (UwbAnchor(1, 0.0, 0.0, 1.0, 0.0),))
    ctx = StreamContext(site=site, trajectory=_line_trajectory(-3.0, 3.0, -8.0), out_dir=Path("."), seed=2, kind="walk")
    log, truth = simulate_uwb(ctx, EXACT)
    assert len(log) > 50 and np.all(np.abs(truth.true_azimuth_deg) > 90.0)
    mirror = np.sign(truth.true_azimuth_deg) * 180.0 - truth.true_azimuth_deg
    assert np.median(np.abs(log.azimuth_deg - mirror)) < 8.0 and np.all(np.abs(log.azimuth_deg) <= 90.0)


def test_seeded_and_the_writer_contract(tmp_path):
    site = _site([_wall(10.0, n0=2.0, n1=10.0)])
    traj = _line_trajectory(5.0, 25.0, 6.0, 5.0)
    a, _ = simulate_uwb(StreamContext(site=site, trajectory=traj, out_dir=tmp_path, seed=4, kind="walk"))
    b, _ = simulate_uwb(StreamContext(site=site, trajectory=traj, out_dir=tmp_path, seed=4, kind="walk"))
    c, _ = simulate_uwb(StreamContext(site=site, trajectory=traj, out_dir=tmp_path, seed=5, kind="walk"))
    np.testing.assert_array_equal(a.range_m, b.range_m)
    assert len(a.range_m) != len(c.range_m) or not np.array_equal(a.range_m, c.range_m)
    assert write_uwb_stream(StreamContext(site=site, trajectory=traj, out_dir=tmp_path, seed=4, kind="survey")) == {}
    bare = Site(name="u", origin=ORIGIN, layout=site.layout)
    assert write_uwb_stream(StreamContext(site=bare, trajectory=traj, out_dir=tmp_path, seed=4, kind="walk")) == {}
    meta = write_uwb_stream(StreamContext(site=site, trajectory=traj, out_dir=tmp_path, seed=4, kind="walk",
                                          options={"uwb": {"rate_hz": 5.0}}))
    assert meta["uwb"]["file"] == "uwb.csv" and meta["uwb"]["rate_hz"] == 5.0 and (tmp_path / "uwb.csv").is_file()
    with pytest.raises(ConfigError, match="unknown key"):
        UwbSimConfig.from_options({"uwb": {"rate": 5}})
    with pytest.raises(ConfigError, match="do not fit"):
        UwbSimConfig(rate_hz=50.0, max_per_round=8, slot_s=0.003)


def test_the_compiled_poll_loop_gives_the_same_rows_however_often_it_stops(monkeypatch):
    """The poll rounds run compiled and stop for Python (a channel not computed yet, rows to grow, the memory
    bound on exact positions) and resume at the same poll with nothing drawn: with room for 16 rows at first
    and 8 exact channels kept (dozens of stops of each kind more) the log is the same, row for row and bit for
    bit; and the rows' count and ranges agree with a hand model of the schedule: one anchor in the open, the tag
    standing 10 m away, fades and packet errors off — every 0.1 s round polls it, every poll gives a row, the
    ranges N(10 m + the anchor's delay residual, 8 cm)."""
    import simulation.uwb.stream as us

    site = _site([_wall(10.0, n0=2.0, n1=10.0)],
                 (UwbAnchor(1, 0.0, 0.0, 1.0, 90.0), UwbAnchor(2, 30.0, 0.0, 1.0, 270.0)))
    ctx = StreamContext(site=site, trajectory=_line_trajectory(5.0, 25.0, 6.0), out_dir=Path("."), seed=4, kind="walk")
    a, ta = simulate_uwb(ctx)
    monkeypatch.setattr(us, "_ROWS_START", 16)
    monkeypatch.setattr(us, "_EXACT_KEEP", 8)
    b, tb = simulate_uwb(ctx)
    assert len(a.t_s) > 100
    for x, y in zip((a.t_s, a.anchor, a.range_m, a.azimuth_deg, a.quality, ta.true_range_m, ta.first_kind),
                    (b.t_s, b.anchor, b.range_m, b.azimuth_deg, b.quality, tb.true_range_m, tb.first_kind)):
        np.testing.assert_array_equal(x, y)
    monkeypatch.undo()

    quiet = UwbSimConfig(fading_db=0.0, per_floor=0.0, quality_noise_db=0.0, survey_sigma_m=0.0,
                         boresight_sigma_deg=0.0, pdoa_offset_sigma_deg=0.0)
    one = _site([], (UwbAnchor(1, 0.0, 0.0, 1.0, 90.0),))
    t = np.arange(0.0, 60.0 + 1e-9, 0.01)
    still = Trajectory(t, np.full(t.size, 10.0), np.zeros(t.size), np.ones(t.size), np.zeros(t.size),
                       np.zeros(t.size), datetime(2026, 7, 1, tzinfo=timezone.utc), 100.0)
    log, truth = simulate_uwb(StreamContext(site=one, trajectory=still, out_dir=Path("."), seed=9, kind="walk"), quiet)
    rounds = len(np.arange(0.0, 60.0 - 8 * 0.003, 0.1))       # a round every 0.1 s while its 8 slots fit
    assert len(log.t_s) == rounds and np.all(truth.true_range_m == pytest.approx(10.0))
    delay = us._installation(one, quiet)[2][0]
    err = log.range_m - 10.0 - delay
    assert abs(err.mean()) < 3 * 0.08 / math.sqrt(rounds) and np.std(err) == pytest.approx(0.08, rel=0.15)
