"""Single-path CIR features against SNR: a clean channel must read the same at every SNR.

One beacon, a static receiver, one straight-line path and white noise
(``tests/acoustic_synth.py``, independent of the simulator); the chirp amplitude
is set so that the receiver's reported peak SNR (strongest matched-filter tap
over the mean noise power per tap) lies near each target. Per target SNR the
median over the detected chirps of the nine features, the median reported SNR
and the share of chirps whose first arrival is more than 0.25 ms early (a noise
tap taken for the leading edge) are printed.

Run: ``.venv/bin/python bench/cir_single_path.py [--seconds 30]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from features.acoustic.cir import FEATURE_NAMES
from tests.acoustic_synth import single_path_run

TARGET_SNR_DB = (10.0, 16.0, 24.0, 32.0, 40.0)


def gain_for_snr(target_db: float, seconds: float, tmp: Path) -> float:
    """Chirp gain giving a median reported SNR near ``target_db`` (SNR ∝ gain², from a 40 dB probe)."""
    g0 = 0.05
    _, snr, _ = single_path_run(g0, min(seconds, 5.0), 99, tmp)
    return g0 * 10 ** ((target_db - float(np.median(snr))) / 20)


def table(seconds: float = 30.0, seed: int = 1) -> list[dict]:
    out = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for target in TARGET_SNR_DB:
            g = gain_for_snr(target, seconds, tmp)
            f, snr, err = single_path_run(g, seconds, seed, tmp)
            med = np.nanmedian(f, axis=0) if len(f) else np.full(9, np.nan)
            row = {"target_snr_db": target, "n": len(snr), "snr_db": float(np.median(snr)) if len(snr) else np.nan,
                   "early_share": float(np.mean(err < -2.5e-4)) if len(err) else np.nan}
            row.update({name: float(v) for name, v in zip(FEATURE_NAMES, med)})
            row["rms_delay_mean_ms"] = float(np.nanmean(f[:, 1])) if len(f) else np.nan
            out.append(row)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args(argv)
    rows = table(args.seconds)
    print(f"{'SNR dB':>7s} {'n':>4s} {'rep.SNR':>7s} {'early':>6s} {'τ_mean ms':>9s} {'τ_rms ms':>8s} "
          f"{'(mean)':>7s} {'K dB':>6s} {'g_m dB':>7s} {'g_rms':>6s}")
    for r in rows:
        print(f"{r['target_snr_db']:7.0f} {r['n']:4d} {r['snr_db']:7.1f} {r['early_share']:6.3f} "
              f"{r['mean_excess_delay_ms']:9.3f} {r['rms_delay_ms']:8.3f} {r['rms_delay_mean_ms']:7.3f} "
              f"{r['rician_k_db']:6.1f} {r['gain_mean_db']:7.2f} {r['gain_rms_db']:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
