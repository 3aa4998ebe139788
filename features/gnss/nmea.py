"""Read NMEA 0183 (2.3 to 4.11) into epochs, one per fix time.

An epoch gathers every sentence between two changes of the fix time: GGA,
RMC, GNS, GLL, ZDA, GST and GBS carry the time and open a new epoch when it
differs from the current one; GSA and GSV carry none and belong to the epoch
open when they arrive. No sentence order is assumed otherwise. Multi-part GSV
is assembled per talker and signal id (one satellite may be listed once per
signal); the satellites "used" are those of the epoch's GSA sentences.

Bad input is skipped and counted in :class:`ReadStats`, never fatal: bad or
missing checksums, truncated sentences, binary garbage (a line is split at
every ``$``, so sentences glued together by a lost newline are recovered),
fields that do not parse, and time jumps backwards. A backwards jump that
persists (``resync_after`` consecutive timed sentences, e.g. a receiver that
reset its clock) is accepted as a new time base spliced one epoch interval
after the last epoch, so ``t_s`` never decreases. A file with no usable epoch
raises :class:`~features.errors.NmeaError`.

Parsing: :mod:`features.gnss.tokens` turns bytes into checked sentences (a
vectorised whole-file path by default, pynmea2 on request, both equal on every
real log; types not used, e.g. VTG and vendor messages, are counted, not
validated); :mod:`features.gnss.quirks` interprets their fields. A whole file
(:func:`read_nmea`, :func:`epochs_from_bytes`) is assembled by the compiled
:mod:`features.gnss.assemble` (the same rules, equal epochs and counts: tests),
into :class:`~features.gnss.assemble.EpochColumns` that :func:`read_nmea_columns`
returns as they are (a walk's GNSS stream: no Python object per satellite) and
:func:`read_nmea` as :class:`Epoch` objects; lines (:func:`iter_epochs`) and
pynmea2 go through :func:`_assemble`, the reference.
"""

from __future__ import annotations

import datetime as dt
import functools
import os
from dataclasses import dataclass
from operator import itemgetter
from pathlib import Path
from typing import Iterable, Iterator, Literal, NamedTuple, Sequence

import numpy as np

from features.errors import ConfigError, NmeaError
from features.gnss.assemble import COUNTER_NAMES, SYSTEM_CODES, EpochColumns, assemble_spans
from features.gnss.tokens import (  # noqa: F401 - ReadStats and parse_sentence are re-exported
    TIMED_TYPES, USED_TYPES, ReadStats, fields_from_buffer, fields_from_lines, parse_sentence, pynmea2_fields,
    sentence_spans,
)
from features.gnss.quirks import (
    FIX_QUALITY_FROM_MODE, gsa_fields, gsv_fields, parse_ddmmyy, parse_latlon, parse_time_of_day,
    primary_signal_rank as _primary_rank,
)

__all__ = ["Satellite", "Fix", "Gst", "Epoch", "ReadStats", "read_nmea", "iter_epochs", "epochs_from_bytes",
           "epochs_on_time_base", "read_nmea_columns", "epoch_columns", "EpochColumns",
           "parse_sentence"]

_TIMED = TIMED_TYPES
_USED_TYPES = USED_TYPES
_FIX_TYPES = frozenset(("GGA", "RMC", "GNS", "ZDA", "GST"))  # timed sentences that carry more than the time
_EPOCH_GAP_DEFAULT_S = 1.0
_FIRST_GNSS_YEAR = 1980
"""GPS time began on 1980-01-06: an earlier ZDA year is garbage (RMC's two-digit years map to 1980-2079)."""
_NAN = float("nan")
_tuple_new = tuple.__new__  # builds a NamedTuple without its Python-level __new__ (hot loop)
_SKY_CACHE_SIZE = 8192
"""Distinct GSV/GSA sentences remembered by one read (cleared when full)."""


class Satellite(NamedTuple):
    """One satellite (one signal of it) in view at an epoch; ``cn0_dbhz`` None when not tracked."""

    system: str
    prn: int
    signal: int | None
    el_deg: float | None
    az_deg: float | None
    cn0_dbhz: float | None
    used: bool


class Gst(NamedTuple):
    """The receiver's own error statistics of an epoch's fix (NMEA 0183 GST), metres, 1σ; None when empty.

    ``rms_m`` is the RMS of the pseudorange residuals (field 2), ``sigma_lat_m`` / ``sigma_lon_m`` /
    ``sigma_alt_m`` the standard deviations of latitude, longitude and altitude (fields 6–8).
    """

    rms_m: float | None
    sigma_lat_m: float | None
    sigma_lon_m: float | None
    sigma_alt_m: float | None


@dataclass(frozen=True)
class Fix:
    """The receiver's position solution at an epoch.

    ``quality`` uses the GGA code (0 none, 1 autonomous, 2 DGNSS, 3 PPS, 4 RTK
    fixed, 5 RTK float, 6 dead reckoning, 7 manual, 8 simulator); ``alt_m`` is
    above mean sea level and ``geoid_sep_m`` the geoid height, so the
    ellipsoidal height is their sum. ``mode`` is GSA's 1/2/3 (no fix, 2-D, 3-D).
    """

    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    geoid_sep_m: float | None
    quality: int
    n_used: int | None
    hdop: float | None
    pdop: float | None
    vdop: float | None
    mode: int | None

    @property
    def has_position(self) -> bool:
        return self.quality > 0 and self.lat_deg is not None and self.lon_deg is not None


@dataclass(frozen=True)
class Epoch:
    """All that a receiver reported for one fix time.

    ``t_s`` counts seconds from the first epoch of the file (monotonic);
    ``time_utc`` is the receiver's UTC time (None while no date was ever
    given); ``sky_reported`` is False for epochs without any GSV (receivers
    that report the sky every few fixes), whose ``satellites`` are then empty
    but not "none in view". ``satellites`` holds one entry per satellite per
    signal, in GSV order; :attr:`primary_satellites` one per satellite;
    ``gst`` the epoch's GST statistics when the receiver sent them (None
    otherwise).
    """

    t_s: float
    time_utc: dt.datetime | None
    time_of_day_s: float
    fix: Fix
    satellites: tuple[Satellite, ...]
    sky_reported: bool
    gst: Gst | None = None

    @functools.cached_property
    def primary_satellites(self) -> tuple[Satellite, ...]:
        """One entry per satellite: the one on its primary signal (the L1/G1/E1/B1 one), in GSV order.

        The entry of lowest :func:`~features.gnss.quirks.primary_signal_rank`: a stated primary
        signal first (GPS L1 C/A, Galileo E1-B/C, BeiDou B1I, ...), then an entry whose signal
        is not stated (no or an empty signal-id field, or "all signals"); a satellite listed
        only on secondary signals (L2, L5, E5a, B2I, ...) is left out. What the GNSS features
        and the C/N0 weighting of fixes read.
        """
        best: dict = {}
        for sat in self.satellites:
            rank = _primary_rank(sat.system, sat.signal)
            if rank is None:
                continue
            key = (sat.system, sat.prn)
            held = best.get(key)
            if held is None or rank < held[0]:
                best[key] = (rank, sat)
        if len(best) == len(self.satellites):
            return self.satellites
        return tuple(v[1] for v in best.values())

    @property
    def n_in_view(self) -> int:
        return len({(s.system, s.prn) for s in self.satellites})

    @property
    def n_tracked(self) -> int:
        return len({(s.system, s.prn) for s in self.satellites if s.cn0_dbhz is not None})

    def to_json_dict(self) -> dict:
        """The epoch as plain JSON types (the ``--epochs`` JSON-lines format).

        Times have a fixed precision: ``time`` ISO 8601 UTC with three decimals (``...T12:00:00.000Z``),
        ``t_s`` and ``time_of_day_s`` rounded to the millisecond.
        """
        f = self.fix
        from features.gnss.gpsd import iso_utc_ms

        return {
            "t_s": round(self.t_s, 3),
            "time": iso_utc_ms(self.time_utc),
            "time_of_day_s": round(self.time_of_day_s, 3),
            "fix": {"lat_deg": f.lat_deg, "lon_deg": f.lon_deg, "alt_m": f.alt_m, "geoid_sep_m": f.geoid_sep_m,
                    "quality": f.quality, "n_used": f.n_used, "hdop": f.hdop, "pdop": f.pdop, "vdop": f.vdop,
                    "mode": f.mode},
            "sky_reported": self.sky_reported,
            "gst": None if self.gst is None else self.gst._asdict(),
            "satellites": [{"system": s.system, "prn": s.prn, "signal": s.signal, "el_deg": s.el_deg,
                            "az_deg": s.az_deg, "cn0_dbhz": s.cn0_dbhz, "used": s.used} for s in self.satellites],
        }


class _Clock:
    """Orders fix times: time of day plus midnight rollovers (a decrease of more than 12 h).

    Dates (RMC, ZDA) only label epochs: cold-starting receivers report
    arbitrary dates (the gpsd coldboot log goes 2019 → 2006 → 2010 → 1999)
    while their time of day runs on smoothly.
    """

    def __init__(self):
        self.offset_s = 0.0
        self.backwards_run = 0
        self.reset_base()

    def reset_base(self):
        self.day = 0
        self.last_tod: float | None = None
        self.known: tuple[dt.date, int] | None = None  # (date, day index) last reported

    def candidate(self, tod: float) -> tuple[float, int]:
        day = self.day
        if self.last_tod is not None and tod < self.last_tod - 43_200.0:
            day += 1
        return day * 86_400.0 + tod + self.offset_s, day

    def accept(self, tod: float, day: int, date: dt.date | None):
        self.day, self.last_tod = day, tod
        if date is not None:
            self.known = (date, day)

    def date_of(self, day: int) -> dt.date | None:
        if self.known is None:
            return None
        try:
            return self.known[0] + dt.timedelta(days=day - self.known[1])
        except OverflowError:  # past 9999-12-31 (a ZDA year 9999 before midnight): no calendar date
            return None


class _EpochBuilder:
    __slots__ = ("rel_s", "tod", "day", "date", "gga", "gns", "rmc", "gst", "gsa", "sats", "sky")

    def __init__(self, rel_s: float, tod: float, day: int, date: dt.date | None):
        self.rel_s, self.tod, self.day, self.date = rel_s, tod, day, date
        self.gga = self.gns = self.rmc = self.gst = None
        self.gsa: list = []
        self.sats: dict = {}
        self.sky = False


def _fix_of(b: _EpochBuilder, used_count: int) -> Fix:
    pdop = hdop = vdop = mode = None
    for g in b.gsa:
        pdop = g.pdop if g.pdop is not None else pdop
        hdop = g.hdop if g.hdop is not None else hdop
        vdop = g.vdop if g.vdop is not None else vdop
        mode = g.mode if g.mode is not None else mode
    if b.gga is not None:
        lat, lon, alt, sep, quality, n_used, gga_hdop = b.gga
        return Fix(lat, lon, alt, sep, quality, n_used, gga_hdop if gga_hdop is not None else hdop, pdop, vdop, mode)
    if b.gns is not None:
        lat, lon, alt, sep, quality, n_used, gns_hdop = b.gns
        return Fix(lat, lon, alt, sep, quality, n_used, gns_hdop if gns_hdop is not None else hdop, pdop, vdop, mode)
    if b.rmc is not None:
        lat, lon, quality = b.rmc
        return Fix(lat, lon, None, None, quality, used_count or None, hdop, pdop, vdop, mode)
    return Fix(None, None, None, None, 0, used_count or None, hdop, pdop, vdop, mode)


def _opt_count(text: str) -> int | None:
    """An optional count of satellites (GGA/GNS field 7): None when empty, ValueError outside 0-999."""
    if not text:
        return None
    value = int(text)
    if not 0 <= value <= 999:
        raise ValueError(f"satellite count {text!r} out of range")
    return value


_MAX_ABS_NUMBER = 1.0e7
"""Largest magnitude accepted for a GGA/GNS number (altitude and geoid separation in metres, HDOP): beyond
any receiver's range; guards the sums downstream (altitude + separation) against overflow."""


def _opt_num(text: str) -> float | None:
    """An optional numeric field: None when empty; ValueError for ``nan``/``inf`` (Python's float()
    accepts them, NMEA has no such values) and for magnitudes beyond :data:`_MAX_ABS_NUMBER`."""
    if not text:
        return None
    value = float(text)
    if not abs(value) <= _MAX_ABS_NUMBER:
        raise ValueError(f"number {text!r} is not finite or out of range")
    return value


def _check_options(parser: str, resync_after: int) -> None:
    if parser not in ("fast", "pynmea2"):
        raise ConfigError(f"NMEA parser must be 'fast' or 'pynmea2', got {parser!r}")
    if not isinstance(resync_after, int) or resync_after < 1:
        raise ConfigError(f"resync_after must be a positive integer, got {resync_after!r}")


def iter_epochs(lines: Iterable[bytes | str], stats: ReadStats | None = None, *,
                parser: Literal["fast", "pynmea2"] = "fast", require_checksum: bool = True,
                resync_after: int = 5) -> Iterator[Epoch]:
    """Stream epochs from lines of NMEA text (bytes decoded as Latin-1, so garbage never raises).

    A timed sentence earlier than the open epoch is skipped (``time_jumps``),
    with the GSA/GSV that follow it, until time moves on; after
    ``resync_after`` consecutive such sentences the new time base is accepted.

    ``stats`` (a :class:`ReadStats`) is filled in as the lines are consumed.
    """
    stats = ReadStats() if stats is None else stats
    _check_options(parser, resync_after)
    tokenise = parse_sentence if parser == "fast" else pynmea2_fields
    return _assemble(fields_from_lines(lines, stats, tokenise, require_checksum), stats, resync_after)


def _finish(b: _EpochBuilder, first_rel: float) -> Epoch:
    """The epoch a builder collected, on the time base whose zero is the first epoch."""
    used = set()
    for g in b.gsa:
        used.update(g.used)
    # GSA names satellites, not signals: a signal listed without C/N0 is not tracked and
    # cannot contribute to the fix, so only tracked signals of a GSA satellite are "used"
    # (gpsd's rule too; it matters for 4.10+ receivers that list L2/L5 untracked).
    sats = tuple([_tuple_new(Satellite, (system, prn, sig, el, az, cn0, cn0 is not None and (system, prn) in used))
                  for (system, prn, sig), (_, _, el, az, cn0) in b.sats.items()])
    when = None
    if b.date is not None:
        when = (dt.datetime(b.date.year, b.date.month, b.date.day, tzinfo=dt.timezone.utc)
                + dt.timedelta(seconds=b.tod))
    return Epoch(b.rel_s - first_rel, when, b.tod, _fix_of(b, len(used)), sats, b.sky, b.gst)


def _add_gsv(current: _EpochBuilder, talker: str, payload, gsv_parts: dict, gsv_open: dict,
             stats: ReadStats) -> None:
    """One GSV part into the epoch: its satellites, and the bookkeeping of the talker's open group.

    Every entry is kept under its own signal id, (system, prn, signal): a second signal of a
    satellite is a second entry, never a replacement of the first (gpsd keeps one entry per
    satellite per signal too). Only the part numbering may span signal ids: dual-frequency
    receivers (Quectel LC79D) number one group across their L1 entries (untagged) and the L5 /
    E5a entries that follow (tagged ``8`` / ``1``) -- ``$GPGSV,3,1`` and ``3,2`` untagged, then
    ``$GPGSV,3,3,10,06,,,40,09,,,27,30,,,39,8`` re-lists PRNs 6, 9 and 30 on L5. A part that
    continues the talker's open group exactly (same part count, the next part number) under
    another signal id therefore completes that group (``gsv_signal_continued``) instead of
    counting as incomplete, while its entries stay on their own signal.
    """
    current.sky = True
    key = (talker, payload.signal)
    expected = gsv_parts.get(key, 1)
    if payload.msg_num != expected:
        open_group = gsv_open.get(talker)
        if (open_group is not None and payload.msg_num > 1
                and (open_group[1], open_group[3]) == (payload.n_msgs, payload.msg_num)):
            key = open_group[0]
            stats.gsv_signal_continued += 1
        else:
            stats.gsv_incomplete += 1
    gsv_parts[key] = payload.msg_num % payload.n_msgs + 1
    gsv_open[talker] = (key, payload.n_msgs, payload.n_in_view, gsv_parts[key])
    sats = current.sats
    signal = payload.signal
    for sat in payload.satellites:
        sats[(sat[0], sat[1], signal)] = sat


def _assemble(sentences: Iterable[list[str]], stats: ReadStats, resync_after: int) -> Iterator[Epoch]:
    """Epochs from checked, comma-split sentences (address first)."""
    clock = _Clock()
    current: _EpochBuilder | None = None
    first_rel: float | None = None
    last_t_s = None
    last_interval = _EPOCH_GAP_DEFAULT_S
    gsv_parts: dict = {}
    gsv_open: dict = {}  # talker -> (group key, n_msgs, n_in_view, next part) of its last GSV
    orphaned = False
    current_time_text = None
    sky_cache: dict = {}  # GSV/GSA fields -> their (immutable) interpretation

    for fields in sentences:
        address = fields[0]
        kind = address[2:]
        if len(address) != 5 or kind not in _USED_TYPES or address[0] == "P" and address[:2] != "PQ":
            stats.other_types[address[:8]] += 1
            continue
        talker = address[:2]
        data = fields[1:]
        try:
            if kind in _TIMED:
                time_text = data[4] if kind == "GLL" else data[0]
                if time_text == current_time_text and kind not in _FIX_TYPES:
                    stats.used_sentences += 1  # same fix time, nothing else used from it (hot path)
                    orphaned = False
                    clock.backwards_run = 0
                    continue
                tod = parse_time_of_day(time_text)
                if tod is None:
                    stats.no_time += 1
                    continue
                date = None
                if kind == "RMC" and len(data) > 8:
                    date = parse_ddmmyy(data[8])
                elif kind == "ZDA" and len(data) >= 4 and data[1] and data[2] and data[3]:
                    date = dt.date(int(data[3]), int(data[2]), int(data[1]))
                    if date.year < _FIRST_GNSS_YEAR:
                        raise ValueError(f"ZDA year {date.year} before GPS time began")
                payload = _timed_payload(kind, data)
            else:
                # GSV/GSA repeat verbatim from epoch to epoch (at 5 Hz half the GSV and nearly every GSA of
                # a walk): their interpretation, an immutable tuple, is looked up by the sentence's fields.
                key = (address, *data)
                payload = sky_cache.get(key)
                if payload is None:
                    payload = gsv_fields(talker, data) if kind == "GSV" else gsa_fields(talker, data)
                    if len(sky_cache) >= _SKY_CACHE_SIZE:
                        sky_cache.clear()
                    sky_cache[key] = payload
        except (ValueError, IndexError, OverflowError):
            stats.malformed += 1
            continue
        if kind in _TIMED:
            rel, day = clock.candidate(tod)
            if current is not None and rel < current.rel_s:
                clock.backwards_run += 1
                if clock.backwards_run < resync_after:
                    stats.time_jumps += 1
                    orphaned = True  # this cycle's GSA/GSV must not land in the earlier epoch
                    continue
                # The new time base persisted: splice it one epoch interval after the last epoch.
                current_time_text = None
                stats.time_resets += 1
                clock.reset_base()
                clock.offset_s = 0.0
                raw_rel, day = clock.candidate(tod)
                clock.offset_s = current.rel_s + last_interval - raw_rel
                rel, day = clock.candidate(tod)
            clock.backwards_run = 0
            orphaned = False
            clock.accept(tod, day, date)
            if current is None or rel != current.rel_s:
                if current is not None:
                    epoch = _finish(current, first_rel)
                    if last_t_s is not None and epoch.t_s > last_t_s:
                        last_interval = epoch.t_s - last_t_s
                    last_t_s = epoch.t_s
                    yield epoch
                current = _EpochBuilder(rel, tod, day, clock.date_of(day))
                current_time_text = time_text
                if first_rel is None:
                    first_rel = rel
                gsv_parts.clear()
                gsv_open.clear()
            elif date is not None:
                current.date = date
            stats.used_sentences += 1
            if kind == "GGA":
                current.gga = payload
            elif kind == "GNS":
                current.gns = payload
            elif kind == "RMC":
                current.rmc = payload
            elif kind == "GST" and payload is not None:
                current.gst = payload
            continue
        if current is None:
            if kind == "GSV":
                stats.gsv_before_time += 1
            continue  # sky data before any time: no epoch to attach it to
        if orphaned:
            stats.time_jumps += 1
            continue
        stats.used_sentences += 1
        if kind == "GSA":
            current.gsa.append(payload)
            continue
        _add_gsv(current, talker, payload, gsv_parts, gsv_open, stats)
    if current is not None:
        yield _finish(current, first_rel)


def _timed_payload(kind: str, data: list[str]):
    """Fix content of a timed sentence.

    GGA/GNS → (lat, lon, alt, sep, quality, n_used, hdop); RMC → (lat, lon, quality); GST → :class:`Gst`
    (None when it states neither σ_lat nor σ_lon); others None. A GST σ that is not a positive finite
    number (empty, 0, negative) is None.
    """
    if kind == "GST":
        vals = [_opt_num(data[i]) if len(data) > i else None for i in (1, 5, 6, 7)]
        vals = [v if v is not None and 0.0 < v < 1e6 else None for v in vals]
        return None if vals[1] is None and vals[2] is None else _tuple_new(Gst, vals)
    if kind == "GGA":
        lat = parse_latlon(data[1], data[2], True)
        lon = parse_latlon(data[3], data[4], False)
        quality = int(data[5]) if data[5] else 0
        if not 0 <= quality <= 9:
            raise ValueError(f"GGA quality {quality}")
        hdop = _opt_num(data[7])
        return (lat, lon, _opt_num(data[8]), _opt_num(data[10]) if len(data) > 10 else None,
                quality, _opt_count(data[6]), hdop if hdop is None or 0 < hdop < 99 else None)
    if kind == "GNS":
        lat = parse_latlon(data[1], data[2], True)
        lon = parse_latlon(data[3], data[4], False)
        modes = data[5]
        quality = max((FIX_QUALITY_FROM_MODE.get(c, 0) for c in modes if c in "ADPRF"), default=0)
        if quality == 0 and any(c == "E" for c in modes):
            quality = 6
        hdop = _opt_num(data[7])
        return (lat, lon, _opt_num(data[8]), _opt_num(data[9]) if len(data) > 9 else None,
                quality, _opt_count(data[6]), hdop if hdop is None or 0 < hdop < 99 else None)
    if kind == "RMC":
        lat = parse_latlon(data[2], data[3], True)
        lon = parse_latlon(data[4], data[5], False)
        quality = 0
        if data[1] == "A":
            mode = data[11] if len(data) > 11 else ""
            quality = FIX_QUALITY_FROM_MODE.get(mode[:1], 1) if mode else 1
        return (lat, lon, quality)
    return None


def epochs_from_bytes(buf: bytes, stats: ReadStats | None = None, *, require_checksum: bool = True,
                      resync_after: int = 5) -> list[Epoch]:
    """All epochs of a whole NMEA file's bytes (the vectorised fast path); never raises on content.

    Gives exactly what :func:`iter_epochs` gives on the same bytes split into lines.
    """
    stats = ReadStats() if stats is None else stats
    columns, epochs = _read_bytes(bytes(buf), stats, require_checksum, resync_after)
    return epochs if epochs is not None else _epochs_from_columns(columns)


def _read_bytes(buf: bytes, stats: ReadStats, require_checksum: bool, resync_after: int
                ) -> tuple[EpochColumns | None, list[Epoch] | None]:
    """The file's epochs as columns from the compiled assembly, or (None, epochs) from the reference
    assembler when a field needs Python's number parsing (:mod:`features.gnss.assemble`)."""
    if not isinstance(resync_after, int) or resync_after < 1:
        raise ConfigError(f"resync_after must be a positive integer, got {resync_after!r}")
    starts, ends = sentence_spans(buf, stats, require_checksum)
    data = np.frombuffer(buf, dtype=np.uint8)
    status, counts, epoch_f, epoch_i, sat_i, sat_f = assemble_spans(data, starts, ends, resync_after)
    if status != 0:
        text = buf.decode("latin-1")
        return None, list(_assemble((text[a:b].split(",") for a, b in zip(starts.tolist(), ends.tolist())), stats,
                                    resync_after))
    for name, value in zip(COUNTER_NAMES, counts.tolist()):
        setattr(stats, name, getattr(stats, name) + value)
    return EpochColumns(epoch_f, epoch_i, sat_i, sat_f), None


def _nones(values: np.ndarray, missing: np.ndarray) -> list:
    """``values`` as a list of Python scalars, None where ``missing``."""
    out = values.astype(object)
    out[missing] = None
    return out.tolist()


def _utc_times(date_ordinal: list, tod: list) -> list:
    """The UTC datetime of each epoch (None without a date), as :func:`_finish` builds it."""
    midnight: dict = {}
    out = []
    for day, seconds in zip(date_ordinal, tod):
        if day < 0:
            out.append(None)
            continue
        base = midnight.get(day)
        if base is None:
            base = midnight[day] = dt.datetime.fromordinal(day).replace(tzinfo=dt.timezone.utc)
        out.append(base + dt.timedelta(seconds=seconds))
    return out


def _epochs_from_columns(columns: EpochColumns) -> list[Epoch]:
    """The epochs :func:`features.gnss.assemble.assemble_spans` wrote as columns, as :func:`_finish` builds them."""
    epoch_f, epoch_i, sat_i, sat_f = columns.epoch_f, columns.epoch_i, columns.sat_i, columns.sat_f
    system = np.array(SYSTEM_CODES, dtype=object)[sat_i[:, 0]].tolist()
    signal = _nones(sat_i[:, 2], sat_i[:, 2] < 0)
    el, az, cn0 = (_nones(sat_f[:, j], np.isnan(sat_f[:, j])) for j in range(3))
    satellites = [_tuple_new(Satellite, row) for row in zip(system, sat_i[:, 1].tolist(), signal, el, az, cn0,
                                                             (sat_i[:, 3] != 0).tolist())]
    f = [_nones(epoch_f[:, j], np.isnan(epoch_f[:, j])) for j in range(epoch_f.shape[1])]
    t_s, tod = epoch_f[:, 0].tolist(), epoch_f[:, 1].tolist()
    date_ord, quality, sky, has_gst, first, end = (epoch_i[:, j].tolist() for j in (0, 1, 4, 5, 6, 7))
    n_used, mode = (_nones(epoch_i[:, j], epoch_i[:, j] < 0) for j in (2, 3))
    when = _utc_times(date_ord, tod)
    epochs = []
    for i in range(len(t_s)):
        fix = Fix(f[2][i], f[3][i], f[4][i], f[5][i], quality[i], n_used[i], f[6][i], f[7][i], f[8][i], mode[i])
        gst = _tuple_new(Gst, (f[9][i], f[10][i], f[11][i], f[12][i])) if has_gst[i] else None
        epochs.append(Epoch(t_s[i], when[i], tod[i], fix, tuple(satellites[first[i]:end[i]]), bool(sky[i]), gst))
    return epochs


def epoch_columns(epochs: Sequence[Epoch] | EpochColumns, satellites: bool = True) -> EpochColumns:
    """Epochs as :class:`~features.gnss.assemble.EpochColumns` (columns given are returned as they are);
    ``satellites=False``: the epochs' columns only, no satellite rows (each epoch's range empty)."""
    if isinstance(epochs, EpochColumns):
        return epochs
    code = {name: k for k, name in enumerate(SYSTEM_CODES)}
    sats = [s for e in epochs for s in e.satellites] if satellites else []
    counts = np.fromiter((len(e.satellites) if satellites else 0 for e in epochs), dtype=np.int64,
                         count=len(epochs))
    end = np.cumsum(counts)
    sat_i = np.zeros((len(sats), 4), dtype=np.int64)
    sat_f = np.zeros((len(sats), 3))
    if sats:
        n = len(sats)
        # per field (zip(*sats) would build 72,000 iterators for a 10-minute walk)
        system, prn, signal, el, az, cn0, used = (list(map(itemgetter(k), sats)) for k in range(7))
        sat_i[:, 0] = np.fromiter(map(code.__getitem__, system), dtype=np.int64, count=n)
        sat_i[:, 1] = np.fromiter(prn, dtype=np.int64, count=n)
        sat_i[:, 2] = np.fromiter((-1 if v is None else v for v in signal), dtype=np.int64, count=n)
        sat_i[:, 3] = np.fromiter(used, dtype=bool, count=n)
        for j, values in enumerate((el, az, cn0)):
            sat_f[:, j] = np.fromiter((_NAN if v is None else v for v in values), dtype=float, count=n)
    fixes = [e.fix for e in epochs]
    gsts = [e.gst if e.gst is not None else (None,) * 4 for e in epochs]
    epoch_f = np.zeros((len(epochs), 13))
    epoch_i = np.zeros((len(epochs), 8), dtype=np.int64)
    if epochs:
        epoch_f[:, 0] = [e.t_s for e in epochs]
        epoch_f[:, 1] = [e.time_of_day_s for e in epochs]
        for j, name in enumerate(("lat_deg", "lon_deg", "alt_m", "geoid_sep_m", "hdop", "pdop", "vdop")):
            epoch_f[:, 2 + j] = np.array([getattr(f, name) for f in fixes], dtype=float)
        epoch_f[:, 9:] = np.array(gsts, dtype=float).reshape(-1, 4)
        # the date of an epoch: its UTC time less its time of day (23:59:60.5 is still the day before)
        epoch_i[:, 0] = [-1 if e.time_utc is None
                         else (e.time_utc - dt.timedelta(seconds=e.time_of_day_s)).toordinal() for e in epochs]
        epoch_i[:, 1] = [f.quality for f in fixes]
        epoch_i[:, 2] = np.nan_to_num(np.array([f.n_used for f in fixes], dtype=float), nan=-1.0)
        epoch_i[:, 3] = np.nan_to_num(np.array([f.mode for f in fixes], dtype=float), nan=-1.0)
        epoch_i[:, 4] = [e.sky_reported for e in epochs]
        epoch_i[:, 5] = [e.gst is not None for e in epochs]
        epoch_i[:, 6], epoch_i[:, 7] = end - counts, end
    return EpochColumns(epoch_f, epoch_i, sat_i, sat_f)


def _no_epoch_error(path: Path, stats: ReadStats) -> NmeaError:
    if stats.gsv_before_time:
        return NmeaError(f"{path}: {stats.gsv_before_time} GSV sentences list satellites in view, but no "
                         f"sentence carries a time (GGA, RMC, GNS, GLL or ZDA), so they cannot be placed "
                         f"on a time base; {stats.summary()}")
    return NmeaError(f"{path}: no usable epoch (no fix and no satellites in view) in "
                     f"{stats.lines} lines; {stats.summary()}")


def read_nmea_columns(path: str | os.PathLike, *, require_checksum: bool = True, resync_after: int = 5
                      ) -> tuple[EpochColumns, ReadStats]:
    """:func:`read_nmea` (fast parser) as :class:`~features.gnss.assemble.EpochColumns`: the same epochs,
    without a Python object per satellite (what a walk's GNSS stream reads)."""
    path = Path(path)
    stats = ReadStats()
    try:
        columns, epochs = _read_bytes(path.read_bytes(), stats, require_checksum, resync_after)
    except FileNotFoundError:
        raise NmeaError(f"NMEA file {path} does not exist") from None
    except IsADirectoryError:
        raise NmeaError(f"NMEA path {path} is a directory, not a file") from None
    columns = columns if columns is not None else epoch_columns(epochs)
    has_position = ((columns.col("quality") > 0) & ~np.isnan(columns.col("lat_deg"))
                    & ~np.isnan(columns.col("lon_deg")))
    if not (has_position | (columns.col("sky_reported") != 0)).any():
        raise _no_epoch_error(path, stats)
    return columns, stats


def read_nmea(path: str | os.PathLike, *, parser: Literal["fast", "pynmea2"] = "fast",
              require_checksum: bool = True, resync_after: int = 5) -> tuple[list[Epoch], ReadStats]:
    """Read a whole NMEA file into epochs and the statistics of what was skipped.

    Raises NmeaError when the file holds no usable epoch (one with a fix or a
    reported sky), DataError subclasses only; never a parsing exception.
    """
    path = Path(path)
    _check_options(parser, resync_after)
    stats = ReadStats()
    try:
        if parser == "fast":
            epochs = epochs_from_bytes(path.read_bytes(), stats, require_checksum=require_checksum,
                                       resync_after=resync_after)
        else:
            with path.open("rb") as fh:
                epochs = list(iter_epochs(fh, stats, parser=parser, require_checksum=require_checksum,
                                          resync_after=resync_after))
    except FileNotFoundError:
        raise NmeaError(f"NMEA file {path} does not exist") from None
    except IsADirectoryError:
        raise NmeaError(f"NMEA path {path} is a directory, not a file") from None
    if not any(e.sky_reported or e.fix.has_position for e in epochs):
        raise _no_epoch_error(path, stats)
    return epochs, stats


def epochs_on_time_base(epochs: list[Epoch] | EpochColumns, start_utc) -> list[Epoch] | EpochColumns:
    """Shift the epochs' ``t_s`` so that 0 is ``start_utc`` (a walk's time base).

    ``start_utc`` is a timezone-aware datetime (naive is taken as UTC). Every
    epoch that carries a date (RMC/ZDA) implies a shift, (UTC − start) − t_s;
    the median of them is taken, not the first one's: a receiver's first dated
    epochs after a cold start can carry a bogus date (the firmware's build date,
    1980-01-06, a week-rollover date) until it has decoded the real one, and one
    such epoch would move every epoch by years. A file without any date raises
    :class:`NmeaError`. Epochs given as :class:`~features.gnss.assemble.EpochColumns` come back as such.
    """
    import dataclasses
    import statistics

    if start_utc.tzinfo is None:
        start_utc = start_utc.replace(tzinfo=dt.timezone.utc)
    if isinstance(epochs, EpochColumns):
        t_s = epochs.col("t_s")
        dated = np.flatnonzero(epochs.col("date_ordinal") >= 0)
        when = _utc_times(epochs.col("date_ordinal")[dated].tolist(), epochs.col("time_of_day_s")[dated].tolist())
        pairs = zip(when, t_s[dated].tolist())
    else:
        pairs = ((e.time_utc, e.t_s) for e in epochs if e.time_utc is not None)
    shifts = [(when - start_utc).total_seconds() - t for when, t in pairs]
    if not shifts:
        raise NmeaError("the NMEA file carries no date (no RMC/ZDA), so it cannot be put on the walk's time base")
    shift = statistics.median_low(shifts)
    if isinstance(epochs, EpochColumns):
        return epochs if shift == 0.0 else epochs.with_t_s(t_s + shift)
    if shift == 0.0:
        return list(epochs)
    return [dataclasses.replace(e, t_s=e.t_s + shift) for e in epochs]
