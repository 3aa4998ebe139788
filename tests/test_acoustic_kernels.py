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
