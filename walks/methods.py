"""Every fusion method by name: a registry of name → builder, and the built-in methods.

A method is a function of a :class:`MethodContext` (the fitted model, the
walk's inputs, the site map if any) that returns a :class:`~walks.track.Track`
or a filter run (:class:`~models.fusion.ekf.FilterRun`; a filter method is
also reported RTS-smoothed as ``<name>+rts``), or raises :class:`MethodSkipped`
with the reason it cannot run on this walk. :func:`register` adds one; the
order of registration is the report order. Adding a method is one function
and one ``register`` line (docs/architecture.md gives a worked example)::

    def my_method(ctx):
        return EventEKF(ctx.model.ekf, ctx.model.quality, "my_method").run(ctx.events())

    register(Method("my_method", my_method, "kf_quality with my twist", filter=True))

Built-in methods:

==================  ==========================================================
``gnss``            the GGA fixes alone
``acoustic``        the acoustic fixes alone
``pdr``             dead reckoning from the first GNSS fix (steps × length × heading)
``kf``              event-driven EKF, one fitted R per source (the paper's method 2)
``kf_quality``      R from what the devices report (UERE per quality refit on training walks,
                    GST, the acoustic covariance scaled), Huber weights by default
``kf_map``          R per class, the class looked up in a site map at the last estimate (method 1)
``aekf``            variational-Bayes adaptive R, no classifier (Särkkä & Nummenmaa 2009)
``imm``             one mode per class, the classifier's probabilities as mode evidence
``adaptive_nobp``   the error model in context: white scale, Gauss–Markov bias states and outlier prior
                    per class and GGA quality, the class from the online classifier
``adaptive_nobp_blind`` the same machinery fitted and run without the class (the twin that measures
                    what the environment adds; the strongest environment-free baseline)
``adaptive``        adaptive_nobp with each fix's R multiplied by the BP network's output: the network
                    maps the environment (class probabilities, window features), the fix and the filter's
                    state at it (NIS, innovation, update step, gain) to the filter's R
                    (:mod:`models.bp_params`)
``adaptive_blind``  the same without the environment inputs (its twin)
``adaptive_correction`` adaptive_nobp + the guarded BP position correction (the seed's section 2.2)
==================  ==========================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from models.bp import bp_inputs
from models.fusion import (ClassMap, ContextNoise, EventEKF, FilterResume, FilterRun, IMMFilter, VBAdaptiveNoise,
                           fixed_lag_smooth, rts_smooth)
from models.fusion.model import FusionModel
from walks.calibrate import calibrate_tracks
from walks.inputs import WalkInputs
from walks.track import Track

__all__ = ["Method", "MethodContext", "MethodSkipped", "register", "unregister", "method", "method_names",
           "run_methods", "bp_features", "adaptive_run", "tuned", "filter_track", "LAG_S", "parameter_rows",
           "parameter_run", "window_at", "track_state_before"]


class MethodSkipped(Exception):
    """A method cannot run on this walk (the message says why); the others go on."""


@dataclass(frozen=True)
class Method:
    """A fusion method: its ``name``, the ``build`` function of a :class:`MethodContext`, a one-line
    ``summary``, and whether it is a ``filter`` (its run is also smoothed as ``<name>+rts``)."""

    name: str
    build: Callable[["MethodContext"], "Track | FilterRun"]
    summary: str
    filter: bool = False


@dataclass
class MethodContext:
    """What a method may use: the fitted ``model``, the walk's ``inputs``, the site map ``class_at``
    (:class:`~models.fusion.events.ClassMap`, or None), and the results already computed on this walk."""

    model: FusionModel
    inputs: WalkInputs
    class_at: ClassMap | None = None
    results: dict = field(default_factory=dict)

    def events(self):
        """The walk's event stream; :class:`MethodSkipped` when no fix could start a filter."""
        ev = self.inputs.events
        if not np.any(ev.available):
            raise MethodSkipped("no GNSS or acoustic fix to start the filter from")
        return ev

    def result(self, name: str):
        """Another method's result on this walk, computed once (a method may build on another's run)."""
        if name not in self.results:
            self.results[name] = method(name).build(self)
        return self.results[name]


_REGISTRY: dict[str, Method] = {}


def register(m: Method) -> Method:
    """Add ``m`` to the registry (after the methods already there); a name may be registered once."""
    if m.name in _REGISTRY:
        raise ValueError(f"a method named {m.name!r} is already registered")
    if "+" in m.name or not m.name:
        raise ValueError(f"method names must be non-empty and without '+', got {m.name!r}")
    _REGISTRY[m.name] = m
    return m


def unregister(name: str) -> None:
    """Remove a registered method (tests that register a toy method clean up with this)."""
    _REGISTRY.pop(name)


def method(name: str) -> Method:
    """The registered method ``name``."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; choose from {list(_REGISTRY)}") from None


LAG_S = 3.0
"""Default lag of the fixed-lag smoothed tracks (``<filter>+lag``), s: a patrol track is rarely needed with zero
latency, and a few seconds carry most of what the RTS smoother gains from the future (issue 22)."""


def method_names(smoothed: bool = False) -> tuple[str, ...]:
    """Registered method names in report order; with ``smoothed``, each filter's ``+rts`` and ``+lag`` variants
    after it."""
    out = []
    for m in _REGISTRY.values():
        out.append(m.name)
        if smoothed and m.filter:
            out += [m.name + "+rts", m.name + "+lag"]
    return tuple(out)


def filter_track(run: FilterRun, name: str, inputs: WalkInputs) -> Track:
    """A filter run as a :class:`~walks.track.Track` named ``name`` (position, its covariance, NIS, classes)."""
    return Track(name, run.t_s, run.x[:, 0].copy(), run.x[:, 1].copy(), run.P[:, :2, :2].copy(),
                 {"nis": run.nis, "class_proba": inputs.classes.at(run.t_s), "run": run})


def run_methods(model: FusionModel, inputs: WalkInputs, methods=None, smooth: bool = True,
                class_at: ClassMap | None = None, lag_s: float | None = LAG_S,
                results: dict | None = None) -> tuple[dict, dict]:
    """Run ``methods`` (default: every registered one) on one walk: ({name: Track}, {name: reason skipped});
    filter methods also give ``<name>+rts`` when ``smooth`` and ``<name>+lag`` (fixed-lag, ``lag_s``) unless
    ``lag_s`` is None. ``results``: a dict filled with every method's raw result computed on the way, the
    first passes the asked methods build on included (a long walk hands their filter states to its next
    segment)."""
    names = method_names() if methods is None else tuple(methods)
    for n in names:
        method(n)
    ctx = MethodContext(model, inputs, class_at, {} if results is None else results)
    tracks, skipped = {}, {}
    for n in names:
        m = method(n)
        try:
            out = ctx.result(n)
        except MethodSkipped as why:
            skipped[n] = str(why)
            continue
        if isinstance(out, FilterRun):
            tracks[n] = filter_track(out, n, inputs)
            smoothed = []
            if m.filter and smooth:
                smoothed.append(("+rts", rts_smooth(out)))
            if m.filter and lag_s is not None:
                smoothed.append(("+lag", fixed_lag_smooth(out, lag_s)))
            for suffix, sm in smoothed:
                tracks[n + suffix] = Track(n + suffix, sm.t_s, sm.x[:, 0].copy(), sm.x[:, 1].copy(),
                                           sm.P[:, :2, :2].copy())
            calibrate_tracks(tracks, n, out, model, inputs)
        else:
            tracks[n] = out
    return tracks, skipped


# -- single sources -------------------------------------------------------------------------------------------


def _gnss(ctx: MethodContext) -> Track:
    g = ctx.inputs.data.gnss
    if g is None or not len(g.positions):
        raise MethodSkipped("no GNSS fixes")
    p = g.positions
    return Track("gnss", p.t_s, p.east_m, p.north_m, np.eye(2)[None] * (p.sigma_en_m ** 2)[:, None, None])


def _acoustic(ctx: MethodContext) -> Track:
    a = ctx.inputs.data.acoustic
    if a is None or not len(a.t_s):
        raise MethodSkipped("no acoustic fixes")
    return Track("acoustic", a.t_s, a.east_m, a.north_m, a.covariance_en_m2)


def _pdr(ctx: MethodContext) -> Track:
    """Dead reckoning from the first fix; resumed (a long walk's later segment): the steps from the handed
    state's time on are dead-reckoned from the position the previous segment's track reached
    (:func:`track_state_before`), the earlier ones of the cut (its warm-up) from the cut's first fix."""
    from features.imu.pdr import dead_reckon

    pdr, ev = ctx.inputs.data.pdr, ctx.inputs.events
    if pdr is None or not len(pdr.result):
        raise MethodSkipped("no steps")
    if not np.any(ev.available):
        raise MethodSkipped("no fix to start from")
    r = pdr.result
    start = ev.z_m[np.flatnonzero(ev.available)[0]]
    e, n = dead_reckon(r.step_length_m, r.heading_rad, float(start[0]), float(start[1]))
    resume = _resume(ctx.inputs, "pdr")
    if resume is not None:
        j = int(np.searchsorted(r.t_s, resume.t_s, side="left"))
        e[j:], n[j:] = dead_reckon(r.step_length_m[j:], r.heading_rad[j:], float(resume.x[0]), float(resume.x[1]))
    return Track("pdr", r.t_s, e, n, None)


def track_state_before(name: str, track, t_s: float) -> FilterResume | None:
    """What a method whose result is a plain track hands the next segment of a long walk at walk time ``t_s``
    (:meth:`walks.fuse.FusedWalk.handover`): ``pdr``'s position after its last step before ``t_s`` (``x`` =
    (east, north), P empty; dead reckoning carries nothing else); None for the others (fixes alone, or a
    method that does not resume)."""
    if name != "pdr" or not isinstance(track, Track):
        return None
    i = int(np.searchsorted(track.t_s, t_s, side="left")) - 1
    if i < 0 or not (np.isfinite(track.east_m[i]) and np.isfinite(track.north_m[i])):
        return None
    return FilterResume(float(t_s), np.array([track.east_m[i], track.north_m[i]]), np.zeros((0, 0)),
                        event_t_s=float(track.t_s[i]))


# -- filters --------------------------------------------------------------------------------------------------


def _resume(inputs: WalkInputs, name: str):
    """The state the run of filter ``name`` over the previous segment of a long walk handed over (None for a walk
    fused whole): the run continues from it at the segment's start (:mod:`walks.segments`), with everything
    the filter carries from event to event (``aekf``'s variational noise estimate, ``imm``'s per-mode states
    and mode probabilities: :class:`~models.fusion.ekf.FilterResume`)."""
    return getattr(inputs, "resume", {}).get(name)


def tuned(model: FusionModel, name: str) -> tuple:
    """(EkfConfig, scales) of method ``name``: the model's filter settings and noise with the knobs the method
    was tuned to on the training walks (:mod:`training.tuning`; all 1 when untuned): ``q_walk`` multiplies the
    walking random walk, ``gnss`` / ``acoustic`` the R of each source, ``bias`` the bias variance."""
    knobs = dict(model.tuning.get(name, {})) if model.tuning else {}
    cfg = model.ekf
    if "q_walk" in knobs:
        cfg = replace(cfg, q_walk_m2_s=cfg.q_walk_m2_s * float(knobs["q_walk"]))
    return cfg, {k: float(v) for k, v in knobs.items() if k in ("gnss", "acoustic", "bias")}


def _kf(ctx: MethodContext) -> FilterRun:
    cfg, scales = tuned(ctx.model, "kf")
    return EventEKF(cfg, ctx.model.fixed, "kf", scales).run(ctx.events(), resume=_resume(ctx.inputs, "kf"))


def _kf_quality(ctx: MethodContext) -> FilterRun:
    cfg, scales = tuned(ctx.model, "kf_quality")
    return EventEKF(cfg, ctx.model.quality, "kf_quality", scales).run(ctx.events(),
                                                                    resume=_resume(ctx.inputs, "kf_quality"))


def _kf_map(ctx: MethodContext) -> FilterRun:
    if ctx.class_at is None:
        raise MethodSkipped("no map of the site (a simulated site's layout gives one)")
    cfg, scales = tuned(ctx.model, "kf_map")
    return EventEKF(cfg, ctx.model.per_class_map, "kf_map", scales).run(ctx.events(), class_at=ctx.class_at,
                                                                        resume=_resume(ctx.inputs, "kf_map"))


def _aekf(ctx: MethodContext) -> FilterRun:
    rg, ra = ctx.model.fixed.R_gnss_, ctx.model.fixed.R_acoustic_
    vb = VBAdaptiveNoise(gnss_sigma_m=float(np.sqrt(np.trace(rg) / 2)),
                         acoustic_sigma_m=float(np.sqrt(np.trace(ra) / 2)))
    cfg, scales = tuned(ctx.model, "aekf")
    return EventEKF(cfg, vb, "aekf", scales).run(ctx.events(), resume=_resume(ctx.inputs, "aekf"))


def _imm(ctx: MethodContext) -> FilterRun:
    cfg, scales = tuned(ctx.model, "imm")
    return IMMFilter(ctx.model.per_class, cfg, scales=scales).run(ctx.events(), classes=ctx.inputs.classes,
                                                                  resume=_resume(ctx.inputs, "imm"))


def adaptive_run(model: FusionModel, inputs: WalkInputs, method_name: str = "adaptive_nobp", blind: bool = False):
    """The adaptive methods' filter run: the error model in context (white scale, Gauss–Markov bias and outlier
    prior per class and GGA quality, :class:`~models.fusion.context.ContextNoise`) with the class from the
    online classifier; ``blind``: the same machinery fitted and run without the class (its twin)."""
    ev = inputs.events
    if not np.any(ev.available):
        raise MethodSkipped("no GNSS or acoustic fix to start the filter from")
    cfg, scales = tuned(model, method_name)
    if blind:
        if model.context_blind is None:
            raise MethodSkipped("the model has no environment-blind context model (trained before it existed)")
        return EventEKF(replace(cfg, outlier="mixture"), model.context_blind, method_name, scales).run(
            ev, resume=_resume(inputs, method_name))
    policy = model.adaptive_policy()
    if isinstance(policy, ContextNoise):
        cfg = replace(cfg, outlier="mixture")
    return EventEKF(cfg, policy, method_name, scales).run(ev, classes=inputs.classes,
                                                          resume=_resume(inputs, method_name))


def _adaptive_nobp(ctx: MethodContext) -> FilterRun:
    return adaptive_run(ctx.model, ctx.inputs)


def _adaptive_nobp_blind(ctx: MethodContext) -> FilterRun:
    return adaptive_run(ctx.model, ctx.inputs, "adaptive_nobp_blind", blind=True)


# -- the BP networks -------------------------------------------------------------------------------------------


def bp_features(run: FilterRun, inputs: WalkInputs) -> np.ndarray:
    """The BP corrector's input rows for every event of a filter run (:func:`models.bp.bp_inputs`)."""
    return bp_inputs(run.t_s, run.kind, run.updated, run.accepted, run.K, run.nu, run.dx, run.nis,
                     inputs.classes.at(run.t_s))


def window_at(inputs: WalkInputs, t_s: np.ndarray) -> np.ndarray:
    """The window features in force at each of ``t_s`` (the last complete window) with the GNSS and acoustic
    availability flags, (m, 16); zeros before the first window (a long walk's cut
    without a window of its own before its segment: the window its class state was handed at)."""
    from features.schema import modality_columns

    rows = inputs.classes.row_at(t_s)
    before = np.full(inputs.window_X.shape[1], np.nan) if inputs.X_before is None else inputs.X_before
    X = np.vstack([before[None, :], inputs.window_X])[rows]
    flags = [np.isfinite(X[:, list(modality_columns(m))]).any(axis=1) for m in ("gnss", "acoustic")]
    return np.column_stack([np.nan_to_num(X)] + [f.astype(float) for f in flags])


def parameter_rows(run: FilterRun, inputs: WalkInputs, blind: bool) -> np.ndarray:
    """The BP parameter network's inputs (:func:`models.bp_params.parameter_inputs`) from a first-pass run;
    ``blind``: without the class probabilities and the window features."""
    from models.bp_params import parameter_inputs

    ev = inputs.events
    quality = np.zeros(len(ev), int)
    g = ev.kind == 1
    if ev.gnss is not None and g.any():
        quality[g] = ev.gnss.quality[ev.index[g]]
    return parameter_inputs(ev.kind, quality, ev.cov_m2, run.nis, run.nu, run.dx, run.K,
                            None if blind else inputs.classes.at(ev.t_s), None if blind else window_at(inputs, ev.t_s))


def parameter_run(model: FusionModel, inputs: WalkInputs, first: FilterRun, blind: bool, name: str):
    """The second pass of the adaptive filter with each fix's R multiplied by the BP parameter network's s
    (``first``: the first pass, ``adaptive_nobp`` or its twin). Returns (run, share of fixes guarded)."""
    net = model.bp_params_blind if blind else model.bp_params
    log_s, ood = net.log_scale(parameter_rows(first, inputs, blind))
    fix = inputs.events.kind != 0
    scale = np.where(fix, np.exp(log_s), 1.0)
    base = "adaptive_nobp_blind" if blind else "adaptive_nobp"
    cfg, scales = tuned(model, base)
    policy = model.context_blind if blind else model.adaptive_policy()
    if isinstance(policy, ContextNoise):
        cfg = replace(cfg, outlier="mixture")
    run = EventEKF(cfg, policy, name, scales).run(inputs.events, classes=None if blind else inputs.classes,
                                                  r_scale_event=scale, resume=_resume(inputs, name))
    run.info["bp_log_scale"] = np.where(fix, log_s, np.nan)
    run.info["bp_guard_share"] = float(ood[fix].mean()) if fix.any() else 0.0
    return run


def _adaptive(ctx: MethodContext) -> FilterRun:
    if ctx.model.bp_params is None:
        raise MethodSkipped("the model has no BP parameter network (trained with --no-bp)")
    ctx.events()
    return parameter_run(ctx.model, ctx.inputs, ctx.result("adaptive_nobp"), False, "adaptive")


def _adaptive_blind(ctx: MethodContext) -> FilterRun:
    if ctx.model.bp_params_blind is None:
        raise MethodSkipped("the model has no environment-blind BP parameter network")
    ctx.events()
    return parameter_run(ctx.model, ctx.inputs, ctx.result("adaptive_nobp_blind"), True, "adaptive_blind")


def _adaptive_correction(ctx: MethodContext) -> Track:
    """adaptive_nobp's run with the guarded BP position correction added to its output (the seed's §2.2)."""
    if ctx.model.bp is None:
        raise MethodSkipped("the model has no BP corrector (trained with --no-bp)")
    bp = ctx.model.bp
    run = ctx.result("adaptive_nobp")
    X = bp_features(run, ctx.inputs)
    corr = bp.correct(X, run.x_prior[:, :2], ctx.inputs.events.z_m, run.S, run.updated)
    east = run.x[:, 0] + corr.delta_m[:, 0]
    north = run.x[:, 1] + corr.delta_m[:, 1]
    # P + Var(correction)/2 per axis where a correction was applied
    extra = np.where(np.any(corr.delta_m != 0, axis=1), corr.var_m2.sum(1) / 2, 0.0)
    cov = run.P[:, :2, :2] + np.eye(2)[None] * extra[:, None, None]
    return Track("adaptive_correction", run.t_s, east, north, cov,
                 {"nis": run.nis, "class_proba": ctx.inputs.classes.at(run.t_s), "bp_delta_m": corr.delta_m,
                  "bp_disabled_share": corr.disabled_share, "run": run})


for _m in (Method("gnss", _gnss, "the GGA fixes alone"),
           Method("acoustic", _acoustic, "the acoustic fixes alone"),
           Method("pdr", _pdr, "dead reckoning from the first fix"),
           Method("kf", _kf, "one fitted R per source (the paper's method 2)", filter=True),
           Method("kf_quality", _kf_quality, "R from what each device reports about itself", filter=True),
           Method("kf_map", _kf_map, "R per class of the site map at the last estimate (method 1)", filter=True),
           Method("aekf", _aekf, "variational-Bayes adaptive R, no classifier", filter=True),
           Method("imm", _imm, "one mode per environment class", filter=True),
           Method("adaptive_nobp", _adaptive_nobp, "bias states and outlier prior per class and quality",
                  filter=True),
           Method("adaptive_nobp_blind", _adaptive_nobp_blind, "adaptive_nobp without the class (its twin)",
                  filter=True),
           Method("adaptive", _adaptive, "adaptive_nobp with each fix's R set by the BP network", filter=True),
           Method("adaptive_blind", _adaptive_blind, "adaptive without the class and window inputs (its twin)",
                  filter=True),
           Method("adaptive_correction", _adaptive_correction, "adaptive_nobp + the guarded BP position "
                  "correction of the seed's section 2.2")):
    register(_m)
