"""GNSS σ consistency: mean NEES per fix quality and environment class, for each σ model (issue 11 item 8).

Reads simulated walks exactly as the pipeline does (NMEA → epochs on the walk's time base →
:func:`features.gnss.positions.fixes_to_enu`), compares each fix with the truth at its time and
prints the mean NEES (2 degrees of freedom: 2 for a consistent σ; Bar-Shalom, Li & Kirubarajan
2001, §5.4.2) per GGA quality and class of the truth, for:

* ``table``: σ = UERE(quality)·HDOP/√2, the table alone (before issue 11);
* ``cn0``: the built-in model, table × the SIGMA-ε factor g of the used satellites' C/N0 (not for RTK fixed);
* ``cn0+zeta``: as ``cn0`` with the variance also scaled by 1 + c_q·ζ, ζ the epoch's invisible ratio
  (in-view-but-untracked share above the mask), c_q per quality by maximum likelihood on the
  training walks;
* ``cn0+zeta(c)``: the same with c_q chosen on the training walks by the reported criterion
  (mean |ln(NEES/2)| over the quality's classes);
* ``fitted``: :func:`fit_uere` on the training walks (UERE per quality and attenuation bin);
* ``fitted+zeta``: the same with the fitted variance scaled by 1 + c_q·ζ (c_q fitted on the
  training walks after the table).

GST (the receiver's own residual statistics) is used whenever a log has it; the simulator writes
none, so these walks cannot say whether GST's rms residual would add anything.

Usage: ``python bench/bench_gnss_sigma.py --train W... --test W...`` (walk directories with truth.csv).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

QUALITY_NAMES = {4: "RTK fixed", 5: "RTK float", 2: "DGNSS", 1: "SPS"}
C_GRID = np.concatenate([[0.0], np.geomspace(0.01, 100.0, 161)])


def walk_fixes(walk_dir: Path) -> tuple:
    """(positions, truth (t, east, north), class per fix) of one walk."""
    from features.gnss.features import sky_arrays
    from features.gnss.nmea import epochs_on_time_base, read_nmea
    from features.gnss.positions import fixes_to_enu
    from features.walk import load_walk, read_truth

    walk = load_walk(walk_dir)
    o = walk.load_site().origin
    epochs = epochs_on_time_base(read_nmea(walk.path("gnss"))[0], walk.start_utc)
    pos = fixes_to_enu(epochs, o.lat_deg, o.lon_deg, o.alt_m, sky=sky_arrays(epochs))
    truth = read_truth(walk.directory)
    return pos, truth


def _errors(pos, truth):
    """(inside mask, per-axis squared error mean r = |e|²/2, class index) per fix."""
    inside = (pos.t_s >= truth.t_s[0]) & (pos.t_s <= truth.t_s[-1])
    e = pos.east_m - np.interp(pos.t_s, truth.t_s, truth.east_m)
    n = pos.north_m - np.interp(pos.t_s, truth.t_s, truth.north_m)
    i = np.clip(np.searchsorted(truth.t_s, pos.t_s), 0, len(truth.t_s) - 1)
    return inside, e, n, np.asarray(truth.env_class)[i].astype(int)


def _pool(walks, uere=None):
    """Concatenated per-fix columns over walks: quality, class, e, n, σ_cn0, σ_table, σ_fitted, ζ."""
    from features.gnss.positions import UERE_BY_QUALITY_M

    cols = {k: [] for k in ("q", "cls", "e", "n", "s_cn0", "s_table", "s_fit", "zeta")}
    for pos, truth in walks:
        inside, e, n, cls = _errors(pos, truth)
        table = np.array([UERE_BY_QUALITY_M[q] for q in pos.quality.tolist()]) * pos.hdop / np.sqrt(2.0)
        s_fit = pos.sigma_en_m
        if uere is not None:
            from features.gnss.positions import fixes_to_enu  # noqa: F401 (same rule as fixes_to_enu)

            fitted = np.array([np.nan if v is None else v for v in
                               (uere.lookup(q, a) for q, a in zip(pos.quality.tolist(), pos.attenuation_db.tolist()))])
            s_fit = np.where(np.isfinite(fitted), fitted * pos.hdop / np.sqrt(2.0), pos.sigma_en_m)
        for k, v in (("q", pos.quality), ("cls", cls), ("e", e), ("n", n), ("s_cn0", pos.sigma_en_m),
                     ("s_table", table), ("s_fit", s_fit), ("zeta", np.nan_to_num(pos.invisible_ratio))):
            cols[k].append(np.asarray(v)[inside])
    return {k: np.concatenate(v) for k, v in cols.items()}


def fit_zeta_scale(p: dict, sigma_key: str) -> dict:
    """c_q per quality (not RTK fixed) maximising the Gaussian likelihood of the errors under
    σ² = σ_model²·(1 + c·ζ): minimise Σ log σ² + |e|²/σ² over a grid of c ≥ 0."""
    out = {}
    r = p["e"] ** 2 + p["n"] ** 2
    for q in np.unique(p["q"]).tolist():
        if q == 4:
            continue
        m = p["q"] == q
        if m.sum() < 20:
            continue
        s2 = p[sigma_key][m] ** 2
        nll = [np.sum(2 * np.log(s2 * (1 + c * p["zeta"][m])) + r[m] / (s2 * (1 + c * p["zeta"][m]))) for c in C_GRID]
        out[q] = float(C_GRID[int(np.argmin(nll))])
    return out


def fit_zeta_scale_cells(p: dict, sigma_key: str) -> dict:
    """c_q per quality (not RTK fixed) chosen on the training walks by the reported criterion
    itself: the mean |ln(NEES/2)| over that quality's classes with at least 30 fixes."""
    out = {}
    r = p["e"] ** 2 + p["n"] ** 2
    for q in np.unique(p["q"]).tolist():
        if q == 4:
            continue
        cells = [(p["q"] == q) & (p["cls"] == k) for k in range(3)]
        cells = [m for m in cells if m.sum() >= 30]
        if not cells:
            continue
        cost = [np.mean([abs(np.log(np.mean(r[m] / (p[sigma_key][m] ** 2 * (1 + c * p["zeta"][m]))) / 2))
                         for m in cells]) for c in C_GRID]
        out[q] = float(C_GRID[int(np.argmin(cost))])
    return out


def nees_table(p: dict, sigma: np.ndarray) -> dict:
    """{(quality, class): (n, mean NEES)}."""
    from features.site import ENV_CLASSES

    nees = (p["e"] ** 2 + p["n"] ** 2) / sigma ** 2
    out = {}
    for q in QUALITY_NAMES:
        for k, name in enumerate(ENV_CLASSES):
            m = (p["q"] == q) & (p["cls"] == k)
            if m.sum():
                out[(q, name)] = (int(m.sum()), float(np.mean(nees[m])))
    return out


def main(argv=None) -> int:
    from features.gnss.positions import fit_uere

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", nargs="+", type=Path, required=True, help="walks to fit on (truth.csv)")
    ap.add_argument("--test", nargs="+", type=Path, required=True, help="held-out walks to report on")
    args = ap.parse_args(argv)
    train = [walk_fixes(w) for w in args.train]
    test = [walk_fixes(w) for w in args.test]
    uere = fit_uere([p for p, _ in train], [(t.t_s, t.east_m, t.north_m) for _, t in train])
    ptr, pte = _pool(train, uere), _pool(test, uere)
    c_cn0 = fit_zeta_scale(ptr, "s_cn0")
    c_fit = fit_zeta_scale(ptr, "s_fit")
    k_cn0 = fit_zeta_scale_cells(ptr, "s_cn0")
    print(f"fitted on {len(train)} walks ({ptr['q'].size} fixes), reported on {len(test)} held-out walks "
          f"({pte['q'].size} fixes)")
    print("c_q (variance × (1 + c_q·ζ)), maximum likelihood: cn0 model", c_cn0, " fitted table", c_fit,
          "; by the cell criterion: cn0 model", k_cn0)

    def scaled(p, key, c):
        f = np.array([1.0 + c.get(q, 0.0) * z for q, z in zip(p["q"].tolist(), p["zeta"].tolist())])
        return p[key] * np.sqrt(f)

    models = {"table": pte["s_table"], "cn0": pte["s_cn0"], "cn0+zeta": scaled(pte, "s_cn0", c_cn0),
              "cn0+zeta(c)": scaled(pte, "s_cn0", k_cn0),
              "fitted": pte["s_fit"], "fitted+zeta": scaled(pte, "s_fit", c_fit)}
    tables = {k: nees_table(pte, v) for k, v in models.items()}
    keys = sorted(set().union(*tables.values()), key=lambda k: (list(QUALITY_NAMES).index(k[0]), k[1]))
    print(f"{'quality / class':22s} {'n':>6s} " + " ".join(f"{m:>11s}" for m in models))
    for key in keys:
        n = next(t[key][0] for t in tables.values() if key in t)
        vals = " ".join(f"{tables[m].get(key, (0, np.nan))[1]:11.2f}" for m in models)
        print(f"{QUALITY_NAMES[key[0]] + ' ' + key[1]:22s} {n:6d} {vals}")
    # one summary: mean |log(NEES / 2)| over the cells with at least 30 fixes (0 = every cell consistent)
    for m, t in tables.items():
        cells = [v for v in t.values() if v[0] >= 30]
        print(f"  {m:12s} mean |ln(NEES/2)| over {len(cells)} cells of >= 30 fixes: "
              f"{np.mean([abs(np.log(v[1] / 2)) for v in cells]):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
