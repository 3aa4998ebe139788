"""Benchmark of the audio simulator: audio seconds simulated per wall-clock second.

Renders a walk (default 300 s) along an aisle route of a generated site and a
static 30 s survey capture, and prints real-time factors, the peak of Python
heap allocations (tracemalloc) and, for reference, absorption in the beacon
band and example path sets. Memory holds one block of audio (65 536 samples)
plus arrays the size of the 100 Hz trajectory, never the recording.

    .venv/bin/python bench/bench_audio_sim.py [--duration 300] [--site-seed 3] [--seed 1]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from features.site import Atmosphere  # noqa: E402
from simulation.acoustic.channel import beacon_arrivals, build_scene  # noqa: E402
from simulation.acoustic.atmosphere import absorption_db_per_m  # noqa: E402
from simulation.acoustic.stream import AudioConfig, render_audio  # noqa: E402
from simulation.site.layout import generate_site  # noqa: E402
from simulation.rng import stream_rng  # noqa: E402
from simulation.site.route import RouteConfig, plan_route, route_trajectory, static_trajectory  # noqa: E402

START = datetime(2026, 6, 1, 8, 0, 0, tzinfo=timezone.utc)


def _timed(site, traj, seed, path, traced: bool):
    if traced:
        tracemalloc.start()
    t0 = time.perf_counter()
    res = render_audio(site, traj, seed, path, AudioConfig(), truth_path=path.with_suffix(".csv"))
    wall = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] if traced else 0
    if traced:
        tracemalloc.stop()
    return res, wall, peak


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0, help="walk length, s")
    ap.add_argument("--site-seed", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)

    atm = Atmosphere()
    a = absorption_db_per_m(np.array([17e3, 20e3, 23e3]), atm)
    print(f"ISO 9613-1 absorption at {atm.temperature_c} °C, {atm.relative_humidity_pct} % RH, "
          f"{atm.pressure_kpa} kPa: 17 kHz {a[0]:.3f}, 20 kHz {a[1]:.3f}, 23 kHz {a[2]:.3f} dB/m")

    site = generate_site(args.site_seed)
    print(f"site {site.name}: {len(site.layout)} boxes, {len(site.beacons)} beacons, {site.acoustic.n_slots} slots, "
          f"frame {site.acoustic.frame_s:.1f} s")
    scene = build_scene(site)
    for rx in ((60.0, 30.0, 1.0), (45.0, 66.0, 1.0)):
        print(f"example paths at receiver {rx[:2]}:")
        arr = sorted(beacon_arrivals(site, rx, scene).items(), key=lambda kv: kv[1][0])[:4]
        for bid, (delay, kind, paths) in arr:
            desc = ", ".join(f"{k} {l:.2f} m" + (f" (δ {d:.2f} m)" if k == "diffraction" else "")
                             for k, l, d in zip(paths.kind_names(), paths.length_m, paths.detour_m))
            print(f"  beacon {bid:2d}: first {kind} {delay * 1e3:.2f} ms, direct {paths.direct_m:.2f} m: {desc}")

    route = RouteConfig()
    poly, stops, speed = plan_route(site, stream_rng(args.seed, "route"), args.duration, route)
    walk = route_trajectory(poly, stops, speed, args.duration, START, site.device_height_m, route)
    cell = static_trajectory(60.0, 30.0, site.device_height_m, 30.0, START)
    with tempfile.TemporaryDirectory() as tmp:
        res, wall, _ = _timed(site, walk, args.seed, Path(tmp) / "walk.wav", traced=False)
        print(f"walk {args.duration:.0f} s: {wall:.1f} s wall, {args.duration / wall:.1f}x real time; "
              f"{res.n_rendered}/{res.n_emissions} emissions rendered, {res.n_clipped} clipped samples")
        res, wall, _ = _timed(site, cell, args.seed, Path(tmp) / "cell.wav", traced=False)
        print(f"static cell 30 s: {wall:.2f} s wall, {30.0 / wall:.1f}x real time")
        for dur in (60.0, 240.0, 600.0):
            w = route_trajectory(*plan_route(site, stream_rng(args.seed, "route"), dur, route), dur, START,
                                 site.device_height_m, route)
            _, wall, peak = _timed(site, w, args.seed, Path(tmp) / "m.wav", traced=True)
            print(f"walk {dur:.0f} s under tracemalloc: peak Python heap {peak / 2**20:.1f} MiB "
                  f"(audio written: {dur * 48_000 * 2 / 2**20:.1f} MiB; trajectory arrays "
                  f"{6 * w.t_s.nbytes / 2**20:.1f} MiB)")


if __name__ == "__main__":
    main()
