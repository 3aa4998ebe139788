"""Two-state receiver clock filter: offset δ and drift δ̇ of the audio sample clock.

The clock model of GNSS receivers (Brown & Hwang, "Introduction to Random Signals
and Applied Kalman Filtering", 4th ed., 2012, §9.3, eq. 9.3.1–9.3.8; Kaplan &
Hegarty, "Understanding GPS/GNSS", 3rd ed., 2017, §11.2.2): state x = [δ, δ̇]
(s, s/s), white frequency noise of spectral density S_f and random-walk
frequency noise S_g:

    # x(t + Δt) = F·x(t),   F = [[1, Δt], [0, 1]]
    # Q = [[S_f·Δt + S_g·Δt³/3, S_g·Δt²/2], [S_g·Δt²/2, S_g·Δt]]

S_f and S_g (:data:`WHITE_FREQUENCY_S`, :data:`RANDOM_WALK_FREQUENCY_PER_S`) are
set well above a TCXO's (Brown & Hwang Table 9.1: h₀ ≈ 2e−19 s, h₋₂ ≈ 2e−20 s⁻¹)
to cover the temperature wander of a consumer audio crystal: 1 ppm of frequency
change per 100 s, and about 1 µs (0.3 mm) of offset noise per second.

Measurement: each acoustic fix estimates δ jointly with the position, with this
filter's prediction as a prior (:func:`features.acoustic.positions.solve_position`).
Since the prior enters only δ's diagonal, the fix's marginal on δ is exactly the
prior combined with the ranges' own information, so the filter takes the fix's
(δ, σ²_δ) as the posterior of δ and conditions the drift on it (Gaussian
conditioning, equal to the Kalman update with the ranges-only measurement and no
double counting of the prior):

    # x⁺ = x⁻ + P⁻[:, 0]·(δ_fix − δ⁻)/P⁻₀₀,   P⁺ = P⁻ − P⁻[:, 0]·P⁻[0, :]·(P⁻₀₀ − σ²_δ)/P⁻₀₀²

A fix solved without the prior (acquisition) is an ordinary measurement (Kalman
update, H = [1, 0], R = σ²_δ).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["ClockState", "WHITE_FREQUENCY_S", "RANDOM_WALK_FREQUENCY_PER_S", "INITIAL_DRIFT_SIGMA"]

WHITE_FREQUENCY_S = 1e-12
"""S_f, white frequency noise of the audio clock, s (≈ 1 µs of offset noise per second)."""

RANDOM_WALK_FREQUENCY_PER_S = 1e-14
"""S_g, random-walk frequency noise of the audio clock, 1/s (≈ 1 ppm of drift change per 100 s)."""

INITIAL_DRIFT_SIGMA = 50e-6
"""σ of the drift before any is measured (the receiver's search windows allow ±100 ppm: 2σ)."""


class ClockState(NamedTuple):
    """Clock offset and drift at stated time ``t_s``: x = (offset_s, drift), P as (p00, p01, p11)."""

    t_s: float
    offset_s: float
    drift: float
    p00: float
    p01: float
    p11: float

    @classmethod
    def first(cls, t_s: float, offset_s: float, offset_var_s2: float) -> "ClockState":
        """From one offset measurement, drift unknown (σ :data:`INITIAL_DRIFT_SIGMA`).

        >>> ClockState.first(10.0, 0.004, 1e-10).predict(12.0).p00 > 1e-10 + (2 * 50e-6) ** 2
        True
        """
        return cls(t_s, offset_s, 0.0, offset_var_s2, 0.0, INITIAL_DRIFT_SIGMA ** 2)

    def predict(self, t_s: float) -> "ClockState":
        """The state at ``t_s`` (module docstring: F, Q); never backwards."""
        dt = t_s - self.t_s
        if dt <= 0:
            return self
        sf, sg = WHITE_FREQUENCY_S, RANDOM_WALK_FREQUENCY_PER_S
        # P = F P Fᵀ + Q
        p00 = self.p00 + 2 * dt * self.p01 + dt * dt * self.p11 + sf * dt + sg * dt ** 3 / 3
        p01 = self.p01 + dt * self.p11 + sg * dt * dt / 2
        p11 = self.p11 + sg * dt
        return ClockState(t_s, self.offset_s + dt * self.drift, self.drift, p00, p01, p11)

    def measured(self, t_s: float, offset_s: float, offset_var_s2: float) -> "ClockState":
        """Kalman update with an offset measured without this filter's prior (H = [1, 0])."""
        p = self.predict(t_s)
        s = p.p00 + offset_var_s2
        k0, k1 = p.p00 / s, p.p01 / s
        v = offset_s - p.offset_s
        # Joseph-free form is fine here: 2×2, s > 0, and P stays symmetric by construction.
        return ClockState(t_s, p.offset_s + k0 * v, p.drift + k1 * v, p.p00 - k0 * p.p00, p.p01 - k0 * p.p01,
                          p.p11 - k1 * p.p01)

    def conditioned(self, offset_s: float, offset_var_s2: float) -> "ClockState":
        """This predicted state given a fix that used it as prior and found (offset, variance).

        >>> prior = ClockState(0.0, 0.0, 0.0, 4e-10, 1e-12, 1e-14)
        >>> post = prior.conditioned(1e-5, 1e-10)
        >>> round(post.offset_s * 1e6, 3), post.p00 == 1e-10
        (10.0, True)
        """
        if not self.p00 > 0:
            return self
        var = min(max(offset_var_s2, 0.0), self.p00)
        g = (offset_s - self.offset_s) / self.p00
        shrink = (self.p00 - var) / (self.p00 * self.p00)
        return ClockState(self.t_s, offset_s, self.drift + self.p01 * g, var, self.p01 - self.p01 * self.p00 * shrink,
                          self.p11 - self.p01 * self.p01 * shrink)
