"""False chirps per hour on clicks, tones and real phone recordings; true chirps kept on walks.

Every signal here holds no beacon chirp, so every detection is false:

* ``clicks`` — white noise (rms 0.002) with one-sample clicks (amplitude 0.5, 2 per second,
  the substation's switching impulses and corona in the extreme);
* ``tone 1 kHz`` — a plain 1 kHz sine at half scale, no noise (out of band);
* ``tone 20 kHz`` — an in-band 20 kHz sine (0.05) in noise (a phone's near-ultrasound
  gesture tone, a transformer's magnetostriction harmonic);
* ``ultrasense`` — the five real Galaxy S3 recordings of a 20 kHz tone with hand and body
  motion in ../shared/data/audio_ultrasense (44.1 kHz, resampled by the reader).

The site is the five-beacon square of ``tests/acoustic_synth.py``; the bare-WAV timing
(start 0, ±0.05 s). Run: ``.venv/bin/python bench/false_chirps.py``.
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from features.acoustic.detection import AudioTiming, detect_frames
from tests.acoustic_synth import square_site, write_wav

ULTRASENSE = Path(__file__).resolve().parents[2] / "shared" / "data" / "audio_ultrasense"
if not ULTRASENSE.is_dir():
    ULTRASENSE = Path("/work/shared/data/audio_ultrasense")


def synthetic(kind: str, seconds: float = 60.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n = int(seconds * 48_000)
    t = np.arange(n) / 48_000
    if kind == "clicks":
        x = rng.normal(0, 0.002, n)
        x[rng.choice(n, int(2 * seconds), replace=False)] += 0.5 * rng.choice([-1.0, 1.0], int(2 * seconds))
    elif kind == "tone 1 kHz":
        x = 0.5 * np.sin(2 * np.pi * 1000.0 * t)
    elif kind == "tone 20 kHz":
        x = 0.05 * np.sin(2 * np.pi * 20_000.0 * t) + rng.normal(0, 0.002, n)
    else:
        raise ValueError(kind)
    return x


def count(path, site=None) -> tuple[int, float]:
    import soundfile as sf

    site = site or square_site(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        n = sum(len(fr.detections) for fr in detect_frames(path, site, AudioTiming(0.0, 0.05, 0.0)))
    return n, sf.info(str(path)).duration


def table() -> list[tuple[str, int, float]]:
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for kind in ("clicks", "tone 1 kHz", "tone 20 kHz"):
            n_tot, s_tot = 0, 0.0
            for seed in range(5 if kind == "clicks" else 1):       # clicks: 600 s over five seeds
                p = Path(d) / f"{kind}.wav"
                write_wav(p, synthetic(kind, 120.0 if kind == "clicks" else 60.0, seed))
                n, s = count(p)
                n_tot, s_tot = n_tot + n, s_tot + s
            rows.append((kind, n_tot, s_tot))
    n_tot, s_tot = 0, 0.0
    for p in sorted(ULTRASENSE.glob("*.wav")):
        n, s = count(p)
        n_tot, s_tot = n_tot + n, s_tot + s
    rows.append(("ultrasense (5 files)", n_tot, s_tot))
    return rows


def main() -> int:
    print(f"{'signal':22s} {'false chirps':>12s} {'seconds':>8s} {'per hour':>9s}")
    for name, n, s in table():
        print(f"{name:22s} {n:12d} {s:8.1f} {3600 * n / s:9.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
