"""The NMEA epoch assembly compiled (numba): checked sentences' bytes → epoch and satellite columns.

The same rules as :func:`features.gnss.nmea._assemble` (the reference, which also serves the pynmea2
path and the streaming reader), over the byte spans of the sentences :func:`features.gnss.tokens.sentence_spans`
kept, written as one loop so that a whole file costs what numba's machine code costs, not ~9 µs of Python a
sentence. Field interpretation follows :mod:`features.gnss.quirks` rule for rule (same checks, same order of
arithmetic, so the same floats).

Numbers are read only in their canonical NMEA spelling (:mod:`features.numtext`: digits, one optional sign for
decimals, one optional decimal point, at most 15 significant digits and 22 decimals; Clinger's fast path,
bit-identical to Python's correctly rounded ``float()``). Any other spelling Python would still accept
(``1e3``, ``nan``, ``1_0``, surrounding blanks, ``+5`` or ``-1`` as an integer, more digits) makes the whole
file go to the reference assembler instead (``status`` ``_FALLBACK``): none of the 18 shared receiver logs
holds one, fuzzed files do (about half of the mutated batches of the tests), and such a file costs what it
cost before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from features.gnss.quirks import SYSTEMS, primary_signal_rank
from features.numtext import EMPTY, FALLBACK, INVALID, OK, read_float, read_int

__all__ = ["assemble_spans", "EpochColumns", "EPOCH_F", "EPOCH_I", "SYSTEM_CODES", "COUNTER_NAMES", "primary_rows"]

SYSTEM_CODES = SYSTEMS
"""System names by code: their order in :data:`features.gnss.quirks.SYSTEMS` (GPS 0, SBAS 1, GLONASS 2, ...)."""
_GPS, _SBAS, _GLONASS, _GALILEO, _BEIDOU, _QZSS, _NAVIC = range(7)

COUNTER_NAMES = ("used_sentences", "malformed", "no_time", "time_jumps", "time_resets", "gsv_incomplete",
                 "gsv_signal_continued", "gsv_before_time")
"""The :class:`~features.gnss.tokens.ReadStats` counters the assembly fills, in the order of its ``counts``."""



@dataclass(frozen=True)
class EpochColumns:
    """A file's epochs as arrays (what :func:`assemble_spans` writes; :func:`features.gnss.nmea.epoch_columns`
    turns :class:`~features.gnss.nmea.Epoch` objects into the same), None written NaN or -1.

    ``epoch_f`` : float array of shape (n_epochs, 13), columns :data:`EPOCH_F`;
    ``epoch_i`` : int64 array of shape (n_epochs, 8), columns :data:`EPOCH_I` (the satellites of epoch k are
    rows ``sat_first[k]:sat_end[k]``);
    ``sat_i`` : int64 array of shape (n_sats, 4): system code (:data:`SYSTEM_CODES`), number, signal id (-1
    none), used; ``sat_f`` : float array of shape (n_sats, 3): elevation and azimuth (deg), C/N0 (dB-Hz).
    """

    epoch_f: np.ndarray
    epoch_i: np.ndarray
    sat_i: np.ndarray
    sat_f: np.ndarray

    def __len__(self) -> int:
        return self.epoch_f.shape[0]

    def col(self, name: str) -> np.ndarray:
        """One epoch column by name (:data:`EPOCH_F`, :data:`EPOCH_I`)."""
        if name in EPOCH_F:
            return self.epoch_f[:, EPOCH_F.index(name)]
        return self.epoch_i[:, EPOCH_I.index(name)]

    def with_t_s(self, t_s: np.ndarray) -> "EpochColumns":
        """The same epochs with ``t_s`` replaced."""
        epoch_f = self.epoch_f.copy()
        epoch_f[:, 0] = t_s
        return EpochColumns(epoch_f, self.epoch_i, self.sat_i, self.sat_f)


EPOCH_F = ("t_s", "time_of_day_s", "lat_deg", "lon_deg", "alt_m", "geoid_sep_m", "hdop", "pdop", "vdop",
           "gst_rms_m", "gst_sigma_lat_m", "gst_sigma_lon_m", "gst_sigma_alt_m")
"""Float columns of :class:`EpochColumns` (NaN for None)."""

EPOCH_I = ("date_ordinal", "quality", "n_used", "mode", "sky_reported", "has_gst", "sat_first", "sat_end")
"""Integer columns of :class:`EpochColumns` (-1 for None; the date as ``datetime.date.toordinal``)."""

_OK, _EMPTY, _INVALID, _FALLBACK = OK, EMPTY, INVALID, FALLBACK
"""Outcome of reading a field (:mod:`features.numtext`): a value; an empty field; one Python would refuse
(the sentence is malformed); one only Python can decide (the file goes to the reference assembler)."""

_int, _float = read_int, read_float

_MAX_DATE_ORDINAL = 3652059
"""``datetime.date.max.toordinal()`` (9999-12-31)."""

_MODE_QUALITY = np.full(256, -1, dtype=np.int64)
for _c, _q in {"N": 0, "A": 1, "D": 2, "P": 3, "R": 4, "F": 5, "E": 6, "M": 7, "S": 8}.items():
    _MODE_QUALITY[ord(_c)] = _q
"""GNS/RMC mode character → GGA quality (:data:`features.gnss.quirks.FIX_QUALITY_FROM_MODE`), -1 elsewhere."""

_DAYS_BEFORE_MONTH = np.array([0, 0, 31, 59, 90, 120, 151, 181, 212, 243, 273, 304, 334], dtype=np.int64)
_DAYS_IN_MONTH = np.array([0, 31, 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31], dtype=np.int64)


def _kind_code(text: str) -> int:
    return (ord(text[0]) << 16) | (ord(text[1]) << 8) | ord(text[2])


_GGA, _RMC, _GNS, _GLL, _ZDA, _GST, _GBS, _GSA, _GSV = (_kind_code(k) for k in
                                                       ("GGA", "RMC", "GNS", "GLL", "ZDA", "GST", "GBS", "GSA", "GSV"))


# ----------------------------------------------------------------------------------------------------------
# Fields (quirks.py's readers, on bytes [a, b) of the file)
# ----------------------------------------------------------------------------------------------------------

@njit(cache=True)
def _opt_num(data, a, b):
    """:func:`features.gnss.nmea._opt_num`: |value| ≤ 1e7."""
    st, v = _float(data, a, b)
    if st == _OK and not abs(v) <= 1.0e7:
        return _INVALID, 0.0
    return st, v


@njit(cache=True)
def _single_hex(data, a, b):
    """:func:`features.gnss.quirks._single_hex`: one hexadecimal digit, else -1."""
    if b - a != 1:
        return -1
    c = data[a]
    if 48 <= c <= 57:
        return c - 48
    if 65 <= c <= 70:
        return c - 55
    if 97 <= c <= 102:
        return c - 87
    return -1


@njit(cache=True)
def _is(data, a, b, char):
    return b - a == 1 and data[a] == char


@njit(cache=True)
def _latlon(data, a, b, ha, hb, is_lat):
    """:func:`features.gnss.quirks.parse_latlon`: (status, degrees)."""
    if a >= b or ha >= hb:
        return _EMPTY, 0.0
    dot = b
    for i in range(a, b):
        if data[i] == 46:
            dot = i
            break
    if dot - a < 3:
        return _INVALID, 0.0
    st, degrees = _int(data, a, dot - 2)
    if st != _OK:
        return st, 0.0
    st, minutes = _float(data, dot - 2, b)
    if st != _OK:
        return st, 0.0
    if not 0.0 <= minutes < 60.0:
        return _INVALID, 0.0
    deg = degrees + minutes / 60.0
    if deg > (90.0 if is_lat else 180.0):
        return _INVALID, 0.0
    if _is(data, ha, hb, 83) or _is(data, ha, hb, 87):  # 'S' 'W'
        return _OK, -deg
    if _is(data, ha, hb, 78) or _is(data, ha, hb, 69):  # 'N' 'E'
        return _OK, deg
    return _INVALID, 0.0


@njit(cache=True)
def _time_of_day(data, a, b):
    """:func:`features.gnss.quirks.parse_time_of_day`: (status, seconds of the day)."""
    if a >= b:
        return _EMPTY, 0.0
    if b - a < 6:
        return _INVALID, 0.0
    for i in range(a, a + 6):
        if data[i] < 48 or data[i] > 57:
            return _INVALID, 0.0  # str.isdigit's other Latin-1 digits (superscripts) fail int() in Python
    if b > a + 6:
        if data[a + 6] != 46:
            return _FALLBACK, 0.0
        for i in range(a + 7, b):
            if data[i] < 48 or data[i] > 57:
                return _FALLBACK, 0.0
    h = (data[a] - 48) * 10 + data[a + 1] - 48
    m = (data[a + 2] - 48) * 10 + data[a + 3] - 48
    st, s = _float(data, a + 4, b)
    if st != _OK:
        return st, 0.0
    if h > 23 or m > 59 or not 0.0 <= s < 61.0:
        return _INVALID, 0.0
    return _OK, h * 3600.0 + m * 60.0 + s


@njit(cache=True)
def _ordinal(year, month, day):
    """Proleptic Gregorian ordinal (``datetime.date.toordinal``), -1 for an invalid date."""
    if not 1 <= year <= 9999 or not 1 <= month <= 12:
        return -1
    leap = year % 4 == 0 and (year % 100 != 0 or year % 400 == 0)
    dim = 29 if month == 2 and leap else _DAYS_IN_MONTH[month]
    if not 1 <= day <= dim:
        return -1
    y = year - 1
    return y * 365 + y // 4 - y // 100 + y // 400 + _DAYS_BEFORE_MONTH[month] + (1 if month > 2 and leap else 0) + day


@njit(cache=True)
def _satellite_id(talker_system, number, hint):
    """:func:`features.gnss.quirks.satellite_id`: (system code, system-local number), (-1, -1) when unknown."""
    if number < 1:
        return -1, -1
    system = hint if hint >= 0 else talker_system
    if system == _GLONASS:
        if 65 <= number <= 96:
            return system, number - 64
        return (system, number) if number <= 32 else (-1, -1)
    if system == _GALILEO:
        for base in (0, 100, 300):
            if 1 <= number - base <= 36:
                return system, number - base
        return -1, -1
    if system == _BEIDOU:
        for base in (0, 200, 400):
            if 1 <= number - base <= 63:
                return system, number - base
        return -1, -1
    if system == _QZSS:
        if 1 <= number <= 10:
            return system, number
        return (system, number - 192) if 193 <= number <= 202 else (-1, -1)
    if system == _NAVIC:
        return (system, number) if number <= 14 else (-1, -1)
    if number <= 32:
        return _GPS, number
    if number <= 64:
        return _SBAS, number + 87
    if number <= 96:
        return _GLONASS, number - 64
    if 120 <= number <= 158:
        return _SBAS, number
    if 193 <= number <= 200:
        return _QZSS, number - 192
    if 201 <= number <= 263:
        return _BEIDOU, number - 200
    if 301 <= number <= 336:
        return _GALILEO, number - 300
    if 401 <= number <= 463:
        return _BEIDOU, number - 400
    return -1, -1


@njit(cache=True)
def _talker_system(c0, c1):
    """quirks' talker table: GL GA GB/BD/PQ GQ/QZ GI; -1 for the talkers read by number range."""
    if c0 == 71 and c1 == 76:
        return _GLONASS
    if c0 == 71 and c1 == 65:
        return _GALILEO
    if (c0 == 71 and c1 == 66) or (c0 == 66 and c1 == 68) or (c0 == 80 and c1 == 81):
        return _BEIDOU
    if (c0 == 71 and c1 == 81) or (c0 == 81 and c1 == 90):
        return _QZSS
    if c0 == 71 and c1 == 73:
        return _NAVIC
    return -1


@njit(cache=True)
def _nmea_system(sid):
    """NMEA 4.11 system id → code (:data:`features.gnss.quirks.NMEA_SYSTEM_IDS`), -1 for none."""
    if sid == 1:
        return _GPS
    if 2 <= sid <= 6:
        return sid  # GLONASS 2, Galileo 3, BeiDou 4, QZSS 5, NavIC 6: the codes' order
    return -1


@njit(cache=True)
def _worse(a, b):
    """The outcome of two fields read together: FALLBACK over INVALID over the rest (OK)."""
    if a == _FALLBACK or b == _FALLBACK:
        return _FALLBACK
    if a == _INVALID or b == _INVALID:
        return _INVALID
    return _OK


@njit(cache=True)
def _read_date(data, fa, fb, nd, kind):
    """The date of an RMC (``ddmmyy``, data field 8) or a ZDA (day, month, year: data fields 1-3) as a date
    ordinal, -1 when the sentence states none: (status, ordinal). ``data[fa[k]:fb[k]]`` is field k (0 the
    address), ``nd`` the number of data fields. (nmea._assemble, quirks.parse_ddmmyy)"""
    if kind == _RMC and nd > 8:
        a, b = fa[9], fb[9]
        if a >= b:
            return _OK, -1
        st, ddmmyy = _int(data, a, b)
        if b - a != 6 or st != _OK:
            return _INVALID, -1  # "not text.isdigit()": Python refuses every other byte here
        yy = ddmmyy % 100
        date = _ordinal(1900 + yy if yy >= 80 else 2000 + yy, ddmmyy // 100 % 100, ddmmyy // 10000)
        return (_OK if date >= 0 else _INVALID), date
    if kind == _ZDA and nd >= 4 and fb[2] > fa[2] and fb[3] > fa[3] and fb[4] > fa[4]:
        s1, day = _int(data, fa[2], fb[2])
        s2, month = _int(data, fa[3], fb[3])
        s3, year = _int(data, fa[4], fb[4])
        st = _worse(_worse(s1, s2), s3)
        if st != _OK:
            return st, -1
        date = _ordinal(year, month, day)
        if date < 0 or year < 1980:  # GPS time began in 1980 (nmea._FIRST_GNSS_YEAR)
            return _INVALID, -1
        return _OK, date
    return _OK, -1


@njit(cache=True)
def _read_fix(data, fa, fb, nd, kind, out):
    """A GGA's or GNS's fix (nmea._timed_payload): (status, quality, n_used or -1); latitude, longitude,
    altitude, geoid separation and HDOP (NaN for None) into ``out``, shape (5,)."""
    if nd < 9:
        return _INVALID, 0, -1
    s1, lat = _latlon(data, fa[2], fb[2], fa[3], fb[3], True)
    s2, lon = _latlon(data, fa[4], fb[4], fa[5], fb[5], False)
    s3, hdop = _opt_num(data, fa[8], fb[8])
    s4, alt = _opt_num(data, fa[9], fb[9])
    sep_field = 11 if kind == _GGA else 10
    s5, sep = _opt_num(data, fa[sep_field], fb[sep_field]) if nd >= sep_field else (_EMPTY, 0.0)
    s6, n_used = _int(data, fa[7], fb[7])
    if s6 == _OK and not 0 <= n_used <= 999:
        s6 = _INVALID
    s7 = _OK
    quality = 0
    if kind == _GGA:
        if fb[6] > fa[6]:
            s7, quality = _int(data, fa[6], fb[6])
            if s7 == _OK and not 0 <= quality <= 9:
                s7 = _INVALID
    else:  # GNS: the best of the per-system mode characters, E (dead reckoning) only without any other
        emergency = False
        for i in range(fa[6], fb[6]):
            c = data[i]
            if c == 65 or c == 68 or c == 80 or c == 82 or c == 70:  # A D P R F
                quality = max(quality, _MODE_QUALITY[c])
            elif c == 69:
                emergency = True
        if quality == 0 and emergency:
            quality = 6
    status = _OK
    for s_ in (s1, s2, s3, s4, s5, s6, s7):
        status = _worse(status, s_)
    out[0] = lat if s1 == _OK else np.nan
    out[1] = lon if s2 == _OK else np.nan
    out[2] = alt if s4 == _OK else np.nan
    out[3] = sep if s5 == _OK else np.nan
    out[4] = hdop if s3 == _OK and 0.0 < hdop < 99.0 else np.nan
    return status, quality, (n_used if s6 == _OK else -1)


@njit(cache=True)
def _read_rmc(data, fa, fb, nd, out):
    """An RMC's fix (nmea._timed_payload): (status, quality); latitude and longitude into ``out[:2]``."""
    if nd < 6:
        return _INVALID, 0
    s1, lat = _latlon(data, fa[3], fb[3], fa[4], fb[4], True)
    s2, lon = _latlon(data, fa[5], fb[5], fa[6], fb[6], False)
    quality = 0
    if _is(data, fa[2], fb[2], 65):  # status 'A': the mode character's quality, 1 without one
        quality = 1
        if nd > 11 and fb[12] > fa[12]:
            q = _MODE_QUALITY[data[fa[12]]]
            quality = q if q >= 0 else 1
    out[0] = lat if s1 == _OK else np.nan
    out[1] = lon if s2 == _OK else np.nan
    return _worse(s1, s2), quality


@njit(cache=True)
def _read_gst(data, fa, fb, nd, out):
    """A GST's RMS and σ_lat, σ_lon, σ_alt (data fields 1, 5, 6, 7) into ``out``, NaN unless in (0, 1e6)."""
    status = _OK
    out[:] = np.nan
    for j in range(4):
        f = (2, 6, 7, 8)[j]
        if nd >= f:
            st, v = _opt_num(data, fa[f], fb[f])
            status = _worse(status, st)
            if st == _OK and 0.0 < v < 1e6:
                out[j] = v
    return status


@njit(cache=True)
def _read_gsv(data, fa, fb, nd, t_sys, sys_out, prn_out, val_out):
    """A GSV sentence (quirks.gsv_fields): (status, n_msgs, msg_num, signal id or -1, n_satellites); the
    satellites' system code, number and (el, az, C/N0) into ``sys_out``, ``prn_out``, ``val_out``."""
    if nd < 3:
        return _INVALID, 0, 0, -1, 0
    s1, n_msgs = _int(data, fa[1], fb[1])
    s2, msg_num = _int(data, fa[2], fb[2])
    s3, n_in_view = _int(data, fa[3], fb[3])
    st = _worse(_worse(s1, s2), s3)
    if st == _FALLBACK:
        return st, 0, 0, -1, 0
    if s1 != _OK or s2 != _OK or st == _INVALID or not 1 <= msg_num <= n_msgs or n_msgs > 99 \
            or not n_in_view <= 999:
        return _INVALID, 0, 0, -1, 0
    n_body = nd - 3
    signal = -1
    hint = -1
    last = 3 + n_body  # the field of the body's last
    if n_body % 4 == 1:  # a trailing signal id (NMEA 4.10+)
        signal = _single_hex(data, fa[last], fb[last])
        if signal < 0 and fb[last] > fa[last]:
            return _INVALID, 0, 0, -1, 0
        n_body -= 1
    elif n_body % 4 == 2 and _single_hex(data, fa[last - 1], fb[last - 1]) >= 0 \
            and fb[last] - fa[last] == 1 and 49 <= data[fa[last]] <= 54:  # Quectel PQGSV: signal, system id
        signal = _single_hex(data, fa[last - 1], fb[last - 1])
        hint = _nmea_system(data[fa[last]] - 48)
        n_body -= 2
    n = 0
    for g in range(0, n_body, 4):
        f0 = 4 + g
        if fb[f0] == fa[f0]:
            continue  # no number: nothing to key the satellite by
        st, number = _int(data, fa[f0], fb[f0])
        # a last satellite cut short: its missing fields are empty
        s_el, el = _float(data, fa[f0 + 1], fb[f0 + 1]) if g + 1 < n_body else (_EMPTY, 0.0)
        s_az, az = _float(data, fa[f0 + 2], fb[f0 + 2]) if g + 2 < n_body else (_EMPTY, 0.0)
        s_cn, cn0 = _float(data, fa[f0 + 3], fb[f0 + 3]) if g + 3 < n_body else (_EMPTY, 0.0)
        st = _worse(_worse(st, s_el), _worse(s_az, s_cn))
        if st == _FALLBACK:
            return st, 0, 0, -1, 0
        if st == _INVALID or (s_el == _OK and not -90.0 <= el <= 90.0) or (s_az == _OK and not 0.0 <= az <= 360.0) \
                or (s_cn == _OK and not 0.0 <= cn0 <= 99.0):
            return _INVALID, 0, 0, -1, 0
        system, prn = _satellite_id(t_sys, number, hint)
        if system < 0:
            continue
        sys_out[n], prn_out[n] = system, prn
        val_out[n, 0] = el if s_el == _OK else np.nan
        val_out[n, 1] = az if s_az == _OK else np.nan
        val_out[n, 2] = cn0 if s_cn == _OK and cn0 != 0.0 else np.nan  # 0 dB-Hz: not tracked
        n += 1
    return _OK, n_msgs, msg_num, signal, n


@njit(cache=True)
def _read_gsa(data, fa, fb, nd, t_sys, sys_out, prn_out, dops_out):
    """A GSA sentence (quirks.gsa_fields): (status, mode or -1, n_used); the used satellites' system code
    and number into ``sys_out``, ``prn_out``; PDOP, HDOP, VDOP (NaN unless in (0, 99)) into ``dops_out``."""
    if nd < 5:
        return _INVALID, -1, 0
    system = -1
    if nd == 18:  # 4.10+: a system id after the DOPs
        sid = _single_hex(data, fa[18], fb[18])
        if sid >= 0:
            system = _nmea_system(sid)
        p0, p1, d0 = 3, 15, 15
    else:
        p0, p1, d0 = 3, max(3, nd - 2), nd - 2
    status, mode = _int(data, fa[2], fb[2])
    if status == _OK and not 1 <= mode <= 3:
        status = _INVALID
    mode = mode if status == _OK else -1
    if status == _EMPTY:
        status = _OK
    n = 0
    for f in range(p0, p1):
        if fb[f] > fa[f]:
            st, number = _int(data, fa[f], fb[f])
            status = _worse(status, st)
            if st != _OK:
                continue
            sys_, prn = _satellite_id(t_sys, number, system)
            if sys_ >= 0:
                sys_out[n], prn_out[n] = sys_, prn
                n += 1
    dops_out[:] = np.nan
    for j in range(3):
        st, v = _float(data, fa[d0 + j], fb[d0 + j])
        status = _worse(status, st)
        if st == _OK and 0.0 < v < 99.0:
            dops_out[j] = v
    return status, mode, n


# ----------------------------------------------------------------------------------------------------------
# The assembly (nmea._assemble, _add_gsv, _finish)
# ----------------------------------------------------------------------------------------------------------

@njit(cache=True)
def assemble_spans(data, starts, ends, resync_after):
    """Epochs from the sentences ``data[starts[k]:ends[k]]`` (address first, checksum removed).

    Returns ``(status, counts, epoch_f, epoch_i, sat_i, sat_f)``; ``status`` 0, or 3 when a field needs the
    reference assembler (then nothing else is meaningful). ``counts``: :data:`COUNTER_NAMES`.
    ``epoch_f`` (n_epochs, 13) float: t_s, time of day, lat, lon, alt, geoid separation, hdop, pdop, vdop,
    GST rms, σ_lat, σ_lon, σ_alt, NaN for None; ``epoch_i`` (n_epochs, 8) int: date ordinal (-1 none),
    quality, n_used (-1), mode (-1), sky reported, has GST, first satellite row, end satellite row;
    ``sat_i`` (n_sats, 4) int: system code, number, signal id (-1 none), used; ``sat_f`` (n_sats, 3)
    float: elevation, azimuth, C/N0 (NaN for None).
    """
    nan = np.nan
    n_sent = starts.size
    counts = np.zeros(8, dtype=np.int64)
    used_sentences, malformed, no_time, time_jumps, time_resets, gsv_incomplete, gsv_continued, gsv_before = (
        0, 0, 0, 0, 0, 0, 0, 0)
    n_commas = 0
    longest = 1
    for k in range(n_sent):
        longest = max(longest, ends[k] - starts[k] + 1)
        for i in range(starts[k], ends[k]):
            if data[i] == 44:
                n_commas += 1
    epoch_f = np.empty((n_sent + 1, 13))
    epoch_i = np.empty((n_sent + 1, 8), dtype=np.int64)
    max_sats = n_commas // 4 + n_sent + 1
    sat_i = np.empty((max_sats, 4), dtype=np.int64)
    sat_f = np.empty((max_sats, 3))
    field_a = np.empty(longest + 1, dtype=np.int64)  # field k of a sentence: data[field_a[k]:field_b[k]]
    field_b = np.empty(longest + 1, dtype=np.int64)
    gsv_sys = np.empty(longest, dtype=np.int64)  # one GSV sentence's satellites
    gsv_prn = np.empty(longest, dtype=np.int64)
    gsv_val = np.empty((longest, 3))
    gsa_sys = np.empty(longest, dtype=np.int64)
    gsa_prn = np.empty(longest, dtype=np.int64)
    used_sys = np.empty(max(longest, 64), dtype=np.int64)  # the open epoch's GSA satellites, distinct
    used_prn = np.empty(max(longest, 64), dtype=np.int64)
    # GSV group bookkeeping of the open epoch: parts[(talker, signal)] -> next part; open_[talker] -> group
    parts_talker = np.empty(64, dtype=np.int64)
    parts_signal = np.empty(64, dtype=np.int64)
    parts_next = np.empty(64, dtype=np.int64)
    open_talker = np.empty(64, dtype=np.int64)
    open_key = np.empty((64, 2), dtype=np.int64)
    open_n_msgs = np.empty(64, dtype=np.int64)
    open_next = np.empty(64, dtype=np.int64)
    n_parts = 0
    n_open = 0

    # the clock (nmea._Clock)
    offset_s = 0.0
    backwards_run = 0
    clock_day = 0
    has_last_tod = False
    last_tod = 0.0
    known_ord = -1
    known_day = 0

    n_epochs = 0
    n_sats = 0
    has_current = False
    first_rel = 0.0
    has_last_t = False
    last_t_s = 0.0
    last_interval = 1.0
    orphaned = False
    cur_time_a = -1  # the open epoch's time text, data[cur_time_a:cur_time_b]; -1: none
    cur_time_b = -1
    # the open epoch (nmea._EpochBuilder)
    cur_rel = cur_tod = 0.0
    cur_day = cur_date = 0
    cur_source = 0              # 3 GGA, 2 GNS, 1 RMC, 0 none (a GGA wins over a GNS over an RMC)
    gga = np.empty(5)           # lat, lon, alt, sep, hdop of its last GGA; quality, n_used in gga_i
    gga_i = np.empty(2, dtype=np.int64)
    gns = np.empty(5)
    gns_i = np.empty(2, dtype=np.int64)
    rmc = np.empty(2)
    rmc_quality = 0
    new_fix = np.empty(5)       # the sentence being read
    new_gst = np.empty(4)
    new_quality = new_n_used = 0
    new_dops = np.empty(3)
    gsa_mode_new = -1
    rel = 0.0
    day = 0
    ta = tb = -1
    kind = 0
    msg_num = n_msgs = signal = 0
    n_gsv = n_gsa = 0
    has_first = False
    gst = np.empty(4)
    has_gst = False
    dops = np.empty(3)
    gsa_mode = -1
    n_used_sats = 0
    cur_sky = False
    cur_first_sat = 0

    for k in range(n_sent + 1):
        closing = k == n_sent
        opens = False
        if not closing:
            s, e = starts[k], ends[k]
            n_fields = 0
            field_a[0] = s
            for i in range(s, e):
                if data[i] == 44:
                    field_b[n_fields] = i
                    n_fields += 1
                    field_a[n_fields] = i + 1
            field_b[n_fields] = e
            n_fields += 1
            nd = n_fields - 1  # data fields: field k + 1 is data[k]
            if field_b[0] - s != 5:
                continue  # the tokeniser passes only five-character addresses of the used types
            c0, c1 = data[s], data[s + 1]
            kind = (np.int64(data[s + 2]) << 16) | (np.int64(data[s + 3]) << 8) | np.int64(data[s + 4])
            talker = np.int64(c0) * 256 + c1
            timed = kind == _GGA or kind == _RMC or kind == _GNS or kind == _GLL or kind == _ZDA \
                or kind == _GST or kind == _GBS
            tod = 0.0
            date = -1
            if timed:
                t_field = 5 if kind == _GLL else 1
                if nd < t_field:
                    malformed += 1
                    continue
                ta, tb = field_a[t_field], field_b[t_field]
                if kind == _GLL or kind == _GBS:
                    if cur_time_a >= 0 and tb - ta == cur_time_b - cur_time_a:
                        same = True
                        for i in range(tb - ta):
                            if data[ta + i] != data[cur_time_a + i]:
                                same = False
                                break
                        if same:
                            used_sentences += 1  # same fix time, nothing else used from it
                            orphaned = False
                            backwards_run = 0
                            continue
                st, tod = _time_of_day(data, ta, tb)
                if st == _FALLBACK:
                    return _FALLBACK, counts, epoch_f[:0], epoch_i[:0], sat_i[:0], sat_f[:0]
                if st == _EMPTY:
                    no_time += 1
                    continue
                if st == _INVALID:
                    malformed += 1
                    continue
                # the date, then the fix content (nmea._timed_payload)
                status, date = _read_date(data, field_a, field_b, nd, kind)
                if status == _OK:
                    if kind == _GGA or kind == _GNS:
                        status, new_quality, new_n_used = _read_fix(data, field_a, field_b, nd, kind, new_fix)
                    elif kind == _RMC:
                        status, new_quality = _read_rmc(data, field_a, field_b, nd, new_fix)
                    elif kind == _GST:
                        status = _read_gst(data, field_a, field_b, nd, new_gst)
                if status == _FALLBACK:
                    return _FALLBACK, counts, epoch_f[:0], epoch_i[:0], sat_i[:0], sat_f[:0]
                if status == _INVALID:
                    malformed += 1
                    continue
                # on the clock (nmea._assemble's timed branch)
                day = clock_day
                if has_last_tod and tod < last_tod - 43_200.0:
                    day += 1
                rel = day * 86_400.0 + tod + offset_s
                if has_current and rel < cur_rel:
                    backwards_run += 1
                    if backwards_run < resync_after:
                        time_jumps += 1
                        orphaned = True
                        continue
                    # the new time base persisted: splice it one epoch interval after the last epoch
                    cur_time_a = cur_time_b = -1
                    time_resets += 1
                    clock_day = 0
                    has_last_tod = False
                    known_ord = -1
                    raw_rel = 0 * 86_400.0 + tod + 0.0
                    offset_s = cur_rel + last_interval - raw_rel
                    day = 0
                    rel = day * 86_400.0 + tod + offset_s
                backwards_run = 0
                orphaned = False
                clock_day, last_tod, has_last_tod = day, tod, True
                if date >= 0:
                    known_ord, known_day = date, day
                opens = not has_current or rel != cur_rel
                if not opens and date >= 0:
                    cur_date = date
            else:
                # GSA / GSV (quirks.gsa_fields, gsv_fields)
                t_sys = _talker_system(c0, c1)
                if kind == _GSV:
                    status, n_msgs, msg_num, signal, n_gsv = _read_gsv(data, field_a, field_b, nd, t_sys, gsv_sys,
                                                                       gsv_prn, gsv_val)
                elif kind == _GSA:
                    status, gsa_mode_new, n_gsa = _read_gsa(data, field_a, field_b, nd, t_sys, gsa_sys, gsa_prn,
                                                            new_dops)
                else:
                    continue
                if status == _FALLBACK:
                    return _FALLBACK, counts, epoch_f[:0], epoch_i[:0], sat_i[:0], sat_f[:0]
                if status == _INVALID:
                    malformed += 1
                    continue
                if not has_current:
                    if kind == _GSV:
                        gsv_before += 1
                    continue
                if orphaned:
                    time_jumps += 1
                    continue
                used_sentences += 1
                if kind == _GSA:
                    if gsa_mode_new >= 0:
                        gsa_mode = gsa_mode_new
                    for j in range(3):
                        if not np.isnan(new_dops[j]):
                            dops[j] = new_dops[j]
                    for j in range(n_gsa):
                        seen = False
                        for u in range(n_used_sats):
                            if used_sys[u] == gsa_sys[j] and used_prn[u] == gsa_prn[j]:
                                seen = True
                                break
                        if not seen:
                            if n_used_sats == used_sys.size:
                                used_sys = np.concatenate((used_sys, np.empty(used_sys.size, np.int64)))
                                used_prn = np.concatenate((used_prn, np.empty(used_prn.size, np.int64)))
                            used_sys[n_used_sats], used_prn[n_used_sats] = gsa_sys[j], gsa_prn[j]
                            n_used_sats += 1
                    continue
                # GSV into the epoch (nmea._add_gsv)
                cur_sky = True
                key_t, key_s = talker, signal
                expected = 1
                for j in range(n_parts):
                    if parts_talker[j] == key_t and parts_signal[j] == key_s:
                        expected = parts_next[j]
                        break
                if msg_num != expected:
                    o = -1
                    for j in range(n_open):
                        if open_talker[j] == talker:
                            o = j
                            break
                    if o >= 0 and msg_num > 1 and open_n_msgs[o] == n_msgs and open_next[o] == msg_num:
                        key_t, key_s = open_key[o, 0], open_key[o, 1]
                        gsv_continued += 1
                    else:
                        gsv_incomplete += 1
                nxt = msg_num % n_msgs + 1
                p = -1
                for j in range(n_parts):
                    if parts_talker[j] == key_t and parts_signal[j] == key_s:
                        p = j
                        break
                if p < 0:
                    if n_parts == parts_talker.size:
                        parts_talker = np.concatenate((parts_talker, np.empty(n_parts, np.int64)))
                        parts_signal = np.concatenate((parts_signal, np.empty(n_parts, np.int64)))
                        parts_next = np.concatenate((parts_next, np.empty(n_parts, np.int64)))
                    p = n_parts
                    parts_talker[p], parts_signal[p] = key_t, key_s
                    n_parts += 1
                parts_next[p] = nxt
                o = -1
                for j in range(n_open):
                    if open_talker[j] == talker:
                        o = j
                        break
                if o < 0:
                    if n_open == open_talker.size:
                        open_talker = np.concatenate((open_talker, np.empty(n_open, np.int64)))
                        open_key = np.concatenate((open_key, np.empty((n_open, 2), np.int64)))
                        open_n_msgs = np.concatenate((open_n_msgs, np.empty(n_open, np.int64)))
                        open_next = np.concatenate((open_next, np.empty(n_open, np.int64)))
                    o = n_open
                    open_talker[o] = talker
                    n_open += 1
                open_key[o, 0], open_key[o, 1] = key_t, key_s
                open_n_msgs[o], open_next[o] = n_msgs, nxt
                for j in range(n_gsv):
                    r = -1
                    for q in range(cur_first_sat, n_sats):  # one entry per (system, prn, signal), first place kept
                        if sat_i[q, 0] == gsv_sys[j] and sat_i[q, 1] == gsv_prn[j] and sat_i[q, 2] == signal:
                            r = q
                            break
                    if r < 0:
                        r = n_sats
                        n_sats += 1
                        sat_i[r, 0], sat_i[r, 1], sat_i[r, 2] = gsv_sys[j], gsv_prn[j], signal
                    sat_f[r, 0], sat_f[r, 1], sat_f[r, 2] = gsv_val[j, 0], gsv_val[j, 1], gsv_val[j, 2]
                continue
        # a timed sentence that opens an epoch, or the end: close the open one (nmea._finish)
        if has_current and (opens or closing):
            t_s = cur_rel - first_rel
            row_f = epoch_f[n_epochs]
            row_i = epoch_i[n_epochs]
            row_f[0], row_f[1] = t_s, cur_tod
            if cur_source == 3 or cur_source == 2:
                src, src_i = (gga, gga_i) if cur_source == 3 else (gns, gns_i)
                row_f[2], row_f[3], row_f[4], row_f[5] = src[0], src[1], src[2], src[3]
                row_f[6] = src[4] if not np.isnan(src[4]) else dops[1]
                row_i[1], row_i[2] = src_i[0], src_i[1]
            elif cur_source == 1:
                row_f[2], row_f[3], row_f[4], row_f[5] = rmc[0], rmc[1], nan, nan
                row_f[6] = dops[1]
                row_i[1], row_i[2] = rmc_quality, n_used_sats if n_used_sats > 0 else -1
            else:
                row_f[2], row_f[3], row_f[4], row_f[5] = nan, nan, nan, nan
                row_f[6] = dops[1]
                row_i[1], row_i[2] = 0, n_used_sats if n_used_sats > 0 else -1
            row_f[7], row_f[8] = dops[0], dops[2]
            row_f[9], row_f[10], row_f[11], row_f[12] = gst[0], gst[1], gst[2], gst[3]
            row_i[0], row_i[3], row_i[4], row_i[5] = cur_date, gsa_mode, cur_sky, has_gst
            row_i[6], row_i[7] = cur_first_sat, n_sats
            for q in range(cur_first_sat, n_sats):
                used = False
                if not np.isnan(sat_f[q, 2]):
                    for u in range(n_used_sats):
                        if used_sys[u] == sat_i[q, 0] and used_prn[u] == sat_i[q, 1]:
                            used = True
                            break
                sat_i[q, 3] = used
            n_epochs += 1
            if has_last_t and t_s > last_t_s:
                last_interval = t_s - last_t_s
            has_last_t, last_t_s = True, t_s
        if closing:
            break
        if opens:
            has_current = True
            cur_rel, cur_tod, cur_day = rel, tod, day
            cur_date = -1
            if known_ord >= 0:
                cur_date = known_ord + (day - known_day)
                if not 1 <= cur_date <= _MAX_DATE_ORDINAL:
                    cur_date = -1
            cur_time_a, cur_time_b = ta, tb
            if not has_first:
                first_rel, has_first = rel, True
            n_parts = n_open = 0
            cur_source = 0
            has_gst = False
            dops[:] = nan
            gsa_mode = -1
            n_used_sats = 0
            cur_sky = False
            cur_first_sat = n_sats
            gst[:] = nan
        used_sentences += 1
        if kind == _GGA:
            gga[:] = new_fix
            gga_i[0], gga_i[1] = new_quality, new_n_used
            cur_source = 3
        elif kind == _GNS:
            gns[:] = new_fix
            gns_i[0], gns_i[1] = new_quality, new_n_used
            if cur_source < 3:
                cur_source = 2
        elif kind == _RMC:
            rmc[0], rmc[1], rmc_quality = new_fix[0], new_fix[1], new_quality
            if cur_source < 2:
                cur_source = 1
        elif kind == _GST and not (np.isnan(new_gst[1]) and np.isnan(new_gst[2])):
            gst[:] = new_gst
            has_gst = True
    counts[0], counts[1], counts[2], counts[3] = used_sentences, malformed, no_time, time_jumps
    counts[4], counts[5], counts[6], counts[7] = time_resets, gsv_incomplete, gsv_continued, gsv_before
    return _OK, counts, epoch_f[:n_epochs], epoch_i[:n_epochs], sat_i[:n_sats], sat_f[:n_sats]


# ----------------------------------------------------------------------------------------------------------
# Primary signals (nmea.Epoch.primary_satellites)
# ----------------------------------------------------------------------------------------------------------

def _rank_table() -> np.ndarray:
    """:func:`features.gnss.quirks.primary_signal_rank` as a table [system code, signal id + 1] (-1: never)."""
    table = np.full((len(SYSTEM_CODES), 17), -1, dtype=np.int64)
    for code, system in enumerate(SYSTEM_CODES):
        for signal in range(-1, 16):
            rank = primary_signal_rank(system, None if signal < 0 else signal)
            table[code, signal + 1] = -1 if rank is None else rank
    return table


@njit(cache=True)
def _primary(sat_i, first, end, ranks):
    """Rows of each epoch's primary satellites, in :attr:`~features.gnss.nmea.Epoch.primary_satellites`' order:
    per (system, number), the entry of lowest rank (the first of equal ones), placed where the satellite's
    first ranked entry was. Returns (rows, counts per epoch)."""
    rows = np.empty(sat_i.shape[0], dtype=np.int64)
    held = np.empty(sat_i.shape[0], dtype=np.int64)
    counts = np.zeros(first.size, dtype=np.int64)
    n = 0
    for k in range(first.size):
        start = n
        for q in range(first[k], end[k]):
            signal = sat_i[q, 2]
            rank = ranks[sat_i[q, 0], signal + 1] if -1 <= signal <= 15 else -1
            if rank < 0:
                continue
            p = -1
            for j in range(start, n):
                if sat_i[rows[j], 0] == sat_i[q, 0] and sat_i[rows[j], 1] == sat_i[q, 1]:
                    p = j
                    break
            if p < 0:
                rows[n], held[n] = q, rank
                n += 1
            elif rank < held[p]:
                rows[p], held[p] = q, rank
        counts[k] = n - start
    return rows[:n], counts


_RANKS = _rank_table()


def primary_rows(columns: EpochColumns) -> tuple[np.ndarray, np.ndarray]:
    """(rows of ``columns.sat_i`` on their primary signal, their count per epoch); see :func:`_primary`."""
    return _primary(columns.sat_i, columns.col("sat_first"), columns.col("sat_end"), _RANKS)
