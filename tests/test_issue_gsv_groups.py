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
    """GPS L1 groups of 3 parts (10 satellites) whose third part is labelled with ``last_signal``."""
    out = []
    for k in range(n_epochs):
        t = f"1200{k:02d}.00"
        out.append(_s(f"GNRMC,{t},A,3000.0000,N,12000.0000,E,0.0,0.0,150624,,,A"))
        out.append(_s(f"GNGGA,{t},3000.0000,N,12000.0000,E,1,08,0.9,10.0,M,0.0,M,,"))
        out.append(_s("GNGSA,A,3,01,02,03,04,05,06,07,08,,,,,1.5,0.9,1.2,1"))
        sats = [f"{p:02d},{10 + 5 * p},{20 * p:03d},{30 + p}" for p in range(1, 11)]
        parts = [sats[0:4], sats[4:8], sats[8:10]]
        for i, part in enumerate(parts, start=1):
            if i == drop_part:
                continue
            sig = last_signal if i == 3 else "1"
            out.append(_s(f"GPGSV,3,{i},10,{','.join(part)},{sig}"))
        # a genuine second signal group (L5, signal 8) of one part
        out.append(_s("GPGSV,1,1,02,01,15,020,28,02,20,040,29,8"))
    return "".join(out).encode()


def test_last_part_under_another_signal_is_joined_not_incomplete():
    stats = ReadStats()
    epochs = epochs_from_bytes(_lc79d(60), stats)
    assert len(epochs) == 60
    assert stats.gsv_incomplete == 0 and stats.gsv_signal_continued == 60
    assert "incomplete" not in stats.summary() and "joined" in stats.summary()
    sats = {(s.prn, s.signal) for s in epochs[0].satellites}
    assert {(9, 1), (10, 1)} <= sats and (9, 8) not in sats      # parts 3 belong to the L1 group
    assert {(1, 8), (2, 8)} <= sats                               # the real L5 group is kept apart
    assert len(epochs[0].satellites) == 12


def test_a_really_missing_part_is_still_incomplete():
    stats = ReadStats()
    epochs_from_bytes(_lc79d(5, drop_part=2), stats)
    assert stats.gsv_incomplete == 5 and stats.gsv_signal_continued == 0


def test_same_signal_groups_unchanged():
    stats = ReadStats()
    epochs_from_bytes(_lc79d(5, last_signal="1"), stats)
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
