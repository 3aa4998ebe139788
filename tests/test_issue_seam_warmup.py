"""What rode on a long walk's warm-up (issue 25 item 3, walks/segments.py): the GNSS ``fluct_per_s`` extremum
detector judges each extremum's swing from the previous one, a memory that outlasts any warm-up while a
satellite's C/N0 holds still (a stop), so a cut read it from scratch and marked other extrema than the whole
log (the class-aware filters 2e-5..6e-4 m off at 60 s segments). It is now handed over
(:class:`features.gnss.features.FluctuationState`), and the cuts' audio starts on the 1 s window grid, aligned
on the whole recording by ``first_sample``, instead of the 32 s block grid."""

import numpy as np
import pytest

from features.gnss.features import (
    FluctuationState, GnssFeatureConfig, SkyArrays, fluctuation_extrema, fluctuation_state, gnss_features,
)


def _sky(t_s, cn0):
    cn0 = np.asarray(cn0, float)
    n, m = cn0.shape
    el = np.tile(np.array([70.0, 40, 40, 40, 40, 25][:m]), (n, 1))
    az = np.tile(np.array([0.0, 0, 90, 180, 270, 45][:m]), (n, 1))
    return SkyArrays(np.asarray(t_s, float), tuple(("GPS", i + 1) for i in range(m)), el, az, cn0,
                     np.ones((n, m), bool), np.isfinite(cn0), np.ones(n))


def _cut(sky: SkyArrays, i: int) -> SkyArrays:
    """The epochs from row ``i`` on, as a later cut of the log reads them (its columns in the same order)."""
    return SkyArrays(sky.t_s[i:], sky.sat_keys, sky.el_deg[i:], sky.az_deg[i:], sky.cn0_dbhz[i:], sky.in_view[i:],
                     sky.used[i:], sky.hdop[i:], sky.interval_s)


def _plateau_log():
    """1 Hz, two satellites: the first rises 40 → 41 → 44, holds 44 dB-Hz for 100 s (a stop), falls to 42 and
    rises to 43, 43; the second flickers 45/46 (swings of 1 dB-Hz, below the 2 dB-Hz threshold: never marked)."""
    a = np.r_[40.0, 41.0, np.full(100, 44.0), 42.0, 43.0, 43.0]
    b = np.where(np.arange(a.size) % 2 == 0, 45.0, 46.0)
    return _sky(np.arange(a.size, dtype=float), np.c_[a, b])


def test_extrema_after_a_plateau_need_the_memory_from_before_it():
    """By hand: the whole log marks the plateau's end (row 101: rise into it, fall after it, swing 44 − 40 = 4)
    and the dip (row 102: swing 44 − 42 = 2); the flicker never. A cut from row 30 (inside the plateau) read
    from scratch sees no rise into the plateau and measures the dip from its first value: it marks the dip
    only. Resumed from the memory before row 30 (:func:`fluctuation_state` of the whole log), it marks both."""
    sky = _plateau_log()
    thr = GnssFeatureConfig().fluct_threshold_dbhz
    tracked = np.isfinite(sky.cn0_dbhz)
    whole = fluctuation_extrema(sky.cn0_dbhz, tracked, thr)
    assert np.flatnonzero(whole[:, 0]).tolist() == [101, 102] and not whole[:, 1].any()
    fresh = fluctuation_extrema(sky.cn0_dbhz[30:], tracked[30:], thr)
    assert (np.flatnonzero(fresh[:, 0]) + 30).tolist() == [102]
    state = fluctuation_state(sky, 30.0)
    assert state.t_s == 30.0 and state.sat_keys == sky.sat_keys
    # by hand: last value 44, last change up (41 → 44), swing reference 40 (no extremum yet: the first value)
    assert state.last_dbhz[0] == 44.0 and state.direction[0] == 1.0 and state.extremum_dbhz[0] == 40.0
    resumed = fluctuation_extrema(sky.cn0_dbhz[30:], tracked[30:], thr, state.columns(sky.sat_keys))
    assert np.array_equal(resumed, whole[30:])


def test_gnss_features_of_a_resumed_cut_are_the_whole_logs_from_the_resumption_on():
    """``fluct_per_s`` of a cut from 20 s resumed at 30 s (the memory of the whole log there) equals the whole
    log's in every window that holds no epoch before 30 s (bit for bit: sums of whole counts), and is 0 where
    the fresh cut misses the plateau's end (the window centred at 100 s: tags [99, 101) s, 1 Hz epochs tagged t − 0.5); the other four features never depended
    on the past (equal to the round-off of the running sums they are differenced from, 1e-12 of ~3 dB). The state of the resumed cut at 60 s is the whole log's there; one whose columns lie in another
    order (a cut lists satellites in order of first appearance) maps them by key."""
    sky = _plateau_log()
    whole = gnss_features(sky)
    at = 30.0
    cut = _cut(sky, 20)
    resumed = gnss_features(cut, resume=fluctuation_state(sky, at))
    fresh = gnss_features(cut)
    w = whole["t_s"] >= at + 1.0                 # windows [t − 1, t + 1): from 31 s all epochs ≥ 30 s
    c = resumed["t_s"] >= at + 1.0
    assert np.array_equal(whole["t_s"][w], resumed["t_s"][c])
    assert np.array_equal(whole["fluct_per_s"][w], resumed["fluct_per_s"][c])
    f = fresh["t_s"] >= at + 1.0                 # (the resumed cut also has the window reaching back to 19 s)
    assert np.any(whole["fluct_per_s"][w] != fresh["fluct_per_s"][f])
    for name in whole:
        np.testing.assert_allclose(resumed[name][c], whole[name][w], rtol=0, atol=1e-9, err_msg=name)
    k = np.flatnonzero(np.isclose(fresh["t_s"], 100.0))[0]
    assert whole["fluct_per_s"][np.isclose(whole["t_s"], 100.0)][0] > 0 and fresh["fluct_per_s"][k] == 0.0
    later_whole = fluctuation_state(sky, 60.0)
    later_cut = fluctuation_state(cut, 60.0, resume=fluctuation_state(sky, at))
    for a, b in zip(later_whole.columns(sky.sat_keys), later_cut.columns(sky.sat_keys)):
        assert np.array_equal(a, b, equal_nan=True)
    state = fluctuation_state(sky, at)
    swapped = FluctuationState(at, sky.sat_keys[::-1], *(np.asarray(a)[::-1] for a in state.columns(sky.sat_keys)),
                               state.window_origin_s)
    assert np.array_equal(gnss_features(cut, resume=swapped)["fluct_per_s"], resumed["fluct_per_s"])


def _listed(sky: SkyArrays, lo: float, hi: float) -> SkyArrays:
    """The epochs of walk times [lo, hi) with only the satellites they list (a receiver's GSV naming tracked
    satellites only: a satellite blocked through the whole cut is not a column of it)."""
    k = (sky.t_s >= lo) & (sky.t_s < hi)
    cols = np.flatnonzero(np.isfinite(sky.cn0_dbhz[k]).any(axis=0))
    return SkyArrays(sky.t_s[k], tuple(sky.sat_keys[j] for j in cols), sky.el_deg[k][:, cols],
                     sky.az_deg[k][:, cols], sky.cn0_dbhz[k][:, cols], sky.in_view[k][:, cols],
                     sky.used[k][:, cols], sky.hdop[k], sky.interval_s)


def test_a_satellite_absent_from_a_whole_cut_keeps_its_memory():
    """1 Hz, 300 s; G1 flickers 45/46 (never marked), G2 rises 40 → 44 over rows 0–9, is blocked (not listed)
    from 10 to 199 s, comes back at 44, dips to 42 at row 205 and holds 43 after. By hand, the whole log marks
    G2 at 204 (it rose into 44 before the gap, falls after: swing 44 − 40 = 4) and 205 (swing 44 − 42 = 2).
    Read in cuts [0, 110), [90, 200), [180, 300) with the memory handed on at 100 s and 190 s, the middle cut
    lists no G2: the state it hands on must still hold G2's memory (last 44, rising, reference 40), so the last
    cut marks 204 too and its ``fluct_per_s`` from 191 s on is the whole log's. Before, G2 was dropped from
    that state and the last cut marked 205 only."""
    t = np.arange(300, dtype=float)
    g1 = 45.0 + (np.arange(300) % 2)
    g2 = np.full(300, np.nan)
    g2[:10] = np.linspace(40.0, 44.0, 10)
    g2[200:], g2[205], g2[206:] = 44.0, 42.0, 43.0
    whole = _sky(t, np.c_[g1, g2])
    thr = GnssFeatureConfig().fluct_threshold_dbhz
    marks = fluctuation_extrema(whole.cn0_dbhz, np.isfinite(whole.cn0_dbhz), thr)
    assert np.flatnonzero(marks[:, 1]).tolist() == [204, 205] and not marks[:, 0].any()
    c0, c1, c2 = _listed(whole, 0, 110), _listed(whole, 90, 200), _listed(whole, 180, 300)
    assert c1.sat_keys == (("GPS", 1),)
    s1 = fluctuation_state(c0, 100.0)
    s2 = fluctuation_state(c1, 190.0, resume=s1)
    g2_memory = [np.asarray(a)[0] for a in s2.columns([("GPS", 2)])]
    assert g2_memory[:3] == [44.0, 1.0, 40.0] and not g2_memory[3]       # by hand: as before the gap, untracked
    cut_marks = fluctuation_extrema(np.where(np.isfinite(c2.cn0_dbhz), c2.cn0_dbhz, np.nan),
                                    np.isfinite(c2.cn0_dbhz), thr, s2.columns(c2.sat_keys))
    rows = c2.t_s[cut_marks[:, c2.sat_keys.index(("GPS", 2))]].astype(int).tolist()
    assert [r for r in rows if r >= 190] == [204, 205]
    fw, fc = gnss_features(whole), gnss_features(c2, resume=s2)
    w, c = fw["t_s"] >= 191.0, fc["t_s"] >= 191.0
    assert np.array_equal(fw["t_s"][w], fc["t_s"][c]) and np.array_equal(fw["fluct_per_s"][w], fc["fluct_per_s"][c])


def test_random_logs_cut_anywhere_mark_the_whole_logs_extrema():
    """300 random integer C/N0 logs (random walks, plateaus, untracked epochs), each cut in up to four pieces,
    every piece resumed from the memory the previous one reached at its end: the marks equal the whole log's
    at every row but each piece's last (its mark needs the next row, which the next piece decides: in a long
    walk's cut that row lies in the warm-up)."""
    from features.gnss.features import _extrema_memory

    rng = np.random.default_rng(1)
    tested = 0
    for _ in range(300):
        n, m = int(rng.integers(1, 60)), int(rng.integers(1, 5))
        x = np.round(40 + np.cumsum(rng.normal(0, 1, (n, m)), 0) * rng.choice([0, 1, 3], m))
        tr = rng.random((n, m)) > 0.2
        x = np.where(tr, x, np.nan)
        whole = fluctuation_extrema(x, tr, 2.0)
        cuts = sorted(set(rng.integers(1, n + 1, int(rng.integers(0, 4))).tolist()) - {n})
        memory, parts, lo = None, [], 0
        for hi in cuts + [n]:
            parts.append(fluctuation_extrema(x[lo:hi], tr[lo:hi], 2.0, memory))
            memory = _extrema_memory(x[lo:hi], tr[lo:hi], 2.0, hi - lo, memory)
            lo = hi
        keep = np.ones(n, bool)
        keep[[c - 1 for c in cuts]] = False
        assert np.array_equal(np.vstack(parts)[keep], whole[keep])
        tested += int(whole[keep].sum())
    assert tested > 1000


@pytest.fixture(scope="module")
def looped(walk_dir, tmp_path_factory):
    """The 60 s session walk looped 3 times (180 s)."""
    from tests.long_walk import loop_walk

    return loop_walk(walk_dir, tmp_path_factory.mktemp("warmup") / "x3", 3)


def test_a_cut_reads_its_epochs_samples_and_fixes_at_the_whole_walks_times(looped):
    """Each 60 s segment's cut (20 s warm-up: its first NMEA epoch, IMU sample and audio sample are not the
    walk's) read with the readers alone: every GNSS epoch and IMU sample of the cut is at the whole walk's time
    bit for bit (the microsecond grid; before, the times carried the cut's first epoch in their round-off,
    ~1e-11 s), and every acoustic fix from the receiver's resumption on (10 s into the cut) is the whole walk's
    bit for bit (read with ``first_sample`` on the walk's recording, the cut starting on a whole second, not on
    the 32 s block grid). The cut states its first sample and the recording's start in walk.toml."""
    import tomllib

    from walks.reader import read_walk
    from walks.segments import RESUME_AFTER_S, WARMUP_S, walk_cuts

    assert WARMUP_S == 20.0
    whole = read_walk(looped, truth=False)
    resume, later = None, 0
    for seg in walk_cuts(looped, 60.0):
        data = read_walk(seg.directory, truth=False, resume=resume, keep_states_from_s=seg.states_from_s)
        resume = _reader_states(data, seg.states_from_s)
        tg, ti = data.gnss.positions.t_s, data.pdr.imu.t_s
        assert np.all(np.isin(tg, whole.gnss.positions.t_s)) and np.all(np.isin(ti, whole.pdr.imu.t_s))
        if seg.index == 0:
            continue
        later += 1
        audio = tomllib.loads((seg.directory / "walk.toml").read_text())["audio"]
        first = audio["first_sample"]
        assert audio["recording_start_s"] == 0.0 and first == round(audio["start_s"] * 48_000)
        assert first % 48_000 == 0 and 0 <= seg.own_from_s - first / 48_000 - WARMUP_S < 1.0
        t0 = first / 48_000 + RESUME_AFTER_S + 1.0
        a = whole.acoustic
        mine = data.acoustic.t_s >= t0
        theirs = (a.t_s >= t0) & (a.t_s <= data.acoustic.t_s[-1])
        assert mine.sum() >= 5
        assert np.array_equal(data.acoustic.t_s[mine], a.t_s[theirs])
        assert np.array_equal(data.acoustic.east_m[mine], a.east_m[theirs])
    assert later == 2


def _reader_states(data, states_from_s):
    """The readers' states a cut's read kept for the next (as walks.fuse.FusedWalk.handover takes them)."""
    from walks.reader import ReaderStates

    if not np.isfinite(states_from_s):
        return ReaderStates()
    imu = data.pdr.imu
    i = int(np.searchsorted(imu.t_s, states_from_s)) - 1
    return ReaderStates(data.pdr.result.heading.state_at(i, float(imu.t_s[i])),
                        data.acoustic.analysis.receiver_state, data.gnss.fluct_state)


def test_warm_up_by_method():
    """20 s for the methods whose resumed track needs no more (their smoothed tracks too, the UWB/PDR filters
    since their resumed run fuses the cut's first fix), 120 s as soon as one starts afresh on each cut, and every
    registered method is one or the other."""
    from walks.fuse import RESUMED_METHODS, warmup_for
    from walks.graph_methods import GRAPH_METHODS
    from walks.methods import method_names

    assert warmup_for(("adaptive_blind+lag",)) == warmup_for(("pdr", "imm+rts", "kf", "uwb")) == 20.0
    assert warmup_for(("kf", "fg_isam2")) == warmup_for(("foot_ins_fkf",)) == warmup_for(None) == 120.0
    assert warmup_for(("uwb_aoa_pdr+lag", "uwb_aoa_pdr_env", "uwb_aoa_pdr_blind+rts")) == 20.0
    assert warmup_for(("adaptive_correction",)) == 120.0    # its BP inputs reach back to the last fix
    fresh = set(GRAPH_METHODS) | {"foot_ins_fkf", "ekf_rtk_pdr", "adaptive_correction"}
    assert set(method_names()) <= RESUMED_METHODS | fresh and not RESUMED_METHODS & fresh


def test_steps_before_a_stop_do_not_depend_on_what_follows_it(site_dir, tmp_path):
    """A 600 s walk (IMU only, seed 5 on the tests' site) stands from ~371 s to ~477 s. Its steps read from the
    whole file and from the file cut at 430 s (inside the stop, as a long walk's cut ends) are the same up to
    420 s. Before, a step's prominence was measured against bases sought out to the next higher peak, across the
    stop: the last step before it (371.33 s) counted in the whole walk (its right base at 477 s) and not in the
    cut, and ``pdr`` was 0.48 m off from there at 60 s segments."""
    from features.imu.reader import read_imu_csv
    from features.imu.steps import detect_steps
    from simulation.walk import simulate_walk

    walk = simulate_walk(site_dir, tmp_path / "w5", seed=5, duration_s=600.0,
                         writers=("simulation.imu.stream:write_imu",), progress=False)
    true_steps = np.loadtxt(walk / "truth_steps.csv", delimiter=",", skiprows=1, ndmin=2)[:, 0]
    assert not np.any((true_steps > 373.0) & (true_steps < 476.0))          # the stop the cut ends in
    imu = read_imu_csv(walk / "imu.csv")
    whole = detect_steps(imu.acc_m_s2, imu.rate_hz, imu.t_s, imu.valid)
    k = imu.t_s < 430.0
    cut = detect_steps(imu.acc_m_s2[k], imu.rate_hz, imu.t_s[k], imu.valid[k])
    a, b = whole.t_s[whole.t_s < 420.0], cut.t_s[cut.t_s < 420.0]
    assert len(a) > 250 and np.array_equal(a, b)


def test_a_bouts_first_step_does_not_depend_on_the_bouts_end(site_dir, tmp_path):
    """A bout's first step has no step before it to time it by: it takes the median of its bout's next three
    intervals (by hand from the step times here), in samples for its window. Cut 6 s after a bout starts (as a
    long walk's cut ends inside a bout), the record gives that step the same duration, window and extremes as
    the whole walk. Before, it took the median of the whole bout's intervals, which the cut did not hold."""
    from features.imu.reader import read_imu_csv
    from features.imu.steps import detect_steps
    from simulation.walk import simulate_walk

    walk = simulate_walk(site_dir, tmp_path / "w5", seed=5, duration_s=600.0,
                         writers=("simulation.imu.stream:write_imu",), progress=False)
    imu = read_imu_csv(walk / "imu.csv")
    whole = detect_steps(imu.acc_m_s2, imu.rate_hz, imu.t_s, imu.valid)
    starts = np.flatnonzero(whole.bout_start)
    tested = 0
    for i in starts:
        nxt = starts[starts > i]
        if (nxt[0] if len(nxt) else len(whole)) - i < 25 or whole.t_s[i] < 5.0:
            continue                      # a long bout: its median differs from its first intervals'
        tb = whole.t_s[i]
        dt = np.diff(whole.t_s[i: i + 4])
        assert whole.duration_s[i] == np.median(dt)                       # by hand: the next three intervals
        k = imu.t_s < tb + 6.0
        cut = detect_steps(imu.acc_m_s2[k], imu.rate_hz, imu.t_s[k], imu.valid[k])
        j = int(np.flatnonzero(np.isclose(cut.t_s, tb, atol=1e-9))[0])
        assert cut.bout_start[j]
        for name in ("index", "window_start", "duration_s"):
            assert getattr(cut, name)[j] == getattr(whole, name)[i], (tb, name)
        for name in ("a_max_m_s2", "a_min_m_s2", "mean_change_m_s2"):     # the zero-phase filter's round-off
            assert abs(getattr(cut, name)[j] - getattr(whole, name)[i]) <= 1e-9, (tb, name)
        tested += 1
    assert tested >= 3


def test_a_cut_after_a_gap_in_the_log_has_the_whole_logs_windows_that_reach_back_over_it():
    """1 Hz epochs 0-29 s and 78-149 s (the receiver silent 30-77 s), tagged t − 0.5: the whole log has a
    window starting at 76 s (holding only the 78 s epoch, tag 77.5) and one at 77 s. A cut from 78 s
    resumed with the state the log's read before handed (its window grid's origin 0 s, -1 s for tags at -0.5)
    has both, with the whole log's values, and so every window from there on. Before, its first window started
    at 77 s and the window ending at 78 s was missing (the class filters took the prior there)."""
    t = np.r_[np.arange(0.0, 30.0), np.arange(78.0, 150.0)]
    rng = np.random.default_rng(3)
    sky = _sky(t, 40.0 + rng.integers(0, 6, (t.size, 3)).astype(float))
    whole = gnss_features(sky)
    assert 76.0 + 1.0 in whole["t_s"].tolist() and whole["n_epochs"][whole["t_s"] == 77.0][0] == 1
    state = fluctuation_state(sky, 60.0)
    assert state.window_origin_s == -1.0
    i = int(np.searchsorted(t, 78.0))
    resumed = gnss_features(_cut(sky, i), resume=state)
    w = whole["t_s"] >= 77.0
    assert resumed["t_s"].tolist() == whole["t_s"][w].tolist()
    for name in whole:
        np.testing.assert_allclose(resumed[name], whole[name][w], rtol=0, atol=1e-9, err_msg=name)
    # read from scratch (no state: the log's first cut) the first window holds the first epoch's tag at or
    # after its start, as before
    assert gnss_features(_cut(sky, i))["t_s"][0] == 78.0
