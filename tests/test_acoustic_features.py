"""Per-hop accumulation of chirp features (features.acoustic.features._HopBins)."""

from __future__ import annotations

import numpy as np

from features.acoustic.features import _HopBins


def _fill(bins: _HopBins, rng: np.random.Generator, n: int) -> list:
    chirps = []
    for _ in range(n):
        values = rng.normal(0.0, 3.0, 9)
        values[rng.random(9) < 0.2] = np.nan               # undefined statistics
        values[rng.random(9) < 0.02] = np.inf
        chirp = (int(rng.integers(0, 40)), tuple(values.tolist()), float(rng.normal(20, 5)), int(rng.integers(1, 9)))
        bins.add(*chirp)
        chirps.append(chirp)
    bins.flush()
    return chirps


def test_hop_sums_do_not_depend_on_the_flush_batch_and_skip_undefined_values():
    rng = np.random.default_rng(3)
    whole = _HopBins()
    chirps = _fill(whole, rng, 1300)                          # flushes at 512 and 1024, then the rest
    small = _HopBins()
    small._FLUSH_AT = 7
    for chirp in chirps:
        small.add(*chirp)
    small.flush()
    for name in ("sums", "counts", "n_chirps", "snr_sum"):
        np.testing.assert_allclose(getattr(small, name), getattr(whole, name), rtol=1e-12, atol=1e-9)
    assert small.beacons == whole.beacons
    # Against a direct sum: hop 5, feature 0.
    vals = [c[1][0] for c in chirps if c[0] == 5 and np.isfinite(c[1][0])]
    assert whole.counts[5, 0] == len(vals)
    assert abs(whole.sums[5, 0] - sum(vals)) < 1e-9
    assert whole.n_chirps.sum() == 1300
    assert whole.sums.shape == (max(c[0] for c in chirps) + 1, 9)
