"""The statistics behind the drive's figures (issue 24): block-bootstrap comparisons over one recording, Spearman
with block intervals, the error per window, GNSS-only clustering, odometry steps spread over their own segments.
Expected values worked by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest


def test_block_compare_interval_is_over_blocks_worked_by_hand():
    """Two 20 s blocks of 20 epochs: A = 1 m throughout; B = 1 m in the first block, 3 m in the second. A resample
    of blocks is one of AA, AB, BA, BB (equally likely): Δ = 20/20 − 1 = 0, 40/80 − 1 = −0.5 twice, 20/60 − 1 =
    −2/3. Over 4000 resamples the 2.5 % and 97.5 % quantiles are −2/3 and 0; Δ over all epochs is −0.5. A bootstrap
    over epochs would give a narrow interval round −0.5 instead."""
    from pipeline.compare import block_compare

    t = np.arange(40.0)
    c = block_compare(t, np.ones(40), t, np.r_[np.ones(20), np.full(20, 3.0)], "A", "B", block_s=20.0)
    assert c.delta == pytest.approx(-0.5)
    assert c.lo == pytest.approx(-2.0 / 3.0) and c.hi == pytest.approx(0.0)
    assert (c.n_epochs, c.n_blocks, c.mean_a_m, c.mean_b_m) == (40, 2, 1.0, 2.0)
    assert c.excludes_zero is False


def test_block_compare_keeps_every_event_of_one_stream():
    """A filter's events repeat times (a step and a fix at one epoch): two runs on one stream pair row by row."""
    from pipeline.compare import block_compare

    t = np.array([0.0, 0.3, 0.3, 0.6, 0.6])
    c = block_compare(t, np.array([1.0, 1.0, 3.0, 1.0, 5.0]), t, np.full(5, 2.0), block_s=20.0, n_boot=50)
    assert c.n_epochs == 5 and c.delta == pytest.approx(11.0 / 10.0 - 1.0)
    d = block_compare(np.array([0.0, 1.0, 2.0]), np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 5.0]),
                      np.array([4.0, 4.0, 4.0]), block_s=20.0, n_boot=50)
    assert d.n_epochs == 2 and d.delta == pytest.approx(5.0 / 8.0 - 1.0)


def test_spearman_by_hand_and_its_block_interval():
    """x = 1..5, y = 2 1 4 3 5: rank differences −1 1 −1 1 0, ρ = 1 − 6·4/(5·24) = 0.8. With two blocks (t < 20,
    t ≥ 20) the bootstrap interval's ends are among the statistics of the four block resamples."""
    from scipy.stats import spearmanr

    from pipeline.env_error import rank_correlation

    x = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0])
    y = np.array([2.0, 1.0, 4.0, 3.0, 5.0, 8.0, 6.0, 7.0])
    r5 = rank_correlation(x[:5], y[:5], np.arange(5.0), block_s=100.0, n_boot=100)
    assert r5.rho == pytest.approx(0.8)
    t = np.array([0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0])
    r = rank_correlation(x, y, t, name="P(heavy)", block_s=20.0)
    blocks = [np.arange(4), np.arange(4, 8)]
    outcomes = {round(float(spearmanr(x[np.r_[blocks[a], blocks[b]]], y[np.r_[blocks[a], blocks[b]]]).statistic), 9)
                for a, b in itertools.product((0, 1), repeat=2)}
    assert round(r.lo, 9) in outcomes and round(r.hi, 9) in outcomes
    assert r.lo <= r.rho <= r.hi and r.n_blocks == 2 and r.n == 8
    assert "P(heavy): Spearman rho +" in str(r)


def test_window_error_takes_the_fixes_inside_each_window():
    """Window (end − 2, end]: a fix exactly at a window's end counts, one exactly 2 s before does not."""
    from pipeline.env_error import occlusion_scores, window_error

    w = window_error(np.array([2.0, 4.0, 9.0]), np.array([0.0, 1.0, 2.0, 3.0]), np.array([10.0, 2.0, 4.0, 6.0]))
    np.testing.assert_allclose(w[:2], [3.0, 6.0])           # (2 + 4)/2; then 6 alone (the fix at 2 s is out)
    assert np.isnan(w[2])
    s = occlusion_scores(np.array([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(s["E[severity]"], [1.3, 0.0])
    np.testing.assert_allclose(s["P(heavy)"], [0.5, 0.0])


def test_gnss_only_windows_cluster_on_the_gnss_features():
    """A drive has no beacons: the windows are clustered on the five GNSS features, and the clusters named by
    severity (the synthetic library's attenuation grows 2 → 7 → 12 dB from open to heavy)."""
    from sklearn.metrics import adjusted_rand_score

    from tests.env_synth import synthetic_library
    from training.clustering import cluster_columns, cluster_windows

    X, y = synthetic_library(300, seed=2)
    X[:, 5:] = np.nan
    assert cluster_columns(X) == (0, 1, 2, 3, 4)
    r = cluster_windows(X, method="kmeans", random_state=0)
    assert adjusted_rand_score(y, r.labels) > 0.9
    att = [X[r.labels == k, 0].mean() for k in range(3)]
    assert att[0] < att[1] < att[2]
    both = synthetic_library(300, seed=3)[0]
    assert cluster_columns(both) == tuple(range(14))
    mixed = both.copy()
    mixed[:280, 5:] = np.nan            # 20 complete windows, GNSS in every one but acoustic in some: refused
    from features.errors import DataError

    with pytest.raises(DataError, match="clustering needs at least 40"):
        cluster_windows(mixed, method="kmeans")


def test_odometry_segments_split_at_fixes_inside_them():
    """An odometry event states its own segment (0.3 s), not the walker's 0.55 s after a stop: a fix inside the
    segment cuts it in proportion to time; σ_L of a part is σ_L·√f, its heading σ the event's."""
    from walks.inputs import split_steps

    t, length, heading = split_steps(np.array([10.0, 10.3]), np.array([3.0, 3.0]), np.array([0.1, 0.2]),
                                     np.array([9.6, 10.1]), duration_s=np.array([0.3, 0.3]))
    np.testing.assert_allclose(t, [10.0, 10.1, 10.3])
    np.testing.assert_allclose(length, [3.0, 1.0, 2.0])
    np.testing.assert_allclose(heading, [0.1, 0.2, 0.2])
    # the walker's rule would have started the first step 0.55 s earlier and cut it at 9.6
    t_w, l_w, _ = split_steps(np.array([10.0, 10.3]), np.array([3.0, 3.0]), np.array([0.1, 0.2]), np.array([9.6]))
    np.testing.assert_allclose(t_w[:2], [9.6, 10.0])


def test_unknown_truth_class_is_not_shaded_as_heavy():
    """Class code −1 (unknown) must not index the class colours (ENV_CLASSES[−1] is 'heavy')."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline import evaluate_plots

    fig, ax = plt.subplots()
    evaluate_plots._class_band(ax, {"t_s": np.arange(5.0), "cls": np.array([-1, -1, 2, 2, -1])})
    assert len(ax.patches) == 1                    # the heavy span only
    plt.close(fig)
