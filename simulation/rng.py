"""Seeded random streams: every draw in the simulator comes from here.

Each named stream gets its own generator derived from the user's seed and a
stable hash of the name, so adding a stream never changes the draws of another
(``hash()`` is salted per process, so CRC-32 is used instead).
"""

from __future__ import annotations

import functools
import zlib

import numpy as np

__all__ = ["stream_rng", "stream_seed"]


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
