"""UWB radio constants and formulas: link budget, materials, penetration, diffraction, DW3000 receiver.

Channel 5 of IEEE 802.15.4z HRP UWB (the DW3000's default), 6489.6 MHz, 499.2 MHz wide.
Each function is one formula with its source; the numbers are module constants with unit and source.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CENTRE_HZ", "WAVELENGTH_M", "C_M_S", "TX_POWER_DBM", "SENSITIVITY_DBM", "ANCHOR_GAIN_DBI", "FIRST_PATH_FLOOR_DBM",
           "FIRST_PATH_DYNAMIC_DB", "Material", "MATERIALS",
           "material", "free_space_loss_db", "knife_edge_loss_db", "slab_attenuation_db_per_m",
           "slab_excess_path_m", "interface_loss_db", "slab_loss_db", "reflection_loss_db", "BUILDING_WALL_M",
           "LATTICE_LOSS_DB", "GROUND_REFLECTION_LOSS_DB", "BACK_LOBE_LOSS_DB"]

C_M_S = 299_792_458.0
"""Speed of light in vacuum, m/s."""

CENTRE_HZ = 6_489.6e6
"""Centre frequency of UWB channel 5, Hz (IEEE Std 802.15.4z-2020, Table 15-10; DW3000 datasheet §1)."""

WAVELENGTH_M = C_M_S / CENTRE_HZ
"""Wavelength at :data:`CENTRE_HZ`, m (≈ 4.6 cm)."""

TX_POWER_DBM = -14.3
"""Total transmitted power, dBm: the −41.3 dBm/MHz mean-EIRP limit (FCC §15.519, ETSI EN 302 065) over
499.2 MHz (+27.0 dB), 0 dBi antennas."""

SENSITIVITY_DBM = -94.0
"""Receiver sensitivity, dBm: DW3000 datasheet (Qorvo DW3000 Data Sheet v1.1, receiver characteristics:
≈ −94 dBm at 6.8 Mb/s, 64 MHz PRF, 1 % PER, channel 5). A packet whose strongest path is weaker is lost."""

ANCHOR_GAIN_DBI = 3.0
"""Gain of an anchor's PDoA patch antennas towards its front, dBi (patch elements, 3–6 dBi; the tag's
chip antenna ≈ 0 dBi)."""

FIRST_PATH_FLOOR_DBM = SENSITIVITY_DBM - 3.0
"""Weakest first path the leading-edge search finds, dBm: the accumulator integrates the whole preamble, so
a path a little under the packet's decoding threshold still stands out of the CIR's noise."""

FIRST_PATH_DYNAMIC_DB = 20.0
"""The leading-edge detector finds a path at most this far below the CIR's peak, dB: its threshold is a
fraction of the peak as well as a multiple of the noise (DW1000 User Manual v2.17 §4.7.1, LDE_CFG1
``NTM`` / ``PMULT``; the same design in the DW3000)."""

BUILDING_WALL_M = 0.24
"""Thickness of a building's exterior wall, m (a one-brick / 24 cm cast wall, GB 50003 masonry module):
a building box is hollow to a radio path, which crosses two of its walls."""

LATTICE_LOSS_DB = 2.0
"""Loss of a path through one lattice gantry, dB: steel members shadow 15–30 % of its face, spaced many
wavelengths apart (λ ≈ 4.6 cm), so most of the wavefront passes (the acoustic model's 1.5 dB, same geometry)."""

GROUND_REFLECTION_LOSS_DB = 6.0
"""Loss of the ground bounce off the yard's crushed rock, dB (|Γ| ≈ 0.5 at grazing incidence for a rough
dry ground, ITU-R P.527 / P.2040 ground types)."""

BACK_LOBE_LOSS_DB = 10.0
"""Gain of an anchor's patch antenna pair behind its array re. its front, −dB (front-to-back ratio of a
patch antenna, ≈ 10 dB; Balanis, Antenna Theory, 4th ed., §14.2)."""


@dataclass(frozen=True)
class Material:
    """ITU-R P.2040-1 Table 3 building material: ε' = a·f^b, σ = c·f^d (f in GHz, σ in S/m)."""

    name: str
    a: float
    b: float
    c: float
    d: float
    metal: bool = False

    def permittivity(self, f_hz: float = CENTRE_HZ) -> float:
        """Relative permittivity ε' at ``f_hz`` (ITU-R P.2040-1 eq. 28)."""
        return self.a * (f_hz / 1e9) ** self.b

    def conductivity_s_m(self, f_hz: float = CENTRE_HZ) -> float:
        """Conductivity σ at ``f_hz``, S/m (ITU-R P.2040-1 eq. 29)."""
        return self.c * (f_hz / 1e9) ** self.d


MATERIALS = {
    "concrete": Material("concrete", 5.24, 0.0, 0.0462, 0.7822),
    "brick": Material("brick", 3.91, 0.0, 0.0238, 0.16),
    "plasterboard": Material("plasterboard", 2.73, 0.0, 0.0085, 0.9395),
    "wood": Material("wood", 1.99, 0.0, 0.0047, 1.0718),
    "glass": Material("glass", 6.31, 0.0, 0.0036, 1.3394),
    "steel": Material("steel", 1.0, 0.0, 1e7, 0.0, metal=True),
}
"""Materials of ITU-R P.2040-1 (2015) Table 3 (valid 1–10 GHz; metal: no transmission)."""


def material(name: str) -> Material:
    """The :data:`MATERIALS` entry for a site's material name (``"steel lattice"`` → steel; unknown → concrete,
    the most common yard material and the more obstructive of the masonry ones)."""
    key = name.strip().lower()
    if key in MATERIALS:
        return MATERIALS[key]
    if "steel" in key or "metal" in key or "iron" in key or "alumin" in key:
        return MATERIALS["steel"]
    return MATERIALS["concrete"]


def free_space_loss_db(distance_m, f_hz: float = CENTRE_HZ):
    """Friis free-space path loss, dB: 20·log10(4πd/λ) (Friis 1946; ITU-R P.525-4 eq. 4)."""
    d = np.maximum(np.asarray(distance_m, float), 0.05)
    return 20.0 * np.log10(4.0 * math.pi * d * f_hz / C_M_S)


def knife_edge_loss_db(detour_m, f_hz: float = CENTRE_HZ):
    """Single knife-edge diffraction loss, dB, from the path's detour δ (ITU-R P.526-15 eq. 31):
    J(ν) = 6.9 + 20·log10(√((ν − 0.1)² + 1) + ν − 0.1) for ν > −0.78, with ν = 2·√(δ/λ) (eq. 26–27: ν² = 2h²(d1 +
    d2)/(λd1d2) and δ ≈ h²(d1 + d2)/(2d1d2)). Several edges are taken as one screen of the total detour, as
    the acoustic channel does.

    >>> round(float(knife_edge_loss_db(0.0)), 2)      # grazing: the edge halves the field
    6.03
    """
    nu = 2.0 * np.sqrt(np.maximum(np.asarray(detour_m, float), 0.0) * f_hz / C_M_S)
    return 6.9 + 20.0 * np.log10(np.sqrt((nu - 0.1) ** 2 + 1.0) + nu - 0.1)


def slab_attenuation_db_per_m(mat: Material, f_hz: float = CENTRE_HZ) -> float:
    """Attenuation inside a lossy dielectric, dB/m (ITU-R P.2040-1 eq. 26–27):
    α = ω·√(μ0ε0ε'/2)·√(√(1 + (σ/(ωε0ε'))²) − 1) Np/m, × 8.686 dB/Np. Infinite for metal."""
    if mat.metal:
        return math.inf
    eps0 = 8.854187817e-12
    w = 2.0 * math.pi * f_hz
    er = mat.permittivity(f_hz)
    tan_d = mat.conductivity_s_m(f_hz) / (w * eps0 * er)
    alpha = w / C_M_S * math.sqrt(er / 2.0) * math.sqrt(math.sqrt(1.0 + tan_d ** 2) - 1.0)
    return 8.686 * alpha


def slab_excess_path_m(mat: Material, thickness_m, f_hz: float = CENTRE_HZ):
    """Extra electrical length of a path crossing ``thickness_m`` of a material, m: t·(√ε' − 1) (the wave
    travels at c/√ε' inside; low-loss phase velocity, ITU-R P.2040-1 §2). Infinite for metal."""
    if mat.metal:
        return np.full_like(np.asarray(thickness_m, float), math.inf)
    return np.asarray(thickness_m, float) * (math.sqrt(mat.permittivity(f_hz)) - 1.0)


def interface_loss_db(mat: Material, f_hz: float = CENTRE_HZ) -> float:
    """Transmission loss of one air–material interface at normal incidence, dB: −10·log10(1 − Γ²),
    Γ = (1 − √ε')/(1 + √ε') (Fresnel)."""
    if mat.metal:
        return math.inf
    n = math.sqrt(mat.permittivity(f_hz))
    gamma = (1.0 - n) / (1.0 + n)
    return -10.0 * math.log10(1.0 - gamma ** 2)


def slab_loss_db(mat: Material, thickness_m, f_hz: float = CENTRE_HZ):
    """Penetration loss of a slab, dB: attenuation × thickness plus two interfaces."""
    t = np.asarray(thickness_m, float)
    if mat.metal:
        return np.full_like(t, math.inf)
    return slab_attenuation_db_per_m(mat, f_hz) * t + 2.0 * interface_loss_db(mat, f_hz)


def reflection_loss_db(mat: Material, f_hz: float = CENTRE_HZ) -> float:
    """Specular reflection loss off a thick wall at normal incidence, dB: −20·log10|Γ| (Fresnel; metal 0 dB)."""
    if mat.metal:
        return 0.0
    n = math.sqrt(mat.permittivity(f_hz))
    return -20.0 * math.log10(abs((1.0 - n) / (1.0 + n)))
