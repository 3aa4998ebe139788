"""The compiled receiver core gives the fixes the Python one gave: record them once, compare after (issue 25 item 1).

``--record FILE.npz`` runs the acoustic receiver (as ``walks.reader.read_walk`` does: walking-speed prior
1.4 m/s) over held-out simulated walks and stores every fix (time, east, north, clock offset, covariance, beacons
used and rejected, rms residual) and every detection (beacon, emission, arrival, SNR); ``--compare FILE.npz``
runs it again and reports, per walk, whether the fixes are the same ones (same count, same beacons kept) and
the largest difference of position (m), clock (s) and covariance, and how many fixes are bit-identical. The
criterion of the issue: same beacons, positions within 1e-9 m.

The walks are made here from seeds with the command line (``envfuse simulate site --seed S``, ``envfuse
simulate walk SITE --seed W --duration-s 300``), under ``--root`` (kept between runs): by default sites
201–205 (the standard split's test sites) and walk seeds 1000·site + 1 (``--walks-per-site N``: + 1 ... + N), three walks by default.

Run: ``.venv/bin/python bench/receiver_identity.py --root /tmp/identity --record before.npz``, change the
receiver, then ``... --compare before.npz``. ``--walks DIR ...`` runs given walk folders instead of ``--root``'s.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

ENVFUSE = [sys.executable, "-m", "pipeline"]


def walks(root: Path, sites, duration_s: float, per_site: int = 1) -> list[Path]:
    """Simulate (once) ``per_site`` walks per site under ``root`` with the CLI (walk seeds 1000·site + 1, + 2, ...);
    their directories."""
    out = []
    for s in sites:
        site_dir = root / f"site{s}"
        if not (site_dir / "site.toml").exists():
            subprocess.run(ENVFUSE + ["simulate", "site", "--seed", str(s), "--out", str(site_dir), "--force"],
                           check=True, capture_output=True)
        for k in range(1, per_site + 1):
            walk_dir = root / f"site{s}_walk{1000 * s + k}"
            if not (walk_dir / "walk.toml").exists():
                subprocess.run(ENVFUSE + ["simulate", "walk", str(site_dir), "--seed", str(1000 * s + k),
                                          "--duration-s", str(duration_s), "--out", str(walk_dir), "--force"],
                               check=True, capture_output=True)
            out.append(walk_dir)
    return out


def run(walk_dir: Path) -> tuple[dict, float]:
    """The receiver's fixes and detections on one walk (arrays), and its CPU seconds."""
    from features.acoustic.features import analyse_audio
    from features.acoustic.positions import PositionConfig
    from features.acoustic.timing import timing_from_walk
    from features.walk import load_walk

    w = load_walk(walk_dir)
    site = w.load_site()
    timing = timing_from_walk(w, site)
    t0 = time.process_time()
    res = analyse_audio(w.path("audio"), site, timing, keep_frames=True,
                        positions=PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05,
                                                 motion_speed_m_s=1.4))
    cpu = time.process_time() - t0
    fixes = res.fixes
    width = max([len(f.used_ids) for f in fixes] + [len(f.rejected_ids) for f in fixes] + [1])
    used = np.full((len(fixes), width), -1, dtype=np.int64)
    rejected = np.full((len(fixes), width), -1, dtype=np.int64)
    for i, f in enumerate(fixes):
        used[i, :len(f.used_ids)] = f.used_ids
        rejected[i, :len(f.rejected_ids)] = f.rejected_ids
    dets = [(d.beacon_id, d.tx_s, d.arrival_s, d.snr_db) for fr in res.frames for d in fr.detections]
    return {"t_s": np.array([f.t_s for f in fixes]), "east_m": np.array([f.east_m for f in fixes]),
            "north_m": np.array([f.north_m for f in fixes]), "clock_s": np.array([f.clock_offset_s for f in fixes]),
            "cov": np.array([np.asarray(f.covariance).ravel() for f in fixes]).reshape(-1, 9),
            "rms_m": np.array([f.rms_residual_m for f in fixes]), "used": used, "rejected": rejected,
            "detections": np.array(dets, dtype=float).reshape(-1, 4)}, cpu


def _same_ids(a: np.ndarray, b: np.ndarray) -> bool:
    w = max(a.shape[1], b.shape[1])
    pad = lambda m: np.pad(m, ((0, 0), (0, w - m.shape[1])), constant_values=-1)
    return a.shape[0] == b.shape[0] and bool(np.array_equal(pad(a), pad(b)))


def compare(before: dict, after: dict) -> dict:
    same = len(before["t_s"]) == len(after["t_s"]) and _same_ids(before["used"], after["used"])
    out = {"fixes": (len(before["t_s"]), len(after["t_s"])), "same_beacons": same,
           "same_detections": before["detections"].shape == after["detections"].shape and bool(
               np.array_equal(before["detections"], after["detections"]))}
    if same and len(before["t_s"]):
        d_pos = np.hypot(before["east_m"] - after["east_m"], before["north_m"] - after["north_m"])
        out.update(max_pos_m=float(d_pos.max()), max_clock_s=float(np.abs(before["clock_s"] - after["clock_s"]).max()),
                   max_t_s=float(np.abs(before["t_s"] - after["t_s"]).max()),
                   max_cov_rel=float(np.max(np.abs(before["cov"] - after["cov"]) / (np.abs(before["cov"]) + 1e-30))),
                   bit_identical=int(np.sum((before["east_m"] == after["east_m"]) & (before["north_m"] == after["north_m"])
                                            & (before["clock_s"] == after["clock_s"]))))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, help="where the walks are made and kept (unless --walks)")
    ap.add_argument("--sites", type=int, nargs="+", default=[201, 202, 203])
    ap.add_argument("--duration-s", type=float, default=300.0)
    ap.add_argument("--walks-per-site", type=int, default=1, help="walk seeds 1000·site + 1 ... + N")
    ap.add_argument("--walks", type=Path, nargs="+", default=None,
                    help="walk folders to run instead of the simulated ones (other sites, longer walks, real data)")
    group = ap.add_mutually_exclusive_group(required=True)
    group.add_argument("--record", type=Path)
    group.add_argument("--compare", type=Path)
    args = ap.parse_args(argv)
    if not (args.walks or args.root):
        ap.error("give --root (simulated walks made and kept there) or --walks")
    dirs = args.walks if args.walks else walks(args.root, args.sites, args.duration_s, args.walks_per_site)
    if args.walks and len({d.name for d in dirs}) < len(dirs):
        ap.error("--walks: the folders' names must differ (the record is keyed by name)")
    if args.record:
        store = {}
        for d in dirs:
            out, cpu = run(d)
            for k, v in out.items():
                store[f"{d.name}/{k}"] = v
            print(f"{d.name}: {len(out['t_s'])} fixes, {len(out['detections'])} detections, receiver {cpu:.2f} s CPU")
        np.savez(args.record, **store)
        return 0
    ref = np.load(args.compare)
    worst = 0.0
    ok = True
    for d in dirs:
        before = {k.split("/", 1)[1]: ref[k] for k in ref.files if k.startswith(d.name + "/")}
        after, cpu = run(d)
        c = compare(before, after)
        ok &= c["same_beacons"] and c.get("max_pos_m", 0.0) <= 1e-9
        worst = max(worst, c.get("max_pos_m", np.inf))
        print(f"{d.name}: {c}  (receiver {cpu:.2f} s CPU)")
    print(f"{'PASS' if ok else 'FAIL'}: same beacons kept and positions within 1e-9 m (largest {worst:.3g} m)")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
