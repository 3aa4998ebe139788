"""False chirps on impulses, tones and real phone recordings; true chirps kept on simulated walks.

Part 1 — signals that hold no beacon chirp, so every detection is false (false chirps per minute):

* ``noise`` — white noise alone (rms 0.002);
* ``impulses 2/s``, ``impulses 10/s``, ``impulses 50/s`` — the noise with one-sample impulses
  (Poisson; amplitude 0.5, or log-uniform 0.01–0.5 with ``(levels)``): switching transients and
  corona/partial-discharge pulses; 10 per second is the rate the review (issue 21) names for
  HV equipment;
* ``impulses 10/s + 20 kHz tone`` — the same with an in-band 20 kHz sine (0.05) under it (the
  review's case: a phone's gesture tone, a transformer's magnetostriction harmonic);
* ``PD bursts`` — the simulator's discharge model (:mod:`simulation.acoustic.discharge`: pulses in
  phase windows of the 50 Hz supply, levels N(60, 8) dB at 1 m) heard 2 m from an active source,
  at its rate of 10/s and at 50/s;
* ``tone 1 kHz`` (out of band, half scale), ``tone 20 kHz`` (in noise);
* ``ultrasense`` — the five real Galaxy S3 recordings of a 20 kHz tone with hand and body motion in
  ../shared/data/audio_ultrasense (44.1 kHz, resampled by the reader).

Two sites: the five-beacon square of ``tests/acoustic_synth.py`` and the default coverage deployment
of a generated yard (``simulation.site.layout.generate_site(201)``: 24 beacons in two sub-bands,
0.96 s frames, so 24 search windows per frame and two templates); the bare-WAV timing (start 0,
±0.05 s). Each signal is run with the impulse blanker (:mod:`features.acoustic.impulses`, the
default) and without (``DetectorConfig(impulse_ratio=0)``, the receiver before it).

Part 2 (``--walks DIR``) — true chirps on simulated walks: for each walk directory (with
``audio_truth.csv``), chirps found within 2 ms of the truth, other detections, fixes and frames
with a fix per class, with and without the blanker.

Run: ``.venv/bin/python bench/false_chirps.py [--seconds 60] [--walks W1 W2 ...]``.
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from features.acoustic.detection import AudioTiming, DetectorConfig, detect_frames
from tests.acoustic_synth import square_site, write_wav

FS = 48_000
ULTRASENSE = Path(__file__).resolve().parents[2] / "shared" / "data" / "audio_ultrasense"
if not ULTRASENSE.is_dir():
    ULTRASENSE = Path("/work/shared/data/audio_ultrasense")

KINDS = ("noise", "impulses 2/s", "impulses 10/s", "impulses 10/s (levels)", "impulses 50/s (levels)",
         "impulses 10/s + 20 kHz tone", "PD bursts 10/s", "PD bursts 50/s", "tone 1 kHz", "tone 20 kHz")
"""The synthetic signals of part 1, in the order printed."""

BLANKER = {"after (blanker)": DetectorConfig(), "before (no blanker)": DetectorConfig(impulse_ratio=0.0)}


def _impulses(rng, n: int, rate_hz: float, levels: bool) -> np.ndarray:
    k = rng.poisson(rate_hz * n / FS)
    x = np.zeros(n)
    at = rng.integers(0, n, k)
    amp = np.exp(rng.uniform(np.log(0.01), np.log(0.5), k)) if levels else np.full(k, 0.5)
    np.add.at(x, at, amp * rng.choice([-1.0, 1.0], k))
    return x


def _pd_bursts(rng, n: int, rate_hz: float, distance_m: float = 2.0) -> np.ndarray:
    """The simulator's discharge pulses from one active source ``distance_m`` away, in full-scale units."""
    import dataclasses

    from features.site import Box
    from simulation.acoustic.discharge import DischargeConfig, DischargeSources

    site = dataclasses.replace(square_site(5), layout=(Box("transformer", "steel", False, 0.0, 1.0, 0.0, 1.0, 1.0),),
                               seed=1)
    src = DischargeSources(site, DischargeConfig(rate_hz=rate_hz, active_share=1.0), FS,
                           float(rng.uniform(0, 2 * np.pi)), 343.0)
    out = np.zeros(n + 64)
    rx = src.sources[0] + np.array([distance_m, 0.0, 0.0])
    chunk = 16384
    for i in range(0, n, chunk):
        m = min(chunk, n - i)
        seg = np.zeros(m + 64)
        src.add_pulses(seg, rng, i / FS, (i + m) / FS, FS, rx, 110.0, -100.0)
        out[i: i + m + 64] += seg
    return out[:n]


def synthetic(kind: str, seconds: float = 60.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    if kind == "clicks":                       # the earlier name of "impulses 2/s"
        kind = "impulses 2/s"
    if kind.startswith("tone 1 kHz"):
        return 0.5 * np.sin(2 * np.pi * 1000.0 * t)
    x = rng.normal(0, 0.002, n)
    if kind.startswith("impulses"):
        rate = float(kind.split()[1].split("/")[0])
        x += _impulses(rng, n, rate, "(levels)" in kind)
    elif kind.startswith("PD bursts"):
        x += _pd_bursts(rng, n, float(kind.split()[2].split("/")[0]))
    if "20 kHz" in kind:
        x += 0.05 * np.sin(2 * np.pi * 20_000.0 * t)
    return x


def count(path, site=None, detector: DetectorConfig = DetectorConfig()) -> tuple[int, float]:
    """(detections, seconds) of the receiver on ``path`` (every detection is false on these signals)."""
    import soundfile as sf

    site = site or square_site(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        n = sum(len(fr.detections) for fr in detect_frames(path, site, AudioTiming(0.0, 0.05, 0.0), detector))
    return n, sf.info(str(path)).duration


@functools.lru_cache(maxsize=1)
def sites() -> dict:
    """The two sites of part 1 (module docstring)."""
    from simulation.site.layout import generate_site

    return {"square, 5 beacons": square_site(5), "yard 201, 24 beacons": generate_site(201)}


def table(seconds: float = 60.0, seeds: int = 3) -> list[tuple[str, str, dict]]:
    """Per site and signal: {variant: (false chirps, seconds)} over ``seeds`` seeds of ``seconds`` each."""
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for kind in KINDS:
            tot = {(sn, name): [0, 0.0] for sn in sites() for name in BLANKER}
            for seed in range(seeds if "tone 1 kHz" not in kind else 1):
                p = Path(d) / "x.wav"
                write_wav(p, synthetic(kind, seconds, seed))
                for (sn, name) in tot:
                    n, s = count(p, sites()[sn], detector=BLANKER[name])
                    tot[sn, name][0] += n
                    tot[sn, name][1] += s
            rows += [(sn, kind, {name: tot[sn, name] for name in BLANKER}) for sn in sites()]
    for sn, site in sites().items():
        tot = {name: [0, 0.0] for name in BLANKER}
        for p in sorted(ULTRASENSE.glob("*.wav")):
            for name, det in BLANKER.items():
                n, s = count(p, site, detector=det)
                tot[name][0] += n
                tot[name][1] += s
        rows.append((sn, "ultrasense (5 phone files)", tot))
    return rows


def walk_chirps(walk_dir: Path, detector: DetectorConfig) -> dict:
    """True chirps found (within 2 ms of ``audio_truth.csv``), other detections, fixes and frames with a
    fix per class of the truth, for one simulated walk."""
    import csv

    from features.acoustic.features import analyse_audio
    from features.acoustic.positions import PositionConfig
    from features.acoustic.timing import timing_from_walk
    from features.walk import load_walk, read_truth

    w = load_walk(walk_dir)
    site = w.load_site()
    timing = timing_from_walk(w, site)
    truth = read_truth(w.directory)
    with open(walk_dir / "audio_truth.csv") as f:
        arr = {(int(r["beacon_id"]), round(float(r["emit_t_s"]), 3)): float(r["arrival_sample"]) / FS
               for r in csv.DictReader(f)}
    res = analyse_audio(w.path("audio"), site, timing, detector, keep_frames=True,
                        positions=PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05,
                                                 motion_speed_m_s=1.4))
    true = other = 0
    frames = np.zeros((3, 2), int)
    for fr in res.frames:
        for d in fr.detections:
            a = arr.get((d.beacon_id, round(d.tx_s, 3)))
            if a is not None and abs(d.arrival_s - timing.start_s - a) < 0.002:
                true += 1
            else:
                other += 1
        mid = fr.frame_start_s + 0.5 * site.acoustic.frame_s
        if truth.t_s[0] <= mid <= truth.t_s[-1]:
            k = int(truth.env_class[min(np.searchsorted(truth.t_s, mid), len(truth.t_s) - 1)])
            frames[k] += (1, fr.fix is not None)
    return {"true": true, "other": other, "fixes": len(res.fixes), "frames": frames}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--walks", type=Path, nargs="*", default=[])
    args = ap.parse_args(argv)
    names = list(BLANKER)
    print(f"{'site':22s} {'signal':30s} " + " ".join(f"{n + ', per min':>28s}" for n in names) + f" {'seconds':>8s}")
    for sn, kind, tot in sorted(table(args.seconds, args.seeds), key=lambda r: r[0]):
        s = tot[names[0]][1]
        print(f"{sn:22s} {kind:30s} " + " ".join(f"{tot[n][0]:14d} ({60 * tot[n][0] / tot[n][1]:8.2f})    "
                                                 for n in names) + f" {s:8.0f}")
    if args.walks:
        from features.site import ENV_CLASSES

        print(f"\n{'walk':28s} {'variant':20s} {'true':>6s} {'other':>6s} {'fixes':>6s} "
              + " ".join(f"{k + ' fix%':>10s}" for k in ENV_CLASSES))
        for w in args.walks:
            for name, det in BLANKER.items():
                r = walk_chirps(w, det)
                fr = r["frames"]
                print(f"{str(w)[-28:]:28s} {name:20s} {r['true']:6d} {r['other']:6d} {r['fixes']:6d} "
                      + " ".join(f"{100 * fr[k, 1] / max(fr[k, 0], 1):9.1f}%" for k in range(3)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
