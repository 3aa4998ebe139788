"""Issue 11, defects 1 and 5: an acoustic fix carries the time its position refers to.

Defect 1: motion is compensated to the mean arrival of all associated chirps, so that
is the tag too, whatever beacons the exclusion keeps (the tag was the mean over the
kept ones: 0.10 s early when the far, late beacon is excluded).

Defect 5: the linear chirp's matched-filter peak moves with the Doppler factor η by
−(η − 1)·T·f1/B (38.3 ms per unit η − 1 for 17→23 kHz in 10 ms), i.e. a moving
receiver's range is the one 38 ms after the arrival; the tag now includes it.

Figures, held-out walks (sites 41, 52, 63 × walks 2, 3; 300 s each;
``bench/eval_receiver.py``): median along-track error of walking fixes / speed
(the tag's lag) 0.035 s before → −0.002 s after; site 31 walk 2 (the issue's):
0.149 s → −0.0005 s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from features.acoustic.cir import CirFeatures
from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank
from features.acoustic.positions import PositionConfig
from features.acoustic.timing import ChirpDetection, speed_of_sound_m_s
from features.acoustic.tracking import frame_fix
from tests.acoustic_synth import FS_HZ, chirp_at, square_site

C = speed_of_sound_m_s(20.0)
_NAN = CirFeatures(*([float("nan")] * 9))


@pytest.mark.parametrize("eta", [1.003, 0.997, 1.006])
def test_doppler_scaled_chirp_peak_moves_by_the_coupling_lag(eta):
    """s(η·t) heard (moving observer), matched to s(t): the peak moves by −(η − 1)·T·f1/B within 3 %."""
    spec = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
    bank = MatchedFilterBank([spec], FS_HZ)
    t = np.arange(4800) / FS_HZ
    ref = bank.envelope(chirp_at(t - 0.02), 0)
    heard = bank.envelope(chirp_at(eta * (t - 0.02)), 0)
    shift_s = (_peak(heard) - _peak(ref)) / FS_HZ
    assert shift_s == pytest.approx(-(eta - 1) * spec.range_doppler_lag_s, rel=0.03)


def _peak(env):
    i = int(np.argmax(env))
    y = np.log(env[i - 1: i + 2])
    return i + 0.5 * (y[0] - y[2]) / (y[0] - 2 * y[1] + y[2])


def test_tag_is_the_compensation_time_when_a_late_beacon_is_excluded():
    """A receiver walking east at 1.4 m/s; eight beacons, the last (slot 7, heard 0.7 s after
    the first) 4 m NLOS-late and excluded. The fix is the position at the mean arrival of all
    eight (plus the coupling lag) and is tagged so; the kept-beacons mean would be 0.05 s early."""
    site = square_site(8)
    v = (1.4, 0.0)
    clock = 0.003
    lag = 0.0383
    dets = []
    for b in site.beacons:
        tx = b.slot * site.acoustic.slot_s
        t_a = tx
        for _ in range(4):
            p = (20.0 + v[0] * t_a, 25.0 + v[1] * t_a)
            t_a = tx + math.dist((*p, site.device_height_m), (b.east_m, b.north_m, b.up_m)) / C
        # The range read is the one ``lag`` later (range–Doppler coupling), as the receiver measures it.
        p_l = (20.0 + v[0] * (t_a + lag), 25.0)
        r_l = math.dist((*p_l, site.device_height_m), (b.east_m, b.north_m, b.up_m))
        late = 4.0 if b.id == 8 else 0.0
        dets.append(ChirpDetection(0, b.id, tx, tx + (r_l + late) / C + clock, 30.0, _NAN))
    cfg = PositionConfig(max_clock_offset_s=0.07, motion_speed_m_s=0.5)
    bw = {b.id: 6000.0 for b in site.beacons}
    fix = frame_fix(dets, site, C, bw, cfg, velocity_m_s=v, range_lag_s={b.id: lag for b in site.beacons})
    assert fix is not None and fix.rejected_ids == (8,)
    t_all = np.mean([d.arrival_s for d in dets]) + lag - fix.clock_offset_s
    t_kept = np.mean([d.arrival_s for d in dets if d.beacon_id != 8]) + lag - fix.clock_offset_s
    assert fix.t_s == pytest.approx(t_all, abs=1e-9)
    assert t_all - t_kept > 0.04                                   # what the old tag lost
    assert fix.east_m == pytest.approx(20.0 + v[0] * fix.t_s, abs=0.01)
    assert fix.north_m == pytest.approx(25.0, abs=0.01)
    # Without the coupling lag the same ranges put the fix 1.4 m/s × 38 ms = 5 cm ahead of its tag.
    old = frame_fix(dets, site, C, bw, cfg, velocity_m_s=v)
    assert old.east_m - (20.0 + v[0] * old.t_s) == pytest.approx(v[0] * lag, abs=0.01)


@pytest.fixture(scope="module")
def ideal_air_walk(site_dir, tmp_path_factory):
    """The conftest walk (site 3, seed 11, 60 s) with the stated air and ideal transducers: the tag's lag
    is a receiver property; wind and beacon survey errors (issue 10) would add their own along-track bias."""
    from simulation.walk import simulate_walk

    return simulate_walk(site_dir, tmp_path_factory.mktemp("ideal") / "w11", seed=11, duration_s=60.0,
                         options={"acoustic_air": False, "acoustic_hardware": False})


def test_walk_fixes_are_not_ahead_of_their_tags(ideal_air_walk):
    """On the simulated 60 s walk (site 3, walk 11): median along-track error of walking fixes
    over speed within ±40 ms (measured −23 ms over 18 fixes, +4 ms before: this short walk
    rarely excludes a late beacon, and one fix's error/speed scatters by ~35 ms; a coupling
    correction of the wrong sign would read −100 ms). The before/after figure is from 300 s
    walks: +35 → −2 ms held out, +149 → −0.5 ms on site 31 walk 2.

    Re-pinned ±40 → ±70 ms: the receiver now takes the wearer's torso off the ranges of beacons
    behind (``tracking.frame_ranges``, 0.1–0.2 m), and this walk is simulated without hardware
    (no torso), so its fixes trail slightly: measured −51 ms (coverage deployment, 0.96 s frames).
    On the held-out walks, which have the torso, the lag fell from 0.086 to 0.054 s."""
    from walks.reader import read_walk

    wd = read_walk(ideal_air_walk)
    a, tr = wd.acoustic, wd.truth
    lags = []
    for t, e, n in zip(a.t_s, a.east_m, a.north_m):
        ve = (np.interp(t + 0.25, tr.t_s, tr.east_m) - np.interp(t - 0.25, tr.t_s, tr.east_m)) / 0.5
        vn = (np.interp(t + 0.25, tr.t_s, tr.north_m) - np.interp(t - 0.25, tr.t_s, tr.north_m)) / 0.5
        speed = math.hypot(ve, vn)
        if speed > 0.5:
            de, dn = e - np.interp(t, tr.t_s, tr.east_m), n - np.interp(t, tr.t_s, tr.north_m)
            lags.append((de * ve + dn * vn) / speed / speed)
    assert len(lags) >= 10
    assert abs(float(np.median(lags))) < 0.07
