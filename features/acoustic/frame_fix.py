"""One frame's position fix: a frame's detections → motion-, lag-, drift- and torso-corrected
pseudoranges (:func:`frame_ranges`), gated on their innovation at the track's prediction
(:func:`_innovation_gate`), solved by :func:`features.acoustic.positions.solve_position`
(:func:`frame_fix`). The tracker calling it each frame is
:class:`features.acoustic.tracking.ClockPositionTracker`.
"""

from __future__ import annotations

import math

from features.acoustic.positions import AcousticFix, BeaconRange, PositionConfig, solve_position, toa_range_sigma_m
from features.acoustic.timing import ChirpDetection
from features.acoustic.air import air_range_corrections_m
from features.site import Site

__all__ = ["frame_fix", "frame_ranges", "TORSO_RADIUS_M"]


TORSO_RADIUS_M = 0.13
"""Radius of the cylinder a waist-worn receiver's torso is taken for, m (half the median adult waist
depth, 0.22–0.25 m for women and men; ANSUR II anthropometric survey, Gordon et al. 2014): see :func:`frame_ranges`."""


def frame_fix(detections: list[ChirpDetection], site: Site, c: float, bandwidth: dict,
              config: PositionConfig, start: AcousticFix | None = None,
              clock_prior: tuple[float, float] | None = None,
              velocity_m_s: tuple[float, float] | None = None,
              position_prior: tuple[float, float, float] | None = None,
              range_lag_s: dict | None = None, clock_drift: float = 0.0,
              air: tuple | None = None) -> AcousticFix | None:
    """Position fix from one frame's detections (None when fewer than three beacons).

    ``start``: the previous fix (initial value); ``clock_prior``: (δ, σ_δ) of a tracked clock;
    ``velocity_m_s``: (east, north) velocity of the receiver during the frame, known from the
    track. A frame's chirps arrive up to a frame apart, so the receiver at arrival i stood at
    p + v·(tᵢ − t̄); since ‖p + v·(tᵢ − t̄) − sᵢ‖ = ‖p − (sᵢ − v·(tᵢ − t̄))‖, each beacon is
    moved by −v·(tᵢ − t̄) and the fix p is the position at the mean arrival time t̄, which
    is also its time tag (``t_s`` = t̄ − δ), whichever beacons the exclusion then keeps: the
    excluded ones are usually the far, late ones, and a tag from the kept beacons alone was
    0.10 s early on 75 % of walk fixes (issue 11, defect 1).

    ``range_lag_s``: beacon id → the range–Doppler lag λ of its chirp
    (:attr:`~features.acoustic.matched_filter.ChirpSpec.range_doppler_lag_s`). A moving
    receiver's linear-chirp range is the range λ after the arrival (38 ms for the default
    chirp, 5 cm at walking pace), so each range is taken at tᵢ = arrivalᵢ + λᵢ, for the motion
    compensation and for the time tag alike; no velocity is needed, and with every beacon on
    one chirp the correction is a shift of the tag by λ.

    ``clock_drift``: the receiver clock's drift δ̇ (s/s, from the tracker's clock filter). The
    offset at arrival i is δ + δ̇·(tᵢ − t̄), so each pseudorange loses c·δ̇·(tᵢ − t̄) and the fix's
    δ is the offset at t̄ (100 ppm over a 2 s frame is ±3.4 cm of range otherwise).

    ``air``: ((w_east, w_north), k, (east, north)) — the tracker's estimate of the wind (m/s) and of the
    sound-speed scale, and where the receiver is thought to be; each pseudorange gets back what the air
    took off it (:func:`features.acoustic.air.air_range_corrections_m`).
    """
    used = [d for d in detections if d.associated]
    if len(used) < 3:
        return None
    ranges, t_mean = frame_ranges(used, site, c, bandwidth, config, velocity_m_s, range_lag_s, clock_drift,
                                  position_prior)
    if air is not None:
        dr = air_range_corrections_m(air[0], air[1], air[2], [(r.east_m, r.north_m, r.up_m) for r in ranges],
                                     site.device_height_m, c).tolist()
        ranges = [r._replace(pseudorange_m=r.pseudorange_m + d) for r, d in zip(ranges, dr)]
    if position_prior is not None and clock_prior is not None:
        ranges = _innovation_gate(ranges, site.device_height_m, c, position_prior, clock_prior)
    # Start from the previous fix, moved to the track's prediction when there is one (fewer iterations).
    if start is None:
        x0 = None
    elif position_prior is not None:
        x0 = (position_prior[0], position_prior[1], start.clock_offset_s)
    else:
        x0 = (start.east_m, start.north_m, start.clock_offset_s)
    return solve_position(ranges, site, c, config, x0, clock_prior, position_prior,
                          t_ref_s=t_mean if velocity_m_s is not None else None)


def _innovation_gate(ranges: list[BeaconRange], h: float, c: float, position_prior, clock_prior,
                     k: float = 3.0, nlos_m: float = 1.0) -> list[BeaconRange]:
    """The ranges whose innovation at the track's prediction is within the gate (Bar-Shalom, Li &
    Kirubarajan 2001, §2.4.3 validation gate), or all of them when fewer than three would remain.

    ν = ρᵢ − ‖p̂ − sᵢ‖ − c·δ̂ must lie within −k·s … k·s + ``nlos_m`` (an NLOS first path is
    late, never early), s² = σ_p² + σᵢ² + (c·σ_δ)² with σ_p the prediction's horizontal σ. A
    coverage deployment's tracked frame holds 8–18 arrivals of which 2–4 are another beacon's
    chirp or an echo, metres off: left to the exclusion they exhausted its budget and cost the
    frame its fix.
    """
    pe, pn, ps = position_prior
    d0, sd = clock_prior
    kept = []
    for r in ranges:
        nu = r.pseudorange_m - math.sqrt((pe - r.east_m) ** 2 + (pn - r.north_m) ** 2 + (h - r.up_m) ** 2) - c * d0
        gate = k * math.sqrt(ps * ps + r.sigma_m * r.sigma_m + (c * sd) ** 2)
        if -gate <= nu <= gate + nlos_m:
            kept.append(r)
    return kept if len(kept) >= 3 else ranges


def frame_ranges(used: list[ChirpDetection], site: Site, c: float, bandwidth: dict, config: PositionConfig,
                 velocity_m_s=None, range_lag_s: dict | None = None, clock_drift: float = 0.0,
                 position_en=None) -> tuple[list[BeaconRange], float]:
    """The pseudoranges of :func:`frame_fix` (motion-, lag- and drift-compensated) and their mean time t̄.

    The wearer's body. A waist-worn device hears a beacon behind the wearer only round the torso:
    the creeping path round a cylinder of radius R is R·(θ − π/2) longer for a beacon θ off the
    walking direction (θ > π/2; Keller 1962, geometrical theory of diffraction), 0.1–0.3 m for a
    torso of 0.22–0.25 m waist depth (ANSUR II means, women and men: R ≈ :data:`TORSO_RADIUS_M`).
    While walking (≥ 0.5 m/s, the direction from the track's velocity, the position from its
    prediction ``position_en``) that excess is taken off the range and a third of it added as σ
    (the radius and the device's place on the belt vary). Left uncorrected, beacons behind read
    long and the fix leads the walker: on the coverage deployment's walks the fixes stood
    0.14 m ahead (0.13 s of "time-tag lag" at walking pace).
    """
    by_id = site.beacon_by_id
    lag = range_lag_s or {}
    t_range = [d.arrival_s + lag.get(d.beacon_id, 0.0) for d in used]
    t_mean = sum(t_range) / len(used)
    ve, vn = (0.0, 0.0) if velocity_m_s is None else velocity_m_s
    # Walking during the frame: σᵢ² += ½·(v·(tᵢ − t̄))² (see PositionConfig; v = 0 when standing).
    v_motion = config.motion_speed_m_s if config.motion_speed_m_s > 0 else 0.0
    ranges = []
    speed = math.hypot(ve, vn)
    body = position_en is not None and speed >= 0.5
    for d, t_i in zip(used, t_range):
        b, dt = by_id[d.beacon_id], t_i - t_mean
        sigma_m = toa_range_sigma_m(d.snr_db, bandwidth[d.beacon_id], c)
        rho = c * (d.arrival_s - d.tx_s - clock_drift * dt)
        # The air's path-by-path error scales with the range (PositionConfig.path_rel_sigma).
        var = sigma_m * sigma_m + (config.path_rel_sigma * rho) ** 2
        if v_motion:
            var += 0.5 * (v_motion * dt) ** 2
        if body:
            be, bn = b.east_m - position_en[0], b.north_m - position_en[1]
            dist = math.hypot(be, bn)
            if dist > 0:
                theta = math.acos(max(-1.0, min(1.0, (be * ve + bn * vn) / (dist * speed))))
                if theta > 0.5 * math.pi:
                    excess = TORSO_RADIUS_M * (theta - 0.5 * math.pi)
                    rho -= excess
                    var += (excess / 3.0) ** 2
        ranges.append(BeaconRange(d.beacon_id, b.east_m - ve * dt, b.north_m - vn * dt, b.up_m, rho,
                                  math.sqrt(var), t_i))
    return ranges, t_mean
