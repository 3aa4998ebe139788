"""The air the chirps travel through — wind and the speed of sound — estimated from the ranges of the track's fixes.

The receiver converts times into ranges with c from the crew's thermometer, dry air
(:func:`features.acoustic.timing.speed_of_sound_m_s`). The true air differs in two ways
common to every beacon of a fix:

* **wind**: sound moves with the air, so along a path of horizontal direction n̂ the
  effective speed is c_eff = c + w·n̂ (the effective sound speed approximation; Ostashev
  & Wilson, "Acoustics in Moving Inhomogeneous Media", 2nd ed., 2015, eq. 3.28);
* **scale**: the thermometer is off by 1–2 K and humid air is faster (c ∝ √T_v; Cramer
  1993): c_true = c·(1 + k) with k of a few 0.1 %.

To first order a range reads

    ρᵢ = rᵢ − (p − sᵢ)_h·w/c − k·rᵢ + c·δ                                (1)

((p − sᵢ)_h the horizontal vector from beacon i to the receiver), the model of the
consider parameters in :func:`features.acoustic.lsq.consider_covariance`. A
steady wind biases every fix of a walk alike, by about the mean range times w/c: at
2 m/s and 20 m, 0.12 m downwind — on held-out walks two thirds of the open-area error
(``bench/acoustic_error_causes.py``). Within one fix these terms are hard to see (the
part common to all beacons looks like a shift of the position, and a scale error
like a wind along the beacons' mean direction); over a walk, as the receiver moves
among the beacons, they separate. So a = (w_east, w_north, k) is a three-state random
walk, and every fix of the track adds its information in a Kalman update with the
position and clock of the fix projected out (the Schur complement of the joint least
squares in (e, n, δ, a)):

    # G = ∂ρ/∂a = [−(p − sᵢ)_h/c, −rᵢ] (n × 3),  N = JᵀWJ (+ the clock prior),  v = residuals of the fix
    # Λ = GᵀWG − GᵀWJ·N⁻¹·JᵀWG          (what the fix says about a, position and clock unknown)
    # P⁺ = (P⁻¹ + ηΛ)⁻¹,  Δa = P⁺·η·GᵀW·v  (JᵀW·v = 0 at the fix; η = UPDATE_WEIGHT)
    # Δx = −N⁻¹·JᵀWG·Δa                  (the fix moves with the air it implies)

Before a frame is solved its ranges get back what eq. (1) took off them at the
estimate (at the predicted position), and the fix's covariance takes the estimate's σ
as its consider parameters instead of the priors. Warm air over transformers varies
path by path and stays in the per-path variance (``PositionConfig.path_rel_sigma``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

__all__ = ["AirState", "air_range_corrections_m", "WIND_RANDOM_WALK_M2_S3", "SCALE_RANDOM_WALK_PER_S", "GUST_SIGMA_M_S",
           "SCALE_FLOOR", "UPDATE_WEIGHT", "AIR_UPDATE_MIN_SPEED_M_S"]

WIND_RANDOM_WALK_M2_S3 = 0.01
"""Spectral density of the wind's random walk, (m/s)²/s: 1 m/s of change is believed within about 100 s."""

SCALE_RANDOM_WALK_PER_S = 1e-9
"""Spectral density of the sound-speed scale's random walk, 1/s (0.1 % over about 15 minutes: the day warming)."""

GUST_SIGMA_M_S = 0.5
"""σ per axis of the wind about its estimate from one frame to the next, m/s: gusts of seconds, which the random
walk does not follow (gust factors of 1.3–1.5 over a 10-minute mean of 1–4 m/s). It stays in a fix's consider
covariance whatever the estimate's own σ."""

SCALE_FLOOR = 0.001
"""σ of the sound-speed scale about its estimate from place to place: warm air beside transformers (2–5 K, 0.3–0.9 %
within a few metres of a tank) moves it where the walker goes. Kept in the consider covariance likewise."""

UPDATE_WEIGHT = 0.5
"""Share of a fix's information about the air that an update counts. A fix's σ describe its own frame; at one
place the errors of consecutive frames persist (multipath, a beacon's survey error, the torso's residue), which
makes them look like air frame after frame. Counted at 1, in air with no error of its own (the simulator's
air, survey errors, codec and multipath switched off) the estimate's wandering doubled the open-area median
error of the training walks (0.016 → 0.034 m); at 0.5 with the random walk of 0.01 (m/s)²/s, 0.032 m, while
in the default world it gained most (0.113 → 0.090 m). Tuned on the training sites' walks (101–103, walks 0–1)
only."""

AIR_UPDATE_MIN_SPEED_M_S = 0.5
"""The air is updated from fixes of a walking receiver only (track speed at least this, m/s): see the tracker."""

_MIN_BEACONS = 5
"""Fixes on fewer beacons say too little about the air (and more often keep an NLOS range) to update it."""

_GATE_CHI2_3DOF = 16.3
"""Innovation gate of an update: the chi-square 0.999 quantile with 3 degrees of freedom."""


def air_range_corrections_m(wind_m_s, scale: float, receiver_en, beacons: np.ndarray, height_m: float,
                            c: float) -> np.ndarray:
    """What each range read short by the air, eq. (1) negated: (p − sᵢ)_h·w/c + k·rᵢ, m; shape (n,).
    ``beacons``: (n, 3) east, north, up.

    >>> air_range_corrections_m((2.0, 0.0), 0.0, (20.0, 0.0), np.array([[0.0, 0.0, 1.0], [40.0, 0.0, 1.0]]), 1.0,
    ...                         343.0).round(4).tolist()
    [0.1166, -0.1166]
    """
    b = np.asarray(beacons, float).reshape(-1, 3)
    d = np.column_stack([receiver_en[0] - b[:, 0], receiver_en[1] - b[:, 1], height_m - b[:, 2]])
    return (d[:, :2] @ np.asarray(wind_m_s, float)) / c + scale * np.sqrt((d ** 2).sum(axis=1))


class AirState(NamedTuple):
    """Air estimate at stated time ``t_s``: ``x`` = (w_east m/s, w_north m/s, k), covariance ``p`` (3, 3)."""

    t_s: float
    x: np.ndarray
    p: np.ndarray

    @classmethod
    def prior(cls, t_s: float, wind_sigma_m_s: float, scale_sigma: float) -> "AirState":
        """No air known: calm, the stated temperature; σ per axis ``wind_sigma_m_s``, ``scale_sigma``."""
        return cls(t_s, np.zeros(3), np.diag([wind_sigma_m_s ** 2, wind_sigma_m_s ** 2, scale_sigma ** 2]))

    @property
    def wind_sigma_m_s(self) -> float:
        """The larger axis σ of the wind about the estimate in one frame, m/s: the estimate's and the gusts'
        (:data:`GUST_SIGMA_M_S`); the consider parameter of a fix's covariance."""
        return math.sqrt(max(float(np.linalg.eigvalsh(self.p[:2, :2])[-1]), 0.0) + GUST_SIGMA_M_S ** 2)

    @property
    def scale_sigma(self) -> float:
        """σ of the sound-speed scale about the estimate where the walker is: the estimate's and
        :data:`SCALE_FLOOR`'s."""
        return math.sqrt(max(float(self.p[2, 2]), 0.0) + SCALE_FLOOR ** 2)

    def predict(self, t_s: float, cap: "AirState") -> "AirState":
        """Random walk to ``t_s`` (never backwards); each variance capped at the prior ``cap``'s."""
        dt = t_s - self.t_s
        if dt <= 0:
            return self
        p = self.p + np.diag([WIND_RANDOM_WALK_M2_S3, WIND_RANDOM_WALK_M2_S3, SCALE_RANDOM_WALK_PER_S]) * dt
        d = np.minimum(np.diag(p), np.diag(cap.p))
        s = np.sqrt(d / np.maximum(np.diag(p), 1e-300))
        return AirState(t_s, self.x, p * s[:, None] * s[None, :])

    def update(self, ranges, x: np.ndarray, h: float, c: float, clock_prior_sigma_s: float | None):
        """The air after a fix at ``x`` = (east, north, clock s) solved from ``ranges`` (their pseudoranges
        already corrected by this estimate), and the fix's correction (Δeast, Δnorth, Δclock_s); the state
        unchanged and zeros when the fix has too few beacons or what it implies fails the gate. Equations
        in the module docstring."""
        n = len(ranges)
        none = (self, (0.0, 0.0, 0.0))
        if n < _MIN_BEACONS:
            return none
        s = np.array([[r.east_m, r.north_m, r.up_m] for r in ranges])
        rho = np.array([r.pseudorange_m for r in ranges])
        w = 1.0 / np.array([r.sigma_m for r in ranges]) ** 2
        d = np.column_stack([x[0] - s[:, 0], x[1] - s[:, 1], h - s[:, 2]])
        dist = np.sqrt((d ** 2).sum(axis=1))
        jac = np.column_stack([d[:, 0] / dist, d[:, 1] / dist, np.full(n, c)])
        g = np.column_stack([-d[:, :2] / c, -dist])                          # ∂ρ/∂a
        v = rho - dist - c * x[2]
        normal = jac.T @ (w[:, None] * jac)
        if clock_prior_sigma_s is not None:
            normal[2, 2] += 1.0 / clock_prior_sigma_s ** 2
        jwg = jac.T @ (w[:, None] * g)                                       # JᵀWG (3 × 3)
        try:
            n_inv_jwg = np.linalg.solve(normal, jwg)
            info = UPDATE_WEIGHT * (g.T @ (w[:, None] * g) - jwg.T @ n_inv_jwg)   # Λ
            b = UPDATE_WEIGHT * (g.T @ (w * v))
            p_post = np.linalg.inv(np.linalg.inv(self.p) + info)
            # Gate: b = Λ·(a − â) + noise of covariance Λ, so b ~ N(0, ΛPΛ + Λ) when the fix agrees.
            s_b = info @ self.p @ info + info + 1e-12 * np.eye(3) * max(float(np.trace(info)), 1e-30)
            if float(b @ np.linalg.solve(s_b, b)) > _GATE_CHI2_3DOF:
                return none
        except np.linalg.LinAlgError:
            return none
        da = p_post @ b
        dx = -n_inv_jwg @ da                                                 # (m, m, s): J's clock column is c
        return AirState(self.t_s, self.x + da, 0.5 * (p_post + p_post.T)), (float(dx[0]), float(dx[1]),
                                                                              float(dx[2]))
