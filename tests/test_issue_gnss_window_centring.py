"""Issue 11 (smaller): GNSS windows were centred half an epoch interval early.

A receiver's C/N0 at fix time t is its estimate over the interval ending at t,
(t − Δt, t] (the simulator averages power over it). Windows took epochs by t,
so a 2 s window on [s, s + 2) covered [s − Δt, s + 2 − Δt): 0.1 s early at
5 Hz, 0.5 s early at 1 Hz. Epochs now go to windows by t − Δt/2.

The check: an attenuation ramp of 1 dB/s, each epoch reporting its interval's
mean, so a window's mean attenuation reads the ramp at the time the window
measured. Before: μ = a(t_window) − 0.1 dB at 5 Hz (−0.5 dB at 1 Hz); after: a(t_window).
"""

import numpy as np
import pytest

from features.gnss.features import Cn0Reference, GnssFeatureConfig, SkyArrays, gnss_features

SLOPE_DB_S = 1.0
OFFSET_DB = 5.0


def _ramp_sky(rate_hz: float, duration_s: float = 20.0, interval_known: bool = True) -> SkyArrays:
    dt = 1.0 / rate_hz
    t = np.arange(0.0, duration_s + 1e-9, dt)
    el = np.tile(np.array([90.0, 60, 60, 60, 60]), (t.size, 1))
    az = np.tile(np.array([0.0, 0, 90, 180, 270]), (t.size, 1))
    # mean attenuation over (t − dt, t] of a(τ) = OFFSET + SLOPE·τ: a at t − dt/2
    att = OFFSET_DB + SLOPE_DB_S * (t - 0.5 * dt)
    cn0 = Cn0Reference().cref_dbhz(el) - att[:, None]
    ones = np.ones(el.shape, bool)
    return SkyArrays(t, tuple(("GPS", i + 1) for i in range(5)), el, az, cn0, ones, ones, np.ones(t.size),
                     dt if interval_known else float("nan"))


@pytest.mark.parametrize("rate_hz, early_before_s", [(5.0, 0.1), (1.0, 0.5)])
@pytest.mark.parametrize("interval_known", [True, False])
def test_windows_read_the_ramp_at_their_centre(rate_hz, early_before_s, interval_known):
    f = gnss_features(_ramp_sky(rate_hz, interval_known=interval_known), GnssFeatureConfig(window_s=2.0, hop_s=1.0))
    full = f["n_epochs"] == int(round(2.0 * rate_hz))
    assert full.sum() >= 17
    expected = OFFSET_DB + SLOPE_DB_S * f["t_s"][full]
    # before the fix: f["att_mean_db"] − expected = −early_before_s · SLOPE everywhere
    np.testing.assert_allclose(f["att_mean_db"][full], expected, atol=1e-9)
    assert early_before_s * SLOPE_DB_S > 0.09  # the error the old assignment made, far above the tolerance


def test_window_grid_and_counts_at_5_hz():
    """Windows stay on whole seconds of walk time (the audio grid); a full 5 Hz window holds the
    10 epochs whose intervals tile it: [0, 2) holds t = 0.2 … 2.0 (before: 0.0 … 1.8)."""
    sky = _ramp_sky(5.0, duration_s=6.0)
    f = gnss_features(sky, GnssFeatureConfig(window_s=2.0, hop_s=1.0))
    # the epoch at t = 0 measured (−0.2, 0]: it opens the window [−1, 1)
    assert f["t_s"].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert f["n_epochs"].tolist() == [6, 10, 10, 10, 10, 10]   # [−1, 1): t = 0 … 1.0


def test_interval_comes_from_every_epoch_not_only_the_sky_ones():
    """A receiver that reports its sky every 5th fix at 5 Hz still measured over 0.2 s intervals."""
    from features.gnss.features import sky_arrays
    from features.gnss.nmea import Epoch, Fix, Satellite

    fix = Fix(None, None, None, None, 0, None, None, None, None, None)
    sat = (Satellite("GPS", 1, None, 50.0, 10.0, 40.0, False),)
    epochs = [Epoch(0.2 * i, None, 0.2 * i, fix, sat if i % 5 == 0 else (), i % 5 == 0) for i in range(50)]
    sky = sky_arrays(epochs)
    assert sky.n_epochs == 10
    assert sky.epoch_interval_s == pytest.approx(0.2)
