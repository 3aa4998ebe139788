"""Acoustic simulation against closed forms and tables: sound speed, ISO 9613-1, Maekawa, paths, chirp, TDMA."""

from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np
import pytest

from features.errors import ConfigError
from features.site import AcousticConfig, Atmosphere, Beacon, Box, Origin, Site
from simulation.acoustic.channel import (ChannelConfig, beacon_arrivals, build_scene, channel_paths, clutter_index,
                                         tail_model)
from simulation.acoustic.atmosphere import (absorption_db_per_m, fresnel_number, maekawa_loss_db, reflection_coefficient,
                                  speed_of_sound_m_s, spreading_gain)
from simulation.acoustic.stream import detection_range_m
from simulation.acoustic.chirp import (ChirpSpec, beacon_chirp, chirp_waveform, emission_times_s, frame_phase_s,
                              reference_chirp, slot_reuse_conflicts)

ORIGIN = Origin(31.0, 118.0)


def _site(layout=(), beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),), **kw) -> Site:
    return Site(name="t", origin=ORIGIN, layout=tuple(layout), beacons=tuple(beacons), **kw)


# --- air ---------------------------------------------------------------------------------------------------------

def test_speed_of_sound_closed_form():
    assert speed_of_sound_m_s(0.0) == pytest.approx(331.3)
    assert speed_of_sound_m_s(20.0) == pytest.approx(331.3 * math.sqrt(293.15 / 273.15), rel=1e-12)
    assert speed_of_sound_m_s(np.array([-10.0, 30.0])) == pytest.approx([325.179, 349.019], abs=1e-3)


# ISO 9613-2:1996 Table 2 (computed there from ISO 9613-1 at the exact octave midbands 1000·10^(n/10) Hz), dB/km
_ISO_TABLE = {
    (10.0, 70.0): [0.1, 0.4, 1.0, 1.9, 3.7, 9.7, 32.8, 117.0],
    (20.0, 70.0): [0.1, 0.3, 1.1, 2.8, 5.0, 9.0, 22.9, 76.6],
    (30.0, 70.0): [0.1, 0.3, 1.0, 3.1, 7.4, 12.7, 23.1, 59.3],
    (15.0, 20.0): [0.3, 0.6, 1.2, 2.7, 8.2, 28.2, 88.8, 202.0],
    (15.0, 50.0): [0.1, 0.5, 1.2, 2.2, 4.2, 10.8, 36.2, 129.0],
    (15.0, 80.0): [0.1, 0.3, 1.1, 2.4, 4.1, 8.3, 23.7, 82.8],
}


@pytest.mark.parametrize("atm", sorted(_ISO_TABLE))
def test_absorption_matches_iso_table(atm):
    f = 1000.0 * 10.0 ** (np.arange(-12, 10, 3) / 10.0)          # 63 Hz … 8 kHz exact midbands
    got = absorption_db_per_m(f, Atmosphere(atm[0], atm[1], 101.325)) * 1000.0
    want = np.array(_ISO_TABLE[atm])
    # table printed to 0.1 dB/km (three significant figures above 100): half a unit plus float ties
    assert np.all(np.abs(got - want) <= np.maximum(0.06, 0.006 * want)), (got.round(2), want)


def test_absorption_in_beacon_band_default_atmosphere():
    """20 °C, 60 % RH, 101.325 kPa: 0.35 / 0.47 / 0.59 dB/m at 17 / 20 / 23 kHz, rising with frequency."""
    a = absorption_db_per_m(np.array([17e3, 20e3, 23e3]), Atmosphere())
    assert a == pytest.approx([0.354, 0.468, 0.591], abs=0.002)
    # drier air absorbs more at these frequencies (below the O2 relaxation peak)
    assert absorption_db_per_m(20e3, Atmosphere(20.0, 30.0)) > absorption_db_per_m(20e3, Atmosphere(20.0, 60.0))


def test_spreading_is_inverse_distance():
    r = np.array([1.0, 2.0, 10.0, 40.0])
    assert spreading_gain(r) == pytest.approx(1.0 / r)
    assert 20 * math.log10(spreading_gain(2.0) / spreading_gain(1.0)) == pytest.approx(-6.0206, abs=1e-4)


# --- diffraction and reflection -----------------------------------------------------------------------------

def test_maekawa_closed_form():
    assert maekawa_loss_db(0.0) == pytest.approx(10 * math.log10(3.0))
    assert maekawa_loss_db(1.0) == pytest.approx(10 * math.log10(23.0))
    assert maekawa_loss_db(np.array([0.5, 5.0, 50.0])) == pytest.approx([11.139, 20.128, 30.013], abs=1e-3)
    assert maekawa_loss_db(-1.0) == pytest.approx(maekawa_loss_db(0.0))        # lit side clamps to grazing
    # N = 2δ/λ = 2δf/c: 0.5 m detour at 20 kHz, 343 m/s
    assert fresnel_number(0.5, 20e3, 343.0) == pytest.approx(2 * 0.5 * 20e3 / 343.0)


def test_reflection_coefficients_from_absorption():
    assert reflection_coefficient("concrete") == pytest.approx(math.sqrt(0.95))
    assert reflection_coefficient("Steel") == pytest.approx(math.sqrt(0.95))
    assert reflection_coefficient("gravel") == pytest.approx(math.sqrt(0.5))
    assert reflection_coefficient("steel lattice") == pytest.approx(math.sqrt(0.9))   # unknown → α = 0.1


def test_free_field_paths_direct_and_ground_image():
    scene = build_scene(_site())
    for d_h in (5.0, 10.0, 25.0):
        p = channel_paths(scene, (0.0, 0.0, 3.0), (d_h, 0.0, 1.0))
        assert p.kind_names() == ["direct", "ground"]
        d = math.hypot(d_h, 2.0)
        lg = math.hypot(d_h, 4.0)                                 # image source at z = −3
        assert p.length_m == pytest.approx([d, lg])
        assert p.gain == pytest.approx([1.0 / d, math.sqrt(0.5) / lg])
        assert p.los


def test_image_source_reflection_geometry():
    wall = Box("firewall", "concrete", False, 10.0, 10.4, -20.0, 20.0, 9.0)
    scene = build_scene(_site([wall]))
    src, rx = (0.0, 0.0, 3.0), (5.0, 5.0, 1.0)
    p = channel_paths(scene, src, rx)
    assert p.kind_names() == ["direct", "ground", "reflection"]
    image = np.array([20.0, 0.0, 3.0])                            # mirrored in east = 10
    assert p.length_m[2] == pytest.approx(np.linalg.norm(np.array(rx) - image))
    assert p.gain[2] == pytest.approx(math.sqrt(0.95) / p.length_m[2])
    assert p.box[2] == 0
    # specular point off the face (wall too short in north) → no reflection
    short = Box("firewall", "concrete", False, 10.0, 10.4, 4.0, 6.0, 9.0)
    p2 = channel_paths(build_scene(_site([short])), src, rx)
    assert "reflection" not in p2.kind_names()
    # a pillar on the incident leg hides the reflection, the direct path stays
    pillar = Box("equipment", "steel", False, 7.2, 7.8, 2.2, 2.8, 4.0)
    p3 = channel_paths(build_scene(_site([wall, pillar])), src, rx)
    assert p3.kind_names()[:2] == ["direct", "ground"] and 0 not in p3.box[p3.kind == 2]
    # a porous gantry on the direct path costs porous_loss_db and does not block
    gantry = Box("gantry", "steel lattice", True, 2.0, 3.0, -30.0, 30.0, 12.0)
    p4 = channel_paths(build_scene(_site([gantry]), ChannelConfig(porous_loss_db=2.0)), src, rx)
    assert p4.los and p4.gain[0] == pytest.approx(10 ** (-2.0 / 20) / np.linalg.norm(np.subtract(rx, src)))


def test_blocked_direct_path_diffracts_over_the_top():
    wall = Box("firewall", "concrete", False, 10.0, 11.0, -20.0, 20.0, 5.0)
    scene = build_scene(_site([wall]))
    src, rx = (0.0, 0.0, 3.0), (20.0, 0.0, 1.0)
    p = channel_paths(scene, src, rx)
    assert not p.los and p.kind_names() == ["diffraction"]
    over = math.hypot(10.0, 2.0) + 1.0 + math.hypot(9.0, 4.0)    # taut string over both top edges
    assert p.length_m[0] == pytest.approx(over)
    assert p.detour_m[0] == pytest.approx(over - math.hypot(20.0, 2.0))
    assert p.gain[0] == pytest.approx(1.0 / math.hypot(20.0, 2.0))


def test_blocked_direct_path_diffracts_round_a_vertical_edge():
    """A tall, narrow wall: going round its end is shorter than over its 10 m top."""
    wall = Box("firewall", "concrete", False, 10.0, 10.4, -2.0, 2.0, 10.0)
    scene = build_scene(_site([wall]))
    src, rx = (0.0, 0.0, 3.0), (20.0, 0.0, 1.0)
    p = channel_paths(scene, src, rx)
    assert p.kind_names()[0] == "diffraction"
    eps = 1e-3                     # corners are taken 1 mm outside the box
    plan = math.hypot(10.0 - eps, 2.0 + eps) + 0.4 + 2 * eps + math.hypot(9.6 - eps, 2.0 + eps)
    assert p.length_m[0] == pytest.approx(math.hypot(plan, 2.0), abs=1e-3)
    assert p.detour_m[0] == pytest.approx(p.length_m[0] - math.hypot(20.0, 2.0), abs=1e-9)


def test_nlos_first_arrival_and_reflection_geometry_on_generated_site():
    layout = pytest.importorskip("simulation.site.layout")
    site = layout.generate_site(3)
    arr = beacon_arrivals(site, (60.0, 30.0, 1.0))
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    for bid, (delay, kind, paths) in arr.items():
        b = next(x for x in site.beacons if x.id == bid)
        d = math.dist((b.east_m, b.north_m, b.up_m), (60.0, 30.0, 1.0))
        assert delay >= d / c - 1e-12                              # nothing beats the straight line
        assert (kind == "direct") == paths.los
        assert np.all(np.diff(paths.length_m) >= 0)


def test_clutter_and_tail_grow_with_enclosure():
    open_site = build_scene(_site())
    court = [Box("building", "concrete", False, *extent, 6.0)
             for extent in ((-12, -10, -12, 12), (10, 12, -12, 12), (-12, 12, 10, 12), (-12, 12, -12, -10))]
    closed = build_scene(_site(court))
    aisle = build_scene(_site(court[:2]))
    c_open, c_aisle, c_closed = (clutter_index(s, (0.0, 0.0)) for s in (open_site, aisle, closed))
    assert c_open == 0.0 and c_closed == 1.0 and 0.3 < c_aisle < 0.7
    t0, t1 = tail_model(c_open), tail_model(c_closed)
    assert t1.decay_ms > t0.decay_ms and t1.density_per_ms > t0.density_per_ms and t1.level_db > t0.level_db


# --- chirp and schedule -----------------------------------------------------------------------------------------

def test_chirp_matches_documented_reference_and_band():
    spec = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
    s = chirp_waveform(spec, 48_000.0)
    assert s == pytest.approx(reference_chirp(spec, 48_000.0), abs=1e-9)
    spectrum = np.abs(np.fft.rfft(s, 8192))
    f = np.fft.rfftfreq(8192, 1 / 48_000)
    in_band = spectrum[(f > 17_000) & (f < 23_000)] ** 2
    assert in_band.sum() / (spectrum ** 2).sum() > 0.97
    # Doppler: closing at 1.5 m/s shortens the chirp by η and scales its frequencies by η
    eta = 1.0 + 1.5 / 343.0
    sd = chirp_waveform(spec, 48_000.0, eta)
    assert len(sd) == math.ceil(480 / eta)
    centroid = lambda x: (f * np.abs(np.fft.rfft(x, 8192)) ** 2).sum() / (np.abs(np.fft.rfft(x, 8192)) ** 2).sum()
    assert centroid(sd) / centroid(s) == pytest.approx(eta, abs=2e-4)


def test_beacon_overrides_band_and_duration():
    b = Beacon(7, 0.0, 0.0, 3.0, 0, f0_hz=18_000.0, f1_hz=20_000.0, chirp_duration_s=0.02)
    site = _site(beacons=(b, Beacon(8, 50.0, 0.0, 3.0, 1)))
    assert beacon_chirp(site, b) == ChirpSpec(18_000.0, 20_000.0, 0.02, site.acoustic.taper_fraction)
    assert beacon_chirp(site, site.beacons[1]) == ChirpSpec(17_000.0, 23_000.0, 0.01, 0.2)
    with pytest.raises(ConfigError):
        ChirpSpec(20_000.0, 18_000.0, 0.01, 0.2)
    with pytest.raises(ConfigError, match="Nyquist"):
        beacon_chirp(site, Beacon(9, 0.0, 0.0, 3.0, 0, f1_hz=25_000.0))
    with pytest.raises(ConfigError, match="slot"):
        beacon_chirp(site, Beacon(9, 0.0, 0.0, 3.0, 0, chirp_duration_s=0.15))


def test_tdma_schedule_on_walk_time_base():
    acoustic = AcousticConfig(slot_s=0.1, n_slots=4)
    beacons = tuple(Beacon(i, 10.0 * i, 0.0, 3.0, i) for i in range(4))
    site = _site(beacons=beacons, acoustic=acoustic)
    start = datetime(2026, 6, 1, 8, 0, 0, 250_000, tzinfo=timezone.utc)   # 0.25 s into a 0.4 s frame
    assert frame_phase_s(start, 0.4) == pytest.approx(0.25)
    t = {b.slot: emission_times_s(site, b, start, 0.0, 2.0) for b in beacons}
    assert t[0].tolist() == pytest.approx([0.15, 0.55, 0.95, 1.35, 1.75])
    assert t[3][0] == pytest.approx(0.05)
    # in UTC every emission sits on k·frame + slot·slot_s
    utc = (start - datetime(2026, 6, 1, tzinfo=timezone.utc)).total_seconds()
    for slot, times in t.items():
        off = np.mod(utc + times - 0.1 * slot + 0.2, 0.4) - 0.2            # circular distance to the slot start
        assert off == pytest.approx(np.zeros(len(times)), abs=1e-9)
    with pytest.raises(ConfigError):
        frame_phase_s(datetime(2026, 6, 1), 0.4)                         # naive time refused


def test_detection_range_and_slot_reuse_of_generated_sites():
    """Slot-mates must be ≥ 2 × detection range apart to be unambiguous everywhere.

    Link budget: 100 dB SPL at 1 m, T·B = 60, 12 dB detection threshold,
    20 °C / 60 %. With the default in-band noise (35 dB SPL ambient + a MEMS
    floor, 35.8 dB SPL) the free-field range is ≈ 70 m, so slot-mates need
    ≈ 141 m; the generator's reuse distance (145 m) keeps every pair of
    slot-mates out of any receiver's joint hearing, so on a 120 × 80 m yard
    slots are hardly reused (frame ≈ n_beacons × slot_s). With the noisy phone
    floor measured on real audio (50 dB SPL) the range is ≈ 47 m.
    """
    from simulation.acoustic.stream import AudioConfig
    spec = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
    r_default = detection_range_m(100.0, AudioConfig().inband_noise_db_spl, spec, Atmosphere())
    r_noisy = detection_range_m(100.0, AudioConfig(device_noise_dbfs=-63.0).inband_noise_db_spl, spec, Atmosphere())
    assert r_default == pytest.approx(70.5, abs=1.0)
    assert r_noisy == pytest.approx(47.3, abs=1.0)
    layout = pytest.importorskip("simulation.site.layout")
    cfg = layout.LayoutConfig()
    assert cfg.reuse_distance_m >= 2.0 * r_default
    for seed in (1, 2, 3):
        site = layout.generate_site(seed)
        assert slot_reuse_conflicts(site, cfg.reuse_distance_m) == []         # the generator keeps its promise
        assert slot_reuse_conflicts(site, 2.0 * r_default) == []              # no slot-mates heard together
        assert site.acoustic.frame_s <= 2.5                                    # still a fix every few seconds


def test_paths_are_reciprocal_on_a_generated_site():
    """Acoustic reciprocity: swapping source and receiver leaves every path length and gain unchanged."""
    layout = pytest.importorskip("simulation.site.layout")
    from simulation.site.geometry import boxes_array, inside_boxes
    site = layout.generate_site(5)
    scene = build_scene(site)
    rng = np.random.default_rng(7)
    solid = boxes_array([b for b in site.layout if not b.porous])
    n_checked = n_nlos = n_refl = 0
    while n_checked < 40:
        a = np.array([rng.uniform(0, 120), rng.uniform(0, 80), rng.uniform(0.8, 3.0)])
        b = np.array([rng.uniform(0, 120), rng.uniform(0, 80), rng.uniform(0.8, 3.0)])
        if inside_boxes(np.vstack([a[:2], b[:2]]), solid, 0.3).any() or np.linalg.norm(a - b) < 5:
            continue
        ab, ba = channel_paths(scene, a, b), channel_paths(scene, b, a)
        assert ab.length_m == pytest.approx(ba.length_m, abs=1e-6)
        assert ab.gain == pytest.approx(ba.gain, rel=1e-9)
        assert ab.kind.tolist() == ba.kind.tolist()
        n_checked += 1
        n_nlos += not ab.los
        n_refl += int((ab.kind == 2).sum())
    assert n_nlos >= 5 and n_refl >= 5            # the sample exercised diffraction and reflections


def test_documented_reference_chirp_runs_and_matches():
    """The numpy snippet of docs/beacon_protocol.md §1 builds exactly the transmitted chirp."""
    import re
    from pathlib import Path
    doc = (Path(__file__).resolve().parents[1] / "docs" / "beacon_protocol.md").read_text()
    snippet = re.search(r"```python\n(.*?)```", doc, re.S).group(1)
    spec = ChirpSpec(18_000.0, 22_500.0, 0.008, 0.3)
    env = {"T": spec.duration_s, "fs": 48_000.0, "f0": spec.f0_hz, "f1": spec.f1_hz, "taper": spec.taper_fraction}
    exec(snippet, env)
    assert env["s"] == pytest.approx(chirp_waveform(spec, 48_000.0), abs=1e-9)


def test_receiver_template_equals_transmitted_chirp():
    """Interface check with the receiver half: its template is the waveform the simulator transmits."""
    mf = pytest.importorskip("features.acoustic.matched_filter")
    if not hasattr(mf, "chirp_template"):
        pytest.skip("features.acoustic.matched_filter has no chirp_template")
    for f0, f1, dur, taper in ((17_000.0, 23_000.0, 0.010, 0.2), (18_000.0, 21_000.0, 0.02, 0.5)):
        theirs = mf.chirp_template(mf.ChirpSpec(f0, f1, dur, taper), 48_000)
        ours = chirp_waveform(ChirpSpec(f0, f1, dur, taper), 48_000.0)
        assert theirs == pytest.approx(ours, abs=1e-9)
