"""GNSS figures of the simulator's calibration report (``bench/calibrate_sim.py``), per environment class.

:func:`gnss_walk_figures` simulates GNSS-only walks (default routes, so the time share per class is the default
walks') on the given sites and reads every walk back as a receiver log is read (NMEA with GST → epochs →
``fixes_to_enu`` → features), then pools per class:

- C/N0 of LOS and NLOS satellites (tracked, above 10°), by the simulator's NLOS flag (a reflection dominates) and
  by geometry (a solid structure in the direct path, diffracted or reflected: the labelling of a 3-D city model
  such as smartLoc's), beside smartLoc's labelled sample (:mod:`bench.smartloc`);
- the NLOS share among tracked and among used satellites;
- per-satellite pseudorange residual (error after differential corrections minus the epoch's median of its
  system, as the Berlin figure is computed) by C/N0 bin, beside the Berlin drive's;
- RTK: quality-4 share, share of quality-4 epochs more than 0.2 m wrong, time to first fix and to re-fix;
- GST NEES per quality and class (error²/σ² of east and north, σ from the GST read back; 2 is consistent);
- error autocorrelation, pooled (issue 21 item 5) and per visit (the earlier figure);
- time share per class; RMC speed error; the five GNSS features; attenuation of every in-view satellite.
"""

from __future__ import annotations

import tempfile
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from simulation.gnss.nmea_writer import format_nmea
from simulation.gnss.stream import simulate_gnss, to_nmea_epochs
from simulation.rng import stream_rng
from simulation.site.environment import blocked_share, classify_share
from simulation.site.layout import generate_site
from simulation.site.route import RouteConfig, plan_route, route_trajectory

CN0_EDGES = (30.0, 35.0, 40.0, 45.0)
QUALITIES = (2, 4, 5)


def classes(site, east, north) -> np.ndarray:
    return classify_share(blocked_share(site, east, north, n_az=90)).astype(int)


def walk_traj(site, seed, duration_s, start, route: RouteConfig = RouteConfig()):
    poly, stops, speed = plan_route(site, stream_rng(seed, "route"), duration_s, route)
    return route_trajectory(poly, stops, speed, duration_s, start, site.device_height_m, route)


def _read_back(sim, site, seed, traj):
    """The walk's NMEA (with GST) read as a receiver log: (epochs on the walk's time base, positions, features)."""
    from features.gnss.features import gnss_features, sky_arrays
    from features.gnss.nmea import epochs_on_time_base, read_nmea
    from features.gnss.positions import fixes_to_enu

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "g.nmea"
        p.write_text(format_nmea(to_nmea_epochs(sim, site, seed, traj, gst=True)))
        epochs, _ = read_nmea(p)
    epochs = epochs_on_time_base(epochs, traj.start_utc)
    sky = sky_arrays(epochs)
    o = site.origin
    return fixes_to_enu(epochs, o.lat_deg, o.lon_deg, o.alt_m, sky=sky), gnss_features(sky)


def refix_times_s(t_s, quality, cls=None):
    """Seconds from each loss of RTK fixed (4 → other) to the next fixed epoch; with ``cls``, a dict per class of
    the epoch where the fix was lost."""
    q4 = np.asarray(quality) == 4
    out = []
    i, n = 1, len(q4)
    while i < n:
        if q4[i - 1] and not q4[i]:
            j = i
            while j < n and not q4[j]:
                j += 1
            if j < n:
                out.append((t_s[j] - t_s[i - 1], i))
            i = j
        i += 1
    if cls is None:
        return np.asarray([d for d, _ in out], float)
    return {c: np.asarray([d for d, i0 in out if cls[i0] == c], float) for c in range(3)}


def _sat_residuals(sim) -> tuple[np.ndarray, np.ndarray]:
    """Per used satellite: pseudorange error minus the median of its system at that epoch, and its C/N0."""
    res, cn0 = [], []
    for s in np.unique(sim.system):
        cols = sim.system == s
        e = np.where(sim.used[:, cols], sim.code_error_m[:, cols], np.nan)
        n_used = np.isfinite(e).sum(axis=1)
        with np.errstate(all="ignore"):
            med = np.nanmedian(np.where(n_used[:, None] >= 2, e, np.nan), axis=1)
        r = e - med[:, None]
        ok = np.isfinite(r)
        res.append(r[ok])
        cn0.append(sim.cn0_reported_dbhz[:, cols][ok])
    return np.concatenate(res), np.concatenate(cn0)


def _new_acc():
    keys = ("fixed", "wrong", "herr", "refix", "feats", "speed_err", "att_all", "los", "nlos", "clear", "blocked",
            "share", "nees", "time", "ac", "ac_visit", "res", "first_fix")
    return {k: {c: [] for c in range(3)} for k in keys}


def gnss_walk_figures(site_seeds, walk_seeds, duration_s: float, lags_s=(1.0, 5.0, 20.0, 60.0)) -> dict:
    """GNSS walk figures pooled over sites × walks (module docstring)."""
    from bench.calibrate_sim import autocorr_sums

    acc = _new_acc()
    ac = {c: np.zeros((len(lags_s), 4)) for c in range(3)}
    ac_visit = {c: np.zeros((len(lags_s), 4)) for c in range(3)}
    refix_all, first_fix, series = [], [], []
    res_all, cn0_all = [], []
    for s in site_seeds:
        site = generate_site(s)
        for w in walk_seeds:
            seed = 1000 * s + w
            start = datetime(2026, 6, 1, tzinfo=timezone.utc) + timedelta(hours=(3 * s + 7 * w) % 24)
            traj = walk_traj(site, seed, duration_s, start)
            sim = simulate_gnss(site, traj, seed=seed)
            cls = classes(site, sim.truth_enu_m[:, 0], sim.truth_enu_m[:, 1])
            e = sim.fix_enu_m[:, :2] - sim.truth_enu_m[:, :2]
            h = np.hypot(e[:, 0], e[:, 1])
            for c, rows in autocorr_sums(sim.t_s, e, cls, lags_s).items():
                ac[c] += rows
            for c, rows in autocorr_sums(sim.t_s, e, cls, lags_s, per_visit=True).items():
                ac_visit[c] += rows
            series.append((sim.t_s, e, cls))
            refix_all.append(refix_times_s(sim.t_s, sim.quality))
            q4 = sim.quality == 4
            first_fix.append(sim.t_s[np.argmax(q4)] if q4.any() else np.nan)
            for c, v in refix_times_s(sim.t_s, sim.quality, cls).items():
                acc["refix"][c].append(v)
            _per_class_sky(acc, sim, cls)
            r, cn = _sat_residuals(sim)
            res_all.append(r)
            cn0_all.append(cn)
            pos, f = _read_back(sim, site, seed, traj)
            _per_class_fixes(acc, sim, cls, h, pos, traj)
            _speed_errors(acc, sim, site, seed, traj, cls)
            fc = classes(site, np.interp(f["t_s"], sim.t_s, sim.truth_enu_m[:, 0]),
                         np.interp(f["t_s"], sim.t_s, sim.truth_enu_m[:, 1]))
            for c in range(3):
                if (fc == c).any():
                    acc["feats"][c].append(np.column_stack([f[k][fc == c] for k in (
                        "att_mean_db", "att_std_db", "invisible_ratio", "dop_growth", "fluct_per_s")]))
    return _summarise(acc, ac, ac_visit, refix_all, first_fix, series, np.concatenate(res_all),
                      np.concatenate(cn0_all))


def _per_class_sky(acc, sim, cls):
    view = sim.tracked & (sim.el_rad > np.radians(10))
    above = sim.in_view & (sim.el_rad > np.radians(10))
    used = sim.used
    for c in range(3):
        m = (cls == c)[:, None]
        acc["time"][c].append(int((cls == c).sum()))
        if not m.any():
            continue
        acc["att_all"][c].append(sim.attenuation_db[m & above])
        acc["los"][c].append(sim.cn0_reported_dbhz[m & view & sim.los])
        acc["nlos"][c].append(sim.cn0_reported_dbhz[m & view & sim.nlos])
        acc["clear"][c].append(sim.cn0_reported_dbhz[m & view & ~sim.blocked])
        acc["blocked"][c].append(sim.cn0_reported_dbhz[m & view & sim.blocked])
        acc["share"][c].append(((m & view & sim.nlos).sum(), (m & view).sum(), (m & used & sim.nlos).sum(),
                                (m & used).sum()))


def _per_class_fixes(acc, sim, cls, h, pos, traj):
    for c in range(3):
        m = cls == c
        if m.sum() >= 50:
            acc["fixed"][c].append((int((sim.quality[m] == 4).sum()), int(m.sum())))
            q4 = m & (sim.quality == 4)
            acc["wrong"][c].append((int(q4.sum()), int(np.sum(q4 & (h > 0.2)))))
            acc["herr"][c].append(h[m & np.isfinite(h)])
    # GST NEES of the fixes read back (σ from the GST sentences, matched to the epoch's truth)
    te = np.interp(pos.t_s, sim.t_s, sim.truth_enu_m[:, 0])
    tn = np.interp(pos.t_s, sim.t_s, sim.truth_enu_m[:, 1])
    pc = cls[np.clip(np.searchsorted(sim.t_s, pos.t_s - 1e-6), 0, len(cls) - 1)]
    gst = pos.sigma_source == "gst"
    nees = ((pos.east_m - te) / pos.sigma_east_m) ** 2 + ((pos.north_m - tn) / pos.sigma_north_m) ** 2
    for c in range(3):
        for q in QUALITIES:
            sel = gst & (pc == c) & (pos.quality == q)
            if sel.any():
                acc["nees"][c].append((q, nees[sel]))


def _speed_errors(acc, sim, site, seed, traj, cls):
    """|RMC speed − true speed| per class (the Doppler solution's error, :mod:`simulation.gnss.velocity`)."""
    ne = to_nmea_epochs(sim, site, seed, traj)
    v_true = np.interp(sim.t_s, traj.t_s, traj.speed_m_s)
    for c in range(3):
        m = (cls == c) & np.isfinite(ne.speed_m_s)
        acc["speed_err"][c].append(np.abs(ne.speed_m_s[m] - v_true[m]))


def _mean_sd(parts):
    v = np.concatenate(parts) if parts else np.zeros(0)
    return (float(v.mean()), float(v.std()), int(v.size)) if v.size else (np.nan, np.nan, 0)


def _summarise(acc, ac, ac_visit, refix_all, first_fix, series, res, cn0) -> dict:
    from bench.calibrate_sim import autocorr_from_sums
    from bench.smartloc import residual_by_cn0

    out = {"autocorr": {}, "autocorr_pairs": {}, "autocorr_visit": {}, "fixed": {}, "wrong": {}, "n_q4": {},
           "herr_med": {}, "herr_p95": {}, "features": {}, "cn0": {}, "nlos_share": {}, "nees": {}, "time_share": {},
           "refix_by_class": {}}
    total_t = sum(sum(v) for v in acc["time"].values())
    for c in range(3):
        out["time_share"][c] = sum(acc["time"][c]) / max(total_t, 1)
        out["autocorr"][c] = autocorr_from_sums(ac[c])
        out["autocorr_pairs"][c] = ac[c][:, 3].astype(int).tolist()
        out["autocorr_visit"][c] = autocorr_from_sums(ac_visit[c])
        out["cn0"][c] = {k: _mean_sd(acc[k][c]) for k in ("los", "nlos", "clear", "blocked")}
        sh = np.sum(acc["share"][c], axis=0) if acc["share"][c] else np.zeros(4)
        out["nlos_share"][c] = (sh[0] / max(sh[1], 1), sh[2] / max(sh[3], 1))
        out["nees"][c] = {}
        for q in QUALITIES:
            v = [x for qq, x in acc["nees"][c] if qq == q]
            if v:
                v = np.concatenate(v)
                out["nees"][c][q] = (int(v.size), float(np.mean(v)), float(np.median(v)))
        v = np.concatenate(acc["refix"][c]) if acc["refix"][c] else np.zeros(0)
        out["refix_by_class"][c] = (int(v.size), float(np.median(v)) if v.size else np.nan,
                                    float(np.percentile(v, 90)) if v.size else np.nan)
        if not acc["fixed"][c]:
            continue
        n4 = sum(a for a, _ in acc["fixed"][c])
        out["fixed"][c] = n4 / max(sum(b for _, b in acc["fixed"][c]), 1)
        out["n_q4"][c] = sum(a for a, _ in acc["wrong"][c])
        out["wrong"][c] = sum(b for _, b in acc["wrong"][c]) / max(out["n_q4"][c], 1)
        allh = np.concatenate(acc["herr"][c])
        out["herr_med"][c] = float(np.median(allh))
        out["herr_p95"][c] = float(np.percentile(allh, 95))
        if acc["feats"][c]:
            out["features"][c] = np.nanmedian(np.vstack(acc["feats"][c]), axis=0).tolist()
        se = np.concatenate(acc["speed_err"][c])
        out.setdefault("speed_err_med", {})[c] = float(np.median(se)) if se.size else np.nan
        out.setdefault("speed_err_p95", {})[c] = float(np.percentile(se, 95)) if se.size else np.nan
    out["att_all_mean"] = {c: float(np.mean(np.concatenate(v))) for c, v in acc["att_all"].items() if v}
    out["cn0_all"] = {k: _mean_sd([x for c in range(3) for x in acc[k][c]]) for k in ("los", "nlos", "clear",
                                                                                       "blocked")}
    r = np.concatenate(refix_all) if refix_all else np.zeros(0)
    out["refix_median_s"] = float(np.median(r)) if r.size else np.nan
    out["refix_p90_s"] = float(np.percentile(r, 90)) if r.size else np.nan
    out["n_refix"] = int(r.size)
    out["first_fix_s"] = (float(np.nanmedian(first_fix)), float(np.nanmax(first_fix)))
    out["residual_by_cn0"] = residual_by_cn0(res, cn0, CN0_EDGES)
    out["series"] = series
    return out
