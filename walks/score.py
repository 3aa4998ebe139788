"""A track against the walk's truth: per-epoch errors, NEES, and the metric rows every report is made of.

Errors are horizontal (east/north) at the track's own epochs inside the
truth's time span, the truth interpolated to them; the class of an epoch is
the truth's class there (``truth.csv``'s ``env_class``). A metric row is
(:data:`METRIC_COLUMNS`): the count, mean, median, 95th percentile and
maximum of the horizontal error, and the share of epochs whose NEES
e'P⁻¹e lies inside the two-sided 95 % χ²₂ region (Bar-Shalom, Li &
Kirubarajan 2001, §5.4; :func:`models.fusion.consistency.chi2_bounds`).
"""

from __future__ import annotations

import numpy as np

from features.schema import ENV_CLASSES
from models.fusion.consistency import chi2_bounds
from walks.track import latest_per_time

__all__ = ["METRIC_COLUMNS", "track_errors", "errors_at", "metric_rows", "score"]

METRIC_COLUMNS = ("walk", "method", "env_class", "n", "mean_m", "median_m", "p95_m", "max_m", "nees_in_bounds")
"""Columns of a metric row (``metrics.csv``)."""


def track_errors(tr, truth) -> dict:
    """A track (:class:`walks.track.Track`) against truth at its epochs inside the truth's span (the last of each
    instant, :func:`walks.track.latest_per_time`): ``t_s`` (k,),
    ``e`` (k, 2) east/north error, ``err_m`` (k,), ``nees`` (k,) e'P⁻¹e (NaN without a usable covariance),
    ``cls`` (k,) truth class, ``ok`` (m,) which of the track's epochs these are."""
    ok = np.isfinite(tr.east_m) & (tr.t_s >= truth.t_s[0]) & (tr.t_s <= truth.t_s[-1]) & latest_per_time(tr.t_s)
    te, tn = truth.at(tr.t_s[ok])
    return errors_at(tr, ok, te, tn, truth.class_at(tr.t_s[ok]))


def errors_at(tr, ok: np.ndarray, te: np.ndarray, tn: np.ndarray, cls: np.ndarray) -> dict:
    """:func:`track_errors` of the track's epochs ``ok`` (bool, (m,)) given the truth there: east ``te``, north
    ``tn`` and class ``cls`` (k,) each (a long walk's segments keep those for a track smoothed once the walk is
    done, :mod:`pipeline.evaluate_segments`)."""
    e = np.stack([tr.east_m[ok] - te, tr.north_m[ok] - tn], axis=1)
    nees = np.full(len(e), np.nan)
    if tr.cov_m2 is not None:
        c = tr.cov_m2[ok]
        good = np.all(np.isfinite(c), axis=(1, 2)) & (np.linalg.det(c) > 0)
        # ε = e' P⁻¹ e
        nees[good] = np.einsum("ni,nij,nj->n", e[good], np.linalg.inv(c[good]), e[good])
    return {"ok": ok, "t_s": tr.t_s[ok], "e": e, "err_m": np.hypot(e[:, 0], e[:, 1]), "nees": nees, "cls": cls}


def metric_rows(err_m: np.ndarray, nees: np.ndarray, cls: np.ndarray, walk: str, method: str) -> list[dict]:
    """Rows of :data:`METRIC_COLUMNS` ('all' first, then each class present) from per-epoch errors, NEES
    and truth classes; ``nees_in_bounds`` is the share inside the two-sided 95 % χ²₂ region (NaN when no epoch
    has a covariance)."""
    lo, hi = chi2_bounds(2)
    out = []
    for label, sel in [("all", np.ones(len(err_m), bool))] + [(c, cls == k) for k, c in enumerate(ENV_CLASSES)]:
        if not sel.any():
            continue
        v = nees[sel]
        fin = np.isfinite(v)
        nib = float(np.mean((v[fin] >= lo) & (v[fin] <= hi))) if fin.any() else float("nan")
        x = err_m[sel]
        out.append({"walk": walk, "method": method, "env_class": label, "n": int(x.size), "mean_m": float(x.mean()),
                    "median_m": float(np.median(x)), "p95_m": float(np.percentile(x, 95)), "max_m": float(x.max()),
                    "nees_in_bounds": nib})
    return out


def score(tracks: dict, data, walk_name: str = "") -> list[dict]:
    """Metric rows (:data:`METRIC_COLUMNS`) per method and class ('all' first) against the walk's truth
    (:class:`walks.reader.WalkData`); none without ``truth.csv``."""
    if data.truth is None:
        return []
    out = []
    for name, tr in tracks.items():
        te = track_errors(tr, data.truth)
        if len(te["err_m"]):
            out += metric_rows(te["err_m"], te["nees"], te["cls"], walk_name, name)
    return out
