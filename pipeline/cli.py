"""The ``envfuse`` command line: a thin layer over library functions.

Every sub-command lives in a module of :mod:`pipeline.commands` that defines
``GROUP`` (the first word: ``simulate``, ``features``, ...) and
``register(subparsers)``. Domain errors become one line on stderr and exit
status 1; usage errors one line and status 2; never a traceback (set
``ENVFUSE_DEBUG=1`` to see one for an internal error).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import signal
import sys
import threading

from features.errors import EnvfuseError
from pipeline.args import UsageError

__all__ = ["main", "build_parser", "CliParser"]

GROUP_EXAMPLES = {
    "simulate": "envfuse simulate site --seed 1 --out site1 --plot",
    "features": "envfuse features gnss walk7/gnss.nmea --site site1 --out gnss_features.csv",
    "report": "envfuse report walk walk7 --out walk7.png",
    "train": "envfuse train env --library fp.sqlite --out env_model",
    "survey": "envfuse survey build survey1 --library fp.sqlite",
    "convert": "envfuse convert smartloc Berlin_Potsdamer_Platz_Input.txt Berlin_Potsdamer_Platz_GT.txt --out drive",
}
"""One example per command group, shown at the foot of ``envfuse GROUP --help``."""

GROUPS = {
    "simulate": "write a synthetic substation, walk or survey in device formats",
    "features": "extract features, fixes and steps from raw device files",
    "train": "fit environment and fusion models",
    "survey": "fingerprint survey of a substation",
    "report": "tables and plots of what a walk recorded",
    "convert": "turn other recordings (a smartLoc drive) into a walk folder",
}


class CliParser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line, not a usage dump, and whose options' help may be computed when
    a help page is printed (:func:`pipeline.args.lazy_help`)."""

    def error(self, message):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message} (see '{self.prog} --help')")

    def format_help(self) -> str:
        for action in self._actions:
            text = getattr(action, "lazy_help", None)
            if text is not None:
                action.help = text()
        return super().format_help()


def _version() -> str:
    """The installed distribution's version (pyproject.toml), or 'unknown' when run from an uninstalled tree."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("envfuse")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> CliParser:
    parser = CliParser(
        prog="envfuse",
        description="Environment-aware GNSS / acoustic / PDR positioning for substations.",
        epilog="Example: envfuse simulate site --seed 1 --out site1 --plot",
    )
    parser.add_argument("--version", action="version", version=f"envfuse {_version()}")
    sub = parser.add_subparsers(dest="group", metavar="COMMAND", parser_class=CliParser)
    group_parsers = {}
    modules = sorted(m.name for m in pkgutil.iter_modules(importlib.import_module("pipeline.commands").__path__))
    for name in modules:
        module = importlib.import_module(f"pipeline.commands.{name}")
        group = getattr(module, "GROUP", None)
        if group is None:
            continue
        if group not in group_parsers:
            example = GROUP_EXAMPLES.get(group)
            gp = sub.add_parser(group, help=GROUPS.get(group, ""), description=GROUPS.get(group, ""),
                                epilog=f"Example: {example}" if example else None)
            group_parsers[group] = gp.add_subparsers(dest="command", metavar="SUBCOMMAND", parser_class=CliParser)
            group_parsers[group].required = True
            gp.set_defaults(_group_parser=gp)
        module.register(group_parsers[group])
    # Commands that stand alone (e.g. ``demo``) register on the top level.
    for name in modules:
        module = importlib.import_module(f"pipeline.commands.{name}")
        if hasattr(module, "register_top"):
            module.register_top(sub)
    return parser


_OUTPUT_OPTIONS = ("out", "epochs", "positions", "fit_cn0_reference", "gpsd_json")


class Terminated(BaseException):
    """Raised by the SIGTERM handler: unwinds like Ctrl-C's KeyboardInterrupt (every temporary output is
    removed by the ``except BaseException`` of :mod:`features.fileio`), and ends with status 143 (128 + 15)."""


_RETRY_S = 0.05
"""Delay before a SIGTERM whose Terminated was dropped is sent again, s (:func:`_sigterm_as_interrupt`)."""

_retries: list[threading.Timer] = []


def _terminate(signum, frame):  # noqa: ARG001 - signal handler API
    raise Terminated


def _on_unraisable(unraisable, previous) -> None:
    """``sys.unraisablehook`` while SIGTERM is handled: a :class:`Terminated` that Python dropped is signalled again.

    Python runs a signal's handler at the next bytecode of whatever code runs, finalizers (``__del__``) and garbage
    collector callbacks included, and an exception raised there is dropped ("Exception ignored in ..."): the
    command then ran on to its end and exited 0, its output written (seen in CI: a survey's SIGTERM landed in
    llvmlite's ``ObjectRef.__del__``; in the test suite, in a gc callback). Such a Terminated sends SIGTERM again
    :data:`_RETRY_S` later, to land in the code that was interrupted; any other exception goes to ``previous``."""
    if isinstance(unraisable.exc_value, Terminated):
        timer = threading.Timer(_RETRY_S, os.kill, (os.getpid(), signal.SIGTERM))
        timer.daemon = True
        _retries.append(timer)
        timer.start()
    else:
        previous(unraisable)


@contextlib.contextmanager
def _sigterm_as_interrupt():
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    previous_hook = sys.unraisablehook
    sys.unraisablehook = lambda unraisable: _on_unraisable(unraisable, previous_hook)
    try:
        yield
    finally:
        while _retries:                 # a retry still pending must not reach the handler restored below
            _retries.pop().cancel()
        sys.unraisablehook = previous_hook
        signal.signal(signal.SIGTERM, previous)


def _run(args) -> int:
    """Run a command; with an output ``-`` its data goes to stdout and its summary lines to stderr."""
    from features.fileio import data_stdout, is_stdout

    if any(is_stdout(getattr(args, name, None)) for name in _OUTPUT_OPTIONS):
        with data_stdout(sys.stdout), contextlib.redirect_stdout(sys.stderr):
            return int(args.func(args) or 0)
    return int(args.func(args) or 0)


_OUR_PACKAGES = ("features", "simulation", "fingerprints", "models", "walks", "training", "pipeline")


def _show_warning(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001 - warnings API
    """envfuse's own warnings as one ``envfuse: warning:`` line; a library's (numpy's RuntimeWarning on an
    all-NaN window, openTSNE's, scikit-learn's) say nothing a user can act on and stay off stderr unless
    ENVFUSE_DEBUG is set."""
    ours = category.__module__.split(".")[0] in _OUR_PACKAGES
    if ours or os.environ.get("ENVFUSE_DEBUG"):
        print(f"envfuse: warning: {message}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _warnings_as_lines():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = _show_warning
        yield


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        with _sigterm_as_interrupt(), _warnings_as_lines():
            parser = build_parser()
            args = parser.parse_args(argv)
            if not hasattr(args, "func"):
                (getattr(args, "_group_parser", None) or parser).print_help()
                return 2
            return _run(args)
    except UsageError as exc:  # the parser's carry the command's name; a command's own get the prefix
        text = str(exc)
        print(text if text.startswith("envfuse") else f"envfuse: error: {text}", file=sys.stderr)
        return 2
    except EnvfuseError as exc:
        print(f"envfuse: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("envfuse: interrupted; files already written are complete, nothing half-written was kept",
              file=sys.stderr)
        return 130
    except Terminated:
        print("envfuse: terminated (SIGTERM); files already written are complete, nothing half-written was kept",
              file=sys.stderr)
        return 143
    except (OSError, MemoryError) as exc:
        print(f"envfuse: error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # pragma: no cover - last resort for bugs
        if os.environ.get("ENVFUSE_DEBUG"):
            raise
        print(f"envfuse: internal error: {type(exc).__name__}: {exc} (set ENVFUSE_DEBUG=1 for a traceback)",
              file=sys.stderr)
        return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
