"""Which beacon was heard: acquisition, then tracking, of the receiver's position and clock offset.

Beacons share one chirp and are told apart by time alone (docs/beacon_protocol.md:
propagation crosses slots, slots are reused), so the search window of each
(frame, beacon) is narrowed as soon as the receiver knows where it is.
:class:`ClockPositionTracker` acquires by a Hough vote over position and clock
offset verified by least squares, then tracks position and the drifting clock
offset from fix to fix; :func:`frame_fix` turns a frame's detections into a fix.

This module holds the tracker's state machine: search windows, the lock
(acquisition → tentative → confirmed, :meth:`ClockPositionTracker.frame_done`)
and the clock's continuation from fix to fix. The vote and the re-acquisition
live in :mod:`features.acoustic.acquisition` (:class:`~features.acoustic.acquisition.HoughAcquisition`,
the tracker's base class, and :func:`~features.acoustic.acquisition.acquisition_windows`),
the per-frame fix in :mod:`features.acoustic.frame_fix`; :func:`frame_fix` and
:func:`acquisition_windows` are re-exported here.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from features.acoustic.acquisition import HoughAcquisition, acquisition_windows
from features.acoustic.air import AIR_UPDATE_MIN_SPEED_M_S, AirState
from features.acoustic.clock import ClockState
from features.acoustic.frame_fix import frame_fix, frame_ranges
from features.acoustic.positions import AcousticFix, PositionConfig
from features.acoustic.timing import AudioTiming, ChirpDetection, SearchWindow
from features.site import Site

__all__ = ["ClockPositionTracker", "ReceiverState", "frame_fix", "acquisition_windows"]


class ClockPositionTracker(HoughAcquisition):
    """Acquisition, then tracking, of the receiver's clock offset and position.

    Acquisition (no lock; attempted every other frame while it fails): beacon
    ``b``'s chirp may start anywhere in ``[tx − u, tx + u + r_max/c]``. These
    windows overlap several slots, so the arrivals in them are associated with
    beacons by :meth:`acquire` (Hough vote, least-squares verification). A fix
    on four or more beacons that passes the residual test is a *tentative*
    lock; the next frame, tracked from it, must confirm it: a sane fix on four
    or more beacons, within walking speed and clock drift of the tentative one,
    and either five beacons or more between the two fixes or, with the same
    four, both frames passing the strict static test (nothing excluded, 5 cm
    floor) within ``static_agreement_m`` — a standing receiver repeating a
    wrong association of four arrivals never confirms it. The confirmed
    tentative fix is then reported for its own frame
    (:meth:`take_confirmed_tentative`). After a confirmed lock the clock offset
    is known up to drift: a re-acquisition must agree with it within
    ``max_drift_ppm`` over the time since, plus 1 ms. With
    ``clock_aided_reacquisition`` (default) the re-acquisition instead votes over
    position alone with the clock filter's prediction (:meth:`_acquire_with_clock`),
    accepts ``reacquisition_min_beacons`` (4) with the clock prior, refuses a fix
    another solution fits as well (:meth:`mirror_free`), and is confirmed by a second
    sane fix on four beacons or more between the two frames (issue 11, defect 7).
    Tracked frames gate each arrival on its innovation at the constant-velocity
    prediction (:func:`~features.acoustic.frame_fix._innovation_gate`) before the
    exclusion, which may leave out up to ``track_excluded_share`` of the rest.

    Tracking (a fix at most ``track_timeout_s`` old): the window is centred on
    the arrival predicted from the last fix, ``tx + ‖p − s_b‖/c + δ``, with a
    half-width that grows with the fix's 3σ, a walking speed of
    ``max_speed_m_s`` and a clock drift of ``max_drift_ppm`` over the elapsed
    time; an NLOS first arrival may come up to ``nlos_slack_m`` later. Beacons
    predicted beyond ``r_max`` are not searched. The clock offset drifts (a
    sample clock off by 10 ppm gains 6 ms in 10 minutes), so it is tracked by a
    two-state offset + drift filter (:mod:`features.acoustic.clock`; Brown &
    Hwang's clock model): each tracked fix takes the predicted offset as a prior
    and its ranges are corrected for the drift within the frame, which leaves
    three beacons a degree of freedom for the residual test; three-beacon fixes
    that pass it carry the track on. (The one-state model before — last offset,
    σ² + (20 ppm·Δt)² — biased the clock 3–5σ at 50 ppm.) Once two
    fixes give a velocity, each frame's ranges are compensated for the motion
    during the frame (:func:`frame_fix`), the exclusion search prefers the
    subset nearest the constant-velocity prediction, and a fix farther from it
    than ``max_turn_speed_m_s``·dt plus 3σ is refused (an innovation gate).
    Fixes are reported only when sane: horizontal 1σ within ``max_fix_sigma_m``
    and rms residual within ``max_rms_m``.
    """

    max_speed_m_s = 2.5
    max_drift_ppm = 100.0
    nlos_slack_m = 10.0
    track_timeout_s = 4.0
    acquisition_min_beacons = 4
    reacquisition_min_beacons = 4
    clock_aided_reacquisition = True
    max_fix_sigma_m = 0.5
    residual_speed_m_s = 0.5
    max_turn_speed_m_s = 1.0
    static_agreement_m = 0.3
    max_rms_m = 0.5
    track_excluded_share = 0.4

    def __init__(self, site: Site, timing: AudioTiming, fs_hz: float, c: float, r_max: float,
                 positions: PositionConfig, range_lag_s: dict | None = None):
        self.site, self.timing, self.fs, self.c, self.r_max = site, timing, fs_hz, c, r_max
        # the recording's start, from which the clock's drift bound grows (kept when a cut of the recording
        # resumes this tracker: its own timing then starts later, :meth:`resumed`)
        self.clock_origin_s = timing.start_s
        # Beacon id -> the chirp's range–Doppler lag (ChirpSpec.range_doppler_lag_s): see frame_fix.
        self.range_lag_s = range_lag_s
        self.positions = positions
        self.order = sorted(range(len(site.beacons)), key=lambda i: (site.beacons[i].slot, site.beacons[i].id))
        # (index, slot offset s, east, north, up) of each beacon in slot order, for windows().
        self._beacon_geometry = [(i, site.beacons[i].slot * site.acoustic.slot_s, site.beacons[i].east_m,
                                  site.beacons[i].north_m, site.beacons[i].up_m) for i in self.order]
        self.last_fix: AcousticFix | None = None
        # Verifying a hypothesis may drop one wrongly associated beacon; more is a new hypothesis.
        # Acquisition keeps the static model whatever the motion prior: its tight residual
        # test is what rejects wrong associations; tracking uses ``positions`` as given.
        self._acquire_config = positions
        self._verify_config = dataclasses.replace(positions, motion_speed_m_s=0.0, max_excluded=1)
        # A tracked frame of a coverage deployment hears 8–18 beacons, several NLOS: up to
        # ``track_excluded_share`` of them may be excluded (lsq._backward_elimination).
        self._track_config = dataclasses.replace(
            positions, max_excluded_share=max(positions.max_excluded_share, self.track_excluded_share))
        self._strict_config = dataclasses.replace(positions, motion_speed_m_s=0.0, max_excluded=0)
        # With the velocity known from the track, what remains of the motion is its change over
        # a frame (turns, stops): at most ``residual_speed_m_s``.
        self._compensated_config = dataclasses.replace(
            self._track_config, motion_speed_m_s=min(positions.motion_speed_m_s, self.residual_speed_m_s))
        self._skip_acquisition = False
        self.confirmed = False
        self._previous_fix: AcousticFix | None = None
        self._confirmed_tentative: AcousticFix | None = None
        self._tentative_detections: list[ChirpDetection] = []
        self._tentative_ids: set = set()
        self._clock_anchor: tuple[float, float] | None = None
        self._clock: ClockState | None = None          # the two-state clock filter, from the first confirmed track
        self._anchor_fix: AcousticFix | None = None
        self._reacquired: AcousticFix | None = None       # the clock-aided vote's fix (_acquire_with_clock)
        self._tentative_clock_aided = False
        self._air: AirState | None = None                  # the air estimate (features.acoustic.air)
        self.mirror_refused = 0                            # re-acquisition fixes refused as ambiguous

    def resumed(self, timing: AudioTiming) -> "ClockPositionTracker":
        """A copy of this tracker for a later cut of the same recording whose samples start at ``timing``'s
        ``start_s`` (the clock's drift bound still grows from the recording's start)."""
        other = copy.deepcopy(self)
        other.timing = timing
        return other

    def tracking_at(self, t_s: float) -> bool:
        return self.last_fix is not None and t_s - self.last_fix.t_s <= self.track_timeout_s

    def windows(self, frame_start_s: float) -> list[SearchWindow]:
        """Search windows of the frame starting at ``frame_start_s``, one per beacon searched, in slot order."""
        u, fs, start_s, c = self.timing.start_uncertainty_s, self.fs, self.timing.start_s, self.c
        out = []
        if not self.tracking_at(frame_start_s):
            for i, slot_s, _, _, _ in self._beacon_geometry:
                tx = frame_start_s + slot_s
                out.append(SearchWindow(i, tx, math.floor((tx - u - start_s) * fs),
                                        math.ceil((tx + u + self.r_max / c - start_s) * fs)))
            return out
        fix = self.last_fix
        cov = fix.covariance
        sigma_h_m = math.sqrt(max(cov[0, 0], cov[1, 1], 0.0))        # per fix, not per beacon
        sigma_clock_s = math.sqrt(max(cov[2, 2], 0.0))
        e, n, h = fix.east_m, fix.north_m, self.site.device_height_m
        for i, slot_s, be, bn, bu in self._beacon_geometry:
            tx = frame_start_s + slot_s
            dt = tx - fix.t_s if tx > fix.t_s else 0.0
            radius_m = 3.0 * sigma_h_m + self.max_speed_m_s * dt + 0.5
            clock_s = 3.0 * sigma_clock_s + self.max_drift_ppm * 1e-6 * dt + 5e-4
            r = math.sqrt((e - be) ** 2 + (n - bn) ** 2 + (h - bu) ** 2)
            if r - radius_m > self.r_max:
                continue
            centre = tx + r / c + fix.clock_offset_s
            lo_s = centre - radius_m / c - clock_s
            hi_s = centre + (radius_m + self.nlos_slack_m) / c + clock_s
            out.append(SearchWindow(i, tx, math.floor((lo_s - start_s) * fs), math.ceil((hi_s - start_s) * fs),
                                    expected=round((centre - start_s) * fs)))
        return out

    def skip_acquisition(self) -> bool:
        """After a failed attempt the next frame skips acquisition (halves its cost while unlocked)."""
        if self.clock_aided_reacquisition and self._clock is not None:
            return False               # clock-aided re-acquisition votes over a disk: cheap, never skipped
        skip = self._skip_acquisition
        self._skip_acquisition = not skip
        return skip

    def _clock_plausible(self, fix: AcousticFix) -> bool:
        """|δ| within the stated start uncertainty, plus 5 ms and the drift allowed since the start."""
        bound = self.timing.start_uncertainty_s + 5e-3 + self.max_drift_ppm * 1e-6 * abs(fix.t_s - self.clock_origin_s)
        return abs(fix.clock_offset_s) <= bound

    def _continues(self, fix: AcousticFix, last: AcousticFix,
                   velocity: tuple[float, float] | None = None) -> bool:
        """Clock offset and position of ``fix`` within what drift and walking allow since ``last``.

        Without a velocity the receiver may have walked ``max_speed_m_s`` in any direction;
        with one (a confirmed track) the fix must lie near the constant-velocity prediction,
        within ``max_turn_speed_m_s``·dt (turns, stops) plus both fixes' 3σ: a gate on the
        innovation that catches a wrong subset kept by the exclusion search under poor geometry.
        """
        dt = max(0.0, fix.t_s - last.t_s)
        # 0.3 ms of slack, not more: a looser bound let a track's clock walk off by a
        # millisecond a frame, pulling the position metres away with it.
        clock_ok = abs(fix.clock_offset_s - last.clock_offset_s) <= (
            3.0 * math.sqrt(max(last.covariance[2, 2], 0.0) + max(fix.covariance[2, 2], 0.0))
            + self.max_drift_ppm * 1e-6 * dt + 3e-4)
        sigma = math.sqrt(max(last.covariance[0, 0] + last.covariance[1, 1]
                              + fix.covariance[0, 0] + fix.covariance[1, 1], 0.0))
        if velocity is None:
            moved_ok = math.hypot(fix.east_m - last.east_m, fix.north_m - last.north_m) <= (
                3.0 * sigma + self.max_speed_m_s * dt + 1.0)
        else:
            moved_ok = math.hypot(fix.east_m - last.east_m - velocity[0] * dt,
                                  fix.north_m - last.north_m - velocity[1] * dt) <= (
                3.0 * sigma + self.max_turn_speed_m_s * dt + 0.5)
        return clock_ok and moved_ok

    def _sane(self, fix: AcousticFix) -> bool:
        """A fix worth reporting: horizontal 1σ within ``max_fix_sigma_m``, rms residual within ``max_rms_m``."""
        cov = fix.covariance
        # Largest eigenvalue of the 2×2 horizontal covariance.
        half_tr, det = 0.5 * (cov[0, 0] + cov[1, 1]), cov[0, 0] * cov[1, 1] - cov[0, 1] ** 2
        lam = half_tr + math.sqrt(max(half_tr * half_tr - det, 0.0))
        return lam <= self.max_fix_sigma_m ** 2 and fix.rms_residual_m <= self.max_rms_m

    def frame_done(self, frame_start_s: float, detections: list[ChirpDetection],
                   bandwidth: dict) -> AcousticFix | None:
        """Fix of one frame, or None; updates the lock (acquisition → tentative → confirmed)."""
        tracking = self.tracking_at(frame_start_s)
        prior = None
        clock_pred = None
        drift = 0.0
        if tracking:
            # The two-state clock filter's offset at this frame's fix time, and its drift (features.acoustic.clock).
            clock_pred = self._clock_base().predict(self._fix_time(detections, frame_start_s))
            prior = (clock_pred.offset_s, math.sqrt(max(clock_pred.p00, 0.0) + 1e-14))
            drift = clock_pred.drift
        elif self.last_fix is not None:
            self.last_fix, self._previous_fix, self.confirmed = None, None, False   # lock lost: re-acquire
        reacquiring = not tracking and self.clock_aided_reacquisition and self._clock is not None
        if reacquiring:
            # Re-acquisition after a confirmed track: the clock filter's prediction is the prior
            # (three beacons then suffice; see _acquire_with_clock), at the fix's time.
            used = [d for d in detections if d.associated]
            t_fix = frame_start_s + 0.5 * self.site.acoustic.frame_s
            if used:
                lag = self.range_lag_s or {}
                t_fix = sum(d.arrival_s + lag.get(d.beacon_id, 0.0) for d in used) / len(used) \
                    - self._clock.predict(t_fix).offset_s
            clock_pred = self._clock.predict(t_fix)
            prior = (clock_pred.offset_s, math.sqrt(max(clock_pred.p00, 0.0) + 1e-14))
            drift = clock_pred.drift
        velocity = self._velocity() if tracking else None
        config = self._acquire_config if not tracking else (
            self._track_config if velocity is None else self._compensated_config)
        predicted = None
        if velocity is not None:
            # Constant-velocity prediction for the exclusion's choice of subset (see solve_position).
            last = self.last_fix
            dt = max(0.0, frame_start_s + 0.5 * self.site.acoustic.frame_s - last.t_s)
            predicted = (last.east_m + velocity[0] * dt, last.north_m + velocity[1] * dt, math.sqrt(
                last.covariance[0, 0] + last.covariance[1, 1] + (self.max_turn_speed_m_s * dt) ** 2 + 0.25))
        start = self.last_fix if tracking else (self._reacquired if reacquiring else None)
        air, config = self._air_for_frame(frame_start_s, config, predicted, start)
        fix = frame_fix(detections, self.site, self.c, bandwidth, config, start, prior, velocity, predicted,
                        self.range_lag_s, drift, air)
        if fix is None or not self._clock_plausible(fix):
            if tracking and not self.confirmed:
                self.last_fix = None                         # a tentative lock not confirmed is dropped
            return None
        if not tracking:
            # Acquisition: a tentative lock on four or more beacons that passed the residual test,
            # reported only once the next frame confirms it. After an earlier confirmed lock the
            # clock offset is known up to drift, which a wrong association rarely matches.
            least = self.reacquisition_min_beacons if reacquiring else self.acquisition_min_beacons
            if fix.n_beacons < least or not self._clock_continues(fix):
                return None
            if reacquiring or fix.n_beacons <= 5:
                used = [d for d in detections if d.associated and d.beacon_id in fix.used_ids]
                ranges, _ = frame_ranges(used, self.site, self.c, bandwidth, config, None, self.range_lag_s, drift)
                if not self.mirror_free(fix, (ranges, prior)):
                    self.mirror_refused += 1
                    return None
            self.last_fix, self.confirmed, self._tentative_ids = fix, False, set(fix.used_ids)
            self._tentative_detections = [d for d in detections if d.beacon_id in fix.used_ids]
            self._tentative_clock_aided = reacquiring
            if reacquiring:
                # Solved with the filter's prior: the fix's δ is the filter's posterior (no double counting).
                self._clock = clock_pred.conditioned(fix.clock_offset_s, float(fix.covariance[2, 2]))._replace(
                    t_s=fix.t_s)
            return None
        last = self.last_fix
        if not self._continues(fix, last, velocity):
            if not self.confirmed:
                self.last_fix = None
            return None
        if not self._sane(fix) or (fix.n_beacons < 4 and fix.rejected_ids):
            if not self.confirmed:
                self.last_fix = None
            return None
        if not self.confirmed:
            # Confirmation: a second sane fix on four or more beacons continuing the first, and
            # five beacons or more between the two, so that a standing receiver repeating one
            # wrong association of the same four arrivals never confirms it.
            if self._tentative_clock_aided:
                # With the clock known to µs a chance alignment of wrong arrivals must fit ranges, not
                # pseudoranges, twice: a second sane fix continuing it confirms, on four beacons or more
                # between the two frames.
                if len(self._tentative_ids | set(fix.used_ids)) < 4:
                    self.last_fix = None
                    return None
            elif fix.n_beacons < 4 or (len(self._tentative_ids | set(fix.used_ids)) < 5
                                       and not self._static_confirmation(detections, fix, bandwidth)):
                self.last_fix = None
                return None
            self.confirmed = True
            # The acquisition fix itself is reported only when it lies where the confirming fix
            # says the receiver was (walking speed, not the looser confirmation gate).
            dt = max(0.0, fix.t_s - last.t_s)
            if self._sane(last) and math.hypot(fix.east_m - last.east_m, fix.north_m - last.north_m) <= (
                    1.5 * dt + 3.0 * math.sqrt(max(fix.covariance[0, 0] + fix.covariance[1, 1], 0.0)) + 0.5):
                self._confirmed_tentative = last
        if velocity is not None and math.hypot(*velocity) >= AIR_UPDATE_MIN_SPEED_M_S:
            # The air is learnt from walking fixes: standing, the wearer's body shadows the beacons behind it
            # by a one-sided excess from a direction the receiver does not know, which looks like a wind.
            fix = self._update_air(fix, prior)
        # With the drift-aware clock prior a three-beacon fix keeps a degree of freedom for the residual
        # test (issue 11, defect 7): it carries the track on, as four or more do.
        self._previous_fix, self.last_fix = self.last_fix, fix
        self._clock_anchor = (fix.t_s, fix.clock_offset_s)
        self._anchor_fix = fix
        self._clock = clock_pred.conditioned(fix.clock_offset_s, float(fix.covariance[2, 2]))._replace(t_s=fix.t_s)
        return fix

    def _air_for_frame(self, t_s: float, config: PositionConfig, predicted, start):
        """((w_east, w_north), k, (east, north)) to correct this frame's ranges by (None before any position
        is known), and ``config`` with the estimate's σ as the air's consider parameters
        (:mod:`features.acoustic.air`)."""
        pos = self.positions
        if not (pos.estimate_air and pos.wind_sigma_m_s > 0 and pos.air_rel_sigma > 0):
            return None, config
        prior = AirState.prior(t_s, pos.wind_sigma_m_s, pos.air_rel_sigma)
        self._air = (self._air or prior).predict(t_s, prior)
        a = self._air
        config = dataclasses.replace(config, wind_sigma_m_s=min(a.wind_sigma_m_s, pos.wind_sigma_m_s),
                                     air_rel_sigma=min(a.scale_sigma, pos.air_rel_sigma))
        where = predicted[:2] if predicted is not None else (
            (start.east_m, start.north_m) if start is not None else None)
        return (None if where is None else ((float(a.x[0]), float(a.x[1])), float(a.x[2]), where)), config

    def _update_air(self, fix: AcousticFix, clock_prior) -> AcousticFix:
        """The air after a track's fix, and the fix moved by the air it implies."""
        if self._air is None:
            return fix
        self._air, (de, dn, dd) = self._air.update(fix.ranges, np.array([fix.east_m, fix.north_m,
                                                                         fix.clock_offset_s]),
                                                   self.site.device_height_m, self.c,
                                                   None if clock_prior is None else clock_prior[1])
        if de == 0.0 and dn == 0.0 and dd == 0.0:
            return fix
        return dataclasses.replace(fix, east_m=fix.east_m + de, north_m=fix.north_m + dn,
                                   clock_offset_s=fix.clock_offset_s + dd)

    def _clock_base(self) -> ClockState:
        """The clock filter's state including the last fix (a new lock's first fix, solved without
        the filter's prior, is an ordinary measurement of it; the very first starts the filter)."""
        st, last = self._clock, self.last_fix
        var = max(float(last.covariance[2, 2]), 0.0)
        if st is None:
            return ClockState.first(last.t_s, last.clock_offset_s, var)
        if st.t_s < last.t_s - 1e-9:
            return st.measured(last.t_s, last.clock_offset_s, var)
        return st

    def _fix_time(self, detections: list[ChirpDetection], frame_start_s: float) -> float:
        """The time the frame's fix will carry (:func:`frame_fix`), from the last fix's clock offset."""
        used = [d for d in detections if d.associated]
        if not used:
            return frame_start_s + 0.5 * self.site.acoustic.frame_s
        lag = self.range_lag_s or {}
        return sum(d.arrival_s + lag.get(d.beacon_id, 0.0) for d in used) / len(used) - self.last_fix.clock_offset_s

    def _static_confirmation(self, detections: list[ChirpDetection], fix: AcousticFix, bandwidth: dict) -> bool:
        """Four beacons only, the same in both frames: both frames pass the static residual test
        with nothing excluded (5 cm range floor, one degree of freedom each) and agree within
        ``static_agreement_m`` (each frame's beacons as its fix kept them). A chance alignment of wrong arrivals that survived the vote's
        1.5 m tolerance rarely fits to centimetres; a walker seeing the same four beacons does
        not stay within the agreement and waits for a fifth beacon.
        """
        a = frame_fix(self._tentative_detections, self.site, self.c, bandwidth, self._strict_config,
                      range_lag_s=self.range_lag_s)
        b = frame_fix([d for d in detections if d.beacon_id in fix.used_ids], self.site, self.c, bandwidth,
                      self._strict_config, range_lag_s=self.range_lag_s)
        return (a is not None and b is not None and min(a.n_beacons, b.n_beacons) >= 4
                and math.hypot(a.east_m - b.east_m, a.north_m - b.north_m) <= self.static_agreement_m)

    def take_confirmed_tentative(self) -> AcousticFix | None:
        """The acquisition fix the last :meth:`frame_done` confirmed (once), for its own frame."""
        fix, self._confirmed_tentative = self._confirmed_tentative, None
        return fix

    def _velocity(self) -> tuple[float, float] | None:
        """Receiver velocity (east, north), m/s, from the last two fixes of a confirmed track.

        None before two fixes at most ``track_timeout_s`` apart; clipped to ``max_speed_m_s``.
        """
        a, b = self._previous_fix, self.last_fix
        if not self.confirmed or a is None or b is None or not 0 < b.t_s - a.t_s <= self.track_timeout_s:
            return None
        dt = b.t_s - a.t_s
        ve, vn = (b.east_m - a.east_m) / dt, (b.north_m - a.north_m) / dt
        speed = math.hypot(ve, vn)
        if speed > self.max_speed_m_s:
            ve, vn = ve * self.max_speed_m_s / speed, vn * self.max_speed_m_s / speed
        return ve, vn

    def _clock_continues(self, fix: AcousticFix) -> bool:
        """Clock offset within the drift allowed since the last confirmed fix (always true before one)."""
        if self._clock_anchor is None:
            return True
        t0, d0 = self._clock_anchor
        return abs(fix.clock_offset_s - d0) <= self.max_drift_ppm * 1e-6 * abs(fix.t_s - t0) + 1e-3


@dataclass(frozen=True)
class ReceiverState:
    """The acoustic receiver's tracking state before TDMA frame ``frame`` (absolute: frame starts are
    ``frame_phase_s + frame·frame_s`` on the walk's time base whatever the cut): a copy of its ``tracker`` (lock,
    two-state clock filter, air estimate, acquisition memory). A run over a later cut of the same recording
    resumes from it at that frame (:func:`features.acoustic.detection.detect_frames`), so that from there on it
    detects and solves what the run over the whole recording does (a long walk's segments)."""

    frame: int
    tracker: ClockPositionTracker
    window_clock_s: float = 0.0
    """The clock offset :func:`features.acoustic.features.analyse_audio` places the chirps of this frame's
    detections in feature windows with, until the frame's own fix (the latest fix's before it; 0 before any): a
    stretch without fixes across a cut's resumption would otherwise place them by the cut's own warm-up fixes."""
