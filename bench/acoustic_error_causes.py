"""What sets the acoustic position error: a table of causes with measured contributions (issue 21, item 6).

Two measurements on held-out walks (sites of the standard split's test set, walks nobody tuned on):

1. **The world, one source at a time.** Each walk is simulated again (same seeds: same route,
   noise, beacons) with one error source of the simulator switched off (the options of
   :func:`simulation.acoustic.stream.write_audio`: air, hardware, multipath, Doppler, clock drift),
   and the receiver's fixes are scored against the truth per environment class. A source's
   contribution is how much the open-area median error falls without it.
2. **The receiver, by oracles.** On the default walks the receiver runs as it is, and every
   frame it solves is solved again, in the same tracker state (association, clock prior,
   velocity, exclusion), with the measured arrival times replaced by
   (a) the true first-path arrivals (``audio_truth.csv``; what is left is the world's bias:
   NLOS first paths, air, hardware), and
   (b) geometric pseudoranges — the true distance to the surveyed beacon at the time the
   receiver tags each range, at the receiver's own speed of sound and device height — which
   a perfect receiver would solve exactly (without its air correction, as they hold no air):
   whatever error remains is the receiver's own (its motion model, the time tag, its clock
   prior), and (b′) the same at the walker's true device height. The first-path oracle keeps
   the receiver's air correction of the frame but not the move of the fix the air update
   makes after it.
   Beside them: HDOP of the used beacons at the true position and the LOS ranging error.

Time tag: for walking fixes the along-track error over the speed (s; > 0: the fix is ahead
of where the walker was at its tag), and the shift of the tag that minimises the error.

Run: ``.venv/bin/python bench/acoustic_error_causes.py --root /tmp/causes`` (builds sites and
walks under ``--root`` once, then reuses them; ``--sites``, ``--walks``, ``--duration-s``,
``--configs`` narrow it).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

SPLIT_TEST_SITES = (201, 202, 203, 204, 205)

_NO_MULTIPATH = {"ground_reflection": False, "wall_reflections": False, "tail_offset_db": -100.0}
_IDEAL_BUT_TORSO = {"survey_sigma_h_m": 0.0, "survey_sigma_v_m": 0.0, "emission_delay_sigma_s": 0.0,
                    "emission_jitter_s": 0.0, "codec_order": 0, "piston_radius_m": 0.0}
CONFIGS: dict[str, dict] = {
    "default": {},
    "no wind": {"acoustic_air": {"wind_max_m_s": 0.0, "gust_floor_m_s": 0.0}},
    "no thermometer error": {"acoustic_air": {"thermometer_min_k": 0.0, "thermometer_max_k": 0.0}},
    "no warm air at tanks": {"acoustic_air": {"hot_air_min_k": 0.0, "hot_air_max_k": 0.0}},
    "dry air": {"acoustic_air": {"humidity": False}},
    "air as stated": {"acoustic_air": False},
    "no survey/emission errors": {"acoustic_hardware": {"survey_sigma_h_m": 0.0, "survey_sigma_v_m": 0.0,
                                                        "emission_delay_sigma_s": 0.0, "emission_jitter_s": 0.0}},
    "no torso": {"acoustic_hardware": {"torso_radius_m": 0.0, "torso_loss_min_db": 0.0, "torso_loss_max_db": 0.0}},
    "no codec roll-off": {"acoustic_hardware": {"codec_order": 0}},
    "ideal hardware": {"acoustic_hardware": False},
    "no reflections": {"audio": {"channel": {"ground_reflection": False, "wall_reflections": False}}},
    "no diffuse tail": {"audio": {"channel": {"tail_offset_db": -100.0}}},
    "no multipath": {"audio": {"channel": _NO_MULTIPATH}},
    "no Doppler": {"audio": {"doppler": False}},
    "no clock drift": {"audio": {"clock_drift_ppm": 0.0}},
    "ideal world": {"acoustic_air": False, "acoustic_hardware": False,
                    "audio": {"channel": _NO_MULTIPATH, "doppler": False, "clock_drift_ppm": 0.0}},
    # What the receiver models stays (the wearer's torso, Doppler); every other error source is off.
    "ideal but torso, Doppler": {"acoustic_air": False, "acoustic_hardware": _IDEAL_BUT_TORSO,
                                 "audio": {"channel": _NO_MULTIPATH, "clock_drift_ppm": 0.0}},
}
"""Simulator options per configuration (everything not named stays at its default)."""


def build(root: Path, sites, walks, duration_s: float, configs) -> dict[tuple[str, int, int], Path]:
    """Sites under ``root/sites/<seed>``, walks under ``root/<config>/<site>_w<k>`` (audio and truth only)."""
    from features.fileio import atomic_directory
    from features.site import save_site
    from simulation.site.layout import generate_site
    from simulation.walk import simulate_walk
    from training.benchmark import SPLITS

    split = SPLITS["standard"]
    out = {}
    for s in sites:
        sdir = root / "sites" / str(s)
        if not (sdir / "site.toml").exists():
            with atomic_directory(sdir, overwrite=True) as tmp:
                save_site(generate_site(s), tmp / "site.toml")
        for name in configs:
            for k in walks:
                wdir = root / name.replace(" ", "_").replace("/", "_") / f"{s}_w{k}"
                if not (wdir / "walk.toml").exists():
                    t0 = time.perf_counter()
                    simulate_walk(sdir, wdir, seed=split.walk_seed(s, k), duration_s=duration_s,
                                  person=split.person(s, k), options={**CONFIGS[name], "progress": False},
                                  writers=("simulation.acoustic.stream:write_audio",), progress=False)
                    print(f"  simulated {name} {s}_w{k} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
                out[(name, s, k)] = wdir
    return out


def _truth_rows(walk_dir: Path) -> dict:
    rows = {}
    with open(walk_dir / "audio_truth.csv") as f:
        for r in csv.DictReader(f):
            rows[(int(r["beacon_id"]), round(float(r["emit_t_s"]), 3))] = r
    return rows


class _Oracle:
    """Wraps the tracker's ``frame_fix``: every fix it solves is solved again on oracle arrival times."""

    def __init__(self, walk_dir: Path, timing, truth, site, c: float):
        self.rows, self.timing, self.truth, self.site, self.c = _truth_rows(walk_dir), timing, truth, site, c
        self.by_fix: dict[int, tuple] = {}
        self.range_errors: list[tuple[int, float]] = []      # (los, measured − true first path, m)

    def substitute(self, detections, range_lag_s, kind: str):
        out = []
        lag = range_lag_s or {}
        fs, start, c = 48_000.0, self.timing.start_s, self.c
        for d in detections:
            r = self.rows.get((d.beacon_id, round(d.tx_s, 3)))
            if r is None or not d.associated:
                out.append(d)
                continue
            lam = lag.get(d.beacon_id, 0.0)
            stated = start + float(r["arrival_sample"]) / fs          # the true first arrival, stated clock
            if kind == "first path":
                # The matched filter of a moving receiver peaks (η − 1)·λ early (range–Doppler coupling).
                arrival = stated - (float(r["doppler"]) - 1.0) * lam
            else:
                t_true = float(r["arrival_t_s"])
                offset = stated - t_true                                 # the receiver clock's offset δ
                e, n = self.truth.at(t_true + lam)
                b = self.site.beacon_by_id[d.beacon_id]
                up = float(r["rx_up_m"]) if kind == "true height" else self.site.device_height_m
                rng_m = math.dist((float(e), float(n), up), (b.east_m, b.north_m, b.up_m))
                arrival = d.tx_s + rng_m / c + offset
            out.append(d._replace(arrival_s=arrival))
        return out

    def wrap(self, frame_fix):
        import inspect

        sig = inspect.signature(frame_fix)

        def wrapped(*args, **kw):
            real = frame_fix(*args, **kw)
            if real is not None:
                bound = sig.bind(*args, **kw)
                lag = bound.arguments.get("range_lag_s")
                variants = {}
                air = bound.arguments.get("air")
                for kind in ("first path", "geometric", "true height"):
                    bound.arguments["detections"] = self.substitute(args[0] if args else kw["detections"], lag, kind)
                    # Geometric ranges hold no air: the receiver's air correction would only move them.
                    bound.arguments["air"] = air if kind == "first path" else None
                    variants[kind] = frame_fix(*bound.args, **bound.kwargs)
                self.by_fix[id(real)] = (real, variants)
            return real
        return wrapped

    def ranging(self, frames, range_lag_s) -> None:
        """Measured − true first-path range of every detection with a truth row (Doppler coupling removed)."""
        for fr in frames:
            for d in fr.detections:
                r = self.rows.get((d.beacon_id, round(d.tx_s, 3)))
                if r is None or not d.associated:
                    continue
                lam = range_lag_s.get(d.beacon_id, 0.0)
                true_arr = self.timing.start_s + float(r["arrival_sample"]) / 48_000.0 - (float(r["doppler"]) - 1) * lam
                self.range_errors.append((int(r["los"]), self.c * (d.arrival_s - true_arr)))


def _hdop(site, ids, e: float, n: float) -> float:
    """HDOP of the beacons ``ids`` at (e, n): rows [∂r/∂e, ∂r/∂n, 1] (clock in metres), sqrt(Q_ee + Q_nn)."""
    rows = []
    for i in ids:
        b = site.beacon_by_id[i]
        r = math.dist((e, n, site.device_height_m), (b.east_m, b.north_m, b.up_m))
        rows.append([(e - b.east_m) / r, (n - b.north_m) / r, 1.0])
    g = np.asarray(rows)
    try:
        q = np.linalg.inv(g.T @ g)
    except np.linalg.LinAlgError:
        return float("nan")
    return float(math.sqrt(max(q[0, 0] + q[1, 1], 0.0)))


RECEIVERS = {"after": {}, "before": {"detector": {"impulse_ratio": 0.0}, "positions": {"estimate_air": False}}}
"""The receiver as it is, and as it was before issue 21 item 6 (no impulse removal, the air only as consider
parameters)."""


def evaluate(walk_dir: Path, oracle: bool = False, receiver: str = "after") -> dict:
    """Per-fix records and per-class frame counts of the receiver on one walk (and its oracles)."""
    import features.acoustic.tracking as tracking
    from features.acoustic.detection import DetectorConfig, beacon_chirp_spec
    from features.acoustic.features import analyse_audio
    from features.acoustic.positions import PositionConfig
    from features.acoustic.timing import speed_of_sound_m_s, timing_from_walk
    from features.walk import load_walk, read_truth

    walk = load_walk(walk_dir)
    site = walk.load_site()
    truth = read_truth(walk.directory)
    timing = timing_from_walk(walk, site)
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    lag = {b.id: beacon_chirp_spec(site, b).range_doppler_lag_s for b in site.beacons}
    pos = PositionConfig(max_clock_offset_s=timing.start_uncertainty_s + 0.05, motion_speed_m_s=1.4,
                         **RECEIVERS[receiver].get("positions", {}))
    det = DetectorConfig(**RECEIVERS[receiver].get("detector", {}))
    orc = _Oracle(walk_dir, timing, truth, site, c) if oracle else None
    original = tracking.frame_fix
    if orc is not None:
        tracking.frame_fix = orc.wrap(original)
    try:
        res = analyse_audio(walk.path("audio"), site, timing, det, positions=pos, keep_frames=True)
    finally:
        tracking.frame_fix = original
    cls_at = lambda t: int(truth.env_class[int(np.clip(np.searchsorted(truth.t_s, t), 0, len(truth.t_s) - 1))])
    frames = np.zeros((3, 2), int)
    for fr in res.frames:
        mid = fr.frame_start_s + 0.5 * site.acoustic.frame_s
        if truth.t_s[0] <= mid <= truth.t_s[-1]:
            frames[cls_at(mid), 0] += 1
            frames[cls_at(mid), 1] += fr.fix is not None
    recs = []
    for f in res.fixes:
        if not truth.t_s[0] <= f.t_s <= truth.t_s[-1]:
            continue
        rec = _score(f, truth, site)
        rec["class"] = cls_at(f.t_s)
        rec["hdop"] = _hdop(site, f.used_ids, rec["te"], rec["tn"])
        rec["sigma_m"] = math.sqrt(max(f.covariance[0, 0] + f.covariance[1, 1], 0.0))
        if orc is not None and id(f) in orc.by_fix:
            for kind, g in orc.by_fix[id(f)][1].items():
                rec[kind] = _score(g, truth, site)["err"] if g is not None else float("nan")
        rec["east"], rec["north"] = f.east_m, f.north_m
        recs.append(rec)
    # The walk's median tag lag (walking fixes, every class), and each fix's error with its tag moved by it.
    walk_lag = _median([r["along"] / r["speed"] for r in recs if np.isfinite(r["along"])])
    walk_lag = walk_lag if np.isfinite(walk_lag) else 0.0
    for r in recs:
        e, n = truth.at(r["t"] + walk_lag)
        r["err_lag"] = float(math.hypot(r["east"] - float(e), r["north"] - float(n)))
    if orc is not None:
        orc.ranging(res.frames, lag)
    return {"fixes": recs, "frames": frames, "ranging": orc.range_errors if orc is not None else []}


def _score(f, truth, site) -> dict:
    te, tn = (float(v) for v in truth.at(f.t_s))
    de, dn = f.east_m - te, f.north_m - tn
    ve = (float(truth.at(f.t_s + 0.25)[0]) - float(truth.at(f.t_s - 0.25)[0])) / 0.5
    vn = (float(truth.at(f.t_s + 0.25)[1]) - float(truth.at(f.t_s - 0.25)[1])) / 0.5
    speed = math.hypot(ve, vn)
    along = (de * ve + dn * vn) / speed if speed > 0.5 else float("nan")
    cross = abs(de * vn - dn * ve) / speed if speed > 0.5 else float("nan")
    # The tag shift within ±0.5 s that brings the fix closest to the walked path.
    shifts = np.linspace(-0.5, 0.5, 101)
    pe, pn = truth.at(f.t_s + shifts)
    best = int(np.argmin(np.hypot(f.east_m - pe, f.north_m - pn)))
    return {"t": f.t_s, "te": te, "tn": tn, "err": math.hypot(de, dn), "speed": speed, "along": along,
            "cross": cross, "best_shift": float(shifts[best]) if speed > 0.5 else float("nan"),
            "err_best_shift": float(np.hypot(f.east_m - pe[best], f.north_m - pn[best]))}


def _median(x) -> float:
    x = np.asarray([v for v in x if np.isfinite(v)])
    return float(np.median(x)) if len(x) else float("nan")


def _p95(x) -> float:
    x = np.asarray([v for v in x if np.isfinite(v)])
    return float(np.percentile(x, 95)) if len(x) else float("nan")


def config_table(results: dict) -> None:
    from features.site import ENV_CLASSES

    print("\n## The world, one source off at a time (median error, m; fixes; frames with a fix)")
    print(f"{'configuration':28s} {'open med':>8s} {'p95':>6s} {'n':>5s} {'fix%':>5s} {'light med':>9s}"
          f" {'heavy med':>9s} {'lag s':>6s} {'shifted':>7s} {'Δ open':>7s}")
    base = None
    for name, (recs, frames) in results.items():
        cols = []
        for k in range(3):
            e = [r["err"] for r in recs if r["class"] == k]
            cols.append((_median(e), _p95(e), len(e), frames[k, 1] / max(frames[k, 0], 1)))
        lag = _median([r["along"] / r["speed"] for r in recs if r["class"] == 0 and np.isfinite(r["along"])])
        # The open median with each fix's tag moved by the walk's median lag (what the time tag costs).
        shifted = _median([r["err_lag"] for r in recs if r["class"] == 0])
        if base is None:
            base = cols[0][0]
        print(f"{name:28s} {cols[0][0]:8.3f} {cols[0][1]:6.3f} {cols[0][2]:5d} {100 * cols[0][3]:5.1f} "
              f"{cols[1][0]:9.3f} {cols[2][0]:9.3f} {lag:6.3f} {shifted:7.3f} {cols[0][0] - base:+7.3f}")
    _ = ENV_CLASSES


def oracle_table(recs: list, ranging: list) -> None:
    from features.site import ENV_CLASSES

    print("\n## The receiver on the default walks, by oracle (median / p95 horizontal error, m)")
    print(f"{'class':6s} {'n':>5s} {'measured':>14s} {'true 1st path':>14s} {'geometric':>14s} {'true height':>14s}"
          f" {'HDOP':>5s} {'σ rep.':>6s} {'lag s':>6s} {'best shift':>10s} {'walk/stand':>12s}")
    for k, name in enumerate(ENV_CLASSES):
        rs = [r for r in recs if r["class"] == k]
        if not rs:
            continue
        cells = []
        for key in ("err", "first path", "geometric", "true height"):
            v = [r.get(key, float("nan")) for r in rs]
            cells.append(f"{_median(v):6.3f} / {_p95(v):5.2f}")
        walking = [r["err"] for r in rs if np.isfinite(r["along"])]
        standing = [r["err"] for r in rs if not np.isfinite(r["along"])]
        lag = _median([r["along"] / r["speed"] for r in rs if np.isfinite(r["along"])])
        print(f"{name:6s} {len(rs):5d} " + " ".join(f"{c:>14s}" for c in cells)
              + f" {_median([r['hdop'] for r in rs]):5.2f} {_median([r['sigma_m'] for r in rs]):6.3f} {lag:6.3f}"
              f" {_median([r['best_shift'] for r in rs]):10.3f} {_median(walking):5.3f}/{_median(standing):5.3f}")
    los = np.array([abs(e) for l, e in ranging if l == 1])
    nlos = np.array([e for l, e in ranging if l == 0])
    if len(los):
        print(f"\nLOS ranging error |measured − true first path|: median {1e3 * np.median(los):.1f} mm, "
              f"p90 {1e3 * np.percentile(los, 90):.0f} mm (n = {len(los)}); NLOS first paths: median "
              f"{1e3 * np.median(np.abs(nlos)) if len(nlos) else float('nan'):.0f} mm (n = {len(nlos)})")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, required=True)
    ap.add_argument("--sites", type=int, nargs="+", default=list(SPLIT_TEST_SITES))
    ap.add_argument("--walks", type=int, nargs="+", default=[0])
    ap.add_argument("--duration-s", type=float, default=300.0)
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--no-oracle", action="store_true")
    ap.add_argument("--receivers", nargs="+", default=list(RECEIVERS), choices=list(RECEIVERS))
    args = ap.parse_args(argv)
    dirs = build(args.root, args.sites, args.walks, args.duration_s, args.configs)
    print(f"walks: sites {args.sites}, walks {args.walks}, {args.duration_s:g} s each")
    for receiver in args.receivers:
        results = {}
        oracle_recs, ranging = [], []
        for name in args.configs:
            recs, frames = [], np.zeros((3, 2), int)
            for s in args.sites:
                for k in args.walks:
                    out = evaluate(dirs[(name, s, k)], oracle=(name == "default" and not args.no_oracle),
                                   receiver=receiver)
                    recs += out["fixes"]
                    frames += out["frames"]
                    if name == "default":
                        oracle_recs += out["fixes"]
                        ranging += out["ranging"]
            results[name] = (recs, frames)
        print(f"\n# receiver: {receiver}")
        config_table(results)
        if oracle_recs and not args.no_oracle:
            oracle_table(oracle_recs, ranging)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
