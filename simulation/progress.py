"""Progress for long simulations: a tqdm bar on a terminal, plain lines in a log (issue 12, item 17).

A bar's carriage returns make a mess of a log file, so when the stream is not a
TTY :class:`Progress` writes one plain line per ``every_fraction`` of the work
(and at the end) instead, e.g. ``audio: 120/600 s (20 %)``.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """Context manager counting ``total`` units of work.

    ``enabled`` False shows nothing; ``stream`` defaults to ``sys.stderr``;
    ``tty`` forces bar (True) or lines (False), default: ``stream.isatty()``.

    >>> import io
    >>> buf = io.StringIO()
    >>> with Progress(4, "cells", unit="cell", stream=buf, every_fraction=0.5) as p:
    ...     for _ in range(4):
    ...         p.update(1)
    >>> print(buf.getvalue(), end="")
    cells: 2/4 cell (50 %)
    cells: 4/4 cell (100 %)
    """

    def __init__(self, total: int, desc: str, unit: str = "", enabled: bool = True, stream=None,
                 tty: bool | None = None, every_fraction: float = 0.1):
        self.total = max(int(total), 0)
        self.desc = desc
        self.unit = unit
        self.enabled = bool(enabled)
        self.stream = stream if stream is not None else sys.stderr
        self.tty = tty if tty is not None else bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_fraction = every_fraction
        self.n = 0
        self._bar = None
        self._next_line = 0
        self._t0 = 0.0

    def __enter__(self) -> "Progress":
        self._t0 = time.monotonic()
        if self.enabled and self.tty:
            from tqdm import tqdm
            self._bar = tqdm(total=self.total, desc=self.desc, unit=self.unit or "it", file=self.stream, leave=False)
        self._next_line = max(1, int(round(self.every_fraction * self.total)))
        return self

    def update(self, k: int = 1) -> None:
        """Count ``k`` more units done."""
        if k <= 0:
            return
        self.n = min(self.total, self.n + k) if self.total else self.n + k
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(k)
            return
        if self.n >= self._next_line or (self.total and self.n >= self.total):
            pct = f" ({100 * self.n / self.total:.0f} %)" if self.total else ""
            unit = f" {self.unit}" if self.unit else ""
            print(f"{self.desc}: {self.n}/{self.total}{unit}{pct}", file=self.stream, flush=True)
            step = max(1, int(round(self.every_fraction * self.total)))
            while self._next_line <= self.n:
                self._next_line += step

    def set(self, n: int) -> None:
        """Set the count to ``n`` (monotone)."""
        if n > self.n:
            self.update(n - self.n)

    def __exit__(self, *exc) -> None:
        if self._bar is not None:
            self._bar.close()
