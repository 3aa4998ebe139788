"""Matched filter: template, sidelobes, streaming equals one-shot, noise scale."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from features.acoustic.matched_filter import (ChirpSpec, MatchedFilterBank, StreamingMatchedFilter, analytic_convolve,
                                     bandpass_fir, chirp_template)
from tests.acoustic_synth import FS_HZ, add_chirp, chirp_at

SPEC = ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2)


@pytest.fixture(scope="module")
def bank():
    return MatchedFilterBank([SPEC], FS_HZ)


def test_template_is_the_documented_chirp():
    """docs/beacon_protocol.md: s(t) = w(t)·sin(2π(f0·t + ½k·t²)), Tukey w."""
    s = chirp_template(SPEC, FS_HZ)
    ref = chirp_at(np.arange(480) / FS_HZ)
    np.testing.assert_allclose(s, ref, atol=1e-9)


def test_bandpass_passes_the_band_and_stops_hum():
    h = bandpass_fir(FS_HZ)
    w, resp = scipy.signal.freqz(h, worN=[100.0, 1_000.0, 17_000.0, 20_000.0, 23_000.0], fs=FS_HZ)
    db = 20 * np.log10(np.abs(resp))
    assert np.all(db[:2] < -50)                 # transformer hum and speech gone
    assert np.all(np.abs(db[2:]) < 1.0)         # chirp band flat within 1 dB


def test_peak_at_chirp_start_and_sidelobes_below_tap_threshold(bank):
    x = np.zeros(4000)
    add_chirp(x, 1000 / FS_HZ, 1.0)
    env = bank.envelope(x, 0)
    assert int(np.argmax(env)) == 1000
    assert env.max() == pytest.approx(1.0, abs=0.01)
    # Outside the main lobe every sidelobe sits below −30 dB (Kaiser weighting on receive),
    # i.e. well under the −20 dB tap threshold.
    half = int(round(bank.mainlobe_s[0] * FS_HZ / 2)) + 4      # to the first null
    outside = np.r_[env[: 1000 - half], env[1000 + half:]]
    assert 20 * np.log10(outside.max()) < -30.0
    # Main lobe above −20 dB: 27 samples (0.56 ms) at 6 kHz bandwidth.
    assert bank.mainlobe_s[0] * FS_HZ == pytest.approx(27, abs=2)


def test_streaming_equals_one_shot_for_any_blocking(bank):
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.01, 30_000).astype(np.float32)
    add_chirp(x, 0.1, 0.5)
    add_chirp(x, 0.3217, 0.2)
    full = bank.envelope(x, 0)
    for sizes in ([30_000], [12_345, 17_655], [1, 4096, 7, 20_000, 5_892]):
        mf = StreamingMatchedFilter(bank)
        outs, first = [], None
        pos = 0
        for n in sizes:
            j0, env = mf.process(x[pos: pos + n])
            pos += n
            first = j0 if first is None else first
            outs.append(env)
        outs.append(mf.flush()[1])
        env = np.concatenate(outs, axis=1)[0]
        starts = mf.chirp_start(np.arange(len(env)))
        ok = (starts >= 0) & (starts < len(x) - bank.kernel_len)
        assert ok.sum() > 7000
        np.testing.assert_allclose(env[ok], full[starts[ok]], atol=2e-5)
        assert starts[np.argmax(env)] in (4800, 4799, 4801, 4802, 4798)


def test_noise_envelope_is_rayleigh_with_predicted_scale(bank):
    rng = np.random.default_rng(5)
    sigma = 0.01
    x = rng.normal(0, sigma, 200_000)
    env = bank.envelope(x, 0)[2000:-2000]
    # Band-limited white noise: the analytic output's I and Q have std ≈ σ·‖h‖ (in-band share of
    # the kernel's energy is ~1), so the Rayleigh median is σ‖h‖·sqrt(2 ln 2).
    predicted = sigma * bank.noise_gain[0] * np.sqrt(2 * np.log(2))
    assert np.median(env) == pytest.approx(predicted, rel=0.05)
    q25 = np.percentile(env, 25) / np.sqrt(-2 * np.log(0.75))
    assert q25 == pytest.approx(np.median(env) / np.sqrt(2 * np.log(2)), rel=0.03)


def test_analytic_convolve_envelope_of_a_tone():
    n = np.arange(2000)
    z = analytic_convolve(np.cos(2 * np.pi * 0.2 * n), np.array([0.5]))
    assert np.abs(z[200:1800]).mean() == pytest.approx(0.5, rel=1e-3)


def test_hand_written_windows_and_filter_equal_scipy_signal():
    """The receiver avoids importing scipy.signal (1.4 s of start-up): its own Tukey window,
    chirp and band-pass FIR must equal scipy's definitions."""
    import scipy.signal

    from features.acoustic.matched_filter import _firwin_bandpass, _tukey, bandpass_fir, chirp_template, ChirpSpec

    for n, alpha in ((480, 0.2), (481, 0.5), (100, 0.0), (100, 1.0)):
        np.testing.assert_allclose(_tukey(n, alpha), scipy.signal.windows.tukey(n, alpha), atol=1e-12)
    np.testing.assert_allclose(_firwin_bandpass(127, 16_500.0, 23_500.0, 48_000.0),
                               scipy.signal.firwin(127, [16_500.0, 23_500.0], pass_zero=False, fs=48_000.0),
                               atol=1e-12)
    np.testing.assert_allclose(bandpass_fir(44_100.0),
                               scipy.signal.firwin(127, [16_500.0, 0.49 * 44_100.0], pass_zero=False, fs=44_100.0),
                               atol=1e-12)
    t = np.arange(480) / 48_000.0
    ref = scipy.signal.chirp(t, f0=17_000.0, t1=0.010, f1=23_000.0, method="linear", phi=-90.0)
    np.testing.assert_allclose(chirp_template(ChirpSpec(17_000.0, 23_000.0, 0.010, 0.2), 48_000.0),
                               ref * scipy.signal.windows.tukey(480, 0.2), atol=1e-12)


def test_streaming_two_templates_any_segment_length_and_block_order():
    """Buffers reused across blocks that grow and shrink, two templates (band products of
    shape (2, n_seg, ·)), segment lengths 4096 (the default here) and 8192: all equal the
    one-shot full-rate envelope of each template at the decimated instants."""
    rng = np.random.default_rng(3)
    bank2 = MatchedFilterBank([SPEC, ChirpSpec(18_000.0, 22_000.0, 0.020, 0.2)], FS_HZ)
    x = rng.normal(0, 0.01, 60_000).astype(np.float32)
    add_chirp(x, 0.2, 0.5)
    full = [bank2.envelope(x, k) for k in range(2)]
    for nfft, sizes in ((None, [100, 40_000, 3, 600, 19_297]), (8192, [60_000]), (4096, [7] * 10 + [59_930])):
        mf = StreamingMatchedFilter(bank2, nfft=nfft)
        outs = [mf.process(x[a: a + n])[1] for a, n in zip(np.cumsum([0] + sizes[:-1]), sizes)]
        env = np.concatenate(outs + [mf.flush()[1]], axis=1)
        assert env.dtype == np.float32 and env.shape == (2, (len(x) + bank2.delay_samples + 4) // 4)
        starts = mf.chirp_start(np.arange(env.shape[1]))
        ok = (starts >= 0) & (starts < len(x) - bank2.kernel_len)
        for k in range(2):
            np.testing.assert_allclose(env[k, ok], full[k][starts[ok]], atol=2e-5)
    assert StreamingMatchedFilter(bank2).nfft == 8192          # 20 ms template: longer kernel, longer segments
