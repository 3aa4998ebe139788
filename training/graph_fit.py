"""Fitting the graph methods' parameters on training walks (:class:`models.graph.model.GraphModel`).

From each training walk (read as at run time: :func:`walks.reader.read_walk`, :func:`walks.inputs.walk_inputs`):

1. every GNSS and acoustic fix against truth, whitened by the covariance the graph gives it (the fusion
   model's ``kf_quality`` policy: what each device reports, refit), d² = e'R⁻¹e; with the GGA quality and
   the class the online classifier gave at the fix time → the environment-aware kernel table and,
   from the same rows without the class, its blind twin (:class:`models.graph.robust.KernelTable`);
2. the improved step-length model of the RTK/PDR EKF: (K, β) by linear least squares over 10 s segments
   of known truth length (:func:`features.imu.steps.fit_improved_model`, all walks' steps together);
3. the complementary heading's time constant τ: the value of a grid whose step headings, minus each
   walk's mean offset (the mounting yaw the filter estimates), scatter least about the truth's walking
   direction.

Nothing here sees a test site.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from features.errors import DataError
from features.imu.steps import Steps, fit_improved_model
from models.fusion.events import ACOUSTIC, GNSS
from models.graph.model import GraphModel
from models.graph.robust import KernelTable, whitened_d2
from models.rtkpdr import seed_step_headings

__all__ = ["kernel_rows", "fit_kernel_tables", "fit_step_model", "fit_heading_tau", "fit_graph_model",
           "TAU_GRID_S", "SEGMENT_S"]

TAU_GRID_S = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
"""Candidate time constants of the seed's complementary heading, s."""

SEGMENT_S = 10.0
"""Length of the calibration segments of the step-length fit, s of walk time."""


def kernel_rows(data, inputs, quality_policy) -> dict:
    """One walk's fixes against truth: ``gnss_d2`` (n,), ``gnss_quality`` (n,), ``gnss_class`` (n,) (the
    classifier's most probable class), ``acoustic_d2`` (k,), ``acoustic_class`` (k,)."""
    truth = data.truth
    if truth is None:
        raise DataError("a training walk needs truth.csv")
    ev = inputs.events
    r = quality_policy.measurement_noise(ev).r_event
    out = {}
    for name, code in (("gnss", GNSS), ("acoustic", ACOUSTIC)):
        sel = (ev.kind == code) & ev.available & (ev.t_s >= truth.t_s[0]) & (ev.t_s <= truth.t_s[-1])
        sel &= np.all(np.isfinite(r), axis=(1, 2))
        te, tn = truth.at(ev.t_s[sel])
        err = ev.z_m[sel] - np.stack([te, tn], axis=1)
        out[f"{name}_d2"] = whitened_d2(err, r[sel])
        out[f"{name}_class"] = np.argmax(inputs.classes.at(ev.t_s[sel]), axis=1)
        if code == GNSS:
            q = ev.gnss.quality[ev.index[sel]] if ev.gnss is not None else np.zeros(0, int)
            out["gnss_quality"] = np.asarray(q, int)
    return out


def fit_kernel_tables(rows: list[dict], n_classes: int, min_samples: int = 30) -> tuple[KernelTable, KernelTable]:
    """(environment-aware table, blind twin) from :func:`kernel_rows` of the training walks."""
    cat = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    env = KernelTable(n_classes, min_samples).fit(cat["gnss_d2"], cat["gnss_quality"], cat["gnss_class"],
                                                  cat["acoustic_d2"], cat["acoustic_class"])
    blind = KernelTable(n_classes, min_samples).fit(cat["gnss_d2"], cat["gnss_quality"], None,
                                                    cat["acoustic_d2"], None)
    return env, blind


def _segments(steps: Steps, truth) -> tuple[np.ndarray, np.ndarray]:
    """Segment of each step (−1: none) and each segment's truth length, for :func:`fit_improved_model`.

    A step's truth length is the truth's displacement since the previous step; a bout's first step (its
    start unknown) and steps outside the truth are left out."""
    t = steps.t_s
    te, tn = truth.at(t)
    d = np.r_[0.0, np.hypot(np.diff(te), np.diff(tn))]
    usable = (t >= truth.t_s[0]) & (t <= truth.t_s[-1]) & ~np.asarray(steps.bout_start, bool)
    usable[:1] = False
    seg = np.full(len(t), -1)
    if not usable.any():
        return seg, np.zeros(0)
    _, seg[usable] = np.unique(np.floor((t[usable] - t[0]) / SEGMENT_S).astype(int), return_inverse=True)
    return seg, np.bincount(seg[usable], d[usable], minlength=int(seg.max()) + 1)


def fit_step_model(walks: list) -> tuple[float, float] | None:
    """(K, β) of the improved step model over the steps of ``walks`` [(WalkData, ...)], or None."""
    parts, segs, dists, offset = [], [], [], 0
    for data in walks:
        if data.pdr is None or len(data.pdr.result) < 4 or data.truth is None:
            continue
        st = data.pdr.result.steps
        seg, dist = _segments(st, data.truth)
        parts.append(st)
        segs.append(np.where(seg >= 0, seg + offset, -1))
        dists.append(dist)
        offset += len(dist)
    if offset < 3:
        return None
    merged = Steps(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(Steps)})
    model = fit_improved_model(merged, np.concatenate(segs), np.concatenate(dists), select=False)
    return float(model.k), float(model.beta)


def fit_heading_tau(walks: list, grid=TAU_GRID_S) -> float:
    """The τ of ``grid`` whose step headings (minus each walk's circular-mean offset) are closest to the
    truth's walking direction (rms over steps of ≥ 0.3 m); 2 s when no walk has IMU and truth."""
    best, best_rms = 2.0, math.inf
    for tau in grid:
        errs = []
        for data in walks:
            pdr = data.pdr
            if pdr is None or pdr.imu is None or data.truth is None or len(pdr.result) < 4:
                continue
            psi = seed_step_headings(pdr.imu, pdr.result.steps, pdr.config.heading.declination_rad, tau)
            te, tn = data.truth.at(pdr.result.t_s)
            de, dn = np.diff(te), np.diff(tn)
            ok = np.hypot(de, dn) >= 0.3
            e = np.angle(np.exp(1j * (psi[1:][ok] - np.arctan2(de[ok], dn[ok]))))
            if e.size:
                errs.append(np.angle(np.exp(1j * (e - np.angle(np.mean(np.exp(1j * e)))))))
        if errs:
            rms = float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))
            if rms < best_rms:
                best, best_rms = float(tau), rms
    return best


def fit_graph_model(walks: list, fusion_model, min_samples: int = 30) -> GraphModel:
    """Everything of the module docstring from ``walks`` [(WalkData, WalkInputs)] of training walks with
    truth, the fusion model supplying the classifier's classes (in the inputs) and the quality policy."""
    if not walks:
        raise DataError("no training walks to fit the graph model on")
    rows = [kernel_rows(d, i, fusion_model.quality) for d, i in walks]
    env, blind = fit_kernel_tables(rows, fusion_model.classifier.n_classes_, min_samples)
    datas = [d for d, _ in walks]
    step = fit_step_model(datas)
    tau = fit_heading_tau(datas)
    return GraphModel(env, blind, None if step is None else step[0], None if step is None else step[1], tau,
                      {"training_walks": len(walks)})
