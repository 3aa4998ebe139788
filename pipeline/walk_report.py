"""One walk, every raw position source, against the truth: figures and a summary.

Reads only the walk directory's files (as for a real device's log): the
NMEA fixes, the acoustic positions from the audio, the PDR track from the IMU,
and ``truth.csv`` when present. Fusion comes in its own module; this report
shows what each sensor gives on its own, per environment class.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from features.site import ENV_CLASSES
from features.imu.pdr import dead_reckon
from walks.reader import OdometryStream, PdrStream, pdr_position_at, pdr_start_from_gnss, read_walk
from walks.track import latest_per_time

__all__ = ["SourceTrack", "WalkSources", "walk_sources", "error_table", "plot_walk"]


@dataclass(frozen=True)
class SourceTrack:
    """Positions of one source on the walk's time base; arrays of shape (n,)."""

    name: str
    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    info: dict = field(default_factory=dict)


@dataclass(frozen=True)
class WalkSources:
    site: object
    tracks: dict
    truth: object | None
    gnss_features: dict | None
    quality: np.ndarray | None
    acoustic_features: list | None = None
    notes: tuple = ()
    """The reader's notes: streams the walk names but could not use (:attr:`walks.reader.WalkData.notes`)."""


def _pdr_track(pdr: PdrStream, gnss: SourceTrack | None = None, quality=None, calibrate: bool = True,
               anchor: tuple[float, float, float] | None = None) -> SourceTrack:
    """PDR track; with RTK-fixed GNSS and no K given, K and the mounting yaw are calibrated on it first.

    Calibration uses only steps whose both ends fall between RTK-fixed epochs
    (quality 4, centimetre level): K = Σ GNSS step distance / Σ Weinberg units,
    yaw offset = circular mean of (GNSS step heading − PDR heading). The calibrated track is then
    translated to pass through ``anchor`` (t_s, east_m, north_m: the GNSS fix the read anchored PDR on,
    :func:`walks.reader.pdr_start_from_gnss`) at its time, as the uncalibrated one did — dead
    reckoning it again from the start alone would carry the new K and yaw's difference over the steps
    before the anchor into the whole track.
    """
    res, cfg, start_en = pdr.result, pdr.config, pdr.start_en_m
    info = {"steps": len(res), "distance_m": res.distance_m, "k": cfg.length.k, "yaw_offset_deg": 0.0}
    east, north = res.east_m, res.north_m
    if calibrate and gnss is not None and quality is not None and len(res) > 10:
        fixed = quality == 4
        t_g = gnss.t_s
        idx = np.searchsorted(t_g, res.t_s)
        ok_t = (idx > 0) & (idx < len(t_g))
        ii = np.clip(idx, 1, len(t_g) - 1)
        covered = ok_t & fixed[ii] & fixed[ii - 1]
        ge, gn = np.interp(res.t_s, t_g, gnss.east_m), np.interp(res.t_s, t_g, gnss.north_m)
        de, dn = np.diff(ge), np.diff(gn)
        d = np.hypot(de, dn)
        use = covered[1:] & covered[:-1] & (d > 0.2) & (d < 1.5)
        if use.sum() >= 20:
            units = res.step_length_m / cfg.length.k
            k_cal = float(d[use].sum() / units[1:][use].sum())
            offset = float(np.angle(np.sum(d[use] * np.exp(1j * (np.arctan2(de[use], dn[use])
                                                                  - res.heading_rad[1:][use])))))
            east, north = dead_reckon(units * k_cal, res.heading_rad + offset, start_en[0], start_en[1])
            if anchor is not None:
                t_a, e_a, n_a = anchor
                e_i, n_i = pdr_position_at(dataclasses.replace(res, east_m=east, north_m=north), t_a, start_en)
                east, north = east + (e_a - e_i), north + (n_a - n_i)
            info.update(k=k_cal, yaw_offset_deg=float(np.degrees(offset)), calibrated_steps=int(use.sum()),
                        distance_m=float((units * k_cal).sum()))
    return SourceTrack("PDR", res.t_s, east, north, info)


def walk_sources(walk_dir: str | os.PathLike, pdr_k: float | None = None) -> WalkSources:
    """Every available position source of a walk directory, read once by :func:`walks.reader.read_walk`."""
    data = read_walk(walk_dir, pdr_k=pdr_k)
    tracks, feats, quality, acoustic_rows = {}, None, None, None
    if data.gnss is not None:
        pos = data.gnss.positions
        tracks["GNSS"] = SourceTrack("GNSS", pos.t_s, pos.east_m, pos.north_m, {"nmea": data.gnss.nmea_summary})
        feats, quality = data.gnss.features, pos.quality
    if data.acoustic is not None:
        ac = data.acoustic
        tracks["acoustic"] = SourceTrack("acoustic", ac.t_s, ac.east_m, ac.north_m,
                                         {"chirps": ac.analysis.n_detections, "fixes": len(ac.t_s)})
        acoustic_rows = ac.feature_rows
    if isinstance(data.pdr, OdometryStream):
        r = data.pdr.result
        tracks["odometry"] = SourceTrack("odometry", r.t_s, r.east_m, r.north_m,
                                         {"events": len(r), "distance_m": r.distance_m,
                                          "initial_heading_deg": float(np.degrees(data.pdr.alignment.heading_rad))})
    elif data.pdr is not None:
        anchor = pdr_start_from_gnss(data.gnss.positions) if data.gnss is not None else None
        tracks["PDR"] = _pdr_track(data.pdr, tracks.get("GNSS"), quality, calibrate=pdr_k is None, anchor=anchor)
    return WalkSources(site=data.site, tracks=tracks, truth=data.truth, gnss_features=feats, quality=quality,
                       acoustic_features=acoustic_rows, notes=data.notes)


def error_table(src: WalkSources) -> dict:
    """Horizontal error statistics per source and class: {source: {class|'all': (n, mean, median, p95)}}."""
    out = {}
    if src.truth is None:
        return out
    for name, tr in src.tracks.items():
        # the last state of each instant, as evaluate scores it (walks.track.latest_per_time)
        ok = np.isfinite(tr.east_m) & (tr.t_s >= src.truth.t_s[0]) & (tr.t_s <= src.truth.t_s[-1]) & \
            latest_per_time(tr.t_s)
        if not ok.any():
            continue
        te, tn = src.truth.at(tr.t_s[ok])
        err = np.hypot(tr.east_m[ok] - te, tr.north_m[ok] - tn)
        cls = src.truth.class_at(tr.t_s[ok])
        row = {"all": _stats(err)}
        for k, c in enumerate(ENV_CLASSES):
            if (cls == k).any():
                row[c] = _stats(err[cls == k])
        out[name] = row
    return out


def _stats(err):
    return (int(err.size), float(np.mean(err)), float(np.median(err)), float(np.percentile(err, 95)))


_SRC_STYLE = {"GNSS": dict(color="#d62728", marker="o", s=9, edgecolors="#4a0000", linewidths=0.3),
              "acoustic": dict(color="#6a3d9a", marker="D", s=14, edgecolors="black", linewidths=0.4),
              "PDR": dict(color="#1f77b4", s=4)}
"""Source styles: dark-edged markers stay visible on every class background (acoustic was orange, lost
on the light and heavy shading)."""
_MAP_MARGIN_M = 5.0


def _walk_extent(src: WalkSources) -> tuple[float, float, float, float]:
    """East/north limits of the truth and every track (finite points), with a margin, clipped to the site."""
    es, ns = [], []
    if src.truth is not None:
        es.append(np.asarray(src.truth.east_m, float))
        ns.append(np.asarray(src.truth.north_m, float))
    for tr in src.tracks.values():
        es.append(np.asarray(tr.east_m, float))
        ns.append(np.asarray(tr.north_m, float))
    e = np.concatenate(es) if es else np.zeros(0)
    n = np.concatenate(ns) if ns else np.zeros(0)
    ok = np.isfinite(e) & np.isfinite(n)
    g = src.site.grid
    if not ok.any():
        return g.east_min_m, g.east_max_m, g.north_min_m, g.north_max_m
    e0, e1 = np.percentile(e[ok], [0.5, 99.5])
    n0, n1 = np.percentile(n[ok], [0.5, 99.5])
    e0, e1 = max(e0 - _MAP_MARGIN_M, g.east_min_m - _MAP_MARGIN_M), min(e1 + _MAP_MARGIN_M, g.east_max_m + _MAP_MARGIN_M)
    n0, n1 = max(n0 - _MAP_MARGIN_M, g.north_min_m - _MAP_MARGIN_M), min(n1 + _MAP_MARGIN_M, g.north_max_m + _MAP_MARGIN_M)
    return float(e0), float(e1), float(n0), float(n1)


def plot_walk(src: WalkSources, path: str | os.PathLike, title: str = "") -> Path:
    """Map of the sources (zoomed to the walk) and, with a truth, their errors over time on the truth class.

    Legends sit outside the axes, so nothing covers the track; without ``truth.csv`` there is only the map.
    """
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from pipeline.plots import CLASS_COLOURS, draw_structures, save_figure

    has_truth = src.truth is not None
    if has_truth:
        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(16, 6.5), gridspec_kw={"width_ratios": [1.1, 1]})
    else:
        fig, ax = plt.subplots(figsize=(9, 6.5))
        ax2 = None
    e0, e1, n0, n1 = _walk_extent(src)
    structures = draw_structures(ax, src.site, alpha=0.45, zorder=1, extent=(e0, e1, n0, n1))
    for bc in src.site.beacons:
        ax.plot(bc.east_m, bc.north_m, "k^", ms=5)
    if has_truth:
        ax.plot(src.truth.east_m, src.truth.north_m, "k-", lw=0.8, label="truth", zorder=3)
        ax.plot(src.truth.east_m[0], src.truth.north_m[0], "o", ms=9, mfc="white", mec="black", mew=1.5, zorder=6,
                label="start")
        ax.plot(src.truth.east_m[-1], src.truth.north_m[-1], "s", ms=8, mfc="black", mec="black", zorder=6,
                label="end")
    for name, tr in src.tracks.items():
        style = _SRC_STYLE.get(name, {})
        if name in ("PDR", "odometry"):
            lab = name + (" (K, yaw from RTK GNSS)" if "calibrated_steps" in tr.info else "")
            ax.plot(tr.east_m, tr.north_m, "-", color=_SRC_STYLE["PDR"]["color"], lw=1, label=lab, zorder=4)
        else:
            ax.scatter(tr.east_m, tr.north_m, label=name, alpha=0.8, zorder=5, **style)
    if src.site.beacons:
        ax.plot([], [], "k^", ms=5, ls="", label="beacon")
    e0, e1, n0, n1 = _walk_extent(src)
    ax.set_xlim(e0, e1)
    ax.set_ylim(n0, n1)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(handles=handles + structures, loc="upper left", bbox_to_anchor=(0.0, -0.12), ncol=3, fontsize=8,
              frameon=False)
    ax.set_title(title or ("walk: sources against truth" if has_truth else "walk: sources (no truth.csv)"))
    if has_truth:
        t = src.truth.t_s
        c = src.truth.env_class
        edges = np.flatnonzero(np.diff(c)) + 1
        for a, b in zip(np.r_[0, edges], np.r_[edges, len(t)]):
            if c[a] >= 0:           # unknown class (a drive's reference): not shaded
                ax2.axvspan(t[a], t[min(b, len(t) - 1)], color=CLASS_COLOURS[ENV_CLASSES[c[a]]], alpha=0.6, lw=0)
        handles = []
        for name, tr in src.tracks.items():
            ok = np.isfinite(tr.east_m)
            te, tn = src.truth.at(tr.t_s[ok])
            style = dict(_SRC_STYLE.get(name, _SRC_STYLE["PDR"]))
            style["s"] = max(4, style.get("s", 4) - 3)
            h = ax2.scatter(tr.t_s[ok], np.maximum(np.hypot(tr.east_m[ok] - te, tr.north_m[ok] - tn), 1e-3),
                            label=name, zorder=3, **style)
            handles.append(h)
        ax2.set_yscale("log")
        handles += [Patch(color=CLASS_COLOURS[k], alpha=0.6, label=f"truth class: {k}")
                    for i, k in enumerate(ENV_CLASSES) if np.any(c == i)]
        if np.any(c < 0):
            handles.append(Patch(facecolor="white", edgecolor="0.6", label="truth class unknown"))
        ax2.set_xlabel("t (s)")
        ax2.set_ylabel("horizontal error (m)")
        ax2.set_title("horizontal error over time, on the truth class")
        ax2.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.0, -0.12), ncol=3, fontsize=8,
                   frameon=False)
    return save_figure(fig, path)
