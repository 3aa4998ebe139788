"""Compiled numeric kernels: :func:`numba.njit` applied lazily, cached on disk.

The acoustic receiver runs a handful of small loops per TDMA frame (local
maxima of an envelope, the leading edge of a few CIRs, a three-unknown
Gauss-Newton). In Python or numpy their cost is interpreter and per-call
overhead, many times the arithmetic, and it bounds the receiver's speed.
They are written as plain loops over numpy arrays and compiled with numba
(Lam, Pitrou & Seibert 2015, "Numba: a LLVM-based Python JIT compiler",
LLVM-HPC workshop), the compiler audio libraries such as librosa use for
the same reason.

Compilation happens at the first call, not at import (importing numba costs
about 0.4 s, which commands that never touch audio should not pay), and the
machine code is cached next to the module (``cache=True``), so only the first
run after an install compiles (a few seconds). ``NUMBA_DISABLE_JIT=1`` runs
the same functions as plain Python (slowly), for debugging.
"""

from __future__ import annotations

import functools

__all__ = ["jit"]


def jit(fn):
    """``numba.njit(cache=True)(fn)``, applied on the first call; ``fn`` itself stays importable.

    >>> @jit
    ... def add(a, b):
    ...     return a + b
    >>> add(2, 3)
    5
    """
    compiled = None

    @functools.wraps(fn)
    def call(*args):
        nonlocal compiled
        if compiled is None:
            from numba import njit

            try:
                compiled = njit(cache=True, nogil=True)(fn)
            except RuntimeError:          # no source file to cache beside (an interactive definition)
                compiled = njit(nogil=True)(fn)
        return compiled(*args)

    call.py_func = fn
    return call
