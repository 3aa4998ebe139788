"""Argument types shared by the CLI commands: each rejects bad values with one clear line."""

from __future__ import annotations

import argparse
import math

__all__ = ["seed", "positive", "non_negative", "finite", "bounded"]


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def seed(text: str) -> int:
    """A non-negative integer seed."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seed must be a non-negative integer, got {text!r}") from None
    if value < 0 or value >= 2 ** 63:
        raise argparse.ArgumentTypeError(f"seed must be a non-negative integer below 2**63, got {text!r}")
    return value


def finite(text: str) -> float:
    """Any finite number."""
    return _number(text)


def positive(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def non_negative(text: str) -> float:
    """A finite number ≥ 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative number, got {text!r}")
    return value


def bounded(lo: float, hi: float, unit: str = ""):
    """A type accepting finite numbers in [lo, hi].

    >>> bounded(1, 10, "s")("5")
    5.0
    """
    def parse(text: str) -> float:
        value = _number(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected a value in [{lo:g}, {hi:g}]{' ' + unit if unit else ''}, "
                                             f"got {text!r}")
        return value
    parse.__name__ = f"bounded[{lo:g},{hi:g}]"
    return parse
