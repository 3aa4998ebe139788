"""Fusing one walk with every method, on one code path, and scoring the tracks against truth.

:func:`walk_inputs` turns a walk read by :func:`pipeline.walk_data.read_walk`
into what the filters take: one event stream (PDR steps, GNSS fixes with
their reported σ, quality and HDOP, acoustic fixes with their covariance,
standing intervals from the gaps between steps) and the environment
classifier's evidence over time. The classifier answers on each 2 s feature
window only once the window is complete (its end time), so the filter never
uses a class from the future.

:func:`run_methods` runs the methods of issue 14 on those inputs:

==================  ==========================================================
``gnss``            the GGA fixes alone
``acoustic``        the acoustic fixes alone
``pdr``             dead reckoning from the first GNSS fix (steps × length × heading)
``kf``              event-driven EKF, one fitted R per source (the paper's method 2)
``kf_quality``      R from what the devices report (UERE per quality refit on training walks,
                    GST, the acoustic covariance scaled); χ² gate
``kf_map``          R per class, class looked up in the site's map at the last estimate (method 1)
``aekf``            variational-Bayes adaptive R, no classifier (Särkkä & Nummenmaa 2009)
``imm``             one mode per class, the classifier's probabilities as mode evidence
``adaptive_nobp``   R per class and GGA quality, the class from the online classifier
``adaptive``        adaptive_nobp + the guarded BP correction added to the output
``adaptive_closed`` the same correction fed back into the filter state after each update
``<filter>+rts``    the RTS-smoothed track of each filter method
==================  ==========================================================

:func:`score` gives per method and class (by the truth class at each epoch)
the horizontal error mean, median, p95, max and the share of epochs whose
NEES lies inside the two-sided 95 % χ²₂ region.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from features.schema import ACOUSTIC_FEATURES, ENV_CLASSES, FEATURES, GNSS_FEATURES
from models.bp import bp_inputs
from models.fusion import (AcousticEvents, ClassTrack, EventEKF, GnssEvents, IMMFilter, StandIntervals, StepEvents,
                           VBAdaptiveNoise, merge_events, rts_smooth)
from models.fusion.consistency import chi2_bounds
from models.fusion.events import EventStream
from models.fusion_model import FusionModel
from pipeline.walk_data import WalkData

__all__ = ["METHODS", "FILTER_METHODS", "WalkInputs", "Track", "walk_inputs", "window_features", "run_methods",
           "score", "track_errors", "metric_rows", "METRIC_COLUMNS", "STAND_GAP_S", "split_steps", "adaptive_noise", "bp_features"]

METHODS = ("gnss", "acoustic", "pdr", "kf", "kf_quality", "kf_map", "aekf", "imm", "adaptive_nobp", "adaptive",
           "adaptive_closed")
"""Every method, in report order (``+rts`` variants follow their filter)."""

FILTER_METHODS = ("kf", "kf_quality", "kf_map", "aekf", "imm", "adaptive_nobp")
"""Methods that run the event-driven filter (and so have an RTS-smoothed variant)."""

STAND_GAP_S = 1.5
"""A gap between steps longer than this is standing (from 0.5 s after the last step to 0.5 s before the next)."""

WINDOW_S = 2.0
"""Feature window length, s (the readers' default): a window centred at t is complete at t + 1 s."""

METRIC_COLUMNS = ("walk", "method", "env_class", "n", "mean_m", "median_m", "p95_m", "max_m", "nees_in_bounds")


@dataclass(frozen=True)
class WalkInputs:
    """A walk ready for the filters: ``events``; the classifier's evidence ``classes`` at window ends
    ``window_t_s`` (n,), with the window features ``window_X`` (n, 14) and ``window_ood`` (n,)."""

    data: WalkData
    events: EventStream
    window_t_s: np.ndarray
    window_X: np.ndarray
    classes: ClassTrack
    window_ood: np.ndarray


@dataclass
class Track:
    """One method's output: positions at ``t_s`` (m,), covariance ``cov_m2`` (m, 2, 2) or None, and per-epoch
    extras in ``info`` (``nis``, ``bp_delta_m``, ``class_proba``, ...)."""

    method: str
    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    cov_m2: np.ndarray | None
    info: dict = field(default_factory=dict)


def window_features(data: WalkData) -> tuple[np.ndarray, np.ndarray]:
    """The 14 features per window on one grid: (window end times (n,), X (n, 14)); NaN where missing.

    GNSS and acoustic windows are joined by their centre time (both hop 1 s on the walk's time base);
    a window one source lacks keeps NaN for its features.
    """
    rows: dict[float, np.ndarray] = {}

    def row(t):
        key = round(float(t), 1)
        if key not in rows:
            rows[key] = np.full(len(FEATURES), np.nan)
        return rows[key]

    if data.gnss is not None:
        f = data.gnss.features
        for i, t in enumerate(np.asarray(f["t_s"], float)):
            r = row(t)
            r[: len(GNSS_FEATURES)] = [f[name][i] for name in GNSS_FEATURES]
    if data.acoustic is not None:
        for rec in data.acoustic.feature_rows:
            if rec.get("acoustic_available"):
                row(rec["t_s"])[len(GNSS_FEATURES):] = [rec[name] for name in ACOUSTIC_FEATURES]
    if not rows:
        return np.zeros(0), np.zeros((0, len(FEATURES)))
    keys = sorted(rows)
    return np.array(keys) + WINDOW_S / 2.0, np.vstack([rows[k] for k in keys])


TYPICAL_STEP_S = 0.55
"""Duration given to a step that follows a stop (no previous step within :data:`STAND_GAP_S`), s."""


def split_steps(t_s: np.ndarray, length_m: np.ndarray, heading_rad: np.ndarray,
                fix_t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each step spread over the time it took, cut at the fixes that fall inside it.

    A step is detected at its heel strike, but the walker covered it during the
    preceding step period, while GNSS (5 Hz) kept measuring. Predicting the
    whole step at the heel strike would hold the state still between steps and
    then jump a full step past fixes that already saw the motion. So step k
    (from the previous heel strike, or :data:`TYPICAL_STEP_S` before it after a
    stop, to ``t_k``) becomes sub-steps ending at each fix time inside it and at
    ``t_k``, of lengths proportional to their durations, same heading. The cost
    is a fixed lag of one step (≤ ~0.6 s): a fix is fused once the step it falls
    in has ended.

    Returns (t_s, step_length_m, heading_rad) of the sub-steps, in time order.
    """
    t_s, length_m, heading_rad = (np.asarray(a, float) for a in (t_s, length_m, heading_rad))
    if t_s.size == 0:
        return t_s, length_m, heading_rad
    fix = np.sort(np.asarray(fix_t_s, float))
    prev = np.concatenate([[-np.inf], t_s[:-1]])
    start = np.where(t_s - prev > STAND_GAP_S, t_s - TYPICAL_STEP_S, prev)
    lo = np.searchsorted(fix, start, side="right")
    hi = np.searchsorted(fix, t_s, side="left")
    out_t, out_l, out_h = [], [], []
    for k in range(t_s.size):
        cuts = fix[lo[k]:hi[k]]
        bounds = np.concatenate([[start[k]], cuts, [t_s[k]]])
        frac = np.diff(bounds) / (t_s[k] - start[k])
        out_t.append(bounds[1:])
        out_l.append(length_m[k] * frac)
        out_h.append(np.full(frac.size, heading_rad[k]))
    return np.concatenate(out_t), np.concatenate(out_l), np.concatenate(out_h)


def _stands(step_t: np.ndarray) -> StandIntervals:
    if step_t.size < 2:
        return StandIntervals(np.zeros(0), np.zeros(0))
    gaps = np.flatnonzero(np.diff(step_t) > STAND_GAP_S)
    return StandIntervals(step_t[gaps] + 0.5, step_t[gaps + 1] - 0.5)


def walk_inputs(data: WalkData, model: FusionModel) -> WalkInputs:
    """Events and class evidence of one walk (see the module docstring)."""
    steps = gnss = acoustic = stands = None
    fix_t = np.concatenate([data.gnss.positions.t_s if data.gnss is not None else np.zeros(0),
                            data.acoustic.t_s if data.acoustic is not None else np.zeros(0)])
    if data.pdr is not None and len(data.pdr.result):
        r = data.pdr.result
        ok = np.isfinite(r.heading_rad) & np.isfinite(r.step_length_m)
        stands = _stands(r.t_s[ok])
        steps = StepEvents(*split_steps(r.t_s[ok], r.step_length_m[ok], r.heading_rad[ok], fix_t))
    if data.gnss is not None and len(data.gnss.positions):
        p = data.gnss.positions
        gnss = GnssEvents.from_sigma(p.t_s, p.east_m, p.north_m, p.sigma_en_m, quality=p.quality,
                                     hdop=np.where(p.hdop_assumed, np.nan, p.hdop))
    if data.acoustic is not None and len(data.acoustic.t_s):
        a = data.acoustic
        acoustic = AcousticEvents(a.t_s, a.east_m, a.north_m, a.covariance_en_m2)
    events = merge_events(steps=steps, gnss=gnss, acoustic=acoustic, stands=stands)
    t_end, X = window_features(data)
    if len(t_end):
        proba = model.classifier.predict_proba(X)
        ood = model.classifier.is_ood(X)
    else:
        proba, ood = np.tile(model.classifier.prior_, (1, 1)), np.ones(1, bool)
        t_end = np.array([events.t_s[0]])
    # Before the first complete window the filter knows nothing of the environment: the prior.
    t_cls = np.concatenate([[min(events.t_s[0], t_end[0]) - 1.0], t_end])
    proba = np.vstack([model.classifier.prior_, proba])
    return WalkInputs(data=data, events=events, window_t_s=t_end, window_X=X,
                      classes=ClassTrack(t_cls, proba), window_ood=ood)


def _map_lookup(data: WalkData):
    """Class at (east, north) from the site's layout map (the paper's method 1), or None without a layout."""
    if not data.site.layout:
        return None
    east, north, cls = _site_class_grid(data.site)
    e0, n0 = float(east[0]), float(north[0])
    de = float(east[1] - east[0]) if len(east) > 1 else 1.0
    dn = float(north[1] - north[0]) if len(north) > 1 else 1.0
    ni, nj = cls.shape

    def at(e: float, n: float) -> int:
        i = min(max(int(round((n - n0) / dn)), 0), ni - 1)
        j = min(max(int(round((e - e0) / de)), 0), nj - 1)
        return int(cls[i, j])

    return at


@functools.lru_cache(maxsize=8)
def _site_class_grid(site):
    """The site's class map on a 2 m grid (~0.2 s), once per site and process: every walk of a site shares it."""
    from simulation.site.environment import class_map, classify_share   # the map baseline reads the drawing

    east, north, share = class_map(site, resolution_m=2.0)
    return east, north, classify_share(share)              # inside a structure (NaN share): heavy


def adaptive_noise(model: FusionModel):
    """The adaptive methods' noise policy: R per class and GGA quality when the model has it, else per class."""
    return model.class_quality if model.class_quality is not None else model.per_class


def _filter_track(run, method: str, inputs: WalkInputs) -> Track:
    return Track(method, run.t_s, run.x[:, 0].copy(), run.x[:, 1].copy(), run.P[:, :2, :2].copy(),
                 {"nis": run.nis, "class_proba": inputs.classes.at(run.t_s), "run": run})


def run_methods(model: FusionModel, inputs: WalkInputs, methods=METHODS, smooth: bool = True) -> tuple[dict, dict]:
    """Run ``methods`` on one walk: ({name: Track}, {name: reason}) for the tracks and the methods skipped."""
    data, ev = inputs.data, inputs.events
    tracks, skipped = {}, {}
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise ValueError(f"unknown methods {unknown}; choose from {list(METHODS)}")
    want = list(methods)
    has_fix = bool(np.any(ev.available))
    if "gnss" in want:
        if data.gnss is not None and len(data.gnss.positions):
            p = data.gnss.positions
            tracks["gnss"] = Track("gnss", p.t_s, p.east_m, p.north_m,
                                   np.eye(2)[None] * (p.sigma_en_m ** 2)[:, None, None])
        else:
            skipped["gnss"] = "no GNSS fixes"
    if "acoustic" in want:
        if data.acoustic is not None and len(data.acoustic.t_s):
            a = data.acoustic
            tracks["acoustic"] = Track("acoustic", a.t_s, a.east_m, a.north_m, a.covariance_en_m2)
        else:
            skipped["acoustic"] = "no acoustic fixes"
    if "pdr" in want:
        if data.pdr is not None and len(data.pdr.result) and has_fix:
            from features.imu.pdr import dead_reckon

            r = data.pdr.result
            start = ev.z_m[np.flatnonzero(ev.available)[0]]
            e, n = dead_reckon(r.step_length_m, r.heading_rad, float(start[0]), float(start[1]))
            tracks["pdr"] = Track("pdr", r.t_s, e, n, None)
        else:
            skipped["pdr"] = "no steps" if data.pdr is None or not len(data.pdr.result) else "no fix to start from"
    if not has_fix:
        for m in want:
            if m in FILTER_METHODS + ("adaptive",):
                skipped[m] = "no GNSS or acoustic fix to start the filter from"
        return tracks, skipped
    cfg = model.ekf
    runs = {}
    for m in want:
        if m == "kf":
            runs[m] = EventEKF(cfg, model.fixed, "kf").run(ev)
        elif m == "kf_quality":
            runs[m] = EventEKF(cfg, model.quality, "kf_quality").run(ev)
        elif m == "kf_map":
            lookup = _map_lookup(data)
            if lookup is None:
                skipped[m] = "the site has no map (no layout in site.toml)"
                continue
            runs[m] = EventEKF(cfg, model.per_class_map, "kf_map").run(ev, class_at=lookup)
        elif m == "aekf":
            rg, ra = model.fixed.R_gnss_, model.fixed.R_acoustic_
            vb = VBAdaptiveNoise(gnss_sigma_m=float(np.sqrt(np.trace(rg) / 2)),
                                 acoustic_sigma_m=float(np.sqrt(np.trace(ra) / 2)))
            runs[m] = EventEKF(cfg, vb, "aekf").run(ev)
        elif m == "imm":
            runs[m] = IMMFilter(model.per_class, cfg).run(ev, classes=inputs.classes)
        elif m in ("adaptive_nobp", "adaptive") and "adaptive_nobp" not in runs:
            runs["adaptive_nobp"] = EventEKF(cfg, adaptive_noise(model), "adaptive_nobp").run(ev, classes=inputs.classes)
    for m, run in runs.items():
        if m in want:
            tracks[m] = _filter_track(run, m, inputs)
            if smooth:
                s = rts_smooth(run)
                tracks[m + "+rts"] = Track(m + "+rts", s.t_s, s.x[:, 0].copy(), s.x[:, 1].copy(),
                                           s.P[:, :2, :2].copy())
    if "adaptive" in want:
        if model.bp is None:
            skipped["adaptive"] = "the model has no BP network (trained with --no-bp)"
        else:
            tracks["adaptive"] = _with_bp(model, inputs, runs["adaptive_nobp"])
    if "adaptive_closed" in want:
        if model.bp is None:
            skipped["adaptive_closed"] = "the model has no BP network (trained with --no-bp)"
        else:
            tracks["adaptive_closed"] = _closed_loop(model, inputs)
    return tracks, skipped


def bp_features(run, inputs: WalkInputs) -> np.ndarray:
    """The BP network's input rows for every event of a filter run."""
    return bp_inputs(run.t_s, run.kind, run.updated, run.accepted, run.K, run.nu, run.dx, run.nis,
                     inputs.classes.at(run.t_s))


def _with_bp(model: FusionModel, inputs: WalkInputs, run) -> Track:
    X = bp_features(run, inputs)
    corr = model.bp.correct(X, run.x_prior[:, :2], inputs.events.z_m, run.S, run.updated)
    east = run.x[:, 0] + corr.delta_m[:, 0]
    north = run.x[:, 1] + corr.delta_m[:, 1]
    cov = run.P[:, :2, :2] + np.eye(2)[None] * np.where(np.any(corr.delta_m != 0, axis=1), corr.var_m2.sum(1) / 2,
                                                         0.0)[:, None, None]
    return Track("adaptive", run.t_s, east, north, cov,
                 {"nis": run.nis, "class_proba": inputs.classes.at(run.t_s), "bp_delta_m": corr.delta_m,
                  "bp_disabled_share": corr.disabled_share, "run": run})


def _closed_loop(model: FusionModel, inputs: WalkInputs) -> Track:
    """adaptive_closed: after every accepted update the guarded BP correction is added to the state.

    Guards as in :class:`models.bp.BPCorrector`: no correction out of distribution or below its own σ;
    and while the mean NIS of the last ``guard_window`` updates lies above the 99 % point of its χ²
    law (2·window degrees of freedom, over window) the correction is off — the filter fed with it has
    stopped agreeing with its measurements.
    """
    from scipy.special import chdtri

    from models.bp import GNSS_KIND, ACOUSTIC_KIND

    ev, bp = inputs.events, model.bp
    window = bp.config.guard_window
    limit = float(chdtri(2 * window, 0.01) / window)       # chi2.ppf(0.99, 2·window) / window
    proba = inputs.classes.at(ev.t_s)
    # Whether a fix of each source was available in the 2 s up to each event (causal).
    recent = {}
    for code in (GNSS_KIND, ACOUSTIC_KIND):
        tk = ev.t_s[ev.available & (ev.kind == code)]
        idx = np.searchsorted(tk, ev.t_s, side="right") - 1
        prev = np.where(idx >= 0, tk[np.maximum(idx, 0)] if tk.size else 0.0, -np.inf)
        recent[code] = (ev.t_s - prev) <= 2.0
    nis_hist: list = []
    state = {"off": 0, "withheld": 0, "calls": 0}

    def correct(k, x_prior, x, P, nu, S, K):
        state["calls"] += 1
        nis = float(nu @ np.linalg.solve(S, nu))
        nis_hist.append(nis)
        if len(nis_hist) > window:
            nis_hist.pop(0)
        row = np.zeros((1, len(bp.x_mean_)))
        row[0, :3] = proba[k]
        row[0, 3:7] = K[:2, :].reshape(-1)
        row[0, 7:9] = nu
        row[0, 9:11] = (x - x_prior)[:2]
        row[0, 11] = np.log1p(nis)
        row[0, 12] = ev.kind[k] == GNSS_KIND
        row[0, 13] = ev.kind[k] == ACOUSTIC_KIND
        row[0, 14] = 1.0
        row[0, 16] = recent[GNSS_KIND][k]
        row[0, 17] = recent[ACOUSTIC_KIND][k]
        if len(nis_hist) >= window and np.mean(nis_hist) > limit:
            state["off"] += 1
            return None
        mu, var = bp.predict(row)
        if bp.is_ood(row)[0] or float(np.sum(mu ** 2)) < float(np.sum(var)):
            state["withheld"] += 1
            return None
        return mu[0]

    run = EventEKF(model.ekf, adaptive_noise(model), "adaptive_closed").run(ev, classes=inputs.classes,
                                                                            correct=correct)
    calls = max(state["calls"], 1)
    return Track("adaptive_closed", run.t_s, run.x[:, 0].copy(), run.x[:, 1].copy(), run.P[:, :2, :2].copy(),
                 {"nis": run.nis, "class_proba": proba, "bp_delta_m": run.correction,
                  "bp_disabled_share": (state["off"] + state["withheld"]) / calls, "run": run})


def track_errors(tr: Track, truth) -> dict:
    """A track against truth at its epochs inside the truth's span: ``t_s`` (k,), ``e`` (k, 2) east/north
    error, ``err_m`` (k,), ``nees`` (k,) e'P⁻¹e (NaN without a usable covariance), ``cls`` (k,) truth class."""
    ok = np.isfinite(tr.east_m) & (tr.t_s >= truth.t_s[0]) & (tr.t_s <= truth.t_s[-1])
    te, tn = truth.at(tr.t_s[ok])
    e = np.stack([tr.east_m[ok] - te, tr.north_m[ok] - tn], axis=1)
    nees = np.full(len(e), np.nan)
    if tr.cov_m2 is not None:
        c = tr.cov_m2[ok]
        good = np.all(np.isfinite(c), axis=(1, 2)) & (np.linalg.det(c) > 0)
        # ε = e' P⁻¹ e
        nees[good] = np.einsum("ni,nij,nj->n", e[good], np.linalg.inv(c[good]), e[good])
    return {"ok": ok, "t_s": tr.t_s[ok], "e": e, "err_m": np.hypot(e[:, 0], e[:, 1]), "nees": nees,
            "cls": truth.class_at(tr.t_s[ok])}


def metric_rows(err_m: np.ndarray, nees: np.ndarray, cls: np.ndarray, walk: str, method: str) -> list[dict]:
    """Rows of :data:`METRIC_COLUMNS` ('all' first, then each class present) from per-epoch errors, NEES
    and truth classes; ``nees_in_bounds`` is the share inside the two-sided 95 % χ²₂ region."""
    lo, hi = chi2_bounds(2)
    out = []
    for label, sel in [("all", np.ones(len(err_m), bool))] + [(c, cls == k) for k, c in enumerate(ENV_CLASSES)]:
        if not sel.any():
            continue
        v = nees[sel]
        nib = float(np.mean((v >= lo) & (v <= hi))) if np.isfinite(v).any() else float("nan")
        x = err_m[sel]
        out.append({"walk": walk, "method": method, "env_class": label, "n": int(x.size), "mean_m": float(x.mean()),
                    "median_m": float(np.median(x)), "p95_m": float(np.percentile(x, 95)), "max_m": float(x.max()),
                    "nees_in_bounds": nib})
    return out


def score(tracks: dict, data: WalkData, walk_name: str = "") -> list[dict]:
    """Metric rows (:data:`METRIC_COLUMNS`) per method and class ('all' first) against the walk's truth."""
    if data.truth is None:
        return []
    out = []
    for name, tr in tracks.items():
        te = track_errors(tr, data.truth)
        if len(te["err_m"]):
            out += metric_rows(te["err_m"], te["nees"], te["cls"], walk_name, name)
    return out
