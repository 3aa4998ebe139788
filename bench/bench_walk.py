"""Speed and memory of a whole simulated walk (every stream): wall time, real-time factor, peak RSS.

Usage: /work/main/.venv/bin/python bench/bench_walk.py [--duration 600] [--site-seed 1] [--seed 1]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from features.site import save_site  # noqa: E402
from simulation.site.layout import generate_site  # noqa: E402
from simulation.walk import simulate_walk  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--site-seed", type=int, default=1)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "site"
        d.mkdir()
        save_site(generate_site(args.site_seed), d / "site.toml")
        t0 = time.perf_counter()
        kwargs = {"progress": False} if "progress" in simulate_walk.__code__.co_varnames else {}
        simulate_walk(d, Path(tmp) / "walk", seed=args.seed, duration_s=args.duration, **kwargs)
        wall = time.perf_counter() - t0
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"walk {args.duration:.0f} s: {wall:.1f} s wall, {args.duration / wall:.1f}x real time, "
          f"peak RSS {peak_mib:.0f} MiB")


if __name__ == "__main__":
    main()
