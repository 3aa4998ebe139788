"""Calibration report of the simulator: every Must-show figure per class beside the real figure it is held to.

Simulates walks (GNSS only, fast) and survey captures on site seeds the
simulator was not tuned on (tuning used seeds 1–3; the report uses 21–25 by
default), one full walk (every stream) for the acoustic and demo figures, and
prints per class (open / light / heavy):

- GNSS horizontal error autocorrelation at 1, 5, 20 s lag (class mean removed);
- RTK share fixed, share of quality-4 epochs more than 0.2 m wrong, re-fix time;
- GNSS features μ, σ, ζ, λ, β from the written NMEA, read back by the receiver
  code, beside the real-receiver spread (gpsd logs: ζ 12–67 %, μ 3.6–24.6 dB)
  and the substation paper's attenuation (light 5–10 dB, heavy 18–23 dB);
- C/N0 of LOS and NLOS beside smartLoc (43.8 ± 4.5 vs 31.4 ± 7.9 dB-Hz);
- survey fix error medians per class per site seed;
- the demo walk's error table (GNSS / acoustic / PDR, median and p95 per class)
  and the acoustic frame length and share of frames with a fix per class.

Writes a PNG (error autocorrelation per source, error CDFs per source and
class). ``tests/test_calibration.py`` pins the figures inside their bands.

Why some simulated figures sit outside the real ones (measured on site seeds
21–25, 2 × 400 s walks, 2026-12-01):

- **Open-sky ζ ≈ 0.06 vs the gpsd logs' 0.12–0.67.** The simulated untracked
  satellites above 10° come from physical causes only: 84 % of them lie below
  20° elevation, where the open-sky C/N0 (40–42 dB-Hz), less the receiver's
  offset (0 to −5 dB), the wearer's body behind (up to 7.5 dB at 10°) and
  fading, falls under the 25–28 dB-Hz tracking threshold; 40 % of them sit
  behind a distant structure (≥ 18 dB down). The gpsd logs are not open-sky
  captures: their untracked satellites are spread over the sky (20–50 % above
  40°), 9 of the 13 logs report a median tracked C/N0 of 20–39 dB-Hz (indoors
  or at a window), several are cold starts of 2–16 epochs listing almanac
  satellites not yet acquired, and whole constellations are listed but not
  tracked (BeiDou 297 of 297 in quectel-eg25-g, SBAS 216 of 216 in ublox-8).
  A simulator that listed GPS/BeiDou satellites it never tries to track
  would only copy a receiver configuration, so none is added.
- **Heavy μ ≈ 6 dB vs the paper's 18–23 dB.** μ is the attenuation of the
  satellites a receiver reports, i.e. tracked ones. Open-sky C/N0 above 10° is
  40–50 dB-Hz and the tracking threshold 25–28 dB-Hz, so a tracked satellite
  can be at most ≈ 15–22 dB down, and its mean cannot reach 18–23 dB unless
  every one sits at the threshold. The attenuation of every in-view heavy
  satellite is 11.5 dB (tracked 6.0, untracked 23.5); 37 % of them are 18 dB
  or more down and 76 % of those are not tracked — they count in ζ (0.31 in
  heavy), which is where a receiver shows the paper's heavy attenuation.
- **Heavy error autocorrelation at 20 s.** The figure uses pairs inside one
  visit of the class with the class mean removed per walk. Heavy visits are
  short (median 9 s; 19 % of heavy time in visits ≥ 20 s), and the sample
  autocorrelation of a short record with its mean removed is biased low
  (≈ −1/N_eff): a Gauss–Markov error of τ = 30 s (true ρ(20 s) = 0.51) sampled
  on these walks' heavy visits reads +0.01, on light visits +0.36
  (tests/test_calibration.py checks the estimator on a known process).

Usage: /work/main/.venv/bin/python bench/calibrate_sim.py [--sites 21 22 23 24 25] [--walk-s 400]
       [--png calibration.png] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from features.site import ENV_CLASSES, save_site  # noqa: E402
from simulation.gnss.fix import FixConfig  # noqa: E402
from simulation.gnss.nmea_writer import format_nmea  # noqa: E402
from simulation.gnss.stream import simulate_gnss, to_nmea_epochs  # noqa: E402
from simulation.rng import stream_rng  # noqa: E402
from simulation.site.environment import blocked_share, classify_share  # noqa: E402
from simulation.site.layout import generate_site  # noqa: E402
from simulation.site.route import RouteConfig, plan_route, route_trajectory, static_trajectory  # noqa: E402
from simulation.survey import survey_cells  # noqa: E402

LAGS_S = (1.0, 5.0, 20.0, 60.0)
WARM = FixConfig(rtk_cold_start=False)  # a survey crew keeps the receiver running between cells
REAL = {
    "autocorr_target": "light/heavy: >= 0.5 at 5 s, >= 0.2 at 20 s (NLOS biases persist 10-30 s past a wall)",
    "wrong_fix_target": "light/heavy 0.5-5 %, open ~0 (urban RTK studies; u-blox F9P integrity notes)",
    "zeta": "gpsd real logs 12-67 % (12 of 13 logs)",
    "mu": "gpsd real logs 3.6-24.6 dB; paper: light 5-10 dB, heavy 18-23 dB",
    "cn0": "smartLoc LOS 43.8 +- 4.5, NLOS 31.4 +- 7.9 dB-Hz",
}


def _classes(site, east, north) -> np.ndarray:
    return classify_share(blocked_share(site, east, north, n_az=90)).astype(int)


def _class_runs(cls: np.ndarray) -> np.ndarray:
    """Label of the contiguous run of one class each epoch belongs to, (n,) int (a new label at every change)."""
    cls = np.asarray(cls)
    return np.cumsum(np.r_[True, cls[1:] != cls[:-1]]) if cls.size else np.zeros(0, int)


def autocorr_sums(t_s, err_en, cls, lags_s=LAGS_S, per_visit: bool = False) -> dict[int, np.ndarray]:
    """Sums behind the error autocorrelation of one walk, per class: rows (Σa·b, Σ|a|², Σ|b|², n pairs) per lag.

    The pooled estimator (issue 21 item 5, the default): the class mean is removed over the whole walk (the bias
    an engineer would calibrate out for that class), and a pair of epochs (i, i + L) counts when both hold a fix
    and both lie in the class, whether in one visit or two — the error process of a class is sampled wherever the
    walker is in it. ``per_visit=True`` is the earlier figure, which kept only pairs inside one contiguous visit:
    short visits leave few pairs at long lags, all from the visits' ends, and (tests/test_calibration.py) it reads
    far below the truth. Pool over walks by adding the sums: ρ(L) = Σa·b / sqrt(Σ|a|² Σ|b|²)
    (:func:`autocorr_from_sums`), the sample autocorrelation of the 2-D error (Box, Jenkins & Reinsel, *Time
    Series Analysis*, 4th ed., eq. 2.1.12, with the pair sums normalised by the pairs' own variances). Removing
    a mean estimated from the same record biases ρ down by about (1 − ρ)/N_eff; a walk of N_eff ≈ T_class/(2τ)
    independent samples of a Gauss–Markov error of time constant τ, so report only classes with minutes of time.
    """
    dt = float(np.median(np.diff(t_s)))
    ok = np.isfinite(err_en).all(axis=1)
    run = _class_runs(cls)
    out = {}
    for c in range(3):
        m = ok & (cls == c)
        rows = np.zeros((len(lags_s), 4))
        if m.sum() >= 2:
            e = np.where(m[:, None], err_en - err_en[m].mean(axis=0), 0.0)
            for j, lag_s in enumerate(lags_s):
                lag = int(round(lag_s / dt))
                if lag >= len(m) or lag < 1:
                    continue
                pair = m[:-lag] & m[lag:]
                if per_visit:
                    pair &= run[:-lag] == run[lag:]
                a, b = e[:-lag][pair], e[lag:][pair]
                rows[j] = ((a * b).sum(), (a * a).sum(), (b * b).sum(), pair.sum())
        out[c] = rows
    return out


def autocorr_from_sums(rows: np.ndarray, min_pairs: int = 10) -> list[float]:
    """ρ per lag from summed :func:`autocorr_sums` rows; NaN with fewer than ``min_pairs`` pairs."""
    return [float(r[0] / np.sqrt(r[1] * r[2])) if r[3] >= min_pairs and r[1] * r[2] > 0 else np.nan for r in rows]


def autocorr_by_class(t_s, err_en, cls, lags_s=LAGS_S, per_visit: bool = False) -> dict[int, list[float]]:
    """Autocorrelation of the 2-D horizontal error at each lag, per class, for one walk (:func:`autocorr_sums`)."""
    return {c: autocorr_from_sums(r) for c, r in autocorr_sums(t_s, err_en, cls, lags_s, per_visit).items()}


def refix_times_s(t_s, quality, cls=None) -> np.ndarray | dict[int, np.ndarray]:
    """Seconds from each loss of RTK fixed (4 → other) to the next fixed epoch.

    With ``cls`` (n,), a dict per class of the epoch where the fix was lost.
    """
    q4 = np.asarray(quality) == 4
    out = []
    i = 1
    n = len(q4)
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


def _walk_traj(site, seed, duration_s, start):
    route = RouteConfig()
    poly, stops, speed = plan_route(site, stream_rng(seed, "route"), duration_s, route)
    return route_trajectory(poly, stops, speed, duration_s, start, site.device_height_m, route)


def _nmea_features(sim, site, seed, traj):
    from features.gnss.features import gnss_features, sky_arrays
    from features.gnss.nmea import epochs_on_time_base, read_nmea

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "g.nmea"
        p.write_text(format_nmea(to_nmea_epochs(sim, site, seed, traj)))
        epochs, _ = read_nmea(p)
    epochs = epochs_on_time_base(epochs, traj.start_utc)
    return gnss_features(sky_arrays(epochs))


def gnss_walk_figures(site_seeds, walk_seeds, duration_s: float) -> dict:
    """GNSS walk figures pooled over sites × walks (see module docstring)."""
    ac_sums = {c: np.zeros((len(LAGS_S), 4)) for c in range(3)}
    fixed = {c: [] for c in range(3)}
    wrong = {c: [] for c in range(3)}
    herr = {c: [] for c in range(3)}
    refix = []
    refix_cls = {c: [] for c in range(3)}
    feats = {c: [] for c in range(3)}
    los, nlos = [], []
    speed_err = {c: [] for c in range(3)}
    att_all = {c: [] for c in range(3)}
    err_series = []
    for s in site_seeds:
        site = generate_site(s)
        for w in walk_seeds:
            start = datetime(2026, 6, 1, tzinfo=timezone.utc) + timedelta(hours=(3 * s + 7 * w) % 24)
            traj = _walk_traj(site, 1000 * s + w, duration_s, start)
            sim = simulate_gnss(site, traj, seed=1000 * s + w)
            cls = _classes(site, sim.truth_enu_m[:, 0], sim.truth_enu_m[:, 1])
            e = sim.fix_enu_m[:, :2] - sim.truth_enu_m[:, :2]
            h = np.hypot(e[:, 0], e[:, 1])
            for c, rows in autocorr_sums(sim.t_s, e, cls).items():
                ac_sums[c] += rows
            for c in range(3):
                m = cls == c
                if m.sum() >= 50:
                    fixed[c].append(np.mean(sim.quality[m] == 4))
                    q4 = m & (sim.quality == 4)
                    wrong[c].append((q4.sum(), np.sum(q4 & (h > 0.2))))
                    herr[c].append(h[m & np.isfinite(h)])
            refix.append(refix_times_s(sim.t_s, sim.quality))
            for c, v in refix_times_s(sim.t_s, sim.quality, cls).items():
                refix_cls[c].append(v)
            err_series.append((sim.t_s, e, cls))
            view = sim.tracked & (sim.el_rad > np.radians(10))
            above = sim.in_view & (sim.el_rad > np.radians(10))
            for c in range(3):
                m = (cls == c)[:, None] & above
                if m.any():
                    att_all[c].append(sim.attenuation_db[m])
            los.append(sim.cn0_reported_dbhz[view & sim.los])
            nlos.append(sim.cn0_reported_dbhz[view & sim.nlos])
            f = _nmea_features(sim, site, 1000 * s + w, traj)
            fc = _classes(site, np.interp(f["t_s"], sim.t_s, sim.truth_enu_m[:, 0]),
                          np.interp(f["t_s"], sim.t_s, sim.truth_enu_m[:, 1]))
            for c in range(3):
                if (fc == c).any():
                    feats[c].append(np.column_stack([f[k][fc == c] for k in
                                                     ("att_mean_db", "att_std_db", "invisible_ratio", "dop_growth",
                                                      "fluct_per_s")]))
            ne = to_nmea_epochs(sim, site, 1000 * s + w, traj)
            v_true = np.interp(sim.t_s, traj.t_s, traj.speed_m_s)
            for c in range(3):
                m = (cls == c) & np.isfinite(ne.speed_m_s)
                speed_err[c].append(np.abs(ne.speed_m_s[m] - v_true[m]))
    out = {"autocorr": {}, "fixed": {}, "wrong": {}, "herr_med": {}, "herr_p95": {}, "features": {},
           "speed_err_med": {}, "speed_err_p95": {}}
    for c in range(3):
        if not fixed[c]:
            continue
        out["autocorr"][c] = autocorr_from_sums(ac_sums[c])
        out.setdefault("autocorr_pairs", {})[c] = ac_sums[c][:, 3].astype(int).tolist()
        out["fixed"][c] = float(np.mean(fixed[c]))
        n4 = sum(a for a, _ in wrong[c])
        out["wrong"][c] = float(sum(b for _, b in wrong[c]) / max(n4, 1))
        allh = np.concatenate(herr[c])
        out["herr_med"][c] = float(np.median(allh))
        out["herr_p95"][c] = float(np.percentile(allh, 95))
        if feats[c]:
            fa = np.vstack(feats[c])
            out["features"][c] = np.nanmedian(fa, axis=0).tolist()
        se = np.concatenate(speed_err[c])
        out["speed_err_med"][c] = float(np.median(se)) if se.size else np.nan
        out["speed_err_p95"][c] = float(np.percentile(se, 95)) if se.size else np.nan
    out["att_all_mean"] = {c: float(np.mean(np.concatenate(v))) for c, v in att_all.items() if v}
    r = np.concatenate(refix)
    out["refix_median_s"] = float(np.median(r)) if r.size else np.nan
    out["refix_p90_s"] = float(np.percentile(r, 90)) if r.size else np.nan
    out["n_refix"] = int(r.size)
    rc = {c: np.concatenate(v) if v else np.zeros(0) for c, v in refix_cls.items()}
    out["refix_by_class"] = {c: (int(v.size), float(np.median(v)) if v.size else np.nan,
                                 float(np.percentile(v, 90)) if v.size else np.nan) for c, v in rc.items()}
    lo, nl = np.concatenate(los), np.concatenate(nlos)
    out["cn0_los"] = (float(lo.mean()), float(lo.std()))
    out["cn0_nlos"] = (float(nl.mean()), float(nl.std())) if nl.size else (np.nan, np.nan)
    out["series"] = err_series
    return out


def survey_figures(site_seeds, cell_size_m: float = 10.0, capture_s: float = 20.0) -> dict:
    """Median fix error per class per site seed from static captures (one per cell)."""
    out = {}
    for s in site_seeds:
        site = generate_site(s)
        cells = survey_cells(site, cell_size_m)
        cls = _classes(site, [c[1] for c in cells], [c[2] for c in cells])
        start = datetime(2026, 6, 1, 9, tzinfo=timezone.utc)
        meds = {c: [] for c in range(3)}
        for i, ((cid, e, n), c) in enumerate(zip(cells, cls)):
            traj = static_trajectory(e, n, site.device_height_m, capture_s, start + timedelta(seconds=40 * i))
            sim = simulate_gnss(site, traj, seed=10_000 * s + i, fix_cfg=WARM)
            h = sim.horizontal_error_m
            meds[int(c)].append(np.nanmedian(h) if np.isfinite(h).any() else np.nan)
        out[s] = {c: (len(v), float(np.nanmedian(v)) if v else np.nan) for c, v in meds.items()}
    return out


def walk_figures(site_seed: int, walk_seed: int, duration_s: float) -> dict:
    """One full walk (every stream), read back as the walk report does: error table, acoustic frame figures."""
    from pipeline.walk_report import error_table, walk_sources

    site = generate_site(site_seed)
    with tempfile.TemporaryDirectory() as tmp:
        sd = Path(tmp) / "site"
        sd.mkdir()
        save_site(site, sd / "site.toml")
        from simulation.walk import simulate_walk
        t0 = time.perf_counter()
        wd = simulate_walk(sd, Path(tmp) / "walk", seed=walk_seed, duration_s=duration_s)
        sim_wall = time.perf_counter() - t0
        src = walk_sources(wd)
        table = error_table(src)
        ranging = _ranging_errors(wd, src.site, src.truth)
        frame_s = site.acoustic.frame_s
        ac = src.tracks.get("acoustic")
        truth = src.truth
        frames_t = np.arange(truth.t_s[0] + frame_s / 2, truth.t_s[-1], frame_s)
        fcls = truth.class_at(frames_t)
        has = np.zeros(len(frames_t), bool)
        if ac is not None and len(ac.t_s):
            idx = np.clip(np.floor((ac.t_s - truth.t_s[0]) / frame_s).astype(int), 0, len(frames_t) - 1)
            has[idx] = True
        share = {c: float(has[fcls == c].mean()) if (fcls == c).any() else np.nan for c in range(3)}
        tracks = {}
        for name, tr in src.tracks.items():
            ok = np.isfinite(tr.east_m)
            te, tn = truth.at(tr.t_s[ok])
            tracks[name] = (tr.t_s[ok], np.column_stack([tr.east_m[ok] - te, tr.north_m[ok] - tn]),
                            truth.class_at(tr.t_s[ok]))
    return {"table": table, "frame_s": frame_s, "frame_fix_share": share, "sim_wall_s": sim_wall,
            "tracks": tracks, "ranging": ranging}


def _ranging_errors(walk_dir, site, truth) -> dict:
    """LOS arrival error in metres (receiver's arrival against the simulator's, 10-25 m direct paths),
    standing (< 0.1 m/s) and walking: {"static": array, "walking": array}."""
    import csv

    from features.acoustic.features import analyse_audio
    from features.acoustic.timing import speed_of_sound_m_s, timing_from_walk
    from features.walk import load_walk

    walk = load_walk(walk_dir)
    timing = timing_from_walk(walk, site)
    res = analyse_audio(walk.path("audio"), site, timing, keep_frames=True)
    rows = {(int(r["beacon_id"]), round(float(r["emit_t_s"]), 6)): r
            for r in csv.DictReader(open(Path(walk_dir) / "audio_truth.csv"))}
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    t_tr = truth.t_s
    sp = np.hypot(np.gradient(truth.east_m, t_tr), np.gradient(truth.north_m, t_tr))
    out = {"static": [], "walking": []}
    for fr in res.frames:
        for d in fr.detections:
            r = rows.get((d.beacon_id, round(d.tx_s, 6)))
            if r is None or r["first_path"] != "direct" or not 10.0 <= float(r["direct_m"]) <= 25.0:
                continue
            err = c * ((d.arrival_s - timing.start_s) * 48_000 - float(r["arrival_sample"])) / 48_000
            v = float(np.interp(float(r["arrival_t_s"]), t_tr, sp))
            out["static" if v < 0.1 else "walking"].append(abs(err))
    return {k: np.asarray(v) for k, v in out.items()}


def _fmt(x, f="{:.3f}"):
    return "  n/a" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f.format(x)


def print_report(g: dict, sv: dict, wk: dict | None) -> None:
    print("== GNSS walks (pooled) ==")
    print(f"autocorrelation of horizontal error at {LAGS_S} s   [target {REAL['autocorr_target']}]")
    for c, v in g["autocorr"].items():
        print(f"  {ENV_CLASSES[c]:6s} " + " / ".join(f"{x:+.2f}" for x in v)
              + "   (pairs " + " / ".join(str(n) for n in g["autocorr_pairs"][c]) + ")")
    print(f"RTK fixed share, wrong-fix share (q4 > 0.2 m)   [target {REAL['wrong_fix_target']}]")
    for c in g["fixed"]:
        print(f"  {ENV_CLASSES[c]:6s} fixed {100 * g['fixed'][c]:5.1f} %  wrong {100 * g['wrong'][c]:5.2f} %  "
              f"error median {g['herr_med'][c]:.3f} m  p95 {g['herr_p95'][c]:.3f} m  "
              f"RMC speed |err| median {g['speed_err_med'][c]:.3f} p95 {g['speed_err_p95'][c]:.3f} m/s")
    print(f"  re-fix after a loss: median {_fmt(g['refix_median_s'], '{:.1f}')} s, p90 "
          f"{_fmt(g['refix_p90_s'], '{:.1f}')} s (n={g['n_refix']}); by class of the loss: "
          + "  ".join(f"{ENV_CLASSES[c]} {_fmt(m, '{:.1f}')} / {_fmt(p, '{:.1f}')} s (n={n})"
                      for c, (n, m, p) in g["refix_by_class"].items()))
    print(f"GNSS features (medians of windows) μ dB, σ dB, ζ, λ, β /s   [real: ζ {REAL['zeta']}; μ {REAL['mu']}]")
    for c, v in g["features"].items():
        print(f"  {ENV_CLASSES[c]:6s} μ {v[0]:5.2f}  σ {v[1]:5.2f}  ζ {v[2]:5.3f}  λ {v[3]:5.3f}  β {v[4]:5.3f}")
    print("true attenuation of every in-view satellite above 10 deg, tracked or not (mean dB): "
          + "  ".join(f"{ENV_CLASSES[c]} {v:.1f}" for c, v in g["att_all_mean"].items())
          + "   [paper: light 5-10, heavy 18-23 dB]")
    print(f"C/N0 LOS {g['cn0_los'][0]:.1f} ± {g['cn0_los'][1]:.1f}, NLOS {g['cn0_nlos'][0]:.1f} ± "
          f"{g['cn0_nlos'][1]:.1f} dB-Hz   [{REAL['cn0']}]")
    print("== Survey fix error, median of cell medians (n cells) per site seed ==")
    for s, row in sv.items():
        print(f"  site {s}: " + "  ".join(f"{ENV_CLASSES[c]} {_fmt(m)} m ({n})" for c, (n, m) in row.items()))
    if wk is None:
        return
    print(f"== Walk (every stream): frame {wk['frame_s']:.2f} s, simulated in {wk['sim_wall_s']:.1f} s ==")
    print("  share of frames with an acoustic fix [target >= 70 % in every class]: "
          + "  ".join(f"{ENV_CLASSES[c]} {_fmt(v, '{:.2f}')}" for c, v in wk["frame_fix_share"].items()))
    for k, v in wk["ranging"].items():
        if v.size:
            print(f"  LOS arrival error 10-25 m, {k}: median {1000 * np.median(v):.1f} mm, p90 "
                  f"{1000 * np.percentile(v, 90):.1f} mm (n={v.size})   [Lazik & Rowe 2012: 95 % ~10 cm static indoors]")
    print("  source    class   n     median   p95   (m)")
    for name, row in wk["table"].items():
        for c in ("all",) + ENV_CLASSES:
            if c in row:
                n, _mean, med, p95 = row[c]
                print(f"  {name:9s} {c:6s} {n:5d}  {med:7.3f} {p95:7.3f}")


def plot(g: dict, wk: dict | None, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5))
    ax = axes[0]
    lags = np.arange(0.2, 40.0, 0.2)
    srcs = {"GNSS": g["series"]}
    if wk:
        for name, (t, e, c) in wk["tracks"].items():
            if name != "GNSS":
                srcs[name] = [(t, e, c)]
    colours = {"GNSS": "#d62728", "acoustic": "#ff7f0e", "PDR": "#1f77b4"}
    for name, series in srcs.items():
        for c, ls in zip(range(3), ("-", "--", ":")):
            tot = np.zeros((len(lags[::5]), 4))
            for t, e, cl in series:
                if len(t) < 50:
                    continue
                # resample onto 0.2 s for irregular sources
                tt = np.arange(t[0], t[-1], 0.2)
                ee = np.column_stack([np.interp(tt, t, e[:, 0]), np.interp(tt, t, e[:, 1])])
                cc = np.rint(np.interp(tt, t, cl)).astype(int)
                tot += autocorr_sums(tt, ee, cc, lags_s=tuple(lags[::5]))[c]
            if tot[:, 3].any():
                r = autocorr_from_sums(tot)
                ax.plot(lags[::5], r, ls, color=colours.get(name, "k"), label=f"{name} {ENV_CLASSES[c]}")
    ax.axhline(0, color="#999999", lw=0.5)
    ax.set_xlabel("lag, s")
    ax.set_ylabel("autocorrelation of horizontal error")
    ax.set_title("Error autocorrelation per source and class")
    ax.legend(fontsize=7, ncol=2)
    ax = axes[1]
    for name, series in srcs.items():
        for c, ls in zip(range(3), ("-", "--", ":")):
            h = np.concatenate([np.hypot(e[cl == c, 0], e[cl == c, 1]) for _, e, cl in series])
            h = h[np.isfinite(h)]
            if h.size:
                ax.plot(np.sort(h), np.linspace(0, 1, h.size), ls, color=colours.get(name, "k"),
                        label=f"{name} {ENV_CLASSES[c]}")
    ax.set_xscale("log")
    ax.set_xlabel("horizontal error, m")
    ax.set_ylabel("CDF")
    ax.set_title("Error CDF per source and class")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sites", type=int, nargs="+", default=[21, 22, 23, 24, 25])
    ap.add_argument("--walks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--walk-s", type=float, default=400.0)
    ap.add_argument("--full-walk-site", type=int, default=1, help="site seed of the full walk (demo: 1)")
    ap.add_argument("--full-walk-seed", type=int, default=1)
    ap.add_argument("--full-walk-s", type=float, default=120.0, help="0 = skip the full walk")
    ap.add_argument("--png", type=Path, default=Path("calibration.png"))
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    g = gnss_walk_figures(args.sites, args.walks, args.walk_s)
    sv = survey_figures(args.sites)
    wk = walk_figures(args.full_walk_site, args.full_walk_seed, args.full_walk_s) if args.full_walk_s > 0 else None
    print_report(g, sv, wk)
    plot(g, wk, args.png)
    print(f"wrote {args.png}; report took {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
