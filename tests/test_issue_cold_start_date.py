"""Issue 11 (smaller): ``epochs_on_time_base`` no longer trusts the first dated epoch, which after
a cold start can carry a bogus date (here 1980-01-06, the GPS epoch many receivers start from).

Before: the two bogus epochs set the shift, and every epoch's t_s was off by 44 years
(1.4e9 s). After: the median shift of all dated epochs; t_s of the walk's first true second is 0.
"""

from __future__ import annotations

import datetime as dt
import functools

import pytest

from features.gnss.nmea import epochs_on_time_base, read_nmea


def _s(body: str) -> str:
    return f"${body}*{functools.reduce(lambda x, ch: x ^ ord(ch), body, 0):02X}\r\n"


def test_bogus_cold_start_date_is_outvoted(tmp_path):
    lines = []
    for k in range(10):
        hhmmss = f"1200{k:02d}.00"
        date = "060180" if k < 2 else "150624"                 # cold start: 1980-01-06, then the real date
        lines.append(_s(f"GNRMC,{hhmmss},A,3000.00000,N,12000.00000,E,0.01,,{date},,,D,V"))
        lines.append(_s(f"GNGGA,{hhmmss},3000.00000,N,12000.00000,E,1,05,1.20,15.0,M,5.0,M,,"))
    p = tmp_path / "cold.nmea"
    p.write_text("".join(lines))
    epochs, _ = read_nmea(p)
    assert len(epochs) == 10 and epochs[0].time_utc.year == 1980
    start = dt.datetime(2024, 6, 15, 12, 0, 0, tzinfo=dt.timezone.utc)
    shifted = epochs_on_time_base(epochs, start)
    assert [e.t_s for e in shifted] == pytest.approx(list(range(10)), abs=1e-6)
