"""Field layouts of the NMEA 0183 sentences envfuse reads, with every receiver quirk in one place.

The reader (:mod:`features.gnss.nmea`) tokenises a line (checksum, split on commas)
and hands the field list to the functions here, which interpret it. The same
functions interpret a :mod:`pynmea2` sentence (``msg.talker``,
``msg.sentence_type``, ``msg.data``) through :func:`decode_pynmea2`, so the
fast path and pynmea2 can be compared line by line (tests do so on every real
log under ``../shared/data/nmea``).

Where pynmea2 1.19 is wrong or silent, the correction lives here:

* **GSV signal id (NMEA 4.10+).** A GSV sentence ends with a hexadecimal
  signal id after the 1-4 satellite groups. pynmea2's ``GSV`` class maps
  fields positionally, so in a sentence with fewer than four satellites the
  signal id lands in ``sv_prn_num_<k+1>`` and reads as one more satellite
  (``$GPGSV,3,3,12,26,..,30,00,159,,1`` → phantom PRN 1). :func:`gsv_fields`
  counts fields: after the three header fields, ``4·k`` satellite fields and
  one trailing field are ``k`` satellites plus the signal id.
* **Quectel ``$PQGSV``** ends with two fields, signal id and system id
  (``...,0,4``; gpsd calls it the "Quectel Querk"); read as such.
* **GSA system id (NMEA 4.10+).** The 18th field names the constellation of
  the PRNs listed; pynmea2 keeps it only in ``data`` (no attribute). Without
  it a ``GNGSA`` PRN is classified by number range.
* **BeiDou PRNs above 32.** BeiDou-3 numbers satellites 1-63. Under the
  ``GB``/``BD``/``PQ`` talkers these are BeiDou; only the NMEA 2.x numbering of
  the ``GP``/``GN`` talkers reserves 33-64 for SBAS (PRN = NMEA id + 87).
* **Talkers.** ``GB`` (NMEA 4.10) and ``BD`` (older) are both BeiDou, ``GN``
  is a combined solution whose satellites are classified by number range
  (1-32 GPS, 33-64 SBAS, 65-96 GLONASS, 193-200 QZSS, 201-263 / 401-463 BeiDou,
  301-336 Galileo, the ranges of NMEA 4.11 and of the receivers gpsd documents
  in ``driver_nmea0183.c: nmeaid_to_prn``), ``GQ``/``QZ`` QZSS, ``GI`` NavIC.

* **Several signals of one satellite (NMEA 4.10+).** Dual-frequency receivers
  list a satellite once per signal, each GSV sentence tagged with its signal
  id; the reader keeps every entry. Which one the features read is decided
  by :func:`primary_signal_rank` (the L1/G1/E1/B1 open-service signal).

Satellite numbers are returned system-local (GPS 1-32, SBAS 120-158, GLONASS
slot 1-32, Galileo 1-36, BeiDou 1-63, QZSS 1-10, NavIC 1-14), the numbering
of RINEX and of gpsd's ``svid``.
"""

from __future__ import annotations

import datetime as _dt
import functools
from typing import NamedTuple

__all__ = [
    "SYSTEMS", "NMEA_SYSTEM_IDS", "GsvSatellite", "GsvFields", "GsaFields",
    "satellite_id", "gsv_fields", "gsa_fields", "parse_time_of_day", "parse_latlon",
    "parse_ddmmyy", "decode_pynmea2", "FIX_QUALITY_FROM_MODE", "PRIMARY_SIGNAL_IDS", "primary_signal_rank",
]

SYSTEMS = ("GPS", "SBAS", "GLONASS", "Galileo", "BeiDou", "QZSS", "NavIC")
"""Constellation names used in epochs and JSON output."""

NMEA_SYSTEM_IDS = {1: "GPS", 2: "GLONASS", 3: "Galileo", 4: "BeiDou", 5: "QZSS", 6: "NavIC"}
"""GNSS system id of the NMEA 4.11 GSA/GSV system-id field (also used by u-blox and Quectel)."""

_TALKER_SYSTEM = {
    "GL": "GLONASS", "GA": "Galileo", "GB": "BeiDou", "BD": "BeiDou", "PQ": "BeiDou",
    "GQ": "QZSS", "QZ": "QZSS", "GI": "NavIC",
}

FIX_QUALITY_FROM_MODE = {"N": 0, "A": 1, "D": 2, "P": 3, "R": 4, "F": 5, "E": 6, "M": 7, "S": 8}
"""GNS/RMC mode indicator → GGA quality code (NMEA 0183 v4.11, GNS field 6 and GGA field 6)."""


PRIMARY_SIGNAL_IDS = {
    "GPS": (1,),          # L1 C/A (2 L1 P(Y) and 3 L1 M are military)
    "SBAS": (1,),         # L1 C/A (listed under GP, GPS's signal ids)
    "QZSS": (1, 2, 3),    # L1 C/A, then L1C (D), L1C (P)
    "GLONASS": (1,),      # G1 C/A ("L1 C/A")
    "Galileo": (7, 6),    # E1-B/C ("L1-BC"), then E1-A ("L1-A", the id Quectel's LC79D gives E1)
    "BeiDou": (1, 3),     # B1I, then B1C
    "NavIC": (1, 5),      # L5-SPS (NavIC's open service has no legacy L1 signal), then L1-SPS
}
"""Signal ids (NMEA 0183 v4.11, GSV/GRS signal-id table, as reproduced in gpsd's ``www/NMEA.adoc``,
"NMEA 4.11 System ID and Signal ID") of each system's primary signal, most preferred first: the
open-service signal of the L1 band (E1 for Galileo, B1 for BeiDou, G1 for GLONASS) that every
receiver tracks and that the open-sky C/N0 reference describes. Not primary: L2, L5 / E5a / E5b /
B2 / B3, E6, L6 (secondary frequencies), and ids 4 and up where the table names no L1-band signal."""

_PRIMARY_RANK = {(system, sig): k for system, ids in PRIMARY_SIGNAL_IDS.items() for k, sig in enumerate(ids)}
_UNSTATED_RANK = max(len(ids) for ids in PRIMARY_SIGNAL_IDS.values())


def primary_signal_rank(system: str, signal: int | None) -> int | None:
    """How primary a satellite's listed signal is: 0 best, larger worse, ``None`` = never primary.

    Rule (NMEA 0183 v4.10/4.11 signal ids): a stated primary signal ranks first, in the order of
    :data:`PRIMARY_SIGNAL_IDS` (GPS 1 = L1 C/A; Galileo 7 = E1-B/C, then 6; BeiDou 1 = B1I, then
    3 = B1C; ...). An entry whose signal is not stated ranks after them: a GSV sentence without the
    signal-id field (NMEA ≤ 4.00, one signal per satellite, the L1-band one on every receiver gpsd
    documents), one whose field is empty (the u-blox ZED-F9P of gpsd's log writes its second, B2I,
    BeiDou group so: it must not outrank the B1I entry tagged 1) and id 0 ("all signals"; Quectel's
    ``$PQGSV``). Any other id (L5 = 7/8 for GPS, E5a = 1 for Galileo, B2I = 11 for BeiDou, ...) is
    a secondary signal, never primary. The features read, per satellite and epoch, the listed
    entry of lowest rank, and leave out a satellite listed only on secondary signals.

    >>> primary_signal_rank("GPS", 1), primary_signal_rank("GPS", None), primary_signal_rank("GPS", 8)
    (0, 3, None)
    >>> primary_signal_rank("Galileo", 7), primary_signal_rank("Galileo", 1), primary_signal_rank("BeiDou", 11)
    (0, None, None)
    """
    if signal is None or signal == 0:
        return _UNSTATED_RANK
    return _PRIMARY_RANK.get((system, signal))


class GsvSatellite(NamedTuple):
    """One satellite entry of a GSV sentence (system-local ``prn``; ``None`` = empty field)."""

    system: str
    prn: int
    el_deg: float | None
    az_deg: float | None
    cn0_dbhz: float | None


class GsvFields(NamedTuple):
    """A GSV sentence: part ``msg_num`` of ``n_msgs``, ``n_in_view`` announced, its satellites."""

    n_msgs: int
    msg_num: int
    n_in_view: int
    signal: int | None
    satellites: tuple[GsvSatellite, ...]


class GsaFields(NamedTuple):
    """A GSA sentence: fix mode (1 none, 2 2-D, 3 3-D), used satellites as (system, prn), DOPs."""

    mode: int | None
    used: tuple[tuple[str, int], ...]
    pdop: float | None
    hdop: float | None
    vdop: float | None
    system: str | None


def satellite_id(talker: str, number: int, system_hint: str | None = None) -> tuple[str, int] | None:
    """Constellation and system-local number of an NMEA satellite id, or ``None`` if unknown.

    ``system_hint`` is the system named by a 4.10+ system-id field; it wins
    over the talker.

    >>> satellite_id("GP", 12), satellite_id("GP", 40), satellite_id("GB", 40)
    (('GPS', 12), ('SBAS', 127), ('BeiDou', 40))
    >>> satellite_id("GN", 82), satellite_id("GN", 214), satellite_id("BD", 214)
    (('GLONASS', 18), ('BeiDou', 14), ('BeiDou', 14))
    """
    if number < 1:
        return None
    system = system_hint or _TALKER_SYSTEM.get(talker)
    if system == "GLONASS":
        if 65 <= number <= 96:
            return system, number - 64
        return (system, number) if number <= 32 else None
    if system == "Galileo":
        for base in (0, 100, 300):
            if 1 <= number - base <= 36:
                return system, number - base
        return None
    if system == "BeiDou":
        for base in (0, 200, 400):
            if 1 <= number - base <= 63:
                return system, number - base
        return None
    if system == "QZSS":
        if 1 <= number <= 10:
            return system, number
        return (system, number - 192) if 193 <= number <= 202 else None
    if system == "NavIC":
        return (system, number) if number <= 14 else None
    # GP, GN, unknown talkers and GPS system id: NMEA number ranges.
    if number <= 32:
        return "GPS", number
    if number <= 64:
        return "SBAS", number + 87
    if number <= 96:
        return "GLONASS", number - 64
    if 120 <= number <= 158:
        return "SBAS", number
    if 193 <= number <= 200:  # QZSS 193-199 (u-blox); 201+ under GN is BeiDou (SiRF), as gpsd reads it
        return "QZSS", number - 192
    if 201 <= number <= 263:
        return "BeiDou", number - 200
    if 301 <= number <= 336:
        return "Galileo", number - 300
    if 401 <= number <= 463:
        return "BeiDou", number - 400
    return None


_tuple_new = tuple.__new__
_satellite_id_cached = functools.lru_cache(maxsize=4096)(satellite_id)


def _single_hex(text: str) -> int | None:
    if len(text) == 1 and text in "0123456789ABCDEFabcdef":
        return int(text, 16)
    return None


def gsv_fields(talker: str, data: list[str]) -> GsvFields:
    """Interpret the data fields (after the address) of a GSV sentence.

    Raises ValueError for a malformed sentence.

    >>> g = gsv_fields("GP", "3,3,12,26,04,276,,27,15,218,31,29,24,004,13,30,00,159,,1".split(","))
    >>> g.signal, [s.prn for s in g.satellites], g.satellites[1].cn0_dbhz
    (1, [26, 27, 29, 30], 31.0)
    >>> [s.prn for s in gsv_fields("GA", "3,3,09,33,62,034,08,7".split(",")).satellites]
    [33]
    """
    if len(data) < 3:
        raise ValueError("GSV shorter than its header")
    n_msgs, msg_num = int(data[0]), int(data[1])
    n_in_view = int(data[2]) if data[2] else 0
    if not 1 <= msg_num <= n_msgs or n_msgs > 99 or not 0 <= n_in_view <= 999:
        raise ValueError(f"GSV header {data[:3]} inconsistent")
    body = data[3:]
    rem = len(body) % 4
    signal = None
    system_hint = None
    if rem == 1:
        signal = _single_hex(body[-1])
        if signal is None and body[-1]:
            raise ValueError(f"GSV signal id {body[-1]!r} is not one hexadecimal digit")
        body = body[:-1]
    elif rem == 2 and _single_hex(body[-2]) is not None and body[-1] in ("1", "2", "3", "4", "5", "6"):
        # Quectel PQGSV: signal id then NMEA system id.
        signal = _single_hex(body[-2])
        system_hint = NMEA_SYSTEM_IDS[int(body[-1])]
        body = body[:-2]
    satellites = []
    append = satellites.append
    one = _gsv_satellite
    n_body = len(body)
    if n_body % 4:
        body = body + [""] * (4 - n_body % 4)  # a last satellite cut short: its missing fields are empty
    for i in range(0, n_body, 4):
        prn_t = body[i]
        if not prn_t:
            continue  # empty padding group, or a satellite without number (Quectel): nothing to key it by
        sat = one(talker, system_hint, prn_t, body[i + 1], body[i + 2], body[i + 3])
        if sat is not None:
            append(sat)
    return GsvFields(n_msgs, msg_num, n_in_view, signal, tuple(satellites))


@functools.lru_cache(maxsize=16384)
def _gsv_satellite(talker: str, system_hint: str | None, prn_t: str, el_t: str, az_t: str, cn_t: str
                   ) -> GsvSatellite | None:
    """One ``prn,el,az,cn0`` group of a GSV sentence (None: a number no system owns); ValueError when invalid.

    Memoised: a satellite's group repeats verbatim over many epochs (elevation and azimuth move
    by whole degrees every few minutes), so each distinct group is interpreted once.
    """
    sat = _satellite_id_cached(talker, int(prn_t), system_hint)
    el = float(el_t) if el_t else None
    az = float(az_t) if az_t else None
    cn0 = float(cn_t) if cn_t else None
    if (el is not None and not -90.0 <= el <= 90.0) or (az is not None and not 0.0 <= az <= 360.0) \
            or (cn0 is not None and not 0.0 <= cn0 <= 99.0):
        raise ValueError(f"GSV satellite fields {[prn_t, el_t, az_t, cn_t]} out of range")
    if sat is None:
        return None
    if cn0 == 0.0:
        cn0 = None  # 0 dB-Hz is "not tracked" for many receivers (NMEA: null when not tracking)
    # = GsvSatellite(...), skipping its Python-level __new__
    return _tuple_new(GsvSatellite, (sat[0], sat[1], el, az, cn0))


def _dop(text: str) -> float | None:
    """A DOP field; empty, non-positive or >= 99 (the "invalid" placeholder many receivers send) → None."""
    if not text:
        return None
    value = float(text)
    return value if 0.0 < value < 99.0 else None


def gsa_fields(talker: str, data: list[str]) -> GsaFields:
    """Interpret the data fields of a GSA sentence (NMEA 2.x 17 fields, 4.10+ 18 with system id).

    >>> g = gsa_fields("GN", "A,3,82,66,81,,,,,,,,,,1.05,0.64,0.83,2".split(","))
    >>> g.system, g.used, g.hdop
    ('GLONASS', (('GLONASS', 18), ('GLONASS', 2), ('GLONASS', 17)), 0.64)
    """
    if len(data) < 5:
        raise ValueError("GSA too short")
    system = None
    if len(data) == 18:
        # 4.10+: system id; some SiRF receivers put a fourth DOP (TDOP, "3.3") there instead.
        sid = _single_hex(data[17])
        if sid is not None:
            system = NMEA_SYSTEM_IDS.get(sid)
        prn_fields, dops = data[2:14], data[14:17]
    else:
        prn_fields, dops = data[2:-3], data[-3:]
    mode = int(data[1]) if data[1] else None
    if mode is not None and not 1 <= mode <= 3:
        raise ValueError(f"GSA fix mode {mode} not in 1..3")
    used = []
    for text in prn_fields:
        if text:
            sat = _satellite_id_cached(talker, int(text), system)
            if sat is not None:
                used.append(sat)
    return GsaFields(mode, tuple(used), _dop(dops[0]), _dop(dops[1]), _dop(dops[2]), system)


def parse_time_of_day(text: str) -> float | None:
    """``hhmmss[.sss]`` → seconds of the UTC day, ``None`` when empty; ValueError when invalid.

    >>> parse_time_of_day("003956.50")
    2396.5
    """
    if not text:
        return None
    if len(text) < 6 or not text[:6].isdigit():
        raise ValueError(f"time {text!r} is not hhmmss.ss")
    h, m, s = int(text[0:2]), int(text[2:4]), float(text[4:])
    if h > 23 or m > 59 or not 0.0 <= s < 61.0:
        raise ValueError(f"time {text!r} out of range")
    return h * 3600.0 + m * 60.0 + s


def parse_ddmmyy(text: str):
    """RMC date ``ddmmyy`` → :class:`datetime.date` (years 80-99 → 19xx, else 20xx), None when empty."""
    if not text:
        return None
    if len(text) != 6 or not text.isdigit():
        raise ValueError(f"date {text!r} is not ddmmyy")
    yy = int(text[4:6])
    return _dt.date(1900 + yy if yy >= 80 else 2000 + yy, int(text[2:4]), int(text[0:2]))


def parse_latlon(value: str, hemi: str, is_lat: bool) -> float | None:
    """``(d)ddmm.mmmm`` plus hemisphere → signed degrees; None when either is empty.

    >>> round(parse_latlon("4552.65403", "S", True), 9)
    -45.877567167
    """
    if not value or not hemi:
        return None
    dot = value.find(".")
    if dot < 0:
        dot = len(value)
    if dot < 3:
        raise ValueError(f"coordinate {value!r} lacks degrees")
    degrees = int(value[:dot - 2])
    minutes = float(value[dot - 2:])
    if not 0.0 <= minutes < 60.0:
        raise ValueError(f"coordinate minutes {minutes} out of range")
    deg = degrees + minutes / 60.0
    if deg > (90.0 if is_lat else 180.0):
        raise ValueError(f"coordinate {value!r} out of range")
    if hemi in ("S", "W"):
        return -deg
    if hemi not in ("N", "E"):
        raise ValueError(f"hemisphere {hemi!r}")
    return deg


def decode_pynmea2(msg):
    """A pynmea2 sentence → ``(talker, sentence_type, data fields)``, the input of the interpreters here.

    The GSV/GSA attribute views of pynmea2 are bypassed (see the module
    docstring); its field split, which is correct, is used as is.
    """
    return msg.talker, msg.sentence_type, list(msg.data)
