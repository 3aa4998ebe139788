"""Mutated NMEA through the reader and the whole GNSS feature/fix path (issue 20, Deliver 4).

A hypothesis strategy draws a *batch*: a run of consecutive real sentences from one receiver log
(so that epochs, GSV groups and time bases are as coherent as a real file's), each line kept or
mutated — bytes flipped, cut, inserted, whitespace and ``$ * #`` injected; fields swapped, duplicated,
deleted or replaced by tokens chosen to hurt (empty, signs, ``nan``/``inf``, 400-digit and 5000-digit
numbers, hex, Latin-1 digits, dates and times at the edges); most lines then re-signed so the mutation
gets past the checksum into the interpreters — and the batch itself sometimes reordered, doubled or
cut short. :func:`run_gnss_path` pushes a batch through everything a walk's GNSS goes through:

* the reader three ways: the whole-file path (:func:`read_nmea`), the streaming path over lines and the
  pynmea2 tokeniser (all three must give equal epochs and equal statistics: the pynmea2 one equal epochs);
* :func:`epochs_on_time_base`, :func:`sky_arrays`, :func:`gnss_features`, :func:`fixes_to_enu`,
  :func:`read_gst`, :func:`fit_cn0_reference`, the ``--epochs`` JSON and ``--gpsd-json`` writers.

Allowed outcomes: success, or a :class:`~features.errors.DataError` (``NmeaError`` for a file without a
usable epoch, ``DataError`` for too little data to fit a reference). Anything else raised, a warning
emitted, a non-finite number in an output (JSON that needs ``NaN``, an ENU position or σ that is not
finite, an infinite feature), epochs out of time order or reader paths that disagree is a *failure*,
returned with its input so it can be replayed.

Used by ``tests/test_issue_nmea_fuzz.py`` (a few thousand lines) and ``bench/fuzz_nmea.py`` (10⁶).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import random
import signal
import sys
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from functools import reduce
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

from features.errors import DataError
from features.gnss.features import fit_cn0_reference, gnss_features, sky_arrays
from features.gnss.gpsd import gpsd_json_lines
from features.gnss.nmea import ReadStats, epochs_on_time_base, iter_epochs, read_nmea
from features.gnss.positions import fixes_to_enu, read_gst

__all__ = ["corpus", "batches", "run_gnss_path", "FuzzTally", "fuzz"]

REPO = Path(__file__).resolve().parents[1]

TOKENS = ("", "0", "00", "-0", "-1", "1", "2", "9", "99", "100", "360", "361", "-91", "91", "255", "999",
          "1e308", "-1e308", "1e400", "nan", "NaN", "inf", "-inf", "Infinity", "0x1F", "1.5.2", ".", "-", "+5",
          " 7", "7 ", "1_0", "²³", "\xbd", "9" * 400, "9" * 5000, "A", "V", "N", "S", "E", "W", "M", "Z", "F",
          "000000", "235959.99", "240000", "235960", "999999", "-10000", "010100", "311299", "290223", "000000.",
          "9999", "0000", "1.0e2", "4916.45", "18000.00001", "9000.0000", "12000.00", "B", "G", "10", "16", "4")


def _checksum(body: str) -> str:
    return "%02X" % reduce(lambda a, c: a ^ c, body.encode("latin-1", "replace"), 0)


def resign(line: str) -> str:
    """The line with its checksum recomputed (so a mutation reaches the field interpreters)."""
    if "$" in line and "*" in line and line.index("$") < line.rindex("*"):
        body = line[line.index("$") + 1:line.rindex("*")]
        return "$" + body + "*" + _checksum(body)
    return line


def corpus() -> list[list[str]]:
    """Real sentences, one list per file: gpsd's receiver logs in ../shared/data (all 14), the repo's
    hand-made files, and the hand-written dual-signal group of issue 20."""
    from tests.conftest import SHARED_DATA
    from tests.test_issue_gsv_dual_signal import LINES

    files = sorted((SHARED_DATA / "nmea" / "gpsd").glob("*.log")) + sorted((REPO / "tests" / "data").glob("*.nmea"))
    out = []
    for path in files:
        lines = [ln for ln in path.read_text(encoding="latin-1").splitlines() if "$" in ln]
        if lines:
            out.append(lines)
    out.append(list(LINES))
    return out


def _mutate_fields(line: str, rng: random.Random) -> str:
    fields = line.split(",")
    op = rng.randrange(5)
    i = rng.randrange(len(fields))
    if op == 0:
        k = rng.randrange(len(fields))
        fields[i], fields[k] = fields[k], fields[i]
    elif op == 1:
        fields.insert(i, fields[i])
    elif op == 2 and len(fields) > 1:
        del fields[i]
    elif op == 3:
        fields.append(rng.choice(TOKENS))
    else:
        star = fields[i].find("*")
        tail = fields[i][star:] if star >= 0 else ""
        head = fields[i][:1] if i == 0 and fields[i].startswith("$") else ""
        fields[i] = head + rng.choice(TOKENS) + tail
    return ",".join(fields)


_INSERTS = (" ", "\t", "\r", "\xa0", "\x85", "$", "*", "#", ",")


def _mutate_bytes(line: str, rng: random.Random) -> str:
    b = bytearray(line.encode("latin-1"))
    op = rng.randrange(4)
    if op == 0 and b:
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif op == 1:
        b = b[:rng.randint(0, len(b))]
    elif op == 2:
        i = rng.randint(0, len(b))
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
    else:  # whitespace (str.strip's Latin-1 set) and '$' / '*' / '#' / ',' where they hurt
        i = rng.randint(0, len(b))
        b[i:i] = "".join(rng.choice(_INSERTS) for _ in range(rng.randint(1, 3))).encode("latin-1")
    return b.decode("latin-1")


def mutate_line(line: str, plan: int) -> str:
    """One line under one mutation plan (an integer hypothesis draws): 4 in 10 kept as they are, the rest
    mutated in their fields (4 in 10) or bytes (2 in 10), four in five of those re-signed."""
    what = plan % 10
    if what <= 3:
        return line
    rng = random.Random(plan)
    line = _mutate_fields(line, rng) if what <= 7 else _mutate_bytes(line, rng)
    return resign(line) if rng.randrange(5) else line


_PLAN = st.integers(0, 2**32 - 1)


@st.composite
def batches(draw, files: list[list[str]], max_lines: int = 80) -> list[str]:
    """One batch of lines (see the module docstring): the file, the run of lines, one mutation plan per line
    and the batch's reordering are hypothesis draws."""
    lines = draw(st.sampled_from(files))
    n = draw(st.integers(min(8, max_lines), max_lines))
    start = draw(st.integers(0, max(0, len(lines) - n)))
    run = lines[start:start + n]
    raw = draw(st.binary(min_size=4 * len(run), max_size=4 * len(run)))  # one draw: 4 bytes of plan per line
    out = [mutate_line(line, int.from_bytes(raw[4 * i:4 * i + 4], "little")) for i, line in enumerate(run)]
    shuffle = draw(st.integers(0, 7))
    if shuffle == 0:
        random.Random(draw(_PLAN)).shuffle(out)
    elif shuffle == 1:
        out = out + out  # the same cycle twice: time stands still, then jumps back
    elif shuffle == 2:
        out = out[::-1]
    return out


@dataclass
class FuzzTally:
    """What a fuzz run saw."""

    batches: int = 0
    lines: int = 0
    typed_errors: dict = field(default_factory=dict)
    skipped_sentences: int = 0
    epochs: int = 0
    failures: list = field(default_factory=list)
    hangs: int = 0
    max_batch_s: float = 0.0

    def add_typed(self, exc: Exception) -> None:
        name = type(exc).__name__
        self.typed_errors[name] = self.typed_errors.get(name, 0) + 1


def _finite_json(obj) -> None:
    json.dumps(obj, allow_nan=False)  # ValueError when a NaN or inf leaked into an output


def _check_outputs(epochs, tally: FuzzTally, tmp: Path) -> None:
    t = [e.t_s for e in epochs]
    if any(b < a for a, b in zip(t, t[1:])) or any(not np.isfinite(x) for x in t):
        raise AssertionError(f"epoch times out of order or not finite: {t[:10]}")
    for e in epochs:
        _finite_json(e.to_json_dict())
    _finite_json([json.loads(x) for x in gpsd_json_lines(epochs).splitlines()])
    try:
        epochs = epochs_on_time_base(epochs, dt.datetime(2024, 6, 15, tzinfo=dt.timezone.utc))
    except DataError as exc:  # no date in the file: the walk cannot be placed, a typed error
        tally.add_typed(exc)
    sky = sky_arrays(epochs)
    feats = gnss_features(sky)
    for name, col in feats.items():
        if np.isinf(np.asarray(col, dtype=float)).any():
            raise AssertionError(f"feature {name} infinite")
    pos = fixes_to_enu(epochs, 30.0, 120.0, 10.0, sky=sky, gst=read_gst(tmp))
    for name in ("east_m", "north_m", "up_m", "sigma_east_m", "sigma_north_m", "sigma_up_m"):
        col = getattr(pos, name)
        if not np.isfinite(col).all():
            raise AssertionError(f"fixes_to_enu {name} not finite: {col[~np.isfinite(col)][:3]}")
    try:
        fit_cn0_reference(sky.el_deg, sky.cn0_dbhz, min_per_bin=1)
    except DataError as exc:
        tally.add_typed(exc)


def run_gnss_path(lines: list[str], tally: FuzzTally, tmp: Path) -> None:
    """One batch through the reader and the GNSS path; failures are recorded in ``tally``, not raised."""
    buf = ("\n".join(lines) + "\n").encode("latin-1")
    tally.batches += 1
    tally.lines += len(lines)
    tmp.write_bytes(buf)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                epochs, stats = read_nmea(tmp)
            except DataError as exc:
                tally.add_typed(exc)
                epochs, stats = None, None
            raw = buf.split(b"\n")[:-1]  # as a file iterated in binary mode
            s_line = ReadStats()
            streamed = list(iter_epochs(raw, s_line))
            if epochs is not None:
                if streamed != epochs or s_line != stats:
                    raise AssertionError("whole-file and streaming paths disagree")
                tally.skipped_sentences += stats.skipped
                tally.epochs += len(epochs)
                ref = list(iter_epochs(raw, ReadStats(), parser="pynmea2"))
                if ref != epochs:
                    raise AssertionError("pynmea2 path disagrees with the fast path")
                _check_outputs(epochs, tally, tmp)
    except Exception as exc:  # noqa: BLE001 - the point of a fuzz run: record whatever escaped
        tally.failures.append((type(exc).__name__, str(exc)[:200], traceback.format_exc(limit=6), lines))


def temp_path() -> Path:
    """A scratch file for read_nmea (which reads paths), removed by the caller."""
    fd, name = tempfile.mkstemp(suffix=".nmea", prefix="envfuse-fuzz-")
    os.close(fd)
    return Path(name)


class _Hang(BaseException):
    """Raised by the alarm in a batch that runs too long (a BaseException: no ``except Exception`` stops it)."""


def fuzz(n_lines: int, rng_seed: int, max_lines: int = 80, progress: bool = True,
         hang_s: float = 10.0) -> tuple[FuzzTally, float, float]:
    """Run batches until ``n_lines`` lines went through; (tally, wall s, CPU s).

    A batch running longer than ``hang_s`` seconds (wall) is stopped by SIGALRM and counted as a hang
    (a batch of ≤ 160 lines takes milliseconds). Main thread only (signals).
    """
    files = corpus()
    tally = FuzzTally()
    tmp = temp_path()
    mean_batch = (1 + max_lines) / 2 * 1.4  # mutated batches may be doubled
    n_examples = int(n_lines / mean_batch * 1.3) + 10
    next_report = [100_000]

    @seed(rng_seed)
    @settings(max_examples=n_examples, deadline=None, database=None, phases=[Phase.generate],
              suppress_health_check=list(HealthCheck))
    @given(batches(files, max_lines))
    def one(lines):
        if tally.lines >= n_lines:
            return
        t0 = time.perf_counter()
        signal.setitimer(signal.ITIMER_REAL, hang_s)
        try:
            run_gnss_path(lines, tally, tmp)
        except _Hang:
            tally.hangs += 1
            tally.failures.append(("hang", f"batch took over {hang_s} s", "", lines))
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        tally.max_batch_s = max(tally.max_batch_s, time.perf_counter() - t0)
        if progress and tally.lines >= next_report[0]:
            print(f"  {tally.lines:,} lines, {len(tally.failures)} failures", file=sys.stderr, flush=True)
            next_report[0] += 100_000

    def _alarm(signum, frame):
        raise _Hang()

    previous = signal.signal(signal.SIGALRM, _alarm)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    try:
        while tally.lines < n_lines:  # another round with the next seed if the examples ran out first
            one()
            rng_seed += 1
            one = seed(rng_seed)(one)
    finally:
        signal.signal(signal.SIGALRM, previous)
        tmp.unlink(missing_ok=True)
    return tally, time.perf_counter() - wall0, time.process_time() - cpu0
