"""Speed of the GNSS path on a mixed real corpus (the 14 gpsd logs in ../shared/data/nmea/gpsd).

Prints, for the same lines:

* pynmea2's bare parse rate — ``pynmea2.parse(line, check=True)`` in a loop,
  nothing else: the ceiling the issue measures against;
* the reader, sentences/s: the whole-file fast path
  (:func:`features.gnss.nmea.epochs_from_bytes`: line/``$`` splitting and checksums
  vectorised with numpy, :mod:`features.gnss.quirks` interpreters), the
  streaming fast path (:func:`iter_epochs` over lines, checksum per sentence)
  and the pynmea2 path (same interpreters on pynmea2's tokens);
* the features (:func:`sky_arrays` + :func:`gnss_features`), epochs/s;
* the whole path (read + arrays + features) in sentences/s and its ratio to
  pynmea2's bare rate (target ≥ 40 %).

The fast path exists because pynmea2 alone costs about as much per sentence as
the target allows for the whole path: its regex split and class dispatch take
~10 µs a sentence, our checksum and ``str.split`` ~4 µs. pynmea2 remains the
reference: tests assert both paths give identical epochs on every real log.

Timings are CPU time of this process (``time.process_time``), medians over
interleaved rounds, because the machine is shared.

Usage: ``.venv/bin/python bench/bench_gnss.py [--repeat 7]``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pynmea2  # noqa: E402

from features.gnss.features import gnss_features, sky_arrays  # noqa: E402
from features.gnss.nmea import ReadStats, epochs_from_bytes, iter_epochs  # noqa: E402

GPSD = ROOT.parent / "shared" / "data" / "nmea" / "gpsd"


def _cpu_s(fn) -> float:
    """CPU seconds of this process for one call (process time: other processes' load does not count)."""
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="timing rounds; medians are reported")
    args = ap.parse_args(argv)
    if not GPSD.is_dir():
        print(f"no corpus at {GPSD}", file=sys.stderr)
        return 1
    corpus = []
    for log in sorted(GPSD.glob("*.log")):
        buf = log.read_bytes()
        sentences = [ln.decode("latin-1").strip() for ln in buf.split(b"\n") if ln.startswith(b"$")]
        corpus.append((log.name, buf, sentences))
    n_sentences = sum(len(s) for _, _, s in corpus)

    def bare():
        for _, _, sentences in corpus:
            for s in sentences:
                try:
                    pynmea2.parse(s, check=True)
                except pynmea2.ParseError:
                    pass

    def whole_file_reader():
        return [epochs_from_bytes(buf) for _, buf, _ in corpus]

    def line_reader(parser):
        def run():
            return [list(iter_epochs(buf.split(b"\n"), ReadStats(), parser=parser)) for _, buf, _ in corpus]
        return run

    epochs_per_file = whole_file_reader()
    n_epochs = sum(len(e) for e in epochs_per_file)
    n_sky = sum(sum(x.sky_reported for x in e) for e in epochs_per_file)

    def feats():
        for epochs in epochs_per_file:
            gnss_features(sky_arrays(epochs))

    def whole():
        for _, buf, _ in corpus:
            gnss_features(sky_arrays(epochs_from_bytes(buf)))

    runs = {k: [] for k in ("bare", "file", "lines", "pynmea2", "feats", "whole", "ratio")}
    for _ in range(args.repeat):  # interleaved, so a burst of load hits every variant alike
        b = _cpu_s(bare)
        w = _cpu_s(whole)
        runs["bare"].append(b)
        runs["whole"].append(w)
        runs["ratio"].append(b / w)
        runs["file"].append(_cpu_s(whole_file_reader))
        runs["lines"].append(_cpu_s(line_reader("fast")))
        runs["pynmea2"].append(_cpu_s(line_reader("pynmea2")))
        runs["feats"].append(_cpu_s(feats))
    med = {k: statistics.median(v) for k, v in runs.items()}
    bare_rate = n_sentences / med["bare"]
    print(f"corpus: {len(corpus)} gpsd logs, {n_sentences} sentences, {n_epochs} epochs ({n_sky} with sky); "
          f"CPU-time medians of {args.repeat} rounds")
    print(f"pynmea2.parse bare          : {bare_rate:9.0f} sentences/s")
    for key, label in (("file", "reader, whole file (fast)"), ("lines", "reader, lines (fast)"),
                       ("pynmea2", "reader, lines (pynmea2)")):
        rate = n_sentences / med[key]
        print(f"{label:<28}: {rate:9.0f} sentences/s  ({rate / bare_rate:.2f} x pynmea2)")
    print(f"features (arrays + 5)       : {n_epochs / med['feats']:9.0f} epochs/s  ({n_sky / med['feats']:.0f} sky epochs/s)")
    ratios = sorted(runs["ratio"])
    print(f"whole path (file -> features): {n_sentences / med['whole']:8.0f} sentences/s = "
          f"{100 * med['ratio']:.0f} % of pynmea2's bare rate (rounds: {100 * ratios[0]:.0f}-{100 * ratios[-1]:.0f} %; "
          f"target >= 40 %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
