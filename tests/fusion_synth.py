"""Synthetic event streams for the fusion filters, drawn from the filter's own model.

Independent of ``simulation/`` on purpose: the truth evolves event by event by
exactly the process model of :mod:`models.fusion.ekf` (steps with length and
heading noise scaled by the true step-scale error and rotated by the true
heading offset, position random walk between events, random walks on δψ and s,
optional Gauss–Markov GNSS bias), so a consistent filter must pass the
chi-square tests on it. Every draw comes from one ``numpy.random.Generator``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from models.fusion.ekf import EkfConfig
from models.fusion.events import ACOUSTIC, GNSS, STEP, AcousticEvents, EventStream, GnssEvents, StepEvents, \
    merge_events


@dataclass
class Synth:
    stream: EventStream
    truth: np.ndarray          # (m, 4 or 6): state after each event
    steps: StepEvents
    gnss: GnssEvents | None
    acoustic: AcousticEvents | None
    pdr_en: np.ndarray         # (m, 2): PDR alone (dead reckoning from the true start, no corrections)
    x0: np.ndarray
    P0: np.ndarray


def _sigma_fn(v) -> Callable[[np.ndarray], np.ndarray]:
    if callable(v):
        return v
    return lambda t: np.full(np.shape(t), float(v))


def synth_walk(seed: int, duration_s: float = 120.0, cfg: EkfConfig = EkfConfig(), step_hz: float = 1.8,
               length_m: float = 0.7, heading_offset_rad: float | None = None, scale_error: float | None = None,
               gnss_hz: float | None = 5.0, gnss_sigma_m=1.5, gnss_reported_sigma_m=None,
               acoustic_hz: float | None = None, acoustic_sigma_m=0.3, turn_every_s: float = 20.0,
               bias_sigma_m: float = 0.0, bias_tau_s: float = 30.0, start_en=(0.0, 0.0),
               irregular: bool = False, gnss_sigma_at=None, gnss_quality=None) -> Synth:
    """One walk. Unset ``heading_offset_rad``/``scale_error`` are drawn from the filter's prior
    (so NEES tests see the prior the filter assumes); the start position likewise.
    ``irregular``: fix times with exponential gaps of the same mean rate instead of a fixed period.
    ``gnss_sigma_at``: callable (east_m, north_m) → true σ at the true position (overrides
    ``gnss_sigma_m``, the reported σ stays as given); ``gnss_quality``: callable t → GGA quality (n,)."""
    rng = np.random.default_rng(seed)
    n_state = cfg.n_state
    x0 = np.zeros(n_state)
    x0[:2] = start_en
    d = [cfg.sigma0_pos_m ** 2] * 2 + [cfg.sigma0_heading_rad ** 2, cfg.sigma0_scale ** 2]
    if cfg.gnss_bias:
        d += [cfg.bias_sigma_m ** 2] * 2
    P0 = np.diag(d)
    truth0 = rng.multivariate_normal(x0, P0)
    if heading_offset_rad is not None:
        truth0[2] = heading_offset_rad
    if scale_error is not None:
        truth0[3] = scale_error
    if not cfg.gnss_bias:
        truth0 = np.concatenate([truth0, np.zeros(2)])
    # step times with jitter; measured headings: straight legs joined by 90° turns, plus a slow wander
    n_steps = int(duration_s * step_hz)
    t_step = np.cumsum(np.full(n_steps, 1.0 / step_hz) + rng.uniform(-0.05, 0.05, n_steps))
    legs = np.floor(t_step / turn_every_s)
    turn = rng.choice([-1.0, 1.0], size=int(legs.max()) + 1) * (math.pi / 2)
    psi_m = np.cumsum(turn)[legs.astype(int)] + 0.05 * np.sin(t_step / 7.0)
    len_m = length_m + rng.normal(0.0, 0.03, n_steps)
    steps = StepEvents(t_step, len_m, psi_m)
    def fix_times(hz, phase_s):
        if not hz:
            return np.zeros(0)
        if irregular:
            t = np.cumsum(rng.exponential(1.0 / hz, int(2 * t_step[-1] * hz) + 10))
            return t[t < t_step[-1]]
        return np.arange(0.0, t_step[-1], 1.0 / hz) + phase_s

    gnss_t = fix_times(gnss_hz, 0.013)
    ac_t = fix_times(acoustic_hz, 0.031)
    g_sig = _sigma_fn(gnss_sigma_m)(gnss_t)
    g_rep = g_sig if gnss_reported_sigma_m is None else _sigma_fn(gnss_reported_sigma_m)(gnss_t)
    a_sig = _sigma_fn(acoustic_sigma_m)(ac_t)
    # placeholder positions for the merge; the fixes are drawn along the truth below
    gnss = GnssEvents.from_sigma(gnss_t, np.zeros_like(gnss_t), np.zeros_like(gnss_t), g_rep) if gnss_hz else None
    ac = AcousticEvents.from_sigma(ac_t, np.zeros_like(ac_t), np.zeros_like(ac_t), a_sig) if acoustic_hz else None
    order = merge_events(steps, gnss, ac, t0_s=0.0)
    m = len(order)
    truth = np.empty((m, 6))
    pdr = np.empty((m, 2))
    x = truth0.copy()
    p = x0[:2].copy() + (truth0[:2] - x0[:2])       # PDR alone starts at the true start
    ge, gn = np.zeros(len(gnss_t)), np.zeros(len(gnss_t))
    ae, an = np.zeros(len(ac_t)), np.zeros(len(ac_t))
    for k in range(m):
        dt = order.dt_s[k]
        x[:2] += rng.normal(0.0, math.sqrt(cfg.q_walk_m2_s * dt), 2)
        x[2] += rng.normal(0.0, math.sqrt(cfg.q_heading_rad2_s * dt))
        x[3] += rng.normal(0.0, math.sqrt(cfg.q_scale_1_s * dt))
        bs = bias_sigma_m if not cfg.gnss_bias else cfg.bias_sigma_m
        btau = bias_tau_s if not cfg.gnss_bias else cfg.bias_tau_s
        if bs > 0:
            phi = math.exp(-dt / btau)
            x[4:6] = phi * x[4:6] + rng.normal(0.0, bs * math.sqrt(1 - phi * phi), 2)
        c, i = order.kind[k], order.index[k]
        if c == STEP:
            L = (1.0 + x[3]) * (len_m[i] + rng.normal(0.0, cfg.sigma_step_length_m))
            th = psi_m[i] + x[2] + rng.normal(0.0, cfg.sigma_heading_rad)
            x[0] += L * math.sin(th)
            x[1] += L * math.cos(th)
            p[0] += len_m[i] * math.sin(psi_m[i])
            p[1] += len_m[i] * math.cos(psi_m[i])
        elif c == GNSS:
            sig = g_sig[i] if gnss_sigma_at is None else float(gnss_sigma_at(x[0], x[1]))
            ge[i], gn[i] = x[:2] + x[4:6] + rng.normal(0.0, sig, 2)
        elif c == ACOUSTIC:
            ae[i], an[i] = x[:2] + rng.normal(0.0, a_sig[i], 2)
        truth[k] = x
        pdr[k] = p
    if gnss_hz:
        quality = None if gnss_quality is None else np.asarray(gnss_quality(gnss_t), int)
        gnss = GnssEvents.from_sigma(gnss_t, ge, gn, g_rep, hdop=np.full(len(gnss_t), 1.0), quality=quality)
    if acoustic_hz:
        ac = AcousticEvents.from_sigma(ac_t, ae, an, a_sig)
    stream = merge_events(steps, gnss, ac, t0_s=0.0)
    return Synth(stream, truth[:, :n_state] if cfg.gnss_bias else truth[:, :4], steps, gnss, ac, pdr, x0, P0)
