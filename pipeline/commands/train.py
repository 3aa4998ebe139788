"""``envfuse train env`` and ``envfuse train fusion``: fit the environment and the fusion model."""

from __future__ import annotations

import sys
from pathlib import Path

from features.errors import ConfigError
from pipeline.args import UsageError, seed
from pipeline.outputs import check_outputs, check_replaceable

GROUP = "train"


def register(sub) -> None:
    p = sub.add_parser(
        "env", help="environment model from a fingerprint library",
        description="Fit the online environment classifier from a fingerprint library: 'supervised' learns the "
                    "cells' map labels of the given sites; 'survey' clusters the library without labels "
                    "(t-SNE + density-peak clustering, clusters named by severity) and learns the clusters; "
                    "'transfer' does the same on training sites for use on a new one.",
        epilog="Example: envfuse train env --library fp.sqlite --site sim-0101 --site sim-0102 --out env_model")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--library", type=Path, help="fingerprint library (SQLite, from survey build)")
    src.add_argument("--walks", type=Path, nargs="+",
                     help="walk directories instead of a library: every 2 s window of each (a drive converted by "
                          "'convert smartloc' has no survey; --mode survey clusters its own windows)")
    p.add_argument("--site", action="append", default=None, help="site to fit on (repeat; default: every site)")
    p.add_argument("--mode", choices=("supervised", "survey", "transfer"), default="supervised",
                   help="where the classes come from (default supervised)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the embedding and clustering (default 0)")
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
    p.add_argument("--env-model", type=Path, required=True, help="environment model directory (train env)")
    p.add_argument("--out", type=Path, required=True, help="model directory to write")
    p.add_argument("--no-bp", action="store_true", help="fit the noise only, no BP network")
    p.add_argument("--outlier", choices=("huber", "gate", "none"), default="huber",
                   help="outlier handling of the filter: Huber down-weighting (default: held on held-out sites "
                        "where the chi-square gate locked out), the 99.9 %% chi-square gate, or none")
    p.add_argument("--hidden", type=int, default=8, help="BP hidden units (default 8, as the source method)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the BP network's training (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing model directory")
    p.set_defaults(func=_run_fusion)


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

    plots = {f"--plots {args.plots / n}": args.plots / n for n in ENV_PLOTS} if args.plots is not None else {}
    sealed = {f"--walks {w}": w for w in args.walks} if args.walks is not None else None
    check_outputs({"--library": args.library}, plots, {"--out": args.out}, sealed)
    _refuse_existing(args.out, args.overwrite, "environment model")
    if args.plots is not None and args.plots.exists() and not args.plots.is_dir():
        raise UsageError(f"--plots {args.plots} exists and is not a directory")
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
    clf, info = fit_env_model(data, args.mode, random_state=args.seed, diagnostics=diag)
    for text in info.get("warnings", []):
        print(f"envfuse: warning: {text}", file=sys.stderr)
    if args.walks is not None:
        info["walks"] = [str(w) for w in args.walks]
    save_env_model(clf, args.out, info, library=args.library, overwrite=args.overwrite)
    if args.plots is not None:
        for png in _env_plots(clf, diag, args.plots):
            print(f"plot -> {png}")
    counts = "/".join(str(c) for c in info["class_counts"])
    print(f"environment model ({args.mode}): {info['n_windows']} windows ({info['window_s']:g} s, hop "
          f"{info['hop_s']:g} s) of {info['n_cells']} cells on {', '.join(info['sites'])}; windows per class "
          f"open/light/heavy = {counts}; sub-models {', '.join(sorted(clf.submodels_))} -> {args.out}")
    return 0


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
    from training.env import load_env_model
    from training.filters import train_fusion
    from walks.fuse import check_windows

    if args.hidden < 1:
        raise UsageError(f"--hidden must be at least 1, got {args.hidden}")
    refuse_repeated(args.walks, "--walks")
    inputs = {}
    for w in args.walks:
        inputs.update(walk_files(w, f"training walk {w.name}"))
    check_outputs(inputs, {}, {"--out": args.out}, model_inputs(args.env_model, "--env-model"))
    _refuse_existing(args.out, args.overwrite, "fusion model")
    for w in args.walks:
        if not (w / "walk.toml").is_file():
            raise ConfigError(f"--walks {w}: no walk.toml (expected a walk directory)")
    clf, env_meta = load_env_model(args.env_model)
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
    print(f"fusion model: {len(args.walks)} training walks on {', '.join(model.meta['sites'])}; "
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
