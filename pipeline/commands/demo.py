"""``envfuse demo``: the whole story on the small built-in split, in a few minutes on 2 cores.

Simulates two training substations and one held-out substation (surveys and
walks), builds the fingerprint library from the training surveys, trains the
environment and fusion models on the training sites only, evaluates every
fusion method on the held-out walks, prints the table and writes the report;
then puts the first held-out walk's raw sources against its truth.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.args import seed

GROUP = None  # a top-level command, registered by register_top


def register_top(sub) -> None:
    p = sub.add_parser("demo", help="the whole story on a small built-in split (a few minutes)",
                       description="Simulate training and held-out substations, survey them, build the "
                                   "fingerprint library, train the environment and fusion models on the training "
                                   "sites, evaluate every fusion method on the held-out walks and write the report.",
                       epilog="Example: envfuse demo --out demo_out")
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output directory (default demo_out)")
    p.add_argument("--seed", type=seed, default=0, help="model seed (default 0)")
    p.add_argument("--workers", type=int, default=None, help="evaluation workers (default one per core)")
    p.set_defaults(func=run_demo)


def run_demo(args) -> int:
    from features.errors import ConfigError
    from pipeline.benchmark import run_benchmark
    from pipeline.plots import plot_site
    from pipeline.walk_report import error_table, plot_walk, walk_sources
    from training.benchmark import split_layout

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.out)
    run_benchmark("demo", out, workers=args.workers, seed=args.seed)
    layout = split_layout(out / "data")
    test_site = layout.split.test_sites[0]
    walk = layout.test_walks[0]
    src = walk_sources(walk)
    png = plot_site(src.site, out / "report" / "test_site.png")
    print(f"[held-out site] {src.site.name}: {len(src.site.layout)} structures, {len(src.site.beacons)} beacons "
          f"-> {png}")
    print(f"[held-out walk] {walk}: raw sources, median (p95) horizontal error in m:   all | open | light | heavy")
    for name, row in error_table(src).items():
        cells = [f"{row[c][2]:.2f} ({row[c][3]:.2f})" if c in row else "-" for c in ("all", "open", "light", "heavy")]
        print(f"           {name:8s} " + " | ".join(cells))
    png = plot_walk(src, out / "report" / "test_walk_sources.png", title=f"site {test_site}, {walk.name}: sources")
    print(f"[plot] {png}")
    print(f"done: outputs in {out}")
    return 0
