"""Issue 20, Deliver 4: mutated NMEA through the reader and the GNSS feature/fix path.

The fast version of ``bench/fuzz_nmea.py`` (which runs 10⁶ lines): a few thousand hypothesis-drawn
mutated lines (tests/nmea_fuzz.py) must give no unexpected exception, no warning, no non-finite output,
no disagreement between the reader's three paths and no hang. Then one test per crash or silent wrong
answer the fuzz runs found, each on hand-written lines.
"""

from __future__ import annotations

import datetime as dt
import json
from functools import reduce

import numpy as np
import pytest

from features.errors import DataError
from features.gnss.features import fit_cn0_reference
from features.gnss.gpsd import gpsd_json_lines, iso_utc_ms
from features.gnss.nmea import ReadStats, epochs_from_bytes, iter_epochs
from features.gnss.positions import fixes_to_enu
from tests.nmea_fuzz import fuzz


def _s(body: str) -> str:
    return "$%s*%02X" % (body, reduce(lambda a, c: a ^ c, body.encode("latin-1"), 0))


GGA = "GPGGA,120000.00,3000.0000,N,12000.0000,E,1,08,0.9,10.0,M,5.0,M,,"


def _all_paths(lines):
    """Epochs and stats by the whole-file, streaming and pynmea2 paths (the first two must be equal)."""
    buf = ("\n".join(lines) + "\n").encode("latin-1")
    s_whole, s_line = ReadStats(), ReadStats()
    whole = epochs_from_bytes(buf, s_whole)
    line = list(iter_epochs(buf.split(b"\n")[:-1], s_line))
    ref = list(iter_epochs(buf.split(b"\n")[:-1], ReadStats(), parser="pynmea2"))
    assert whole == line == ref and s_whole == s_line
    return whole, s_whole


def test_a_few_thousand_mutated_lines_pass_cleanly():
    tally, _, _ = fuzz(3000, rng_seed=20, progress=False)
    assert tally.lines >= 3000 and tally.batches >= 30
    assert tally.failures == [] and tally.hangs == 0
    # the run reached the interpreters: sentences were skipped and counted, and files without a usable
    # epoch raised the reader's typed error
    assert tally.skipped_sentences > 100 and tally.typed_errors.get("NmeaError", 0) > 0 and tally.epochs > 100


def test_star_inside_a_field_is_malformed_not_data():
    """'*' is the checksum delimiter: ``$GNRMC,...,**A,...*04`` was read with status "**A" by the fast path
    (checksum taken after the last '*') and rejected by pynmea2 (after the first)."""
    epochs, stats = _all_paths([_s(GGA), _s("GNRMC,120000.00,**A,3000.0000,N,12000.0000,E,0.0,,150624,,,A"),
                                _s(GGA.replace("120000", "120001"))])
    assert stats.malformed == 1 and len(epochs) == 2 and epochs[0].time_utc is None


def test_only_five_character_addresses_are_read():
    """``GabcdefLGSV`` (bytes inserted into the address) was read as a GSV of talker "Ga", ``GbGSV`` (one
    flipped bit) as GPS by us and as BeiDou by pynmea2 (which upper-cases it): both are garbage now."""
    lines = [_s(GGA), _s("GabcdefLGSV,1,1,01,87,14,030,40,3"), _s("GbGSV,1,1,01,35,50,045,41,1"),
             _s("GBGSV,1,1,01,08,20,135,33,1")]
    epochs, stats = _all_paths(lines)
    assert [(s.system, s.prn) for s in epochs[0].satellites] == [("BeiDou", 8)]
    assert stats.other_types["GabcdefL"] == 1 and stats.truncated == 1


@pytest.mark.parametrize("alt,n_used", [("inf", "08"), ("1e400", "08"), ("nan", "08"), ("10.0", "9" * 400),
                                        ("-1e308", "08")])
def test_non_finite_or_absurd_gga_numbers_are_malformed(alt, n_used):
    """Python's float() reads "inf" / "nan" / "1e400"; GGA's altitude became inf and every ENU position NaN,
    JSON output "Infinity"; a 400-digit satellite count overflowed numpy (OverflowError)."""
    bad = GGA.replace(",10.0,", f",{alt},").replace(",08,", f",{n_used},")
    epochs, stats = _all_paths([_s(bad), _s(GGA.replace("120000", "120001"))])
    assert stats.malformed == 1 and [e.fix.alt_m for e in epochs] == [10.0]
    pos = fixes_to_enu(epochs, 30.0, 120.0, 10.0)
    assert np.isfinite(pos.up_m).all() and len(pos) == 1
    json.loads(gpsd_json_lines(epochs).splitlines()[0])


def test_zda_year_9999_crossing_midnight_does_not_overflow():
    """The day after 9999-12-31 is no date: the reader raised OverflowError; now the epoch has no date."""
    lines = [_s("GPZDA,235959.00,31,12,9999,00,00"), _s(GGA.replace("120000", "235959")),
             _s(GGA.replace("120000", "000000"))]
    epochs, stats = _all_paths(lines)
    assert [e.time_utc for e in epochs] == [dt.datetime(9999, 12, 31, 23, 59, 59, tzinfo=dt.timezone.utc), None]
    assert stats.skipped == 0


def test_zda_year_before_gps_time_is_malformed_and_iso_times_keep_four_digit_years():
    epochs, stats = _all_paths([_s("GPZDA,120000.00,01,01,0001,00,00"), _s(GGA)])
    assert stats.malformed == 1 and epochs[0].time_utc is None
    assert iso_utc_ms(dt.datetime(812, 3, 4, 5, 6, 7, 890000, tzinfo=dt.timezone.utc)) == "0812-03-04T05:06:07.890Z"


def test_an_implausible_fitted_reference_is_a_data_error():
    """Two elevation bins whose C/N0 falls steeply with elevation fit a line whose intercept exceeds 80 dB-Hz: it was
    a ConfigError (a settings problem, exit 2) raised from the data; now a DataError naming the fit."""
    el = np.r_[np.full(30, 15.0), np.full(30, 85.0)]
    cn0 = np.r_[np.full(30, 75.0), np.full(30, 1.0)]  # a + b·sin(el) through both: a ≈ 101 dB-Hz
    with pytest.raises(DataError, match="implausible"):
        fit_cn0_reference(el, cn0)


@pytest.mark.parametrize("digits", [" 6", "+6", "6\t0", "06 "])
def test_checksum_must_be_two_hex_digits(digits):
    """The 10⁶-line run found ``...*␠6`` and ``...*0\\r\\t0`` accepted by the streaming path (Python's
    int(" 6", 16) is 6) and refused by the whole-file path: only the last is a checksum (trailing
    whitespace ends a line)."""
    body = "GNGSA,A,3,13,12,22,19,08,21,,,,,,,1.19,0.71,0.96,4"
    assert reduce(lambda a, c: a ^ c, body.encode(), 0) == int(digits[:2], 16) == 6
    forged = f"${body}*{digits}"
    stats = ReadStats()
    list(iter_epochs([_s(GGA), forged], stats))
    whole = ReadStats()
    epochs_from_bytes(f"{_s(GGA)}\n{forged}\n".encode(), whole)
    assert stats == whole
    assert stats.bad_checksum == (0 if digits == "06 " else 1) and stats.used_sentences == (2 if digits == "06 " else 1)
