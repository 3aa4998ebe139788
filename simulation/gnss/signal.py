"""GNSS signal model: open-sky C/N0, blockage by the site's boxes, fading, C/N0 estimation, tracking.

Per epoch and satellite (arrays of shape (n_epochs, k)):

1. **Open-sky C/N0** (:func:`open_sky_cn0_dbhz`): a link budget in which the
   received power falls toward the horizon through the longer path (free-space
   loss 20·log10(r(el)/r(90°)), r from the orbit radius) and the receive
   antenna's gain roll-off (a patch antenna loses roughly 8–10 dB from zenith to
   5°; Kaplan & Hegarty 2017, *Understanding GPS/GNSS*, 3rd ed., §§ on the
   link budget and antenna patterns). Calibrated to ≈ 38 dB-Hz at 5° and
   ≈ 50 dB-Hz at zenith (docs/design.md §6), plus a per-satellite offset (transmit
   power and antenna differences between satellites).
2. **Blockage** (:func:`blockage`): rays from the receiver toward each satellite
   are tested against the layout boxes with :func:`simulation.site.geometry.ray_blockers`.
   A solid box in the way makes the direct path unavailable: the signal arrives
   diffracted over the roof edge, with the knife-edge loss J(ν) of
   ITU-R P.526-15 eq. (31); or specularly reflected off another structure's
   face (NLOS), found by the image method with the loss of the face's material
   (ITU-R P.2040-1 permittivities, Fresnel coefficients) and of the antenna's
   cross-polar rejection, and the extra path 2·d·cos θᵢ of the geometry
   (:mod:`simulation.gnss.reflection`); or diffusely scattered (NLOS) with a
   loss of 15–30 dB drawn once per (satellite, blocking box) so it is stable in
   time — sized so that, with the tracking threshold below, the NLOS C/N0 of the
   smartLoc u-blox log is reproduced (its NLOS pile up at 21–24 dB-Hz, a third
   of them: diffuse signals at the tracking limit). The receiver gets the
   strongest: loss = min(J(ν), L_spec, L_diffuse), and the path is NLOS
   (biased pseudorange) when a reflection dominates. Rays that
   pass just above a roof edge (−0.78 < ν < 0) lose up to 6 dB, so the shadow
   edge is not a hard cut. Porous boxes (lattice gantries) add 5–10 dB each.
3. **EMI zones** (:func:`emi_loss_db`): a raised-cosine loss profile around
   each zone's centre lowers every satellite's C/N0 (a modelling choice; the
   site file gives the peak loss and radius).
4. **Fading** (:func:`rician_power`): a Rician channel whose diffuse part is a
   sum-of-sinusoids Clarke/Jakes process (Clarke 1968; Pätzold 2011, *Mobile
   Radio Channels*, §4.1) driven by the distance the walker has moved, so
   decorrelation follows the Doppler spread f_d = v/λ; a small Doppler floor
   stands for satellite motion and moving scatterers. K ≈ 10 dB for LOS in the
   open, lower near clutter; a specular reflection's K from its face's
   roughness (:func:`simulation.gnss.reflection.specular_fraction`, capped at
   the place's LOS K), 0 (Rayleigh) for diffuse scattering.
5. **C/N0 estimator and tracking** (:func:`estimate_cn0`, :func:`track`):
   the receiver averages power over each 200 ms epoch and smooths it with a
   ≈ 1 s first-order filter, adds estimator noise that grows at low C/N0, and
   reports integer dB-Hz. A satellite is lost below ≈ 20 dB-Hz and reacquired
   only above ≈ 23 dB-Hz held for a short delay (hysteresis), plus a
   per-receiver offset of 0–3 dB. u-blox receivers hold far weaker signals
   (tracking sensitivity −167 dBm, ≈ 7 dB-Hz, on the M8 data sheet), but their
   logs report nothing below ≈ 20 dB-Hz: the smartLoc u-blox sample's lowest
   C/N0 is 21 dB-Hz. NLOS signals that clear the threshold are tracked and
   used like any other: the receiver cannot tell them apart.

Calibration against docs/design.md §6 "Real figures" is reported by
``bench/bench_gnss_sim.py`` and checked by ``tests/test_gnss_sim.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from features.constants import GPS_L1_HZ, SPEED_OF_LIGHT_M_S, WGS84_A_M
from features.errors import ConfigError
from simulation.gnss.reflection import specular_reflections
from simulation.site.geometry import ray_blockers

__all__ = [
    "SignalConfig", "Blockage", "Reflectors", "open_sky_cn0_dbhz", "knife_edge_loss_db", "fresnel_nu",
    "blockage", "emi_loss_db", "clutter_index", "rician_power", "estimate_cn0", "track", "body_loss_db",
    "receiver_draws",
]

WAVELENGTH_M = SPEED_OF_LIGHT_M_S / GPS_L1_HZ
"""L1 / B1 carrier wavelength, m (≈ 0.19 m)."""

_GPS_RADIUS_M = 26_559_700.0


@dataclass(frozen=True)
class SignalConfig:
    """Parameters of the signal model (defaults per docs/design.md §6).

    Attributes are in dB, dB-Hz, metres, seconds and hertz as named.
    """

    cn0_zenith_dbhz: float = 50.0
    cn0_low_dbhz: float = 38.0
    low_el_deg: float = 5.0
    sat_offset_sigma_db: float = 1.0
    nlos_loss_min_db: float = 15.0
    nlos_loss_max_db: float = 30.0
    porous_loss_min_db: float = 5.0
    porous_loss_max_db: float = 10.0
    nlos_excess_mean_m: float = 3.0
    nlos_extra_max_m: float = 60.0
    wavelength_m: float = WAVELENGTH_M
    k_open_db: float = 10.0
    k_clutter_drop_db: float = 6.0
    clutter_scale_m: float = 5.0
    doppler_floor_hz: float = 0.05
    n_sinusoids: int = 12
    estimator_tau_s: float = 1.0
    estimator_noise_db: float = 0.4
    track_lose_dbhz: float = 20.0
    track_acquire_dbhz: float = 23.0
    reacquire_delay_s: float = 1.0
    in_view_mask_deg: float = 0.0
    rx_offset_min_db: float = -5.0
    rx_offset_max_db: float = 0.0
    rx_threshold_max_db: float = 3.0
    xpr_min_db: float = 5.0
    xpr_max_db: float = 15.0
    body_loss_db: float = 10.0
    body_el_deg: float = 40.0
    body_half_width_deg: float = 90.0

    def __post_init__(self):
        for name, value in vars(self).items():
            if not np.isfinite(value):
                raise ConfigError(f"SignalConfig.{name} must be finite, got {value!r}")
        if not self.cn0_low_dbhz < self.cn0_zenith_dbhz:
            raise ConfigError(f"SignalConfig needs cn0_low_dbhz < cn0_zenith_dbhz, got {self.cn0_low_dbhz}, "
                             f"{self.cn0_zenith_dbhz}")
        if not 0.0 < self.low_el_deg < 90.0:
            raise ConfigError(f"SignalConfig.low_el_deg must lie in (0, 90), got {self.low_el_deg}")
        if not 0 <= self.nlos_loss_min_db <= self.nlos_loss_max_db:
            raise ConfigError("SignalConfig needs 0 <= nlos_loss_min_db <= nlos_loss_max_db")
        if not 0 <= self.porous_loss_min_db <= self.porous_loss_max_db:
            raise ConfigError("SignalConfig needs 0 <= porous_loss_min_db <= porous_loss_max_db")
        if self.track_acquire_dbhz < self.track_lose_dbhz:
            raise ConfigError(f"SignalConfig.track_acquire_dbhz ({self.track_acquire_dbhz}) must be >= "
                             f"track_lose_dbhz ({self.track_lose_dbhz})")
        if not 0.0 <= self.xpr_min_db <= self.xpr_max_db:
            raise ConfigError(f"SignalConfig needs 0 <= xpr_min_db <= xpr_max_db, got {self.xpr_min_db}, "
                              f"{self.xpr_max_db}")
        if not self.rx_offset_min_db <= self.rx_offset_max_db or self.rx_threshold_max_db < 0:
            raise ConfigError("SignalConfig needs rx_offset_min_db <= rx_offset_max_db and rx_threshold_max_db >= 0")
        if self.body_loss_db < 0 or not 0 < self.body_el_deg <= 90 or not 0 < self.body_half_width_deg <= 180:
            raise ConfigError("SignalConfig needs body_loss_db >= 0, body_el_deg in (0, 90], "
                              "body_half_width_deg in (0, 180]")
        if self.n_sinusoids < 4 or self.estimator_tau_s <= 0 or self.wavelength_m <= 0:
            raise ConfigError("SignalConfig needs n_sinusoids >= 4, estimator_tau_s > 0, wavelength_m > 0")


def _slant_range_m(el_rad, orbit_radius_m) -> np.ndarray:
    """Receiver–satellite distance on a spherical Earth: r = sqrt(a² − R²cos²el) − R·sin el."""
    r_e = WGS84_A_M
    return np.sqrt(orbit_radius_m ** 2 - (r_e * np.cos(el_rad)) ** 2) - r_e * np.sin(el_rad)


def _range_loss_db(el_rad, orbit_radius_m) -> np.ndarray:
    """Extra free-space loss relative to zenith, 20·log10(r(el)/r(90°)), dB."""
    return 20.0 * np.log10(_slant_range_m(el_rad, orbit_radius_m) / (orbit_radius_m - WGS84_A_M))


def open_sky_cn0_dbhz(el_rad, orbit_radius_m=_GPS_RADIUS_M, cfg: SignalConfig = SignalConfig()) -> np.ndarray:
    """Open-sky C/N0 of a satellite at elevation ``el_rad``, dB-Hz (same shape as ``el_rad``).

    C/N0(el) = C_zenith − 20·log10(r(el)/r(90°)) − A·(1 − sin el)², with the
    antenna roll-off A chosen so that a GPS-height satellite gives
    ``cn0_low_dbhz`` at ``low_el_deg``. Below 0° the value at 0° is kept.

    >>> c = open_sky_cn0_dbhz(np.radians([5.0, 30.0, 90.0]))
    >>> [round(float(x), 1) for x in c]
    [38.0, 45.9, 50.0]
    """
    el = np.clip(np.asarray(el_rad, float), 0.0, np.pi / 2)
    low = np.radians(cfg.low_el_deg)
    roll_a = ((cfg.cn0_zenith_dbhz - cfg.cn0_low_dbhz - _range_loss_db(low, _GPS_RADIUS_M))
              / (1.0 - np.sin(low)) ** 2)
    return cfg.cn0_zenith_dbhz - _range_loss_db(el, orbit_radius_m) - roll_a * (1.0 - np.sin(el)) ** 2


def fresnel_nu(clearance_m, distance_m, wavelength_m: float = WAVELENGTH_M) -> np.ndarray:
    """Fresnel–Kirchhoff diffraction parameter ν = h·sqrt(2/(λ·d)) (ITU-R P.526-15 eq. (26), d2 → ∞).

    ``clearance_m`` h is the edge's height above the direct ray, measured
    perpendicular to it (positive = obstructed); ``distance_m`` d the distance
    from the receiver to the edge along the ray.

    >>> round(float(fresnel_nu(1.0, 10.0, 0.2)), 3)
    1.0
    """
    d = np.maximum(np.asarray(distance_m, float), 1e-3)
    return np.asarray(clearance_m, float) * np.sqrt(2.0 / (wavelength_m * d))


def knife_edge_loss_db(nu) -> np.ndarray:
    """Single knife-edge diffraction loss J(ν), dB (ITU-R P.526-15 eq. (31)); 0 for ν ≤ −0.78.

    J(ν) = 6.9 + 20·log10(sqrt((ν − 0.1)² + 1) + ν − 0.1).

    >>> [round(float(knife_edge_loss_db(v)), 2) for v in (-1.0, 0.0, 1.0, 3.0)]
    [0.0, 6.03, 13.93, 22.42]
    """
    v = np.asarray(nu, float)
    with np.errstate(invalid="ignore", over="ignore"):
        x = np.where(np.isfinite(v), v, 0.0)
        j = 6.9 + 20.0 * np.log10(np.sqrt((x - 0.1) ** 2 + 1.0) + x - 0.1)
    j = np.where(v > -0.78, j, 0.0)
    return np.where(np.isposinf(v), np.inf, j)


@dataclass(frozen=True, eq=False)
class Blockage:
    """Outcome of the ray–box tests; arrays of shape (n_epochs, k).

    loss_db : total propagation loss below open sky (diffraction or reflection, porous), dB
    nlos : the received signal is a reflection (pseudorange biased)
    solid_blocked : a solid box stands in the direct path
    nlos_extra_m : extra path length of the reflected signal, m (0 where not NLOS)
    diffraction_db : J(ν) of the dominant roof edge, dB
    specular : the reflection is a specular one off a face (else diffuse); False where not NLOS
    nlos_k_lin : Rician K of the reflected signal (0 for diffuse scattering and where not NLOS)
    path_id : int, which path arrives: −1 direct or diffracted, the reflecting box's index for a specular
        reflection, −2 − (index of the dominant blocking box) for diffuse scattering
    """

    loss_db: np.ndarray
    nlos: np.ndarray
    solid_blocked: np.ndarray
    nlos_extra_m: np.ndarray
    diffraction_db: np.ndarray
    specular: np.ndarray = None
    nlos_k_lin: np.ndarray = None
    path_id: np.ndarray = None

    FIELDS = ("loss_db", "nlos", "solid_blocked", "nlos_extra_m", "diffraction_db", "specular", "nlos_k_lin",
              "path_id")

    def take(self, rows: np.ndarray) -> "Blockage":
        """The same outcome at the epochs ``rows`` (an index array)."""
        return Blockage(*(getattr(self, f)[rows] for f in self.FIELDS))


@dataclass(frozen=True, eq=False)
class Reflectors:
    """What the specular search needs of the site and receiver (:mod:`simulation.gnss.reflection`).

    eta : (m,) complex relative permittivity of each box at the carrier; roughness_m : (m,) σ_h
    xpr_db : the receive antenna's cross-polar rejection, dB; k_los_lin : (n,) line-of-sight K at each epoch
    (a reflection's K is capped there)
    """

    eta: np.ndarray
    roughness_m: np.ndarray
    xpr_db: float
    k_los_lin: np.ndarray


def blockage(p_en: np.ndarray, z0_m: np.ndarray, az_rad: np.ndarray, el_rad: np.ndarray, boxes: np.ndarray,
             porous: np.ndarray, nlos_loss_db: np.ndarray, porous_loss_db: np.ndarray,
             nlos_excess_m: np.ndarray, cfg: SignalConfig = SignalConfig(),
             max_block: int = 2_000_000, reflectors: Reflectors | None = None) -> Blockage:
    """Propagation loss and NLOS state of every ray (see the module docstring, item 2).

    A solid box in the direct path leaves three ways in: diffraction over its roof edge (J(ν), counted as
    line of sight), a specular reflection off another structure's face (:func:`simulation.gnss.reflection.
    specular_reflections`, when ``reflectors`` is given) and diffuse scattering (loss ``nlos_loss_db`` of the
    dominant blocking box); the receiver gets the strongest.

    Parameters
    ----------
    p_en : (n, 2) receiver east/north, m; z0_m : (n,) receiver height above ground, m
    az_rad, el_rad : (n, k) satellite directions
    boxes : (m, 5) from :func:`simulation.site.geometry.boxes_array`; porous : bool (m,)
    nlos_loss_db, porous_loss_db, nlos_excess_m : (k, m) per (satellite, box) draws
        diffuse-scattering loss, porous-crossing loss, exponential part of the diffuse NLOS extra path.
    max_block : work size (n·k·m) per chunk, to bound memory.
    reflectors : the faces' materials and the antenna (None: no specular search, diffuse only).
    """
    p_en = np.asarray(p_en, float)
    n, k = np.shape(el_rad)
    m = boxes.shape[0]
    shape = (n, k)
    if m == 0:
        z = np.zeros(shape)
        f = np.zeros(shape, bool)
        return Blockage(z, f, f.copy(), z.copy(), z.copy(), f.copy(), z.copy(), np.full(shape, -1, int))
    loss = np.empty(shape)
    nlos = np.empty(shape, bool)
    solid_any = np.empty(shape, bool)
    extra = np.empty(shape)
    diff = np.empty(shape)
    spec_out = np.zeros(shape, bool)
    k_out = np.zeros(shape)
    path_out = np.full(shape, -1, int)
    solid = ~np.asarray(porous, bool)
    z0_all = np.asarray(z0_m, float)
    step = max(1, max_block // max(1, k * m))
    for i0 in range(0, n, step):
        sl = slice(i0, min(n, i0 + step))
        el = el_rad[sl]
        _, clearance, t_in = ray_blockers(p_en[sl], az_rad[sl], el, boxes, 0.0)
        clearance = clearance - z0_all[sl, None, None]
        blocked = clearance > 0.0
        cos_el = np.cos(el)[..., None]
        with np.errstate(invalid="ignore", divide="ignore"):
            # Edge height above the ray, perpendicular to it; slant distance to the edge.
            nu = fresnel_nu(clearance * cos_el, t_in / np.maximum(cos_el, 1e-6), cfg.wavelength_m)
        nu = np.where(np.isfinite(t_in), nu, -np.inf)
        nu = np.where((t_in <= 0.0) & blocked, np.inf, nu)  # receiver inside the footprint
        j = np.where(solid, knife_edge_loss_db(nu), 0.0)
        j_max = j.max(axis=-1)
        sb = blocked & solid
        any_sb = sb.any(axis=-1)
        refl = np.where(sb, nlos_loss_db[None], -np.inf)
        jdom = refl.argmax(axis=-1)
        l_diffuse = np.take_along_axis(refl, jdom[..., None], -1)[..., 0]
        d_h = np.take_along_axis(t_in, jdom[..., None], -1)[..., 0]
        exc = np.take_along_axis(np.broadcast_to(nlos_excess_m[None], sb.shape), jdom[..., None], -1)[..., 0]
        ex_diffuse = np.minimum(2.0 * np.where(np.isfinite(d_h), d_h, 0.0) * np.cos(el) + exc, cfg.nlos_extra_max_m)
        l_spec = np.full(any_sb.shape, np.inf)
        ex_spec = np.zeros(any_sb.shape)
        k_spec = np.zeros(any_sb.shape)
        box_spec = np.full(any_sb.shape, -1, int)
        if reflectors is not None and any_sb.any():
            ei, si = np.nonzero(any_sb)
            rows = ei + i0
            r = specular_reflections(p_en[rows], z0_all[rows], az_rad[rows, si], el_rad[rows, si], boxes, porous,
                                     reflectors.eta, reflectors.roughness_m, reflectors.xpr_db, cfg.wavelength_m,
                                     np.asarray(reflectors.k_los_lin, float)[rows], cfg.nlos_extra_max_m)
            l_spec[ei, si], ex_spec[ei, si], k_spec[ei, si], box_spec[ei, si] = r.loss_db, r.extra_m, r.k_lin, r.box
        is_spec = any_sb & (l_spec <= l_diffuse) & (l_spec < j_max)
        is_diffuse = any_sb & ~is_spec & (l_diffuse < j_max)
        is_nlos = is_spec | is_diffuse
        solid_loss = np.where(is_spec, l_spec, np.where(is_diffuse, l_diffuse, j_max))
        porous_loss = np.where(blocked & ~solid, porous_loss_db[None], 0.0).sum(axis=-1)
        loss[sl] = solid_loss + porous_loss
        nlos[sl] = is_nlos
        solid_any[sl] = any_sb
        extra[sl] = np.where(is_spec, ex_spec, np.where(is_diffuse, ex_diffuse, 0.0))
        diff[sl] = j_max
        spec_out[sl] = is_spec
        k_out[sl] = np.where(is_spec, k_spec, 0.0)
        path_out[sl] = np.where(is_spec, box_spec, np.where(is_diffuse, -2 - jdom, -1))
    return Blockage(loss, nlos, solid_any, extra, diff, spec_out, k_out, path_out)


def body_loss_db(az_rad: np.ndarray, el_rad: np.ndarray, heading_rad: np.ndarray,
                 cfg: SignalConfig = SignalConfig()) -> np.ndarray:
    """Masking of the sky by the wearer's body for a waist-worn antenna, dB, shape (n, k).

    L = L_b·cos(π/2·Δ/W)·(1 − el/E) for |Δ| < W and el < E, 0 elsewhere, with Δ
    the azimuth of the satellite from the wearer's back (heading + π), W =
    ``body_half_width_deg`` and E = ``body_el_deg``: strongest straight behind
    and low, gone overhead and in front. A modelling choice sized after
    body-worn antenna measurements, which find blockage losses of 10 dB and
    more behind the wearer (cf. Bancroft, Garrett, Lachapelle & Petovello
    2011, on antenna locations on the human body, ION GNSS 2011).

    >>> body_loss_db(np.radians([[180.0, 0.0, 180.0]]), np.radians([[0.0, 0.0, 60.0]]), np.zeros(1)).round(2).tolist()
    [[10.0, 0.0, 0.0]]
    """
    back = np.asarray(heading_rad, float)[:, None] + np.pi
    delta = np.abs(np.angle(np.exp(1j * (np.asarray(az_rad, float) - back))))
    w = np.radians(cfg.body_half_width_deg)
    e = np.radians(cfg.body_el_deg)
    az_term = np.where(delta < w, np.cos(0.5 * np.pi * delta / w), 0.0)
    el_term = np.clip(1.0 - np.asarray(el_rad, float) / e, 0.0, 1.0)
    return cfg.body_loss_db * az_term * el_term


def receiver_draws(rng: np.random.Generator, cfg: SignalConfig = SignalConfig()) -> tuple[float, float, float]:
    """One receiver's C/N0 offset, tracking-threshold offset and antenna cross-polar rejection, dB.

    Receivers differ: a body-worn device's small antenna and front end report
    C/N0 several dB below a survey antenna on a pole (smartphones sit about
    10 dB below geodetic receivers; Paziewski 2020, "Recent advances and
    perspectives for positioning and applications with smartphone GNSS
    observations", Meas. Sci. Technol. 31(9)), offset ~ U(min, max); and
    their tracking loops hold and reacquire at different strengths, so the
    same sky leaves a different share listed without SNR (threshold offset
    ~ U(0, ``rx_threshold_max_db``)); and their antennas reject left-hand
    polarised (reflected) signals by different amounts (XPR ~ U(``xpr_min_db``,
    ``xpr_max_db``), :mod:`simulation.gnss.reflection`).
    """
    return (float(rng.uniform(cfg.rx_offset_min_db, cfg.rx_offset_max_db)),
            float(rng.uniform(0.0, cfg.rx_threshold_max_db)),
            float(rng.uniform(cfg.xpr_min_db, cfg.xpr_max_db)))


def emi_loss_db(p_en: np.ndarray, zones) -> np.ndarray:
    """C/N0 loss from EMI zones at positions (n, 2), dB, shape (n,).

    Raised-cosine profile per zone, L(d) = L0·(1 + cos(π·d/R))/2 for d < R,
    summed over zones (a modelling choice: in-band interference raises the
    noise floor, ΔC/N0 = 10·log10(1 + I0/N0), strongest beside the source).

    >>> from features.site import EmiZone
    >>> emi_loss_db(np.array([[0.0, 0.0], [5.0, 0.0], [20.0, 0.0]]), [EmiZone(0.0, 0.0, 10.0, 6.0)]).round(3).tolist()
    [6.0, 3.0, 0.0]
    """
    p = np.atleast_2d(np.asarray(p_en, float))
    out = np.zeros(p.shape[0])
    for z in zones:
        d = np.hypot(p[:, 0] - z.east_m, p[:, 1] - z.north_m)
        out += np.where(d < z.radius_m, z.loss_db * 0.5 * (1.0 + np.cos(np.pi * d / z.radius_m)), 0.0)
    return out


def clutter_index(p_en: np.ndarray, boxes: np.ndarray, porous: np.ndarray, scale_m: float) -> np.ndarray:
    """Nearness of solid structures, exp(−d/scale) with d the horizontal distance to the nearest solid box; (n,)."""
    p = np.atleast_2d(np.asarray(p_en, float))
    solid = boxes[~np.asarray(porous, bool)]
    if solid.shape[0] == 0:
        return np.zeros(p.shape[0])
    de = np.maximum(np.maximum(solid[:, 0] - p[:, :1], p[:, :1] - solid[:, 1]), 0.0)
    dn = np.maximum(np.maximum(solid[:, 2] - p[:, 1:], p[:, 1:] - solid[:, 3]), 0.0)
    return np.exp(-np.hypot(de, dn).min(axis=1) / scale_m)


def rician_power(rng: np.random.Generator, path_m: np.ndarray, k_lin: np.ndarray, wavelength_m: float,
                 n_sinusoids: int = 12, chunk: int = 4096) -> np.ndarray:
    """Power gain |h|² of a Rician channel with a Clarke/Jakes diffuse part; shape (n_t, k), mean 1.

    h(s) = sqrt(K/(K+1))·exp(j·κ·s·cosθ₀) + sqrt(1/(K+1))·N^(−1/2)·Σₙ exp(j(κ·s·cos αₙ + φₙ)),
    κ = 2π/λ, with s the effective distance moved (walked distance plus
    λ·f_floor·t), so the autocorrelation of the diffuse part tends to
    J₀(2π·f_d·τ) with f_d = v/λ (Clarke 1968; sum-of-sinusoids with random
    angles and phases, Pätzold 2011 §4.1).

    Parameters
    ----------
    path_m : (n_t,) effective distance, m; k_lin : (n_t, k) Rician K-factor (linear).
    """
    n_t, k = k_lin.shape
    alpha = rng.uniform(0.0, 2.0 * np.pi, (k, n_sinusoids))
    phi = rng.uniform(0.0, 2.0 * np.pi, (k, n_sinusoids))
    theta0 = rng.uniform(0.0, 2.0 * np.pi, k)
    kappa = 2.0 * np.pi / wavelength_m
    ca = np.cos(alpha)[None]
    out = np.empty((n_t, k))
    for i0 in range(0, n_t, chunk):
        s = np.asarray(path_m[i0:i0 + chunk], float)[:, None]
        arg = kappa * s[..., None] * ca + phi[None]
        diff_re = np.cos(arg).sum(-1) / np.sqrt(n_sinusoids)
        diff_im = np.sin(arg).sum(-1) / np.sqrt(n_sinusoids)
        kk = k_lin[i0:i0 + chunk]
        a_los = np.sqrt(kk / (kk + 1.0))
        a_d = np.sqrt(1.0 / (kk + 1.0))
        los_arg = kappa * s * np.cos(theta0)[None]
        re = a_los * np.cos(los_arg) + a_d * diff_re
        im = a_los * np.sin(los_arg) + a_d * diff_im
        out[i0:i0 + chunk] = re * re + im * im
    return out


def estimate_cn0(rng: np.random.Generator, cn0_epoch_dbhz: np.ndarray, dt_s: float,
                 cfg: SignalConfig = SignalConfig()) -> np.ndarray:
    """The receiver's C/N0 estimate, dB-Hz, shape (n, k), before rounding.

    First-order smoothing of the linear C/N0 with time constant τ
    (y_i = y_{i−1} + α(x_i − y_{i−1}), α = 1 − exp(−Δt/τ)), started in steady
    state, then estimator noise of σ = σ0·sqrt(1 + 10^((30 − C/N0)/10)) dB
    (the spread of moment-based SNR estimators grows as SNR falls; Pauluzzi &
    Beaulieu 2000, IEEE Trans. Commun. 48(10)).
    """
    x = 10.0 ** (np.asarray(cn0_epoch_dbhz, float) / 10.0)
    alpha = 1.0 - np.exp(-dt_s / cfg.estimator_tau_s)
    zi = ((1.0 - alpha) * x[0])[None]
    y, _ = lfilter([alpha], [1.0, alpha - 1.0], x, axis=0, zi=zi)
    c = 10.0 * np.log10(y)
    sigma = cfg.estimator_noise_db * np.sqrt(1.0 + 10.0 ** ((30.0 - c) / 10.0))
    return c + sigma * rng.standard_normal(c.shape)


def track(cn0_est_dbhz: np.ndarray, in_view: np.ndarray, dt_s: float, cfg: SignalConfig = SignalConfig()) -> np.ndarray:
    """Tracking state with hysteresis, bool (n, k).

    A tracked satellite is lost when its estimate falls below
    ``track_lose_dbhz`` or it leaves the sky; an untracked one is (re)acquired
    once its estimate has stayed at or above ``track_acquire_dbhz`` for
    ``reacquire_delay_s``. At the first epoch the receiver is taken as already
    running: satellites at or above the acquisition threshold are tracked.
    """
    n, k = cn0_est_dbhz.shape
    need = max(1, int(round(cfg.reacquire_delay_s / dt_s)))
    out = np.zeros((n, k), bool)
    state = in_view[0] & (cn0_est_dbhz[0] >= cfg.track_acquire_dbhz)
    run = np.zeros(k, int)
    for i in range(n):
        c = cn0_est_dbhz[i]
        v = in_view[i]
        strong = v & (c >= cfg.track_acquire_dbhz)
        run = np.where(strong, run + 1, 0)
        if i > 0:
            state = np.where(state, v & (c >= cfg.track_lose_dbhz), run >= need)
        out[i] = state
    return out
