"""The sibling methods in the registry: factor-graph fusion on GTSAM and the RTK/PDR EKF.

Registered here (after the built-in methods of :mod:`walks.methods`, in this order):

================  ===========================================================================
``fg_batch``      the whole walk as one graph (:mod:`models.graph`), Levenberg–Marquardt; PDR
                  between-factors with heading-offset / step-scale calibration, GNSS and acoustic
                  position factors with the ``kf_quality`` covariance under Huber (k of the model's EKF)
``fg_gauss``      the same with Gaussian factors (the seed's form: no robustness)
``fg_cauchy``     the same under the Cauchy kernel
``fg_dcs``        the same under dynamic covariance scaling (switchable constraints, closed form)
``fg_env``        DCS with the scale and Φ of each fix from its class probabilities and GGA quality,
                  fitted on training walks (:class:`models.graph.robust.KernelTable`)
``fg_blind``      its blind twin: the same fit and machinery without the class
``fg_isam2``      the graph incrementally in iSAM2, causal: each event's estimate right after it
``fg_lag``        fixed-lag smoothing (iSAM2 with marginalisation), the window ``GraphConfig.lag_s``
``fg_tight``      fixed lag with tightly coupled acoustic range factors and a clock per frame
``fg_ins``        IMU preintegration factors (waist IMU, bias variables) with GNSS and acoustic factors
``ekf_rtk_pdr``   the RTK/PDR EKF of Zhang et al. 2023 (:mod:`models.rtkpdr`), also RTS-smoothed
================  ===========================================================================

Importing this module registers them; ``walks/__init__.py`` imports it, so every user of the registry
(``run``, ``evaluate``, the benchmark, Dask workers) sees them. gtsam is imported only when a graph
method runs.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from models.fusion.events import STEP, StepEvents, merge_events
from models.graph.model import graph_model_of
from walks.methods import Method, MethodContext, MethodSkipped, register
from walks.track import Track

__all__ = ["graph_config", "fix_noise", "graph_track", "GRAPH_METHODS"]

GRAPH_METHODS = ("fg_batch", "fg_gauss", "fg_cauchy", "fg_dcs", "fg_env", "fg_blind", "fg_isam2", "fg_lag",
                 "fg_tight", "fg_ins", "ekf_rtk_pdr")
"""The methods this module registers, in report order."""


def graph_config(ctx: MethodContext, **overrides):
    """The graph settings of a method: the model's EKF motion model, its Huber k as kernel width."""
    from models.graph.config import GraphConfig

    return GraphConfig.from_ekf(ctx.model.ekf, **overrides)


def fix_noise(ctx: MethodContext, ev):
    """Every fix's covariance: the ``kf_quality`` policy (what each device reports, refit on training walks)."""
    from models.graph.build import FixNoise

    return FixNoise.from_cov(ev, ctx.model.quality.measurement_noise(ev).r_event)


def graph_track(run, ctx: MethodContext) -> Track:
    """A :class:`~walks.track.Track` of a graph run (its solver figures in ``info['graph']``)."""
    cov = run.cov_m2 if np.any(np.isfinite(run.cov_m2)) else None
    return Track(run.method, run.t_s, run.east_m, run.north_m, cov,
                 {"class_proba": ctx.inputs.classes.at(run.t_s), "graph": run.info})


def _batch(name: str, **kernels):
    def build(ctx: MethodContext) -> Track:
        from models.graph.solve import solve_batch

        ev = ctx.events()
        return graph_track(solve_batch(ev, fix_noise(ctx, ev), graph_config(ctx, **kernels), name), ctx)

    build.__name__ = f"_{name}"
    return build


def _tabled(name: str, table_attr: str):
    """fg_env / fg_blind: DCS with per-fix scale and Φ from the fitted kernel table."""

    def build(ctx: MethodContext) -> Track:
        from dataclasses import replace

        from models.fusion.events import ACOUSTIC, GNSS
        from models.graph.solve import solve_batch

        gm = graph_model_of(ctx.model)
        table = None if gm is None else getattr(gm, table_attr)
        if table is None:
            raise MethodSkipped("the fusion model has no fitted graph kernel table (training.graph_fit)")
        ev = ctx.events()
        noise = fix_noise(ctx, ev)
        cov, width = noise.cov_m2.copy(), noise.width.copy()
        proba = ctx.inputs.classes.at(ev.t_s)
        g = np.flatnonzero(ev.kind == GNSS)
        if g.size:
            s, phi = table.gnss_params(ev.gnss.quality[ev.index[g]], proba[g])
            cov[g] *= (s ** 2)[:, None, None]
            width[g] = np.sqrt(phi)
        a = np.flatnonzero(ev.kind == ACOUSTIC)
        if a.size:
            s, phi = table.acoustic_params(a.size, proba[a])
            cov[a] *= (s ** 2)[:, None, None]
            width[a] = np.sqrt(phi)
        noise = replace(noise, cov_m2=cov, width=width)
        cfg = graph_config(ctx, gnss_kernel="dcs", acoustic_kernel="dcs")
        return graph_track(solve_batch(ev, noise, cfg, name), ctx)

    build.__name__ = f"_{name}"
    return build


def _fg_isam2(ctx: MethodContext) -> Track:
    from models.graph.solve import solve_isam2

    ev = ctx.events()
    return graph_track(solve_isam2(ev, fix_noise(ctx, ev), graph_config(ctx), "fg_isam2"), ctx)


def _fg_lag(ctx: MethodContext) -> Track:
    from models.graph.solve import solve_fixed_lag

    ev = ctx.events()
    return graph_track(solve_fixed_lag(ev, fix_noise(ctx, ev), graph_config(ctx), "fg_lag"), ctx)


def _fg_tight(ctx: MethodContext) -> Track:
    from models.graph.tight import solve_tight

    ev = ctx.events()
    ranges = getattr(ctx.inputs.data.acoustic, "ranges", None) if ctx.inputs.data.acoustic is not None else None
    if ranges is None or not len(ranges):
        raise MethodSkipped("no acoustic ranges on this walk")
    return graph_track(solve_tight(ev, fix_noise(ctx, ev), ranges, graph_config(ctx), "fg_tight"), ctx)


def _fg_ins(ctx: MethodContext) -> Track:
    from models.graph.ins import InsConfig, solve_ins

    pdr = ctx.inputs.data.pdr
    imu = getattr(pdr, "imu", None)          # a drive's odometry stream has none
    if imu is None or imu.gyro_rad_s is None:
        raise MethodSkipped("no IMU with a gyro on this walk")
    if not np.isfinite(pdr.result.heading_rad).any():       # a walk (or a long walk's cut) standing still
        raise MethodSkipped("no step with a heading to orient the INS keyframes by")
    ev = ctx.events()
    start = ctx.result("fg_batch")
    cfg = InsConfig(gnss_width=ctx.model.ekf.huber_k, acoustic_width=ctx.model.ekf.huber_k)
    run = solve_ins(pdr.imu, ev, fix_noise(ctx, ev), (start.t_s, start.east_m, start.north_m),
                    pdr.result.t_s, pdr.result.heading_rad, cfg, "fg_ins")
    return graph_track(run, ctx)


def _seed_stream(ctx: MethodContext):
    """The seed's event stream: its steps (complementary heading, improved length) split at the GNSS fixes,
    the GNSS fixes, the walk's standing intervals; and the share of its step each sub-step is."""
    from features.imu.steps import StepLengthModel
    from models.rtkpdr import seed_step_headings
    from walks.inputs import split_steps

    data = ctx.inputs.data
    pdr, ev = data.pdr, ctx.inputs.events
    if getattr(pdr, "imu", None) is None or len(pdr.result) < 2:      # a drive's odometry has no IMU
        raise MethodSkipped("no IMU steps on this walk")
    if ev.gnss is None or not np.any(ev.gnss.available):
        raise MethodSkipped("no GNSS fix (the RTK measurement)")
    gm = graph_model_of(ctx.model)
    steps = pdr.result.steps
    tau = gm.heading_tau_s if gm is not None else 2.0
    psi = seed_step_headings(pdr.imu, steps, pdr.config.heading.declination_rad, tau)
    if gm is not None and gm.step_k is not None:
        length = StepLengthModel(k=gm.step_k, beta=gm.step_beta).predict(steps)
    else:
        length = pdr.result.step_length_m
    t, L, h = split_steps(pdr.result.t_s, length, psi, ev.gnss.t_s)
    stream = merge_events(steps=StepEvents(t, L, h), gnss=ev.gnss, stands=ev.stands)
    parent = np.clip(np.searchsorted(pdr.result.t_s, stream.t_s, side="left"), 0, len(length) - 1)
    frac = np.where(stream.kind == STEP, stream.step_length_m / np.maximum(length[parent], 1e-9), 1.0)
    return stream, np.clip(frac, 0.0, 1.0)


def _ekf_rtk_pdr(ctx: MethodContext):
    from models.rtkpdr import RtkPdrEKF

    stream, frac = _seed_stream(ctx)
    r = ctx.model.quality.measurement_noise(stream).r_event
    return RtkPdrEKF(method="ekf_rtk_pdr").run(stream, r, frac)


def _solver_guard(build):
    """A GTSAM solver that gives up on a walk (an indeterminate system, a failed elimination: RuntimeError)
    skips that method with GTSAM's reason instead of failing the walk, so every other method's track is kept."""
    def guarded(ctx: MethodContext):
        try:
            return build(ctx)
        except RuntimeError as exc:
            first = next((ln.strip() for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            raise MethodSkipped(f"GTSAM could not solve this walk ({first})") from None
    return guarded


for _m in (Method("fg_batch", _batch("fg_batch"), "factor graph, Levenberg–Marquardt, Huber factors"),
           Method("fg_gauss", _batch("fg_gauss", gnss_kernel="gauss", acoustic_kernel="gauss"),
                  "factor graph with Gaussian factors (the seed's form)"),
           Method("fg_cauchy", _batch("fg_cauchy", gnss_kernel="cauchy", acoustic_kernel="cauchy"),
                  "factor graph, Cauchy factors"),
           Method("fg_dcs", _batch("fg_dcs", gnss_kernel="dcs", acoustic_kernel="dcs"),
                  "factor graph, dynamic covariance scaling (switchable constraints)"),
           Method("fg_env", _tabled("fg_env", "kernels_env"), "DCS with scale and Φ per class and quality"),
           Method("fg_blind", _tabled("fg_blind", "kernels_blind"), "fg_env's blind twin (no class)"),
           Method("fg_isam2", _fg_isam2, "factor graph incrementally (iSAM2), causal"),
           Method("fg_lag", _fg_lag, "fixed-lag smoother (iSAM2 with marginalisation)"),
           Method("fg_tight", _fg_tight, "fixed lag, tightly coupled acoustic ranges and clocks"),
           Method("fg_ins", _fg_ins, "IMU preintegration factors with GNSS and acoustic factors"),
           Method("ekf_rtk_pdr", _ekf_rtk_pdr, "the RTK/PDR EKF of Zhang et al. 2023", filter=True)):
    register(_m if _m.filter else dataclasses.replace(_m, build=_solver_guard(_m.build)))
