"""``envfuse demo`` and ``envfuse benchmark``: a seeded split end to end (:func:`pipeline.benchmark.run_benchmark`).

``benchmark`` builds a documented split (:data:`simulation.split.SPLITS`):
training and held-out test sites with surveys and walks, the fingerprint
library of the training surveys, the environment and fusion models fitted on
the training sites only, every method evaluated on the test sites' walks.
``demo`` is the small built-in split in a few minutes on 2 cores, then puts
the first held-out walk's raw sources against its truth.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.args import UsageError, seed

GROUP = None  # a top-level command, registered by register_top


def register_top(sub) -> None:
    from simulation.split import SPLITS
    from training.env import MODES

    p = sub.add_parser(
        "benchmark", help="a seeded split end to end: train on training sites, evaluate on held-out ones",
        description="Build a documented benchmark split (training sites and held-out test sites, each with a "
                    "survey and walks; resumable), ingest the training surveys into a fingerprint library, fit the "
                    "environment and fusion models on the training sites only and evaluate every method on the "
                    "test sites' walks. Splits: " + "; ".join(
                        f"{k}: train {list(v.train_sites)}, test {list(v.test_sites)}, {v.walks_per_site} walks of "
                        f"{v.walk_s:g} s per site" for k, v in SPLITS.items()),
        epilog="Example: envfuse benchmark --split standard --out bench_standard --workers 2")
    p.add_argument("--split", choices=sorted(SPLITS), default="demo", help="which split (default demo)")
    p.add_argument("--out", type=Path, required=True, help="directory for data, models and report (resumable)")
    p.add_argument("--env-mode", choices=MODES, default="supervised", help="environment model mode")
    p.add_argument("--workers", type=int, default=None,
                   help="simulation and evaluation workers (default one per core)")
    p.add_argument("--seed", type=seed, default=0, help="model seed (default 0)")
    p.set_defaults(func=run_benchmark_command)

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
    from pipeline.benchmark import run_benchmark
    from pipeline.plots import plot_site
    from pipeline.walk_report import error_table, plot_walk, walk_sources
    from simulation.split import split_layout

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1, got {args.workers}")
    out = Path(args.out)
    check_benchmark_dir(out)
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


def run_benchmark_command(args) -> int:
    from pipeline.benchmark import run_benchmark

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1, got {args.workers}")
    check_benchmark_dir(args.out)
    run_benchmark(args.split, args.out, env_mode=args.env_mode, workers=args.workers, seed=args.seed)
    return 0


def check_benchmark_dir(out: Path) -> None:
    """``--out`` of ``benchmark`` / ``demo``: absent, empty, or a benchmark folder (its ``data/split.toml``
    and nothing a benchmark does not write) — it is resumed and its models and report replaced, so nothing
    else may be there (exit 2)."""
    from pipeline.outputs import check_outputs, directory_kind

    check_outputs({}, {}, {"--out": out})
    if not out.exists():
        return
    if not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory")
    kind = directory_kind(out)
    if kind == "empty" or (kind == "benchmark" and (out / "data" / "split.toml").is_file()):
        return
    raise UsageError(f"--out {out} holds {'a ' + kind if kind else 'other files'}, not a benchmark (data/split.toml "
                     "with the models and report a benchmark writes): its models and report would be replaced; "
                     "name a new or empty directory")
