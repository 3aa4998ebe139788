"""Fuzz run: at least 10⁶ mutated NMEA lines through the reader and the GNSS feature/fix path (issue 20).

Hypothesis draws batches of real receiver sentences (../shared/data/nmea/gpsd, tests/data), mutated as
:mod:`tests.nmea_fuzz` describes, and each batch goes through the reader (whole-file, streaming and
pynmea2 paths, held equal), the time base, the sky arrays, the five features, the ENU fixes with σ, the
GST reader, the C/N0 reference fit and both JSON writers. The run does not stop at a failure: every
failure is counted and the first few are written out (``--crash-dir``) for replay.

Prints: lines, batches, sentences skipped by the reader, typed errors by class, failures (0 is the
target), hangs (a batch stopped after 10 s), the slowest batch, wall and CPU time, lines/s, and a
yardstick timed in the same run (``scipy.signal.oaconvolve`` of 2·10⁶ float32 samples with 480 taps,
best of 3, as the other benches) with the run's CPU time in yardsticks, since the machine is shared.

Usage: ``.venv/bin/python bench/fuzz_nmea.py [--lines 1000000] [--seed 0] [--crash-dir DIR]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.nmea_fuzz import fuzz  # noqa: E402


def yardstick_s() -> float:
    """Best of 3 wall seconds of scipy.signal.oaconvolve(2e6 float32 samples, 480 taps)."""
    import time

    import numpy as np
    import scipy.signal

    x = np.random.default_rng(1).normal(size=2_000_000).astype(np.float32)
    h = np.random.default_rng(2).normal(size=480).astype(np.float32)
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=1_000_000, help="mutated lines to run (default 10^6)")
    ap.add_argument("--seed", type=int, default=0, help="hypothesis seed (the run is reproducible)")
    ap.add_argument("--crash-dir", type=Path, help="write the first 20 failing batches here")
    args = ap.parse_args(argv)
    yard = yardstick_s()
    tally, wall_s, cpu_s = fuzz(args.lines, args.seed)
    print(f"lines {tally.lines:,}  batches {tally.batches:,}  epochs {tally.epochs:,}  "
          f"sentences skipped by the reader {tally.skipped_sentences:,}")
    print(f"typed errors: {json.dumps(tally.typed_errors, sort_keys=True)}")
    kinds: dict = {}
    for name, msg, _, _ in tally.failures:
        kinds[f"{name}: {msg[:90]}"] = kinds.get(f"{name}: {msg[:90]}", 0) + 1
    print(f"failures (unexpected exceptions, warnings, non-finite outputs, paths disagreeing): {len(tally.failures)}")
    for k, v in sorted(kinds.items(), key=lambda kv: -kv[1])[:20]:
        print(f"  {v:6d}  {k}")
    print(f"hangs (a batch over 10 s): {tally.hangs}")
    print(f"slowest batch {1000 * tally.max_batch_s:.1f} ms; wall {wall_s:.1f} s, CPU {cpu_s:.1f} s, "
          f"{tally.lines / wall_s:,.0f} lines/s")
    print(f"yardstick (oaconvolve) {1000 * yard:.1f} ms; the run's CPU time = {cpu_s / yard:,.0f} yardsticks")
    if args.crash_dir and tally.failures:
        args.crash_dir.mkdir(parents=True, exist_ok=True)
        for i, (name, msg, tb, lines) in enumerate(tally.failures[:20]):
            (args.crash_dir / f"crash_{i:02d}.nmea").write_text("\n".join(lines) + "\n", encoding="latin-1")
            (args.crash_dir / f"crash_{i:02d}.txt").write_text(tb)
    return 1 if tally.failures else 0


if __name__ == "__main__":
    sys.exit(main())
