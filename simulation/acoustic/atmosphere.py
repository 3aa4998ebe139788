"""Outdoor sound propagation formulas for the beacon channel (one function per formula).

* speed of sound in air from temperature (ideal gas);
* spherical spreading;
* atmospheric absorption, ISO 9613-1:1993 §6 (eqs. 3–5, relaxation of O₂/N₂);
* barrier (edge) diffraction, Maekawa (1968) via the Fresnel number;
* pressure reflection coefficients of the yard's surfaces.

All frequencies in Hz, lengths in metres, levels in dB. The functions are
vectorised over numpy arrays.
"""

from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np

from features.constants import SPEED_OF_SOUND_0C_M_S
from features.errors import ConfigError
from features.site import Atmosphere

__all__ = [
    "speed_of_sound_m_s", "spreading_gain", "absorption_db_per_m", "fresnel_number", "maekawa_loss_db",
    "reflection_coefficient", "ABSORPTION_COEFFICIENTS", "PRESSURE_REF_PA", "GROUND_MATERIAL",
]

PRESSURE_REF_PA = 20e-6
"""Reference sound pressure for dB SPL, Pa (IEC 61672-1)."""

_T0_K = 293.15
"""ISO 9613-1 reference air temperature, K (20 °C)."""

_T01_K = 273.16
"""ISO 9613-1 triple-point isotherm temperature, K (eq. B.3)."""

_PR_KPA = 101.325
"""ISO 9613-1 reference ambient pressure, kPa."""

ABSORPTION_COEFFICIENTS = MappingProxyType({
    "concrete": 0.05,
    "steel": 0.05,
    "brick": 0.07,
    "glass": 0.03,
    "asphalt": 0.10,
    "grass": 0.60,
    "gravel": 0.50,
})
"""Random-incidence absorption coefficient α of the yard's materials in the 4 kHz octave
(the highest octave usually tabulated; used over 17–23 kHz as well), dimensionless.

Values from the usual design tables (Vorländer, *Auralization*, 2008, App. A;
Kuttruff, *Room Acoustics*, 5th ed., Table 6.1): unpainted concrete 0.02–0.07,
sheet steel on a frame 0.02–0.1, brick 0.07, glass 0.02–0.04; crushed-rock
surfacing of a substation yard (IEEE Std 80 surface layer, 0.1–0.15 m of
porous gravel) 0.4–0.7 at 2–4 kHz. Read-only mapping.
"""

GROUND_MATERIAL = "gravel"
"""Ground surface of a substation yard: crushed rock (IEEE Std 80 §12.5 surface layer)."""

_DEFAULT_ABSORPTION = 0.10
"""α assumed for a material the table does not know (a typical hard, slightly rough surface)."""


def speed_of_sound_m_s(temperature_c: float | np.ndarray) -> float | np.ndarray:
    """Speed of sound in air, c = 331.3·sqrt(1 + T/273.15) m/s (ideal gas; Cramer 1993, JASA 93(5)).

    >>> round(speed_of_sound_m_s(20.0), 2)
    343.21
    """
    c = SPEED_OF_SOUND_0C_M_S * np.sqrt(1.0 + np.asarray(temperature_c, float) / 273.15)
    return c if c.ndim else float(c)


def spreading_gain(distance_m: float | np.ndarray) -> float | np.ndarray:
    """Pressure gain of spherical spreading re. 1 m, p(r)/p(1 m) = 1/r (point source in free field).

    >>> spreading_gain(10.0)
    0.1
    """
    g = 1.0 / np.maximum(np.asarray(distance_m, float), 1e-3)
    return g if g.ndim else float(g)


def absorption_db_per_m(frequency_hz: float | np.ndarray, atmosphere: Atmosphere) -> np.ndarray:
    """Pure-tone atmospheric absorption coefficient α, dB/m, ISO 9613-1:1993 §6.

    Molar concentration of water vapour (Annex B, eqs. B.1–B.3)::

        C = −6.8346·(T01/T)^1.261 + 4.6151,  p_sat/p_r = 10^C,  h = h_r·(p_sat/p_r)/(p_a/p_r)  [%]

    relaxation frequencies of oxygen and nitrogen (eqs. 3 and 4)::

        f_rO = (p_a/p_r)·(24 + 4.04e4·h·(0.02 + h)/(0.391 + h))
        f_rN = (p_a/p_r)·(T/T0)^(−1/2)·(9 + 280·h·exp(−4.170·((T/T0)^(−1/3) − 1)))

    and the coefficient (eq. 5)::

        α = 8.686·f²·[1.84e−11·(p_a/p_r)^(−1)·(T/T0)^(1/2)
                      + (T/T0)^(−5/2)·(0.01275·exp(−2239.1/T)/(f_rO + f²/f_rO)
                                       + 0.1068·exp(−3352.0/T)/(f_rN + f²/f_rN))]

    with T0 = 293.15 K, T01 = 273.16 K, p_r = 101.325 kPa.

    Parameters
    ----------
    frequency_hz : float or ndarray of any shape
    atmosphere : temperature, relative humidity and pressure

    Returns
    -------
    ndarray of the shape of ``frequency_hz``, dB/m.

    >>> from features.site import Atmosphere
    >>> round(float(absorption_db_per_m(1000 * 10**0.6, Atmosphere(20, 70, 101.325)) * 1000), 1)  # dB/km, 4 kHz
    22.9
    """
    f = np.asarray(frequency_hz, float)
    t_k = atmosphere.temperature_c + 273.15
    pa = atmosphere.pressure_kpa / _PR_KPA
    c_exp = -6.8346 * (_T01_K / t_k) ** 1.261 + 4.6151                       # eq. B.3
    h = atmosphere.relative_humidity_pct * 10.0 ** c_exp / pa                # eq. B.1, %
    tr = t_k / _T0_K
    fr_o = pa * (24.0 + 4.04e4 * h * (0.02 + h) / (0.391 + h))               # eq. 3
    fr_n = pa * tr ** -0.5 * (9.0 + 280.0 * h * math.exp(-4.170 * (tr ** (-1.0 / 3.0) - 1.0)))  # eq. 4
    f2 = f * f
    return 8.686 * f2 * (1.84e-11 / pa * tr ** 0.5                          # eq. 5
                         + tr ** -2.5 * (0.01275 * math.exp(-2239.1 / t_k) / (fr_o + f2 / fr_o)
                                         + 0.1068 * math.exp(-3352.0 / t_k) / (fr_n + f2 / fr_n)))


def fresnel_number(path_difference_m: float | np.ndarray, frequency_hz: float | np.ndarray,
                   speed_m_s: float) -> np.ndarray:
    """Fresnel number N = 2δ/λ = 2δf/c of a diffracted path with detour δ (Maekawa 1968).

    >>> float(fresnel_number(0.5, 343.0, 343.0))
    1.0
    """
    return 2.0 * np.asarray(path_difference_m, float) * np.asarray(frequency_hz, float) / speed_m_s


def maekawa_loss_db(fresnel_n: float | np.ndarray) -> np.ndarray:
    """Barrier insertion loss ΔL = 10·log10(3 + 20N) dB for N ≥ 0 (Maekawa 1968, Appl. Acoust. 1(3),
    in the closed form of ISO 9613-2:1996 eq. 14 with C2 = 20, C3 = 1).

    Defined for the shadow zone (N ≥ 0; N = 0 is the grazing path, 4.8 dB).
    Maekawa's lit-zone branch (loss falling to 0 by N ≈ −0.3) is left out: at
    20 kHz it spans under 3 mm of path difference, so a walker crosses it
    within one step. No
    upper cap: the 20–25 dB limit of ISO 9613-2 stands for turbulent scattering
    over long outdoor ranges, not for the 10–100 m paths of a yard, and the
    diffuse tail of the channel already carries the scattered energy.

    >>> [round(float(maekawa_loss_db(n)), 2) for n in (0.0, 1.0, 10.0)]
    [4.77, 13.62, 23.07]
    """
    n = np.asarray(fresnel_n, float)
    return 10.0 * np.log10(3.0 + 20.0 * np.maximum(n, 0.0))


def reflection_coefficient(material: str) -> float:
    """Magnitude of the plane-wave pressure reflection coefficient, |R| = sqrt(1 − α).

    Energy balance of a locally reacting surface (Kuttruff, *Room Acoustics*,
    §2.1: α = 1 − |R|²), taken real and positive (hard surfaces reflect in
    phase) and frequency- and angle-independent over the narrow 17–23 kHz band.
    A material the table does not list gets α = 0.10.

    >>> round(reflection_coefficient("concrete"), 4), round(reflection_coefficient("gravel"), 4)
    (0.9747, 0.7071)
    """
    if not isinstance(material, str):
        raise ConfigError(f"material must be a string, got {material!r}")
    alpha = ABSORPTION_COEFFICIENTS.get(material.strip().lower(), _DEFAULT_ABSORPTION)
    return math.sqrt(1.0 - alpha)
