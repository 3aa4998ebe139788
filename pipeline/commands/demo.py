"""``envfuse demo``: simulate a site and a walk end to end and print what came out."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from pipeline.args import bounded, seed

GROUP = None  # a top-level command, registered by register_top


def register_top(sub) -> None:
    p = sub.add_parser("demo", help="simulate a site and a walk and summarise them",
                       description="End-to-end demonstration on a simulated substation.",
                       epilog="Example: envfuse demo --out demo_out")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output directory (default demo_out)")
    p.add_argument("--seed", type=seed, default=1, help="site and walk seed (default 1)")
    p.add_argument("--duration-s", "--duration", dest="duration", type=bounded(10.0, 3600.0, "s"), default=120.0,
                   help="walk length, s, 10 to 3600 (default 120; --duration is the old name)")
    p.set_defaults(func=run_demo)


def run_demo(args) -> int:
    from features.site import save_site
    from features.walk import load_walk, read_truth
    from pipeline.plots import plot_site
    from simulation.site.layout import class_shares, generate_site
    from simulation.walk import simulate_walk

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    site = generate_site(args.seed)
    site_dir = out / "site"
    site_dir.mkdir(exist_ok=True)
    save_site(site, site_dir / "site.toml")
    plot_site(site, site_dir / "site.png")
    shares = class_shares(site)
    print(f"[site]   {site.name}: {site.grid.east_max_m:.0f} x {site.grid.north_max_m:.0f} m, {len(site.layout)} "
          f"structures, {len(site.beacons)} beacons; area open/light/heavy = "
          f"{100 * shares[0]:.0f}/{100 * shares[1]:.0f}/{100 * shares[2]:.0f} %  -> {site_dir / 'site.png'}")
    walk_dir = simulate_walk(site_dir, out / "walk", seed=args.seed, duration_s=args.duration, overwrite=True)
    walk = load_walk(walk_dir)
    truth = read_truth(walk_dir)
    import numpy as np
    dist = float(np.sum(np.hypot(np.diff(truth.east_m), np.diff(truth.north_m))))
    cls = Counter(np.asarray(["open", "light", "heavy"])[truth.env_class])
    print(f"[walk]   {walk_dir}: {walk.duration_s:.0f} s, {dist:.0f} m walked; time in open/light/heavy = "
          f"{cls['open'] / len(truth.t_s):.0%}/{cls['light'] / len(truth.t_s):.0%}/{cls['heavy'] / len(truth.t_s):.0%}")
    nmea = walk.path("gnss")
    if nmea is not None:
        lines = nmea.read_text().splitlines()
        qual = Counter(line.split(",")[6] for line in lines if line[3:6] == "GGA")
        names = {"4": "RTK fixed", "5": "RTK float", "2": "DGNSS", "1": "autonomous", "0": "no fix"}
        print(f"[gnss]   {nmea.name}: {len(lines)} NMEA lines; fix quality "
              + ", ".join(f"{names.get(k, k)} {v}" for k, v in sorted(qual.items(), key=lambda kv: -kv[1])))
    for stream in ("audio", "imu"):
        p = walk.path(stream)
        if p is not None:
            print(f"[{stream}]{' ' * (6 - len(stream))}{p.name}: {p.stat().st_size / 1e6:.1f} MB")

    from pipeline.walk_report import error_table, plot_walk, walk_sources
    src = walk_sources(walk_dir)
    feats = src.gnss_features
    if feats is not None and len(feats["t_s"]):
        cls = truth.class_at(feats["t_s"])
        print("[features] GNSS medians per truth class (att_mean_db / invisible_ratio / dop_growth):")
        for k, c in enumerate(("open", "light", "heavy")):
            sel = cls == k
            if sel.any():
                print(f"           {c:5s}: " + " / ".join(f"{np.nanmedian(feats[f][sel]):.2f}" for f in
                                                        ("att_mean_db", "invisible_ratio", "dop_growth")))
    rows = src.acoustic_features
    if rows:
        t = np.array([r["t_s"] for r in rows])
        cls = truth.class_at(t)
        print("[features] acoustic medians per truth class (rms_delay_ms / rician_k_db), windows with a chirp:")
        for k, c in enumerate(("open", "light", "heavy")):
            sel = [r for r, ck in zip(rows, cls) if ck == k and r["acoustic_available"]]
            if sel:
                print(f"           {c:5s}: {np.nanmedian([r['rms_delay_ms'] for r in sel]):.2f} / "
                      f"{np.nanmedian([r['rician_k_db'] for r in sel]):.1f}   ({len(sel)} windows)")
    print("[errors] horizontal error per source, median (p95) in m:   all | open | light | heavy")
    for name, row in error_table(src).items():
        cells = [f"{row[c][2]:.2f} ({row[c][3]:.2f})" if c in row else "-" for c in ("all", "open", "light", "heavy")]
        print(f"           {name:8s} " + " | ".join(cells))
    png = plot_walk(src, out / "walk.png", title=f"{site.name}, walk seed {args.seed}")
    print(f"[plot]   {png}")
    print(f"done: outputs in {out}")
    return 0
