"""The UWB methods in the registry (registered after the graph methods, in this order):

================  ===========================================================================
``uwb``           the UWB fixes alone: every ranging round solved from ranges and PDoA angles
                  (:func:`features.uwb.position.uwb_positions`, ``use_aoa="always"``)
``uwb_aoa_pdr``   Zhou et al. 2025: a Kalman filter on the difference of the PDR and the UWB AOA+range
                  positions, the gain compensating the PDR error (:mod:`models.uwb_pdr`), χ²-gated
``uwb_aoa_pdr_env``   the same with each fix's covariance scaled by the environment's NLOS prior: the
                  class probabilities at the fix (the online classifier) times the per-class scale
                  fitted on the training walks (:class:`models.uwb_pdr.UwbNoisePrior`)
``uwb_aoa_pdr_blind`` its twin: one scale fitted over every class (what the environment adds)
================  ===========================================================================

Both are skipped (:class:`~walks.methods.MethodSkipped`) on a walk without UWB — no ``uwb.csv``, or a site
without ``[[uwb_anchors]]`` — so walks written before UWB existed run every other method unchanged.
"""

from __future__ import annotations

import numpy as np

from features.uwb.position import UwbSolveConfig
from walks.methods import Method, MethodContext, MethodSkipped, register
from walks.track import Track

__all__ = ["UWB_METHODS", "AOA_SOLVE"]

UWB_METHODS = ("uwb", "uwb_aoa_pdr", "uwb_aoa_pdr_env", "uwb_aoa_pdr_blind")
"""The methods this module registers, in report order."""

AOA_SOLVE = UwbSolveConfig(use_aoa="always")
"""How the methods solve each round: ranges and angles together, as the seed's AOA positioning."""


def _fixes(ctx: MethodContext):
    uwb = ctx.inputs.data.uwb
    if uwb is None:
        raise MethodSkipped("no UWB (the walk has no uwb.csv, or its site lists no [[uwb_anchors]])")
    fixes = uwb.positions(AOA_SOLVE)
    if not len(fixes):
        raise MethodSkipped("no UWB round could be solved")
    return fixes


def _uwb(ctx: MethodContext) -> Track:
    f = _fixes(ctx)
    return Track("uwb", f.t_s, f.east_m, f.north_m, f.cov_en.copy())


def _uwb_aoa_pdr(ctx: MethodContext):
    from models.uwb_pdr import UwbPdrFilter

    steps, start = _pdr_of(ctx, "uwb_aoa_pdr")
    fixes = _fixes(ctx)
    return UwbPdrFilter(method="uwb_aoa_pdr").run(steps, start, fixes, resume=_resume_of(ctx, "uwb_aoa_pdr"))


def _resume_of(ctx: MethodContext, name: str):
    """The state filter ``name`` resumes from (a long walk's previous segment's), None for a walk fused whole."""
    return getattr(ctx.inputs, "resume", {}).get(name)


def _pdr_of(ctx: MethodContext, name: str):
    """(the PDR steps, its start) the filter ``name`` runs on: the reader's dead-reckoned track, or, when the
    filter resumes a long walk's previous segment (its cut's steps before the heading resumed have none), the
    steps with a heading dead-reckoned from the origin (the filter takes only the track's increments then:
    :meth:`models.uwb_pdr.UwbPdrFilter.run`)."""
    from types import SimpleNamespace

    from features.imu.pdr import dead_reckon

    pdr = ctx.inputs.data.pdr
    if pdr is not None and _resume_of(ctx, name) is not None:
        r = pdr.result            # a cut without a step (the walker stands through it) keeps p_PDR still
        ok = np.isfinite(r.heading_rad) & np.isfinite(r.step_length_m)
        e, n = dead_reckon(r.step_length_m[ok], r.heading_rad[ok])
        r = SimpleNamespace(t_s=r.t_s[ok], step_length_m=r.step_length_m[ok], heading_rad=r.heading_rad[ok],
                            east_m=e, north_m=n)
        return r, (0.0, 0.0)
    if pdr is None or not len(pdr.result.t_s):
        raise MethodSkipped("no steps (the walk has no usable imu.csv)")
    r = pdr.result
    if not np.isfinite(r.east_m).any():
        raise MethodSkipped("no PDR track (the IMU has no heading sensors)")
    return r, pdr.start_en_m


def _with_prior(name: str, blind: bool):
    def build(ctx: MethodContext):
        from models.uwb_pdr import UwbPdrFilter

        steps, start = _pdr_of(ctx, name)
        fixes = _fixes(ctx)
        prior = getattr(ctx.model, "uwb_prior_blind" if blind else "uwb_prior", None)
        if prior is None:
            raise MethodSkipped("the model has no UWB prior (no training walk had uwb.csv)")
        scale = prior.r_scale(np.ones((len(fixes), 1)) if blind else ctx.inputs.classes.at(fixes.t_s))
        return UwbPdrFilter(method=name).run(steps, start, fixes, r_scale=scale, resume=_resume_of(ctx, name))
    return build


for _m in (Method("uwb", _uwb, "the UWB fixes alone (ranges and PDoA angles per round)"),
           Method("uwb_aoa_pdr", _uwb_aoa_pdr, "KF on the PDR − UWB AOA position difference (Zhou et al. 2025)",
                  filter=True),
           Method("uwb_aoa_pdr_env", _with_prior("uwb_aoa_pdr_env", False),
                  "uwb_aoa_pdr with each fix's R scaled by the class's NLOS prior", filter=True),
           Method("uwb_aoa_pdr_blind", _with_prior("uwb_aoa_pdr_blind", True),
                  "uwb_aoa_pdr_env without the class (one pooled scale; its twin)", filter=True)):
    register(_m)
