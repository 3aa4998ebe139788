"""The audio synthesis's compiled kernels (issue 25 item 2) against hand computations with Python's math/cmath.

``band_response`` and ``hum_samples`` evaluate a linear phase with exact sin/cos once per block and a corrected
rotation in between; these tests span several blocks, start the band off bin 0 and give every path its own
delay, gain and loss, so a wrong bin index, a path given another's loss, a rotation off by one step or a residual
of the wrong sign moves the values by far more than the tolerance.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from simulation.acoustic.discharge import add_pulse_templates
from simulation.acoustic.synthesis import band_response, hum_samples


def _h_by_hand(gain, loss_db, delay, k0, n_fft):
    """H[k] = Σ_p g_p·10^(−L_p[k]/20)·exp(−j2π·k·τ_p/n), bin by bin with cmath."""
    out = []
    for j in range(loss_db.shape[1]):
        k = k0 + j
        out.append(sum(float(gain[p]) * 10.0 ** (-float(loss_db[p, j]) / 20.0)
                       * cmath.exp(-2j * math.pi * k * float(delay[p]) / n_fft) for p in range(len(gain))))
    return np.array(out)


def test_band_response_bin_by_bin():
    rng = np.random.default_rng(3)
    n_fft, k0, n_bins = 3645, 1291, 53                  # 53 bins: three full blocks of 16 and a partial one
    gain = np.array([0.8, 0.3, 0.05])
    delay = np.array([64.37, 311.9, 1480.25])           # samples: fractional, up to the longest excess delay
    loss_db = rng.uniform(0.0, 40.0, (3, n_bins))
    h = band_response(gain, loss_db, delay, k0, n_fft)
    want = _h_by_hand(gain, loss_db, delay, k0, n_fft)
    assert h.shape == (n_bins,)
    # the phases reach 2π·1344·1480/3645 ≈ 3,400 rad, rounded to 4.5e-13 rad in either order of operations; one
    # bin off turns path 1 by 0.54 rad, one path's loss given to another changes H by ~0.1
    np.testing.assert_allclose(h, want, rtol=0, atol=1e-12)


def test_band_response_quarter_turn_per_bin():
    """τ = n/4 samples: the phase turns by −π/2 per bin, H[k] = g·(−j)^k (k0 = 5: (−j)^5 = −j first)."""
    n_fft = 4096
    h = band_response(np.array([0.5]), np.zeros((1, 40)), np.array([1024.0]), 5, n_fft)
    want = 0.5 * np.array([(-1j) ** (k % 4) for k in range(5, 45)])
    np.testing.assert_allclose(h, want, rtol=0, atol=1e-12)
    # 6 dB of loss on every bin halves the pressure (10^(−6/20) = 0.501)
    h6 = band_response(np.array([0.5]), np.full((1, 40), 6.0), np.array([1024.0]), 5, n_fft)
    np.testing.assert_allclose(h6, want * 10 ** (-6 / 20), rtol=0, atol=1e-12)


def _hum_by_hand(t, omega, phase, weight):
    """Σ_h w_h·Im(z^h·e^{jφ_h}), z = cos(ωt) + j·sin(ωt) with ωt rounded as float64, sample by sample."""
    out = []
    for ti in t:
        y = omega * float(ti)
        z = complex(math.cos(y), math.sin(y))
        out.append(sum(float(weight[h]) * ((z ** (h + 1)) * cmath.exp(1j * float(phase[h]))).imag
                       for h in range(len(weight))))
    return np.array(out)


def test_hum_samples_sample_by_sample_early_and_late():
    omega = 2 * math.pi * 100.0
    phase = np.array([0.3, 2.1, 4.0, 5.5])
    weight = 10.0 ** (-3.0 * np.arange(4) / 20.0)
    fs = 48_000.0 * (1 + 7e-6)
    for t0 in (-0.013, 583.2):                          # at 583 s ω·t ≈ 3.7e5 rad: the residual ε matters
        t = t0 + np.arange(75) / fs                     # 75 samples: four blocks and a partial one
        got = hum_samples(t, 1.0 / fs, omega, phase, weight)
        np.testing.assert_allclose(got, _hum_by_hand(t, omega, phase, weight), rtol=0, atol=2e-14)
    # a single line of unit weight at phase 0 is sin(ωt): 100 Hz sampled at 400 Hz reads 0, 1, 0, −1, …
    t = np.arange(40) / 400.0
    got = hum_samples(t, 1.0 / 400.0, omega, np.array([0.0]), np.array([1.0]))
    np.testing.assert_allclose(got, np.tile([0.0, 1.0, 0.0, -1.0], 10), rtol=0, atol=1e-12)


def test_add_pulse_templates_rows_and_offsets_by_hand():
    """Two overlapping pulses: sample ⌊pos⌋ takes template row ⌊frac(pos)·P⌋ times its amplitude; sums add."""
    templates = np.arange(4 * 5, dtype=float).reshape(4, 5) + 1.0        # P = 4 fractions, 5 samples each
    out = np.zeros(12)
    add_pulse_templates(out, np.array([2.30, 4.80]), np.array([2.0, -1.0]), templates)
    want = np.zeros(12)
    want[2:7] += 2.0 * templates[1]          # frac 0.30 → row ⌊1.2⌋ = 1
    want[4:9] += -1.0 * templates[3]         # frac 0.80 → row ⌊3.2⌋ = 3
    np.testing.assert_array_equal(out, want)
    # no pulse: nothing added
    add_pulse_templates(out, np.zeros(0), np.zeros(0), templates)
    np.testing.assert_array_equal(out, want)
