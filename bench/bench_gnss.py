"""Speed of the GNSS path on a mixed real corpus (the 14 gpsd logs in ../shared/data/nmea/gpsd).

Prints, for the same lines:

* pynmea2's bare parse rate — ``pynmea2.parse(line, check=True)`` in a loop,
  nothing else: the ceiling the issue measures against;
* the reader (:func:`features.nmea.iter_epochs`), sentences/s, on its fast
  path (own checksum and split, :mod:`features.nmea_quirks` interpreters) and
  on its pynmea2 path (same interpreters on pynmea2's tokens);
* the features (:func:`sky_arrays` + :func:`gnss_features`), epochs/s;
* the whole path (read + arrays + features) in sentences/s and its ratio to
  pynmea2's bare rate (target ≥ 40 %).

The fast path exists because pynmea2 alone costs about as much per sentence as
the target allows for the whole path: its regex split and class dispatch take
~10 µs a sentence, our checksum and ``str.split`` ~4 µs. pynmea2 remains the
reference: tests assert both paths give identical epochs on every real log.

Usage: ``.venv/bin/python bench/bench_gnss.py [--repeat 5]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pynmea2  # noqa: E402

from features.gnss_features import gnss_features, sky_arrays  # noqa: E402
from features.nmea import ReadStats, iter_epochs  # noqa: E402

GPSD = ROOT.parent / "shared" / "data" / "nmea" / "gpsd"


def _best_of(repeat: int, fn) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="timing repeats (best of)")
    args = ap.parse_args(argv)
    if not GPSD.is_dir():
        print(f"no corpus at {GPSD}", file=sys.stderr)
        return 1
    corpus = []
    for log in sorted(GPSD.glob("*.log")):
        lines = log.read_bytes().splitlines(keepends=True)
        corpus.append((log.name, lines, [ln.decode("latin-1").strip() for ln in lines if ln.startswith(b"$")]))
    n_sentences = sum(len(s) for _, _, s in corpus)

    def bare():
        for _, _, sentences in corpus:
            for s in sentences:
                try:
                    pynmea2.parse(s, check=True)
                except pynmea2.ParseError:
                    pass

    def reader(parser):
        def run():
            out = []
            for _, lines, _ in corpus:
                out.append(list(iter_epochs(lines, ReadStats(), parser=parser)))
            return out
        return run

    epochs_per_file = reader("fast")()
    n_epochs = sum(len(e) for e in epochs_per_file)
    n_sky = sum(sum(x.sky_reported for x in e) for e in epochs_per_file)

    def feats():
        for epochs in epochs_per_file:
            gnss_features(sky_arrays(epochs))

    def whole():
        for _, lines, _ in corpus:
            gnss_features(sky_arrays(list(iter_epochs(lines, ReadStats()))))

    t_bare = _best_of(args.repeat, bare)
    t_fast = _best_of(args.repeat, reader("fast"))
    t_py = _best_of(args.repeat, reader("pynmea2"))
    t_feat = _best_of(args.repeat, feats)
    t_whole = _best_of(args.repeat, whole)
    bare_rate = n_sentences / t_bare
    print(f"corpus: {len(corpus)} gpsd logs, {n_sentences} sentences, {n_epochs} epochs ({n_sky} with sky)")
    print(f"pynmea2.parse bare       : {bare_rate:10.0f} sentences/s")
    print(f"reader, fast path        : {n_sentences / t_fast:10.0f} sentences/s  ({t_bare / t_fast:.2f} x pynmea2)")
    print(f"reader, pynmea2 path     : {n_sentences / t_py:10.0f} sentences/s  ({t_bare / t_py:.2f} x pynmea2)")
    print(f"features (arrays + 5)    : {n_epochs / t_feat:10.0f} epochs/s     ({n_sky / t_feat:.0f} sky epochs/s)")
    print(f"whole path               : {n_sentences / t_whole:10.0f} sentences/s  "
          f"= {100 * t_bare / t_whole:.0f} % of pynmea2's bare rate (target >= 40 %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
