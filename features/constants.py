"""Physical and geodetic constants, each with unit and source.

Module-level names are plain floats: immutable, never a registry to be altered.
"""

__all__ = [
    "SPEED_OF_LIGHT_M_S", "WGS84_A_M", "WGS84_F", "WGS84_E2", "GM_EARTH_M3_S2",
    "OMEGA_EARTH_RAD_S", "SIDEREAL_DAY_S", "GEO_RADIUS_M", "GRAVITY_M_S2",
    "GPS_L1_HZ", "BDS_B1C_HZ", "BOLTZMANN_DBW_HZ_K", "ELEVATION_MASK_DEG",
    "AUDIO_FS_HZ", "SPEED_OF_SOUND_0C_M_S",
]

SPEED_OF_LIGHT_M_S = 299_792_458.0
"""Speed of light in vacuum, m/s (SI definition; IS-GPS-200 §20.3.4.3)."""

WGS84_A_M = 6_378_137.0
"""WGS-84 semi-major axis, m (NIMA TR8350.2, Table 3.1)."""

WGS84_F = 1.0 / 298.257223563
"""WGS-84 flattening (NIMA TR8350.2, Table 3.1)."""

WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""WGS-84 first eccentricity squared."""

GM_EARTH_M3_S2 = 3.986004418e14
"""Earth's gravitational parameter, m³/s² (WGS-84; BDS-SIS-ICD uses 3.986004418e14 too)."""

OMEGA_EARTH_RAD_S = 7.2921151467e-5
"""Earth rotation rate, rad/s (IS-GPS-200 §20.3.3.4.3; CGCS2000 value 7.2921150e-5 differs by 2e-12)."""

SIDEREAL_DAY_S = 86_164.0905
"""Mean sidereal day, s (IERS Conventions 2010)."""

GEO_RADIUS_M = (GM_EARTH_M3_S2 * (SIDEREAL_DAY_S / (2.0 * 3.141592653589793)) ** 2) ** (1.0 / 3.0)
"""Geostationary orbit radius from Kepler's third law, a = (GM·T²/4π²)^(1/3) ≈ 42 164 km."""

GRAVITY_M_S2 = 9.80665
"""Standard gravity, m/s² (CGPM 1901)."""

GPS_L1_HZ = 1_575.42e6
"""GPS L1 C/A carrier, Hz (IS-GPS-200)."""

BDS_B1C_HZ = 1_575.42e6
"""BeiDou-3 B1C carrier, Hz (BDS-SIS-ICD-B1C-1.0)."""

BOLTZMANN_DBW_HZ_K = -228.6
"""Boltzmann's constant, dBW/(Hz·K)."""

ELEVATION_MASK_DEG = 10.0
"""Default elevation mask for features and environment truth, degrees (docs/design.md §5)."""

AUDIO_FS_HZ = 48_000
"""Sample rate of envfuse audio, Hz (docs/design.md §4)."""

SPEED_OF_SOUND_0C_M_S = 331.3
"""Speed of sound in dry air at 0 °C, m/s; c(T) = 331.3·sqrt(1 + T/273.15) (Cramer 1993, ideal-gas form)."""
