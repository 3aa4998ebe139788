"""The whole story on a benchmark split: simulate, survey, library, models, held-out evaluation.

:func:`run_benchmark` is what ``envfuse benchmark`` and ``envfuse demo`` run:

1. build the split (:mod:`simulation.split`): training and test sites, a survey
   of each, walks on each — resumable, what exists is kept; simulated in ``workers`` processes
   (default one per core), the same bytes as a serial build;
2. ingest the *training* sites' surveys into one fingerprint library;
3. fit the environment model on it (mode ``env_mode``);
4. fit the fusion model on the training walks;
5. evaluate every method on the *test* sites' walks, which nothing above has seen:
   ``metrics.csv``, the summary table and the plots in ``<out>/report``.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable

from models.bp import BPConfig
from models.fusion.model import save_fusion_model
from pipeline.evaluate import bp_guard_line, evaluate, summary_table
from simulation.split import build_split
from training.env import fit_env_model, save_env_model, training_set
from training.filters import train_fusion

__all__ = ["run_benchmark", "fit_and_evaluate"]


def fit_and_evaluate(layout, library: Path, out: Path, *, env_mode: str = "supervised", seed: int = 0,
                     workers: int | None = None, bp_members: int = 5, say: Callable[[str], None] = print,
                     progress: bool = False, plots: bool = True, meta: dict | None = None,
                     class_smoothing: str = "forward", methods=None) -> dict:
    """Steps 3–5 on a built split: the environment model on the training sites' windows of ``library``
    (by name, whatever else a reused library may hold), the fusion model on the training walks, every
    method (or ``methods``) on the test walks; models and report written under ``out``. ``class_smoothing``: the
    class HMM's smoothing of the window classes in training and evaluation alike
    (:data:`walks.inputs.CLASS_SMOOTHING`; ``"forward"``, what ``run`` does, by default)."""
    from features.site import load_site

    sp = layout.split
    data = training_set(library, sites=[load_site(layout.site_dir(s) / "site.toml").name for s in sp.train_sites])
    clf, info = fit_env_model(data, env_mode, random_state=seed)
    save_env_model(clf, out / "env_model", info, library=library, overwrite=True)
    say(f"environment model ({env_mode}): {info['n_windows']} windows of {info['n_cells']} cells, "
        f"open/light/heavy = {'/'.join(map(str, info['class_counts']))}")
    for text in info.get("warnings", []):
        say(f"warning: {text}")
    from pipeline.site_map import class_map_for

    model = train_fusion(layout.train_walks, clf, bp_config=BPConfig(seed=seed, n_members=bp_members),
                         meta={"split": sp.name, "env_mode": env_mode, "env_meta": info, **(meta or {})},
                         class_map_for=class_map_for, progress=lambda line: say(f"  {line}"),
                         class_smoothing=class_smoothing)
    save_fusion_model(model, out / "fusion_model", overwrite=True)
    say(f"fusion model: {len(layout.train_walks)} training walks on sites {list(sp.train_sites)}")
    # The model names its training sites (so 'run' and 'evaluate' guard other sites later); here it is applied
    # to the held-out sites on purpose: that is the point of the split.
    return evaluate(layout.test_walks, out / "fusion_model", out / "report", methods=methods, workers=workers,
                    progress=progress, plots=plots, force=True, class_smoothing=class_smoothing)


def run_benchmark(split: str, out: str | os.PathLike, *, env_mode: str = "supervised", workers: int | None = None,
                  seed: int = 0, say: Callable[[str], None] = print, bp_members: int = 5) -> dict:
    """Run the split end to end into ``out``; returns the evaluation (see :func:`pipeline.evaluate.evaluate`)."""
    from fingerprints.survey import build_library

    out = Path(out)
    t0 = time.perf_counter()

    def stage(text):
        say(f"[{time.perf_counter() - t0:6.1f} s] {text}")

    stage(f"split {split!r}: simulating sites, surveys and walks (kept if already there)")
    layout = build_split(split, out / "data", progress=lambda line: stage(f"  simulated {line}"),
                         workers=workers or os.cpu_count() or 1)
    sp = layout.split
    library = out / "fingerprints.sqlite"
    for site in sp.train_sites:
        report = build_library(layout.survey_dir(site), library, progress=False)
        stage(f"  library: {report.summary()}")
    result = fit_and_evaluate(layout, library, out, env_mode=env_mode, seed=seed, workers=workers,
                              bp_members=bp_members, say=stage)
    stage(f"evaluated {len(result['results'])} held-out walks on sites {list(sp.test_sites)}")
    say(summary_table(result["pooled"]))
    shares = [r["bp_disabled_share"] for r in result["results"] if r["bp_disabled_share"] is not None]
    if shares:
        say(bp_guard_line(sum(shares) / len(shares)))
    say(f"report: {out / 'report'} (metrics.csv, {len(result['pngs'])} plots)")
    return result

