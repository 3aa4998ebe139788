"""``envfuse train env`` and ``envfuse train fusion``: fit the environment and the fusion model."""

from __future__ import annotations

import sys
from pathlib import Path

from features.errors import ConfigError, DataError
from pipeline.args import UsageError, seed
from pipeline.outputs import (check_outputs, check_replaceable, check_writable, directory_kind, model_inputs, plural,
                              refuse_repeated, shipped_or_directory)

GROUP = "train"


def register(sub) -> None:
    p = sub.add_parser(
        "env", help="environment model from a fingerprint library",
        description="Fit the online environment classifier from a fingerprint library: 'supervised' learns the "
                    "cells' map labels of the given sites; 'survey' clusters the library without labels "
                    "(t-SNE + density-peak clustering, clusters named by severity) and learns the clusters "
                    "(with --cell: semi-supervised, those labelled cells name the clusters and their labels are "
                    "spread to the other windows); "
                    "'transfer' does the same on training sites for use on a new one; 'default' writes a copy of "
                    "the model shipped in the package (trained on many simulated substations: for a user with no "
                    "labelled survey; no --library); 'finetune' adapts a model (--base, the shipped one by default) "
                    "to the labelled cells of your own survey (map labels of every cell, or of a handful: --cell).",
        epilog="Example: envfuse train env --library fp.sqlite --site sim-0101 --site sim-0102 --out env_model; "
               "envfuse train env --mode default --out env_model; "
               "envfuse train env --mode finetune --library fp.sqlite --site my-yard --out env_model; "
               "envfuse train env --mode survey --library fp.sqlite --site my-yard --cell E001N002 --cell E004N007 "
               "--cell E010N003 --out env_model")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--library", type=Path, help="fingerprint library (SQLite, from survey build)")
    src.add_argument("--walks", type=Path, nargs="+",
                     help="walk directories instead of a library: every 2 s window of each (a drive converted by "
                          "'convert smartloc' has no survey; --mode survey clusters its own windows)")
    p.add_argument("--site", action="append", default=None, help="site to fit on (repeat; default: every site)")
    p.add_argument("--mode", choices=("supervised", "survey", "transfer", "default", "finetune"), default="supervised",
                   help="where the classes come from (default supervised)")
    p.add_argument("--base", default=None,
                   help="--mode finetune: the model to adapt, a model directory or 'default' (the shipped one; "
                        "also when --base is left out)")
    p.add_argument("--cell", action="append", default=None,
                   help="--mode finetune: use only this labelled cell (repeat; default: every cell with a map label); "
                        "--mode survey: semi-supervised, the map labels of these cells name the clusters and are "
                        "spread to the other windows (label spreading), and the classifier learns the spread labels")
    p.add_argument("--sigma", type=_sigma, default=None,
                   help="--mode finetune: prior SD of the weights around the base's, or 'cv' to choose it by "
                        "cross-validation over the labelled cells (default 0.03, measured best on held-out sites)")
    p.add_argument("--seed", type=seed, default=None,
                   help="seed of the embedding, clustering and fits (default 0; --mode default and finetune "
                        "draw nothing and take none)")
    p.add_argument("--out", type=Path, required=True, help="model directory to write")
    p.add_argument("--plots", type=Path, default=None,
                   help="directory for PNGs: decision graph and t-SNE map (clustering modes), confusion matrix")
    p.add_argument("--overwrite", action="store_true", help="replace an existing model directory")
    p.set_defaults(func=_run_env)

    p = sub.add_parser(
        "fusion", help="fusion model (noise per class, BP network) from walks with truth",
        description="Fit the fusion model on training walks with truth.csv: measurement noise per source, per "
                    "GGA quality and per environment class (by the site map and by the environment model), "
                    "and the BP correction network (early stopping on a validation split of walks).",
        epilog="Example: envfuse train fusion --walks split/walks/101/w0 split/walks/101/w1 "
               "--env-model env_model --out fusion_model")
    p.add_argument("--walks", type=Path, nargs="+", required=True, help="training walk directories (with truth.csv)")
    p.add_argument("--env-model", type=Path, required=True,
                   help="environment model directory (train env), or 'default': the model shipped in envfuse")
    p.add_argument("--out", type=Path, required=True, help="model directory to write")
    p.add_argument("--no-bp", action="store_true", help="fit the noise only, no BP network")
    p.add_argument("--outlier", choices=("huber", "gate", "none"), default="huber",
                   help="outlier handling of the filter: Huber down-weighting (default: held on held-out sites "
                        "where the chi-square gate locked out), the 99.9 %% chi-square gate, or none")
    p.add_argument("--hidden", type=int, default=8, help="BP hidden units (default 8, as the source method)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the BP network's training (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing model directory")
    p.set_defaults(func=_run_fusion)


SIGMA_RANGE = (1e-6, 1e6)
"""--sigma's accepted range. The weights are those of standardised features (the shipped model's are of order
1), so 1e-6 is already the base unchanged to the last printed digit and 1e6 the data alone; beyond, σ² under- or
overflows in the prior term."""


def _sigma(text: str):
    """--sigma: 'cv' or a positive number in :data:`SIGMA_RANGE`."""
    import argparse

    if text == "cv":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number or 'cv', got {text!r}") from None
    lo, hi = SIGMA_RANGE
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"must be 'cv' or a number from {lo:g} to {hi:g}, got {text!r}")
    return value


ENV_PLOTS = ("decision_graph.png", "tsne_map.png", "confusion.png")
"""The PNGs ``train env --plots DIR`` may write."""


def _refuse_existing(out: Path, overwrite: bool, kind: str) -> None:
    """An existing --out needs --overwrite, and then must be a model folder of ``kind`` (or empty)."""
    if out.exists() and not overwrite:
        raise UsageError(f"--out {out} exists; pass --overwrite to replace it (only a {kind} folder is replaced)")
    if overwrite:
        check_replaceable(out, kind)


def _run_env(args) -> int:
    from training.env import fit_env_model, save_env_model, training_set

    if args.mode == "default":
        return _run_env_default(args)
    if args.library is None and args.walks is None:
        raise UsageError(f"--mode {args.mode} needs --library or --walks (--mode default needs neither)")
    if args.sigma is not None and args.mode != "finetune":
        raise UsageError("--sigma applies to --mode finetune only")
    if args.cell is not None and args.mode not in ("finetune", "survey"):
        raise UsageError("--cell applies to --mode finetune and --mode survey only")
    if args.base is not None and args.mode != "finetune":
        raise UsageError(f"--base applies to --mode finetune only (the model to adapt); --mode {args.mode} fits "
                         "from the library alone")
    if args.seed is not None and args.mode == "finetune":
        raise UsageError("--mode finetune draws nothing at random and takes no --seed")
    if args.walks is not None:
        refuse_repeated(args.walks, "--walks")
    base_dir = None if args.mode != "finetune" or args.base is None else shipped_or_directory(args.base, "--base")

    plots = {f"--plots {args.plots / n}": args.plots / n for n in ENV_PLOTS} if args.plots is not None else {}
    sealed = {f"--walks {w}": w for w in args.walks} if args.walks is not None else None
    if base_dir is not None:
        sealed = dict(sealed or {}, **model_inputs(base_dir, "--base"))
    check_outputs({"--library": args.library}, plots, {"--out": args.out}, sealed)
    _refuse_existing(args.out, args.overwrite, "environment model")
    check_writable(args.out, "--out")
    if args.plots is not None and args.plots.exists() and not args.plots.is_dir():
        raise UsageError(f"--plots {args.plots} exists and is not a directory")
    if args.plots is not None and args.plots.is_dir() and directory_kind(args.plots) in ("environment model",
                                                                                         "fusion model"):
        raise UsageError(f"--plots {args.plots} is a model folder, which holds its model only (a PNG in it would "
                         "stop it being replaced or checked as a model); name another directory")
    if args.plots is not None and (args.plots.resolve() == args.out.resolve() or args.out.resolve() in
                                   args.plots.resolve().parents):
        raise UsageError(f"--plots {args.plots} lies inside the model folder --out {args.out}: a model folder holds "
                         "the model only; name another directory")
    if args.walks is not None:
        from training.env import walk_training_set

        for w in args.walks:
            if not (w / "walk.toml").is_file():
                raise ConfigError(f"--walks {w}: no walk.toml (expected a walk directory)")
        if args.site:
            raise ConfigError("--site selects sites of a --library; with --walks, list the walks to use")
        data = walk_training_set(args.walks)
    else:
        if not args.library.is_file():
            raise ConfigError(f"--library {args.library}: no such file")
        data = training_set(args.library, args.site)
    diag: dict = {}
    if args.mode == "finetune":
        return _run_env_finetune(args, data, diag, base_dir)
    seeds = None
    if args.cell:
        seeds = _chosen_cells(args.cell, data)
        unlabelled = sorted(set(data.cell[seeds & (data.label < 0)].tolist()))
        if unlabelled:
            raise DataError(f"--cell {', '.join(unlabelled)}: no map label in the library; the semi-supervised "
                            "survey mode needs labelled cells (give the cell a map label, or leave it out)")
    clf, info = fit_env_model(data, args.mode, random_state=0 if args.seed is None else args.seed, diagnostics=diag,
                              seeds=seeds)
    for text in info.get("warnings", []):
        print(f"envfuse: warning: {text}", file=sys.stderr)
    if args.walks is not None:
        info["walks"] = [str(w) for w in args.walks]
    save_env_model(clf, args.out, info, library=args.library, overwrite=args.overwrite)
    if args.plots is not None:
        for png in _env_plots(clf, diag, args.plots):
            print(f"plot -> {png}")
    counts = "/".join(str(c) for c in info["class_counts"])
    if seeds is not None:
        print(f"semi-supervised: {info['seed_cells']} labelled cells ({info['seed_windows']} windows, open/light/heavy "
              f"= {'/'.join(str(c) for c in info['seed_class_counts'])}) named {info['n_clusters']} clusters; "
              f"labels spread to the other windows by {info['propagation']}")
    print(f"environment model ({args.mode}): {info['n_windows']} windows ({info['window_s']:g} s, hop "
          f"{info['hop_s']:g} s) of {plural(info['n_cells'], 'cell')} on {', '.join(info['sites'])}; windows per class "
          f"open/light/heavy = {counts}; sub-models {', '.join(sorted(clf.submodels_))} -> {args.out}")
    return 0


def _run_env_default(args) -> int:
    """``--mode default``: a copy of the shipped model in --out (it then works wherever a model folder does)."""
    from training.default_env import load_default_model
    from training.env import save_env_model

    for opt, value in (("--library", args.library), ("--walks", args.walks), ("--site", args.site),
                       ("--plots", args.plots), ("--cell", args.cell), ("--sigma", args.sigma),
                       ("--base", args.base), ("--seed", args.seed)):
        if value is not None:
            raise UsageError(f"--mode default copies the shipped model and takes no {opt}")
    check_outputs({}, {}, {"--out": args.out})
    _refuse_existing(args.out, args.overwrite, "environment model")
    clf, meta = load_default_model()
    meta = dict(meta, copied_from="the default model shipped in envfuse (training/data/default_env)")
    save_env_model(clf, args.out, meta, overwrite=args.overwrite)
    seeds = meta.get("site_seeds", [])
    print(f"environment model (default, shipped): supervised on {meta.get('n_sites')} simulated substations (site "
          f"seeds {min(seeds)}-{max(seeds)}), {meta.get('n_windows')} windows; sub-models "
          f"{', '.join(sorted(clf.submodels_))} -> {args.out}")
    return 0


def _run_env_finetune(args, data, diag: dict, base_dir: Path | None) -> int:
    """``--mode finetune``: MAP adaptation of --base (``base_dir``; None: the shipped model) to the labelled
    windows (of --cell cells when given)."""
    from models.finetune import SIGMA_GRID
    from training.default_env import DEFAULT_SIGMA, check_library_windows, finetune_env_model, resolve_env_model
    from training.env import save_env_model

    base_name = "default" if args.base is None else str(args.base)
    base, base_meta = resolve_env_model(base_dir)
    check_library_windows(base_meta, data, f"--base {base_name}")
    if args.cell:
        data = data.subset(_chosen_cells(args.cell, data))
        unlabelled = sorted(set(data.cell[data.label < 0].tolist()))
        if unlabelled:
            raise DataError(f"--cell {', '.join(unlabelled)}: no map label in the library; fine-tuning learns "
                            "from labelled cells only (give the cell a map label, or leave it out)")
    if not (data.label >= 0).any():
        if args.walks is not None:
            raise DataError("fine-tuning needs labelled windows: with --walks the labels are each walk's truth "
                            "classes (truth.csv), and none of the walks has one")
        raise DataError("fine-tuning needs labelled cells: none of the chosen cells has a map label")
    labelled = data.label >= 0
    n_classes = len(set(data.label[labelled].tolist()))
    n_cells = len(set(zip(data.site[labelled].tolist(), data.cell[labelled].tolist())))
    if args.sigma == "cv" and (n_cells < 2 or n_classes < 2):
        why = (f"only {plural(n_cells, 'labelled cell')}" if n_cells < 2 else
               f"every labelled cell is {_class_name(data.label[labelled][0])}")
        raise UsageError(f"--sigma cv needs labelled cells of at least two classes to cross-validate ({why}); "
                         f"give --sigma (default {DEFAULT_SIGMA:g}) or label more cells")
    if n_classes < 2:
        print(f"envfuse: warning: every labelled cell is {_class_name(data.label[labelled][0])}: fine-tuning on "
              "one class pulls the model towards it and the other classes' recall can only fall; label cells of "
              "each class you expect on the site", file=sys.stderr)
    clf, info = finetune_env_model(base, base_meta, data, DEFAULT_SIGMA if args.sigma is None else args.sigma)
    if args.sigma == "cv" and info["sigma"] == max(SIGMA_GRID):
        print(f"envfuse: warning: cross-validation chose sigma {info['sigma']:g}, the loosest prior of its grid "
              f"({', '.join(f'{g:g}' for g in SIGMA_GRID)}): the labelled cells pull far from the base (few cells, "
              f"a site unlike the base's, or labels of few classes); check the map on cells you did not label, "
              f"or give --sigma (default {DEFAULT_SIGMA:g})", file=sys.stderr)
    info["base_model"] = base_name
    if args.walks is not None:
        info["walks"] = [str(w) for w in args.walks]
    diag["data"] = data
    save_env_model(clf, args.out, info, library=args.library, overwrite=args.overwrite)
    if args.plots is not None:
        for png in _env_plots(clf, diag, args.plots):
            print(f"plot -> {png}")
    counts = "/".join(str(c) for c in info["class_counts"])
    how = {None: "the default", "cv": "chosen by cross-validation"}.get(args.sigma, "given")
    if info["sigma"] == 0:
        how += ": the base unchanged"
    print(f"environment model (finetune of {base_name}): {info['n_windows']} labelled windows of "
          f"{plural(info['n_cells'], 'cell')} on {', '.join(info['sites'])}; windows per class open/light/heavy = "
          f"{counts}; sigma {info['sigma']:g} ({how}) -> {args.out}")
    return 0


def _class_name(code) -> str:
    from features.site import ENV_CLASSES

    return ENV_CLASSES[int(code)]


def _chosen_cells(cells: list, data):
    """The windows (bool, shape (len(data),)) of the --cell cells; a cell the chosen data lacks is refused."""
    import numpy as np

    unknown = sorted(set(cells) - set(data.cell.tolist()))
    if unknown:
        raise ConfigError(f"--cell {', '.join(unknown)}: no such cell in the chosen data")
    return np.isin(data.cell, cells)


def _env_plots(clf, diag: dict, out: Path) -> list:
    from pipeline.env_plots import confusion, plot_confusion, plot_decision_graph, plot_embedding

    data = diag["data"]
    pngs = []
    cl = diag.get("clusters")
    if cl is not None and cl.embedding is not None:
        pngs.append(plot_decision_graph(cl.rho, cl.delta, cl.centers, out / "decision_graph.png"))
        pngs.append(plot_embedding(cl.embedding, cl.labels, data.label, out / "tsne_map.png"))
    if (data.label >= 0).any():
        m = confusion(data.label, clf.predict(data.X))
        pngs.append(plot_confusion(m, out / "confusion.png", "training windows: map label vs classifier"))
    return pngs


def _run_fusion(args) -> int:
    from features.errors import DataError, EnvfuseError
    from models.bp import BPConfig
    from models.fusion.model import save_fusion_model
    from models.fusion.noise import NoiseError
    from pipeline.outputs import model_inputs, refuse_repeated, walk_files
    from training.filters import train_fusion
    from walks.fuse import check_windows

    if args.hidden < 1:
        raise UsageError(f"--hidden must be at least 1, got {args.hidden}")
    refuse_repeated(args.walks, "--walks")
    inputs = {}
    for w in args.walks:
        inputs.update(walk_files(w, f"training walk {w.name}"))
    env_dir = shipped_or_directory(args.env_model, "--env-model")
    sealed = {f"--walks {w}": w for w in args.walks}           # as train env: nothing is written in a training walk
    if env_dir is not None:
        sealed.update(model_inputs(env_dir, "--env-model"))
    check_outputs(inputs, {}, {"--out": args.out}, sealed)
    _refuse_existing(args.out, args.overwrite, "fusion model")
    check_writable(args.out, "--out")                # before minutes of fitting, not after
    for w in args.walks:
        if not (w / "walk.toml").is_file():
            raise ConfigError(f"--walks {w}: no walk.toml (expected a walk directory)")
    from training.default_env import resolve_env_model

    clf, env_meta = resolve_env_model(env_dir)
    check_windows(env_meta, f"--env-model {args.env_model}")
    from models.fusion.ekf import EkfConfig

    from pipeline.site_map import class_map_for

    try:
        model = train_fusion(args.walks, clf, bp=not args.no_bp,
                             bp_config=BPConfig(hidden=args.hidden, seed=args.seed), ekf=EkfConfig(outlier=args.outlier),
                             meta={"env_model": str(args.env_model), "env_meta": env_meta},
                             class_map_for=class_map_for,
                             progress=lambda line: print(f"train fusion: {line}", file=sys.stderr))
    except (NoiseError, ValueError) as exc:
        if isinstance(exc, EnvfuseError) and not isinstance(exc, NoiseError):
            raise
        # the fits raise ValueError / NoiseError on data they cannot use (no fix with truth, too few events)
        walks = ", ".join(str(w) for w in args.walks)
        raise DataError(f"the fusion model cannot be fitted on --walks {walks}: {exc}") from None
    for text in default_noise_warnings(model):
        print(f"envfuse: warning: {text}", file=sys.stderr)
    save_fusion_model(model, args.out, overwrite=args.overwrite)
    print(f"fusion model: {plural(len(args.walks), 'training walk')} on {', '.join(model.meta['sites'])}; "
          f"BP {'on' if model.bp is not None else 'off'} -> {args.out}")
    return 0


def default_noise_warnings(model) -> list[str]:
    """One line per source whose noise was not fitted because no training walk had its fixes with truth: that
    source keeps the built-in default R (an isotropic σ per axis), which may be far from this receiver's."""
    import numpy as np

    from models.fusion.noise import FixedNoise

    default = FixedNoise()
    out = []
    for name, r, sigma in (("GNSS", model.fixed.R_gnss_, default.gnss_sigma_m),
                           ("acoustic", model.fixed.R_acoustic_, default.acoustic_sigma_m)):
        if np.allclose(r, sigma ** 2 * np.eye(2)):
            out.append(f"no training walk has {name} fixes with truth: the {name} noise keeps the default R "
                       f"(sigma {sigma:g} m per axis, {sigma ** 2:g} m2), not one fitted to this receiver")
    return out
