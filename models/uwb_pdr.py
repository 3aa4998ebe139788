"""UWB angle-of-arrival + PDR fusion of Zhou et al. (2025), on the project's filter core.

Zhou et al., "Seamless Indoor and Outdoor Combination Positioning Method for Substations Based on Ultra
Wideband AOA Estimation and Multi-source Information Fusion" (2025): a UWB position from angle of arrival
and range, a dead-reckoning (MIMU/PDR) position, and a Kalman filter whose state is the **difference**
of the two — the PDR error — so that the Kalman gain "compensates" the PDR position.

Indirect (error-state) filter, state δx = p_PDR − p (the PDR track's error, east/north, m)::

    per step of length L, heading ψ (g = (sin ψ, cos ψ) along track, h = (cos ψ, −sin ψ) across):
    # δx⁻ = δx,   P⁻ = P + σ_L²·g g' + (L σ_ψ)²·h h'      (the step's own length and heading noise
    #                                                      enter the PDR error: Groves 2013 §6.4)
    between events, standing or walking: P⁻ += q·Δt·I
    per UWB fix p_UWB with covariance R (features.uwb.position.uwb_positions):
    # z = p_PDR(t) − p_UWB,   H = I₂,   ν = z − δx⁻,   S = P⁻ + R,   K = P⁻ S⁻¹
    # δx = δx⁻ + K ν,   P = (I − K) P⁻ (I − K)' + K R K'    (Joseph form: models.fusion.core.kalman_update)
    output  p̂ = p_PDR(t) − δx,   Cov(p̂) = P

``p_PDR(t)`` is the dead-reckoned track interpolated linearly over each step, still through a stop
(:func:`pdr_track_at`). The filter starts at the
first UWB fix (δx₀ = z₀, P₀ = R₀). The paper handles no outliers; a UWB fix in NLOS is metres off, so the
χ² gate of the core is on by default (``outlier="gate"``, ``gate_prob``); ``outlier="none"`` is the paper's
form. A gate can lock the filter out when the PDR drifts faster than its noise says (a heading bias is
not a random walk): after ``reset_after`` fixes rejected in a row the filter restarts from the latest fix
as it started (δx = z, P = R). The run is a :class:`models.fusion.ekf.FilterRun` whose states are the corrected positions p̂
(p_PDR is a known input, so p̂ = p_PDR − δx carries the same covariance and the RTS smoother applies with
F = I: ``x_prior[k+1] − x[k]`` is the PDR displacement).

The paper reports 0.001 m static and moving; no UWB reaches that (two-way ranging ≈ 10 cm σ in line of
sight, PDoA a few degrees): ``bench/bench_uwb.py`` measures what the method gives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from features.uwb.position import UwbFixes
from models.fusion.core import kalman_update
from models.fusion.ekf import OUTLIER_CODES, FilterError, FilterResume, FilterRun, empty_records
from models.fusion.events import STEP

__all__ = ["UwbPdrConfig", "UwbPdrFilter", "UWB_FIX", "pdr_track_at", "UwbNoisePrior", "uwb_nees", "STAND_GAP_S",
           "STEP_S"]

UWB_FIX = 3
"""Event kind of a UWB position fix in a :class:`~models.fusion.ekf.FilterRun` (after STEP, GNSS, ACOUSTIC)."""


@dataclass(frozen=True)
class UwbPdrConfig:
    """Settings of :class:`UwbPdrFilter` (PDR noise per step as the project's PDR: 0.07 m length, 2° heading)."""

    sigma_step_length_m: float = 0.07
    sigma_heading_rad: float = math.radians(2.0)
    q_m2_s: float = 1e-4
    outlier: str = "gate"
    gate_prob: float = 0.999
    huber_k: float = 2.5
    reset_after: int = 10

    def __post_init__(self):
        for name in ("sigma_step_length_m", "sigma_heading_rad", "q_m2_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise FilterError(f"{name} must be finite and >= 0, got {v!r}")
        if not (math.isfinite(self.huber_k) and self.huber_k > 0):
            raise FilterError(f"huber_k must be finite and > 0, got {self.huber_k!r}")
        if self.outlier not in OUTLIER_CODES:
            raise FilterError(f"outlier must be one of {tuple(OUTLIER_CODES)}, got {self.outlier!r}")
        if not 0 < self.gate_prob < 1:
            raise FilterError(f"gate_prob must lie in (0, 1), got {self.gate_prob}")
        if isinstance(self.reset_after, bool) or not isinstance(self.reset_after, int) or self.reset_after < 0:
            raise FilterError(f"reset_after must be a non-negative integer, got {self.reset_after!r}")


def uwb_nees(err_en_m, cov_en_m2) -> np.ndarray:
    """Normalised squared error of each fix, eᵀC⁻¹e, shape (n,) (err (n, 2), cov (n, 2, 2)); χ²₂ when C is right."""
    e = np.asarray(err_en_m, float)
    return np.einsum("ni,nij,nj->n", e, np.linalg.inv(np.asarray(cov_en_m2, float)), e)


class UwbNoisePrior:
    """The environment's NLOS prior for UWB fixes: a scale of each fix's covariance per environment class.

    ``fit(nees, classes)``: the scale of class c is the χ²₂-mean estimate of its fixes' eᵀC⁻¹e on the training
    walks, halved (:func:`models.fusion.noise.chi2_2_mean`: ``"mean"``, every NLOS fix counting in full — the
    prior of how often and how far UWB is off where that class holds; ``"median"``, the core only), floored
    at 1 (never trusting a fix more than its solver does). With ``n_classes=1`` it is the blind twin: one
    scale pooled over every class. ``r_scale(class_proba)``: the scale of fixes whose class probabilities are
    given, Σ_c p_c·s_c, shape (n,).
    """

    def __init__(self, n_classes: int = 3, estimator: str = "mean"):
        self.n_classes = n_classes
        self.estimator = estimator

    def fit(self, nees, classes) -> "UwbNoisePrior":
        from models.fusion.noise import chi2_2_mean

        nees = np.asarray(nees, float)
        cls = np.zeros(nees.size, int) if self.n_classes == 1 else np.asarray(classes, int)
        ok = np.isfinite(nees)
        pooled = chi2_2_mean(nees[ok], self.estimator) / 2.0 if ok.any() else 1.0
        scale = np.full(self.n_classes, pooled)
        for c in range(self.n_classes):
            sel = ok & (cls == c)
            if sel.sum() >= 20:          # too few fixes of a class: the pooled scale
                scale[c] = chi2_2_mean(nees[sel], self.estimator) / 2.0
        self.scale_ = np.maximum(scale, 1.0)
        return self

    def r_scale(self, class_proba) -> np.ndarray:
        p = np.atleast_2d(np.asarray(class_proba, float))
        if self.n_classes == 1:
            return np.full(p.shape[0], float(self.scale_[0]))
        return p @ self.scale_

    def get_state(self) -> dict:
        return {"n_classes": int(self.n_classes), "estimator": self.estimator,
                "scale": [float(v) for v in self.scale_]}

    @classmethod
    def from_state(cls, state: dict) -> "UwbNoisePrior":
        prior = cls(int(state["n_classes"]), str(state["estimator"]))
        scale = np.asarray(state["scale"], float)
        if scale.shape != (prior.n_classes,) or not np.all(np.isfinite(scale) & (scale >= 1.0)):
            raise ValueError(f"UWB prior scales must be {prior.n_classes} finite numbers >= 1, got {state['scale']}")
        prior.scale_ = scale
        return prior


STAND_GAP_S = 1.5
"""Steps further apart than this have a stop between them, s (:data:`walks.inputs.STAND_GAP_S`, the event
filters' standing intervals)."""

STEP_S = 0.55
"""Duration of a step that follows a stop (or none), s: a typical step (:data:`walks.inputs.TYPICAL_STEP_S`)."""


def pdr_track_at(t_s, step_t_s, east_m, north_m, start_en) -> tuple[np.ndarray, np.ndarray]:
    """The dead-reckoned position at times ``t_s``, linear over each step from its start to its end (``east_m``,
    ``north_m`` at the step ends ``step_t_s``; ``start_en`` before the first step), and still between steps more
    than :data:`STAND_GAP_S` apart. A step starts at the previous step's end, or :data:`STEP_S` before its own
    end when it follows a stop or is the first: as the event filters split a step
    (:func:`walks.inputs.split_steps`). So the position at t depends on no step ending more than
    :data:`STAND_GAP_S` after t (a stop is not spread over by the step after it), as a long walk's cut that
    ends in a stop needs (:mod:`walks.segments`). Shapes (k,).

    >>> pdr_track_at([-1.0, 9.0, 9.725, 10.0], [0.5, 10.0], [1.0, 2.0], [0.0, 0.0], (0.0, 0.0))[0].tolist()
    [0.0, 1.0, 1.5, 2.0]
    """
    t = np.asarray(step_t_s, float)
    if t.size == 0:
        q = np.asarray(t_s, float)
        return np.full(q.shape, float(start_en[0])), np.full(q.shape, float(start_en[1]))
    e = np.concatenate([[float(start_en[0])], np.asarray(east_m, float)])
    n = np.concatenate([[float(start_en[1])], np.asarray(north_m, float)])
    gap = np.diff(t, prepend=-np.inf)
    start = np.where(gap > STAND_GAP_S, t - STEP_S, t - gap)
    # knots: each step's start (at the previous position) where a stop precedes it, and every step's end
    stop = gap > STAND_GAP_S
    tt = np.concatenate([start[stop], t])
    ee = np.concatenate([e[:-1][stop], e[1:]])
    nn = np.concatenate([n[:-1][stop], n[1:]])
    order = np.argsort(tt, kind="stable")
    return np.interp(t_s, tt[order], ee[order]), np.interp(t_s, tt[order], nn[order])


class UwbPdrFilter:
    """The error-state filter of the module docstring. ``run(steps, fixes)`` → :class:`FilterRun`.

    ``steps``: the PDR (``t_s``, ``step_length_m``, ``heading_rad``, ``east_m``, ``north_m`` of shape (n,):
    :class:`features.imu.pdr.PdrResult`) and ``start_en`` its start; ``fixes``: :class:`UwbFixes`.
    ``r_scale`` (n_fixes,) multiplies each fix's covariance (the environment's NLOS prior; 1 by default).
    """

    def __init__(self, config: UwbPdrConfig | None = None, method: str = "uwb_aoa_pdr"):
        self.config = config
        self.method = method

    def run(self, steps, start_en, fixes: UwbFixes, r_scale=None, gate_prob=None,
            resume: FilterResume | None = None) -> FilterRun:
        """``resume``: the state of a run over an earlier piece of the same walk (a long walk's previous segment,
        :meth:`FilterRun.state_before`): from its time on the filter continues from that run's corrected
        position p̂ and P after its last event, δx = p_PDR(t) − p̂ on this run's PDR track (whose start may
        differ: only its increments enter), and its count of fixes gated in a row."""
        cfg = self.config or UwbPdrConfig()
        if len(fixes) == 0:
            raise FilterError("no UWB fix to start the filter from")
        n_fix = len(fixes)
        scale = np.ones(n_fix) if r_scale is None else np.asarray(r_scale, float)
        gates = np.full(n_fix, cfg.gate_prob) if gate_prob is None else np.asarray(gate_prob, float)
        t0 = float(fixes.t_s[0])
        st = np.asarray(steps.t_s, float)
        # the events start at the first fix, which starts the filter; a resumed run also holds every step and fix
        # from the handed state's time on, fix 0 included (a cut whose warm-up holds no UWB fix: its first fix
        # lies after the resumption and is fused like any other, not taken as a fresh start)
        keep = st > t0 if resume is None else (st > t0) | (st >= float(resume.t_s))
        t = np.concatenate([st[keep], fixes.t_s])
        kind = np.concatenate([np.full(int(keep.sum()), STEP), np.full(n_fix, UWB_FIX)])
        idx = np.concatenate([np.flatnonzero(keep), np.arange(n_fix)])
        order = np.lexsort((kind, t))
        t, kind, idx = t[order], kind[order], idx[order]
        pe, pn = pdr_track_at(t, st, steps.east_m, steps.north_m, start_en)
        m = len(t)
        rec = empty_records(m, 2)
        H = np.eye(2)
        code = OUTLIER_CODES[cfg.outlier]
        sl2, sp2 = cfg.sigma_step_length_m ** 2, cfg.sigma_heading_rad ** 2
        p0 = np.array([pe[0], pn[0]])
        # δx₀ = z₀ = p_PDR(t₀) − p_UWB,0,  P₀ = R₀ (the first fix starts the filter)
        dx = p0 - np.array([fixes.east_m[0], fixes.north_m[0]])
        P = fixes.cov_en[0] * scale[0]
        x0, P0 = p0 - dx, P.copy()
        t_prev, rejected, n_reset = t0, 0, 0
        restart = -1 if resume is None else int(np.searchsorted(t, resume.t_s, side="left"))
        if resume is not None and resume.P.shape != (2, 2):
            raise FilterError(f"cannot resume the UWB/PDR filter from a state of {resume.x.shape[0]} states")
        rejected_rec = np.zeros(m, np.int64)
        for k in range(m):
            if k == restart:
                # δx = p_PDR(t) − p̂ at the handed state's last event, on this run's PDR track
                pr = pdr_track_at(np.array([resume.event_t_s]), st, steps.east_m, steps.north_m, start_en)
                dx = np.array([pr[0][0], pr[1][0]]) - np.asarray(resume.x, float)
                P, rejected, t_prev = np.asarray(resume.P, float).copy(), int(resume.rejected_in_row), resume.event_t_s
            P = P + np.eye(2) * cfg.q_m2_s * max(t[k] - t_prev, 0.0)
            t_prev = t[k]
            p_pdr = np.array([pe[k], pn[k]])
            if kind[k] == STEP:
                i = idx[k]
                L, psi = float(steps.step_length_m[i]), float(steps.heading_rad[i])
                g = np.array([math.sin(psi), math.cos(psi)])
                h = np.array([math.cos(psi), -math.sin(psi)])
                # P⁻ = P + σ_L² g g' + (L σ_ψ)² h h'
                P = P + sl2 * np.outer(g, g) + L * L * sp2 * np.outer(h, h)
            rec["x_prior"][k], rec["P_prior"][k] = p_pdr - dx, P
            if kind[k] == UWB_FIX and (idx[k] > 0 or 0 <= restart <= k):     # fix 0 started the filter unless resumed
                j = idx[k]
                z = p_pdr - np.array([fixes.east_m[j], fixes.north_m[j]])
                R = fixes.cov_en[j] * scale[j]
                gate = -2.0 * math.log1p(-float(gates[j]))
                dxn, Pn, nu, S, K, Ru, nis, w, ok = kalman_update(dx, P, z, R, H, code, gate, cfg.huber_k, True)
                # the innovation of δx is minus that of the position: recorded in the position's sign
                rec["nu"][k], rec["S"][k], rec["R"][k], rec["nis"][k], rec["weight"][k] = -nu, S, Ru, nis, w
                rec["updated"][k], rec["accepted"][k] = True, ok
                if ok:
                    rec["K"][k] = K
                    dx, P = dxn, Pn
                    rejected = 0
                else:
                    rejected += 1
                    if cfg.reset_after and rejected >= cfg.reset_after:
                        # the PDR has left the gate for good (a heading bias the random walk does not hold):
                        # restart from this fix, as the filter started (δx = z, P = R)
                        dx, P, rejected = z.copy(), R.copy(), 0
                        n_reset += 1
            rec["x"][k], rec["P"][k] = p_pdr - dx, P
            rejected_rec[k] = rejected
        run = FilterRun(self.method, t, kind, x0, P0, available=kind == UWB_FIX, **rec)
        run.info["rejected_in_row"] = rejected_rec
        run.info["n_uwb_fixes"] = n_fix
        run.info["n_resets"] = n_reset
        run.info["uwb_accepted_share"] = float(rec["accepted"][kind == UWB_FIX].mean()) if n_fix else 0.0
        return run
