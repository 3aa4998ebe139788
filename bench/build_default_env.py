"""Build the default environment model that ships in the package (issue 27 item 2).

Simulates ``--n-sites`` substations with site seeds 1001, 1002, ... (disjoint from every split of
:data:`simulation.split.SPLITS`: 101-106, 201-205, 301-305 — checked), each surveyed as the ``standard`` split
surveys its sites (10 m cells, 10 s captures, survey seed = site seed), builds their fingerprint library,
fits the supervised classifier (``train env``'s default: balanced multinomial logistic regression with
pairwise products) on every site's map labels, and writes the ``environment`` bundle with the seeds, the
split, the library's hash and the code version in its metadata (:func:`training.default_env.build_default_model`).
Every step is a pure function of the seeds, and what exists in ``--work`` is kept, so a rerun resumes.

Cost (measured, CPU time): 1.3 s per site layout, 24 s per survey of ~100 cells, 16 s to compute its
features on a first run; 17-26 s per site in total once warm (the shipped model's 24 sites: about 9 minutes of
CPU, 35 minutes of wall time in two processes on 2 cores shared with a split build). N = 24: what fitted the
time budget of issue 27's build; the learning curve still rises at 8 sites (bench/env_learning_curve.py), so a
larger N is the first thing to try for a better default.

Usage::

    python bench/build_default_env.py --work /tmp/default_env --n-sites 24 \
        --out training/data/default_env      # (--overwrite to replace the shipped one)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def simulate_sites(work: Path, sites, cell_size_m: float, capture_s: float, say=print, lib: Path | None = None) -> Path:
    """Sites and surveys of ``sites`` under ``work`` (``sites/<seed>``, ``surveys/<seed>``), features of each
    added to ``lib`` (default ``work/library.sqlite``) unless a ``work/library*.sqlite`` holds the site already;
    returns the library path. What exists is kept (an interrupted feature build resumes by rerunning
    :func:`fingerprints.survey.build_library` on that survey)."""
    from features.site import save_site
    from fingerprints.library import FingerprintLibrary
    from fingerprints.survey import build_library
    from simulation.site.layout import generate_site
    from simulation.survey import simulate_survey

    lib = lib or work / "library.sqlite"
    done = set()        # sites already in any library of the work directory (two builders may share it)
    for other in sorted(set(work.glob("library*.sqlite")) | {lib}):
        if other.is_file():
            with FingerprintLibrary.open(other, create=False) as fl:
                done |= set(fl.sites())
    for seed in sites:
        t0 = time.process_time()
        sdir, vdir = work / "sites" / str(seed), work / "surveys" / str(seed)
        if not (sdir / "site.toml").is_file():
            sdir.mkdir(parents=True, exist_ok=True)
            save_site(generate_site(seed), sdir / "site.toml")
        if not vdir.is_dir():
            vdir.parent.mkdir(parents=True, exist_ok=True)
            simulate_survey(sdir, vdir, seed=seed, cell_size_m=cell_size_m, capture_s=capture_s, progress=False)
        from features.site import load_site

        if load_site(vdir / "site.toml").name not in done:
            build_library(vdir, lib, progress=False)
        say(f"site {seed}: {time.process_time() - t0:.0f} s CPU")
    return lib


def main() -> None:
    from simulation.split import SPLITS
    from training.default_env import DEFAULT_CAPTURE_S, DEFAULT_CELL_M, default_sites

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, required=True, help="where sites, surveys and the library are built")
    ap.add_argument("--n-sites", type=int, default=24)
    ap.add_argument("--first-seed", type=int, default=1001)
    ap.add_argument("--out", type=Path, default=None, help="the bundle to write (none: simulate only)")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    sites = default_sites(args.n_sites, args.first_seed)
    taken = {s for sp in SPLITS.values() for s in sp.train_sites + sp.test_sites}
    clash = sorted(taken & set(sites))
    if clash:
        raise SystemExit(f"site seeds {clash} belong to a benchmark split; choose another --first-seed")
    args.work.mkdir(parents=True, exist_ok=True)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        lib = simulate_sites(args.work, sites, DEFAULT_CELL_M, DEFAULT_CAPTURE_S,
                             say=lambda line: print(line, flush=True))
        if args.out is not None:
            t0 = time.process_time()
            from training.default_env import build_default_model

            libs = [lib] + sorted(p for p in args.work.glob("library*.sqlite") if p != lib)
            path = build_default_model(libs, sites, args.out, split_sites=sorted(taken), overwrite=args.overwrite)
            print(f"wrote {path} ({time.process_time() - t0:.0f} s CPU to fit)")


if __name__ == "__main__":
    main()
