"""Benchmark and calibration report of the GNSS simulator.

Simulates a static capture in every survey cell of a generated site (the same
work as ``envfuse simulate survey`` does for the GNSS stream), times the
simulation and the NMEA formatting, and prints the calibration figures:
per-class medians (untracked share, attenuation, C/N0, fix error), LOS/NLOS
C/N0 against the smartLoc figures of docs/design.md §6, and error by fix quality.

Usage: .venv/bin/python bench/bench_gnss_sim.py [--site-seed 1] [--cells 0 (all)] [--capture-s 30] [--walk-s 600]
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from features.site import ENV_CLASSES  # noqa: E402
from simulation.site.environment import blocked_share, classify_share  # noqa: E402
from simulation.gnss.stream import simulate_gnss, to_nmea_epochs  # noqa: E402
from simulation.site.layout import generate_site  # noqa: E402
from simulation.gnss.nmea_writer import format_nmea  # noqa: E402
from simulation.site.route import static_trajectory  # noqa: E402
from simulation.streams import Trajectory  # noqa: E402
from simulation.survey import survey_cells  # noqa: E402


def _bench_walk(site_seed: int, duration_s: float) -> None:
    """A walker going back and forth along a row of the yard at 1.3 m/s (fading sub-sampled, a ray test per epoch)."""
    site = generate_site(site_seed)
    t = np.arange(0.0, duration_s + 1e-9, 0.01)
    g = site.grid
    span = g.east_max_m - g.east_min_m - 20.0
    east = g.east_min_m + 10.0 + span * np.abs(((t * 1.3 / span) % 2.0) - 1.0)
    north = np.full_like(t, 0.5 * (g.north_min_m + g.north_max_m))
    heading = np.where(np.gradient(east) > 0, np.pi / 2, 3 * np.pi / 2)
    traj = Trajectory(t, east, north, np.full_like(t, site.device_height_m), heading, np.full_like(t, 1.3),
                      datetime(2026, 5, 1, 2, 0, tzinfo=timezone.utc), 100.0)
    t0 = time.perf_counter()
    sim = simulate_gnss(site, traj, seed=1)
    t1 = time.perf_counter()
    format_nmea(to_nmea_epochs(sim, site, 1, traj))
    t2 = time.perf_counter()
    n = len(sim.t_s)
    print(f"walk {duration_s:.0f} s ({n} epochs): simulation {t1 - t0:.2f} s ({n / (t1 - t0):,.0f} epochs/s), "
          f"NMEA {t2 - t1:.2f} s ({n / (t2 - t1):,.0f} epochs/s)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--site-seed", type=int, default=1)
    ap.add_argument("--cells", type=int, default=0, help="number of cells (0 = all)")
    ap.add_argument("--capture-s", type=float, default=30.0)
    ap.add_argument("--cell-size", type=float, default=5.0)
    ap.add_argument("--no-corrections", action="store_true")
    ap.add_argument("--walk-s", type=float, default=600.0, help="also time a walk of this length (0 = skip)")
    args = ap.parse_args(argv)
    if args.walk_s > 0:
        _bench_walk(args.site_seed, args.walk_s)

    site = generate_site(args.site_seed)
    cells = survey_cells(site, args.cell_size)
    if args.cells:
        cells = cells[:: max(1, len(cells) // args.cells)][: args.cells]
    labels = classify_share(blocked_share(site, [c[1] for c in cells], [c[2] for c in cells]))
    start = datetime(2026, 5, 1, 2, 0, tzinfo=timezone.utc)
    t_sim = t_fmt = 0.0
    n_epochs = n_bytes = 0
    rows = {c: [] for c in range(3)}
    cn0_los, cn0_nlos, cn0_clear, cn0_blocked = [], [], [], []
    err_by_q: dict[int, list] = {}
    for i, ((cid, e, n), lab) in enumerate(zip(cells, labels)):
        traj = static_trajectory(e, n, site.device_height_m, args.capture_s, start + timedelta(seconds=50 * i))
        t0 = time.perf_counter()
        sim = simulate_gnss(site, traj, seed=1000 + i, corrections=not args.no_corrections)
        t1 = time.perf_counter()
        text = format_nmea(to_nmea_epochs(sim, site, 1000 + i, traj))
        t2 = time.perf_counter()
        t_sim += t1 - t0
        t_fmt += t2 - t1
        n_epochs += len(sim.t_s)
        n_bytes += len(text)
        view = sim.in_view & (sim.el_rad >= np.radians(10.0))
        herr = sim.horizontal_error_m
        trk = sim.tracked & view
        rows[int(lab)].append((
            (view & ~sim.tracked).sum() / max(view.sum(), 1),
            np.mean(sim.attenuation_db[trk]) if trk.any() else np.nan,
            np.nanmean(sim.cn0_reported_dbhz[trk]) if trk.any() else np.nan,
            np.nanmedian(herr) if np.isfinite(herr).any() else np.nan,
            np.mean(sim.quality == 4), np.mean(sim.quality == 0),
        ))
        cn0_los.append(sim.cn0_reported_dbhz[trk & sim.los])
        cn0_nlos.append(sim.cn0_reported_dbhz[trk & sim.nlos])
        cn0_clear.append(sim.cn0_reported_dbhz[trk & ~sim.blocked])
        cn0_blocked.append(sim.cn0_reported_dbhz[trk & sim.blocked])
        for q in np.unique(sim.quality):
            err_by_q.setdefault(int(q), []).append(herr[sim.quality == q])

    print(f"site seed {args.site_seed}: {len(cells)} cells x {args.capture_s:.0f} s, {n_epochs} epochs")
    print(f"simulation {t_sim:.2f} s ({n_epochs / t_sim:,.0f} epochs/s), NMEA formatting {t_fmt:.2f} s "
          f"({n_epochs / t_fmt:,.0f} epochs/s), total {t_sim + t_fmt:.2f} s, {n_bytes / 1e6:.1f} MB of NMEA")
    print("class  cells  untracked  atten_dB  cn0_dBHz  herr_med_m  rtk_fixed  no_fix   (medians over cells)")
    for c in range(3):
        r = np.array(rows[c], float)
        if len(r) == 0:
            continue
        med = np.nanmedian(r, axis=0)
        print(f"{ENV_CLASSES[c]:6s} {len(r):5d}  {med[0]:9.3f}  {med[1]:8.2f}  {med[2]:8.2f}  {med[3]:10.3f}"
              f"  {med[4]:9.2f}  {med[5]:6.2f}")
    los = np.concatenate(cn0_los)
    nlos = np.concatenate(cn0_nlos)
    print(f"tracked C/N0: LOS {los.mean():.1f} +- {los.std():.1f} dB-Hz (n={los.size}), "
          f"NLOS {nlos.mean():.1f} +- {nlos.std():.1f} dB-Hz (n={nlos.size}); smartLoc: 43.8 +- 4.5 vs 31.4 +- 7.9")
    clear = np.concatenate(cn0_clear)
    blocked = np.concatenate(cn0_blocked)
    print(f"tracked C/N0 by geometric ray test (as smartLoc labels): clear {clear.mean():.1f} +- {clear.std():.1f}, "
          f"blocked {blocked.mean():.1f} +- {blocked.std():.1f} dB-Hz (n={blocked.size})")
    names = {0: "none", 1: "autonomous", 2: "DGNSS", 4: "RTK fixed", 5: "RTK float"}
    for q in sorted(err_by_q):
        e = np.concatenate(err_by_q[q])
        if q == 0:
            print(f"quality 0 ({names[0]}): {e.size} epochs")
            continue
        print(f"quality {q} ({names[q]}): {e.size} epochs, horizontal error median {np.median(e):.3f} m, "
              f"p95 {np.percentile(e, 95):.3f} m")


if __name__ == "__main__":
    main()
