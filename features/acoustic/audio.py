"""Reading audio recordings block by block, at 48 kHz, with flat memory.

Choices (issue 4, "bad input"):

* **Integer samples are read as integers** (``soundfile`` with ``dtype='int16'``
  or ``'int32'``) and scaled to [-1, 1) by numpy, which is about 4× faster than
  letting libsndfile convert to float. Float files are read as ``float32``.
* **Wrong sample rate: resampled, with a warning** — not refused — because the
  beacon band (17–23 kHz) survives at any rate whose Nyquist lies above the
  chirp's top frequency, and phones commonly record at 44.1 kHz. Resampling is
  rational polyphase filtering (:func:`scipy.signal.resample_poly`, Kaiser
  window; Crochiere & Rabiner 1983) done block by block with ``_RESAMPLE_PAD``
  input samples of context on each side, so the output equals one call over the
  whole file away from its two ends. Content above the input's Nyquist frequency
  cannot be recovered: a 44.1 kHz file carries nothing above 22.05 kHz, so the
  top of a 17–23 kHz chirp is lost (the matched filter then loses about 1 dB).
* **More than one channel: the first is used, with a warning.**
* **Clipping, silence and truncation are reported, not raised**: each block
  carries its count of full-scale samples, and :class:`AudioInfo` says whether
  the data chunk is shorter than its header claims. Only a file that cannot be
  opened at all raises :class:`~features.errors.AudioError`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import struct
import warnings
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np
import soundfile as sf

from features.constants import AUDIO_FS_HZ
from features.errors import AudioError

__all__ = ["AudioWarning", "AudioInfo", "AudioBlock", "audio_info", "iter_audio_blocks", "read_audio",
           "count_clipped", "require_beacon_band"]

_RESAMPLE_PAD = 64
"""Input samples of context each side of a resampled block (the default
``resample_poly`` filter reaches 10 input samples each way)."""

CLIP_LEVEL = 0.999
"""A sample is counted as clipped when ``|x| >= CLIP_LEVEL`` of full scale."""


class AudioWarning(UserWarning):
    """Audio was usable but not as specified (resampled, channel dropped, truncated)."""


@dataclass(frozen=True)
class AudioInfo:
    """What the file header says, and what is really there.

    ``n_frames`` counts the samples present (per channel) at the file's own rate.
    """

    path: str
    fs_hz: int
    n_channels: int
    n_frames: int
    subtype: str
    truncated: bool

    @property
    def duration_s(self) -> float:
        return self.n_frames / self.fs_hz if self.fs_hz else 0.0


@dataclass(frozen=True)
class AudioBlock:
    """A block of samples at the output rate.

    ``start_index`` is the index of ``samples[0]`` in the output stream,
    ``n_clipped`` the number of input samples at full scale that fed it.
    """

    start_index: int
    samples: np.ndarray
    n_clipped: int


def _declared_data_bytes(path: Path) -> int | None:
    """Size of the RIFF/WAVE ``data`` chunk as the header declares it (None when not a plain WAV)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(12)
            if len(head) < 12 or head[:4] not in (b"RIFF", b"RIFX") or head[8:12] != b"WAVE":
                return None
            endian = "<" if head[:4] == b"RIFF" else ">"
            while True:
                chunk = fh.read(8)
                if len(chunk) < 8:
                    return None
                cid, size = chunk[:4], struct.unpack(endian + "I", chunk[4:])[0]
                if cid == b"data":
                    return size
                fh.seek(size + (size & 1), os.SEEK_CUR)
    except OSError:
        return None


def require_beacon_band(path: str | os.PathLike, band_low_hz: float) -> "AudioInfo":
    """The file's :class:`AudioInfo`, or :class:`~features.errors.AudioError` when it cannot hold a beacon
    chirp at all: no samples, or a Nyquist frequency at or below ``band_low_hz`` (the lowest beacon band
    edge; resampling cannot bring back what the recorder never sampled)."""
    info = audio_info(path)
    if info.n_frames == 0:
        raise AudioError(f"{path}: holds no audio samples")
    if info.fs_hz / 2 <= band_low_hz:
        raise AudioError(f"{path}: sample rate {info.fs_hz} Hz (Nyquist {info.fs_hz / 2:.0f} Hz) cannot carry "
                         f"the beacon band starting at {band_low_hz:.0f} Hz")
    return info


def audio_info(path: str | os.PathLike) -> AudioInfo:
    """Open ``path`` and describe it; raises AudioError when it cannot be read as audio."""
    path = Path(path)
    if not path.is_file():
        raise AudioError(f"audio file {path} does not exist")
    try:
        info = sf.info(str(path))
    except (sf.LibsndfileError, RuntimeError, TypeError) as exc:
        raise AudioError(f"{path}: cannot be read as audio ({exc})") from None
    if info.samplerate <= 0 or info.channels <= 0:
        raise AudioError(f"{path}: header gives sample rate {info.samplerate} and {info.channels} channels")
    truncated = False
    declared = _declared_data_bytes(path)
    bytes_per_frame = {"PCM_16": 2, "PCM_24": 3, "PCM_32": 4, "FLOAT": 4, "DOUBLE": 8, "PCM_U8": 1}.get(info.subtype)
    if declared is not None and bytes_per_frame and declared != 0xFFFFFFFF:
        truncated = info.frames * bytes_per_frame * info.channels < declared
    return AudioInfo(str(path), int(info.samplerate), int(info.channels), int(info.frames), info.subtype, truncated)


def count_clipped(x: np.ndarray) -> int:
    """Number of samples with ``|x| >= CLIP_LEVEL`` (the common case, none, costs two reductions, not a copy).

    >>> count_clipped(np.array([0.5, -1.0, 0.9995], dtype=np.float32))
    2
    """
    if len(x) == 0 or max(float(x.max()), -float(x.min())) < CLIP_LEVEL:
        return 0
    return int(np.count_nonzero(np.abs(x) >= CLIP_LEVEL))


_INT16_CLIP = math.ceil(CLIP_LEVEL * 32768)
"""Least int16 magnitude ``i`` with ``i / 32768 >= CLIP_LEVEL`` (32736: 32735/32768 = 0.998993)."""


def _count_clipped_int16(x: np.ndarray) -> int:
    """:func:`count_clipped` of ``x / 32768``, counted on the int16 samples: half the bytes to scan.

    >>> _count_clipped_int16(np.array([32735, 32736, -32768, -32735, 0], dtype=np.int16))
    2
    """
    if len(x) == 0 or max(int(x.max()), -int(x.min())) < _INT16_CLIP:
        return 0
    return int(np.count_nonzero((x >= _INT16_CLIP) | (x <= -_INT16_CLIP)))


def _read_dtype(subtype: str) -> tuple[str, float]:
    """numpy dtype to read as, and the scale to full scale 1.0."""
    if subtype in ("PCM_16", "PCM_U8", "PCM_S8"):
        return "int16", 1.0 / 32768.0
    if subtype in ("PCM_24", "PCM_32"):
        return "int32", 1.0 / 2147483648.0
    return "float32", 1.0


def iter_audio_blocks(path: str | os.PathLike, block_s: float = 4.0,
                      fs_out_hz: int = AUDIO_FS_HZ, first_index: int = 0) -> Iterator[AudioBlock]:
    """Yield :class:`AudioBlock` s of about ``block_s`` seconds at ``fs_out_hz``, first channel only.

    ``first_index``: the stream index of the file's first sample (a cut of a longer recording: its index in
    the whole). Blocks then end at the same stream indices as the whole recording's (whole multiples of the
    block length; the first block is shorter), so that what is computed block by block downstream is cut the
    same way; ``start_index`` counts from it. (At 48 kHz in; a resampled file's blocks start at
    ``first_index`` and are not aligned.)

    Warns (:class:`AudioWarning`) when resampling, dropping channels or reading a
    truncated file. Memory stays bounded by one block whatever the file length.
    """
    info = audio_info(path)
    if info.n_channels > 1:
        warnings.warn(f"{path}: {info.n_channels} channels, using the first only", AudioWarning, stacklevel=2)
    if info.truncated:
        warnings.warn(f"{path}: data chunk is shorter than its header declares (truncated file); "
                      f"reading the {info.n_frames} samples present", AudioWarning, stacklevel=2)
    ratio = Fraction(int(fs_out_hz), info.fs_hz)
    if ratio != 1:
        warnings.warn(f"{path}: sample rate {info.fs_hz} Hz, resampling to {fs_out_hz} Hz "
                      f"(content above {info.fs_hz / 2:.0f} Hz is absent)", AudioWarning, stacklevel=2)
    dtype, scale = _read_dtype(info.subtype)
    # Input blocks hold a whole number of resampling periods so output lengths are exact.
    period = ratio.denominator
    block_in = max(period, int(round(block_s * info.fs_hz / period)) * period)
    out_index = 0
    warned = False
    try:
        with sf.SoundFile(str(path)) as fh:
            if ratio == 1:
                # libsndfile fills one reused buffer (no array allocated per read); each block's samples
                # are a fresh array, since callers may keep them. Cast, then scale in place: faster here
                # than one mixed-type int16 × float32 multiply (bench/bench_frontend.py), same values.
                raw = np.empty((block_in, fh.channels), dtype=dtype)
                out_index = int(first_index)
                while True:
                    # Up to the next whole multiple of the block length on the stream's index.
                    n = fh.buffer_read_into(raw[: block_in - out_index % block_in], dtype)
                    if n == 0:
                        break
                    samples = raw[:n, 0].astype(np.float32)
                    if scale != 1.0:
                        samples *= np.float32(scale)
                    if dtype.startswith("float"):
                        warned = _zero_non_finite(samples, path, warned)
                    clipped = _count_clipped_int16(raw[:n, 0]) if dtype == "int16" else count_clipped(samples)
                    yield AudioBlock(out_index, samples, clipped)
                    out_index += len(samples)
                return
            for block in _resampled_blocks(fh, dtype, scale, block_in, ratio, info.n_frames, path):
                yield dataclasses.replace(block, start_index=block.start_index + int(first_index))
    except sf.LibsndfileError as exc:
        raise AudioError(f"{path}: read failed ({exc})") from None


def _zero_non_finite(samples: np.ndarray, path, warned: bool) -> bool:
    """Set NaN/inf samples (possible in float WAVs only) to 0, warning once per file; returns ``warned``."""
    bad = ~np.isfinite(samples)
    if bad.any():
        if not warned:
            warnings.warn(f"{path}: non-finite (NaN/inf) samples read as silence", AudioWarning, stacklevel=3)
        samples[bad] = 0.0
        return True
    return warned


def _resampled_blocks(fh, dtype, scale, block_in, ratio: Fraction, n_frames: int,
                      path="audio") -> Iterator[AudioBlock]:
    """Blockwise ``resample_poly(x, up, down)`` with context padding; see the module docstring."""
    import scipy.signal  # here, not at the top: importing it costs about 1.4 s, and 48 kHz files never need it

    up, down = ratio.numerator, ratio.denominator
    pad = int(math.ceil(_RESAMPLE_PAD / down)) * down
    prev = np.zeros(0, dtype=np.float32)
    cur = fh.read(block_in, dtype=dtype, always_2d=True)[:, 0]
    cur_clip = int(np.count_nonzero(np.abs(cur.astype(np.float32) * scale) >= CLIP_LEVEL))
    cur = cur.astype(np.float32) * np.float32(scale)
    warned = _zero_non_finite(cur, path, False) if dtype.startswith("float") else False
    out_index = 0
    total_out = int(math.ceil(n_frames * up / down))
    while len(cur):
        nxt = fh.read(block_in, dtype=dtype, always_2d=True)[:, 0]
        nxt_clip = int(np.count_nonzero(np.abs(nxt.astype(np.float32) * scale) >= CLIP_LEVEL))
        nxt = nxt.astype(np.float32) * np.float32(scale)
        if dtype.startswith("float"):
            warned = _zero_non_finite(nxt, path, warned)
        left = prev[len(prev) - pad:] if len(prev) >= pad else np.concatenate(
            [np.zeros(pad - len(prev), np.float32), prev])
        right = nxt[:pad]
        if len(right) < pad:
            right = np.concatenate([right, np.zeros(pad - len(right), np.float32)])
        y = scipy.signal.resample_poly(np.concatenate([left, cur, right]), up, down).astype(np.float32)
        lead = pad * up // down
        n_out = min(int(math.ceil(len(cur) * up / down)), total_out - out_index)
        samples = y[lead: lead + n_out]
        yield AudioBlock(out_index, samples, cur_clip)
        out_index += len(samples)
        prev, cur, cur_clip = cur, nxt, nxt_clip


def read_audio(path: str | os.PathLike, fs_out_hz: int = AUDIO_FS_HZ) -> tuple[np.ndarray, AudioInfo]:
    """Whole file at ``fs_out_hz`` as float32 of shape (n,) (for short files and tests)."""
    info = audio_info(path)
    blocks = [b.samples for b in iter_audio_blocks(path, fs_out_hz=fs_out_hz)]
    return (np.concatenate(blocks) if blocks else np.zeros(0, np.float32)), info
