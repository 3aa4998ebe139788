"""Argument types shared by the CLI commands: each rejects bad values with one clear line."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["seed", "positive", "non_negative", "finite", "bounded", "open_interval", "UsageError", "check_outputs",
           "plot_path", "LazyChoices", "lazy_help"]


class UsageError(Exception):
    """A usage error (exit status 2): raised by the parser, and by a command for options that clash."""


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


def open_interval(lo: float, hi: float, unit: str = ""):
    """A type accepting finite numbers in (lo, hi), both ends excluded.

    >>> open_interval(0, 1)("1e-6")
    1e-06
    """
    def parse(text: str) -> float:
        value = _number(text)
        if not lo < value < hi:
            raise argparse.ArgumentTypeError(f"expected a value in ({lo:g}, {hi:g}){' ' + unit if unit else ''}, "
                                             f"got {text!r}")
        return value
    parse.__name__ = f"open_interval({lo:g},{hi:g})"
    return parse


def lazy_help(action: argparse.Action, text: Callable[[], str]) -> argparse.Action:
    """Give ``action`` (what ``add_argument`` returned) a help text computed when a help page is printed
    (:class:`pipeline.cli.CliParser`): a help naming a constant of a heavy module (the method registry, the
    segments' warm-ups) then does not import it while the parser is built for every command. Set after
    ``add_argument``, which checks a help string as it adds it (Python 3.14) and would refuse a function."""
    action.lazy_help = text
    return action


class LazyChoices(Sequence):
    """An option's choices read when first needed (a value to check, a help page to print), not when the parser
    is built: ``run`` and ``evaluate`` take theirs from the method registry, whose import (the fusion methods,
    GTSAM, scipy.stats: ~1.4 s) ``envfuse --help`` and every other command would otherwise pay.

    argparse reads ``choices`` as a container (``in``) and iterates it for messages; an option with lazy choices
    needs a ``metavar`` (argparse spells out the choices of one without it while the parser is built).

    >>> names = LazyChoices(lambda: ("kf", "aekf"))
    >>> "aekf" in names, "x" in names, list(names)
    (True, False, ['kf', 'aekf'])
    """

    def __init__(self, load: Callable[[], Sequence[str]]):
        self._load = load
        self._items: tuple | None = None

    def _get(self) -> tuple:
        if self._items is None:
            self._items = tuple(self._load())
        return self._items

    def __getitem__(self, i):
        return self._get()[i]

    def __len__(self) -> int:
        return len(self._get())

    def __contains__(self, value) -> bool:
        return value in self._get()


def check_outputs(inputs: dict, outputs: dict, directory_outputs: dict | None = None, sealed: dict | None = None) -> None:
    """Refuse an output that would overwrite an input, or two outputs naming one file (exit 2); see
    :func:`pipeline.outputs.check_outputs`."""
    from pipeline.outputs import check_outputs as check

    check(inputs, outputs, directory_outputs, sealed)


def plot_path(text: str) -> Path:
    """An output plot path whose suffix is .png, .pdf or .svg (or ``-`` for PNG on stdout)."""
    from pipeline.plots import plot_format

    try:
        plot_format(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return Path(text)


def resolve_site(walk, override=None, option: str = "--site"):
    """The site of a walk or survey cell: ``override`` (the user's --site), else the ``site`` its walk.toml
    names, else, for a survey cell (``SURVEY/cells/<id>/cell.toml``), the survey's own ``SURVEY/site.toml``.

    ``walk`` is a :class:`features.walk.WalkInfo` or None. Raises ConfigError naming what was looked for.
    """
    from features.errors import ConfigError
    from features.site import load_site

    if override is not None:
        return load_site(override)
    if walk is None:
        raise ConfigError(f"{option} is needed (no walk.toml or cell.toml beside the file names a site)")
    if walk.site_ref is not None:
        return walk.load_site()
    is_cell = (walk.directory / "cell.toml").is_file() and not (walk.directory / "walk.toml").is_file()
    if is_cell:
        survey_site = walk.directory.parent.parent / "site.toml"
        if survey_site.is_file():
            return load_site(survey_site)
        raise ConfigError(f"{walk.directory / 'cell.toml'}: the survey cell names no site and there is no "
                          f"{survey_site} (SURVEY/site.toml two folders up); pass {option}")
    raise ConfigError(f"{walk.directory / 'walk.toml'}: the walk names no site (no 'site' key); pass {option}")
