"""Per-satellite decode agreement with gpsd, per receiver log (issue 20, "A real-data regression").

For every ``*.log`` with a ``*.log.chk`` beside it (gpsd's own decode) under the folders given
(default: every folder of ../shared/data/nmea), reads the log with
:func:`features.gnss.nmea.read_nmea` and compares each satellite entry (elevation, azimuth,
C/N0, used) with gpsd's, as :mod:`tests.gpsd_reference` describes. Files without a gpsd
reference (``*.nmea``, ``*.log`` without ``.chk``) are listed with their own entry counts.

Prints one line per log (gpsd entries, agree, differ, missing, extra, share) and the totals.

Usage: ``.venv/bin/python bench/gsv_gpsd_agreement.py [DIR ...] [--json OUT]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from features.errors import DataError  # noqa: E402
from features.gnss.nmea import read_nmea  # noqa: E402
from tests.gpsd_reference import Agreement, compare_with_gpsd, gpsd_cycles  # noqa: E402


def _default_dirs() -> list[Path]:
    from tests.conftest import SHARED_DATA

    base = SHARED_DATA / "nmea"
    return sorted(p for p in base.iterdir() if p.is_dir()) if base.is_dir() else []


def measure(dirs: list[Path]) -> tuple[dict, list]:
    """Agreement per log with a gpsd reference; (name, entries read) for files without one."""
    per_log: dict = {}
    unreferenced = []
    for d in dirs:
        for path in sorted(d.glob("*.log")) + sorted(d.glob("*.nmea")):
            chk = path.with_name(path.name + ".chk")
            try:
                epochs, _ = read_nmea(path)
            except DataError as exc:
                unreferenced.append((f"{d.name}/{path.name}", f"not read: {exc}"[:80]))
                continue
            if not chk.exists():
                unreferenced.append((f"{d.name}/{path.name}", f"{sum(len(e.satellites) for e in epochs)} "
                                     f"satellite entries, {len(epochs)} epochs; no gpsd reference"))
                continue
            cycles = gpsd_cycles(chk)
            if not cycles:  # no GSV in the log, or not NMEA at all (binary protocols, AIS, ...)
                unreferenced.append((f"{d.name}/{path.name}", f"{sum(len(e.satellites) for e in epochs)} "
                                     f"satellite entries; gpsd's decode lists no satellites"))
                continue
            per_log[f"{d.name}/{path.name}"] = compare_with_gpsd(epochs, cycles)
    return per_log, unreferenced


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="*", type=Path, help="folders of *.log + *.log.chk (default: ../shared/data/nmea/*)")
    ap.add_argument("--json", type=Path, help="also write the per-log counts here")
    args = ap.parse_args(argv)
    dirs = args.dirs or _default_dirs()
    if not dirs:
        print("no folder of NMEA logs found (../shared/data/nmea)", file=sys.stderr)
        return 1
    per_log, unreferenced = measure(dirs)
    total = Agreement()
    print(f"{'log':48s} {'gpsd':>6s} {'agree':>6s} {'differ':>6s} {'missing':>7s} {'extra':>6s} {'share':>8s}")
    for name, a in per_log.items():
        total += a
        print(f"{name:48s} {a.gpsd_entries:6d} {a.agree:6d} {a.differ:6d} {a.missing:7d} {a.extra:6d} "
              f"{100 * a.share:7.2f}%")
    print(f"{'total':48s} {total.gpsd_entries:6d} {total.agree:6d} {total.differ:6d} {total.missing:7d} "
          f"{total.extra:6d} {100 * total.share:7.2f}%")
    for name, what in unreferenced:
        print(f"{name:48s} {what}")
    if args.json:
        args.json.write_text(json.dumps({k: {"gpsd": a.gpsd_entries, "agree": a.agree, "differ": a.differ,
                                             "missing": a.missing, "extra": a.extra}
                                         for k, a in per_log.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
