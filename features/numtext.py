"""Decimal numbers read from bytes, compiled (numba), bit-identical to Python's ``float()`` and ``int()``.

Only the canonical spelling is read: one optional sign, digits, one optional decimal point, at most 15
significant digits and 22 decimals. Such a decimal ``M / 10^k`` with ``M < 2^53`` and ``k ≤ 22`` is one
correctly rounded division of two exact doubles (Clinger 1990, "How to read floating point numbers
accurately", PLDI '90, the "fast path"), hence the double that Python's correctly rounded ``float()`` (and
numpy's text reader, which calls it) gives. Every other spelling either one would accept (``1e3``, ``nan``,
``1_0``, blanks, more digits) is reported, so that the caller hands the text to them instead.

Numba's on-disk cache of a compiled caller in another module (:mod:`features.gnss.assemble`) is keyed on
that module's file only: after a change here, delete its cache (``features/gnss/__pycache__/assemble.*.nb?``)
or it keeps the old readers inlined.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["OK", "EMPTY", "INVALID", "FALLBACK", "read_int", "read_float", "read_csv_table"]

OK, EMPTY, INVALID, FALLBACK = 0, 1, 2, 3
"""Outcome of reading a field: a value; an empty field; one Python refuses too; one only Python can decide."""

_POW10 = np.array([1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
                   1e17, 1e18, 1e19, 1e20, 1e21, 1e22])
"""10^k, k = 0..22: every one an exact double."""

def _byte_table(chars: str) -> np.ndarray:
    table = np.zeros(256, dtype=np.bool_)
    for ch in chars:
        table[ord(ch)] = True
    return table


_WHITE = "".join(chr(i) for i in range(256) if chr(i).isspace())
_MAY_INT = _byte_table("+-_" + _WHITE)
"""Bytes other than digits that ``int()`` may accept (sign, underscore, blanks): only Python decides."""
_MAY_FLOAT = _byte_table("+-_." + _WHITE + "eEnNaAiIfFtTyY")
"""Bytes other than digits that ``float()`` may accept (exponent, ``nan``, ``inf``, ``infinity``, ...)."""


@njit(cache=True)
def read_int(data, a, b):
    """``int(data[a:b])`` for up to 17 ASCII digits: (status, value); more digits, a sign, an underscore or a
    blank is FALLBACK, any other byte INVALID (``int()`` refuses a letter, a point, ...)."""
    if a >= b:
        return EMPTY, 0
    if b - a > 17:
        return FALLBACK, 0  # beyond int64, and beyond 4,300 digits int() refuses (sys.get_int_max_str_digits)
    value = 0
    for i in range(a, b):
        c = data[i]
        if c < 48 or c > 57:
            return (FALLBACK if _MAY_INT[c] else INVALID), 0
        value = value * 10 + (c - 48)
    return OK, value


@njit(cache=True)
def read_float(data, a, b):
    """``float(data[a:b])`` for a canonical decimal (module docstring): (status, value); INVALID for text
    ``float()`` refuses for sure (a second point, a sign inside, a byte no float spelling holds)."""
    if a >= b:
        return EMPTY, 0.0
    i = a
    negative = False
    if data[i] == 45 or data[i] == 43:  # '-' '+'
        negative = data[i] == 45
        i += 1
    mantissa = 0
    significant = 0
    decimals = 0
    digits = 0
    dot = False
    for j in range(i, b):
        c = data[j]
        if 48 <= c <= 57:
            digits += 1
            if dot:
                decimals += 1
            if mantissa > 0 or c != 48:
                significant += 1
            mantissa = mantissa * 10 + (c - 48) if significant <= 18 else mantissa
        elif c == 46 and not dot:
            dot = True
        elif c == 46 or c == 45 or c == 43:
            return INVALID, 0.0  # a second '.' or a sign inside: Python refuses it too
        else:
            return (FALLBACK if _MAY_FLOAT[c] else INVALID), 0.0
    if digits == 0:
        return INVALID, 0.0
    if significant > 15 or decimals > 22:
        return FALLBACK, 0.0
    value = mantissa / _POW10[decimals]
    return OK, -value if negative else value


@njit(cache=True)
def read_csv_table(data, n_columns):
    """A table of ``n_columns`` comma-separated canonical decimals per ``\\n``-ended line: (ok, rows).

    ``ok`` False (and rows meaningless) at anything else: a blank line, a comment, ``\\r``, a field that is
    empty or not canonical, a line with another number of fields; the caller then reads the text its own way.
    """
    n_lines = 0
    for i in range(data.size):
        if data[i] == 10:
            n_lines += 1
    if data.size and data[data.size - 1] != 10:
        n_lines += 1
    rows = np.empty((n_lines, n_columns))
    row = 0
    start = 0
    while start < data.size:
        col = 0
        a = start
        i = start
        while True:
            at_end = i == data.size or data[i] == 10
            if at_end or data[i] == 44:
                if col == n_columns:
                    return False, rows
                st, v = read_float(data, a, i)
                if st != OK:
                    return False, rows
                rows[row, col] = v
                col += 1
                a = i + 1
                if at_end:
                    break
            i += 1
        if col != n_columns:
            return False, rows
        row += 1
        start = i + 1
    return row > 0, rows[:row]
