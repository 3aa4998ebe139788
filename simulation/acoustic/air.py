"""The air a chirp actually crosses: true temperature (not the crew's reading), hot air, humidity, wind.

``site.toml`` carries what the crew measured — one thermometer reading, off
by its error and by the hours between survey and walk. The true air of a
recording is drawn here (seeded) and never written where the receiver reads:

* **Air temperature**: T = T_site + ε, ε = ±U(1, 2) K (a hand thermometer
  in sun or shade and the day's drift; the issue's ±1–2 K), drawn per crew
  (``person_seed``: one survey, one reading).
* **Warm air over equipment**: transformers run at 60–90 °C oil temperature
  and heat the air beside them; the excess falls off with distance,
  ΔT(x) = ΔT₀·Σ exp(−dᵢ/ℓ) over transformers (dᵢ horizontal distance to the
  tank, ΔT₀ ~ U(2, 5) K, ℓ = 4 m; a modelling choice). The chirp's travel
  time uses the mean of T along the straight beacon–receiver line (5 points),
  the path-averaged sound speed of ray acoustics.
* **Humidity**: the speed of sound of moist air from the virtual temperature,
  c = 20.05·sqrt(T_v), T_v = T/(1 − 0.378·e/p), e = RH·p_sat(T) with p_sat of
  ISO 9613-1 Annex B (Cramer 1993, J. Acoust. Soc. Am. 93(5), to within
  0.1 % in this range; Ostashev & Wilson 2015, *Acoustics in Moving
  Inhomogeneous Media*, 2nd ed., eq. (2.16)).
* **Wind**: a mean vector (speed ~ U(0, ``wind_max_m_s``), direction
  uniform) plus gusts, a Gauss–Markov process per axis (σ = ``gust_share``
  of the mean speed plus 0.2 m/s, τ = ``gust_tau_s``). Sound moves with the
  air: along a path of direction n̂ the effective speed is c_eff = c + w·n̂
  (Ostashev & Wilson 2015, the effective sound speed approximation, eq. (3.28)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from features.errors import ConfigError
from features.site import Site
from simulation.acoustic.atmosphere import speed_of_sound_m_s

__all__ = ["AirConfig", "Air", "moist_speed_of_sound_m_s"]


@dataclass(frozen=True)
class AirConfig:
    """Parameters of the true air (K, m/s, s, m as named); ``enabled`` False gives the site's stated air.

    Each term is off when its size is 0 (``thermometer_*_k``, ``hot_air_*_k``, ``wind_max_m_s`` with
    ``gust_floor_m_s``); ``humidity`` False makes the true air dry (the receiver's own assumption), so
    that each error source can be switched off alone (``bench/acoustic_error_causes.py``).
    """

    enabled: bool = True
    humidity: bool = True
    thermometer_min_k: float = 1.0
    thermometer_max_k: float = 2.0
    hot_air_min_k: float = 2.0
    hot_air_max_k: float = 5.0
    hot_air_scale_m: float = 4.0
    wind_max_m_s: float = 4.0
    gust_share: float = 0.3
    gust_floor_m_s: float = 0.2
    gust_tau_s: float = 5.0

    def __post_init__(self):
        for name, value in vars(self).items():
            if name not in ("enabled", "humidity") and not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"AirConfig.{name} must be finite and non-negative, got {value!r}")
        if self.thermometer_max_k < self.thermometer_min_k or self.hot_air_max_k < self.hot_air_min_k:
            raise ConfigError("AirConfig needs thermometer_min_k <= thermometer_max_k, hot_air_min_k <= hot_air_max_k")
        if self.gust_tau_s <= 0 or self.hot_air_scale_m <= 0:
            raise ConfigError("AirConfig needs gust_tau_s > 0 and hot_air_scale_m > 0")


def moist_speed_of_sound_m_s(temperature_c, relative_humidity_pct: float, pressure_kpa: float = 101.325):
    """Speed of sound in moist air, m/s: c = 20.05·sqrt(T_v), T_v = T/(1 − 0.378·e/p) (see module docstring).

    >>> round(float(moist_speed_of_sound_m_s(20.0, 0.0)), 2), round(float(moist_speed_of_sound_m_s(20.0, 100.0)), 2)
    (343.29, 344.79)
    """
    t_k = np.asarray(temperature_c, float) + 273.15
    c_exp = -6.8346 * (273.16 / t_k) ** 1.261 + 4.6151          # ISO 9613-1 eq. B.3: p_sat / p_r = 10^C
    e_over_p = relative_humidity_pct / 100.0 * 10.0 ** c_exp * 101.325 / pressure_kpa
    return 20.05 * np.sqrt(t_k / (1.0 - 0.378 * e_over_p))


class Air:
    """The true air of one recording; :meth:`c_eff` gives the effective speed of sound of a path.

    Parameters
    ----------
    site : the site (stated atmosphere, transformers); crew_seed_rng, rng : generators for the crew's
        thermometer error and for this recording's hot air and wind; duration_s : recording length (the
        gust process is tabulated over it at 0.1 s).
    """

    def __init__(self, site: Site, crew_rng: np.random.Generator, rng: np.random.Generator, duration_s: float,
                 cfg: AirConfig = AirConfig()):
        self.cfg = cfg
        atm = site.atmosphere
        self.rh_pct = atm.relative_humidity_pct if cfg.humidity else 0.0
        self.pressure_kpa = atm.pressure_kpa
        if not cfg.enabled:
            self.thermometer_error_k = 0.0
            self.temperature_c = atm.temperature_c
            self.hot_air_k = 0.0
            self.wind_mean = np.zeros(2)
            self._gust_t = np.array([0.0, max(duration_s, 1.0) + 10.0])
            self._gust = np.zeros((2, 2))
            self._tx = np.zeros((0, 4))
            self._dry = True
            return
        self._dry = False
        self.thermometer_error_k = float(crew_rng.choice([-1.0, 1.0])
                                         * crew_rng.uniform(cfg.thermometer_min_k, cfg.thermometer_max_k))
        self.temperature_c = atm.temperature_c - self.thermometer_error_k  # the reading = truth + error
        self.hot_air_k = float(rng.uniform(cfg.hot_air_min_k, cfg.hot_air_max_k))
        speed = float(rng.uniform(0.0, cfg.wind_max_m_s))
        direction = float(rng.uniform(0.0, 2.0 * np.pi))
        self.wind_mean = speed * np.array([math.sin(direction), math.cos(direction)])  # east, north
        dt = 0.1
        n = int(math.ceil((max(duration_s, 1.0) + 10.0) / dt)) + 1
        self._gust_t = -5.0 + dt * np.arange(n)
        phi = math.exp(-dt / cfg.gust_tau_s)
        sigma = cfg.gust_share * speed + cfg.gust_floor_m_s
        w = rng.standard_normal((n, 2))
        g = np.empty((n, 2))
        g[0] = w[0]
        for i in range(1, n):
            g[i] = phi * g[i - 1] + math.sqrt(1.0 - phi * phi) * w[i]
        self._gust = sigma * g
        self._tx = np.array([[b.east_min_m, b.east_max_m, b.north_min_m, b.north_max_m]
                             for b in site.layout if b.kind == "transformer"]).reshape(-1, 4)

    def temperature_at_c(self, east_m, north_m) -> np.ndarray:
        """True air temperature at ground points, °C (hot air beside transformers)."""
        e = np.atleast_1d(np.asarray(east_m, float))
        n = np.atleast_1d(np.asarray(north_m, float))
        t = np.full(e.shape, self.temperature_c)
        if self._tx.shape[0] and self.hot_air_k > 0:
            de = np.maximum(np.maximum(self._tx[:, 0] - e[:, None], e[:, None] - self._tx[:, 1]), 0.0)
            dn = np.maximum(np.maximum(self._tx[:, 2] - n[:, None], n[:, None] - self._tx[:, 3]), 0.0)
            t = t + self.hot_air_k * np.exp(-np.hypot(de, dn) / self.cfg.hot_air_scale_m).sum(axis=1)
        return t

    def wind_at(self, t_s) -> np.ndarray:
        """Wind vector (east, north), m/s, at recording time(s) ``t_s``: shape (2,) for a scalar, (n, 2) for (n,)."""
        g = np.stack([np.interp(t_s, self._gust_t, self._gust[:, 0]), np.interp(t_s, self._gust_t, self._gust[:, 1])],
                     axis=-1)
        return self.wind_mean + g

    def c_eff(self, t_s, src_m: np.ndarray, rx_m: np.ndarray):
        """Effective speed of sound from ``src_m`` to ``rx_m`` (ENU, m) at time ``t_s``: path-mean c + w·n̂, m/s.

        The path mean is over 5 points evenly spaced from source to receiver (hot air beside transformers);
        w the wind at ``t_s``, n̂ the path's unit vector. ``t_s`` a float and ``src_m``, ``rx_m`` of shape (3,)
        give a float; ``t_s`` (n,) and positions (n, 3) (or one of them (3,)) give an array (n,).
        """
        scalar = np.ndim(t_s) == 0
        t = np.atleast_1d(np.asarray(t_s, float))
        src, rx = np.broadcast_arrays(np.atleast_2d(np.asarray(src_m, float)), np.atleast_2d(np.asarray(rx_m, float)))
        if self._dry:
            c = np.full(len(t), self.mean_c())
            return float(c[0]) if scalar else c
        s = np.linspace(0.0, 1.0, 5)
        pts = src[:, None, :2] + s[None, :, None] * (rx[:, None, :2] - src[:, None, :2])        # (n, 5, 2)
        temp = self.temperature_at_c(pts[..., 0].ravel(), pts[..., 1].ravel()).reshape(len(t), 5)
        c = np.mean(moist_speed_of_sound_m_s(temp, self.rh_pct, self.pressure_kpa), axis=1)
        d = rx - src
        norm = np.sqrt(np.vecdot(d, d))          # |d| as numpy.linalg.norm computes it (a dot product)
        far = norm >= 1e-9
        n_hat = d[:, :2] / np.where(far, norm, 1.0)[:, None]
        c = np.where(far, c + np.vecdot(self.wind_at(t), n_hat), c)
        return float(c[0]) if scalar else c

    def mean_c(self) -> float:
        """Speed of sound of the air away from equipment, without wind, m/s (moist; dry ideal gas when disabled,
        as the simulator had it before)."""
        if self._dry:
            return float(speed_of_sound_m_s(self.temperature_c))
        return float(moist_speed_of_sound_m_s(self.temperature_c, self.rh_pct, self.pressure_kpa))
