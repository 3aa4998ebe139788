"""``envfuse survey map``: classify every cell of a surveyed substation and draw its environment map."""

from __future__ import annotations

import io
from pathlib import Path

from features.errors import ConfigError
from pipeline.args import plot_path
from pipeline.outputs import check_outputs, check_writable, model_inputs, shipped_or_directory, survey_inputs

GROUP = "survey"

CELL_COLUMNS = ("cell_id", "east_m", "north_m", "predicted", "probability", "occlusion_estimate", "ood", "map_label",
                "map_share")


def register(sub) -> None:
    p = sub.add_parser(
        "map", help="environment map of a surveyed site from its fingerprint library and a model",
        description="Classify every window of the survey's cells (stored by 'survey build') with an environment "
                    "model, give each cell the class of its windows' combined probabilities, and draw the cells "
                    "over the site outline; where cells carry map labels, print the per-class accuracy and the "
                    "confusion matrix.",
        epilog="Example: envfuse survey map survey1 --library fp.sqlite --model env_model --out map.png "
               "--csv cells.csv")
    p.add_argument("survey", type=Path, metavar="SURVEY_DIR", help="survey directory (its site.toml names the site)")
    p.add_argument("--library", type=Path, required=True, help="fingerprint library holding the survey")
    p.add_argument("--model", type=Path, required=True,
                   help="environment model directory (train env), or 'default': the model shipped in envfuse")
    p.add_argument("--out", type=plot_path, required=True, help="plot to write (.png, .pdf or .svg)")
    p.add_argument("--csv", type=Path, default=None, help="also write one row per cell")
    p.set_defaults(func=_run)


def _survey_cells_in(survey: Path, library: Path, site_name: str) -> list[str]:
    """The ids of ``survey``'s cells, each checked to be the capture the library holds under its id (same start
    time and position): a library may hold another survey of the same site, whose cells must not be mapped as
    this one's. Refused (:class:`~features.errors.DataError`) when a cell is missing or another capture."""
    from features.errors import DataError
    from features.walk import load_walk
    from fingerprints.library import FingerprintLibrary
    from fingerprints.survey import survey_cell_dirs

    with FingerprintLibrary.open(library, create=False) as lib:
        stored = {str(c["cell_id"]): c for c in lib.cells(site_name)}
    ids, missing, other = [], [], []
    for d in survey_cell_dirs(survey):
        w = load_walk(d)
        cid = str(w.extra.get("id", d.name))
        ids.append(cid)
        c = stored.get(cid)
        if c is None:
            missing.append(cid)
            continue
        start = w.start_utc.isoformat().replace("+00:00", "Z") if w.start_utc is not None else ""
        east, north = w.extra.get("east_m"), w.extra.get("north_m")
        if (start and str(c["start_utc"]) and str(c["start_utc"]) != start) or \
                (isinstance(east, (int, float)) and abs(float(c["east_m"]) - east) > 1e-6) or \
                (isinstance(north, (int, float)) and abs(float(c["north_m"]) - north) > 1e-6):
            other.append(cid)
    if missing or other:
        def few(names):
            return ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
        what = (f"has no windows of its cells {few(missing)}" if missing else
                f"holds other captures under the ids of its cells {few(other)} (another survey of "
                f"{site_name}: other start times or positions)")
        raise DataError(f"--library {library} {what}, so it does not hold survey {survey}: build it into the "
                        f"library first ('envfuse survey build {survey} --library LIBRARY')")
    return ids


def _run(args) -> int:
    import numpy as np

    from features.fileio import atomic_write_text, is_stdout
    from features.site import ENV_CLASSES, load_site
    from fingerprints.library import FingerprintLibrary
    from models.environment import combine_windows
    from pipeline.env_plots import confusion, plot_survey_map
    from training.default_env import check_library_windows, resolve_env_model
    from training.env import training_set

    model_dir = shipped_or_directory(args.model, "--model")
    survey_files, survey_cells = survey_inputs(args.survey)
    check_outputs({"--library": args.library, **survey_files}, {"--out": args.out, "--csv": args.csv},
                  sealed={**survey_cells, **({} if model_dir is None else model_inputs(model_dir, "--model"))})
    for option, path in (("--out", args.out), ("--csv", args.csv)):    # both, before either is written
        if path is not None and not is_stdout(path):
            check_writable(path, option)
    if not (args.survey / "site.toml").is_file():
        raise ConfigError(f"{args.survey}: not a survey directory (no site.toml)")
    if not args.library.is_file():
        raise ConfigError(f"--library {args.library}: no such file")
    site = load_site(args.survey / "site.toml")
    clf, meta = resolve_env_model(model_dir)
    data = training_set(args.library, [site.name])
    check_library_windows(meta, data, f"--model {args.model}")
    data = data.subset(np.isin(data.cell, _survey_cells_in(args.survey, args.library, site.name)))
    proba = clf.predict_proba(data.X)
    ood = clf.is_ood(data.X)
    occ = clf.occlusion(data.X)
    cells = []
    keys = data.cell.tolist()
    order = {}
    for i, k in enumerate(keys):
        order.setdefault(k, []).append(i)
    for cell_id, idx in order.items():
        idx = np.array(idx)
        p = combine_windows(proba[idx])
        k = int(np.argmax(p))
        cells.append({"cell_id": cell_id, "predicted": ENV_CLASSES[k], "probability": float(p[k]),
                      "occlusion_estimate": float(np.nanmean(occ[idx])) if np.isfinite(occ[idx]).any() else
                      float("nan"), "ood": bool(ood[idx].mean() > 0.5),
                      "map_label": ENV_CLASSES[data.label[idx[0]]] if data.label[idx[0]] >= 0 else "",
                      "map_share": float(data.share[idx[0]])})
    with FingerprintLibrary.open(args.library, create=False) as lib:
        pos = {str(c["cell_id"]): (float(c["east_m"]), float(c["north_m"])) for c in lib.cells(site.name)}
    for c in cells:
        c["east_m"], c["north_m"] = pos[c["cell_id"]]
    if not cells:
        raise ConfigError(f"{args.library}: no windows of site {site.name!r} (run 'envfuse survey build' first)")
    plot_survey_map(site, cells, None, args.out)
    if args.csv is not None:
        buf = io.StringIO()
        buf.write(",".join(CELL_COLUMNS) + "\n")
        for c in cells:
            buf.write(",".join("" if isinstance(c[k], float) and np.isnan(c[k]) else
                               (f"{c[k]:.6g}" if isinstance(c[k], float) else str(c[k]).lower()
                                if isinstance(c[k], bool) else str(c[k])) for k in CELL_COLUMNS) + "\n")
        atomic_write_text(args.csv, buf.getvalue())
    counts = {k: sum(c["predicted"] == k for c in cells) for k in ENV_CLASSES}
    print(f"{site.name}: {len(cells)} cells, predicted open/light/heavy = "
          f"{counts['open']}/{counts['light']}/{counts['heavy']}, {sum(c['ood'] for c in cells)} OOD "
          f"(model: {meta.get('mode', '?')}) -> {args.out}")
    labelled = [c for c in cells if c["map_label"]]
    if labelled:
        t = np.array([ENV_CLASSES.index(c["map_label"]) for c in labelled])
        pr = np.array([ENV_CLASSES.index(c["predicted"]) for c in labelled])
        m = confusion(t, pr)
        rec = [f"{k} {100 * m[i, i] / m[i].sum():.1f} % ({m[i].sum()})" for i, k in enumerate(ENV_CLASSES) if m[i].sum()]
        trained_here = site.name in meta.get("sites", [])
        print("per-class accuracy against map labels (cells): " + ", ".join(rec)
              + (" -- a training-site figure: the model was fitted on this site's windows, so it says how well "
                 "the model learnt them, not how it does on a site it has not seen" if trained_here else
                 " (a site the model was not fitted on)"))
        print("confusion (rows map label, columns predicted open/light/heavy):")
        for i, k in enumerate(ENV_CLASSES):
            print(f"  {k:5s} " + " ".join(f"{v:4d}" for v in m[i]))
    return 0
