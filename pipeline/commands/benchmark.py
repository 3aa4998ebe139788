"""``envfuse benchmark``: a documented split end to end (simulate, survey, train, evaluate held-out sites)."""

from __future__ import annotations

from pathlib import Path

from pipeline.args import seed

GROUP = None


def register_top(sub) -> None:
    from training.benchmark import SPLITS
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
    p.set_defaults(func=_run)


def _run(args) -> int:
    from features.errors import ConfigError
    from pipeline.benchmark import run_benchmark

    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {args.workers}")
    run_benchmark(args.split, args.out, env_mode=args.env_mode, workers=args.workers, seed=args.seed)
    return 0
