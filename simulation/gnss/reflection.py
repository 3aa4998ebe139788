"""Specular reflection of satellite signals off the vertical faces of the site's structures.

When a structure blocks the direct path, the receiver may still get the
signal reflected off another structure's face (NLOS). This module finds those
reflections and their loss from physics:

* **Geometry** (image method): a vertical face with outward normal n̂ at
  distance d in front of the receiver reflects a satellite in direction û
  (unit vector to the satellite) when û·n̂ > 0; the reflected ray reaches the
  receiver from û′ = û − 2(û·n̂)n̂, so the reflection point is
  R = p + (d/û·n̂)·û′, which must lie on the face (within its width and
  below its top), and both legs — receiver to R, R to the satellite — must be
  clear of solid structures. The extra path of the reflected signal over the
  direct one is Δ = 2·d·(û·n̂) = 2·d·cos θᵢ (the classic two-ray geometry;
  Groves 2013, *Principles of GNSS, Inertial, and Multisensor Integrated
  Navigation Systems*, 2nd ed., §10.4.2, for a vertical reflector).
* **Material** (:func:`relative_permittivity`): the complex relative
  permittivity η = a·f^b − j·17.98·c·f^d / f (f in GHz) with the material
  constants a, b, c, d of ITU-R P.2040-1 (2015), Table 3, eqs. (9a), (9b) and
  (28), (29): concrete, brick, plasterboard, wood, glass, metal, ground.
* **Fresnel coefficients** (:func:`fresnel_coefficients`) of a single smooth
  interface for the two linear polarisations, ITU-R P.2040-1 §2.2:
  Γ_TE = (cos θ − √(η − sin²θ)) / (cos θ + √(η − sin²θ)),
  Γ_TM = (η cos θ − √(η − sin²θ)) / (η cos θ + √(η − sin²θ)).
* **Circular polarisation** (:func:`circular_coefficients`): a right-hand
  (RHCP) satellite signal reflects into a co-polar (RHCP) part
  Γ_co = (Γ_TM + Γ_TE)/2 and a cross-polar (LHCP) part Γ_x = (Γ_TM − Γ_TE)/2
  (Hannah 2001, *Modelling and simulation of GPS multipath propagation*, PhD
  thesis, Queensland University of Technology, ch. 3): near normal incidence
  the handedness flips (a metal wall returns pure LHCP), near grazing it is
  kept. An RHCP antenna receives the LHCP part attenuated by its cross-polar
  rejection XPR, so the reflection's power relative to the direct signal is
  |Γ_co|² + |Γ_x|²·10^(−XPR/10) (:func:`reflection_loss_db`). Patch antennas
  reject LHCP by roughly 5–15 dB toward zenith and little toward the horizon,
  where their axial ratio grows (Kaplan & Hegarty 2017, *Understanding
  GPS/GNSS*, 3rd ed., ch. 9 on antenna polarisation and axial ratio; Groves
  2013 §10.4.2): XPR(el) = XPR_zenith·sin(el) (:func:`antenna_xpr_db`, a
  modelling choice of that shape); each receiver draws its own XPR_zenith.
* **Roughness** (:func:`specular_fraction`): a rough face scatters part of
  the power away from the specular direction; the coherent (specular) share
  of the reflected field is ρ_s = exp(−8·(π·σ_h·cos θᵢ/λ)²) (Rayleigh
  roughness criterion, Beckmann & Spizzichino 1963, *The Scattering of
  Electromagnetic Waves from Rough Surfaces*, ch. 5), σ_h the surface height
  deviation. The reflected signal fades as a Rician channel with
  K = ρ_s²/(1 − ρ_s²): specular, K > 0 (a smooth tank wall high, rough brick
  about 0 dB), and never above the line-of-sight K of the place.

Materials of ``site.toml`` map onto P.2040's table by name
(:data:`MATERIAL_ALIASES`: ``steel`` → metal); an unknown material is taken
as concrete, the commonest yard structure. Porous boxes (lattice gantries)
reflect no specular ray.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

from features.errors import ConfigError
from simulation.site.geometry import footprint_entry, segment_hits_boxes

__all__ = ["ITU_P2040_MATERIALS", "MATERIAL_ALIASES", "SURFACE_ROUGHNESS_M", "relative_permittivity",
           "fresnel_coefficients", "circular_coefficients", "reflection_loss_db", "specular_fraction",
           "material_key", "antenna_xpr_db", "Reflections", "specular_reflections"]

ITU_P2040_MATERIALS = MappingProxyType({
    "concrete": (5.24, 0.0, 0.0462, 0.7822),
    "brick": (3.91, 0.0, 0.0238, 0.16),
    "plasterboard": (2.73, 0.0, 0.0085, 0.9395),
    "wood": (1.99, 0.0, 0.0047, 1.0718),
    "glass": (6.31, 0.0, 0.0036, 1.3394),
    "metal": (1.0, 0.0, 1e7, 0.0),
    "very dry ground": (3.0, 0.0, 0.00015, 2.52),
    "medium dry ground": (15.0, -0.1, 0.035, 1.63),
    "wet ground": (30.0, -0.4, 0.15, 1.30),
})
"""ITU-R P.2040-1 (2015) Table 3: material constants (a, b, c, d) with η′ = a·f^b and σ = c·f^d S/m, f in GHz
(valid 1–100 GHz for concrete, metal; 1–10 GHz for brick and grounds)."""

MATERIAL_ALIASES = MappingProxyType({"steel": "metal", "iron": "metal", "aluminium": "metal",
                                     "aluminum": "metal", "steel lattice": "metal"})
"""Layout material names that P.2040's table lists under another name."""

SURFACE_ROUGHNESS_M = MappingProxyType({"metal": 0.01, "concrete": 0.01, "brick": 0.02, "glass": 0.001,
                                        "wood": 0.005, "plasterboard": 0.002})
"""RMS surface height deviation σ_h of a face, m — a modelling choice: a transformer tank is a smooth plate
but carries stiffeners and radiator fins (≈ 1 cm), cast concrete ≈ 1 cm, a brick wall with its joints ≈ 2 cm.
Materials not listed take 0.01 m."""


def material_key(material: str) -> str:
    """The P.2040 table key of a layout material (unknown → ``"concrete"``).

    >>> material_key("Steel"), material_key("brick"), material_key("basalt")
    ('metal', 'brick', 'concrete')
    """
    if not isinstance(material, str):
        raise ConfigError(f"material must be a string, got {material!r}")
    key = material.strip().lower()
    key = MATERIAL_ALIASES.get(key, key)
    return key if key in ITU_P2040_MATERIALS else "concrete"


def relative_permittivity(material: str, f_hz: float) -> complex:
    """Complex relative permittivity η = η′ − j·η″ of a material at ``f_hz`` (ITU-R P.2040-1 eqs. (9), (28), (29)).

    η′ = a·f^b, σ = c·f^d (S/m), η″ = 17.98·σ/f, f in GHz.

    >>> eta = relative_permittivity("concrete", 1.57542e9)
    >>> round(eta.real, 2), round(-eta.imag, 3)
    (5.24, 0.752)
    """
    a, b, c, d = ITU_P2040_MATERIALS[material_key(material)]
    f = f_hz / 1e9
    return complex(a * f ** b, -17.98 * c * f ** d / f)


def fresnel_coefficients(eta, cos_theta) -> tuple[np.ndarray, np.ndarray]:
    """Fresnel reflection coefficients (Γ_TE, Γ_TM) of a smooth interface (ITU-R P.2040-1 §2.2), same shape as
    ``cos_theta`` (cosine of the angle of incidence from the normal).

    >>> te, tm = fresnel_coefficients(4.0, 1.0)        # normal incidence, η = 4: ∓(√η − 1)/(√η + 1) = ∓1/3
    >>> round(float(te.real), 4), round(float(tm.real), 4)
    (-0.3333, 0.3333)
    """
    c = np.asarray(cos_theta, float).astype(complex)
    eta = np.asarray(eta, complex)
    root = np.sqrt(eta - (1.0 - c * c))
    return (c - root) / (c + root), (eta * c - root) / (eta * c + root)


def circular_coefficients(eta, cos_theta) -> tuple[np.ndarray, np.ndarray]:
    """Co- and cross-polar reflection coefficients of a circularly polarised wave, (Γ_co, Γ_x) (Hannah 2001).

    Γ_co = (Γ_TM + Γ_TE)/2 keeps the handedness, Γ_x = (Γ_TM − Γ_TE)/2 flips it.

    >>> co, x = circular_coefficients(complex(1.0, -1e9), 1.0)     # a conductor at normal incidence: all LHCP
    >>> round(abs(complex(co)), 4), round(abs(complex(x)), 4)
    (0.0, 1.0)
    """
    te, tm = fresnel_coefficients(eta, cos_theta)
    return 0.5 * (tm + te), 0.5 * (tm - te)


def reflection_loss_db(eta, cos_theta, xpr_db) -> np.ndarray:
    """Power of a single reflection received by an RHCP antenna, below the direct signal, dB (module docstring).

    L = −10·log10(|Γ_co|² + |Γ_x|²·10^(−XPR/10)).

    A conductor flips the handedness at every angle (the loss is the XPR); a dielectric near grazing keeps it:

    >>> [round(float(reflection_loss_db(complex(1.0, -1e9), c, 10.0)), 2) for c in (1.0, 0.05)]
    [10.0, 10.0]
    >>> round(float(reflection_loss_db(4.0, 0.05, 10.0)), 2)
    1.22
    """
    co, x = circular_coefficients(eta, cos_theta)
    p = np.abs(co) ** 2 + np.abs(x) ** 2 * 10.0 ** (-np.asarray(xpr_db, float) / 10.0)
    return -10.0 * np.log10(np.maximum(p, 1e-30))


def antenna_xpr_db(xpr_zenith_db, el_rad) -> np.ndarray:
    """Cross-polar rejection of an RHCP patch toward elevation ``el_rad``, dB: XPR_zenith·sin(el) (module docstring).

    >>> [round(float(antenna_xpr_db(12.0, np.radians(e))), 1) for e in (90.0, 30.0, 10.0)]
    [12.0, 6.0, 2.1]
    """
    return np.asarray(xpr_zenith_db, float) * np.sin(np.clip(np.asarray(el_rad, float), 0.0, np.pi / 2))


def specular_fraction(roughness_m, cos_theta, wavelength_m) -> np.ndarray:
    """Coherent share of the reflected field of a rough face, ρ_s = exp(−8·(π·σ_h·cos θ/λ)²) (Beckmann &
    Spizzichino 1963).

    >>> round(float(specular_fraction(0.01, 1.0, 0.19)), 3)
    0.804
    """
    g = np.pi * np.asarray(roughness_m, float) * np.asarray(cos_theta, float) / wavelength_m
    return np.exp(-8.0 * g * g)


class Reflections:
    """The strongest clear specular reflection of each (receiver, satellite) pair asked about; arrays of shape (P,).

    ``loss_db`` (inf where none), ``extra_m`` the extra path 2·d·cos θᵢ, ``k_lin`` its Rician K
    (ρ_s²/(1 − ρ_s²)), ``box`` the reflecting box (−1 where none).
    """

    __slots__ = ("loss_db", "extra_m", "k_lin", "box")

    def __init__(self, loss_db, extra_m, k_lin, box):
        self.loss_db, self.extra_m, self.k_lin, self.box = loss_db, extra_m, k_lin, box


def _faces(boxes: np.ndarray, reflective: np.ndarray):
    """The vertical faces of the reflective boxes: axis (F,), coordinate, outward sign, span lo/hi, top, box index."""
    idx = np.flatnonzero(reflective)
    b = boxes[idx]
    axis = np.repeat([[0, 0, 1, 1]], len(idx), axis=0).ravel()
    coord = np.column_stack([b[:, 1], b[:, 0], b[:, 3], b[:, 2]]).ravel()
    sign = np.repeat([[1.0, -1.0, 1.0, -1.0]], len(idx), axis=0).ravel()
    lo = np.column_stack([b[:, 2], b[:, 2], b[:, 0], b[:, 0]]).ravel()
    hi = np.column_stack([b[:, 3], b[:, 3], b[:, 1], b[:, 1]]).ravel()
    top = np.repeat(b[:, 4], 4)
    owner = np.repeat(idx, 4)
    return axis, coord, sign, lo, hi, top, owner


def specular_reflections(p_en: np.ndarray, z0_m: np.ndarray, az_rad: np.ndarray, el_rad: np.ndarray,
                         boxes: np.ndarray, porous: np.ndarray, eta: np.ndarray, roughness_m: np.ndarray,
                         xpr_db: float, wavelength_m: float, k_cap_lin: np.ndarray,
                         max_distance_m: float = 60.0, chunk: int = 2_000) -> Reflections:
    """Strongest clear specular reflection per pair (module docstring), all arrays of shape (P,) unless noted.

    Parameters
    ----------
    p_en : (P, 2) receiver east/north, m; z0_m : (P,) receiver height, m
    az_rad, el_rad : (P,) satellite direction
    boxes : (m, 5) :func:`simulation.site.geometry.boxes_array`; porous : (m,) bool (no specular face)
    eta : (m,) complex relative permittivity per box; roughness_m : (m,) σ_h per box
    xpr_db : the antenna's cross-polar rejection at zenith, dB (:func:`antenna_xpr_db` gives it per elevation)
    k_cap_lin : (P,) the largest K a reflection may have there (the line-of-sight K of the place)
    max_distance_m : faces farther than this from the receiver are not searched
    """
    n_p = len(az_rad)
    loss = np.full(n_p, np.inf)
    extra = np.zeros(n_p)
    k_out = np.zeros(n_p)
    box_out = np.full(n_p, -1, int)
    solid = ~np.asarray(porous, bool)
    if n_p == 0 or not solid.any():
        return Reflections(loss, extra, k_out, box_out)
    axis, coord, sign, lo, hi, top, owner = _faces(boxes, solid)
    solid_boxes = boxes[solid]
    solid_idx = np.flatnonzero(solid)
    other = 1 - axis
    for i0 in range(0, n_p, chunk):
        sl = slice(i0, min(n_p, i0 + chunk))
        p = np.asarray(p_en, float)[sl]
        z0 = np.asarray(z0_m, float)[sl]
        ce = np.cos(el_rad[sl])
        u = np.column_stack([ce * np.sin(az_rad[sl]), ce * np.cos(az_rad[sl]), np.sin(el_rad[sl])])
        # cos θᵢ = û·n̂ and the receiver's distance in front of the face, (P, F)
        cos_i = u[:, axis] * sign
        d = (p[:, axis] - coord) * sign
        ok = (cos_i > 1e-3) & (d > 1e-3) & (d < max_distance_m)
        s = np.where(ok, d / np.where(ok, cos_i, 1.0), 0.0)
        r_other = p[:, other] + s * u[:, other]
        r_z = z0[:, None] + s * u[:, 2:3]
        ok &= (r_other >= lo) & (r_other <= hi) & (r_z <= top)
        pi, fi = np.nonzero(ok)
        if pi.size == 0:
            continue
        s_c, ci = s[pi, fi], cos_i[pi, fi]
        rp = np.empty((pi.size, 3))
        rp[:, 2] = r_z[pi, fi]
        ax = axis[fi]
        rp[np.arange(pi.size), ax] = coord[fi]
        rp[np.arange(pi.size), 1 - ax] = r_other[pi, fi]
        a = np.column_stack([p[pi], z0[pi]])
        # Leg 1: receiver → reflection point; leg 2: reflection point → satellite (a ray up the sky).
        hit1 = segment_hits_boxes(a, rp, solid_boxes)
        az_c = np.arctan2(u[pi, 0], u[pi, 1])
        t_in, _ = footprint_entry(rp[:, :2], az_c[:, None], solid_boxes)
        t_in = t_in[:, 0, :]
        tan_el = u[pi, 2] / np.maximum(np.hypot(u[pi, 0], u[pi, 1]), 1e-9)
        hit2 = np.isfinite(t_in) & (solid_boxes[:, 4][None, :] > rp[:, 2:3] + t_in * tan_el[:, None])
        own = solid_idx[None, :] == owner[fi][:, None]
        clear = ~((hit1 | hit2) & ~own).any(axis=1)
        if not clear.any():
            continue
        pi, fi, s_c, ci = pi[clear], fi[clear], s_c[clear], ci[clear]
        j = owner[fi]
        l_db = reflection_loss_db(eta[j], ci, antenna_xpr_db(xpr_db, el_rad[sl][pi]))
        # Keep the strongest clear reflection of each pair: sort by (pair, loss), first of each pair.
        order = np.lexsort((l_db, pi))
        first = order[np.r_[True, pi[order][1:] != pi[order][:-1]]]
        gp = i0 + pi[first]
        loss[gp] = l_db[first]
        extra[gp] = 2.0 * d[pi[first], fi[first]] * ci[first]
        rho = specular_fraction(roughness_m[j[first]], ci[first], wavelength_m)
        k_out[gp] = np.minimum(rho ** 2 / np.maximum(1.0 - rho ** 2, 1e-6), np.asarray(k_cap_lin)[gp])
        box_out[gp] = j[first]
    return Reflections(loss, extra, k_out, box_out)
