"""Issue 25 item 2, the audio stream's batches: seeds mixed for a batch of emissions at once (against numpy's
SeedSequence), numpy's interp compiled, the fused hum, a group's taps and band, H of a batch, CSV text by blocks.

The files a seeded walk writes were compared byte for byte with main's (sha256 of every file of five walks and a
survey on five sites; the branch's report).
"""

from __future__ import annotations

import numpy as np
import pytest

from simulation.acoustic.synthesis import (add_hum, band_response, band_responses, band_rows, interp_like_numpy,
                                           scatter_taps)
from simulation.imu.stream import csv_rows
from simulation.rng import seed_words, stream_rng, stream_rngs


@pytest.mark.parametrize("n_words", [1, 3, 4, 5, 7, 9])
def test_seed_words_equal_numpy_seed_sequence(n_words):
    """numpy's own SeedSequence is the reference: below, at and above the pool of 4 words, zeros and 2³² − 1."""
    entropy = np.random.default_rng(n_words).integers(0, 2**32, (64, n_words), dtype=np.uint64).astype(np.uint32)
    entropy[0] = 0
    entropy[1] = 0xFFFFFFFF
    want = np.array([np.random.SeedSequence(row.tolist()).generate_state(4, np.uint64) for row in entropy])
    assert np.array_equal(seed_words(entropy), want)


def test_stream_rngs_draw_what_stream_rng_draws():
    """Row by row the same generator state and draws; a row with a word over 32 bits (two entropy words) and a
    seed over 32 bits too."""
    keys = np.array([[3, 100_001_234, 100_005_678, 100_000_120], [0, 0, 0, 0], [7, 2**32 - 1, 5, 2**32 + 5]])
    for seed in (40, 0, 2**40 + 3):
        got = stream_rngs(seed, ("audio", "tail"), keys)
        assert len(got) == len(keys)
        for rng, row in zip(got, keys):
            ref = stream_rng(seed, "audio", "tail", *row.tolist())
            assert rng.bit_generator.state == ref.bit_generator.state
            assert rng.poisson(12.5) == ref.poisson(12.5)
            assert np.array_equal(rng.standard_normal(7), ref.standard_normal(7))
    # a different row gives a different stream (the key reaches the seed)
    a, b = stream_rngs(1, ("audio", "tail"), np.array([[1, 2, 3, 4], [1, 2, 3, 5]]))
    assert a.random() != b.random()
    with pytest.raises(ValueError, match="non-negative"):
        stream_rngs(1, ("audio", "tail"), np.array([[1, -2, 3, 4]]))


def test_interp_like_numpy_by_hand_and_against_numpy():
    xp, fp = np.array([0.0, 1.0, 3.0]), np.array([0.0, 10.0, 20.0])
    x = np.array([-1.0, 0.0, 0.5, 1.0, 2.0, 3.0, 4.0, np.nan])
    got = interp_like_numpy(x, xp, fp)
    # by hand: left end, the grid points, 10·0.5, 10 + 5·1, the right end beyond; NaN stays NaN
    np.testing.assert_array_equal(got[:7], [0.0, 0.0, 5.0, 10.0, 15.0, 20.0, 20.0])
    assert np.isnan(got[7])
    rs = np.random.default_rng(4)
    for m in (2, 3, 4):
        xp = np.sort(rs.uniform(10.0, 11.0, m))
        fp = rs.uniform(1e-3, 2e-3, m)
        x = np.concatenate([xp, rs.uniform(9.9, 11.1, 5000)])
        assert np.array_equal(interp_like_numpy(x, xp, fp), np.interp(x, xp, fp))   # bit for bit


def test_add_hum_is_the_hum_times_its_interpolated_amplitude_added():
    """One line of unit weight at phase 0 is sin(ωt) (100 Hz at 400 Hz: 0, 1, 0, −1, ...), its amplitude rising
    linearly from 1 to 3 over the chunk, added to what the samples held."""
    fs, n, first = 400.0, 40, 80                        # samples 80 … 119: t = 0.2 … 0.4975 s
    out = np.full(n + 3, 0.5)
    grid = np.array([0.2, 0.2 + n / 2 / fs, 0.2 + n / fs])
    add_hum(out, n, 0.0, first, fs, grid, np.array([1.0, 2.0, 3.0]), 2 * np.pi * 100.0, np.array([0.0]),
            np.array([1.0]))
    t = (first + np.arange(n)) / fs
    want = 0.5 + np.tile([0.0, 1.0, 0.0, -1.0], n // 4) * (1.0 + 2.0 * (t - 0.2) / (n / fs))
    np.testing.assert_allclose(out[:n], want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(out[n:], 0.5)         # nothing beyond the chunk


def test_scatter_taps_sums_coinciding_taps_row_by_row():
    taps = np.zeros((2, 6))
    scatter_taps(taps, np.array([0, 1, 0, 1, 1]), np.array([2, 5, 2, 0, 5]), np.array([1.0, 2.0, 0.25, -3.0, 4.0]))
    np.testing.assert_array_equal(taps, [[0, 0, 1.25, 0, 0, 0], [-3.0, 0, 0, 0, 0, 6.0]])
    # as numpy.bincount with weights gives a row alone
    assert np.array_equal(taps[1], np.bincount([5, 0, 5], [2.0, -3.0, 4.0], 6))


def test_band_rows_by_hand():
    """Row 0: bins 1-2, H alone; row 1: bins 2-4, H + T·g. Columns from bin u0 = 1."""
    k0, k1 = np.array([1, 2]), np.array([3, 5])
    h = np.array([1 + 1j, 2.0, 3j, 4.0, -1.0])
    tail = np.zeros((1, 6), complex)
    tail[0, 2:5] = [1 + 2j, -2.0, 0.5j]
    got = band_rows(1, 5, k0, k1, h, tail, np.array([-1, 0]), np.array([2.0, 0.5, 4.0]))
    want = np.array([[1 + 1j, 2.0, 0.0, 0.0], [0.0, 3j + (2 + 4j), 4.0 - 1.0, -1.0 + 2j]])
    np.testing.assert_array_equal(got, want)


def test_band_responses_equal_band_response_of_each_emission():
    """Two emissions: the first with a path beyond the excess delay (dropped) and a diffracted path (its barrier
    loss added), the second a single path; each against band_response with the loss built as numpy builds it."""
    gain = np.array([0.9, 0.5, 0.3, 1.0])
    length = np.array([10.0, 12.0, 60.0, 7.0])
    delay = np.array([64.3, 75.9, 310.0, 64.8])
    keep = np.array([True, True, False, True])
    diffracted = np.array([False, True, False, False])
    k0, k1, n_fft = np.array([3, 5]), np.array([9, 8]), np.array([64, 32])
    alpha = np.array([0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3])     # 6 bins, then 3
    barrier = np.array([5.0, 5.5, 6.0, 6.5, 7.0, 7.5])                # path 1 on emission 0's 6 bins
    got = band_responses(gain, length, delay, keep, diffracted, np.array([0, 3]), np.array([3, 1]), alpha, k0, k1,
                         n_fft, barrier)
    loss0 = alpha[None, :6] * length[:2, None]
    loss0[1] += barrier
    want0 = band_response(gain[:2], loss0, delay[:2], 3, 64)
    want1 = band_response(gain[3:], alpha[None, 6:] * length[3:, None], delay[3:], 5, 32)
    assert np.array_equal(got, np.concatenate([want0, want1]))
    # and H itself by hand at bin 3 of emission 0: Σ g·10^(−L/20)·e^(−j2π·3·τ/64)
    by_hand = sum(g * 10 ** (-(a * L + b) / 20) * np.exp(-2j * np.pi * 3 * tau / 64)
                  for g, a, L, b, tau in ((0.9, 0.5, 10.0, 0.0, 64.3), (0.5, 0.5, 12.0, 5.0, 75.9)))
    assert abs(got[0] - by_hand) < 1e-14        # the phase by rotation: a few ulp (band_response)


def test_csv_rows_equal_numpy_savetxt():
    import io
    rs = np.random.default_rng(5)
    data = rs.standard_normal((9001, 4)) * 100.0
    data[3, 1], data[4, 2], data[5, 0], data[6, 3] = -0.0, np.nan, np.inf, -4e-9
    fmt = ["%.2f", "%.5f", "%.6f", "%.3f"]
    buf = io.StringIO()
    np.savetxt(buf, data, delimiter=",", fmt=fmt)
    assert csv_rows(data, fmt, block_rows=1000) == buf.getvalue()
    assert csv_rows(data[:0], fmt) == ""
    with pytest.raises(ValueError, match="4 formats"):
        csv_rows(data[:, :3], fmt)


def test_render_many_gives_each_emission_what_it_gets_alone():
    """Four emissions, two of one FFT length (a tail each, one diffracted path), one longer, one of another band
    and Doppler factor: rendered together each equals its render alone, sample for sample (no row given another's
    taps, band or chirp); nothing to render gives nothing."""
    from features.site import Beacon, Origin, Site
    from simulation.acoustic.channel import PathSet
    from simulation.acoustic.chirp import ChirpSpec
    from simulation.acoustic.synthesis import AudioConfig, ChirpRenderer

    site = Site(name="t", origin=Origin(31.0, 118.0), beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),))
    renderer = ChirpRenderer(site, AudioConfig())

    def paths(lengths, kinds):
        n = len(lengths)
        return PathSet(kind=np.array(kinds), length_m=np.array(lengths), gain=np.linspace(1.0, 0.5, n),
                       detour_m=np.where(np.array(kinds) == 3, 0.4, 0.0), box=np.full(n, -1), direct_m=lengths[0],
                       los=True)

    a, b = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2), ChirpSpec(18_000.0, 21_000.0, 0.008, 0.3)
    args = [(paths([12.0, 13.5], [0, 3]), a, 1.002, 4000.25, 0.3, 1, 1.0),
            (paths([12.1, 12.9], [0, 1]), a, 1.001, 9000.75, 0.35, 2, 0.5),
            (paths([30.0, 55.0], [0, 2]), a, 0.998, 20000.5, 0.9, 3, 1.0),
            (paths([8.0], [0]), b, 1.0, 100.0, 0.0, 4, 2.0)]
    together = renderer.render_many([(*e[:5], np.random.default_rng(e[5]), e[6]) for e in args])
    assert len({len(seg) for _, seg in together}) >= 2          # more than one FFT length in the batch
    for (start, seg), e in zip(together, args):
        alone_start, alone = renderer.render(*e[:5], np.random.default_rng(e[5]), e[6])
        assert start == alone_start and np.array_equal(seg, alone)
        assert np.abs(seg).max() > 0
    assert renderer.render_many([]) == []


@pytest.mark.parametrize("n", [480, 3125, 6144, 11025])
def test_scipy_fft_over_rows_equals_each_row_alone(n):
    """The group renderer's premise: pocketfft transforms each row of a 2-D array as it transforms that row
    alone, bit for bit, forward (real) and inverse, at the fast lengths the renderer picks."""
    import scipy.fft as sfft

    x = np.random.default_rng(n).standard_normal((7, n))
    rows = sfft.rfft(x, n, axis=-1)
    assert all(np.array_equal(rows[i], sfft.rfft(x[i], n)) for i in range(7))
    back = sfft.irfft(rows, n, axis=-1)
    assert all(np.array_equal(back[i], sfft.irfft(rows[i], n)) for i in range(7))
