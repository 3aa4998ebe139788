"""The receiver's compiled per-frame kernels against independent numpy references (issue 25 item 1).

The references are written here in array form (as the receiver computed before the kernels, numpy 2's
float32 promotion included); the kernels are loops. Which bug each test would catch is said in its docstring.
"""

from __future__ import annotations

import numpy as np

from features.acoustic.detection import _SIDELOBE_GUARD, _compressed, _envelope_maxima


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
