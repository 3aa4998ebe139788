"""Event-driven extended Kalman filter: PDR steps predict, GNSS and acoustic fixes update.

State (n = 4, or 6 with ``gnss_bias``)::

    x = [east_m, north_m, δψ_rad, s, (b_east_m, b_north_m)]

δψ is the PDR heading offset (true heading ψ + δψ, mounting yaw and slow
gyro drift), s the step-scale error (true length (1 + s)·L), b a GNSS bias
for correlated multi-second errors (NLOS, multipath), first-order
Gauss–Markov with time constant τ: b_k = φ·b_{k−1} + w, φ = e^(−Δt/τ),
Var w = σ_b²(1 − φ²) (Gelb 1974, *Applied Optimal Estimation*, ch. 3). The bias is observable only because
acoustic fixes and PDR do not share it; with GNSS alone it trades with the
position, which the prior σ_b bounds.

Prediction per event (Δt since the previous one, of which Δt_stand standing):

* all events: the stationary model, a position random walk
  (q_walk·(Δt − Δt_stand) + q_stand·Δt_stand), random walks on δψ and s,
  the bias decay — so events of any rate fuse without resampling;
* a step of length L and heading ψ, θ = ψ + δψ, g = 1 + s:
  e += g·L·sin θ, n += g·L·cos θ, with the Jacobian F (∂e/∂δψ = g·L·cos θ,
  ∂e/∂s = L·sin θ, ∂n/∂δψ = −g·L·sin θ, ∂n/∂s = L·cos θ) and step noise
  G·diag(σ_L², σ_ψ²)·G' (G = ∂(e, n)/∂(L, ψ)).

Updates by position fixes, H = [I₂ 0 (I₂ for GNSS with a bias state)]. The
covariance update is the Joseph form, P = (I − KH)P(I − KH)' + KRK', which
stays symmetric PD for any gain (Bucy & Joseph 1968; Bar-Shalom, Li &
Kirubarajan 2001, ch. 5). Outliers (``outlier``):

* ``"gate"``: reject a fix whose NIS = ν'S⁻¹ν exceeds the χ²₂ quantile of
  ``gate_prob`` (the validation gate of Bar-Shalom, Li & Kirubarajan 2001, ch. 5);
* ``"huber"``: Huber (1964) weights on the Mahalanobis norm of the
  innovation, w = min(1, k/√NIS), applied as R/w — a bounded influence
  instead of a hard cut (the robust KF of Masreliez & Martin 1977 in its
  usual covariance-inflation form);
* ``"none"``.

``joseph=False`` switches to the short form P = (I − KH)P, symmetrised:
equal for the optimal gain up to rounding, half the arithmetic of the
scalar loop's update, but without the Joseph form's guarantee of a PD P
when the gain is perturbed (Huber-weighted R stays optimal for its own R,
so both apply; the default is Joseph).

Written by hand rather than on ``filterpy.kalman.ExtendedKalmanFilter``: the
predict is a control-driven step whose Jacobian and Q change per event, H
and R change per event, every update must be recorded (K, ν, S, NIS,
posterior − prior, acceptance), and filterpy's ``KalmanFilter`` takes
~36 µs per predict + update on the project machine, about five times the
scalar loop of :mod:`models.fusion.fast`. The update agrees with
``filterpy.kalman.KalmanFilter.update`` (also Joseph form) to rounding
(tests/test_filters.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from features.errors import EnvfuseError
from models.fusion.events import GNSS, STEP, EventStream

__all__ = ["EkfConfig", "FilterRun", "EventEKF", "run_ekf", "FilterError"]


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
        if self.outlier not in ("gate", "huber", "none"):
            raise FilterError(f"outlier must be 'gate', 'huber' or 'none', got {self.outlier!r}")
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


@dataclass
class FilterRun:
    """Everything a filter run produced, one row per event of the stream (m events, n states).

    ``x_prior``, ``x`` : (m, n) prior and posterior; ``P_prior``, ``P`` : (m, n, n);
    ``F`` : (m, n, n) Jacobian from the previous posterior to this prior (the first from ``x0``, ``P0``);
    per update (NaN elsewhere): ``nu`` (m, 2) innovation, ``S`` (m, 2, 2), ``K`` (m, n, 2) gain,
    ``R`` (m, 2, 2) noise used, ``nis`` (m,), ``weight`` (m,) Huber weight (1 full, 0 rejected);
    ``updated`` (m,) bool: an available fix was processed; ``accepted`` (m,) bool: it changed the state;
    ``correction`` (m, 2): a closed-loop corrector's east/north shift added to ``x`` (zeros without one);
    ``mode_proba`` (m, n_modes) for multiple-model runs, else None.
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
    correction: np.ndarray
    available: np.ndarray
    mode_proba: np.ndarray | None = None
    info: dict = field(default_factory=dict)

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


def _records(m: int, n: int) -> dict:
    eye = np.broadcast_to(np.eye(n), (m, n, n)).copy()
    nan = np.nan
    return dict(x_prior=np.empty((m, n)), P_prior=np.empty((m, n, n)), F=eye, x=np.empty((m, n)),
                P=np.empty((m, n, n)), nu=np.full((m, 2), nan), S=np.full((m, 2, 2), nan),
                K=np.full((m, n, 2), nan), R=np.full((m, 2, 2), nan), nis=np.full(m, nan), weight=np.full(m, nan),
                updated=np.zeros(m, bool), accepted=np.zeros(m, bool), correction=np.zeros((m, 2)))


def _initial(stream: EventStream, cfg: EkfConfig, x0_en, x0=None, P0=None):
    n = cfg.n_state
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
        if cfg.gnss_bias:
            d += [cfg.bias_sigma_m ** 2] * 2
        P0 = np.diag(d)
    return x0, P0


def _time_noise(stream: EventStream, cfg: EkfConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per-event diagonal of the stationary-model Q, (m, n), and the bias decay φ, (m,)."""
    dt = stream.dt_s
    st = stream.dt_stand_s
    m, n = dt.shape[0], cfg.n_state
    q = np.zeros((m, n))
    # Q_pos = q_walk·(Δt − Δt_stand) + q_stand·Δt_stand
    q[:, 0] = q[:, 1] = cfg.q_walk_m2_s * (dt - st) + cfg.q_stand_m2_s * st
    # Q_δψ = q_ψ·Δt,  Q_s = q_s·Δt   (random walks)
    q[:, 2] = cfg.q_heading_rad2_s * dt
    q[:, 3] = cfg.q_scale_1_s * dt
    phi = np.exp(-dt / cfg.bias_tau_s)
    if cfg.gnss_bias:
        # Q_b = σ_b²·(1 − φ²)   (first-order Gauss–Markov)
        q[:, 4] = q[:, 5] = cfg.bias_sigma_m ** 2 * (1.0 - phi * phi)
    return q, phi


def _step_predict(x, P, L, psi, cfg, F):
    """Predict one PDR step in place of F (n, n); returns (x⁻, P⁻)."""
    g = 1.0 + x[3]
    th = psi + x[2]
    sn, cs = math.sin(th), math.cos(th)
    gl = g * L
    x = x.copy()
    # e += (1+s)·L·sin(ψ+δψ),  n += (1+s)·L·cos(ψ+δψ)
    x[0] += gl * sn
    x[1] += gl * cs
    # F = ∂f/∂x: ∂e/∂δψ = gL cos θ, ∂e/∂s = L sin θ, ∂n/∂δψ = −gL sin θ, ∂n/∂s = L cos θ
    F[0, 2] = gl * cs
    F[0, 3] = L * sn
    F[1, 2] = -gl * sn
    F[1, 3] = L * cs
    # P⁻ = F P F'
    P = F @ P @ F.T
    # Q_step = G diag(σ_L², σ_ψ²) G',  G = [[g sin θ, gL cos θ], [g cos θ, −gL sin θ]]
    vl = (g * cfg.sigma_step_length_m) ** 2
    vp = (gl * cfg.sigma_heading_rad) ** 2
    P[0, 0] += vl * sn * sn + vp * cs * cs
    P[1, 1] += vl * cs * cs + vp * sn * sn
    c = (vl - vp) * sn * cs
    P[0, 1] += c
    P[1, 0] += c
    return x, P


def _update(x, P, z, R, H, cfg, runner, k, gate_nis):
    """One position update. Returns (x, P, ν, S, K, R_used, nis, weight, accepted)."""
    n = x.shape[0]
    # ν = z − H x⁻
    nu = z - H @ x
    PHt = P @ H.T
    HPH = H @ PHt
    # S = H P⁻ H' + R
    S = HPH + R
    det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    Si = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
    # NIS = ν' S⁻¹ ν
    nis = float(nu @ Si @ nu)
    w = 1.0
    if cfg.outlier == "gate" and nis > gate_nis:
        runner.feedback(k, nu, HPH, False)
        return x, P, nu, S, None, R, nis, 0.0, False
    if cfg.outlier == "huber":
        d = math.sqrt(nis)
        if d > cfg.huber_k:
            # w = k / √NIS,  R ← R / w   (Huber weight on the Mahalanobis norm)
            w = cfg.huber_k / d
            R = R / w
            S = HPH + R
            det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
            Si = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
    x_prior, P_prior = x, P
    for it in range(runner.n_iter):
        # K = P⁻ H' S⁻¹
        K = PHt @ Si
        # x = x⁻ + K ν
        x = x_prior + K @ nu
        # P = (I − KH) P⁻ (I − KH)' + K R K'   (Joseph form: symmetric PD for any K)
        A = np.eye(n) - K @ H
        if cfg.joseph:
            P = A @ P_prior @ A.T + K @ R @ K.T
        else:
            # P = (I − KH) P⁻   (short form: exact for the optimal K only)
            P = A @ P_prior
        P = 0.5 * (P + P.T)
        if it + 1 < runner.n_iter:
            # variational step: R from the residual of this iterate
            res = z - H @ x
            R = runner.refine(k, res, H @ P @ H.T)
            S = HPH + R
            det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
            Si = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
    if hasattr(runner, "refine"):
        # variational policies: the posterior residual sets this update's β
        runner.refine(k, z - H @ x, H @ P @ H.T)
    runner.feedback(k, nu, HPH, True)
    return x, P, nu, S, K, R, nis, w, True


def _h_matrices(cfg: EkfConfig) -> dict:
    n = cfg.n_state
    h = np.zeros((2, n))
    h[0, 0] = h[1, 1] = 1.0
    hg = h.copy()
    if cfg.gnss_bias:
        hg[0, 4] = hg[1, 5] = 1.0
    return {GNSS: hg, "other": h}


class EventEKF:
    """The event-driven EKF with one noise policy (:mod:`models.fusion.noise`).

    ``fast``: run the 4-state model through the scalar loop of :mod:`models.fusion.fast` (same results
    to rounding; ``False`` forces the matrix form, which the bias states and ``correct`` always use).

    >>> import numpy as np
    >>> from models.fusion.events import GnssEvents, StepEvents, merge_events
    >>> from models.fusion.noise import FixedNoise
    >>> ev = merge_events(StepEvents(np.arange(1, 5) * 0.5, np.full(4, 0.7), np.zeros(4)),
    ...                   GnssEvents.from_sigma(np.arange(0, 3.0), np.zeros(3), np.array([0.0, 1.4, 2.8]), np.ones(3)))
    >>> run = EventEKF(noise=FixedNoise(1.0, 0.5)).run(ev)
    >>> len(run), bool(run.accepted[run.kind == 1].all())
    (7, True)
    """

    def __init__(self, config: EkfConfig | None = None, noise=None, method: str = "kf", fast: bool = True):
        self.config = config
        self.noise = noise
        self.method = method
        self.fast = fast

    def run(self, stream: EventStream, x0_en=None, classes=None, class_at=None, x0=None, P0=None,
            correct=None) -> FilterRun:
        """Filter the whole stream once.

        ``x0_en``: (2,) initial east/north (default: the first available fix); ``x0``/``P0``: full prior;
        ``classes``: :class:`~models.fusion.events.ClassTrack` and ``class_at``: callable (east_m, north_m) →
        class index or probabilities, for per-class noise.

        ``correct``: closed-loop corrector (``adaptive_closed``), called after every accepted update as
        ``correct(k, x_prior, x, P, nu, S, K)`` (shapes (n,), (n,), (n, n), (2,), (2, 2), (n, 2)); a
        returned (2,) east/north correction is added to the posterior, which the next prediction then
        starts from, and is recorded in ``run.correction`` (m, 2) (``None`` or zeros: no change). The
        covariance is left as the filter computed it. Runs the matrix form.
        """
        from models.fusion.noise import FixedNoise

        cfg = self.config or EkfConfig()
        noise = self.noise if self.noise is not None else FixedNoise()
        runner = noise._start(stream, classes=classes, class_at=class_at)
        x, P = _initial(stream, cfg, x0_en, x0, P0)
        x0, P0 = x.copy(), P.copy()
        m, n = len(stream), cfg.n_state
        q, phi = _time_noise(stream, cfg)
        info = {"n_guarded": 0, "fast": False}
        if self.fast and n == 4 and getattr(runner, "fast", False) and correct is None:
            from models.fusion.fast import run_fast4

            rec = run_fast4(stream, cfg, runner, x, P, q)
            info["fast"] = True
            info["n_guarded"] = getattr(runner, "n_guarded", 0)
            if hasattr(runner, "history"):
                info["r_history"] = np.array(runner.history).reshape(-1, 4)   # event, kind, R_ee, R_nn
            return FilterRun(self.method, stream.t_s, stream.kind, x0, P0, available=stream.available, info=info,
                             **rec)
        rec = _records(m, n)
        if cfg.gnss_bias:
            rec["F"][:, 4, 4] = rec["F"][:, 5, 5] = phi
        H = _h_matrices(cfg)
        gate = cfg.gate_nis
        kind, avail, z = stream.kind, stream.available, stream.z_m
        length, heading = stream.step_length_m, stream.heading_rad
        Fr, xpr, Ppr, xr, Pr = rec["F"], rec["x_prior"], rec["P_prior"], rec["x"], rec["P"]
        idx = np.arange(n)
        for k in range(m):
            if cfg.gnss_bias:
                x = x.copy()
                # b = φ b
                x[4:6] *= phi[k]
                # P = Φ P Φ'  (bias rows and columns)
                P = P.copy()
                P[4:6, :] *= phi[k]
                P[:, 4:6] *= phi[k]
            else:
                P = P.copy()
            # P += Q_Δt
            P[idx, idx] += q[k]
            c = kind[k]
            if c == STEP:
                Fs = np.eye(n)
                x, P = _step_predict(x, P, length[k], heading[k], cfg, Fs)
                # F = F_step Φ   (bias decay first, then the step)
                Fr[k] = Fs @ Fr[k]
            xpr[k] = x
            Ppr[k] = P
            if c != STEP and avail[k]:
                Hk = H[GNSS] if c == GNSS else H["other"]
                R = runner.r(k, x)
                x, P, nu, S, K, Ru, nis, w, ok = _update(x, P, z[k], R, Hk, cfg, runner, k, gate)
                rec["nu"][k], rec["S"][k], rec["R"][k], rec["nis"][k], rec["weight"][k] = nu, S, Ru, nis, w
                rec["updated"][k] = True
                rec["accepted"][k] = ok
                if ok:
                    rec["K"][k] = K
                    if correct is not None:
                        dc = correct(k, xpr[k], x, P, nu, S, K)
                        if dc is not None:
                            dc = np.asarray(dc, float)
                            if dc.shape != (2,) or not np.all(np.isfinite(dc)):
                                raise FilterError(f"correct must return a finite (2,) correction, got {dc!r}")
                            x = x.copy()
                            x[:2] += dc
                            rec["correction"][k] = dc
            xr[k] = x
            Pr[k] = P
        info["n_guarded"] = getattr(runner, "n_guarded", 0)
        if hasattr(runner, "history"):
            info["r_history"] = np.array(runner.history).reshape(-1, 4)   # event, kind, R_ee, R_nn
        return FilterRun(self.method, stream.t_s, stream.kind, x0, P0, available=stream.available, info=info, **rec)


def run_ekf(stream: EventStream, noise=None, config: EkfConfig | None = None, method: str = "kf", **kw) -> FilterRun:
    """Thin function over :class:`EventEKF`: ``EventEKF(config, noise, method).run(stream, **kw)``."""
    return EventEKF(config, noise, method).run(stream, **kw)
