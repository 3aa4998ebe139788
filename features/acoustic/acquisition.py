"""Acquisition of the acoustic receiver: which arrival is which beacon's, with no lock yet.

Beacons share one chirp and are told apart by time alone (docs/beacon_protocol.md), so
before the receiver knows where it is each beacon's acquisition window holds several
arrivals. :class:`HoughAcquisition` associates them with beacons by a Hough vote over
position and clock offset verified by least squares (:meth:`~HoughAcquisition.acquire`)
or, after a confirmed track, by a vote over position alone with the clock filter's
prediction (:meth:`~HoughAcquisition._acquire_with_clock`), and checks a fix for a
mirror solution (:meth:`~HoughAcquisition.mirror_free`);
:func:`acquisition_windows` narrows a frame's windows to the associated arrivals.
The tracker that holds the lock is :class:`features.acoustic.tracking.ClockPositionTracker`.

Speed (issue 25): the fine vote's duplicate grid points are found by a one-dimensional ``np.unique`` of one
integer key per point instead of a row-wise unique (the same first occurrences; 1.5 → 0.08 ms a call), and
the clock-aided re-acquisition loops over Python floats with each candidate's emission time from a dict (it
indexed numpy arrays one scalar at a time and searched the candidates linearly per beacon). The vote sorts
its rows by value and argsorts only the rows its best hypotheses lie on (:meth:`HoughAcquisition._vote`), the
verification reads each hypothesis's median from the sorted row and closes the neighbours of each one verified
by a mask, and the clock-aided vote forms a beacon's range once per grid point. Acquisition's share of the
receiver depends on how often the lock is lost: on the bench's walk (site 5, seed 42, 600 s, standing 80 % of
it, a fix in 30 % of its frames) it ran in 283 of 627 frames and took 1.05-1.17 s of CPU of the receiver's
1.8-2.3 (best of 5, two runs); now 0.68-0.89 s, and on a 600 s walk of site 7 (96 fixes) 1.75-2.39 → 1.20-1.49 s
(2026-12-03, main and the change alternated on a noisy day), with fixes and detections bit-identical on the 15
held-out walks of ``bench/receiver_identity.py`` and 15 more of sites 3, 5 and 7 (``--walks``). On a walk that
keeps its lock it is a few per cent.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from features.acoustic.positions import AcousticFix, BeaconRange, chi2_limit, least_squares_fix, solve_position
from features.acoustic.timing import AudioTiming, SearchWindow
from features.site import Site

__all__ = ["HoughAcquisition", "acquisition_windows"]


class HoughAcquisition:
    """The acquisition half of :class:`~features.acoustic.tracking.ClockPositionTracker`, its base class.

    Reads the tracker's state and settings: ``site``, ``c``, ``r_max``,
    ``max_speed_m_s``, ``max_drift_ppm``, ``clock_aided_reacquisition``, the
    solver configurations ``_verify_config`` and ``_track_config``, and the
    lock's ``_clock`` (two-state clock filter), ``_clock_anchor`` and
    ``_anchor_fix``; writes ``_reacquired`` (the clock-aided vote's fix).
    """

    @property
    def grid_step_m(self) -> float:
        """Spacing of the acquisition grid, m: 1 m, coarser on sites above 10 000 m²."""
        g = self.site.grid
        return max(1.0, math.sqrt((g.east_max_m - g.east_min_m) * (g.north_max_m - g.north_min_m) / 10_000))

    @property
    def tolerance_s(self) -> float:
        """Agreement tolerance of the vote: the range error of the nearest grid point, plus 0.5 ms."""
        return self.grid_step_m * math.sqrt(2.0) / self.c + 5e-4


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
        bpos = self._beacon_xyz()[bi]
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
        hyps, _ = self._vote(ee, nn, bi, rho, bpos, coarse * math.sqrt(2.0) / self.c + 5e-4, arrivals)
        if not hyps:
            return {}
        fine = self.grid_step_m
        offsets = np.arange(-coarse, coarse + fine / 2, fine)
        oe, on = np.meshgrid(offsets, offsets)
        seeds = hyps.points(min_distinct=3, n=30)
        if not seeds:
            return {}
        pe = np.concatenate([s[0] + oe.ravel() for s in seeds])
        pn = np.concatenate([s[1] + on.ravel() for s in seeds])
        # Neighbouring seeds' fine grids overlap: each point once (first occurrence, order kept).
        # (One integer key per point, each cell's east and north in 32 bits: a 1-D unique, several times cheaper
        # than the row-wise one, with the same first occurrences.)
        ie, i_n = np.round(pe / fine).astype(np.int64), np.round(pn / fine).astype(np.int64)
        _, first = np.unique(ie * (1 << 32) + (i_n + (1 << 31)), return_index=True)
        first.sort()
        pe, pn = pe[first], pn[first]
        hyps, _ = self._vote(pe, pn, bi, rho, bpos, self.tolerance_s, arrivals, n_best=400)
        # Verify the best distinct hypotheses by least squares (RANSAC-style, Fischler & Bolles
        # 1981): the one whose fix keeps the most beacons, then the smallest residual, wins.
        best, best_key, tried = {}, None, 0
        # A hypothesis within 2 m and 2 ms of one verified already is not verified again: each verified one
        # closes its neighbours among the rest (a mask over the ranked list, instead of a test against every
        # one verified so far, per hypothesis read).
        n_distinct, east, north, d0s = hyps.n_distinct, hyps.east, hyps.north, hyps.medians
        open_ = np.ones(len(hyps), dtype=bool)
        a = 0
        while True:
            rest = np.flatnonzero(open_[a:])
            if len(rest) == 0:
                break
            a += int(rest[0])
            n = int(n_distinct[a])
            # Hypotheses come by decreasing vote; one two votes short of the best verified fix
            # has never been seen to beat it (re-association adds a beacon at most), so stop.
            if n < 3 or tried >= 12 or (best_key is not None and n + 1 < best_key[0]):
                break
            point, d0 = (float(east[a]), float(north[a])), float(d0s[a])
            tried += 1
            open_ &= ~((np.abs(east - point[0]) < 2) & (np.abs(north - point[1]) < 2) & (np.abs(d0s - d0) < 2e-3))
            kept = self._associate(point, d0, bi, rho, bpos, arrivals)
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
        bpos = self._beacon_xyz()[bi]
        tol = step / math.sqrt(2.0) + 3.0 * c * sigma_d + 0.3
        votes = _range_votes(ee, nn, bpos, float(h), rng_m, bi, float(tol))
        order = np.argsort(-votes, kind="stable")
        seeds: list = []
        for k in order[:400].tolist():
            if votes[k] < 3 or len(seeds) >= 6:
                break
            if all(math.hypot(ee[k] - p[0], nn[k] - p[1]) > 3.0 for p in seeds):
                seeds.append((float(ee[k]), float(nn[k])))
        best, best_key = {}, None
        prior = (clock.offset_s, math.sqrt(clock.p00 + 1e-14))
        # Python floats for the loops below (numpy scalars, indexed one by one, cost more than the arithmetic)
        rng_list, bi_list = rng_m.tolist(), bi.tolist()
        tx_of: dict = {}                                             # (index, arrival) -> its emission time
        for i, tx, t in items:
            tx_of.setdefault((i, t), tx)
        for pe, pn in seeds:
            rr = np.sqrt((pe - bpos[:, 0]) ** 2 + (pn - bpos[:, 1]) ** 2 + (h - bpos[:, 2]) ** 2).tolist()
            chosen: dict = {}
            for k, i in enumerate(bi_list):
                if abs(rng_list[k] - rr[k]) <= tol and (i not in chosen or items[k][2] < chosen[i]):
                    chosen[i] = items[k][2]                          # the earliest: echoes come later
            # The frame's chirps are heard up to a frame apart while the receiver walks: the range
            # variance takes the walking term of PositionConfig (½·(v·(tᵢ − t̄))²).
            t_bar = sum(chosen.values()) / max(len(chosen), 1)
            v = self._track_config.motion_speed_m_s
            ranges = [BeaconRange(b[i].id, b[i].east_m, b[i].north_m, b[i].up_m, c * (t - tx_of[i, t]),
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

    def _beacon_xyz(self) -> np.ndarray:
        """(east, north, up) of every beacon of the site, m; shape (n_beacons, 3), indexed by beacon index."""
        return np.array([[b.east_m, b.north_m, b.up_m] for b in self.site.beacons], dtype=float).reshape(-1, 3)

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
        limit = chi2_limit(dof, self._verify_config.chi2_alpha) if dof > 0 else math.inf
        for e0, n0 in starts:
            sol = least_squares_fix(ranges, h, c, self._verify_config.max_iterations,
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
        ``disk``, lies within the drift bound of the anchored clock
        (:meth:`~features.acoustic.tracking.ClockPositionTracker._clock_continues`):
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

    def _associate(self, point, d0, bi, rho, bpos, times) -> dict:
        """Each beacon's earliest candidate within ``tol`` of δ = d0 at ``point``; one arrival, one beacon
        (:func:`_associate_arrivals`; ``times`` the candidates' stated arrivals, s)."""
        kept_i, kept_t = _associate_arrivals(float(point[0]), float(point[1]), float(d0), bi, rho, bpos,
                                             float(self.site.device_height_m), float(self.c), self.tolerance_s, times)
        return dict(zip(kept_i.tolist(), kept_t.tolist()))

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

    def _vote(self, pe, pn, bi, rho, bpos, tol, arrivals, n_best: int = 200) -> tuple[list, object]:
        """Hypotheses (distinct beacons, anchor δ, (east, north), span) best first, and a function giving the δ of
        the agreeing candidates of a span, ascending (formed only for the few hypotheses verified).

        Candidates agreeing with an anchor's δ within [δ, δ + tol] are counted
        for all (point, anchor) pairs at once — each row sorted, then counted by one
        compiled sweep (:func:`_agreement_counts`) — and the ``n_best`` largest counts
        (:func:`_top_counts`) are recounted as distinct beacons (a beacon's echoes must not vote twice)
        using distinct arrivals (one arrival heard in several beacons' windows
        must not vote for each of them), :func:`_ranked_hypotheses`.

        The counts need each row's δ in ascending order, not which candidate is where: the rows are sorted by
        value (numpy's vectorised sort, about four times faster than its argsort here), and a hypothesis's
        members are read by value from its row; only a row where a δ equal to a span's first or last lies just
        outside the span is argsorted (which of the equals are members is then the argsort's choice). The sorted
        values are the argsorted ones whatever order ties take, so the counts, spans and members are those of
        the argsort of every row to the bit.
        """
        delta = _implied_offsets(pe, pn, bpos, float(self.site.device_height_m), rho, float(self.c))
        ascending = np.sort(delta, axis=1)
        # max |δ| from each row's ends (the largest magnitude is one of the extremes)
        offset = 2.0 * (max(-ascending[:, 0].min(), ascending[:, -1].max()) + tol + 1.0)
        count = _agreement_counts(ascending, offset, tol)
        top = _top_counts(count, n_best)
        # A hypothesis's members are the candidates of its row with δ in [its first, its last]: read by value,
        # unless the δ before its first or after its last is equal to it, when which of the equals are members
        # is the argsort's choice: those rows (almost never any) are argsorted, and each such hypothesis's row's
        # place among them given (−1: read by value).
        n = delta.shape[1]
        row_of, k_of = top // n, top % n
        last = k_of + count[top] - 1
        tied = (((k_of > 0) & (ascending[row_of, np.maximum(k_of - 1, 0)] == ascending[row_of, k_of]))
                | ((last + 1 < n) & (ascending[row_of, np.minimum(last + 1, n - 1)] == ascending[row_of, last])))
        rows_tied = np.unique(row_of[tied])
        order = np.argsort(delta[rows_tied], axis=1)
        slot = np.where(tied, np.searchsorted(rows_tied, row_of), -1)
        # Among equal counts the tightest agreement first: a hypothesis that is only just within
        # the tolerance is usually a chance alignment (ordering by smallest δ instead buried
        # the true one under chance alignments whenever the clock offset was positive).
        n_distinct, first, rows, ks, ns = _ranked_hypotheses(delta, ascending, order, slot, top, count,
                                                             np.asarray(bi, dtype=np.int64), np.round(arrivals, 4))
        # The tuples are formed as the caller reads them: it reads a few dozen of the n_best.
        hyps = _Hypotheses(n_distinct, first, pe[rows], pn[rows], rows, ks, ns, ascending)
        return hyps, lambda span: ascending[span[0], span[1]: span[1] + span[2]]


class _Hypotheses:
    """The ranked hypotheses of :meth:`HoughAcquisition._vote` as a sequence of (distinct beacons, anchor δ,
    (east, north), (row, k, count)), each tuple formed (of Python numbers) when read."""

    def __init__(self, n_distinct, first, east, north, rows, ks, ns, ascending):
        self.columns = (n_distinct, first, east, north, rows, ks, ns)
        self.n_distinct, self.east, self.north = n_distinct, east, north
        # Each hypothesis's median δ of its agreeing candidates (ascending[row, k : k + n]), as
        # statistics.median takes it: the middle one, or the mean of the middle two.
        mid = ks + ns // 2
        upper = ascending[rows, mid]
        self.medians = np.where(ns % 2 == 1, upper, (ascending[rows, np.maximum(mid - 1, 0)] + upper) / 2)

    def __len__(self) -> int:
        return len(self.columns[0])

    def __getitem__(self, a: int) -> tuple:
        n, d, e, nn, row, k, m = (col[a].item() for col in self.columns)
        return n, d, (e, nn), (row, k, m)

    def __iter__(self):
        return (self[a] for a in range(len(self)))

    def points(self, min_distinct: int, n: int) -> list[tuple[float, float]]:
        """The first ``n`` distinct (east, north) of the hypotheses of at least ``min_distinct`` beacons, in rank
        order (the points are a grid's, so one row, one point)."""
        rows = self.columns[4]
        enough = self.n_distinct >= min_distinct
        _, first = np.unique(rows[enough], return_index=True)
        first = np.sort(first)[:n]
        return list(zip(self.east[enough][first].tolist(), self.north[enough][first].tolist()))


@njit(cache=True)
def _range_votes(ee: np.ndarray, nn: np.ndarray, bpos: np.ndarray, h: float, rng_m: np.ndarray, bi: np.ndarray,
                 tol: float) -> np.ndarray:
    """Votes of the clock-aided re-acquisition (:meth:`HoughAcquisition._acquire_with_clock`): at each grid point
    (``ee``, ``nn``), how many distinct beacons ``bi`` (sorted) have a candidate range ``rng_m`` within ``tol`` of
    ‖p − s_b‖ (beacon at ``bpos`` (n, 3), the device at height ``h``); shape (n_points,).

    >>> _range_votes(np.array([0.0, 10.0]), np.array([0.0, 0.0]), np.array([[3.0, 4.0, 1.0]] * 3), 1.0,
    ...              np.array([5.0, 5.1, 9.0]), np.array([0, 0, 1]), 0.2).tolist()
    [1, 0]
    """
    votes = np.zeros(ee.shape[0], dtype=np.int64)
    n = rng_m.shape[0]
    if n == 0:
        return votes
    # Each beacon's candidates (a run of equal bi) share its position: its range is formed once per point.
    starts = [0]
    for k in range(1, n):
        if bi[k] != bi[k - 1]:
            starts.append(k)
    starts.append(n)
    for p in range(ee.shape[0]):
        for s in range(len(starts) - 1):
            k0 = starts[s]
            de, dn, du = ee[p] - bpos[k0, 0], nn[p] - bpos[k0, 1], h - bpos[k0, 2]
            r = math.sqrt(de * de + dn * dn + du * du)
            for k in range(k0, starts[s + 1]):
                if abs(rng_m[k] - r) <= tol:
                    votes[p] += 1
                    break
    return votes


@njit(cache=True)
def _implied_offsets(pe: np.ndarray, pn: np.ndarray, bpos: np.ndarray, h: float, rho: np.ndarray,
                     c: float) -> np.ndarray:
    """δ = (ρ − ‖p − s_b‖)/c of each candidate (pseudorange ``rho``, beacon at ``bpos`` (n, 3)) at each grid point
    (``pe``, ``pn``; the device at height ``h``): the clock offset the candidate implies there; (n_points, n).

    >>> _implied_offsets(np.array([3.0]), np.array([4.0]), np.array([[0.0, 0.0, 1.0]]), 1.0, np.array([15.0]),
    ...                  2.0).tolist()
    [[5.0]]
    """
    n = rho.shape[0]
    out = np.empty((pe.shape[0], n))
    # The beacons' coordinates as contiguous columns, and the height term once: the inner loop vectorises.
    be, bn = np.ascontiguousarray(bpos[:, 0]), np.ascontiguousarray(bpos[:, 1])
    du2 = np.empty(n)
    for i in range(n):
        du = h - bpos[i, 2]
        du2[i] = du * du
    for p in range(pe.shape[0]):
        e, nn = pe[p], pn[p]
        for i in range(n):
            de, dn = e - be[i], nn - bn[i]
            out[p, i] = (rho[i] - math.sqrt(de * de + dn * dn + du2[i])) / c
    return out


@njit(cache=True)
def _agreement_counts(ascending: np.ndarray, offset: float, tol: float) -> np.ndarray:
    """For each (point, anchor) of the vote, flattened row-major, each row of ``ascending`` (n_points, n_candidates)
    the implied offsets δ of one point in ascending order: how many candidates of the point's row lie within
    [δ, δ + tol] of the anchor's δ (the anchor included); shape (n_points·n_candidates,), int32.

    The comparison is made, as it was by a global ``searchsorted`` over the flattened rows, on δ + ``offset``·row
    (rows ``offset`` apart never meet), so that the counts are those of that search to the bit. Per row, a merge
    of the ascending shifted δ with the ascending limits δ + tol (:func:`_merge_counts`), four rows at a time.

    >>> _agreement_counts(np.array([[0.0, 0.1, 0.25, 0.3], [0.0, 1.0, 1.05, 2.0]]), 10.0, 0.2).tolist()
    [2, 3, 2, 1, 1, 2, 1, 1]
    """
    n_points, n = ascending.shape
    # Four rows' shifted δ (each ending in +inf, a sentinel the merge never passes) and their limits.
    shifted = np.full((4, n + 1), np.inf)
    limit = np.full((4, n), np.inf)
    count = np.empty(4 * ((n_points + 3) // 4) * n, dtype=np.int32)
    for r0 in range(0, n_points, 4):
        for lane in range(4):
            row = r0 + lane
            if row < n_points:
                base = offset * np.float64(row)
                for k in range(n):
                    shifted[lane, k] = ascending[row, k] + base
                    limit[lane, k] = shifted[lane, k] + tol
        _merge_counts(shifted, limit, count, r0 * n)
    return count[: n_points * n]


@njit(cache=True, inline="always")
def _merge_step(a: np.ndarray, lim: np.ndarray, out: np.ndarray, at: int, row: int, j: int, k: int
                ) -> tuple[int, int]:
    """One step of :func:`_merge_counts` on row ``row``: out[at + row·n + k] = j − k, then j or k moves on."""
    step = np.int64(a[row, j] <= lim[row, k])
    out[at + row * lim.shape[1] + k] = np.int32(j - k)
    return j + step, k + 1 - step


@njit(cache=True)
def _merge_counts(shifted: np.ndarray, limit: np.ndarray, out: np.ndarray, at: int) -> None:
    """For each of four rows: out[at + row·n + k] = #{j ≥ k : shifted[j] ≤ limit[k]}, both rows ascending,
    limit[k] ≥ shifted[k] (``shifted`` (4, n + 1) ends in +inf). A branch-free merge: j, the first index past
    limit[k], only moves forward, and out[k] is final when k moves on; each step waits on the load of the step
    before, so four independent rows are interleaved to keep the processor busy.

    >>> out = np.zeros(12, np.int32)
    >>> _merge_counts(np.array([[0.0, 0.1, 0.5, np.inf]] * 4), np.array([[0.2, 0.3, 0.7]] * 4), out, 0)
    >>> out[:3].tolist()
    [2, 1, 1]
    """
    n = limit.shape[1]
    j0 = j1 = j2 = j3 = 0
    k0 = k1 = k2 = k3 = 0
    while k0 < n or k1 < n or k2 < n or k3 < n:     # each row takes 2n steps at most
        if k0 < n:
            j0, k0 = _merge_step(shifted, limit, out, at, 0, j0, k0)
        if k1 < n:
            j1, k1 = _merge_step(shifted, limit, out, at, 1, j1, k1)
        if k2 < n:
            j2, k2 = _merge_step(shifted, limit, out, at, 2, j2, k2)
        if k3 < n:
            j3, k3 = _merge_step(shifted, limit, out, at, 3, j3, k3)


@njit(cache=True)
def _top_counts(count: np.ndarray, n_best: int) -> np.ndarray:
    """Indices of the ``n_best`` largest of ``count``, ties in index order (as a stable sort of −count); shape
    (min(n_best, len(count)),). A counting sort, the counts being small (at most the number of candidates): a
    histogram gives the smallest count taken and where each larger count's indices start, then one pass places
    the indices (of the smallest count taken, only the first that fit).

    >>> _top_counts(np.array([1, 3, 2, 3, 0, 2], np.int32), 4).tolist()
    [1, 3, 2, 5]
    >>> _top_counts(np.array([1, 3, 2, 3, 0, 2], np.int32), 3).tolist()
    [1, 3, 2]
    """
    m = min(n_best, count.shape[0])
    top = np.empty(m, dtype=np.int64)
    if m == 0:
        return top
    top_count = 0
    for f in range(count.shape[0]):
        if count[f] > top_count:
            top_count = count[f]
    hist = np.zeros(top_count + 1, dtype=np.int64)
    for f in range(count.shape[0]):
        hist[count[f]] += 1
    # start[v]: where the indices of count v begin (the larger counts first); the last value taken, partly.
    start = np.zeros(top_count + 2, dtype=np.int64)
    lowest = top_count
    for v in range(top_count, -1, -1):
        start[v] = start[v + 1] + hist[v + 1] if v < top_count else 0
        lowest = v
        if start[v] + hist[v] >= m:
            break
    for f in range(count.shape[0]):
        v = count[f]
        if v >= lowest and start[v] < m:
            top[start[v]] = f
            start[v] += 1
    return top


@njit(cache=True)
def _ranked_hypotheses(delta: np.ndarray, ascending: np.ndarray, order: np.ndarray, slot: np.ndarray,
                       top: np.ndarray, count: np.ndarray, beacon_of: np.ndarray, arrival_of: np.ndarray):
    """The (point, anchor) pairs ``top`` (flat indices ``row·n + k`` into ``count``; ``k`` a position in row
    ``row`` of ``ascending``, each row of the implied offsets ``delta`` in ascending order), each recounted as
    min(distinct beacons ``beacon_of``, distinct arrivals ``arrival_of``) of its members, then ranked by
    (most distinct, smallest spread of δ, smallest δ), ties kept in the order of ``top``:
    (n_distinct, anchor δ, row, k, count), each of shape (len(top),).

    The members of a pair are the candidates at positions ``k … k + count − 1`` of its row's argsort: read from
    ``order[slot[a]]`` where ``slot[a]`` ≥ 0 (the caller's argsort of the row, for a pair with a δ equal to its
    first or last just outside it), else by value, the candidates of the row with δ in [its first, its last]
    (the same set when no equal δ lies just outside). The counts are sets, whatever order the members come in.

    Pair 0 (row 0, k 0, 3 members: beacons 0, 1, 2) first; pairs 1 and 2 have 2 distinct each, pair 1 (row 1,
    δ 0 and 0.05) the smaller spread; pair 1 read through an argsort, the others by value:

    >>> delta = np.array([[0.0, 0.1, 0.2], [0.0, 0.5, 0.05]])
    >>> [a.tolist() for a in _ranked_hypotheses(delta, np.sort(delta, axis=1), np.array([[0, 2, 1]]),
    ...     np.array([-1, -1, 0]), np.array([0, 1, 3]), np.array([3, 2, 1, 2, 1, 1]), np.array([0, 1, 2]),
    ...     np.array([1.0, 2.0, 3.0]))]
    [[3, 2, 2], [0.0, 0.0, 0.1], [0, 1, 0], [0, 0, 1], [3, 2, 2]]
    """
    n_cand = ascending.shape[1]
    m = top.shape[0]
    n_distinct = np.empty(m, dtype=np.int64)
    first = np.empty(m)
    spread = np.empty(m)
    rows = np.empty(m, dtype=np.int64)
    ks = np.empty(m, dtype=np.int64)
    ns = np.empty(m, dtype=np.int64)
    members = np.empty(n_cand, dtype=np.int64)
    for a in range(m):
        f = top[a]
        row, k = f // n_cand, f % n_cand
        n = count[f]
        lo, hi = ascending[row, k], ascending[row, k + n - 1]
        if slot[a] >= 0:
            for i in range(n):
                members[i] = order[slot[a], k + i]
        else:
            got = 0
            for j in range(n_cand):
                if lo <= delta[row, j] <= hi:
                    members[got] = j
                    got += 1
        beacons = 0
        arrivals = 0
        for i in range(n):
            bi, ti = beacon_of[members[i]], arrival_of[members[i]]
            new_b, new_t = True, True
            for j in range(i):
                if beacon_of[members[j]] == bi:
                    new_b = False
                if arrival_of[members[j]] == ti:
                    new_t = False
            beacons += new_b
            arrivals += new_t
        n_distinct[a] = min(beacons, arrivals)
        first[a] = lo
        spread[a] = hi - lo
        rows[a], ks[a], ns[a] = row, k, n
    # Lexicographic (−n_distinct, spread, first) by stable sorts from the last key to the first.
    rank = np.argsort(first, kind="mergesort")
    rank = rank[np.argsort(spread[rank], kind="mergesort")]
    rank = rank[np.argsort(-n_distinct[rank], kind="mergesort")]
    return n_distinct[rank], first[rank], rows[rank], ks[rank], ns[rank]


@njit(cache=True)
def _associate_arrivals(pe: float, pn: float, d0: float, bi: np.ndarray, rho: np.ndarray, bpos: np.ndarray, h: float,
                        c: float, tol: float, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The association of a voted hypothesis (:meth:`HoughAcquisition._associate`): (beacon indices, arrival times)
    in the order they are kept.

    A candidate (beacon ``bi[k]`` at ``bpos[k]``, pseudorange ``rho[k]``, arrival ``times[k]``) agrees when its
    implied clock offset at (``pe``, ``pn``) (the device at height ``h``) lies within ``tol`` of ``d0``; each
    beacon takes its earliest agreeing candidate (echoes come later), beacons in the order first met. One
    arrival belongs to one beacon: by increasing misfit (ties in that order) a beacon keeps its arrival unless
    one within 1 ms is kept already.

    Beacon 0 has two agreeing candidates (the earlier, 0.1 s, kept); beacon 1's arrival is beacon 0's within
    0.5 ms and fits worse, so it is dropped; beacon 2's (misfit 0.5 ms) is kept:

    >>> [a.tolist() for a in _associate_arrivals(0.0, 0.0, 0.0, np.array([0, 0, 1, 2]),
    ...     np.array([10.0, 10.2, 10.4, 10.5]), np.array([[10.0, 0.0, 0.0]] * 4), 0.0, 1000.0, 1e-3,
    ...     np.array([0.2, 0.1, 0.1005, 0.5]))]
    [[0, 2], [0.1, 0.5]]
    """
    n = rho.shape[0]
    chosen_i = np.empty(n, dtype=np.int64)
    chosen_t = np.empty(n)
    chosen_err = np.empty(n)
    m = 0
    for k in range(n):
        de, dn, du = pe - bpos[k, 0], pn - bpos[k, 1], h - bpos[k, 2]
        r = math.sqrt(de * de + dn * dn + du * du)
        err = abs((rho[k] - r) / c - d0)
        if not err <= tol:
            continue
        at = -1
        for q in range(m):
            if chosen_i[q] == bi[k]:
                at = q
                break
        if at < 0:
            chosen_i[m], chosen_t[m], chosen_err[m] = bi[k], times[k], err
            m += 1
        elif times[k] < chosen_t[at]:
            chosen_t[at], chosen_err[at] = times[k], err
    by_fit = np.argsort(chosen_err[:m], kind="mergesort")
    kept_i = np.empty(m, dtype=np.int64)
    kept_t = np.empty(m)
    n_kept = 0
    for q in by_fit:
        free = True
        for p in range(n_kept):
            if not abs(chosen_t[q] - kept_t[p]) > 1e-3:
                free = False
                break
        if free:
            kept_i[n_kept], kept_t[n_kept] = chosen_i[q], chosen_t[q]
            n_kept += 1
    return kept_i[:n_kept], kept_t[:n_kept]


def _inside(x, site: Site, margin_m: float = 5.0) -> bool:
    g = site.grid
    return (g.east_min_m - margin_m <= x[0] <= g.east_max_m + margin_m
            and g.north_min_m - margin_m <= x[1] <= g.north_max_m + margin_m)


def acquisition_windows(windows: list[SearchWindow], candidates, tracker: HoughAcquisition, timing: AudioTiming,
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
