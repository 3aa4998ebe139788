"""The true air of a recording (issue 10 item 3): thermometer error, hot air, humidity, wind."""

import numpy as np
import pytest

from features.site import Atmosphere, Box, Origin, Site
from simulation.acoustic.air import Air, AirConfig, moist_speed_of_sound_m_s
from simulation.acoustic.atmosphere import speed_of_sound_m_s

TANK = Box("transformer", "steel", False, 10.0, 18.0, 0.0, 5.0, 5.5)
SITE = Site("air", Origin(30.0, 114.0, 0.0), atmosphere=Atmosphere(20.0, 60.0, 101.325), layout=(TANK,))


def _air(seed, **kw):
    return Air(SITE, np.random.default_rng(seed), np.random.default_rng(seed + 100), 120.0, AirConfig(**kw))


def test_thermometer_error_is_one_to_two_kelvin_either_way():
    errs = np.array([_air(s).thermometer_error_k for s in range(100)])
    assert np.all((np.abs(errs) >= 1.0) & (np.abs(errs) <= 2.0)) and 0.3 < np.mean(errs > 0) < 0.7
    a = _air(3)
    assert a.temperature_c == pytest.approx(20.0 - a.thermometer_error_k)


def test_humidity_raises_the_speed_of_sound_by_tenths_of_a_percent():
    dry = moist_speed_of_sound_m_s(20.0, 0.0)
    assert dry == pytest.approx(speed_of_sound_m_s(20.0), rel=5e-4)     # dry air: the ideal-gas value
    wet = moist_speed_of_sound_m_s(20.0, 60.0)
    # Cramer (1993): 20 °C, 60 % RH is about 0.2-0.3 % faster than dry air.
    assert 0.0015 < wet / dry - 1.0 < 0.0035


def test_hot_air_beside_the_transformer_decays_with_distance():
    a = _air(1)
    t = a.temperature_at_c(np.array([14.0, 20.0, 60.0]), np.array([6.0, 2.5, 2.5]))
    assert t[0] - a.temperature_c == pytest.approx(a.hot_air_k * np.exp(-1.0 / 4.0), rel=1e-6)
    assert t[0] > t[1] > t[2] and t[2] - a.temperature_c < 0.01


def test_wind_changes_the_effective_speed_along_the_path_only():
    a = _air(2, hot_air_min_k=0.0, hot_air_max_k=0.0, gust_share=0.0, gust_floor_m_s=0.0)
    w = a.wind_mean
    src = np.array([-40.0, 40.0, 3.0])
    down = src + np.array([w[0], w[1], 0.0]) / np.linalg.norm(w) * 20.0
    up = src - np.array([w[0], w[1], 0.0]) / np.linalg.norm(w) * 20.0
    c0 = a.mean_c()
    assert a.c_eff(0.0, src, down) - c0 == pytest.approx(np.linalg.norm(w) * 20.0 / np.linalg.norm(down - src), rel=1e-6)
    assert a.c_eff(0.0, src, up) - c0 == pytest.approx(-(a.c_eff(0.0, src, down) - c0), rel=1e-6)
    assert 0.0 <= np.linalg.norm(w) <= 4.0


def test_gusts_are_correlated_over_seconds():
    a = _air(4, gust_share=0.3)
    t = np.arange(0.0, 100.0, 0.1)
    g = np.array([a.wind_at(x) for x in t]) - a.wind_mean
    rho1 = np.mean(g[:-10] * g[10:]) / np.mean(g * g)   # 1 s lag, τ = 5 s: e^-0.2
    assert rho1 == pytest.approx(np.exp(-0.2), abs=0.15)


def test_disabled_air_is_the_stated_air():
    a = _air(5, enabled=False)
    assert a.temperature_c == 20.0 and a.mean_c() == pytest.approx(speed_of_sound_m_s(20.0))
    assert a.c_eff(1.0, np.zeros(3), np.array([10.0, 0.0, 0.0])) == pytest.approx(speed_of_sound_m_s(20.0))
