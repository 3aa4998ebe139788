"""CIR features: closed forms on hand-made tap sets, tap-spacing invariance, and a two-path channel."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from features.acoustic.cir import (FEATURE_NAMES, K_MAX_DB, analyse_cir, analyse_cirs, find_paths, first_arrivals,
                                   noise_threshold_factor)
from features.acoustic.matched_filter import ChirpSpec, MatchedFilterBank
from tests.acoustic_synth import FS_HZ, add_chirp


def _two_taps(tap_s=1e-3):
    a = np.zeros(64)
    a[10], a[30] = 1.0, 0.5          # powers 1 and 0.25, 20 taps apart
    return analyse_cir(a, tap_s, noise_power=1e-12)


def test_two_point_profile_closed_forms():
    """Powers (1, 0.25) at delays (0, 20 taps): weights p = (0.8, 0.2)."""
    r = _two_taps(1e-3)
    f = r.features
    p = 0.2
    assert r.first_arrival_tap == pytest.approx(10.0)
    assert f.mean_excess_delay_ms == pytest.approx(p * 20.0)                      # Σpτ/Σp = 4 ms
    assert f.rms_delay_ms == pytest.approx(20.0 * math.sqrt(p * (1 - p)))         # 8 ms
    assert f.delay_skewness == pytest.approx((1 - 2 * p) / math.sqrt(p * (1 - p)))  # 1.5
    assert f.delay_kurtosis == pytest.approx((1 - 3 * p * (1 - p)) / (p * (1 - p)))  # 3.25 (Pearson)
    assert f.rician_k_db == pytest.approx(10 * math.log10(4.0))
    g = np.array([0.0, 10 * math.log10(0.25)])
    assert f.gain_mean_db == pytest.approx(g.mean())
    assert f.gain_rms_db == pytest.approx(math.sqrt(np.mean(g ** 2)))
    assert f.gain_skewness == pytest.approx(0.0, abs=1e-12)
    assert f.gain_kurtosis == pytest.approx(1.0)


def test_tap_spacing_scales_delays_only():
    a, b = _two_taps(1e-3).features, _two_taps(1e-9).features
    assert b.mean_excess_delay_ms == pytest.approx(a.mean_excess_delay_ms * 1e-6)
    assert b.rms_delay_ms == pytest.approx(a.rms_delay_ms * 1e-6)
    for name in ("delay_kurtosis", "delay_skewness", "rician_k_db", "gain_mean_db", "gain_rms_db",
                 "gain_kurtosis", "gain_skewness"):
        assert getattr(b, name) == pytest.approx(getattr(a, name))


def test_thresholds_peak_minus_20db_and_the_noise_false_alarm_budget():
    """Taps above max(peak − 20 dB, N₀·ln(n_taps / 1 %)): for 100 taps the noise threshold is
    ln(10⁴) = 9.21 times (9.6 dB above) the noise power; a tap just above it is kept, just below dropped."""
    a = np.zeros(100)
    a[[10, 20, 30]] = [1.0, 0.11, 0.09]     # −19.2 dB kept, −20.9 dB dropped
    r = analyse_cir(a, 1.0, noise_power=1e-12)
    assert r.tap_index.tolist() == [10, 20]
    factor = math.log(100 / 1e-2)
    assert noise_threshold_factor(100) == pytest.approx(factor)
    r = analyse_cir(a, 1.0, noise_power=0.11 ** 2 / factor * 0.99)     # threshold just below tap 20
    assert r.tap_index.tolist() == [10, 20]
    r = analyse_cir(a, 1.0, noise_power=0.11 ** 2 / factor * 1.01)     # now just above tap 20
    assert r.tap_index.tolist() == [10]
    assert r.features.rician_k_db == K_MAX_DB
    assert math.isnan(r.features.delay_skewness) and r.features.rms_delay_ms == 0.0


def test_noise_only_gives_none():
    rng = np.random.default_rng(3)
    a = np.abs(rng.normal(size=500) + 1j * rng.normal(size=500)) * 1e-3
    assert analyse_cir(a, 1.0, noise_power=float(np.mean(a ** 2)) * 100) is None


def test_leading_edge_finds_weak_direct_path_before_stronger_echo():
    t = np.arange(300)
    lobe = lambda c: np.exp(-0.5 * ((t - c) / 2.0) ** 2)
    a = 0.3 * lobe(100) + 1.0 * lobe(130)        # NLOS-like: direct 10.5 dB below the echo
    r = analyse_cir(a, 1.0, noise_power=1e-10, max_lead_s=50.0, pulse_width_s=8.0)
    assert r.first_arrival_tap == pytest.approx(100.0, abs=0.05)
    assert r.peak_tap == 130
    # K = first-path power / power of the other taps: the two lobes have equal shapes, so
    # K ≈ 20·log10(0.3 / 1.0) = −10.46 dB, less the first lobe's taps counted among "the others".
    assert r.features.rician_k_db == pytest.approx(20 * math.log10(0.3), abs=0.5)
    # With a look-back shorter than the separation the echo is taken as the first arrival.
    r = analyse_cir(a, 1.0, noise_power=1e-10, max_lead_s=20.0, pulse_width_s=8.0)
    assert r.first_arrival_tap == pytest.approx(130.0, abs=0.05)


def test_gain_moments_match_scipy():
    rng = np.random.default_rng(7)
    a = np.abs(rng.normal(size=400)) + 0.2
    a[50] = 5.0
    r = analyse_cir(a, 1.0, noise_power=1e-12)
    g = 10 * np.log10(r.tap_power / r.tap_power.max())
    assert len(g) > 50
    assert r.features.gain_skewness == pytest.approx(scipy.stats.skew(g))
    assert r.features.gain_kurtosis == pytest.approx(scipy.stats.kurtosis(g, fisher=False))


def test_batch_equals_single():
    rng = np.random.default_rng(11)
    rows = np.abs(rng.normal(size=(5, 200))) * 0.05
    for i in range(5):
        rows[i, 40 + 10 * i] = 1.0
        rows[i, 60 + 7 * i] = 0.4
    batch = analyse_cirs(rows, 1e-4, noise_power=1e-4, max_lead_s=2e-3, pulse_width_s=3e-4)
    for i in range(5):
        one = analyse_cir(rows[i], 1e-4, noise_power=1e-4, max_lead_s=2e-3, pulse_width_s=3e-4)
        np.testing.assert_allclose(batch.features[i], one.features.as_array(), equal_nan=True)
        assert batch.first_arrival_tap[i] == pytest.approx(one.first_arrival_tap)
    assert len(FEATURE_NAMES) == 9


def test_scalar_first_arrivals_equal_the_batch_row_for_row():
    """The receiver's per-frame compiled timing and the batched features time the same arrival:
    Rayleigh noise with one to three paths (some below the thresholds, some weak and early),
    random search starts, noise power given; validity, τ₀ and peak SNR agree exactly."""
    rng = np.random.default_rng(12)
    n, length, lead, stop = 400, 63, 30, 57
    amp = rng.rayleigh(1.0, (n, length))
    for row in amp:
        for _ in range(rng.integers(1, 4)):
            k = rng.integers(0, length)
            row[max(k - 2, 0): k + 3] += rng.choice([0.5, 3.0, 30.0]) * np.array([0.3, 0.8, 1.0, 0.8, 0.3])[
                max(2 - k, 0): 2 + length - k]
    amp = amp.astype(np.float32)
    starts = rng.integers(0, 40, n)
    batch = analyse_cirs(amp, 1e-3, noise_power=2.0, max_lead_s=lead * 1e-3, search_start=starts,
                         search_stop=stop, with_features=False)
    valid, tau, snr_db = first_arrivals(amp, starts, stop, lead, 2.0)
    assert valid.tolist() == batch.valid.tolist()
    assert 50 < batch.valid.sum() < n                     # both outcomes occur
    np.testing.assert_allclose(tau[valid], batch.first_arrival_tap[batch.valid], rtol=0, atol=1e-12)
    np.testing.assert_allclose(snr_db[valid], batch.peak_snr_db[batch.valid], rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_path_channel_recovers_delays_and_gain_ratio(seed):
    """Must-show: a hand-built two-path channel, h(t) = δ(t − τ₁) + g·δ(t − τ₂), through the
    receiver's band-pass + matched filter: both delays within one sample, gain ratio within 1 dB."""
    rng = np.random.default_rng(seed)
    tau1_s = 0.0100 + rng.uniform(0, 1) / FS_HZ           # fractional-sample delays
    tau2_s = tau1_s + rng.uniform(0.0015, 0.004)           # 1.5–4 ms later (0.5–1.4 m extra path)
    gain_db = -rng.uniform(3.0, 9.0)
    x = rng.normal(0.0, 0.003, int(0.05 * FS_HZ))
    add_chirp(x, tau1_s, 0.2)
    add_chirp(x, tau2_s, 0.2 * 10 ** (gain_db / 20))
    bank = MatchedFilterBank([ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)], FS_HZ)
    env = bank.envelope(x, 0)
    pos, amp = find_paths(env, 0.1 * env.max())
    assert len(pos) == 2
    assert abs(pos[0] - tau1_s * FS_HZ) < 1.0
    assert abs(pos[1] - tau2_s * FS_HZ) < 1.0
    assert abs(20 * np.log10(amp[1] / amp[0]) - gain_db) < 1.0
