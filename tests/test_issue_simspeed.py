"""Issue 25 item 2: the simulator's compiled and vectorised hot paths against hand computations.

Each test is built so that a vectorisation bug — rows and columns swapped, one emission's values given to
another, a second search round skipped, a sample off by one — changes the figure by far more than its tolerance.
The files a seeded walk writes were also compared byte for byte with main's (the branch's report).
"""

from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import j1

from features.site import Beacon, Origin, Site
from simulation.acoustic.air import Air, AirConfig, moist_speed_of_sound_m_s
from simulation.acoustic.atmosphere import absorption_db_per_m, speed_of_sound_m_s
from simulation.acoustic.channel import ChannelConfig, PathSet
from simulation.acoustic.chirp import ChirpSpec
from simulation.acoustic.hardware import HardwareConfig
from simulation.acoustic.path_geometry import lateral_length, over_top_length, wall_reflections
from simulation.acoustic.stream import _Emitter, _hardware_factors
from simulation.acoustic.synthesis import AudioConfig, ChirpRenderer
from simulation.rng import stream_rng
from simulation.site.geometry import footprint_entry, segment_hits_boxes
from simulation.streams import Trajectory

EPS = 1e-3       # corners of the visibility graph stand 1 mm outside a box


def _box(e0, e1, n0, n1, h):
    return [e0, e1, n0, n1, h]


def test_segment_hits_pattern_rows_are_segments_columns_are_boxes():
    boxes = np.array([_box(0, 1, -1, 1, 2), _box(5, 6, -1, 1, 2), _box(10, 11, -1, 1, 2)], float)
    a = np.array([[-1.0, 0.0, 1.0], [4.0, 0.0, 1.0], [0.0, 5.0, 1.0]])
    b = np.array([[7.0, 0.0, 1.0], [12.0, 0.0, 3.0], [20.0, 5.0, 1.0]])
    # segment 1 rises 1 → 3 m over east 4 → 12: 1.25–1.5 m over box 2 (under its 2 m top), 2.5–2.75 m over box 3
    want = np.array([[True, True, False], [False, True, False], [False, False, False]])
    assert np.array_equal(segment_hits_boxes(a, b, boxes), want)
    # an end point exactly on a face is not a hit; a segment along a face plane (parallel, on the slab's edge) neither
    assert not segment_hits_boxes(np.array([[-3.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]), boxes).any()
    assert not segment_hits_boxes(np.array([[0.0, -5.0, 1.0]]), np.array([[0.0, 5.0, 1.0]]), boxes).any()


def test_footprint_entry_axes_are_origins_azimuths_boxes():
    """Two origins, each with its own two azimuths (east, west), two boxes: entry/exit by hand."""
    boxes = np.array([_box(5, 6, -1, 1, 3), _box(-3, -2, 4, 9, 2)], float)
    p = np.array([[0.0, 0.0], [0.0, 6.0]])
    az = np.array([[np.pi / 2, -np.pi / 2], [np.pi / 2, -np.pi / 2]])
    t_in, t_out = footprint_entry(p, az, boxes)
    inf = np.inf
    assert np.array_equal(t_in, [[[5.0, inf], [inf, inf]], [[inf, inf], [inf, 2.0]]])
    assert np.array_equal(t_out, [[[6.0, inf], [inf, inf]], [[inf, inf], [inf, 3.0]]])
    # one origin with rows of azimuths broadcasts as numpy would; an origin inside a box enters at 0
    one, _ = footprint_entry(p[:1], az, boxes)
    assert np.array_equal(one[1], t_in[0])
    inside, out = footprint_entry(np.array([[5.5, 0.0]]), np.array([np.pi / 2]), boxes)
    assert inside[0, 0, 0] == 0.0 and out[0, 0, 0] == pytest.approx(0.5)


def test_over_top_string_skips_a_lower_box_under_it():
    solid = np.array([_box(10, 11, -20, 20, 8), _box(20, 21, -20, 20, 3)], float)
    src, rx = np.array([0.0, 0.0, 2.0]), np.array([30.0, 0.0, 2.0])
    # the string from (11, 8) to (30, 2) passes 5.2 m up at east 20, above the 3 m box: it touches only the first
    want = math.hypot(10.0, 6.0) + 1.0 + math.hypot(19.0, 6.0)
    assert over_top_length(solid, src, rx) == pytest.approx(want, abs=1e-12)
    # raise the second box to 7 m: now the string rests on its far top edge too (7 m lies above the 8 → 2 m line
    # at east 21; its near edge at east 20 stays under the 8 → 7 m stretch)
    solid[1, 4] = 7.0
    want2 = math.hypot(10.0, 6.0) + 1.0 + math.hypot(10.0, 1.0) + math.hypot(9.0, 5.0)
    assert over_top_length(solid, src, rx) == pytest.approx(want2, abs=1e-12)
    assert over_top_length(solid, src, np.array([0.0, 30.0, 2.0])) == math.inf       # nothing crossed


def test_lateral_route_takes_a_second_round_when_its_first_route_is_blocked():
    """The wall's south end is nearer (3 m) than its north end (3.2 m), but a second box stands on the southern
    route: the first round finds the south route, the second adds that box; round its corner (6, −0.5) the
    south route grows to 21.4 m, so the route goes north (21.1 m)."""
    wall = _box(9, 11, -3, 3.2, 50)
    south_block = _box(4, 6, -30, -0.5, 50)
    src, rx = np.array([0.0, 0.0, 1.0]), np.array([20.0, 0.0, 1.0])
    south = 2 * math.hypot(9 - EPS, 3 + EPS) + 2 + 2 * EPS
    north = 2 * math.hypot(9 - EPS, 3.2 + EPS) + 2 + 2 * EPS
    round_block = math.hypot(6 + EPS, 0.5 - EPS) + math.hypot(3 - 2 * EPS, 2.5 + 2 * EPS) + 2 + 2 * EPS + math.hypot(
        9 - EPS, 3 + EPS)
    assert south < north < round_block
    assert lateral_length(np.array([wall], float), src, rx, np.array([0])) == pytest.approx(south, abs=1e-9)
    assert lateral_length(np.array([wall, south_block], float), src, rx, np.array([0])) == pytest.approx(north,
                                                                                                      abs=1e-9)
    # with a height change the route rises linearly: sqrt(L_plan² + Δz²)
    up = lateral_length(np.array([wall], float), src, np.array([20.0, 0.0, 4.0]), np.array([0]))
    assert up == pytest.approx(math.hypot(south, 3.0), abs=1e-9)


def test_wall_reflection_image_source_by_hand():
    """One box east of source and receiver: only its west face (x = 10, facing −x) can reflect."""
    e0, e1, n0, n1, h, r = 10.0, 12.0, -50.0, 50.0, 10.0, 0.9
    faces = np.array([(0, e0, -1, n0, n1, h, r), (0, e1, 1, n0, n1, h, r),
                      (1, n0, -1, e0, e1, h, r), (1, n1, 1, e0, e1, h, r)], float)
    solid = np.array([_box(e0, e1, n0, n1, h)], float)
    src, rx = np.array([0.0, 0.0, 2.0]), np.array([0.0, 8.0, 1.0])
    direct = float(np.linalg.norm(rx - src))
    length, gain, face = wall_reflections(faces, solid, np.zeros((0, 5)), 1.5, src, rx, direct, 40.0)
    image_length = math.sqrt(20.0 ** 2 + 8.0 ** 2 + 1.0 ** 2)          # image source at (20, 0, 2)
    assert face.tolist() == [0]
    assert length[0] == pytest.approx(image_length, abs=1e-12)
    assert gain[0] == pytest.approx(r / image_length, rel=1e-12)
    # a porous box on the way back costs its loss once; a solid one hides the path
    porous = np.array([_box(2, 3, 6.5, 9, 5)], float)     # on the return leg only (specular point (10, 4, 1.5))
    _, g2, _ = wall_reflections(faces, solid, porous, 1.5, src, rx, direct, 40.0)
    assert g2[0] == pytest.approx(r / image_length * 10 ** (-1.5 / 20), rel=1e-12)
    blocked, _, _ = wall_reflections(faces, np.vstack([solid, porous]), np.zeros((0, 5)), 1.5, src, rx, direct, 40.0)
    assert len(blocked) == 0


def _site() -> Site:
    return Site(name="t", origin=Origin(31.0, 118.0), beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),))


def test_c_eff_of_a_batch_row_by_row():
    """Without transformers the path mean is the moist c of the air; the wind adds w(t)·n̂ of each row's own
    time and direction."""
    site = _site()
    air = Air(site, stream_rng(3, "crew"), stream_rng(3, "air"), 60.0, AirConfig(hot_air_min_k=0.0,
                                                                                  hot_air_max_k=0.0))
    c0 = float(moist_speed_of_sound_m_s(air.temperature_c, air.rh_pct, air.pressure_kpa))
    t = np.array([1.0, 20.0, 45.5])
    src = np.array([0.0, 0.0, 3.0])
    rx = np.array([[10.0, 0.0, 1.0], [0.0, -7.0, 1.0], [3.0, 4.0, 1.0]])
    got = air.c_eff(t, src, rx)
    assert got.shape == (3,)
    for i in range(3):
        w = air.wind_mean + [np.interp(t[i], air._gust_t, air._gust[:, k]) for k in (0, 1)]
        d = rx[i] - src
        assert got[i] == pytest.approx(c0 + w @ d[:2] / np.linalg.norm(d), rel=1e-13)
        assert air.c_eff(float(t[i]), src, rx[i]) == got[i]
    assert np.ptp(got) > 0.1             # the rows really differ (a wind of some m/s along different paths)


def _emitter(trajectory: Trajectory, hardware=None) -> _Emitter:
    cfg = AudioConfig()
    n_total = int(trajectory.duration_s * cfg.fs_hz)
    return _Emitter(_site(), trajectory, 1, cfg, AirConfig(enabled=False), 1, hardware, 0.0, float(cfg.fs_hz),
                    n_total)


def test_arrival_fixed_point_per_emission_of_a_batch():
    """A walker going east at 1.5 m/s; three emissions of one batch: each arrival solves t_a = t_e + |s − x(t_a)|/c
    for its own emission time (brentq here), and the walker 3 km away is screened out."""
    t = np.arange(0.0, 100.0 + 1e-9, 0.01)
    east = -20.0 + 1.5 * t
    traj = Trajectory(t, east, np.full_like(t, 5.0), np.full_like(t, 1.0), np.full_like(t, np.pi / 2),
                      np.full_like(t, 1.5), datetime(2026, 6, 1, tzinfo=timezone.utc), 100.0)
    em = _emitter(traj)
    c = speed_of_sound_m_s(_site().atmosphere.temperature_c)
    t_e = np.array([2.0, 30.0, 55.0])
    src = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 3.0], [0.0, 3000.0, 3.0]])
    spec = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
    arr = em.arrivals(t_e, src, [1, 1, 1], [spec] * 3)
    for i in range(2):
        def pos(ta):
            return np.array([-20.0 + 1.5 * ta, 5.0, 1.0])
        want = brentq(lambda ta: ta - t_e[i] - np.linalg.norm(src[i] - pos(ta)) / c, t_e[i], t_e[i] + 1.0)
        assert arr.t_a_s[i] == pytest.approx(want, abs=5e-6)      # two fixed-point steps: ≈ (v/c)²·d/c ≈ 1.4 µs
        assert np.allclose(arr.rx[i], pos(arr.t_a_s[i]), atol=1e-9)
        assert arr.d_m[i] == pytest.approx(np.linalg.norm(src[i] - arr.rx[i]), abs=1e-12)
    assert arr.heard.tolist() == [True, True, False]
    assert arr.speed_m_s.tolist() == pytest.approx([1.5, 1.5, 1.5])


def test_tweeter_and_torso_factors_row_by_row():
    """Row 0: the walker heads east, away from the beacon (behind: 20 dB, a quarter round the torso); row 1:
    heading south towards it (no torso). Both 11.3° off their nearest tweeter: |D| = |2 J1(x)/x|,
    x = k·a·sin θ (baffled piston, Kinsler et al., Fundamentals of Acoustics, 4th ed., eq. 7.4.17)."""
    hw = HardwareConfig()
    src = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 3.0]])
    rx = np.array([[10.0, 0.0, 1.0], [0.0, 10.0, 1.0]])
    axes = np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]] * 2)
    f_c, c = np.array([20_000.0, 20_000.0]), 343.0
    gain, extra = _hardware_factors(src, rx, axes, f_c, c, np.array([np.pi / 2, np.pi]), hw)
    theta = math.acos(10.0 / math.sqrt(104.0))
    x = 2 * math.pi * 20_000.0 / c * hw.piston_radius_m * math.sin(theta)
    piston = abs(2 * j1(x) / x)
    assert gain == pytest.approx([piston * 10 ** (-hw.torso_loss_max_db / 20), piston], rel=1e-12)
    assert extra == pytest.approx([hw.torso_radius_m * math.pi / 2, 0.0], abs=1e-12)


def test_rendered_chirp_sample_by_sample_at_a_fractional_delay():
    """One direct path of 1 m, no tail: the rendered segment is the analytic chirp s(t − τ), τ a fractional
    number of samples, scaled by 1/L and the ISO 9613-1 absorption at the band centre (it varies by < 1 %
    across the band over 1 m), to within the spectral leakage of the 2 kHz guard bands. One sample off
    would leave a 20 kHz chirp 150° out of phase."""
    site = _site()
    cfg = AudioConfig(channel=ChannelConfig(tail_offset_db=-200.0))
    renderer = ChirpRenderer(site, cfg)
    spec = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
    paths = PathSet(kind=np.array([0]), length_m=np.array([1.0]), gain=np.array([1.0]), detour_m=np.array([0.0]),
                    box=np.array([-1]), direct_m=1.0, los=True)
    first = 1000.37
    start, seg = renderer.render(paths, spec, 1.0, first, 0.0, np.random.default_rng(0), 1.0)
    assert start == 1000 - 64
    fs = float(cfg.fs_hz)
    t = (np.arange(len(seg)) - (first - start)) / fs                # time since the arrival, s
    n_ref = round(spec.duration_s * fs)
    x = t * fs / (n_ref - 1)
    half = spec.taper_fraction / 2
    w = np.where((x >= 0) & (x <= 1), 1.0, 0.0)
    w = np.where((x >= 0) & (x < half), 0.5 * (1 - np.cos(np.pi * x / half)), w)
    w = np.where((x > 1 - half) & (x <= 1), 0.5 * (1 - np.cos(np.pi * (1 - x) / half)), w)
    k = (spec.f1_hz - spec.f0_hz) / spec.duration_s
    absorb = 10 ** (-float(absorption_db_per_m(20_000.0, site.atmosphere)) * 1.0 / 20)
    want = absorb * w * np.sin(2 * np.pi * (spec.f0_hz * t + 0.5 * k * t * t))
    err = np.sqrt(np.mean((seg - want) ** 2)) / np.sqrt(np.mean(want ** 2))
    assert err < 0.03
    shifted = np.roll(want, 1)
    assert np.sqrt(np.mean((seg - shifted) ** 2)) / np.sqrt(np.mean(want ** 2)) > 0.5


# ---------------------------------------------------------------------------------------------------------------
# The UWB, foot-IMU and codec hot paths (the second speed pass)
# ---------------------------------------------------------------------------------------------------------------

def test_codec_biquads_equal_scipy_sosfilt_sample_for_sample_across_blocks():
    """The compiled cascade against scipy's own sosfilt (an independent implementation): bit for bit, state
    carried over uneven blocks; a 4th-order 22 kHz low-pass passes 17 kHz and stops 23.9 kHz."""
    from scipy import signal
    from simulation.acoustic.hardware import sos_filter
    sos = signal.butter(4, 22_000.0, btype="low", fs=48_000.0, output="sos")
    x = np.random.default_rng(3).standard_normal(30_001)
    want, zf = signal.sosfilt(sos, x, zi=np.zeros((2, 2)))
    zi = np.zeros((2, 2))
    got = np.concatenate([sos_filter(sos, x[a:b], zi) for a, b in ((0, 1), (1, 9_999), (9_999, 30_001))])
    assert np.array_equal(got, want) and np.array_equal(zi, zf)
    t = np.arange(48_000) / 48_000.0
    for f_hz, lo, hi in ((17_000.0, 0.95, 1.02), (23_900.0, 0.0, 0.35)):
        y = sos_filter(sos, np.sin(2 * np.pi * f_hz * t), np.zeros((2, 2)))[4_800:]
        assert lo < np.sqrt(2.0) * y.std() < hi


def test_pcm16_rounds_ties_to_even_clips_and_counts_the_clipped():
    from simulation.acoustic.stream import _to_pcm16
    half = 0.5 / 32767.0
    x = np.array([0.0, half, 3 * half, -half, -3 * half, 1.0, -1.0, 1.2, -1.2, 32767.5 / 32767.0, 0.25])
    pcm, clipped = _to_pcm16(x)
    assert pcm.dtype == np.int16
    # 0.5 → 0, 1.5 → 2, −0.5 → 0, −1.5 → −2 (ties to even); ±1.2 and 32767.5 → 32768 over full scale
    assert pcm.tolist() == [0, 0, 2, 0, -2, 32767, -32767, 32767, -32768, 32767, 8192]
    assert clipped == 3


def test_slab_chords_by_hand_oblique_parallel_and_missing():
    from simulation.uwb.channel import segment_chords_m
    boxes = np.array([[4.0, 6.0, -1.0, 1.0, 5.0],      # crossed along east: 2 m
                      [4.0, 6.0, 2.0, 3.0, 5.0],       # beside the segment: 0
                      [-1.0, 1.0, -1.0, 1.0, 0.5]])    # the segment starts inside it at 1 m height, above its top
    got = segment_chords_m([0.0, 0.0, 1.0], [10.0, 0.0, 1.0], boxes)
    assert got.tolist() == pytest.approx([2.0, 0.0, 0.0], abs=1e-12)
    # oblique 3-4-5 segment (east 3, north 4 per 5 m) through a box spanning east 1.5–3: t 0.5–1 of a 5 m segment
    got = segment_chords_m([0.0, 0.0, 1.0], [3.0, 4.0, 1.0], np.array([[1.5, 3.0, -10.0, 10.0, 2.0]]))
    assert got.tolist() == pytest.approx([2.5], abs=1e-12)
    # rising segment leaving through the top at 2 m: from t = 0 (inside) to t = 0.25 of a √(100 + 16) m segment
    got = segment_chords_m([0.0, 0.0, 1.0], [10.0, 0.0, 5.0], np.array([[-1.0, 20.0, -1.0, 1.0, 2.0]]))
    assert got.tolist() == pytest.approx([0.25 * math.sqrt(116.0)], abs=1e-12)


def test_uwb_quality_of_rows_by_hand():
    """First path over the received total with the clusters' tails: two paths of −80 and −86 dBm, the first
    path the stronger (total −80 + 10·log10(1.2512 · 1.5012) = −77.262 dBm); a row of one path; a −inf path
    counts for nothing; the result is at most 0 dB."""
    from simulation.uwb.channel import CLUSTER_TAIL_DB
    from simulation.uwb.stream import _quality_db
    tail = 1.0 + 10.0 ** (CLUSTER_TAIL_DB / 10.0)
    rows = [np.array([-80.0, -86.0]), np.array([-90.0]), np.array([-70.0, -np.inf, -73.0]), np.array([-75.0])]
    got = _quality_db(rows, [0, 0, 0, 0], [0.1, 0.0, 0.0, 50.0])
    want0 = -80.0 - 10.0 * math.log10((1e-8 + 10.0 ** -8.6) * tail) + 0.1
    assert got[0] == pytest.approx(want0, abs=1e-12) and got[0] == pytest.approx(-2.738 + 0.1, abs=0.001)
    assert got[1] == pytest.approx(-10.0 * math.log10(tail), abs=1e-12)
    assert got[2] == pytest.approx(-70.0 - 10.0 * math.log10((1e-7 + 10.0 ** -7.3) * tail), abs=1e-12)
    assert got[3] == 0.0
    assert _quality_db([], [], []) == []


def test_foot_bias_recursion_by_hand():
    from simulation.imu.foot import _ar1
    w = np.array([[9.0, 9.0, 9.0], [1.0, 0.0, -1.0], [0.5, 2.0, 0.0]])
    x = _ar1(0.5, np.array([2.0, -4.0, 0.0]), w)
    assert x.tolist() == [[2.0, -4.0, 0.0], [2.0, -2.0, -1.0], [1.5, 1.0, -0.5]]
    assert _ar1(0.5, np.zeros(3), np.zeros((0, 3))).shape == (0, 3)


def test_accumulator_blocks_equal_the_whole_recording_summed_at_once():
    """Segments added anywhere ahead of the flush point (across block edges, past the buffer, clipped at the
    recording's end) come out block by block as the same samples summed into one array; only the written part
    of the buffer is shifted, so a stale sample would show here."""
    from simulation.acoustic.stream import _Accumulator
    n_total, block = 1_000, 64
    rng = np.random.default_rng(4)
    acc, whole, popped = _Accumulator(block, n_total), np.zeros(n_total), []
    for start in sorted(rng.integers(-20, n_total + 20, 60).tolist()):
        while acc.base + block <= start:                # the renderer flushes up to each emission
            popped.append(acc.pop_block())
        seg = rng.standard_normal(int(rng.integers(1, 400)))
        acc.add(start, seg)
        lo, hi = max(start, 0), min(start + len(seg), n_total)
        if hi > lo:
            whole[lo:hi] += seg[lo - start:hi - start]
    while acc.base < n_total:
        popped.append(acc.pop_block())
    got = np.concatenate(popped)
    assert len(got) == n_total and np.array_equal(got, whole)
