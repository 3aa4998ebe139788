"""A standing start with a datasheet-size gyro turn-on bias is still a standing start.

The static-start detector compared |ω| with 3 °/s, so a device whose zero-rate offset (BMI160: ±3 °/s
typical) exceeded it was never "still", its bias was never measured, and the gyro heading ran away: one
held-out simulated walk (quick split, site 203, walk 1) had a PDR mean error of 45.3 m (max 84.9 m) over
180 s; measuring the rate against its own start value gives 7.3 m (max 14.3 m), bias −2.2 °/s found.
"""

import math

import numpy as np

from features.imu.heading import HeadingConfig, _static_start, estimate_heading


def _standing_then_turning(bias_deg_s: float, rate_hz: float = 100.0):
    rng = np.random.default_rng(3)
    n_still, n_turn = 500, 500
    acc = np.tile([0.0, 0.0, 9.81], (n_still + n_turn, 1)) + rng.normal(0, 0.02, (n_still + n_turn, 3))
    gyro = np.zeros((n_still + n_turn, 3))
    gyro[:, 2] = math.radians(bias_deg_s) + rng.normal(0, math.radians(0.1), n_still + n_turn)
    gyro[n_still:, 2] += math.radians(30.0)                 # then a 30 °/s turn
    acc[n_still:] += rng.normal(0, 1.0, (n_turn, 3))       # and walking
    return acc, gyro


def test_a_biased_gyro_at_rest_is_still_detected_as_standing():
    for bias in (0.0, 2.5, 4.0, -5.0):
        acc, gyro = _standing_then_turning(bias)
        n = _static_start(acc, gyro, 100.0, 2.0)
        assert 450 <= n <= 500, (bias, n)


def test_a_start_that_turns_is_not_taken_for_a_bias():
    acc, gyro = _standing_then_turning(20.0)                 # 20 °/s from the first sample: a turn
    assert _static_start(acc, gyro, 100.0, 2.0) == 0


def test_the_bias_measured_on_the_standing_start_is_removed():
    acc, gyro = _standing_then_turning(4.0)
    res = estimate_heading(acc, gyro, None, 100.0, HeadingConfig(static_start_s=2.0))
    # gyro-only heading over the standing part stays put (within 0.3°) instead of drifting 4 °/s × 5 s = 20°
    assert abs(math.degrees(res.gyro_only[499] - res.gyro_only[0])) < 0.3
