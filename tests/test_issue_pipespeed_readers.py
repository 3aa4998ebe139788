"""Issue 25 item 1 (the readers): the compiled NMEA assembly, the columnar GNSS stream and the compiled IMU CSV
parser give exactly what the Python reference paths give.

References, independent of the compiled code: Python's own ``float()`` (correctly rounded), the Python
assembler (:func:`features.gnss.nmea.iter_epochs`, which the pynmea2 tokeniser also feeds), the Python
:attr:`~features.gnss.nmea.Epoch.primary_satellites`, a dense loop over epoch objects for the sky arrays,
numpy's ``loadtxt`` for the IMU table.
"""

from __future__ import annotations

import random
from functools import reduce

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from features.errors import NmeaError
from features.gnss import nmea
from features.gnss.assemble import EpochColumns, assemble_spans, primary_rows
from features.gnss.features import sky_arrays
from features.gnss.nmea import (ReadStats, epoch_columns, epochs_from_bytes, epochs_on_time_base, iter_epochs,
                                read_nmea, read_nmea_columns)
from features.gnss.positions import fixes_to_enu
from features.gnss.tokens import sentence_spans
from features.imu import reader as imu_reader
from features.numtext import EMPTY, FALLBACK, INVALID, OK, read_csv_table, read_float, read_int
from tests.conftest import SHARED_DATA

SHARED = SHARED_DATA / "nmea"


def _logs():
    files = sorted(SHARED.glob("*/*.log")) + sorted(SHARED.glob("*/*.nmea"))
    if not files:
        pytest.skip(f"real NMEA logs not found under {SHARED}")
    return files


def _s(body: str) -> str:
    return "$%s*%02X" % (body, reduce(lambda a, c: a ^ c, body.encode("latin-1"), 0))


def _status(buf: bytes) -> int:
    starts, ends = sentence_spans(buf, ReadStats(), True)
    return int(assemble_spans(np.frombuffer(buf, dtype=np.uint8), starts, ends, 5)[0])


# ---------------------------------------------------------------- decimal numbers


def _text(s: str) -> np.ndarray:
    return np.frombuffer(s.encode("latin-1"), dtype=np.uint8)


@settings(max_examples=3000, deadline=None, derandomize=True)
@given(st.sampled_from(["", "-", "+"]), st.text("0123456789", min_size=0, max_size=9),
       st.booleans(), st.text("0123456789", min_size=0, max_size=12))
def test_canonical_decimals_read_as_python_float_bit_for_bit(sign, whole, dot, frac):
    text = sign + whole + ("." if dot else "") + (frac if dot else "")
    status, value = read_float(_text(text), 0, len(text))
    if not text:
        assert status == EMPTY
        return
    try:
        expected = float(text)
    except ValueError:
        assert status == INVALID, text        # '-', '.', '+.': Python refuses them too
        return
    significant = len((whole + (frac if dot else "")).lstrip("0"))
    if significant > 15:
        assert status == FALLBACK             # beyond the fast path: left to Python
        return
    assert status == OK, text
    assert value == expected and np.signbit(value) == np.signbit(expected), (text, value, expected)


def test_decimals_that_need_correct_rounding():
    # values where summing digit by digit (0.1 + 0.02 + ...) or multiplying by 0.1 misrounds
    for text in ("0.1", "0.3", "2.675", "1.005", "900719925474.099", "123456.789012", "0.000000000000000000001",
                 "4916.45", "3112.0213817", "-0.0", "359.99999999"):
        status, value = read_float(_text(text), 0, len(text))
        assert status == OK and value == float(text) and np.signbit(value) == np.signbit(float(text)), text


@pytest.mark.parametrize("text", ["1e3", "nan", "inf", " 1", "1 ", "1_0", "1.0e2", "9" * 16, "0." + "1" * 23,
                                  "Infinity", "\xa01"])
def test_spellings_only_python_decides_are_left_to_python(text):
    assert read_float(_text(text), 0, len(text))[0] == FALLBACK


@pytest.mark.parametrize("text,expected", [("", EMPTY), ("1.2.3", INVALID), ("1-2", INVALID), (".", INVALID),
                                           ("+-1", INVALID), ("0x1F", INVALID), ("\xb2", INVALID), ("12W", INVALID)])
def test_spellings_python_refuses_are_refused(text, expected):
    assert read_float(_text(text), 0, len(text))[0] == expected
    if text:
        with pytest.raises(ValueError):
            float(text)


def test_integers_take_digits_only():
    assert read_int(_text("0042"), 0, 4) == (OK, 42)
    assert read_int(_text("+5"), 0, 2)[0] == FALLBACK      # int("+5") is 5: Python decides
    assert read_int(_text("1_0"), 0, 3)[0] == FALLBACK
    for text in ("1.5", "A", "\xb2", "0x1"):                # int() refuses these
        assert read_int(_text(text), 0, len(text))[0] == INVALID
        with pytest.raises(ValueError):
            int(text)
    assert read_int(_text(""), 0, 0)[0] == EMPTY
    assert read_int(_text("9" * 17), 0, 17) == (OK, 10 ** 17 - 1)
    assert read_int(_text("9" * 18), 0, 18)[0] == FALLBACK   # Python's int() refuses > 4,300 digits: it decides


# ---------------------------------------------------------------- NMEA: compiled assembly vs the Python assembler


def test_every_shared_log_is_assembled_compiled_and_equals_the_python_assembler():
    compiled = 0
    for path in _logs():
        buf = path.read_bytes()
        s_fast, s_ref = ReadStats(), ReadStats()
        fast = epochs_from_bytes(buf, s_fast)
        ref = list(iter_epochs(buf.splitlines(keepends=True), s_ref))
        assert fast == ref and s_fast == s_ref, path.name
        compiled += _status(buf) == 0
    # none of the real receivers' logs needs Python's number parsing
    assert compiled == len(_logs())


def _mutated_line(rng: random.Random, line: str) -> str:
    """A real sentence with one field replaced by a canonical token (still read compiled), re-signed."""
    body = line[1:line.rindex("*")]
    fields = body.split(",")
    k = rng.randrange(1, len(fields)) if len(fields) > 1 else 0
    fields[k] = rng.choice(["", "0", "00", "-0", "-1", "1", "9", "99", "100", "360", "361", "-91", "91", "999",
                            "1.5.2", ".", "-", "000000", "235959.99", "240000", "235960", "999999", "010100",
                            "311299", "290223", "000000.", "9999", "0000", "4916.45", "18000.00001", "9000.0000",
                            "12000.00", "A", "V", "N", "S", "E", "W", "M", "F", "10", "16", "4", "1980", "2079"])
    if rng.random() < 0.1:
        del fields[k]
    return _s(",".join(fields))


def test_mutated_real_sentences_compiled_equal_the_python_assembler():
    """Thousands of re-signed mutations of real sentences with tokens the compiled path decides itself:
    malformed fields, out-of-range numbers, times and dates at the edges, missing fields."""
    lines = [ln for p in _logs() for ln in p.read_text("latin-1").splitlines() if ln.startswith("$") and "*" in ln]
    rng = random.Random(25)
    compiled = 0
    for _ in range(400):
        start = rng.randrange(len(lines) - 40)
        batch = [(_mutated_line(rng, ln) if rng.random() < 0.3 else ln) for ln in lines[start:start + 40]]
        if rng.random() < 0.2:
            rng.shuffle(batch)
        buf = ("\n".join(batch) + "\n").encode("latin-1")
        s_fast, s_ref = ReadStats(), ReadStats()
        fast = epochs_from_bytes(buf, s_fast)
        ref = list(iter_epochs(buf.split(b"\n")[:-1], s_ref))
        assert fast == ref and s_fast == s_ref, buf
        compiled += _status(buf) == 0
    # about half the batches hold a signed integer ("-1" as a count), which only Python's int() decides
    assert compiled >= 200  # the compiled path decided them, not the fallback


def test_a_non_canonical_number_sends_the_file_to_the_python_assembler():
    gga = "GPGGA,120000.00,3000.0000,N,12000.0000,E,1,08,0.9,1e1,M,5.0,M,,"   # altitude 1e1: Python reads 10.0
    buf = (_s(gga) + "\n").encode()
    assert _status(buf) != 0
    epochs = epochs_from_bytes(buf)
    assert epochs[0].fix.alt_m == 10.0 and epochs == list(iter_epochs(buf.splitlines()))


def test_primary_signals_compiled_equal_the_epoch_property():
    for path in _logs():
        try:
            epochs, _ = read_nmea(path)
        except NmeaError:
            continue
        cols = epoch_columns(epochs)
        rows, counts = primary_rows(cols)
        k = 0
        for e, c in zip(epochs, counts.tolist()):
            expected = [(s.system, s.prn, s.signal) for s in e.primary_satellites]
            got = [(nmea.SYSTEM_CODES[s], p, None if g < 0 else g) for s, p, g, _ in cols.sat_i[rows[k:k + c]].tolist()]
            assert got == expected, path.name
            k += c


def _dense_sky(epochs):
    """The sky arrays by a plain loop over epoch objects (the reference)."""
    sky = [e for e in epochs if e.sky_reported]
    keys: list = []
    for e in sky:
        for s in e.primary_satellites:
            if (s.system, s.prn) not in keys:
                keys.append((s.system, s.prn))
    el = np.full((len(sky), len(keys)), np.nan)
    az, cn0 = el.copy(), el.copy()
    used = np.zeros(el.shape, bool)
    for i, e in enumerate(sky):
        for s in e.primary_satellites:
            j = keys.index((s.system, s.prn))
            el[i, j] = np.nan if s.el_deg is None else s.el_deg
            az[i, j] = np.nan if s.az_deg is None else s.az_deg
            cn0[i, j] = np.nan if s.cn0_dbhz is None else s.cn0_dbhz
            used[i, j] = s.used
    return tuple(keys), el, az, cn0, used, np.array([e.t_s for e in sky])


def test_reader_columns_give_the_epochs_sky_arrays_and_fixes():
    for path in _logs():
        try:
            epochs, s_obj = read_nmea(path)
        except NmeaError:
            with pytest.raises(NmeaError):
                read_nmea_columns(path)
            continue
        cols, s_cols = read_nmea_columns(path)
        assert isinstance(cols, EpochColumns) and s_cols == s_obj
        assert nmea._epochs_from_columns(cols) == epochs
        assert nmea._epochs_from_columns(epoch_columns(epochs)) == epochs  # objects -> columns -> objects
        sky = sky_arrays(cols)
        keys, el, az, cn0, used, t = _dense_sky(epochs)
        assert sky.sat_keys == keys
        for got, want in ((sky.el_deg, el), (sky.az_deg, az), (sky.cn0_dbhz, cn0), (sky.t_s, t)):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(sky.used, used)
        a = fixes_to_enu(cols, 30.0, 120.0, 10.0)
        b = fixes_to_enu(epochs, 30.0, 120.0, 10.0, sky=sky_arrays(epochs))
        for name in ("t_s", "east_m", "north_m", "up_m", "sigma_east_m", "sigma_north_m", "sigma_up_m", "quality",
                     "n_used", "hdop", "sigma_source", "invisible_ratio"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=f"{path.name} {name}")
        if any(e.time_utc is not None for e in epochs):
            start = next(e.time_utc for e in epochs if e.time_utc is not None)
            shifted = epochs_on_time_base(cols, start)
            np.testing.assert_array_equal(shifted.col("t_s"), [e.t_s for e in epochs_on_time_base(epochs, start)])


def test_a_leap_second_keeps_its_date_in_the_columns():
    lines = [_s("GPRMC,235959.00,A,3000.0000,N,12000.0000,E,0.0,0.0,311216,,,A"),
             _s("GPRMC,235960.00,A,3000.0000,N,12000.0000,E,0.0,0.0,311216,,,A")]
    epochs = epochs_from_bytes(("\n".join(lines) + "\n").encode())
    assert epochs[1].time_utc.day == 1                     # 23:59:60 on 31 Dec 2016 reads as 00:00:00 next day
    assert nmea._epochs_from_columns(epoch_columns(epochs)) == epochs


# ---------------------------------------------------------------- IMU table


def test_plain_imu_tables_parse_as_loadtxt_does(tmp_path):
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 10.0, (500, 10))
    body = "\n".join(",".join(f"{v:.{d}f}" for v, d in zip(row, drow))
                     for row, drow in zip(x, rng.integers(0, 7, (500, 10))))
    text = "t_s,ax,ay,az,gx,gy,gz,mx,my,mz\n" + body + "\n"
    fast = imu_reader._plain_table(text.encode())
    ref = imu_reader._parse_table(text, "x")
    assert fast is not None and fast[0] == ref[0] and fast[2] == ref[2] == 0
    assert np.array_equal(fast[1], ref[1]) and np.array_equal(np.signbit(fast[1]), np.signbit(ref[1]))


@pytest.mark.parametrize("text", ["t,a\n1,2\r\n3,4\r\n", "\ufefft,a\n1,2\n", "t,a\n1,2\n# note\n3,4\n",
                                  "t,a\n1,2\n\n3,4\n", "t,a\n1,2e3\n", "t,a\n1, 2\n", "t,a\n1,2,3\n", "t,a\n",
                                  "t,a\n1,\n"])
def test_any_other_imu_table_is_left_to_the_reference_parser(text):
    assert imu_reader._plain_table(text.encode("utf-8")) is None


def test_csv_rows_without_final_newline():
    ok, rows = read_csv_table(_text("1.5,2\n-3,4.25"), 2)
    assert ok and rows.tolist() == [[1.5, 2.0], [-3.0, 4.25]]
