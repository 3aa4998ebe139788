"""Issue 20, "A real-data regression": a GSV part continuing a group under another signal id overwrote the
first signal's entries with the second's.

Dual-frequency receivers (Quectel LC79D in gpsd's ``test/daemon/quectelLC79D.log``) number one GSV group
across their untagged L1 entries and the tagged L5 / E5a entries of the same PRNs that follow. The reader
joined such a part to the open group *and relabelled its entries with the group's signal*, so PRN 6's L5
entry (no elevation, no azimuth, another C/N0) replaced its L1 entry and the L5 entries disappeared. gpsd
keeps one entry per satellite per signal; so does the reader now, and the features read one stated signal
per satellite, the primary (L1/E1/B1) one.

The group below is written by hand (checksums verified here by an XOR of their own); every expected entry is
worked out from the sentences. gpsd 3.22's ``gpsdecode -j`` on the same lines lists the same 18 entries in the
same order with the same elevation, azimuth and C/N0 (it does not read the GSA system-id field, so its
``used`` flags differ for the Galileo and BeiDou entries; newer gpsd reads it).
"""

from __future__ import annotations

import math
from functools import reduce

import numpy as np
import pytest

from features.gnss.features import sky_arrays
from features.gnss.nmea import ReadStats, epochs_from_bytes, iter_epochs, read_nmea
from features.gnss.positions import epoch_attenuation, sky_attenuation

LINES = [
    "$GNRMC,093000.00,A,3000.0000,N,12000.0000,E,0.0,0.0,150624,,,A*4E",
    "$GNGGA,093000.00,3000.0000,N,12000.0000,E,1,08,0.9,10.0,M,0.0,M,,*78",
    "$GNGSA,A,3,02,05,07,09,,,,,,,,,1.5,0.9,1.2,1*36",          # GPS used: 2 5 7 9
    "$GNGSA,A,3,11,12,,,,,,,,,,,1.5,0.9,1.2,3*3E",              # Galileo used: 11 12
    "$GNGSA,A,3,19,20,,,,,,,,,,,1.5,0.9,1.2,4*30",              # BeiDou used: 19 20
    # one GPS group of 10 entries: parts 1-2 untagged (L1), part 3 tagged 8 (L5-Q) re-listing PRNs 2 5 7 9
    "$GPGSV,3,1,10,02,45,050,44,05,30,120,38,07,62,210,47,09,15,300,31*7D",
    "$GPGSV,3,2,10,13,08,020,,20,25,270,35*77",
    "$GPGSV,3,3,10,02,,,41,05,,,,07,,,45,09,,,28,8*6B",
    # Galileo: the group's last part tagged 1 (E5a) re-lists both satellites (the LC79D's own pattern)
    "$GAGSV,2,1,04,11,50,100,42,12,35,200,39*60",
    "$GAGSV,2,2,04,11,,,44,12,,,36,1*77",
    # BeiDou, u-blox style: one group per signal, B1I (1) then B2I (B = 11); PRN 20 tracked on B2I only
    "$GBGSV,1,1,02,19,60,080,45,20,40,160,,1*72",
    "$GBGSV,1,1,02,19,60,080,43,20,40,160,30,B*04",
    "$GNRMC,093001.00,A,3000.0000,N,12000.0000,E,0.0,0.0,150624,,,A*4F",
]

# (system, prn, signal, el, az, C/N0, used) in GSV order. "used" = named by the system's GSA and tracked
# on that signal (GPS 20 is not in GPS's GSA; GPS 5 and BeiDou 20 are untracked on L5 / B1I).
EXPECTED = [
    ("GPS", 2, None, 45.0, 50.0, 44.0, True), ("GPS", 5, None, 30.0, 120.0, 38.0, True),
    ("GPS", 7, None, 62.0, 210.0, 47.0, True), ("GPS", 9, None, 15.0, 300.0, 31.0, True),
    ("GPS", 13, None, 8.0, 20.0, None, False), ("GPS", 20, None, 25.0, 270.0, 35.0, False),
    ("GPS", 2, 8, None, None, 41.0, True), ("GPS", 5, 8, None, None, None, False),
    ("GPS", 7, 8, None, None, 45.0, True), ("GPS", 9, 8, None, None, 28.0, True),
    ("Galileo", 11, None, 50.0, 100.0, 42.0, True), ("Galileo", 12, None, 35.0, 200.0, 39.0, True),
    ("Galileo", 11, 1, None, None, 44.0, True), ("Galileo", 12, 1, None, None, 36.0, True),
    ("BeiDou", 19, 1, 60.0, 80.0, 45.0, True), ("BeiDou", 20, 1, 40.0, 160.0, None, False),
    ("BeiDou", 19, 11, 60.0, 80.0, 43.0, True), ("BeiDou", 20, 11, 40.0, 160.0, 30.0, True),
]

# The primary entries, one per satellite: GPS and Galileo untagged (L1 / E1), BeiDou B1I (id 1).
PRIMARY = [EXPECTED[k] for k in (0, 1, 2, 3, 4, 5, 10, 11, 14, 15)]


def _rows(sats):
    return [(s.system, s.prn, s.signal, s.el_deg, s.az_deg, s.cn0_dbhz, s.used) for s in sats]


def _epoch(lines=LINES, stats=None):
    return epochs_from_bytes(("\n".join(lines) + "\n").encode(), stats)[0]


def test_hand_written_lines_carry_valid_checksums():
    for line in LINES:
        body, given = line[1:].split("*")
        assert reduce(lambda a, c: a ^ c, body.encode(), 0) == int(given, 16), line


def test_every_signal_keeps_its_own_entry():
    stats = ReadStats()
    e = _epoch(stats=stats)
    assert stats.skipped == 0 and stats.gsv_incomplete == 0
    assert stats.gsv_signal_continued == 2     # GPS part 3 and Galileo part 2 complete their groups
    assert _rows(e.satellites) == EXPECTED
    assert (e.n_in_view, e.n_tracked) == (10, 9)  # distinct satellites; tracked on any signal


def test_same_entries_through_pynmea2_and_the_line_path():
    e_fast = list(iter_epochs(LINES))[0]
    e_ref = list(iter_epochs(LINES, parser="pynmea2"))[0]
    assert _rows(e_fast.satellites) == _rows(e_ref.satellites) == EXPECTED


def test_the_l5_part_never_overwrites_l1_whatever_the_order():
    """The L5 part first and the L1 parts after it (a receiver listing the other way round): same entries."""
    gps = LINES[5:8]
    reordered = LINES[:5] + [gps[2].replace("3,3,10", "3,1,10"), gps[0].replace("3,1,10", "3,2,10"),
                             gps[1].replace("3,2,10", "3,3,10")] + LINES[8:]
    fixed = []
    for line in reordered:
        body = line[1:line.index("*")]
        fixed.append("$%s*%02X" % (body, reduce(lambda a, c: a ^ c, body.encode(), 0)))
    e = _epoch(fixed)
    assert sorted(_rows(e.satellites), key=str) == sorted(EXPECTED, key=str)
    assert _rows(e.primary_satellites) == PRIMARY


def test_features_read_one_primary_signal_per_satellite():
    e = _epoch()
    assert _rows(e.primary_satellites) == PRIMARY
    sky = sky_arrays([e])
    assert sky.sat_keys == tuple((r[0], r[1]) for r in PRIMARY)
    # C/N0 of the primary signal, not the best of the satellite's signals (GPS 7: 47 on L1, not L5's 45;
    # Galileo 11: 42 on E1, not E5a's 44); BeiDou 20 untracked on B1I although B2I tracks it at 30
    want_cn0 = [44.0, 38.0, 47.0, 31.0, np.nan, 35.0, 42.0, 39.0, 45.0, np.nan]
    np.testing.assert_array_equal(sky.cn0_dbhz[0], want_cn0)
    np.testing.assert_array_equal(sky.el_deg[0], [45, 30, 62, 15, 8, 25, 50, 35, 60, 40])
    np.testing.assert_array_equal(sky.used[0], [True] * 4 + [False, False, True, True, True, False])


def _cref_dbhz(el_deg: float) -> float:
    """docs/design.md §6 open-sky line through 38 dB-Hz at 5° and 50 dB-Hz at zenith, linear in sin(el)."""
    s5 = math.sin(math.radians(5.0))
    return 38.0 + 12.0 * (math.sin(math.radians(el_deg)) - s5) / (1.0 - s5)


def test_invisible_ratio_and_attenuation_by_hand():
    e = _epoch()
    # ζ above the 10° mask: GPS 2 5 7 9 20, Galileo 11 12, BeiDou 19 20 in view (GPS 13 at 8° is below);
    # BeiDou 20 is not tracked on B1I -> 1/9. (Reading "tracked on any signal" gave 0; the old
    # overwrite left GPS 2 5 7 9 and Galileo without elevation: 0 of 3.)
    att, g, zeta = sky_attenuation(sky_arrays([e]))
    assert zeta[0] == pytest.approx(1.0 / 9.0, abs=1e-12)
    # attenuation of the used, tracked primary entries: GPS 2 5 7 9, Galileo 11 12, BeiDou 19
    used = [(45.0, 44.0), (30.0, 38.0), (62.0, 47.0), (15.0, 31.0), (50.0, 42.0), (35.0, 39.0), (60.0, 45.0)]
    a = [max(0.0, _cref_dbhz(el) - cn0) for el, cn0 in used]
    assert att[0] == pytest.approx(sum(a) / len(a), abs=1e-9)
    assert g[0] == pytest.approx(math.sqrt(sum(10 ** (x / 10) for x in a) / len(a)), rel=1e-9)
    assert epoch_attenuation(e) == pytest.approx((att[0], g[0]), rel=1e-12)


def test_an_empty_signal_id_does_not_outrank_a_stated_primary_signal():
    """The u-blox ZED-F9P of gpsd's log writes its B2I BeiDou group with an empty signal-id field
    (``$GBGSV,3,1,10,01,29,321,,...,*49``) after the B1I group tagged 1. An unstated signal ranks after a
    stated primary one, so the features read B1I (tracked, 45 dB-Hz), not the untracked B2I listing."""
    lines = LINES[:2] + ["$GNGSA,A,3,19,20,,,,,,,,,,,1.5,0.9,1.2,4*30", "$GBGSV,1,1,02,19,60,080,45,20,40,160,,1*72",
                         "$GBGSV,1,1,02,19,60,080,,20,40,160,,*42", LINES[-1]]
    for line in lines[2:5]:
        body, given = line[1:].split("*")
        assert reduce(lambda a, c: a ^ c, body.encode(), 0) == int(given, 16)
    e = _epoch(lines)
    assert _rows(e.satellites) == [("BeiDou", 19, 1, 60.0, 80.0, 45.0, True), ("BeiDou", 20, 1, 40.0, 160.0, None, False),
                                   ("BeiDou", 19, None, 60.0, 80.0, None, False),
                                   ("BeiDou", 20, None, 40.0, 160.0, None, False)]
    assert _rows(e.primary_satellites) == _rows(e.satellites)[:2]
    # on gpsd's real log: every BeiDou satellite read on B1I, none on the unstated group
    from tests.conftest import shared_data

    epochs, _ = read_nmea(shared_data("nmea", "gpsd", "ublox-zed-f9p-nmea.log"))
    signals = {(s.system, s.signal) for ep in epochs for s in ep.primary_satellites}
    assert signals == {("GPS", 1), ("GLONASS", 1), ("Galileo", 7), ("BeiDou", 1)}
