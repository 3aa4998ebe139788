"""Acoustic front end speed: WAV reading and the streaming matched filter, one core.

Writes a 5-minute 48 kHz int16 recording (white noise at −50 dBFS and a 10 ms
17–23 kHz chirp every 0.1 s; written block by block) and times, with
``time.process_time`` (CPU time of this process, best of ``--repeat`` runs, so
other load on the machine inflates the figures less than wall time would):

* reading alone: ``features.acoustic.audio.iter_audio_blocks`` in 4 s blocks;
* the matched filter alone: ``StreamingMatchedFilter.process`` over the same
  blocks already in memory, at the default segment length and at the others
  listed, for the 10 ms chirp;
* both, as the receiver runs them (read a block, filter it);
* the floor set by the two FFT calls alone: one batched ``scipy.fft.rfft`` of
  all segments and one batched inverse FFT of all band products, per block, with
  nothing else;

and the peak of memory allocated (``tracemalloc``) while reading and filtering
a 1-minute and the 5-minute file, which should not grow with the file.

Run: ``.venv/bin/python bench/bench_frontend.py [--repeat 5]`` (prints figures; no assertions).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"          # one core, set before numpy loads

import argparse
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import scipy.fft
import soundfile as sf

from features.acoustic.audio import iter_audio_blocks
from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank, StreamingMatchedFilter, chirp_template

FS = 48_000
SPEC = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)
BLOCK_S = 4.0


def write_recording(path: Path, minutes: float, seed: int = 0) -> None:
    """Noise at −50 dBFS plus the chirp every 0.1 s at −12 dBFS, int16, written 10 s at a time."""
    rng = np.random.default_rng(seed)
    s = 0.25 * chirp_template(SPEC, FS)
    period = FS // 10
    pattern = np.zeros(10 * FS)
    for start in range(0, len(pattern) - len(s), period):
        pattern[start + 1234: start + 1234 + len(s)] += s
    total = int(minutes * 60 * FS)
    with sf.SoundFile(str(path), "w", FS, 1, subtype="PCM_16") as fh:
        for done in range(0, total, len(pattern)):
            n = min(len(pattern), total - done)
            fh.write(pattern[:n] + rng.normal(0, 0.003, n))


def best_cpu_s(run, repeat: int) -> float:
    """Least CPU time of ``repeat`` calls of ``run``."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        run()
        times.append(time.process_time() - t0)
    return min(times)


def read_all(path: Path) -> None:
    for _ in iter_audio_blocks(path, block_s=BLOCK_S):
        pass


def filter_blocks(bank: MatchedFilterBank, blocks, nfft: int | None) -> None:
    mf = StreamingMatchedFilter(bank, nfft=nfft)
    for x in blocks:
        mf.process(x)
    mf.flush()


def read_and_filter(path: Path, bank: MatchedFilterBank) -> None:
    mf = StreamingMatchedFilter(bank)
    for block in iter_audio_blocks(path, block_s=BLOCK_S):
        mf.process(block.samples)
    mf.flush()


def fft_floor(bank: MatchedFilterBank, blocks) -> None:
    """The two batched FFT calls per block that the filter makes, on the same shapes, and nothing else."""
    mf = StreamingMatchedFilter(bank)
    for x in blocks:
        n_seg = -(-len(x) // mf.hop)
        seg = np.zeros((n_seg, mf.nfft), dtype=np.float32)
        t0 = time.process_time()
        scipy.fft.rfft(seg, axis=1, workers=1)
        scipy.fft.ifft(np.zeros((bank.n_templates, n_seg, mf.nfft // mf.decimation), np.complex64), axis=2,
                       workers=1, norm="forward")
        fft_floor.cpu_s += time.process_time() - t0


def peak_allocated_mib(path: Path, bank: MatchedFilterBank) -> float:
    tracemalloc.start()
    read_and_filter(path, bank)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2 ** 20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per figure; the fastest is kept (default 5)")
    args = parser.parse_args()
    bank = MatchedFilterBank([SPEC], FS)
    default_nfft = StreamingMatchedFilter(bank).nfft
    with tempfile.TemporaryDirectory() as tmp:
        files = {m: Path(tmp) / f"rec_{m}min.wav" for m in (1, 5)}
        for minutes, path in files.items():
            write_recording(path, minutes)
        path = files[5]
        audio_s = sf.info(str(path)).duration
        blocks = [b.samples for b in iter_audio_blocks(path, block_s=BLOCK_S)]

        def show(name: str, cpu_s: float) -> None:
            print(f"  {name:52s} {audio_s / cpu_s:7.0f}x  {cpu_s / audio_s * 1e3:6.3f} ms per audio s")

        print(f"5-min 48 kHz int16 file, {BLOCK_S:g} s blocks, one core, best of {args.repeat} (CPU time):")
        show("read (iter_audio_blocks)", best_cpu_s(lambda: read_all(path), args.repeat))
        for nfft in (default_nfft, 8192, 16384):
            label = f"matched filter alone, nfft {nfft}" + (" (default)" if nfft == default_nfft else "")
            show(label, best_cpu_s(lambda: filter_blocks(bank, blocks, nfft), args.repeat))
        show("read + matched filter", best_cpu_s(lambda: read_and_filter(path, bank), args.repeat))
        floors = []
        for _ in range(args.repeat):
            fft_floor.cpu_s = 0.0
            fft_floor(bank, blocks)
            floors.append(fft_floor.cpu_s)
        show(f"  of which the two FFT calls alone (nfft {default_nfft})", min(floors))
        print("\npeak allocated while reading and filtering (tracemalloc):")
        for minutes, p in files.items():
            print(f"  {minutes}-min file: {peak_allocated_mib(p, bank):.1f} MiB")


if __name__ == "__main__":
    main()
