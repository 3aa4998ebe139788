"""Issue 25 item 2, the audio stream's batches: seeds mixed for a batch of emissions at once, against numpy.

The files a seeded walk writes were compared byte for byte with main's (sha256 of every file of five walks and a
survey on five sites; the branch's report).
"""

from __future__ import annotations

import numpy as np
import pytest

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
