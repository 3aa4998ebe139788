"""Issue 12 item 7: GSV groups whose last part carries another signal id (Quectel LC79D) are not
"incomplete", and a file with satellites in view but no time says so instead of "no satellites in view"."""

from __future__ import annotations

from functools import reduce

import pytest

from features.errors import NmeaError
from features.gnss.nmea import epochs_from_bytes, read_nmea
from features.gnss.tokens import ReadStats
from pipeline.cli import main


def _s(body: str) -> str:
    return f"${body}*{reduce(lambda a, c: a ^ ord(c), body, 0):02X}\n"


def _lc79d(n_epochs: int, last_signal: str = "8", drop_part: int | None = None) -> bytes:
    """GPS groups of 3 parts as the Quectel LC79D numbers them (gpsd's ``test/daemon/quectelLC79D.log``):
    parts 1-2 untagged (L1, PRNs 1-7 with elevation and azimuth), part 3 tagged ``last_signal`` re-listing
    PRNs 1-3 on L5 without elevation or azimuth; 10 entries in the group. Then a separately numbered
    L5 group (signal 8) of PRNs 4 and 5."""
    out = []
    for k in range(n_epochs):
        t = f"1200{k:02d}.00"
        out.append(_s(f"GNRMC,{t},A,3000.0000,N,12000.0000,E,0.0,0.0,150624,,,A"))
        out.append(_s(f"GNGGA,{t},3000.0000,N,12000.0000,E,1,08,0.9,10.0,M,0.0,M,,"))
        out.append(_s("GNGSA,A,3,01,02,03,04,05,06,07,,,,,,1.5,0.9,1.2,1"))
        l1 = [f"{p:02d},{10 + 5 * p},{20 * p:03d},{30 + p}" for p in range(1, 8)]
        l5 = [f"{p:02d},,,{20 + p}" for p in range(1, 4)]
        parts = [(l1[0:4], ""), (l1[4:7], ""), (l5, "," + last_signal)]
        for i, (part, sig) in enumerate(parts, start=1):
            if i != drop_part:
                out.append(_s(f"GPGSV,3,{i},10,{','.join(part)}{sig}"))
        out.append(_s("GPGSV,1,1,02,04,30,080,26,05,35,100,27,8"))
    return "".join(out).encode()


def test_last_part_under_another_signal_is_joined_not_incomplete():
    """The group is complete (its numbering spans both signals), and every entry keeps its own signal:
    PRNs 1-3 have an L1 entry (from parts 1-2) and an L5 entry (part 3), neither overwriting the other."""
    stats = ReadStats()
    epochs = epochs_from_bytes(_lc79d(60), stats)
    assert len(epochs) == 60
    assert stats.gsv_incomplete == 0 and stats.gsv_signal_continued == 60
    assert "incomplete" not in stats.summary() and "joined" in stats.summary()
    got = [(s.prn, s.signal, s.el_deg, s.az_deg, s.cn0_dbhz, s.used) for s in epochs[0].satellites]
    assert got == [
        (1, None, 15.0, 20.0, 31.0, True), (2, None, 20.0, 40.0, 32.0, True), (3, None, 25.0, 60.0, 33.0, True),
        (4, None, 30.0, 80.0, 34.0, True), (5, None, 35.0, 100.0, 35.0, True), (6, None, 40.0, 120.0, 36.0, True),
        (7, None, 45.0, 140.0, 37.0, True),
        (1, 8, None, None, 21.0, True), (2, 8, None, None, 22.0, True), (3, 8, None, None, 23.0, True),
        (4, 8, 30.0, 80.0, 26.0, True), (5, 8, 35.0, 100.0, 27.0, True),
    ]
    # the features read each satellite on L1: the 7 untagged entries, nothing from L5
    assert [(s.prn, s.signal) for s in epochs[0].primary_satellites] == [(p, None) for p in range(1, 8)]


def test_a_really_missing_part_is_still_incomplete():
    stats = ReadStats()
    epochs_from_bytes(_lc79d(5, drop_part=2), stats)
    assert stats.gsv_incomplete == 5 and stats.gsv_signal_continued == 0


def test_same_signal_groups_unchanged():
    stats = ReadStats()
    epochs_from_bytes(_lc79d(5, last_signal=""), stats)  # all three parts untagged
    assert stats.gsv_incomplete == 0 and stats.gsv_signal_continued == 0


def test_sky_only_file_says_satellites_but_no_time(tmp_path, capsys):
    p = tmp_path / "sky.nmea"
    p.write_bytes(b"".join(line.encode() for line in
                           [_s("GPGSV,1,1,02,01,15,020,28,02,20,040,29,1")] * 4))
    with pytest.raises(NmeaError, match="4 GSV sentences list satellites in view, but no sentence carries a time"):
        read_nmea(p)
    assert main(["features", "gnss", str(p), "--out", str(tmp_path / "f.csv")]) == 1
    err = capsys.readouterr().err
    assert "no satellites in view" not in err and "carries a time" in err


def test_real_logs_are_read_as_before():
    """On gpsd's 14 receiver logs no group is joined across signal ids, and the only incomplete groups are
    the cold-start log's 2 (counts measured before and after the change: identical)."""
    from tests.conftest import shared_data

    gpsd = shared_data("nmea", "gpsd")
    incomplete, joined = {}, 0
    for f in sorted(gpsd.glob("*.log")):
        _, stats = read_nmea(f)
        incomplete[f.name] = stats.gsv_incomplete
        joined += stats.gsv_signal_continued
    assert joined == 0
    assert {k: v for k, v in incomplete.items() if v} == {"gp-320fw-2019-04-07-coldboot.log": 2}
