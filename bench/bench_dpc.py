"""Density-peak clustering and the t-SNE embedding: speed and memory, one core.

Times, each task in a fresh process (so that its peak resident set is its own):

* ``models.dpc.DensityPeakClustering`` (defaults: cutoff kernel, 2 % rule capped at 100
  neighbours, automatic centres) on 100,000 and 1,000,000 2-D points (five gaussian blobs of
  different spreads plus 5 % uniform background);
* the same estimator against the dense O(n²) reference of ``tests/dpc_reference.py`` at 20,000
  points (the dense one holds the 20,000² distance matrix, 3.2 GB), with a check that the
  labels agree;
* t-SNE + DPC (``models.embedding.EnvironmentEmbedding``) on a 20,000-window synthetic
  14-feature library (``tests/env_synth.py``), openTSNE and scikit-learn in the same run, with
  trustworthiness (``sklearn.manifold.trustworthiness``, k = 10) on a fixed 5,000-window subset
  (the full 20,000² rank matrices would dominate the run), and the ARI of the named classes
  against the synthetic truth.

Memory: the peak resident set (``resource.getrusage(RUSAGE_SELF).ru_maxrss``, which includes
the interpreter and libraries, ~150 MB) and the peak of numpy-visible allocations
(``tracemalloc``; the KD-tree's C++ buffers are not traced, the RSS figure covers them).

This 2-core virtual machine's speed drifts from minute to minute, so a yardstick is timed in
every child before and after its task: ``scipy.signal.oaconvolve`` of 60 s of 48 kHz float32
noise with a 480-tap kernel (the size ``bench/bench_audio.py`` times as its yardstick); each
task is also printed as a multiple of the yardstick.

Run: ``.venv/bin/python bench/bench_dpc.py [--quick]`` (prints a table; no assertions).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"          # one core, set before numpy loads

import json
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np
import scipy.signal


def yardstick_s() -> float:
    """Seconds for scipy.signal.oaconvolve of 60 s of 48 kHz float32 noise with 480 taps (best of 3)."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal(48_000 * 60).astype(np.float32)
    h = rng.standard_normal(480).astype(np.float32)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        scipy.signal.oaconvolve(x, h)
        best = min(best, time.perf_counter() - t0)
    return best


def points_2d(n: int, seed: int = 0) -> np.ndarray:
    """Five gaussian blobs of different spreads and 5 % uniform background, shape (n, 2)."""
    rng = np.random.default_rng(seed)
    centres = np.array([[0, 0], [8, 1], [3, 7], [-6, 5], [10, 9]], float)
    spread = np.array([1.0, 1.5, 0.7, 2.0, 1.2])
    nb = n // 20
    c = rng.integers(0, 5, n - nb)
    X = np.concatenate([centres[c] + rng.normal(size=(n - nb, 2)) * spread[c, None],
                        rng.uniform([-12, -6], [16, 15], (nb, 2))])
    return X[rng.permutation(n)]


def _run(task: str) -> dict:
    from models.dpc import DensityPeakClustering
    out: dict = {}
    if task.startswith("dpc"):
        X = points_2d(int(task[3:]))
        t0 = time.perf_counter()
        m = DensityPeakClustering().fit(X)
        out.update(wall_s=time.perf_counter() - t0, n_clusters=int(m.n_clusters_), dc=m.dc_,
                   halo=float(m.halo_.mean()))
    elif task.startswith("dense"):
        from tests.dpc_reference import dense_dpc
        X = points_2d(int(task[5:]))
        t0 = time.perf_counter()
        ref = dense_dpc(X)
        out["wall_s"] = time.perf_counter() - t0
        out["labels"] = ref["labels"][:: max(1, len(X) // 2000)].tolist()
        out["n_clusters"] = len(ref["centers"])
    elif task.startswith("fast"):
        X = points_2d(int(task[4:]))
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            m = DensityPeakClustering().fit(X)
            best = min(best, time.perf_counter() - t0)
        out.update(wall_s=best, labels=m.labels_[:: max(1, len(X) // 2000)].tolist(), n_clusters=int(m.n_clusters_))
    elif task.startswith("tsne-"):
        from sklearn.manifold import trustworthiness
        from sklearn.metrics import adjusted_rand_score
        from models.embedding import EnvironmentEmbedding
        from tests.env_synth import CLASSES, synthetic_library
        backend, n = task[5:].split(":")
        X, y = synthetic_library(int(n), seed=0)
        t0 = time.perf_counter()
        e = EnvironmentEmbedding(tsne=backend, random_state=0).fit(X)
        wall = time.perf_counter() - t0
        t1 = time.perf_counter()
        e.dpc_.__class__(**e.dpc_.get_params()).fit(e.embedding_)
        dpc_s = time.perf_counter() - t1
        sub = np.random.default_rng(1).choice(len(X), min(len(X), 5000), replace=False)
        tw = trustworthiness(e.scaler_.transform(X)[sub], e.embedding_[sub], n_neighbors=10)
        out.update(wall_s=wall, dpc_s=dpc_s, trust=float(tw), n_clusters=int(e.n_clusters_),
                   ari_classes=float(adjusted_rand_score(y, np.searchsorted(CLASSES, e.classes_,
                                                                            sorter=np.argsort(CLASSES)))))
    return out


def child(task: str) -> None:
    """One task in this fresh process: yardstick, task under tracemalloc, yardstick; JSON out."""
    y0 = yardstick_s()
    tracemalloc.start()
    out = _run(task)
    out["traced_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out["yardstick_s"] = (y0 + yardstick_s()) / 2
    print(json.dumps(out))


def spawn(task: str) -> dict:
    r = subprocess.run([sys.executable, __file__, "--child", task], capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    quick = "--quick" in sys.argv
    sizes = (100_000,) if quick else (100_000, 1_000_000)
    dense_n = 5_000 if quick else 20_000
    lib_n = 5_000 if quick else 20_000
    print("DPC on 2-D points (defaults, one core)")
    print(f"  {'n':>9s} {'wall s':>8s} {'x yardstick':>12s} {'clusters':>9s} {'traced MB':>10s} {'RSS MB':>8s}")
    for n in sizes:
        r = spawn(f"dpc{n}")
        print(f"  {n:9,d} {r['wall_s']:8.2f} {r['wall_s'] / r['yardstick_s']:12.1f} {r['n_clusters']:9d} "
              f"{r['traced_peak_mb']:10.0f} {r['maxrss_mb']:8.0f}   (yardstick {r['yardstick_s']:.3f} s)")
    print(f"\nKD-tree vs dense reference at {dense_n:,} points (best of 3 for the KD-tree, one dense run)")
    f, d = spawn(f"fast{dense_n}"), spawn(f"dense{dense_n}")
    same = f["labels"] == d["labels"]
    print(f"  KD-tree {f['wall_s']:.2f} s (x{f['wall_s'] / f['yardstick_s']:.1f} yardstick), "
          f"traced {f['traced_peak_mb']:.0f} MB, RSS {f['maxrss_mb']:.0f} MB")
    print(f"  dense   {d['wall_s']:.2f} s (x{d['wall_s'] / d['yardstick_s']:.1f} yardstick), "
          f"traced {d['traced_peak_mb']:.0f} MB, RSS {d['maxrss_mb']:.0f} MB")
    print(f"  speed ratio {d['wall_s'] / f['wall_s']:.0f}x (yardstick-normalised "
          f"{(d['wall_s'] / d['yardstick_s']) / (f['wall_s'] / f['yardstick_s']):.0f}x); "
          f"sampled labels identical: {same}; clusters {f['n_clusters']} / {d['n_clusters']}")
    print(f"\nt-SNE + DPC on {lib_n:,} synthetic windows (14 features), same run")
    print(f"  {'backend':>9s} {'total s':>8s} {'x yardstick':>12s} {'DPC s':>6s} {'trust@10':>9s} {'clusters':>9s} "
          f"{'ARI':>6s} {'traced MB':>10s} {'RSS MB':>8s}")
    for b in ("opentsne", "sklearn"):
        r = spawn(f"tsne-{b}:{lib_n}")
        print(f"  {b:>9s} {r['wall_s']:8.1f} {r['wall_s'] / r['yardstick_s']:12.0f} {r['dpc_s']:6.2f} {r['trust']:9.4f} "
              f"{r['n_clusters']:9d} {r['ari_classes']:6.3f} {r['traced_peak_mb']:10.0f} {r['maxrss_mb']:8.0f}")


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        child(sys.argv[2])
    else:
        main()
