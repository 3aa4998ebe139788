"""A long walk made from a short one, as a device that logged the same loop again and again would write it.

:func:`loop_walk` writes a walk folder of ``n_loops`` copies of a simulated walk, back to back, with every
timestamp continued: NMEA times of day (and RMC/ZDA dates across midnight) shifted by ``k · D`` (``D`` the
source's ``duration_s``) with their checksums recomputed, the IMU CSV's and the truth's ``t_s`` shifted, the
audio appended block by block with :mod:`soundfile` (never held whole: an 8-hour WAV is 2.8 GB of int16). The
walker jumps from the loop's end back to its start at each seam (the filters see a position step there, as
after a long GNSS outage); everything else is what the simulator wrote. This is how the bench and the memory
test get 8-hour and 4-minute walks without simulating them (the simulator runs about 18× real time).

Only the walk's streams and ``truth.csv`` are written (the simulator's own ``audio_truth.csv`` and
``truth_steps.csv`` are not).
"""

from __future__ import annotations

import datetime as dt
import re
import subprocess
import sys
import tomllib
from functools import reduce
from pathlib import Path

import numpy as np
import soundfile as sf

__all__ = ["loop_walk", "shift_nmea_line", "peak_rss_mib"]

_TIME_FIELD = {"GGA": 1, "RMC": 1, "GST": 1, "GNS": 1, "ZDA": 1, "GLL": 5, "GBS": 1}
"""Index of the hhmmss.ss field in each timed sentence (after the address field)."""


def _checksum(body: str) -> str:
    """NMEA 0183 checksum: XOR of the characters between ``$`` and ``*``, two hex digits."""
    return f"{reduce(lambda a, c: a ^ ord(c), body, 0):02X}"


def shift_nmea_line(line: str, shift_s: float) -> str:
    """One NMEA sentence with its time of day (and RMC/ZDA date, across midnight) moved ``shift_s`` later.

    Sentences without a time (GSA, GSV, VTG, ...) come back unchanged; the checksum is recomputed.
    """
    text = line.rstrip("\r\n")
    if not text.startswith("$") or "*" not in text:
        return line
    body = text[1:text.rindex("*")]
    fields = body.split(",")
    kind = fields[0][2:]
    i = _TIME_FIELD.get(kind)
    if i is None or len(fields) <= i or not fields[i]:
        return line
    tod = fields[i]
    hh, mm, ss = int(tod[0:2]), int(tod[2:4]), float(tod[4:])
    decimals = len(tod.split(".")[1]) if "." in tod else 0
    total = hh * 3600 + mm * 60 + ss + shift_s
    days, total = divmod(total, 86400.0)
    total = round(total, decimals)
    h, rem = divmod(total, 3600.0)
    m, s = divmod(rem, 60.0)
    width = 3 + decimals if decimals else 2
    fields[i] = f"{int(h):02d}{int(m):02d}{s:0{width}.{decimals}f}"
    if days and kind == "RMC" and len(fields) > 9 and fields[9]:
        d = dt.datetime.strptime(fields[9], "%d%m%y").date() + dt.timedelta(days=int(days))
        fields[9] = d.strftime("%d%m%y")
    if days and kind == "ZDA" and len(fields) > 4 and fields[2]:
        d = dt.date(int(fields[4]), int(fields[3]), int(fields[2])) + dt.timedelta(days=int(days))
        fields[2], fields[3], fields[4] = f"{d.day:02d}", f"{d.month:02d}", f"{d.year:04d}"
    body = ",".join(fields)
    return f"${body}*{_checksum(body)}\n"


def _nmea_inside(lines: list[str], period_s: float) -> list[bool]:
    """Per line, whether its epoch (opened by the last timed sentence) starts before ``period_s`` after the
    file's first time of day."""
    first = None
    inside, now = [], True
    for x in lines:
        fields = x.split("*")[0].split(",")
        i = _TIME_FIELD.get(fields[0][3:]) if fields[0].startswith("$") else None
        if i is not None and len(fields) > i and fields[i]:
            tod = int(fields[i][0:2]) * 3600 + int(fields[i][2:4]) * 60 + float(fields[i][4:])
            first = tod if first is None else first
            now = (tod - first) % 86400.0 < period_s - 1e-6
        inside.append(now)
    return inside


def _shift_csv(src: Path, dst: Path, n_loops: int, period_s: float) -> None:
    """Copy a CSV whose first column is ``t_s`` ``n_loops`` times, ``t_s`` continued (same decimals); rows at
    ``t_s >= period_s`` are kept in the last copy only."""
    lines = src.read_text().splitlines()
    header, rows = lines[0], [r.split(",", 1) for r in lines[1:] if r]
    decimals = max((len(t.split(".")[1]) if "." in t else 0) for t, _ in rows)
    t = np.array([float(a) for a, _ in rows])
    inside = t < period_s - 1e-9
    with open(dst, "w") as fh:
        fh.write(header + "\n")
        for k in range(n_loops):
            keep = np.ones_like(inside) if k == n_loops - 1 else inside
            fh.writelines(f"{tk:.{decimals}f},{rest}\n" for tk, (_, rest), ok in zip(t + k * period_s, rows, keep)
                          if ok)


def _loop_audio(src: Path, dst: Path, n_loops: int, n_frames: int, block: int = 1 << 18) -> None:
    """Append the source WAV ``n_loops`` times (its first ``n_frames`` samples each), block by block."""
    info = sf.info(str(src))
    dtype = "int16" if info.subtype == "PCM_16" else "float32"
    with sf.SoundFile(str(dst), "w", samplerate=info.samplerate, channels=info.channels, subtype=info.subtype,
                      format="WAV" if n_loops * n_frames * info.channels * 2 < 2 ** 31 else "RF64") as out:
        for _ in range(n_loops):
            with sf.SoundFile(str(src)) as fh:
                left = n_frames
                while left > 0:
                    x = fh.read(min(block, left), dtype=dtype, always_2d=True)
                    if not len(x):
                        break
                    out.write(x)
                    left -= len(x)


def loop_walk(src: str | Path, dst: str | Path, n_loops: int, extra: tuple = ()) -> Path:
    """Write ``dst``, a walk of ``n_loops`` back-to-back copies of the walk folder ``src`` (module docstring).

    The source's ``duration_s`` is the period; its streams must hold nothing after it (a simulated walk's
    don't). The site is referred to by its absolute path. ``extra``: further CSV streams whose first column is
    ``t_s`` to loop (``"uwb"``, ``"imu_foot"``); the others named in ``walk.toml`` are left out of it. Returns
    ``dst``.
    """
    src, dst = Path(src), Path(dst)
    meta = tomllib.loads((src / "walk.toml").read_text())
    period = float(meta["duration_s"])
    dst.mkdir(parents=True, exist_ok=False)
    text = (src / "walk.toml").read_text()
    site = (src / meta["site"]).resolve()
    text = re.sub(r'^site = ".*"$', f'site = "{site}"', text, count=1, flags=re.M)
    text = re.sub(r"^duration_s = .*$", f"duration_s = {n_loops * period!r}", text, count=1, flags=re.M)
    for stream in ("uwb", "imu_foot"):
        if stream in meta and stream not in extra:     # a table without its file: drop it
            text = re.sub(rf"^\[{stream}\]\n(?:[^\[\n][^\n]*\n|\n)*", "", text, flags=re.M)
    (dst / "walk.toml").write_text(text)
    for stream in extra:
        _shift_csv(src / meta[stream]["file"], dst / meta[stream]["file"], n_loops, period)
    if "gnss" in meta:
        lines = (src / meta["gnss"]["file"]).read_text().splitlines(keepends=True)
        inside = _nmea_inside(lines, period)
        with open(dst / meta["gnss"]["file"], "w") as fh:
            for k in range(n_loops):
                last = k == n_loops - 1
                fh.writelines(shift_nmea_line(x, k * period) for x, ok in zip(lines, inside) if ok or last)
    if "imu" in meta:
        _shift_csv(src / meta["imu"]["file"], dst / meta["imu"]["file"], n_loops, period)
    if (src / "truth.csv").is_file():
        _shift_csv(src / "truth.csv", dst / "truth.csv", n_loops, period)
    if "audio" in meta:
        fs = int(sf.info(str(src / meta["audio"]["file"])).samplerate)
        _loop_audio(src / meta["audio"]["file"], dst / meta["audio"]["file"], n_loops, round(period * fs))
    return dst


def peak_rss_mib(args: list) -> float:
    """Peak resident memory of ``envfuse ARGS`` in a child process, MiB: its ``VmHWM`` (proc(5)), the
    high-water mark of its own address space. (Not ``ru_maxrss``: Linux keeps that across fork and execve, so a
    child of a large pytest process reads the parent's peak.)"""
    code = ("import sys; from pipeline.cli import main; rc = main(sys.argv[1:]); "
            "print('HWM', [x for x in open('/proc/self/status') if x.startswith('VmHWM')][0].split()[1]); "
            "sys.exit(rc)")
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True)
    return int(out.stdout.split("HWM")[-1]) / 1024.0
