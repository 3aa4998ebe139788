"""The receiver's compiled per-frame kernels against independent numpy references (issue 25 item 1).

The references are written here in array form (as the receiver computed before the kernels, numpy 2's
float32 promotion included); the kernels are loops. Which bug each test would catch is said in its docstring.
"""

from __future__ import annotations

import numpy as np

from features.acoustic.detection import (_RAYLEIGH_Q25, _SILENCE_REL, _SIDELOBE_GUARD, _assign, _compressed,
                                        _envelope_maxima, _noise_scales)


def _maxima_reference(seg, gamma, dec, template_len):
    idx = 1 + np.flatnonzero(seg[1:-1] > gamma)
    idx = idx[(seg[idx] > seg[idx - 1]) & (seg[idx] >= seg[idx + 1])]
    ends = [i for i, ok in ((0, seg[0] > gamma and seg[0] >= seg[1]),
                            (len(seg) - 1, seg[-1] > gamma and seg[-1] > seg[-2])) if ok]
    if ends:
        idx = np.sort(np.concatenate([idx, np.array(ends, dtype=idx.dtype)]))
    h = seg[idx]
    strong = idx[h > gamma * _SIDELOBE_GUARD]
    if len(strong) and len(idx) > 1:
        near = np.abs(idx[:, None] - strong[None, :]) * dec <= template_len
        idx = idx[~np.any(near & (seg[strong][None, :] > h[:, None] * _SIDELOBE_GUARD), axis=1)]
    return idx


def test_envelope_maxima_equal_the_array_reference():
    """300 Rayleigh envelopes (float32) with strong arrivals and their sidelobes, γ drawn so that both float32
    rounding of γ and the guard's product matter: the same indices — would catch a maximum test off by one
    side (> against >=), a lost end sample, float64 comparisons where numpy compares in float32, or a
    sidelobe window in samples instead of taps."""
    rng = np.random.default_rng(21)
    hits = 0
    for _ in range(300):
        n = int(rng.integers(3, 400))
        seg = rng.rayleigh(1.0, n).astype(np.float32)
        for k in rng.integers(0, n, size=int(rng.integers(0, 4))):
            seg[k] *= np.float32(rng.choice([5.0, 40.0, 300.0]))
        gamma = float(rng.uniform(0.5, 3.0))
        dec, template_len = int(rng.integers(1, 9)), int(rng.integers(50, 600))
        got = _envelope_maxima(seg, gamma, gamma * _SIDELOBE_GUARD, dec, template_len)
        ref = _maxima_reference(seg, gamma, dec, template_len)
        assert got.tolist() == ref.tolist()
        hits += len(ref) < len(_maxima_reference(seg, gamma, dec, 0))     # the guard dropped something
    assert hits > 30


def _compressed_reference(row, centre, main_taps, max_width_taps, noise_power):
    n = len(row)
    lo, hi = max(centre - 2, 0), min(centre + 3, n)
    p = lo + int(np.argmax(row[lo:hi]))
    above = row >= 0.5 * row[p]
    left = p
    while left > 0 and above[left - 1]:
        left -= 1
    right = p
    while right < n - 1 and above[right + 1]:
        right += 1
    if right - left >= max_width_taps:
        return False
    main = row[max(p - main_taps, 0): p + main_taps + 1]
    e_main = float(np.sum(main ** 2)) - len(main) * noise_power
    e_all = float(np.sum(row ** 2)) - n * noise_power
    return e_all > 0 and e_main >= 0.1 * e_all


def test_compressed_equals_the_reference():
    """Narrow lobes, wide plateaus (beating clicks) and noise: the kernel's verdict equals a reference written
    from the definition (−6 dB width, main-lobe energy share 0.1) on 500 rows — would catch a width counted on
    one side only, the energy share against the wrong total, or the noise power not subtracted."""
    rng = np.random.default_rng(4)
    rows = []
    for _ in range(500):
        row = rng.rayleigh(0.05, 43)
        c = 21 + int(rng.integers(-2, 3))
        width = int(rng.choice([1, 2, 6, 14]))
        row[max(c - width, 0): c + width + 1] += np.hanning(2 * width + 3)[1:-1][: len(row[max(c - width, 0): c + width + 1])]
        rows.append(row)
    rows = np.array(rows)
    got = _compressed(rows, 21, 2, 12, 2 * 0.05 ** 2).tolist()
    ref = [_compressed_reference(r, 21, 2, 12, 2 * 0.05 ** 2) for r in rows]
    assert got == ref
    assert 100 < sum(got) < 450                            # both verdicts occur


def _noise_reference(seg):
    """The noise scales as numpy computed them (one partition; the silent fallback compares in float32)."""
    sub = seg[:, ::4]
    k = sub.shape[1] // 4
    part = np.partition(sub, (k, sub.shape[1] - 1), axis=1)
    q25, peak = part[:, k].astype(float), part[:, -1].tolist()
    if all(q > _SILENCE_REL * m for q, m in zip(q25.tolist(), peak)):
        return q25 / _RAYLEIGH_Q25
    out = np.zeros(sub.shape[0])
    for t, row in enumerate(sub):
        nz = row[row > _SILENCE_REL * peak[t]]
        if len(nz):
            out[t] = float(np.partition(nz, len(nz) // 4)[len(nz) // 4]) / _RAYLEIGH_Q25
    return out


def test_noise_scales_equal_the_array_reference():
    """Rayleigh envelopes of 1-3 templates, some with digital silence (exact zeros, float32 round-off below
    1e-6 of the peak) over part or all of a row: the compiled quartile must equal numpy's to the bit. Catches a
    quantile taken over the wrong stride or rank, the silence test done per row instead of for all rows, and the
    silence level compared in float64 (numpy 2 compares a float32 row with a Python float in float32)."""
    rng = np.random.default_rng(7)
    silent_seen = 0
    for _ in range(400):
        n_t, n = int(rng.integers(1, 4)), int(rng.integers(1, 3000))
        seg = rng.rayleigh(rng.uniform(1e-4, 1.0), (n_t, n)).astype(np.float32)
        for t in range(n_t):
            if rng.random() < 0.3:
                a = int(rng.integers(0, n))
                b = int(rng.integers(a, n + 1))
                seg[t, a:b] = np.float32(rng.choice([0.0, 1e-9, 1e-7])) * seg[t].max()
        want = _noise_reference(seg)
        silent_seen += not np.array_equal(want, np.partition(seg[:, ::4], seg[:, ::4].shape[1] // 4, axis=1)[
            :, seg[:, ::4].shape[1] // 4].astype(float) / _RAYLEIGH_Q25)
        assert np.array_equal(_noise_scales(seg), want)
    assert silent_seen > 20                                     # the silent fallback was exercised


def _assign_reference(maxima, windows, gammas, dec, delay, gap, echo):
    """The assignment as Python wrote it before it was compiled: per-window peak lists, then the rounds
    (claims, and whether the rounds ran). ``maxima``: template -> (ascending j, heights); ``windows``: (template, j_lo, j_hi, associated, expected)."""
    cands = {}
    for k, (t, j_lo, j_hi, assoc, _) in enumerate(windows):
        jj, hh = maxima[t]
        sel = [(dec * j - delay, float(h)) for j, h in zip(jj.tolist(), hh.tolist()) if j_lo <= j < j_hi and h > gammas[k]]
        if sel:
            starts, heights = [s for s, _ in sel], [h for _, h in sel]
            cands[k] = starts if assoc else [starts[heights.index(max(heights))]]
    pending = sorted(cands, key=lambda k: not windows[k][3])
    firsts = sorted((windows[k][0], cands[k][0]) for k in pending)
    if all(t1 != t2 or s2 - s1 > gap for (t1, s1), (t2, s2) in zip(firsts, firsts[1:])):
        return [(k, cands[k][0]) for k in pending], False

    def cost(k, sp):
        return abs(sp - windows[k][4]) if windows[k][4] is not None else 0

    claims = []
    for _ in range(4):
        taken, losers = [], []
        for k in pending:
            t = windows[k][0]
            options = [sp for sp in cands[k] if all(not -gap <= sp - f <= echo for k2, f in claims if windows[k2][0] == t)]
            if not options:
                continue
            sp = options[0]
            rival = next((i for i, (k2, f) in enumerate(taken) if windows[k2][0] == t and abs(sp - f) <= gap), None)
            if rival is None:
                taken.append((k, sp))
                continue
            k2 = taken[rival][0]
            if windows[k][3] and windows[k2][3] and cost(k, sp) < cost(k2, sp):
                taken[rival] = (k, sp)
                losers.append(k2)
            else:
                losers.append(k)
        claims.extend(taken)
        if not losers:
            break
        pending = losers
    return claims, True


def test_assign_equals_the_python_rounds():
    """Frames of 2-30 overlapping windows over 1-2 templates' maxima, clustered so that first peaks collide,
    echoes follow claimed arrivals, and tracked windows compete by their predicted arrival: the compiled
    assignment must claim the same (window, start) pairs in the same order as the Python rounds it replaced.
    Catches a lost tie rule (first of the largest, associated first), a rival or echo test against the wrong
    template, and claims checked within the round instead of against earlier rounds."""
    rng = np.random.default_rng(11)
    dec, delay, gap, echo = 4, 1000, 48.0, 720.0
    clashes = 0
    for _ in range(500):
        n_t = int(rng.integers(1, 3))
        maxima = {}
        for t in range(n_t):
            centres = rng.integers(0, 2000, int(rng.integers(1, 6)))
            jj = np.unique(np.concatenate([c + rng.integers(0, 60, int(rng.integers(1, 8))) for c in centres]))
            maxima[t] = (jj.astype(np.int64), rng.choice([3.0, 5.0, 8.0, 20.0], len(jj)).astype(np.float32))
        windows, gammas = [], []
        for _ in range(int(rng.integers(2, 31))):
            t = int(rng.integers(0, n_t))
            lo = int(rng.integers(-100, 2000))
            assoc = bool(rng.random() < 0.8)
            expected = None if rng.random() < 0.3 else dec * (lo + int(rng.integers(0, 300))) - delay
            windows.append((t, lo, lo + int(rng.integers(1, 400)), assoc, expected))
            gammas.append(float(rng.choice([2.0, 4.0, 6.0])))
        want, rounds = _assign_reference(maxima, windows, gammas, dec, delay, gap, echo)
        jj = np.concatenate([maxima[t][0] for t in range(n_t)])
        hh = np.concatenate([maxima[t][1] for t in range(n_t)])
        t_off = np.cumsum([0] + [len(maxima[t][0]) for t in range(n_t)])
        got_w, got_s = _assign(jj, hh, t_off, np.array([w[0] for w in windows]), np.array([w[1] for w in windows]),
                               np.array([w[2] for w in windows]), np.array(gammas), np.array([w[3] for w in windows]),
                               np.array([0 if w[4] is None else w[4] for w in windows]),
                               np.array([w[4] is not None for w in windows]), dec, delay, gap, echo)
        got = list(zip(got_w.tolist(), got_s.tolist()))
        clashes += rounds
        assert got == want
    assert 50 < clashes < 450                          # both the common case and the rounds were exercised


# --- issue 25 item 1, the second pass: candidates, the vote's counts, the association, the blanker's error ----

def _candidates_reference(jj, hh, j_lo, j_hi, gamma, dec, delay, echo, max_candidates):
    """The per-window numpy candidates the receiver computed before :func:`_candidates` (bisection, threshold,
    echo shadowing by an outer comparison, numpy's argsort of the heights, strongest first)."""
    a = int(np.searchsorted(jj, j_lo))
    b = max(a, int(np.searchsorted(jj, j_hi)))
    heights = hh[a:b].astype(np.float64)
    above = heights > gamma
    starts, heights = dec * jj[a:b][above] - delay, heights[above]
    if not len(starts):
        return []
    lag = starts[None, :] - starts[:, None]
    shadowed = np.any((lag > 0) & (lag <= echo) & (heights[:, None] > heights[None, :]), axis=0)
    keep = np.flatnonzero(~shadowed)
    keep = keep[np.argsort(heights[keep])[::-1][:max_candidates]]
    return starts[keep].tolist()


def test_candidates_equal_the_per_window_reference():
    """200 frames of maxima (one or two templates) and random windows, heights quantised so that ties occur:
    the same candidates in the same order — would catch a shadowing window off by one end (0 < lag ≤ echo), the
    strongest-first order reversed, a window's threshold taken from its neighbour, a lost tie order (equal
    heights are left to numpy's argsort, as before), or a template's maxima read from the other's."""
    from features.acoustic.detection import _candidates

    rng = np.random.default_rng(25)
    ties = 0
    for _ in range(200):
        n_t = int(rng.integers(1, 3))
        per = [np.sort(rng.choice(5000, int(rng.integers(0, 40)), replace=False)) for _ in range(n_t)]
        jj = np.concatenate(per).astype(np.int64)
        hh = (np.round(rng.uniform(1, 12, len(jj)) * 4) / 4).astype(np.float32)   # quarter steps: ties
        t_off = np.cumsum([0] + [len(p) for p in per])
        n_w = int(rng.integers(1, 8))
        tmpl = rng.integers(0, n_t, n_w).astype(np.int64)
        j_lo = rng.integers(0, 4000, n_w).astype(np.int64)
        j_hi = j_lo + rng.integers(0, 1500, n_w)
        gamma = rng.uniform(0.5, 6, n_w)
        starts, heights, c_off, n_kept, tied = _candidates(jj, hh, t_off, tmpl, j_lo, j_hi, gamma, 4, 609, 720.0, 12)
        for k in range(n_w):
            lo, hi = t_off[tmpl[k]], t_off[tmpl[k] + 1]
            want = _candidates_reference(jj[lo:hi], hh[lo:hi], j_lo[k], j_hi[k], gamma[k], 4, 609, 720.0, 12)
            a, b = c_off[k], c_off[k + 1]
            if tied[k]:
                ties += 1
                order = np.argsort(heights[a:b])[::-1][:12]          # as _FrameDetector.candidates does
                got = starts[a:b][order].tolist()
            else:
                got = starts[a: a + n_kept[k]].tolist()
            assert got == want
    assert ties > 20


def test_agreement_counts_equal_a_brute_force_count():
    """Random offsets (with exact duplicates) on 37 rows (not a multiple of the four rows merged together):
    each (row, anchor) count equals #{j ≥ k : δ_j + base ≤ (δ_k + base) + tol} counted directly — would catch a
    merge that stops one short, a lane of the four interleaved rows read from another, the last partial group
    dropped, or the count of an anchor taken before its pointer settled."""
    from features.acoustic.acquisition import _agreement_counts

    rng = np.random.default_rng(5)
    for n in (1, 5, 64):
        delta = rng.normal(0, 0.02, (37, n))
        delta[:, n // 2] = delta[:, 0]
        tol = 0.01
        offset = 2.0 * (np.abs(delta).max() + tol + 1.0)
        got = _agreement_counts(np.sort(delta, axis=1), offset, tol).reshape(37, n)
        for row in range(37):
            s = np.sort(delta[row]) + offset * row
            want = [int(np.sum(s[k:] <= s[k] + tol)) for k in range(n)]
            assert got[row].tolist() == want


def test_associate_arrivals_hand_checked():
    """Two beacons 30 m east and north of a receiver at the origin (device height 1 m, beacons at 1 m), c = 300
    m/s, d0 = 10 ms. Beacon 0: candidates at ρ = 33 m (δ = 10 ms, fits) and 33.3 m (11 ms, outside tol 0.5 ms);
    beacon 1: ρ = 33.09 m (δ = 10.3 ms, fits, misfit 0.3 ms) arriving 0.4 ms after beacon 0's, so one arrival
    for two beacons: beacon 0 (misfit 0) keeps it. Beacon 2 at the same place as 1 with ρ = 33.03 m (misfit
    0.1 ms) arriving 5 ms later is kept, after beacon 0 (smaller misfit first)."""
    from features.acoustic.acquisition import _associate_arrivals

    bpos = np.array([[30.0, 0.0, 1.0], [30.0, 0.0, 1.0], [0.0, 30.0, 1.0], [0.0, 30.0, 1.0]])
    got = _associate_arrivals(0.0, 0.0, 0.010, np.array([0, 0, 1, 2]), np.array([33.0, 33.3, 33.09, 33.03]), bpos,
                              1.0, 300.0, 5e-4, np.array([0.100, 0.101, 0.1004, 0.105]))
    assert got[0].tolist() == [0, 2]
    assert got[1].tolist() == [0.100, 0.105]


def test_quantised_error_hand_checked():
    """Dyadic samples (every product and sum exact), segments of 4 samples: position 3 (segment 0) through the
    second difference x[n] − 2x[n−1] + x[n−2], positions 4–7 (segment 1) through the AR filter
    [1, −0.5, 0, 0.25]; |e|·2²⁴ — would catch a segment given its neighbour's filter, a tap lag off by one, or
    a lost absolute value."""
    from features.acoustic.impulses import _quantised_error

    x = np.array([0, 0, 0, 0.5, 0.25, -0.25, 0.125, 0.5, 1.0, -1.0, 0.0, 0.0], np.float32)
    coefs = np.array([[1.0, -2.0, 1.0, 0.0], [1.0, -0.5, 0.0, 0.25]])
    e = [0.5 - 2 * 0 + 0,                  # n = 3: x3 − 2·x2 + x1
         0.25 - 0.5 * 0.5 + 0.25 * 0,      # n = 4: x4 − 0.5·x3 + 0.25·x1 = 0
         -0.25 - 0.5 * 0.25 + 0.25 * 0,    # n = 5: −0.375
         0.125 + 0.5 * 0.25 + 0.25 * 0.5,  # n = 6: 0.375
         0.5 - 0.5 * 0.125 + 0.25 * 0.25]  # n = 7: 0.5
    assert _quantised_error(x, coefs, 0, 4, 0, 3, 8).tolist() == [8388608, 0, 6291456, 6291456, 8388608]
    assert [round(abs(v) * 2 ** 24) for v in e] == [8388608, 0, 6291456, 6291456, 8388608]


def _decide_reference(q, start, stop, wh, g, ratio, hold, hold_left):
    """The impulse test of the module docstring sample by sample: reference = Σ q over [i − g − wh, i − g) and
    (i + g, i + g + wh], each sum formed afresh; a hit masks itself and the ``hold`` samples after it."""
    mask, opened = [], 0
    for i in range(start, stop):
        ref = int(q[i - g - wh: i - g].sum()) + int(q[i + g + 1: i + g + 1 + wh].sum())
        if q[i] > 0 and float(q[i] * 2 * wh) > ratio * float(ref):
            opened += hold_left == 0
            hold_left = hold + 1
        mask.append(hold_left > 0)
        hold_left = max(hold_left - 1, 0)
    return mask, hold_left, opened


def test_decide_equals_the_per_sample_reference():
    """Random |e| with clicks placed across the kernel's 4,096-sample chunks (a hit on a chunk's last sample
    whose hold runs into the next chunk, two clicks within one hold, a hold carried in and one carried out of
    the block): mask, hold left and holes opened equal the per-sample definition — would catch a sliding sum
    that drops or doubles a sample at a chunk seam, a hold not extended by a second hit, or a hole counted
    twice."""
    from features.acoustic.impulses import _DECIDE_CHUNK, _decide

    rng = np.random.default_rng(11)
    wh, g, hold, ratio = 48, 14, 24, 8.0
    margin = wh + g
    n = 3 * _DECIDE_CHUNK + 500
    q = rng.integers(0, 2 ** 20, n + 2 * margin).astype(np.int64)
    for at in (margin + _DECIDE_CHUNK - 1, margin + 2 * _DECIDE_CHUNK - 10, margin + 2 * _DECIDE_CHUNK - 3,
               margin + 17, margin + n - 2):
        q[at] = 2 ** 40
    for hold_in in (0, 7):
        got = _decide(q, margin, margin + n, wh, g, ratio, hold, hold_in)
        want = _decide_reference(q, margin, margin + n, wh, g, ratio, hold, hold_in)
        assert got[0].tolist() == want[0]
        assert (got[1], got[2]) == (want[1], want[2])
    assert want[2] == 4 and want[1] > 0         # the two close clicks are one hole; the last one's hold runs on


def test_top_counts_equal_a_stable_sort():
    """The vote's top-k by count equals numpy's stable argsort of −count cut to k, on random counts with many ties,
    k below, at and above the length (and 0): would catch the smallest value taken filled past k, ties out of
    index order, or a count skipped when the histogram's last value is the one cut."""
    from features.acoustic.acquisition import _top_counts

    rng = np.random.default_rng(11)
    for _ in range(500):
        n = int(rng.integers(0, 200))
        count = rng.integers(0, int(rng.integers(1, 12)), n).astype(np.int32)
        for k in (0, 1, n // 3, n, n + 5):
            assert _top_counts(count, k).tolist() == np.argsort(-count, kind="stable")[:k].tolist()


def test_range_votes_count_distinct_agreeing_beacons():
    """The clock-aided vote at each point equals the number of distinct beacons with a candidate range within tol
    of the point's range to it, counted by brute force over every (point, candidate) pair: would catch a beacon's
    echoes voting twice, a beacon's run of candidates cut short (its range formed from another beacon), or an
    empty candidate list read out of bounds."""
    from features.acoustic.acquisition import _range_votes

    rng = np.random.default_rng(3)
    for n in (0, 1, 7, 60):
        n_beacons = 6
        bi = np.sort(rng.integers(0, n_beacons, n))
        bpos = rng.uniform(0, 50, (n_beacons, 3))[bi]
        ee, nn = rng.uniform(0, 50, 300), rng.uniform(0, 50, 300)
        rng_m = rng.uniform(0, 60, n)
        r = np.sqrt((ee[:, None] - bpos[None, :, 0]) ** 2 + (nn[:, None] - bpos[None, :, 1]) ** 2
                    + (1.2 - bpos[None, :, 2]) ** 2)
        agree = np.abs(rng_m[None, :] - r) <= 3.0
        want = [len({int(bi[k]) for k in np.flatnonzero(agree[p])}) for p in range(300)]
        got = _range_votes(ee, nn, bpos, 1.2, rng_m, bi, 3.0)
        assert got.tolist() == want
        assert n < 7 or max(want) >= 2                  # the random draw exercises multi-beacon agreement
