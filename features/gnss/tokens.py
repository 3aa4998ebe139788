"""Turning bytes into checked, comma-split NMEA sentences, counting what is skipped.

Two equivalent paths (tests hold them equal on every real log and under fuzzing):

* :func:`fields_from_lines` — streaming, one line at a time: split at every
  ``$`` (sentences glued by a lost newline are recovered), checksum per
  sentence (:func:`parse_sentence`, or ``pynmea2.parse(check=True)`` through
  :func:`pynmea2_fields`);
* :func:`fields_from_buffer` — a whole file at once, with the line and ``$``
  splitting and the checksums vectorised in numpy (prefix XOR); its sentences'
  byte ranges (:func:`sentence_spans`) are what the compiled epoch assembly
  (:mod:`features.gnss.assemble`) reads.

Why not pynmea2 alone: it costs about 8-11 µs a sentence here, as much as the
whole GNSS path may spend (≥ 40 % of pynmea2's bare rate, ``bench/bench_gnss.py``);
a checksum and ``str.split`` cost about 3 µs, the vectorised path less. pynmea2
stays the reference the tests compare against.

Sentence types the reader does not use (VTG, TXT, vendor messages) are counted
by address and not validated.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

__all__ = ["ReadStats", "parse_sentence", "pynmea2_fields", "fields_from_lines", "fields_from_buffer",
           "sentence_spans",
           "TIMED_TYPES", "USED_TYPES"]

TIMED_TYPES = frozenset(("GGA", "RMC", "GNS", "GLL", "ZDA", "GST", "GBS"))
"""Sentences that carry the fix time."""

USED_TYPES = TIMED_TYPES | {"GSA", "GSV"}
"""Sentence types the reader interprets."""


@dataclass
class ReadStats:
    """What the reader saw and skipped. ``skipped`` sums the sentence-level failures.

    ``no_time``: a GGA/RMC/GNS/GLL/ZDA/GST/GBS whose time field is empty
    (receivers before their first fix); ``other_types``: valid sentences of
    types the reader does not use (VTG, TXT, vendor messages), not skipped.
    """

    lines: int = 0
    sentences: int = 0
    used_sentences: int = 0
    comment_lines: int = 0
    non_nmea_lines: int = 0
    bad_checksum: int = 0
    no_checksum: int = 0
    truncated: int = 0
    malformed: int = 0
    no_time: int = 0
    time_jumps: int = 0
    time_resets: int = 0
    gsv_incomplete: int = 0
    gsv_signal_continued: int = 0
    """GSV parts that continue a group under another signal id (Quectel LC79D): joined, not incomplete."""
    gsv_before_time: int = 0
    """GSV sentences before the first timed sentence (no epoch to hold them)."""
    other_types: Counter = field(default_factory=Counter)

    @property
    def skipped(self) -> int:
        return (self.non_nmea_lines + self.bad_checksum + self.no_checksum + self.truncated
                + self.malformed + self.no_time + self.time_jumps)

    def summary(self) -> str:
        """One line for a user, e.g. ``skipped 3 (bad checksum 2, truncated 1)``."""
        parts = [(n, getattr(self, n)) for n in ("bad_checksum", "no_checksum", "truncated", "malformed",
                                                 "no_time", "time_jumps", "non_nmea_lines")]
        detail = ", ".join(f"{n.replace('_', ' ')} {v}" for n, v in parts if v)
        text = f"{self.sentences} sentences, {self.used_sentences} used, skipped {self.skipped}"
        if detail:
            text += f" ({detail})"
        if self.time_resets:
            text += f"; time base reset {self.time_resets}x"
        if self.gsv_incomplete:
            text += f"; {self.gsv_incomplete} incomplete GSV groups"
        if self.gsv_signal_continued:
            text += f"; {self.gsv_signal_continued} GSV groups ended under another signal id (joined)"
        return text


def _checksum_ok(body: str, given: str) -> bool:
    """XOR of the body's bytes against the two hex digits given (a plain loop: measured faster
    here than folding one big integer or a numpy reduction on 80-byte sentences)."""
    if len(given) != 2 or given[0] not in _HEX_DIGITS or given[1] not in _HEX_DIGITS:
        return False  # int(" 6", 16), int("+6", 16) and int("0\r", 16) would all read as numbers
    c = 0
    for byte in body.encode("latin-1", "replace"):
        c ^= byte
    return c == int(given, 16)


_HEX_DIGITS = frozenset("0123456789ABCDEFabcdef")


def _address_ok(address: str) -> bool:
    """An address field as NMEA 0183 writes it: three or more upper-case letters and digits (``GPGSV``).

    ``GbGSV`` (one flipped bit) is garbage, not BeiDou's ``GB`` talker: pynmea2 would upper-case it.
    """
    return len(address) >= 3 and address.isalnum() and address == address.upper()


def parse_sentence(fragment: str, stats: ReadStats, require_checksum: bool = True) -> list[str] | None:
    """Check and split one sentence (text after ``$``); None (and counted) when unusable.

    Returns the comma-split fields, first the address (``GPGSV``).

    >>> parse_sentence("GPGSA,A,1,,,,,,,,,,,,,,,*1E", ReadStats())[:3]
    ['GPGSA', 'A', '1']
    """
    star = fragment.rfind("*")
    if star < 0:
        if require_checksum:  # missing, or cut off with the end of the line: indistinguishable
            stats.no_checksum += 1
            return None
        body = fragment
    else:
        body = fragment[:star]
        given = fragment[star + 1:star + 3]
        if len(given) < 2:
            stats.truncated += 1
            return None
        if not _checksum_ok(body, given):
            stats.bad_checksum += 1
            return None
        if "*" in body:  # '*' is NMEA 0183's reserved checksum delimiter, never data: a field holding one
            stats.malformed += 1  # is garbled (pynmea2 rejects it too), whatever its checksum says
            return None
    fields = body.split(",")
    address = fields[0]
    if not _address_ok(address):
        stats.truncated += 1
        return None
    return fields


def pynmea2_fields(fragment: str, stats: ReadStats, require_checksum: bool = True) -> list[str] | None:
    """Same contract as :func:`parse_sentence`, tokenised by ``pynmea2.parse(check=True)``.

    pynmea2 has no class for some sentences (Quectel ``$PQGSV``, vendor
    messages); for a sentence whose checksum pynmea2 accepted but whose format
    it rejects, the raw comma split is returned, as the fast path does.
    """
    import pynmea2

    star = fragment.rfind("*")
    if star < 0 and require_checksum:
        stats.no_checksum += 1
        return None
    if star >= 0:
        fragment = fragment[:star + 3]
    try:
        msg = pynmea2.parse("$" + fragment, check=require_checksum)
    except pynmea2.ChecksumError:
        stats.bad_checksum += 1
        return None
    except Exception:  # ParseError, and bare ValueError/TypeError/AttributeError on some garbage
        fields = parse_sentence(fragment, ReadStats(), require_checksum)
        if fields is None or fields[0][-3:] in USED_TYPES and fields[0][0] != "P":
            stats.truncated += 1
            return None
        return fields
    if isinstance(msg, pynmea2.ProprietarySentence) or not hasattr(msg, "talker"):
        return fragment[:star].split(",") if star >= 0 else fragment.split(",")
    if not _address_ok(fragment.split(",", 1)[0]):  # pynmea2 upper-cases a garbled "GbGSV"; the fast path refuses it
        stats.truncated += 1
        return None
    return [msg.talker + msg.sentence_type, *msg.data]


def _is_unused(head: str) -> bool:
    """True for addresses of sentence types the reader does not use (VTG, TXT, vendor messages).

    A used type has a five-character address, talker and type (``GPGSV``; Quectel's ``PQGSV``):
    a longer one ending in a used type (``GabcdefLGSV``, garbage that pynmea2 rejects too; no
    receiver of gpsd's 199 regression logs sends one) is not read as that type.
    """
    return len(head) != 5 or head[2:] not in USED_TYPES or (head[:1] == "P" and head[:2] != "PQ")


def fields_from_lines(lines: Iterable[bytes | str], stats: ReadStats, tokenise, require_checksum: bool):
    """Checked, comma-split sentences of the used types from lines of text (the streaming path)."""
    for raw in lines:
        stats.lines += 1
        line = raw.decode("latin-1") if isinstance(raw, (bytes, bytearray)) else raw
        line = line.strip()
        if not line:
            continue
        if line[0] == "#":
            stats.comment_lines += 1
            continue
        pieces = line.split("$")
        if len(pieces) == 1:
            stats.non_nmea_lines += 1
            continue
        for fragment in pieces[1:]:
            if len(pieces) > 2:
                fragment = fragment.rstrip()  # right only: what follows '$' is the sentence, as sent
            if not fragment:
                continue
            stats.sentences += 1
            # Types the reader does not use are counted by address and not validated:
            # checking a sentence nobody reads costs a third of the parse.
            head = fragment[:fragment.find(",")] if "," in fragment else fragment
            if _is_unused(head):
                stats.other_types[head[:8]] += 1
                continue
            fields = tokenise(fragment, stats, require_checksum)
            if fields is not None:
                yield fields


_HEX = np.full(256, -1, dtype=np.int16)
for _i, _ch in enumerate(b"0123456789ABCDEF"):
    _HEX[_ch] = _i
for _i, _ch in enumerate(b"abcdef"):
    _HEX[_ch] = 10 + _i
_SPACE = np.array([chr(_i).isspace() for _i in range(256)])
"""Bytes that ``str.strip`` removes from Latin-1 text (includes \\x85 and \\xa0)."""
_ADDRESS_BYTE = np.array([chr(_i).isalnum() and chr(_i).upper() == chr(_i) for _i in range(256)])
"""Bytes an address may hold (:func:`_address_ok`): ``str.isalnum`` in Latin-1 text and their own upper case."""
_USED_KIND_CODES = np.array(sorted((ord(k[0]) << 16) | (ord(k[1]) << 8) | ord(k[2]) for k in USED_TYPES))
"""The used sentence types as three-byte codes."""


def fields_from_buffer(buf: bytes, stats: ReadStats, require_checksum: bool):
    """:func:`fields_from_lines` over a whole file, with the line and ``$`` splitting and the
    checksums vectorised (numpy): the XOR of body bytes [a, b) is P[b] ^ P[a], P the prefix XOR
    of the file. Counts exactly what the line path counts (a test holds them equal on every log).
    """
    text = buf.decode("latin-1")
    for a, b in zip(*(x.tolist() for x in sentence_spans(buf, stats, require_checksum))):
        yield text[a:b].split(",")


def sentence_spans(buf: bytes, stats: ReadStats, require_checksum: bool) -> tuple[np.ndarray, np.ndarray]:
    """Where :func:`fields_from_buffer`'s sentences lie in ``buf``: (starts, ends), int64 arrays of
    shape (n_sentences,), the sentence being ``buf[start:end]`` (address first, no ``$``, no checksum).
    Counts in ``stats`` what the tokenising skipped, as :func:`fields_from_lines` does."""
    data = np.frombuffer(buf, dtype=np.uint8)
    n = data.size
    none = np.zeros(0, dtype=np.int64)
    if n == 0:
        return none, none
    text = buf.decode("latin-1")
    nl = np.flatnonzero(data == 10)
    line_start = np.concatenate([[0], nl + 1])
    line_end = np.concatenate([nl, [n]])
    if line_start[-1] == n:  # nothing after the final newline
        line_start, line_end = line_start[:-1], line_end[:-1]
    stats.lines += int(line_start.size)
    dollars = np.flatnonzero(data == 36)
    line_of = np.searchsorted(line_start, dollars, side="right") - 1
    has_dollar = np.zeros(line_start.size, dtype=bool)
    has_dollar[line_of] = True
    # lines whose first character decides their kind: '#' comments, blank lines, no '$' at all
    first = data[np.minimum(line_start, n - 1)]
    comment = np.zeros(line_start.size, dtype=bool)
    for i in np.flatnonzero(~has_dollar | _SPACE[first] | (first == 35)).tolist():
        stripped = text[line_start[i]:line_end[i]].strip()
        if not stripped:
            continue
        if stripped[0] == "#":
            comment[i] = True
        elif not has_dollar[i]:
            stats.non_nmea_lines += 1
    stats.comment_lines += int(comment.sum())
    keep = ~comment[line_of]
    dollars, line_of = dollars[keep], line_of[keep]
    if dollars.size == 0:
        return none, none
    end = np.minimum(np.concatenate([dollars[1:], [n]]), line_end[line_of])  # next '$' or end of line
    stars = np.flatnonzero(data == 42)
    k = np.searchsorted(stars, end, side="left") - 1  # last '*' before the fragment's end
    star = np.where(k >= 0, stars[np.maximum(k, 0)], -1) if stars.size else np.full(dollars.size, -1)
    has_star = star > dollars
    # a second '*' inside the fragment (before the checksum's): malformed, decided in the loop below
    inner_star = has_star & (k >= 1) & (stars[np.maximum(k - 1, 0)] > dollars) if stars.size else has_star
    g1 = _HEX[data[np.clip(star + 1, 0, n - 1)]]
    g2 = _HEX[data[np.clip(star + 2, 0, n - 1)]]
    given = np.where(has_star & (g1 >= 0) & (g2 >= 0), g1 * 16 + g2, -1)
    prefix = np.concatenate([[0], np.bitwise_xor.accumulate(data)]).astype(np.int16)
    ok = has_star & (given == (prefix[np.where(has_star, star, 0)] ^ prefix[dollars + 1]))
    # The common sentence decided in numpy: a checksum that holds with both digits before the fragment's
    # end, a five-character alphanumeric address followed by a comma, of a type the reader uses (not a
    # vendor 'P' sentence but Quectel's 'PQ'). For these the loop below only splits the body.
    at = dollars[:, None] + np.arange(1, 7)[None, :]
    head = data[np.minimum(at, n - 1)] * (at < end[:, None])
    kind = (head[:, 2].astype(np.int64) << 16) | (head[:, 3].astype(np.int64) << 8) | head[:, 4]
    fast = (ok & ~inner_star & (star + 2 < end) & (head[:, 5] == 44) & _ADDRESS_BYTE[head[:, :5]].all(axis=1)
            & np.isin(kind, _USED_KIND_CODES) & ((head[:, 0] != 80) | (head[:, 1] == 81)))
    starts = dollars + 1
    ends = star.copy()
    keep = fast.copy()
    stats.sentences += int(fast.sum())
    for k in np.flatnonzero(~fast).tolist():
        d, e, st_, has, good = int(dollars[k]), int(end[k]), int(star[k]), bool(has_star[k]), bool(ok[k])
        fragment = text[d + 1:e].rstrip()
        if not fragment:
            continue
        dig = has and st_ + 3 <= d + 1 + len(fragment)  # two characters after '*' before trailing space
        stats.sentences += 1
        head = fragment[:fragment.find(",")] if "," in fragment else fragment
        if _is_unused(head):
            stats.other_types[head[:8]] += 1
            continue
        if not has:
            if require_checksum:
                stats.no_checksum += 1
                continue
            ends[k] = d + 1 + len(fragment)
        elif not dig:
            stats.truncated += 1
            continue
        elif not good:
            stats.bad_checksum += 1
            continue
        elif "*" in text[d + 1:st_]:
            stats.malformed += 1
            continue
        if not _address_ok(text[d + 1:ends[k]].split(",", 1)[0]):
            stats.truncated += 1
            continue
        keep[k] = True
    return starts[keep].astype(np.int64), ends[keep].astype(np.int64)
