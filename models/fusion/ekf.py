"""The event-driven extended Kalman filter: PDR steps predict, GNSS and acoustic fixes update.

State (n = 4, or 6 with ``gnss_bias``)::

    x = [east_m, north_m, δψ_rad, s, (b_east_m, b_north_m)]

δψ is the PDR heading offset (true heading ψ + δψ, mounting yaw and slow
gyro drift), s the step-scale error (true length (1 + s)·L), b a GNSS bias
for correlated multi-second errors (NLOS, multipath), first-order
Gauss–Markov with time constant τ: b_k = φ·b_{k−1} + w, φ = e^(−Δt/τ),
Var w = σ_b²(1 − φ²) (Gelb 1974, *Applied Optimal Estimation*, ch. 3). The bias is observable only because
acoustic fixes and PDR do not share it; with GNSS alone it trades with the
position, which the prior σ_b bounds.

Per event (Δt since the previous one, of which Δt_stand standing) the
stationary model adds a position random walk
(q_walk·(Δt − Δt_stand) + q_stand·Δt_stand), random walks on δψ and s and
the bias decay, so events of any rate fuse without resampling; a step then
moves the state, a fix updates it. The equations, the Joseph form and the
outlier handling (``outlier``: ``"gate"`` — the χ² validation gate of
Bar-Shalom, Li & Kirubarajan 2001, ch. 5; ``"huber"`` — Huber (1964) weights
applied as R/w; ``"mixture"`` — each fix's ε-contaminated likelihood from the
noise policy, :func:`models.fusion.core.mixture_update`; ``"none"``) are those of
the one compiled filter core,
:mod:`models.fusion.core`; this module builds its inputs (Q, Φ, H per event,
R from the noise policy) and its records.

``joseph=False`` switches to the short form P = (I − KH)P, symmetrised: equal
for the optimal gain up to rounding, but without the Joseph form's guarantee
of a PD P when the gain is perturbed. ``consider_bias`` makes the bias states
Schmidt consider states (Schmidt 1966; Petovello et al. 2009): their
uncertainty is carried into every update, their value never estimated.

The GNSS bias block follows the noise policy's process when it models one
(:class:`~models.fusion.context.ContextNoise`: σ_b and τ per quality and
class, shared only by the fixes of biased qualities, reset on a quality
change or a gap), else the config's single process shared by every GNSS fix
(``gnss_bias``).

Written on its own core rather than ``filterpy.kalman.ExtendedKalmanFilter``:
the predict is a control-driven step whose Jacobian and Q change per event, H
and R change per event, every update must be recorded (K, ν, S, NIS,
posterior − prior, acceptance), and filterpy's ``KalmanFilter`` takes ~36 µs
per predict + update on the project machine (bench/bench_fusion.py gives the
core's figure). The update agrees with ``filterpy.kalman.KalmanFilter.update``
(also Joseph form) to rounding (tests/test_filters.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from features.errors import EnvfuseError
from models.fusion.events import GNSS, STEP, EventStream

__all__ = ["EkfConfig", "FilterRun", "FilterResume", "EventEKF", "FilterError", "empty_records", "initial_state", "time_noise",
           "measurement_models", "step_variances", "OUTLIER_CODES"]


OUTLIER_CODES = {"gate": 0, "huber": 1, "none": 2, "mixture": 3}
"""Codes of :attr:`EkfConfig.outlier` in the compiled core (:data:`models.fusion.core.GATE` ...); ``mixture``
needs a noise policy that gives each fix's contamination (:class:`models.fusion.context.ContextNoise`)."""


class FilterError(EnvfuseError, ValueError):
    """A filter parameter is out of range, or a run cannot start."""


@dataclass(frozen=True)
class EkfConfig:
    """Process-noise, prior and outlier settings (units in the names; q are per second of walk time)."""

    sigma_step_length_m: float = 0.05
    sigma_heading_rad: float = 0.03
    q_heading_rad2_s: float = 1e-6
    q_scale_1_s: float = 1e-7
    q_walk_m2_s: float = 1e-3
    q_stand_m2_s: float = 1e-5
    sigma0_pos_m: float = 5.0
    sigma0_heading_rad: float = 0.3
    sigma0_scale: float = 0.1
    outlier: str = "gate"
    gate_prob: float = 0.999
    huber_k: float = 2.5
    joseph: bool = True
    gnss_bias: bool = False
    bias_sigma_m: float = 1.5
    bias_tau_s: float = 30.0
    consider_bias: bool = False

    def __post_init__(self):
        for name in ("sigma_step_length_m", "sigma_heading_rad", "q_heading_rad2_s", "q_scale_1_s", "q_walk_m2_s",
                     "q_stand_m2_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise FilterError(f"{name} must be finite and >= 0, got {v}")
        for name in ("sigma0_pos_m", "sigma0_heading_rad", "sigma0_scale", "huber_k", "bias_sigma_m", "bias_tau_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise FilterError(f"{name} must be finite and > 0, got {v}")
        if self.outlier not in OUTLIER_CODES:
            raise FilterError(f"outlier must be one of {sorted(OUTLIER_CODES)}, got {self.outlier!r}")
        if not 0 < self.gate_prob < 1:
            raise FilterError(f"gate_prob must lie in (0, 1), got {self.gate_prob}")

    @property
    def n_state(self) -> int:
        return 6 if self.gnss_bias else 4

    @property
    def gate_nis(self) -> float:
        """χ²₂ quantile of ``gate_prob``, the NIS above which a fix is rejected: −2 ln(1 − p)
        (the χ² distribution with 2 degrees of freedom is exponential with mean 2)."""
        return -2.0 * math.log1p(-self.gate_prob)


@dataclass(frozen=True)
class FilterResume:
    """A filter's posterior ``x`` (n,), ``P`` (n, n) after its last event before walk time ``t_s``
    (:meth:`FilterRun.state_before`): what a run over a later piece of the same event stream (a long walk's next
    segment, :mod:`walks.segments`) restarts from at its first event at or after ``t_s``, so that from there on
    it is the run over the whole stream.

    What else the filter carries from event to event, when it has it: ``vb_alpha``, ``vb_beta`` (3, 2) the
    variational-Bayes noise estimate (:class:`~models.fusion.noise.VBAdaptiveNoise`, ``aekf``); ``mode_x``
    (M, n), ``mode_P`` (M, n, n), ``mode_proba`` (M,) the per-mode states and mode probabilities of the IMM
    (:class:`~models.fusion.imm.IMMFilter`); ``rejected_in_row`` the fixes gated in a row before it (the UWB
    filter's reset count, :class:`models.uwb_pdr.UwbPdrFilter`); ``event_t_s`` the time of the event the state
    follows; ``nis_t_s``, ``nis`` (k,) the times and NIS of the run's events in the ``history_s`` before ``t_s``
    (:meth:`FilterRun.state_before`): what the covariance calibrator's running means of the NIS read back over
    (:func:`walks.calibrate.track_inputs`), where the later run's own first events are its warm-up's."""

    t_s: float
    x: np.ndarray
    P: np.ndarray
    vb_alpha: np.ndarray | None = None
    vb_beta: np.ndarray | None = None
    mode_x: np.ndarray | None = None
    mode_P: np.ndarray | None = None
    mode_proba: np.ndarray | None = None
    event_t_s: float = math.nan
    rejected_in_row: int = 0
    nis_t_s: np.ndarray | None = None
    nis: np.ndarray | None = None


@dataclass
class FilterRun:
    """Everything a filter run produced, one row per event of the stream (m events, n states).

    ``x_prior``, ``x`` : (m, n) prior and posterior; ``P_prior``, ``P`` : (m, n, n);
    ``F`` : (m, n, n) Jacobian from the previous posterior to this prior (the first from ``x0``, ``P0``);
    per update (NaN elsewhere): ``nu`` (m, 2) innovation, ``S`` (m, 2, 2), ``K`` (m, n, 2) gain,
    ``R`` (m, 2, 2) noise used, ``nis`` (m,), ``weight`` (m,) Huber weight (1 full, 0 rejected);
    ``updated`` (m,) bool: an available fix was processed; ``accepted`` (m,) bool: it changed the state;
    ``mode_proba`` (m, n_modes) for multiple-model runs, else None; ``mode_x`` (m, n_modes, n), ``mode_P``
    (m, n_modes, n, n) their per-mode posteriors; ``vb_alpha``, ``vb_beta`` (m, 3, 2) the VB-AKF's noise
    estimate after each event (None for other filters). These are what :meth:`state_before` hands a run over a
    later piece of the stream besides x and P.
    """

    method: str
    t_s: np.ndarray
    kind: np.ndarray
    x0: np.ndarray
    P0: np.ndarray
    x_prior: np.ndarray
    P_prior: np.ndarray
    F: np.ndarray
    x: np.ndarray
    P: np.ndarray
    nu: np.ndarray
    S: np.ndarray
    K: np.ndarray
    R: np.ndarray
    nis: np.ndarray
    weight: np.ndarray
    updated: np.ndarray
    accepted: np.ndarray
    available: np.ndarray
    mode_proba: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    mode_x: np.ndarray | None = None
    mode_P: np.ndarray | None = None
    vb_alpha: np.ndarray | None = None
    vb_beta: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def dx(self) -> np.ndarray:
        """Posterior − prior, (m, n) (zero where nothing was accepted)."""
        return self.x - self.x_prior

    @property
    def east_m(self) -> np.ndarray:
        return self.x[:, 0]

    @property
    def north_m(self) -> np.ndarray:
        return self.x[:, 1]

    def pos_cov_m2(self) -> np.ndarray:
        """Posterior position covariance, (m, 2, 2)."""
        return self.P[:, :2, :2]

    def state_before(self, t_s: float, history_s: float = 0.0) -> FilterResume | None:
        """The posterior after the last event before ``t_s`` (None when no event precedes it), with the NIS of
        the events in the ``history_s`` before ``t_s``."""
        i = int(np.searchsorted(self.t_s, t_s, side="left")) - 1
        if i < 0:
            return None
        lo = int(np.searchsorted(self.t_s, t_s - history_s, side="left"))

        def row(a):
            return None if a is None else a[i].copy()

        rejected = self.info.get("rejected_in_row")
        return FilterResume(float(t_s), self.x[i].copy(), self.P[i].copy(), row(self.vb_alpha), row(self.vb_beta),
                            row(self.mode_x), row(self.mode_P), row(self.mode_proba), float(self.t_s[i]),
                            0 if rejected is None else int(rejected[i]), self.t_s[lo:i + 1].copy(),
                            self.nis[lo:i + 1].copy())


def empty_records(m: int, n: int) -> dict:
    """The record arrays of a :class:`FilterRun` for m events and n states (F the identity, NaN where no
    update)."""
    eye = np.broadcast_to(np.eye(n), (m, n, n)).copy()
    nan = np.nan
    return dict(x_prior=np.empty((m, n)), P_prior=np.empty((m, n, n)), F=eye, x=np.empty((m, n)),
                P=np.empty((m, n, n)), nu=np.full((m, 2), nan), S=np.full((m, 2, 2), nan),
                K=np.full((m, n, 2), nan), R=np.full((m, 2, 2), nan), nis=np.full(m, nan), weight=np.full(m, nan),
                updated=np.zeros(m, bool), accepted=np.zeros(m, bool))


def initial_state(stream: EventStream, cfg: EkfConfig, x0_en=None, x0=None, P0=None,
                  n_state: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Prior (x0 (n,), P0 (n, n)): ``x0``/``P0`` as given, else the position ``x0_en`` (default: the first
    available fix) with the configured σ0 of each state (bias states: ``bias_sigma_m``)."""
    n = cfg.n_state if n_state is None else n_state
    if x0 is not None:
        x0 = np.asarray(x0, float).copy()
        if x0.shape != (n,):
            raise FilterError(f"x0 must have shape ({n},), got {x0.shape}")
    else:
        if x0_en is None:
            fixes = np.flatnonzero(stream.available)
            if fixes.size == 0:
                raise FilterError("no initial position: give x0_en, or a stream with at least one available fix")
            x0_en = stream.z_m[fixes[0]]
        x0 = np.zeros(n)
        x0[:2] = x0_en
    if P0 is not None:
        P0 = np.asarray(P0, float).copy()
        if P0.shape != (n, n):
            raise FilterError(f"P0 must have shape ({n}, {n}), got {P0.shape}")
    else:
        d = [cfg.sigma0_pos_m ** 2] * 2 + [cfg.sigma0_heading_rad ** 2, cfg.sigma0_scale ** 2]
        d += [cfg.bias_sigma_m ** 2] * (n - 4)
        P0 = np.diag(d)
    return x0, P0


def step_variances(stream: EventStream, cfg: EkfConfig) -> tuple[float, float]:
    """(σ_L² (m²), σ_ψ² (rad²)) of a step for the compiled core: the configured ones, or, when the stream's
    steps state their own σ (:class:`~models.fusion.events.StepEvents`, e.g. odometry from its variances), the
    mean of their squares — the core takes one value per run, and the mean gives the walk's steps the same
    summed variance as their own values would."""
    s = stream.steps
    sl2, sp2 = cfg.sigma_step_length_m ** 2, cfg.sigma_heading_rad ** 2
    if s is not None and len(s):
        if s.sigma_length_m is not None:
            sl2 = float(np.mean(s.sigma_length_m ** 2))
        if s.sigma_heading_rad is not None:
            sp2 = float(np.mean(s.sigma_heading_rad ** 2))
    return sl2, sp2


def has_bias(cfg: EkfConfig, spec=None) -> bool:
    """Whether the state carries the GNSS bias block: asked for by the config, or modelled by the noise policy."""
    return bool(cfg.gnss_bias or (spec is not None and spec.bias_shared is not None))


def time_noise(stream: EventStream, cfg: EkfConfig, spec=None) -> tuple[np.ndarray, np.ndarray]:
    """Per event the diagonals of the time update's Q and Φ, both (m, n) (see :func:`models.fusion.core.time_update`).

    The GNSS bias block follows the noise policy's process when it gives one (``spec.bias_phi``,
    ``bias_q``: per quality and class, with resets), else the config's one Gauss–Markov process."""
    dt = stream.dt_s
    st = stream.dt_stand_s
    m, n = dt.shape[0], 4 + 2 * has_bias(cfg, spec)
    q = np.zeros((m, n))
    phi = np.ones((m, n))
    # Q_pos = q_walk·(Δt − Δt_stand) + q_stand·Δt_stand
    q[:, 0] = q[:, 1] = cfg.q_walk_m2_s * (dt - st) + cfg.q_stand_m2_s * st
    # Q_δψ = q_ψ·Δt,  Q_s = q_s·Δt   (random walks)
    q[:, 2] = cfg.q_heading_rad2_s * dt
    q[:, 3] = cfg.q_scale_1_s * dt
    if n > 4 and spec is not None and spec.bias_phi is not None:
        phi[:, 4] = phi[:, 5] = spec.bias_phi
        q[:, 4] = q[:, 5] = spec.bias_q
    elif n > 4:
        # φ = e^(−Δt/τ);  Q_b = σ_b²·(1 − φ²)   (first-order Gauss–Markov)
        decay = np.exp(-dt / cfg.bias_tau_s)
        phi[:, 4] = phi[:, 5] = decay
        q[:, 4] = q[:, 5] = cfg.bias_sigma_m ** 2 * (1.0 - decay * decay)
    return q, phi


def measurement_models(stream: EventStream, cfg: EkfConfig, spec=None) -> tuple[np.ndarray, np.ndarray]:
    """(H (n_models, 2, n), model index per event (m,)): the position rows for every fix, plus the bias block
    for the GNSS fixes that share the bias (the policy's ``bias_shared``, else every GNSS fix when the config
    asks for ``gnss_bias``); acoustic fixes never share it."""
    n = 4 + 2 * has_bias(cfg, spec)
    h = np.zeros((2, n))
    h[0, 0] = h[1, 1] = 1.0
    hg = h.copy()
    if n > 4:
        hg[0, 4] = hg[1, 5] = 1.0
    if spec is not None and spec.bias_shared is not None:
        shares = np.asarray(spec.bias_shared, bool)
    else:
        shares = (stream.kind == GNSS) & (n > 4)
    return np.stack([h, hg]), shares.astype(np.int64)


def _restart(stream: EventStream, resume: FilterResume | None, x0: np.ndarray, P0: np.ndarray) -> tuple:
    """(event index, x, P) the core restarts from: ``resume`` at the stream's first event at or after its time,
    or (−1, x0, P0) without one (or when no event follows it)."""
    if resume is None:
        return -1, x0, P0
    if resume.x.shape != x0.shape or resume.P.shape != P0.shape:
        raise FilterError(f"cannot resume a filter of {x0.shape[0]} states from one of {resume.x.shape[0]}")
    i = int(np.searchsorted(stream.t_s, resume.t_s, side="left"))
    if i >= len(stream):
        return -1, x0, P0
    return i, np.asarray(resume.x, float), np.asarray(resume.P, float)


class EventEKF:
    """The event-driven EKF with one noise policy (:mod:`models.fusion.noise`, :mod:`models.fusion.adaptive`).

    >>> import numpy as np
    >>> from models.fusion.events import GnssEvents, StepEvents, merge_events
    >>> from models.fusion.noise import FixedNoise
    >>> ev = merge_events(StepEvents(np.arange(1, 5) * 0.5, np.full(4, 0.7), np.zeros(4)),
    ...                   GnssEvents.from_sigma(np.arange(0, 3.0), np.zeros(3), np.array([0.0, 1.4, 2.8]), np.ones(3)))
    >>> run = EventEKF(noise=FixedNoise(1.0, 0.5)).run(ev)
    >>> len(run), bool(run.accepted[run.kind == 1].all())
    (7, True)
    """

    def __init__(self, config: EkfConfig | None = None, noise=None, method: str = "kf", scales: dict | None = None):
        self.config = config
        self.noise = noise
        self.method = method
        self.scales = scales

    def run(self, stream: EventStream, x0_en=None, classes=None, class_at=None, x0=None, P0=None,
            r_scale_event: np.ndarray | None = None, resume: FilterResume | None = None) -> FilterRun:
        """Filter the whole stream once.

        ``x0_en``: (2,) initial east/north (default: the first available fix); ``x0``/``P0``: full prior;
        ``classes``: :class:`~models.fusion.events.ClassTrack` and ``class_at``:
        :class:`~models.fusion.events.ClassMap`, for per-class noise. ``scales`` (at construction):
        ``{"gnss", "acoustic", "bias"}`` multipliers of the policy's R and bias variance (a method's tuning);
        ``r_scale_event`` (m,): a further multiplier of each event's R (the BP parameter network's).
        ``resume``: the state of a run of this filter over an earlier piece of the stream; the events from
        ``resume.t_s`` on continue from it (those before are filtered from the prior as usual, a warm-up),
        the VB-AKF's noise estimate included (a state without one, e.g. another filter's, restarts the
        estimate from the policy's prior there).
        """
        from models.fusion import core
        from models.fusion.noise import FixedNoise

        cfg = self.config or EkfConfig()
        noise = self.noise if self.noise is not None else FixedNoise()
        spec = noise.measurement_noise(stream, classes=classes, class_at=class_at)
        if self.scales:
            spec = spec.scaled(stream.kind, **{k: float(v) for k, v in self.scales.items()
                                               if k in ("gnss", "acoustic", "bias")})
        if r_scale_event is not None:
            f = np.asarray(r_scale_event, float)
            if f.shape != (len(stream),) or not np.all(np.isfinite(f) & (f > 0)):
                raise FilterError(f"r_scale_event must be {len(stream)} positive finite values")
            if spec.r_event.shape[0] != len(stream):
                raise FilterError("r_scale_event needs a noise policy that gives R per event")
            spec = spec.with_fields(r_event=spec.r_event * f[:, None, None])
        if cfg.outlier == "mixture" and spec.eps_event is None:
            raise FilterError(f"outlier='mixture' needs a noise policy that gives each fix's contamination; "
                              f"{type(noise).__name__} does not")
        m = len(stream)
        n = 4 + 2 * has_bias(cfg, spec)
        x, P = initial_state(stream, cfg, x0_en, x0, P0, n_state=n)
        q, phi = time_noise(stream, cfg, spec)
        H, h_idx = measurement_models(stream, cfg, spec)
        consider = np.zeros(n, bool)
        consider[4:] = cfg.consider_bias
        eps = spec.eps_event if spec.eps_event is not None else np.zeros(m)
        kappa = spec.kappa_event if spec.kappa_event is not None else np.ones(m)
        rec = empty_records(m, n)
        sl2, sp2 = step_variances(stream, cfg)
        restart, x_r, P_r = _restart(stream, resume, x, P)
        vb = spec.mode == core.R_VB
        # the VB-AKF's α, β: recorded after every event, and resumed with x and P
        vb_rec = (np.empty((m, 3, 2)), np.empty((m, 3, 2))) if vb else (np.empty((0, 3, 2)), np.empty((0, 3, 2)))
        va_r, vbt_r = spec.vb_alpha.copy(), spec.vb_beta.copy()
        if vb and restart >= 0 and resume.vb_alpha is not None and resume.vb_beta is not None:
            va_r, vbt_r = np.asarray(resume.vb_alpha, float), np.asarray(resume.vb_beta, float)
        core.run_ekf_events(stream.kind.astype(np.int64), stream.available, stream.z_m, stream.step_length_m,
                            stream.heading_rad, phi, q, h_idx, H, x, P, sl2, sp2, OUTLIER_CODES[cfg.outlier], cfg.gate_nis, cfg.huber_k,
                            cfg.joseph, consider, spec.mode, spec.r_event, np.asarray(eps, float),
                            np.asarray(kappa, float), spec.r_table, spec.map_grid, spec.map_geo, spec.vb_alpha,
                            spec.vb_beta, spec.vb_cap, spec.vb_rho, spec.vb_n_iter, rec["x_prior"], rec["P_prior"],
                            rec["F"], rec["x"], rec["P"], rec["nu"], rec["S"], rec["K"], rec["R"], rec["nis"],
                            rec["weight"], rec["updated"], rec["accepted"], restart, x_r, P_r, va_r, vbt_r, *vb_rec)
        # a gated fix leaves no gain
        rec["K"][rec["updated"] & ~rec["accepted"]] = np.nan
        return FilterRun(self.method, stream.t_s, stream.kind, x.copy(), P.copy(), available=stream.available,
                         vb_alpha=vb_rec[0] if vb else None, vb_beta=vb_rec[1] if vb else None, **rec)
