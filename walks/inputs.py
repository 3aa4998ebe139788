"""A read walk turned into what the filters take: one event stream and the environment evidence over time.

:func:`walk_inputs` builds, from a :class:`~walks.reader.WalkData`, the event
stream of :mod:`models.fusion.events` — PDR steps (each spread over the time
it took, :func:`split_steps`), GNSS fixes with their reported σ, quality and
HDOP, acoustic fixes with their covariance, standing intervals from the gaps
between steps (not over a hole in the IMU log, where the walker may walk on unseen: :func:`_imu_holes`) — and
the online environment classifier's evidence over time. A vehicle's odometry
(:class:`~walks.reader.OdometryStream`) gives the steps instead, each with its own
noise from the odometry's variances (:func:`_odometry_steps`).
The classifier answers on each 2 s feature window only once the window is
complete (its end time). With the fusion model's class HMM the window
probabilities are smoothed along the walk (:func:`smooth_classes`):
``forward`` (``run``) is causal, so a filter still never uses a class from the
future; ``forward_backward`` (``evaluate``) uses the whole walk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from features.errors import ConfigError, DataError
from features.schema import ACOUSTIC_FEATURES, FEATURES, GNSS_FEATURES
from models.fusion import AcousticEvents, ClassTrack, GnssEvents, StandIntervals, StepEvents, merge_events
from models.fusion.events import EventStream
from walks.reader import OdometryStream, WalkData

__all__ = ["WalkInputs", "walk_inputs", "smooth_classes", "ClassResume", "class_state_before", "CLASS_SMOOTHING",
           "EventsResume", "events_state_before", "window_features", "split_steps", "gnss_events", "STAND_GAP_S",
           "TYPICAL_STEP_S", "WINDOW_S", "HOP_S", "SilentCut"]

class SilentCut(DataError):
    """A later cut of a long walk holds no event at all (every stream silent for longer than its segment, its
    warm-up and its tail: a logger paused, ``duration_s`` longer than the recording): the whole walk has no
    epoch there either, and the segment hands on what it was handed (:meth:`walks.fuse.FusedWalk.handover`)."""


STAND_GAP_S = 1.5
"""A gap between steps longer than this is standing (from 0.5 s after the last step to 0.5 s before the next)."""

SAME_STEP_S = 0.25
"""Two step times closer than this are one step (a cut's and the whole walk's read of it agree to microseconds; a
walker's steps are 0.4 s apart or more)."""

TYPICAL_STEP_S = 0.55
"""Duration given to a step that follows a stop (no previous step within :data:`STAND_GAP_S`), s."""

WINDOW_S = 2.0
"""Feature window length, s (the readers' default): a window centred at t is complete at t + 1 s."""

HOP_S = 1.0
"""Hop between the walk's feature windows, s (the readers' default)."""


@dataclass(frozen=True)
class WalkInputs:
    """A walk ready for the filters: ``events``; the classifier's evidence ``classes`` at window ends
    ``window_t_s`` (n,), with the window features ``window_X`` (n, 14) and ``window_ood`` (n,); ``resume``: by
    filter method name, the state its run over the previous segment of a long walk ended the segment in
    (:class:`~models.fusion.ekf.FilterResume`, :mod:`walks.segments`), empty for a walk fused whole."""

    data: WalkData
    events: EventStream
    window_t_s: np.ndarray
    window_X: np.ndarray
    classes: ClassTrack
    window_ood: np.ndarray
    resume: dict = field(default_factory=dict)
    ood_before: bool = False
    """Whether the window in force before the first (a long walk's cut: the one its class state was handed at,
    :class:`ClassResume`) was out of the classifier's distribution; False for the prior."""
    X_before: np.ndarray | None = None
    """That window's features (14,), None for the prior (no window)."""

    def ood_at(self, t_s: np.ndarray) -> np.ndarray:
        """Whether the window in force at each of ``t_s`` (m,) was out of the classifier's distribution (m,);
        before the first complete window :attr:`ood_before` (False: the prior is in force then)."""
        flags = np.concatenate([[self.ood_before], np.asarray(self.window_ood, bool)])
        return flags[np.clip(self.classes.row_at(t_s), 0, len(flags) - 1)]


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


def split_steps(t_s: np.ndarray, length_m: np.ndarray, heading_rad: np.ndarray,
                fix_t_s: np.ndarray, duration_s: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each step spread over the time it took, cut at the fixes that fall inside it.

    A step is detected at its heel strike, but the walker covered it during the
    preceding step period, while GNSS (5 Hz) kept measuring. Predicting the
    whole step at the heel strike would hold the state still between steps and
    then jump a full step past fixes that already saw the motion. So step k
    (from the previous heel strike, or :data:`TYPICAL_STEP_S` before it after a
    stop, to ``t_k``) becomes sub-steps ending at each fix time inside it and at
    ``t_k``, of lengths proportional to their durations, same heading. The cost
    is a fixed lag of one step (≤ ~0.6 s): a fix is fused once the step it falls
    in has ended. ``duration_s`` (n,): each step's own duration where the source states it (odometry's
    segments), replacing the previous heel strike and :data:`TYPICAL_STEP_S`.

    Returns (t_s, step_length_m, heading_rad) of the sub-steps, in time order.
    """
    t_s, length_m, heading_rad = (np.asarray(a, float) for a in (t_s, length_m, heading_rad))
    if t_s.size == 0:
        return t_s, length_m, heading_rad
    fix = np.sort(np.asarray(fix_t_s, float))
    prev = np.concatenate([[-np.inf], t_s[:-1]])
    start = np.where(t_s - prev > STAND_GAP_S, t_s - TYPICAL_STEP_S, prev)
    if duration_s is not None:
        start = np.maximum(t_s - np.asarray(duration_s, float), prev)
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


def gnss_events(p) -> GnssEvents:
    """The reader's fixes (:class:`features.gnss.positions.GnssPositions`) as filter events: the covariance the
    reader reports (its full east/north covariance when it has one, else σ per axis: GST's east and north σ
    when the receiver sent GST, else the C/N0 or table model), the GGA quality, the HDOP the receiver gave
    (NaN where the reader only assumed one) and the GST σ (NaN where there was none), so a quality-aware
    policy can tell a receiver's own belief from the reader's model."""
    n = len(p.t_s)
    if p.cov_en_m2 is not None:
        cov = np.asarray(p.cov_en_m2, float)
    else:
        se = p.sigma_east_m if p.sigma_east_m is not None else p.sigma_en_m
        sn = p.sigma_north_m if p.sigma_north_m is not None else p.sigma_en_m
        se, sn = np.where(np.isfinite(se), se, p.sigma_en_m), np.where(np.isfinite(sn), sn, p.sigma_en_m)
        cov = np.zeros((n, 2, 2))
        cov[:, 0, 0], cov[:, 1, 1] = se ** 2, sn ** 2
    gst = np.full((n, 2), np.nan)
    if p.sigma_source is not None and p.sigma_east_m is not None and p.sigma_north_m is not None:
        g = np.asarray(p.sigma_source) == "gst"
        gst[g, 0], gst[g, 1] = p.sigma_east_m[g], p.sigma_north_m[g]
    return GnssEvents(p.t_s, p.east_m, p.north_m, cov, quality=p.quality,
                      hdop=np.where(p.hdop_assumed, np.nan, p.hdop), gst_sigma_m=gst)


def _stands(step_t: np.ndarray, end_s: float, start_s: float | None = None,
            last_step_s: float | None = None) -> StandIntervals:
    """Standing between steps more than :data:`STAND_GAP_S` apart, and after the last step when the record
    (``end_s``, its last IMU sample) goes on for more than that: a stop is standing whether or not a step
    follows it in the record (so a long walk's cut that ends in a stop stands where the whole walk does).

    ``start_s``: the record is a later cut of a long walk (its first IMU sample): a stop is standing whether
    or not a step precedes it in the cut either, so the cut's start stands up to its first step (the whole
    cut when it holds none) when that is more than :data:`STAND_GAP_S` away. The whole walk stood there too
    (its last step before lies before the cut, whose warm-up the segment's own events follow): a walker
    standing through more than a cut's warm-up (walks/segments.py) gets the whole walk's standing noise.
    None (a walk read whole, or from its start): nothing stands before the first step, as before.

    ``last_step_s``: the walk's last step before the cut's segment (:attr:`EventsResume.last_step_t_s`; −inf:
    none), which replaces ``start_s``: it stands before the cut's steps where it lies further back than their
    first, so the cut stands from where the whole walk does (0.5 s after that step; from nowhere before the
    walk's first step), a stop that began before the cut's warm-up included."""
    if last_step_s is not None:
        start_s = None
        if math.isfinite(last_step_s) and (step_t.size == 0 or last_step_s < step_t[0] - SAME_STEP_S):
            step_t = np.r_[last_step_s, step_t]
    start, end = np.zeros(0), np.zeros(0)
    if step_t.size >= 2:
        gaps = np.flatnonzero(np.diff(step_t) > STAND_GAP_S)
        start, end = step_t[gaps] + 0.5, step_t[gaps + 1] - 0.5
    if step_t.size >= (2 if last_step_s is None else 1) and end_s - step_t[-1] > STAND_GAP_S:
        start, end = np.r_[start, step_t[-1] + 0.5], np.r_[end, end_s]
    if start_s is not None:
        if step_t.size == 0:
            return StandIntervals(np.array([start_s]), np.array([end_s])) if end_s > start_s else \
                StandIntervals(np.zeros(0), np.zeros(0))
        if step_t.size == 1 and end_s - step_t[-1] > STAND_GAP_S:
            start, end = np.r_[start, step_t[-1] + 0.5], np.r_[end, end_s]
        if step_t[0] - start_s > STAND_GAP_S:
            start, end = np.r_[start_s, start], np.r_[step_t[0] - 0.5, end]
    return StandIntervals(start, end)


def _usable_steps(r) -> np.ndarray:
    """Which PDR steps (:class:`~features.imu.pdr.PdrResult`) the filters take: those with a length and a heading.
    One rule for the walk's step events and for the last step a segment hands on (:func:`events_state_before`)."""
    return np.isfinite(r.heading_rad) & np.isfinite(r.step_length_m)


def _imu_holes(imu) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) of the spans, longer than :data:`STAND_GAP_S`, where the IMU record holds no measured sample:
    the holes the reader filled on its grid (``valid`` False; :mod:`features.imu.reader`). No step can be found
    there, so a gap between steps across one is no evidence of standing."""
    bad = ~np.asarray(imu.valid, bool)
    if not bad.any():
        return np.zeros(0), np.zeros(0)
    edge = np.diff(np.r_[0, bad.astype(np.int8), 0])
    first, stop = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)       # stop: the first valid after a run
    t = np.asarray(imu.t_s, float)
    dt = 1.0 / float(imu.rate_hz)
    start = t[first]
    end = np.where(stop < t.size, t[np.minimum(stop, t.size - 1)], t[-1] + dt)
    keep = end - start > STAND_GAP_S
    return start[keep], end[keep]


def _without(stands: StandIntervals, hole_start: np.ndarray, hole_end: np.ndarray) -> StandIntervals:
    """``stands`` less the spans [hole_start, hole_end) (an IMU record's holes, :func:`_imu_holes`)."""
    if not hole_start.size or not stands.start_s.size:
        return stands
    out_a, out_b = [], []
    for a, b in zip(stands.start_s.tolist(), stands.end_s.tolist()):
        for hs, he in zip(hole_start.tolist(), hole_end.tolist()):
            if he <= a or hs >= b:
                continue
            if hs > a:
                out_a.append(a)
                out_b.append(hs)
            a = max(a, he)
            if a >= b:
                break
        if a < b:
            out_a.append(a)
            out_b.append(b)
    return StandIntervals(np.array(out_a), np.array(out_b))


def _odometry_steps(r, fix_t: np.ndarray) -> tuple[StepEvents, StandIntervals]:
    """Odometry events (:class:`~features.vehicle.odometry.DeadReckoning`) as steps with their own noise, split at
    the fixes over their own segments; standing wherever no segment runs.

    A sub-step of a share f of its event's segment takes σ_L·√f (the segment's length is an integral of
    speed over time, its noise spread evenly) and the white part of the event's heading, ½σ_Δψ (the
    segment's heading is ψ + ½Δψ; the accumulated Σ Δψ is the filter's heading-offset random walk).
    """
    t, seg = r.t_s, r.segment_s
    st, sl, sh = split_steps(t, r.step_length_m, r.heading_rad, fix_t, seg)
    parent = np.searchsorted(t, st, side="left")
    frac = np.divide(sl, r.step_length_m[parent], out=np.ones_like(sl), where=r.step_length_m[parent] > 0)
    steps = StepEvents(st, sl, sh, sigma_length_m=r.sigma_step_length_m[parent] * np.sqrt(frac),
                       sigma_heading_rad=0.5 * r.sigma_heading_increment_rad[parent])
    gap_start, gap_end = t[:-1], (t - seg)[1:]
    still = gap_end - gap_start > 1e-6
    return steps, StandIntervals(gap_start[still], gap_end[still])


CLASS_SMOOTHING = ("none", "forward", "forward_backward")
"""How the window classes are smoothed along a walk by the fusion model's class HMM
(:class:`models.temporal.ClassHMM`): not at all, causally (``run``), or with the whole walk (``evaluate``)."""


@dataclass(frozen=True)
class ClassResume:
    """The class HMM's forward state a long walk's segment hands the next (:mod:`walks.segments`): the filtered
    probabilities ``proba`` (k,) of the window ending at ``t_end_s``, the last window ending before the next
    segment's start, whether that window was out of the classifier's distribution (``ood``) and its features
    ``X`` (14,) (None: not stated)."""

    t_end_s: float
    proba: np.ndarray
    ood: bool = False
    X: np.ndarray | None = None


@dataclass(frozen=True)
class EventsResume:
    """What a long walk's event stream held before a segment's start, for the next segment's cut
    (:mod:`walks.segments`): ``last_event_t_s``, the time of its last event (−inf: none), and ``last_step_t_s``,
    of its last PDR step (−inf: the walk had none yet). A cut whose warm-up holds no event (every stream silent
    longer than the warm-up across the seam) takes its first event's time since the previous one, and the
    standing time within it, from them (:func:`walk_inputs`), as the whole walk's stream does; before, that
    event's Δt was 0 and the segment parted from the whole walk by up to 9.6 m after a 48 s silence."""

    last_event_t_s: float
    last_step_t_s: float


def events_state_before(inputs: "WalkInputs", t_s: float, got: EventsResume | None = None) -> EventsResume:
    """The :class:`EventsResume` of ``inputs``' stream before walk time ``t_s``; ``got``: what the segment was
    handed, which goes on where its cut holds no event (or no step) before ``t_s``; without it, the cut is the
    walk's first and nothing came before it."""
    ev = inputs.events
    e = ev.t_s[ev.t_s < t_s]
    pdr = inputs.data.pdr
    steps = np.zeros(0)
    if pdr is not None and len(pdr.result):
        steps = pdr.result.t_s[_usable_steps(pdr.result)]
        steps = steps[steps < t_s]
    before = got if got is not None else EventsResume(-math.inf, -math.inf)
    return EventsResume(float(e[-1]) if e.size else before.last_event_t_s,
                        float(steps[-1]) if steps.size else before.last_step_t_s)


def class_state_before(inputs: "WalkInputs", t_s: float) -> ClassResume | None:
    """The forward class probabilities of the last window of ``inputs`` ending before ``t_s`` (None: no window
    ends before it)."""
    i = int(np.searchsorted(inputs.window_t_s, t_s, side="left")) - 1
    if i < 0:
        return None
    return ClassResume(float(inputs.window_t_s[i]), inputs.classes.proba[1 + i].copy(), bool(inputs.window_ood[i]),
                       inputs.window_X[i].copy())


def smooth_classes(proba: np.ndarray, t_end_s: np.ndarray, answered: np.ndarray, classifier, temporal,
                   smoothing: str, resume: ClassResume | None = None) -> np.ndarray:
    """The window probabilities (n, k) after the class HMM ``temporal``: ``"forward"`` filtered (causal: a
    window's output uses no later window), ``"forward_backward"`` smoothed over the walk, ``"none"`` (or no
    HMM) unchanged. ``answered`` (n,): windows some sub-model classified; the others are no evidence
    (uniform likelihood). Windows further apart than one hop are joined by the matrix power.

    ``resume`` (``"forward"`` only): the filtered probabilities a run over the walk up to the window ending at
    ``resume.t_end_s`` reached (:func:`class_state_before`, a long walk's previous segment): that window takes
    them and the windows after it are filtered on from them (Rabiner 1989 eq. 20 from α̂ of that window), so
    from there on they are the whole walk's; the windows before it are filtered from the start distribution
    as usual (a warm-up)."""
    if smoothing not in CLASS_SMOOTHING:
        raise ConfigError(f"class smoothing must be one of {CLASS_SMOOTHING}, got {smoothing!r}")
    if temporal is None or smoothing == "none" or len(proba) == 0:
        return proba
    from models.temporal import scaled_likelihood

    b = scaled_likelihood(proba, classifier.fit_prior())
    b[~np.asarray(answered, bool)] = 1.0
    t_end_s = np.asarray(t_end_s, float)
    steps = np.ones(len(proba), int)
    steps[1:] = np.maximum(np.rint(np.diff(t_end_s) / temporal.hop_s_).astype(int), 1)
    if smoothing == "forward_backward":
        return temporal.forward_backward(b, steps)
    if resume is None:
        return temporal.forward(b, steps)
    # windows up to the handed one: the warm-up; the handed one takes the state; the rest filter on from it
    j = int(np.searchsorted(t_end_s, resume.t_end_s + 1e-6, side="left"))
    out = np.empty_like(b)
    if j:
        out[:j] = temporal.forward(b[:j], steps[:j])
        if abs(t_end_s[j - 1] - resume.t_end_s) < 1e-6:
            out[j - 1] = resume.proba
    if j < len(b):
        later = steps[j:].copy()
        later[0] = max(int(np.rint((t_end_s[j] - resume.t_end_s) / temporal.hop_s_)), 1)
        out[j:] = temporal.forward(b[j:], later, prev=np.asarray(resume.proba, float))
    return out


def _cut_to_s(data: WalkData) -> float:
    """Where a long walk's cut's IMU record ends (``[imu] cut_to_s``, :mod:`walks.segments`); −inf for a walk read
    whole."""
    value = data.walk.streams.get("imu", {}).get("cut_to_s", -math.inf)
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{data.walk.directory / 'walk.toml'}: [imu] cut_to_s must be a number, got {value!r} "
                          f"(a long walk's cut states it)") from None


def walk_inputs(data: WalkData, classifier, temporal=None, smoothing: str = "forward",
                class_resume: ClassResume | None = None, resumed: bool = False,
                events_resume: EventsResume | None = None) -> WalkInputs:
    """Events and class evidence of one walk (see the module docstring); ``classifier``: the online
    :class:`~models.environment.EnvironmentClassifier`; ``temporal``: the class HMM
    (:class:`models.temporal.ClassHMM`, None: each window on its own) applied as ``smoothing``
    (:func:`smooth_classes`, resumed from ``class_resume``: a long walk's previous segment's). ``resumed``:
    ``data`` is a later cut of a long walk whose filters resume the previous segment's (:mod:`walks.segments`):
    its start stands up to its first step (:func:`_stands`); ``events_resume``: what the whole walk's stream held
    before the cut's segment (:class:`EventsResume`), from which its stands run and, when the cut holds no
    event before its segment, its first event's Δt."""
    last_step = None if events_resume is None else events_resume.last_step_t_s
    steps = gnss = acoustic = stands = None
    fix_t = np.concatenate([data.gnss.positions.t_s if data.gnss is not None else np.zeros(0),
                            data.acoustic.t_s if data.acoustic is not None else np.zeros(0)])
    if isinstance(data.pdr, OdometryStream) and len(data.pdr.result):
        steps, stands = _odometry_steps(data.pdr.result, fix_t)
    elif data.pdr is not None and len(data.pdr.result):
        r = data.pdr.result
        ok = _usable_steps(r)
        end = data.pdr.imu.t_s[-1] if data.pdr.imu is not None and len(data.pdr.imu.t_s) else r.t_s[-1]
        # a long walk's cut: its IMU record runs to the cut's end (or the walk's IMU's), past a hole at its end
        end = max(end, _cut_to_s(data))
        first = data.pdr.imu.t_s[0] if data.pdr.imu is not None and len(data.pdr.imu.t_s) else None
        stands = _stands(r.t_s[ok], float(end), float(first) if resumed and first is not None else None, last_step)
        if data.pdr.imu is not None and len(data.pdr.imu.t_s):
            # a hole in the IMU log is not a stop: the walker may have walked through it unseen
            stands = _without(stands, *_imu_holes(data.pdr.imu))
        steps = StepEvents(*split_steps(r.t_s[ok], r.step_length_m[ok], r.heading_rad[ok], fix_t))
    elif resumed and getattr(data.pdr, "imu", None) is not None and len(data.pdr.imu.t_s):
        # a later cut of a long walk without a step: the walker stands through it, as in the whole walk
        end = max(float(data.pdr.imu.t_s[-1]), _cut_to_s(data))
        stands = _without(_stands(np.zeros(0), end, float(data.pdr.imu.t_s[0]), last_step), *_imu_holes(data.pdr.imu))
    if data.gnss is not None and len(data.gnss.positions):
        gnss = gnss_events(data.gnss.positions)
    if data.acoustic is not None and len(data.acoustic.t_s):
        a = data.acoustic
        acoustic = AcousticEvents(a.t_s, a.east_m, a.north_m, a.covariance_en_m2)
    if resumed and not any(src is not None and len(src) for src in (steps, gnss, acoustic)):
        raise SilentCut(f"{data.walk.directory}: no event in the cut (no step, GNSS or acoustic fix)")
    t0 = None
    if events_resume is not None and math.isfinite(events_resume.last_event_t_s):
        first = min((float(src.t_s[0]) for src in (steps, gnss, acoustic) if src is not None and len(src)),
                    default=math.inf)
        t0 = events_resume.last_event_t_s if events_resume.last_event_t_s < first else None
    events = merge_events(steps=steps, gnss=gnss, acoustic=acoustic, stands=stands, t0_s=t0)
    t_end, X = window_features(data)
    if len(t_end):
        proba = classifier.predict_proba(X)
        ood = classifier.is_ood(X)
        proba = smooth_classes(proba, t_end, classifier.answers(X), classifier, temporal, smoothing, class_resume)
    else:
        proba, ood = np.tile(classifier.prior_, (1, 1)), np.ones(1, bool)
        if class_resume is not None and smoothing == "forward":
            # a cut without a window of its own: the whole walk's last one stays in force through it
            proba, ood = np.asarray(class_resume.proba, float)[None, :], np.array([bool(class_resume.ood)])
        t_end = np.array([events.t_s[0]])
    # Before the first complete window the filter knows nothing of the environment: the prior. A long walk's cut
    # whose first window ends after the one its class state was handed at (no window in its warm-up: every
    # stream silent across the seam) has that window's in force until then, as the whole walk has.
    t_cls = np.concatenate([[min(events.t_s[0], t_end[0]) - 1.0], t_end])
    before, ood_before, X_before = classifier.prior_, False, None
    if class_resume is not None and smoothing == "forward" and class_resume.t_end_s < t_end[0] - 1e-6:
        before, ood_before, X_before = np.asarray(class_resume.proba, float), bool(class_resume.ood), class_resume.X
    proba = np.vstack([before, proba])
    return WalkInputs(data=data, events=events, window_t_s=t_end, window_X=X,
                      classes=ClassTrack(t_cls, proba), window_ood=ood, ood_before=ood_before, X_before=X_before)
