"""Which of envfuse's modules one command passes through, in order, and how often it climbs back into ``pipeline``.

Runs one ``envfuse`` command in this process under :func:`sys.setprofile` and
records, for every Python call and return, the module the interpreter is in
(``frame.f_globals['__name__']``), keeping only envfuse's own packages
(a call into numpy or scipy leaves the current module as it was). Consecutive
repeats are collapsed, so the result is the walk of control between modules:

* ``modules``: each module in the order it was first entered;
* ``transitions``: the collapsed sequence of modules (calls and returns);
* ``pipeline entries``: how many times control enters a ``pipeline`` module
  from a module of a lower floor — a call up into ``pipeline`` or a return to
  it from below. The command's own module is entered once from ``cli``; every
  further entry is a result handed back up to ``pipeline`` to be passed on.

Usage (the command's arguments after ``--``)::

    .venv/bin/python bench/call_trace.py -- run WALK --model MODEL --out /tmp/t.csv --method adaptive
    .venv/bin/python bench/call_trace.py --workers-note -- evaluate WALK1 WALK2 --model M --report R --workers 1

``evaluate`` must run with ``--workers 1`` (serial): a Dask worker's calls happen in other processes.
Issue 19's before/after figures were taken with this script on the demo split's held-out walks.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

OURS = ("features", "simulation", "fingerprints", "models", "training", "walks", "pipeline")


def _ours(name: str) -> bool:
    return name.split(".", 1)[0] in OURS


def trace(argv: list[str]) -> dict:
    """Run ``envfuse argv`` and return {'modules', 'transitions', 'pipeline_entries', 'exit'}."""
    from pipeline.cli import build_parser

    args = build_parser().parse_args(argv)
    seq: list[str] = []

    def prof(frame, event, arg):
        if event not in ("call", "return"):
            return
        target = frame if event == "call" else frame.f_back
        if target is None or target.f_code.co_name == "<module>":      # import-time module bodies: not the walk
            return
        name = target.f_globals.get("__name__", "")
        if not _ours(name) or name == "__main__":
            return
        if not seq or seq[-1] != name:
            seq.append(name)

    sys.setprofile(prof)
    try:
        code = args.func(args)
    finally:
        sys.setprofile(None)
    entries = sum(1 for a, b in zip(seq, seq[1:]) if b.startswith("pipeline") and not a.startswith("pipeline"))
    first = list(dict.fromkeys(seq))
    return {"modules": first, "transitions": seq, "pipeline_entries": entries, "exit": code}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers-note", action="store_true", help="(documentation only: evaluate runs serially)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="envfuse arguments after --")
    args = ap.parse_args()
    argv = args.command[1:] if args.command[:1] == ["--"] else args.command
    res = trace(argv)
    print(f"envfuse {' '.join(argv[:1])}: exit {res['exit']}")
    print(f"modules in order of first entry ({len(res['modules'])}):")
    for m in res["modules"]:
        print(f"  {m}")
    layers = []
    for m in res["transitions"]:
        top = m.split(".", 1)[0] if not m.startswith("pipeline") else m
        if not layers or layers[-1] != top:
            layers.append(top)
    print(f"transitions between floors ({len(layers)}): " + " > ".join(layers))
    print(f"entries into pipeline from a lower floor: {res['pipeline_entries']}")


if __name__ == "__main__":
    main()
