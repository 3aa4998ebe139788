"""The bad-input table of issue 20: every case of ``tests/bad_inputs.py`` as an ``envfuse`` subprocess.

Prints, per group and in total, how many cases were clean / internal error / silent wrong / data lost /
unclear (the categories are defined in :mod:`tests.bad_inputs`), and every case that was not clean with
the reason. ``--tree DIR`` runs the commands of another source tree (e.g. ``git archive 0bde6be`` unpacked)
on the same inputs, built by this tree's simulator, which gives the before → after table::

    python bench/bad_inputs.py --tree /tmp/envfuse_main --json before.json
    python bench/bad_inputs.py --json after.json

A case that runs past its timeout (e.g. a benchmark that started simulating into a folder it should have
refused) is stopped and judged on what it did by then.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests import bad_inputs as B  # noqa: E402


def _world(root: Path) -> B.World:
    """Site seed 3 and a 60 s walk (seed 11), as the test session's fixtures, then the corpus's world."""
    if (root / "world" / "fm" / "bundle.json").is_file():
        return B.World(root / "world")
    from features.site import save_site
    from simulation.site.layout import generate_site
    from simulation.walk import simulate_walk

    shutil.rmtree(root, ignore_errors=True)
    (root / "site").mkdir(parents=True)
    save_site(generate_site(3), root / "site" / "site.toml")
    walk = simulate_walk(root / "site", root / "walk", seed=11, duration_s=60.0, progress=False)
    return B.build_world(root / "world", root / "site", walk)


def _run(argv: list[str], cwd: Path, tree: Path | None, timeout_s: float) -> B.Outcome:
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("ENVFUSE_DEBUG", None)
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", *argv], cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout_s)
        status = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)       # the case's own process group (its Dask workers too)
        out, err = proc.communicate()
        status = None
        err += f"\n[still running after {timeout_s:g} s: stopped]"
    return B.Outcome(status, out, err, time.perf_counter() - t0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=None, help="source tree whose commands to run (default: this one)")
    ap.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "envfuse_bad_inputs",
                    help="where the world is built (kept and reused) and the cases run")
    ap.add_argument("--only", default="", help="run only cases whose name or group contains this")
    ap.add_argument("--json", type=Path, default=None, help="also write every case's verdict here")
    args = ap.parse_args()
    world = _world(args.work)
    results = []
    counts: dict = collections.defaultdict(collections.Counter)
    t0 = time.perf_counter()
    for case in B.cases():
        if args.only and args.only not in case.name and args.only not in case.group:
            continue
        d = Path(tempfile.mkdtemp(prefix="case.", dir=args.work))
        try:
            W, argv, before = B.prepare(case, world, d)
            o = B.judge(case, W, d, before, _run(argv, d, args.tree, case.timeout_s))
            if o.status is None and o.kind != "data lost":
                # stopped at the timeout: the input was accepted and the command ran on (a benchmark that
                # started simulating into a folder it should have refused)
                o.kind, o.why = "silent wrong", f"accepted: still running after {case.timeout_s:g} s"
        finally:
            shutil.rmtree(d, ignore_errors=True)
        counts[case.group][o.kind] += 1
        counts["TOTAL"][o.kind] += 1
        results.append({"name": case.name, "group": case.group, "status": o.status, "kind": o.kind, "why": o.why,
                        "elapsed_s": round(o.elapsed_s, 2)})
        if o.kind != "clean":
            print(f"  {o.kind:14s} {case.name}: {o.why[:220]}", flush=True)
    tree = args.tree or REPO
    print(f"\nbad-input corpus: {len(results)} cases through {tree} in {time.perf_counter() - t0:.0f} s")
    head = f"{'group':12s} " + " ".join(f"{k:>15s}" for k in B.KINDS)
    print(head)
    print("-" * len(head))
    for group in list(dict.fromkeys(r["group"] for r in results)) + ["TOTAL"]:
        print(f"{group:12s} " + " ".join(f"{counts[group][k]:15d}" for k in B.KINDS))
    if args.json:
        args.json.write_text(json.dumps({"tree": str(tree), "results": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
