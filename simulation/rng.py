"""Seeded random streams: every draw in the simulator comes from here.

Each named stream gets its own generator derived from the user's seed and a
stable hash of the name, so adding a stream never changes the draws of another
(``hash()`` is salted per process, so CRC-32 is used instead).
"""

from __future__ import annotations

import functools
import zlib

import numpy as np
from numba import njit
from numpy.random.bit_generator import ISeedSequence

__all__ = ["stream_rng", "stream_rngs", "stream_seed", "seed_words"]


def stream_seed(seed: int, *names: str | int) -> np.random.SeedSequence:
    """SeedSequence for the stream ``names`` under the user's ``seed``.

    >>> a = stream_rng(1, "gnss").random(); b = stream_rng(1, "gnss").random()
    >>> a == b, a != stream_rng(2, "gnss").random(), a != stream_rng(1, "audio").random()
    (True, True, True)
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return np.random.SeedSequence([int(seed), *(int(name) if isinstance(name, (int, np.integer)) else _crc32(name)
                                                for name in names)])


@functools.lru_cache(maxsize=1024)
def _crc32(name) -> int:
    """CRC-32 of a stream name's text (a few dozen names recur for every emission and chunk)."""
    return zlib.crc32(str(name).encode())


def stream_rng(seed: int, *names: str | int) -> np.random.Generator:
    """A fresh ``numpy.random.Generator`` for the stream ``names`` under ``seed``."""
    return np.random.default_rng(stream_seed(seed, *names))


# numpy's SeedSequence constants (numpy/random/bit_generator.pyx; O'Neill's seed_seq_fe): pool of 4 words
_POOL_SIZE = 4
_INIT_A, _MULT_A = 0x43B0D7E5, 0x931E8875
_INIT_B, _MULT_B = 0x8B51F9DD, 0x58F38DED
_MIX_MULT_L, _MIX_MULT_R = 0xCA01F9DD, 0x4973F715


@njit(cache=True)
def _hashmix(value: np.uint64, hash_const: np.uint64) -> tuple[np.uint64, np.uint64]:
    """SeedSequence's ``hashmix`` on 32-bit words held in uint64: (mixed value, next hash constant)."""
    m32 = np.uint64(0xFFFFFFFF)
    value = value ^ hash_const
    hash_const = (hash_const * np.uint64(_MULT_A)) & m32
    value = (value * hash_const) & m32
    return value ^ (value >> np.uint64(16)), hash_const


@njit(cache=True)
def _mix(x: np.uint64, y: np.uint64) -> np.uint64:
    """SeedSequence's ``mix``: (L·x − R·y) mod 2³², then xor-shift by 16."""
    result = (np.uint64(_MIX_MULT_L) * x - np.uint64(_MIX_MULT_R) * y) & np.uint64(0xFFFFFFFF)
    return result ^ (result >> np.uint64(16))


@njit(cache=True)
def seed_words(entropy: np.ndarray) -> np.ndarray:
    """``SeedSequence(row).generate_state(4, np.uint64)`` of every row of ``entropy`` (n, L), the rows' 32-bit
    words (each < 2³², none spawned): numpy's pool mixing (``mix_entropy``) and output hashing, one pass.

    Returns (n, 4) uint64: the words PCG64 seeds itself from.
    """
    n, n_in = entropy.shape
    out = np.empty((n, _POOL_SIZE), np.uint64)
    pool = np.empty(_POOL_SIZE, np.uint64)
    for r in range(n):
        hc = np.uint64(_INIT_A)
        for i in range(_POOL_SIZE):         # the entropy up to the pool size (zeros beyond it)
            pool[i], hc = _hashmix(np.uint64(entropy[r, i]) if i < n_in else np.uint64(0), hc)
        for i_src in range(_POOL_SIZE):     # every word into every other, so late words change early ones
            for i_dst in range(_POOL_SIZE):
                if i_src != i_dst:
                    h, hc = _hashmix(pool[i_src], hc)
                    pool[i_dst] = _mix(pool[i_dst], h)
        for i_src in range(_POOL_SIZE, n_in):   # the rest of the entropy, mixed into each pool word
            for i_dst in range(_POOL_SIZE):
                h, hc = _hashmix(np.uint64(entropy[r, i_src]), hc)
                pool[i_dst] = _mix(pool[i_dst], h)
        hc = np.uint64(_INIT_B)
        for k in range(_POOL_SIZE):         # 8 output words of 32 bits, paired little-endian into 4 of 64
            pair = np.uint64(0)
            for half in range(2):
                v = pool[(2 * k + half) % _POOL_SIZE] ^ hc
                hc = (hc * np.uint64(_MULT_B)) & np.uint64(0xFFFFFFFF)
                v = (v * hc) & np.uint64(0xFFFFFFFF)
                v = v ^ (v >> np.uint64(16))
                pair |= v << np.uint64(32 * half)
            out[r, k] = pair
    return out


class _Words(ISeedSequence):
    """A seed sequence whose state is already generated: PCG64 takes its four 64-bit words as they are."""

    __slots__ = ("words",)

    def __init__(self, words: np.ndarray):
        self.words = words

    def generate_state(self, n_words, dtype=np.uint32):
        if n_words != _POOL_SIZE or np.dtype(dtype) != np.uint64:
            raise ValueError(f"only 4 uint64 words are held, asked for {n_words} {np.dtype(dtype)}")
        return self.words


def _uint32_words(value: int) -> list[int]:
    """An entropy integer as numpy's SeedSequence splits it: 32-bit words, least significant first ([0] for 0)."""
    words = [value & 0xFFFFFFFF]
    value >>= 32
    while value:
        words.append(value & 0xFFFFFFFF)
        value >>= 32
    return words


def stream_rngs(seed: int, names: tuple[str | int, ...], keys: np.ndarray) -> list[np.random.Generator]:
    """``[stream_rng(seed, *names, *row) for row in keys]`` with the seeds of all rows mixed in one compiled
    pass (:func:`seed_words`): the same generators, drawing the same numbers, at a tenth of the cost.

    keys : (n, m) integers. A row with a value outside [0, 2³²) (several entropy words, or an error) goes through
    :func:`stream_rng` itself.
    """
    keys = np.asarray(keys, dtype=np.int64)
    if keys.ndim != 2:
        raise ValueError(f"keys must be a 2-D array of integers, got shape {keys.shape}")
    prefix = [word for x in stream_seed(seed, *names).entropy for word in _uint32_words(int(x))]
    ok = np.all((keys >= 0) & (keys <= 0xFFFFFFFF), axis=1)
    entropy = np.empty((len(keys), len(prefix) + keys.shape[1]), np.uint32)
    entropy[:, :len(prefix)] = prefix
    entropy[:, len(prefix):] = np.where(ok[:, None], keys, 0)
    words = seed_words(entropy)
    return [np.random.Generator(np.random.PCG64(_Words(w))) if good else stream_rng(seed, *names, *row.tolist())
            for w, good, row in zip(words, ok, keys)]
