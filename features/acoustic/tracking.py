"""Which beacon was heard: acquisition, then tracking, of the receiver's position and clock offset.

Beacons share one chirp and are told apart by time alone (docs/beacon_protocol.md:
propagation crosses slots, slots are reused), so the search window of each
(frame, beacon) is narrowed as soon as the receiver knows where it is.
:class:`ClockPositionTracker` acquires by a Hough vote over position and clock
offset verified by least squares, then tracks position and the drifting clock
offset from fix to fix; :func:`frame_fix` turns a frame's detections into a fix.
"""

from __future__ import annotations

import dataclasses
import math
import statistics

import numpy as np

from features.acoustic.clock import ClockState
from features.acoustic.positions import (AcousticFix, BeaconRange, PositionConfig, _chi2_limit,
                                        _gauss_newton, solve_position, toa_range_sigma_m)
from features.acoustic.timing import AudioTiming, ChirpDetection, SearchWindow
from features.site import Site

__all__ = ["ClockPositionTracker", "frame_fix", "acquisition_windows"]


class ClockPositionTracker:
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
    prediction (:func:`_innovation_gate`) before the exclusion, which may leave out up
    to ``track_excluded_share`` of the rest.

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
        # ``track_excluded_share`` of them may be excluded (positions._backward_elimination).
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
        self.mirror_refused = 0                            # re-acquisition fixes refused as ambiguous

    @property
    def grid_step_m(self) -> float:
        """Spacing of the acquisition grid, m: 1 m, coarser on sites above 10 000 m²."""
        g = self.site.grid
        return max(1.0, math.sqrt((g.east_max_m - g.east_min_m) * (g.north_max_m - g.north_min_m) / 10_000))

    @property
    def tolerance_s(self) -> float:
        """Agreement tolerance of the vote: the range error of the nearest grid point, plus 0.5 ms."""
        return self.grid_step_m * math.sqrt(2.0) / self.c + 5e-4

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

    def acquire(self, candidates: dict) -> dict:
        """Associate candidate arrivals with beacons by a Hough vote over position and clock offset.

        ``candidates`` maps a beacon index to (tx_s, stated arrival times, s) of
        the envelope maxima in its acquisition window. For each point p of a
        grid over the site, each candidate implies a clock offset
        δ = (c·(t − tx) − ‖p − s_b‖)/c; the (p, δ) on which the most beacons
        agree within ``tol`` wins (a Hough transform, Duda & Hart 1972, CACM
        15(1)); ties go to the smallest δ, since echoes agree with each other
        too, only later. The vote runs on a 4 m grid, then on a 1 m grid round
        the best coarse points. Each beacon keeps its earliest candidate within
        ``tol`` of the median δ of the winning group, and :meth:`_refine`
        re-associates after a least-squares fix. After a lost lock the vote covers
        only the disk the receiver can have reached since (:meth:`_search_disk`),
        with only the candidates that fit the anchored clock (:meth:`_clock_consistent`).
        Returns beacon index → arrival time.
        """
        items = [(i, tx, t) for i, (tx, times) in candidates.items() for t in times]
        self._reacquired = None
        if self.clock_aided_reacquisition and self._clock is not None and items:
            t_end = max((tx for tx, _ in candidates.values()), default=0.0) + self.r_max / self.c
            if self._search_disk(t_end) is not None:
                return self._acquire_with_clock(items)
        g = self.site.grid
        coarse = 4.0 * self.grid_step_m
        # The last beacon of the frame is heard up to r_max/c after its emission: the disk must hold
        # the receiver until then.
        disk = self._search_disk(max((tx for tx, _ in candidates.values()), default=0.0) + self.r_max / self.c)
        if disk is not None:
            items = self._clock_consistent(items, disk)
        # A fix needs four beacons (see _refine): with fewer candidates no vote can succeed.
        if len({i for i, _, _ in items}) < 4:
            return {}
        bi = np.array([i for i, _, _ in items])
        rho = self.c * np.array([t - tx for _, tx, t in items])
        bpos = np.array([[self.site.beacons[i].east_m, self.site.beacons[i].north_m, self.site.beacons[i].up_m]
                         for i in bi])
        ee, nn = np.meshgrid(np.arange(g.east_min_m, g.east_max_m + coarse, coarse),
                             np.arange(g.north_min_m, g.north_max_m + coarse, coarse))
        ee, nn = ee.ravel(), nn.ravel()
        if disk is not None:
            # Every point within the disk has a grid point within coarse/√2 of it.
            inside = np.hypot(ee - disk[0], nn - disk[1]) <= disk[2] + coarse / math.sqrt(2.0)
            ee, nn = ee[inside], nn[inside]
            if len(ee) == 0:
                return {}
        arrivals = np.array([t for _, _, t in items])
        hyps = self._vote(ee, nn, bi, rho, bpos, coarse * math.sqrt(2.0) / self.c + 5e-4, arrivals)
        if not hyps:
            return {}
        fine = self.grid_step_m
        offsets = np.arange(-coarse, coarse + fine / 2, fine)
        oe, on = np.meshgrid(offsets, offsets)
        seeds = []
        for h in hyps:
            if h[0] >= 3 and h[2] not in seeds:
                seeds.append(h[2])
            if len(seeds) == 30:
                break
        if not seeds:
            return {}
        pe = np.concatenate([s[0] + oe.ravel() for s in seeds])
        pn = np.concatenate([s[1] + on.ravel() for s in seeds])
        # Neighbouring seeds' fine grids overlap: each point once (first occurrence, order kept).
        _, first = np.unique(np.round(np.column_stack([pe, pn]) / fine).astype(np.int64), axis=0, return_index=True)
        first.sort()
        pe, pn = pe[first], pn[first]
        hyps = self._vote(pe, pn, bi, rho, bpos, self.tolerance_s, arrivals, n_best=400)
        # Verify the best distinct hypotheses by least squares (RANSAC-style, Fischler & Bolles
        # 1981): the one whose fix keeps the most beacons, then the smallest residual, wins.
        best, best_key, tried = {}, None, []
        for n, _, point, member_delta in hyps:
            # Hypotheses come by decreasing vote; one two votes short of the best verified fix
            # has never been seen to beat it (re-association adds a beacon at most), so stop.
            if n < 3 or len(tried) >= 12 or (best_key is not None and n + 1 < best_key[0]):
                break
            d0 = statistics.median(member_delta.tolist())
            if any(abs(point[0] - p[0]) < 2 and abs(point[1] - p[1]) < 2 and abs(d0 - q) < 2e-3 for p, q in tried):
                continue
            tried.append((point, d0))
            kept = self._associate(point, d0, bi, rho, bpos, items)
            refined, fix = self._refine(kept, candidates)
            if fix is None:
                continue
            key = (fix.n_beacons, -fix.rms_residual_m)
            if best_key is None or key > best_key:
                best, best_key = refined, key
        return best

    def _acquire_with_clock(self, items: list) -> dict:
        """Re-acquisition with the clock known (issue 11, defect 7): a vote over position alone.

        Only within the search disk of :meth:`_search_disk` (the receiver can have walked at most
        ``max_speed_m_s`` since the anchoring fix); beyond it the full vote of :meth:`acquire` runs.

        After a confirmed track the two-state clock filter (:mod:`features.acoustic.clock`) predicts
        δ to σ_δ (10 ppm of drift known to ~1 ppm: tens of µs after a minute), so each candidate
        arrival is a range ρ − c·δ̂, not a pseudorange, and a grid point p gets the vote of every
        beacon with a candidate within ``tol`` of ‖p − s_b‖ (tol = half the grid diagonal plus
        3·c·σ_δ plus 0.3 m): the Hough transform of :meth:`acquire` with the clock dimension
        collapsed, far fewer chance alignments, and three beacons enough. The best few points
        (distinct by 3 m) are solved by least squares with the clock prior (3 beacons leave one
        degree of freedom); the fix keeping most beacons, then the smallest rms, wins. The solution
        is kept for :meth:`frame_done` (its start, and the mirror-solution check).
        """
        t_frame = sum(tx for _, tx, _ in items) / len(items) + 0.5 * self.r_max / self.c
        clock = self._clock.predict(t_frame)
        sigma_d = math.sqrt(max(clock.p00, 0.0))
        disk = self._search_disk(t_frame + 0.5 * self.r_max / self.c)
        if disk is None:
            return {}
        g, h, c = self.site.grid, self.site.device_height_m, self.c
        step = self.grid_step_m
        ee, nn = np.meshgrid(np.arange(g.east_min_m, g.east_max_m + step, step),
                             np.arange(g.north_min_m, g.north_max_m + step, step))
        ee, nn = ee.ravel(), nn.ravel()
        if disk is not None:
            inside = np.hypot(ee - disk[0], nn - disk[1]) <= disk[2] + step
            ee, nn = ee[inside], nn[inside]
        if len(ee) == 0:
            return {}
        items = sorted(items)                                        # by beacon index, then time
        bi = np.array([i for i, _, _ in items])
        rng_m = c * (np.array([t - tx for _, tx, t in items]) - clock.offset_s)
        b = self.site.beacons
        bpos = np.array([[b[i].east_m, b[i].north_m, b[i].up_m] for i in bi])
        tol = step / math.sqrt(2.0) + 3.0 * c * sigma_d + 0.3
        r = np.sqrt((ee[:, None] - bpos[None, :, 0]) ** 2 + (nn[:, None] - bpos[None, :, 1]) ** 2
                    + (h - bpos[None, :, 2]) ** 2)
        agree = np.abs(rng_m[None, :] - r) <= tol                   # (n_points, n_candidates)
        starts = np.flatnonzero(np.r_[True, bi[1:] != bi[:-1]])
        votes = np.logical_or.reduceat(agree, starts, axis=1).sum(axis=1)   # distinct beacons per point
        order = np.argsort(-votes, kind="stable")
        seeds: list = []
        for k in order[:400].tolist():
            if votes[k] < 3 or len(seeds) >= 6:
                break
            if all(math.hypot(ee[k] - p[0], nn[k] - p[1]) > 3.0 for p in seeds):
                seeds.append((float(ee[k]), float(nn[k])))
        best, best_key = {}, None
        prior = (clock.offset_s, math.sqrt(clock.p00 + 1e-14))
        for pe, pn in seeds:
            rr = np.sqrt((pe - bpos[:, 0]) ** 2 + (pn - bpos[:, 1]) ** 2 + (h - bpos[:, 2]) ** 2)
            chosen: dict = {}
            for k, i in enumerate(bi.tolist()):
                if abs(rng_m[k] - rr[k]) <= tol and (i not in chosen or items[k][2] < chosen[i]):
                    chosen[i] = items[k][2]                          # the earliest: echoes come later
            # The frame's chirps are heard up to a frame apart while the receiver walks: the range
            # variance takes the walking term of PositionConfig (½·(v·(tᵢ − t̄))²).
            t_bar = sum(chosen.values()) / max(len(chosen), 1)
            v = self._track_config.motion_speed_m_s
            ranges = [BeaconRange(b[i].id, b[i].east_m, b[i].north_m, b[i].up_m, c * (t - self._tx_of(items, i, t)),
                                  math.sqrt(0.05 ** 2 + 0.5 * (v * (t - t_bar)) ** 2), t) for i, t in chosen.items()]
            fix = solve_position(ranges, self.site, c, self._verify_config, np.array([pe, pn, clock.offset_s]),
                                 prior) if len(ranges) >= 3 else None
            if fix is None or math.hypot(fix.east_m - pe, fix.north_m - pn) > 2.0 * tol + step:
                continue
            key = (fix.n_beacons, -fix.rms_residual_m)
            if best_key is None or key > best_key:
                kept = {i: t for i, t in chosen.items() if b[i].id in fix.used_ids}
                best, best_key, self._reacquired = kept, key, fix
        return best

    @staticmethod
    def _tx_of(items: list, i: int, t: float) -> float:
        """Emission time of beacon ``i``'s candidate arrival ``t`` among the (index, tx, t) items."""
        return next(tx for j, tx, tt in items if j == i and tt == t)

    def mirror_free(self, fix: AcousticFix, ranges_fix) -> bool:
        """No second solution fits the same beacons (the mirror-solution check).

        A pseudorange fix on few beacons can have two solutions (Abel & Chaffee 1991, IEEE Trans.
        AES 27(6); with three beacons and a free clock both fit exactly). Gauss-Newton is started
        from the fix mirrored across the beacons' principal axis and through their centroid, and
        from the four quarters of the site (with the clock prior); if any converges more than 1 m away, outside every solid
        structure of the site's layout, and passes the same chi-square test, the fix is ambiguous
        and refused. Beacons heard in a line (wall mounts along one face) mirror a fix across it
        at any number of beacons.
        """
        ranges, prior = ranges_fix
        h, c = self.site.device_height_m, self.c
        xy = np.array([[r.east_m, r.north_m] for r in ranges])
        centre = xy.mean(axis=0)
        # The mirror image across the beacons' principal axis (their line, when they stand in one).
        _, vecs = np.linalg.eigh((xy - centre).T @ (xy - centre))
        u = vecs[:, -1]
        p = np.array([fix.east_m, fix.north_m]) - centre
        mirror = centre + 2.0 * (u @ p) * u - p
        g = self.site.grid
        starts = [(float(mirror[0]), float(mirror[1])), (2 * centre[0] - fix.east_m, 2 * centre[1] - fix.north_m)] + [
            (g.east_min_m + fe * (g.east_max_m - g.east_min_m), g.north_min_m + fn * (g.north_max_m - g.north_min_m))
            for fe in (0.25, 0.75) for fn in (0.25, 0.75)]
        dof = len(ranges) + (prior is not None) - 3
        limit = _chi2_limit(dof, self._verify_config.chi2_alpha) if dof > 0 else math.inf
        for e0, n0 in starts:
            sol = _gauss_newton(ranges, h, c, self._verify_config.max_iterations,
                                np.array([e0, n0, fix.clock_offset_s]), prior)
            if sol is None:
                continue
            x, _, _, _, chi2 = sol
            if (math.hypot(x[0] - fix.east_m, x[1] - fix.north_m) > 1.0 and chi2 <= limit and _inside(x, self.site)
                    and not self._in_solid(x)):
                return False
        return True

    def _in_solid(self, x) -> bool:
        """Whether (east, north) lies inside a solid box of the layout (no receiver can be there)."""
        return any(not b.porous and b.east_min_m < x[0] < b.east_max_m and b.north_min_m < x[1] < b.north_max_m
                   for b in self.site.layout)

    def _search_disk(self, t_s: float) -> tuple[float, float, float] | None:
        """(east, north, radius) the receiver can have reached by ``t_s`` since the last fix that
        anchored the clock, at ``max_speed_m_s`` plus that fix's 3σ and 1 m; None (search the
        whole site) before any such fix or once the disk would cover half the site's diagonal.
        Re-acquisition after a lost lock then votes over a few grid points instead of the site.
        """
        fix = self._anchor_fix
        if fix is None:
            return None
        sigma = math.sqrt(max(fix.covariance[0, 0] + fix.covariance[1, 1], 0.0))
        radius = 3.0 * sigma + self.max_speed_m_s * max(0.0, t_s - fix.t_s) + 1.0
        g = self.site.grid
        if radius >= 0.5 * math.hypot(g.east_max_m - g.east_min_m, g.north_max_m - g.north_min_m):
            return None
        return fix.east_m, fix.north_m, radius

    def _clock_consistent(self, items: list, disk: tuple[float, float, float]) -> list:
        """The candidate arrivals (beacon index, tx, t) whose implied clock offset, somewhere in
        ``disk``, lies within the drift bound of the anchored clock (:meth:`_clock_continues`):
        from the disk's centre a beacon at range r is between r − R and r + R away."""
        t0, d0 = self._clock_anchor
        e, n, radius = disk
        h = self.site.device_height_m
        out = []
        for i, tx, t in items:
            b = self.site.beacons[i]
            r = math.sqrt((e - b.east_m) ** 2 + (n - b.north_m) ** 2 + (h - b.up_m) ** 2)
            delta = t - tx - r / self.c                        # implied offset at the disk's centre
            bound = self.max_drift_ppm * 1e-6 * abs(tx - t0) + 1e-3 + radius / self.c
            if abs(delta - d0) <= bound:
                out.append((i, tx, t))
        return out

    def _associate(self, point, d0, bi, rho, bpos, items) -> dict:
        """Each beacon's earliest candidate within ``tol`` of δ = d0 at ``point``; one arrival, one beacon."""
        r = np.sqrt((point[0] - bpos[:, 0]) ** 2 + (point[1] - bpos[:, 1]) ** 2
                    + (self.site.device_height_m - bpos[:, 2]) ** 2)
        delta = (rho - r) / self.c
        chosen = {}
        for k, i in enumerate(bi):
            # Within the tolerance, the earliest candidate: echoes come later.
            if abs(delta[k] - d0) <= self.tolerance_s and (i not in chosen or items[k][2] < chosen[i][0]):
                chosen[i] = (items[k][2], abs(delta[k] - d0))
        # One arrival belongs to one beacon: where two beacons took the same arrival (within
        # 1 ms), the one whose δ fits the vote better keeps it.
        kept = {}
        for i, (t, err) in sorted(chosen.items(), key=lambda kv: kv[1][1]):
            if all(abs(t - t2) > 1e-3 for t2 in kept.values()):
                kept[i] = t
        return kept

    def _refine(self, kept: dict, candidates: dict):
        """Least-squares refinement of a voted association, then re-association: (association, fix).

        The vote's grid leaves each beacon's δ off by up to the tolerance, so an
        echo 4 ms late can pass for the first path. A Gauss-Newton fix (with
        exclusion) on the voted arrivals gives position and δ to centimetres;
        each beacon then takes the candidate nearest its predicted arrival,
        within 1.5 ms. Without a fix (fewer than four beacons, or none
        plausible) the association is returned with ``None``.
        """
        b = self.site.beacons
        ranges = [BeaconRange(b[i].id, b[i].east_m, b[i].north_m, b[i].up_m, self.c * (t - candidates[i][0]), 0.05, t)
                  for i, t in kept.items()]
        fix = solve_position(ranges, self.site, self.c, self._verify_config) if len(ranges) >= 4 else None
        if fix is None or fix.n_beacons < 4:
            return kept, None
        out = {}
        for i, (tx, times) in candidates.items():
            pred = tx + math.dist((fix.east_m, fix.north_m, self.site.device_height_m),
                                  (b[i].east_m, b[i].north_m, b[i].up_m)) / self.c + fix.clock_offset_s
            t_best = min(times, key=lambda t: abs(t - pred))
            if abs(t_best - pred) <= 1.5e-3:
                out[i] = t_best
        return (out if len(out) >= fix.n_beacons else kept), fix

    def _vote(self, pe, pn, bi, rho, bpos, tol, arrivals, n_best: int = 200) -> list:
        """Hypotheses (distinct beacons, anchor δ, (east, north), δ of the agreeing) best first.

        Candidates agreeing with an anchor's δ within [δ, δ + tol] are counted
        for all (point, anchor) pairs at once — each row sorted, then one global
        searchsorted on rows offset far apart — and the ``n_best`` largest counts
        are recounted as distinct beacons (a beacon's echoes must not vote twice)
        using distinct arrivals (one arrival heard in several beacons' windows
        must not vote for each of them).
        """
        r = np.sqrt((pe[:, None] - bpos[None, :, 0]) ** 2 + (pn[:, None] - bpos[None, :, 1]) ** 2
                    + (self.site.device_height_m - bpos[None, :, 2]) ** 2)
        delta = (rho[None, :] - r) / self.c                      # (n_points, n_candidates)
        order = np.argsort(delta, axis=1)
        sorted_delta = np.take_along_axis(delta, order, axis=1)
        offset = 2.0 * (np.abs(delta).max() + tol + 1.0)
        flat = (sorted_delta + offset * np.arange(len(pe))[:, None]).ravel()
        hi = np.searchsorted(flat, flat + tol, side="right")
        count = hi - np.arange(flat.size)
        top = _top_stable(count, n_best)
        hyps = []
        n_cand = delta.shape[1]
        beacon_of = bi.tolist()
        arrival_of = np.round(arrivals, 4).tolist()
        for f, n in zip(top.tolist(), count[top].tolist()):
            row, k = divmod(f, n_cand)
            members = order[row, k: k + n]
            m = members.tolist()
            # Distinct beacons, but one physical arrival cannot serve two beacons.
            n_distinct = min(len({beacon_of[i] for i in m}), len({arrival_of[i] for i in m}))
            first, last = sorted_delta[row, k], sorted_delta[row, k + n - 1]
            hyps.append((n_distinct, float(first), row, members, float(last - first)))
        # Among equal counts the tightest agreement first: a hypothesis that is only just within
        # the tolerance is usually a chance alignment (ordering by smallest δ instead buried
        # the true one under chance alignments whenever the clock offset was positive).
        hyps.sort(key=lambda h: (-h[0], h[4], h[1]))
        return [(n, d, (float(pe[row]), float(pn[row])), delta[row, members]) for n, d, row, members, _ in hyps]

    def skip_acquisition(self) -> bool:
        """After a failed attempt the next frame skips acquisition (halves its cost while unlocked)."""
        if self.clock_aided_reacquisition and self._clock is not None:
            return False               # clock-aided re-acquisition votes over a disk: cheap, never skipped
        skip = self._skip_acquisition
        self._skip_acquisition = not skip
        return skip

    def _clock_plausible(self, fix: AcousticFix) -> bool:
        """|δ| within the stated start uncertainty, plus 5 ms and the drift allowed since the start."""
        bound = self.timing.start_uncertainty_s + 5e-3 + self.max_drift_ppm * 1e-6 * abs(fix.t_s - self.timing.start_s)
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
        fix = frame_fix(detections, self.site, self.c, bandwidth, config, start, prior, velocity, predicted,
                        self.range_lag_s, drift)
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
        # With the drift-aware clock prior a three-beacon fix keeps a degree of freedom for the residual
        # test (issue 11, defect 7): it carries the track on, as four or more do.
        self._previous_fix, self.last_fix = self.last_fix, fix
        self._clock_anchor = (fix.t_s, fix.clock_offset_s)
        self._anchor_fix = fix
        self._clock = clock_pred.conditioned(fix.clock_offset_s, float(fix.covariance[2, 2]))._replace(t_s=fix.t_s)
        return fix

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


TORSO_RADIUS_M = 0.13
"""Radius of the cylinder a waist-worn receiver's torso is taken for, m (half the median adult waist
depth, 0.22–0.25 m for women and men; ANSUR II anthropometric survey, Gordon et al. 2014): see :func:`frame_ranges`."""


def _inside(x, site: Site, margin_m: float = 5.0) -> bool:
    g = site.grid
    return (g.east_min_m - margin_m <= x[0] <= g.east_max_m + margin_m
            and g.north_min_m - margin_m <= x[1] <= g.north_max_m + margin_m)


def _top_stable(values: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` largest ``values``, largest first, ties in index order.

    Equals ``np.argsort(-values, kind="stable")[:k]`` but costs a partition, not a
    sort of every (grid point, anchor) pair of the vote.

    >>> _top_stable(np.array([3, 1, 3, 2, 3, 0]), 2).tolist()
    [0, 2]
    """
    n = len(values)
    if k >= n:
        return np.argsort(-values, kind="stable")
    kth = np.partition(values, n - k)[n - k]          # the k-th largest value
    above = np.flatnonzero(values > kth)
    tied = np.flatnonzero(values == kth)[: k - len(above)]
    chosen = np.concatenate([above, tied])
    return chosen[np.lexsort((chosen, -values[chosen]))]


def frame_fix(detections: list[ChirpDetection], site: Site, c: float, bandwidth: dict,
              config: PositionConfig, start: AcousticFix | None = None,
              clock_prior: tuple[float, float] | None = None,
              velocity_m_s: tuple[float, float] | None = None,
              position_prior: tuple[float, float, float] | None = None,
              range_lag_s: dict | None = None, clock_drift: float = 0.0) -> AcousticFix | None:
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
    """
    used = [d for d in detections if d.associated]
    if len(used) < 3:
        return None
    ranges, t_mean = frame_ranges(used, site, c, bandwidth, config, velocity_m_s, range_lag_s, clock_drift,
                                  position_prior)
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


def acquisition_windows(windows: list[SearchWindow], candidates, tracker: ClockPositionTracker, timing: AudioTiming,
                         fs: float, lead: int) -> list[SearchWindow]:
    """Narrow each acquisition window to the arrival the Hough vote associates with its beacon.

    Windows of beacons left unassociated keep their full extent (their strongest
    peak still yields CIR features, not a position).
    """
    cand = {w.beacon_index: (w.tx_s, candidates(w)) for w in windows}
    chosen = tracker.acquire({i: v for i, v in cand.items() if v[1]})
    out = []
    for w in windows:
        if w.beacon_index in chosen:
            s_peak = int(round((chosen[w.beacon_index] - timing.start_s) * fs))
            out.append(SearchWindow(w.beacon_index, w.tx_s, s_peak - lead, s_peak + 8))
        else:
            out.append(SearchWindow(w.beacon_index, w.tx_s, w.lo, w.hi, associated=False))
    return out

