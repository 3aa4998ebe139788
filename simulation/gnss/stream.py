"""The GNSS stream of a walk or survey cell: simulate the receiver and write ``gnss.nmea``.

:func:`simulate_gnss` is the pure simulation (arrays per epoch and satellite,
for tests and benchmarks); :func:`write_gnss` is the stream writer listed in
:data:`simulation.streams.STREAM_WRITERS`. Every random draw comes from
``stream_rng(seed, "gnss", <part>)``, one named stream per model part, so a
change in one part never shifts the draws of another.

Options read from ``StreamContext.options``: ``gnss_corrections`` (bool,
default True: DGNSS/RTK corrections available), ``gnss_rate_hz`` (default 5),
``gnss_rtk_cold_start`` (default: True for a walk, False for a survey cell),
``gnss_gst`` (the receiver model sends GST; default: when corrections are on,
as RTK receivers do).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from datetime import timezone

import numpy as np

from features.constants import SPEED_OF_LIGHT_M_S
from features.errors import ConfigError
from features.fileio import atomic_write_text
from features.geodesy import enu_to_geodetic
from simulation.gnss import fix as gnss_fix
from simulation.gnss import signal as gnss_signal
from simulation.gnss.rtk import RtkConfig
from simulation.gnss.reflection import SURFACE_ROUGHNESS_M, material_key, relative_permittivity
from simulation.site.geometry import boxes_array
from simulation.gnss.nmea_writer import NMEA_SYSTEM_BDS, NMEA_SYSTEM_GPS, NmeaEpochs, format_nmea
from simulation.gnss.orbits import SYSTEM_GPS, all_satellites, azel
from simulation.gnss.velocity import velocity_errors
from simulation.rng import stream_rng
from simulation.streams import StreamContext, Trajectory

__all__ = ["GnssSimulation", "simulate_gnss", "to_nmea_epochs", "write_gnss", "GNSS_FILE", "DEFAULT_RATE_HZ"]

GNSS_FILE = "gnss.nmea"
DEFAULT_RATE_HZ = 5.0


@dataclass(frozen=True, eq=False)
class GnssSimulation:
    """Per-epoch simulator output (n epochs, k satellites); simulator internals for tests.

    t_s : (n,) seconds since the trajectory start; unix_s : (n,) UTC POSIX seconds
    truth_enu_m, fix_enu_m : (n, 3) true and reported positions (fix NaN when quality 0)
    quality, n_used : (n,) int; hdop, vdop, pdop : (n,)
    system : (k,) "GPS"/"BDS"; prn : (k,)
    az_rad, el_rad : (n, k); in_view, tracked, used : (n, k) bool
    los, nlos : (n, k) bool, in view and received directly or diffracted (los) or by reflection (nlos)
    blocked : (n, k) bool, in view with a solid box in the geometric direct path (diffracted or NLOS)
    cn0_open_dbhz : (n, k) open-sky C/N0 (with the satellite's offset)
    attenuation_db : (n, k) blockage + EMI loss (no fading), dB
    cn0_true_dbhz : (n, k) epoch-mean C/N0 with fading; cn0_reported_dbhz : (n, k) integer, NaN untracked
    receiver_offset_db, receiver_threshold_db : this receiver's C/N0 offset and tracking-threshold offset, dB
    code_error_m : (n, k) each satellite's pseudorange error after the differential corrections, m
    gst : (n, 7) the receiver's GST fields (:func:`simulation.gnss.gst.gst_fields`), NaN without a fix
    specular : (n, k) bool, NLOS by a specular reflection off a face (else diffuse scattering)
    nlos_extra_m : (n, k) the reflected path's geometric extra length, m (0 where not NLOS)
    """

    t_s: np.ndarray
    unix_s: np.ndarray
    truth_enu_m: np.ndarray
    fix_enu_m: np.ndarray
    quality: np.ndarray
    n_used: np.ndarray
    hdop: np.ndarray
    vdop: np.ndarray
    pdop: np.ndarray
    system: np.ndarray
    prn: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    in_view: np.ndarray
    tracked: np.ndarray
    used: np.ndarray
    los: np.ndarray
    nlos: np.ndarray
    blocked: np.ndarray
    cn0_open_dbhz: np.ndarray
    attenuation_db: np.ndarray
    cn0_true_dbhz: np.ndarray
    cn0_reported_dbhz: np.ndarray
    receiver_offset_db: float = 0.0
    receiver_threshold_db: float = 0.0
    specular: np.ndarray = None
    nlos_extra_m: np.ndarray = None
    gst: np.ndarray = None
    code_error_m: np.ndarray = None

    @property
    def horizontal_error_m(self) -> np.ndarray:
        """(n,) horizontal fix error, m (NaN without a fix)."""
        d = self.fix_enu_m[:, :2] - self.truth_enu_m[:, :2]
        return np.hypot(d[:, 0], d[:, 1])


def _epoch_times(traj: Trajectory, rate_hz: float) -> np.ndarray:
    dt = 1.0 / rate_hz
    n = int(np.floor(traj.duration_s * rate_hz + 1e-9)) + 1
    return traj.t_s[0] + dt * np.arange(n)


def _key_epochs(t_s: np.ndarray, p_en: np.ndarray, up_m: np.ndarray, move_m: float = 0.05,
                max_dt_s: float = 1.0) -> np.ndarray:
    """Epochs at which the ray–box tests are redone: the receiver moved ≥ ``move_m`` or ``max_dt_s`` passed.

    In between, the satellites move by < 0.01° (MEO angular rate ≈ 0.008°/s),
    so a standing receiver reuses the last test; a walker (≈ 0.3 m per epoch)
    gets a fresh test every epoch. Returns sorted indices starting at 0.
    """
    keys = [0]
    last = 0
    pe, pn, pu, tt = p_en[:, 0].tolist(), p_en[:, 1].tolist(), up_m.tolist(), t_s.tolist()
    for i in range(1, len(tt)):
        if (tt[i] - tt[last] >= max_dt_s - 1e-9
                or (pe[i] - pe[last]) ** 2 + (pn[i] - pn[last]) ** 2 + (pu[i] - pu[last]) ** 2 >= move_m ** 2):
            keys.append(i)
            last = i
    return np.asarray(keys, int)


def _risen_satellites(site, unix_s: np.ndarray, seed: int, cfg: gnss_signal.SignalConfig, n_boxes: int):
    """The satellites above the in-view mask at some epoch: (sats, az, el (n, k) rad, per-satellite C/N0 offset
    (k,) dB, and per satellite and box: NLOS reflection loss, porous loss (dB) and NLOS excess path (m), (k, m)).

    The draws are made for the whole constellation, so a satellite's draws do not depend on which others rise;
    the others never appear in any output.
    """
    sats = all_satellites()
    k_all = len(sats)
    az, el = azel(unix_s, site.origin, sats)
    offset = cfg.sat_offset_sigma_db * stream_rng(seed, "gnss", "sat_offset").standard_normal(k_all)
    refl = stream_rng(seed, "gnss", "nlos_loss").uniform(cfg.nlos_loss_min_db, cfg.nlos_loss_max_db, (k_all, n_boxes))
    por = stream_rng(seed, "gnss", "porous_loss").uniform(cfg.porous_loss_min_db, cfg.porous_loss_max_db,
                                                          (k_all, n_boxes))
    excess = stream_rng(seed, "gnss", "nlos_excess").exponential(cfg.nlos_excess_mean_m, (k_all, n_boxes))
    rises = np.flatnonzero((el > np.radians(cfg.in_view_mask_deg)).any(axis=0))
    return (sats.select(rises), az[:, rises], el[:, rises], offset[rises], refl[rises], por[rises],
            excess[rises])


def _fading_power(traj: Trajectory, t: np.ndarray, dt: float, speed: np.ndarray, k_lin: np.ndarray, seed: int,
                  cfg: gnss_signal.SignalConfig) -> np.ndarray:
    """Received power re. the mean (n, k) of Rician fading with factors ``k_lin`` (n, k), averaged over each epoch
    (epochs ``t`` (n,) s, ``dt`` apart; the walker's ``speed`` (n,) m/s).

    The receiver averages power over the epoch, sampled fast enough for the walker's Doppler spread (n_sub ≤ 8
    instants per epoch); the phase runs with the distance walked plus a floor Doppler.
    """
    n, k = k_lin.shape
    f_max = float(np.max(speed, initial=0.0)) / cfg.wavelength_m + cfg.doppler_floor_hz
    n_sub = int(min(8, max(1, np.ceil(2.0 * f_max * dt))))
    sub = t[:, None] - dt + dt * (np.arange(n_sub) + 0.5)[None, :] / n_sub  # (n, n_sub) inside each epoch
    walked = np.concatenate([[0.0], np.cumsum(0.5 * (traj.speed_m_s[1:] + traj.speed_m_s[:-1]) * np.diff(traj.t_s))])
    path = np.interp(sub, traj.t_s, walked) + cfg.wavelength_m * cfg.doppler_floor_hz * sub
    power = gnss_signal.rician_power(stream_rng(seed, "gnss", "fading"), path.ravel(),
                                     np.repeat(k_lin, n_sub, axis=0), cfg.wavelength_m, cfg.n_sinusoids)
    return power.reshape(n, n_sub, k).mean(axis=1)


def _fixes(seed: int, sats, az: np.ndarray, el: np.ndarray, tracked: np.ndarray, est: np.ndarray,
           reported: np.ndarray, blk, clutter: np.ndarray, speed: np.ndarray, dt: float, corrections: bool,
           cfg: gnss_signal.SignalConfig, fix_cfg: gnss_fix.FixConfig, rx_offset_db: float, rtk_cfg: RtkConfig):
    """The receiver's position solutions (:func:`simulation.gnss.fix.solve_fixes`) from the tracked satellites
    (each array (n, k)): cycle slips, pseudorange errors, code/DGNSS/RTK fixes."""
    n, k = tracked.shape
    sys_idx = np.where(sats.system == SYSTEM_GPS, 0, 1)
    # Cycle slips restart both the carrier smoothing of the code and the RTK engine's lock.
    slip = gnss_fix.cycle_slips(stream_rng(seed, "gnss", "slips"), reported, blk.nlos, fix_cfg)
    # A change of the arriving path (direct ↔ reflected, one reflector for another) moves the carrier by metres
    # between two epochs, which no tracking loop follows: a cycle slip (the receiver re-locks on the new path).
    switch = np.zeros((n, k), bool)
    switch[1:] = blk.path_id[1:] != blk.path_id[:-1]
    slip |= switch & tracked
    untracked = ~tracked
    reset = slip | untracked | np.vstack([np.ones((1, k), bool), untracked[:-1]])
    errors = gnss_fix.pseudorange_errors(stream_rng(seed, "gnss", "errors"), el, np.where(tracked, est, np.nan),
                                         blk.nlos, blk.nlos_extra_m, clutter, speed, dt, cfg.wavelength_m, fix_cfg,
                                         reset=reset, specular=blk.specular)
    return gnss_fix.solve_fixes(stream_rng(seed, "gnss", "rtk"), az, el, sys_idx, tracked, reported, errors,
                                blk.nlos, dt, corrections, fix_cfg, slip=slip, wavelength_m=cfg.wavelength_m,
                                receiver_offset_db=rx_offset_db, rtk_cfg=rtk_cfg)


def simulate_gnss(site, traj: Trajectory, seed: int, corrections: bool = True, rate_hz: float = DEFAULT_RATE_HZ,
                  signal_cfg: gnss_signal.SignalConfig = gnss_signal.SignalConfig(),
                  fix_cfg: gnss_fix.FixConfig = gnss_fix.FixConfig(), receiver_seed: int | None = None,
                  body: bool = True, rtk_cfg: RtkConfig = RtkConfig()) -> GnssSimulation:
    """Simulate the receiver along ``traj`` at ``site`` (see the module docstrings of the parts).

    Parameters
    ----------
    site : features.site.Site (origin, layout boxes, EMI zones)
    traj : Trajectory; its ``up_m`` is the device height above ground
    seed : the walk's or cell's seed; corrections : DGNSS/RTK corrections available
    receiver_seed : the receiver's identity (its C/N0 and tracking offsets; default ``seed``): the cells of one
        survey share one receiver, a walker keeps theirs
    body : the wearer's body masks the sky behind them (a walk; a survey pole-mounted capture has no body)
    """
    if not rate_hz > 0:
        raise ConfigError(f"gnss rate_hz must be positive, got {rate_hz}")
    if len(traj.t_s) < 1:
        raise ConfigError("trajectory is empty")
    dt = 1.0 / rate_hz
    t = _epoch_times(traj, rate_hz)
    n = len(t)
    start = traj.start_utc if traj.start_utc.tzinfo else traj.start_utc.replace(tzinfo=timezone.utc)
    unix = start.timestamp() + (t - traj.t_s[0])
    east, north, up = traj.interp(t)
    speed = np.interp(t, traj.t_s, traj.speed_m_s)
    p_en = np.stack([east, north], axis=1)

    cfg = signal_cfg
    boxes = boxes_array(site.layout)
    porous = np.array([b.porous for b in site.layout], bool)
    sats, az, el, offset, refl, por, excess = _risen_satellites(site, unix, seed, cfg, boxes.shape[0])
    k = len(sats)

    clutter = gnss_signal.clutter_index(p_en, boxes, porous, cfg.clutter_scale_m)
    k_db = cfg.k_open_db - cfg.k_clutter_drop_db * clutter
    rx_offset_db, rx_threshold_db, xpr_db = gnss_signal.receiver_draws(
        stream_rng(seed if receiver_seed is None else receiver_seed, "gnss", "receiver"), cfg)
    eta = np.array([relative_permittivity(b.material, SPEED_OF_LIGHT_M_S / cfg.wavelength_m) for b in site.layout],
                   complex)
    rough = np.array([SURFACE_ROUGHNESS_M.get(material_key(b.material), 0.01) for b in site.layout], float)
    key = _key_epochs(t, p_en, up)
    reflectors = gnss_signal.Reflectors(eta, rough, xpr_db, 10.0 ** (k_db[key] / 10.0))
    blk = gnss_signal.blockage(p_en[key], up[key], az[key], el[key], boxes, porous, refl, por, excess, cfg,
                               reflectors=reflectors)
    blk = blk.take(np.searchsorted(key, np.arange(n), side="right") - 1)
    emi = gnss_signal.emi_loss_db(p_en, site.emi_zones)
    cn0_open = gnss_signal.open_sky_cn0_dbhz(el, sats.a_m[None, :], cfg) + offset[None, :] + rx_offset_db
    attenuation = blk.loss_db + emi[:, None]
    if body:
        idx = np.clip(np.searchsorted(traj.t_s, t), 0, len(traj.t_s) - 1)
        attenuation = attenuation + gnss_signal.body_loss_db(az, el, traj.heading_rad[idx], cfg)
    cn0_mean = cn0_open - attenuation

    # Fading: K from clutter for direct/diffracted paths, the specular reflection's own K (roughness) for
    # specular NLOS, Rayleigh for diffuse scattering; the receiver averages power over each epoch, sampled fast
    # enough for the walker's Doppler spread.
    k_lin = np.where(blk.nlos, blk.nlos_k_lin, 10.0 ** (k_db[:, None] / 10.0) * np.ones((1, k)))
    cn0_true = cn0_mean + 10.0 * np.log10(np.maximum(_fading_power(traj, t, dt, speed, k_lin, seed, cfg), 1e-12))

    in_view = el > np.radians(cfg.in_view_mask_deg)
    est = gnss_signal.estimate_cn0(stream_rng(seed, "gnss", "estimator"), cn0_true, dt, cfg)
    tracked = gnss_signal.track(est, in_view, dt, replace(cfg, track_lose_dbhz=cfg.track_lose_dbhz + rx_threshold_db,
                                                          track_acquire_dbhz=cfg.track_acquire_dbhz + rx_threshold_db))
    reported = np.where(tracked, np.clip(np.rint(est), 0, 99), np.nan)

    fix = _fixes(seed, sats, az, el, tracked, est, reported, blk, clutter, speed, dt, corrections, cfg, fix_cfg,
                 rx_offset_db, rtk_cfg)
    truth = np.stack([east, north, up], axis=1)
    return GnssSimulation(
        t_s=t, unix_s=unix, truth_enu_m=truth, fix_enu_m=truth + fix.error_enu_m, quality=fix.quality,
        n_used=fix.n_used, hdop=fix.hdop, vdop=fix.vdop, pdop=fix.pdop, system=sats.system, prn=sats.prn,
        az_rad=az, el_rad=el, in_view=in_view, tracked=tracked, used=fix.used, los=in_view & ~blk.nlos,
        nlos=in_view & blk.nlos, blocked=in_view & blk.solid_blocked, cn0_open_dbhz=cn0_open,
        attenuation_db=attenuation, cn0_true_dbhz=cn0_true,
        cn0_reported_dbhz=reported, receiver_offset_db=rx_offset_db, receiver_threshold_db=rx_threshold_db,
        specular=in_view & blk.specular, nlos_extra_m=np.where(in_view, blk.nlos_extra_m, 0.0), gst=fix.gst,
        code_error_m=fix.code_error_m)


def to_nmea_epochs(sim: GnssSimulation, site, seed: int, traj: Trajectory, gst: bool = False) -> NmeaEpochs:
    """Receiver-reported quantities for the NMEA writer (geodetic fix, velocity from the Doppler solution, and its
    GST statistics when ``gst``).

    The site origin's ``alt_m`` is taken as the ground's height and written as
    GGA altitude with a geoid separation of 0.0 (no geoid model is simulated),
    so altitude + separation is the ellipsoidal height pymap3d used.
    """
    o = site.origin
    lat, lon, alt = enu_to_geodetic(sim.fix_enu_m[:, 0], sim.fix_enu_m[:, 1], sim.fix_enu_m[:, 2],
                                    o.lat_deg, o.lon_deg, o.alt_m)
    # Up in the trajectory is the device height above ground at the origin; the origin's altitude is the ground.
    # Velocity: the true velocity plus the Doppler solution's error (simulation.gnss.velocity).
    speed_true = np.interp(sim.t_s, traj.t_s, traj.speed_m_s)
    idx = np.clip(np.searchsorted(traj.t_s, sim.t_s), 0, len(traj.t_s) - 1)
    hdg = np.mod(traj.heading_rad[idx], 2.0 * np.pi)
    dt = float(np.median(np.diff(sim.t_s))) if len(sim.t_s) > 1 else 0.2
    sys_idx = np.where(sim.system == SYSTEM_GPS, 0, 1)
    dv = velocity_errors(stream_rng(seed, "gnss", "velocity"), sim.az_rad, sim.el_rad, sys_idx, sim.used,
                         sim.cn0_reported_dbhz, sim.nlos, speed_true, dt, gnss_signal.WAVELENGTH_M)
    ve = speed_true * np.sin(hdg) + dv[:, 0]
    vn = speed_true * np.cos(hdg) + dv[:, 1]
    spd = np.hypot(ve, vn)
    course = np.where(spd > 0.1, np.mod(np.degrees(np.arctan2(ve, vn)), 360.0), np.nan)
    system = np.where(sim.system == SYSTEM_GPS, NMEA_SYSTEM_GPS, NMEA_SYSTEM_BDS)
    return NmeaEpochs(
        unix_s=sim.unix_s, lat_deg=np.asarray(lat, float), lon_deg=np.asarray(lon, float), alt_m=np.asarray(alt, float),
        quality=sim.quality, hdop=sim.hdop, vdop=sim.vdop, pdop=sim.pdop, speed_m_s=spd, course_deg=course,
        sat_system=system, sat_prn=sim.prn, el_deg=np.degrees(sim.el_rad), az_deg=np.degrees(sim.az_rad),
        in_view=sim.in_view, used=sim.used, snr_dbhz=sim.cn0_reported_dbhz,
        gst=sim.gst if gst and sim.gst is not None else None)


def write_gnss(ctx: StreamContext) -> dict:
    """Stream writer: simulate the receiver along ``ctx.trajectory`` and write ``gnss.nmea``.

    Returns the ``[gnss]`` table for walk.toml / cell.toml.
    """
    corrections = ctx.options.get("gnss_corrections", True)
    if not isinstance(corrections, bool):
        raise ConfigError(f"option gnss_corrections must be true or false, got {corrections!r}")
    rate_hz = ctx.options.get("gnss_rate_hz", DEFAULT_RATE_HZ)
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float)) or not 0 < rate_hz <= 20:
        raise ConfigError(f"option gnss_rate_hz must lie in (0, 20], got {rate_hz!r}")
    # A walk log starts with the receiver: its first RTK fix takes a time-to-fix. A survey crew keeps the
    # receiver running between cells, so a cell's capture starts warm.
    cold = ctx.options.get("gnss_rtk_cold_start", ctx.kind == "walk")
    if not isinstance(cold, bool):
        raise ConfigError(f"option gnss_rtk_cold_start must be true or false, got {cold!r}")
    # GST: RTK receivers (u-blox F9P, NEO-M8P, Unicore UM980) send it; a receiver model without it is one option away.
    gst = ctx.options.get("gnss_gst", corrections)
    if not isinstance(gst, bool):
        raise ConfigError(f"option gnss_gst must be true or false, got {gst!r}")
    sim = simulate_gnss(ctx.site, ctx.trajectory, ctx.seed, corrections=corrections, rate_hz=float(rate_hz),
                        fix_cfg=replace(gnss_fix.FixConfig(), rtk_cold_start=cold), receiver_seed=ctx.person_seed,
                        body=ctx.kind == "walk")
    text = format_nmea(to_nmea_epochs(sim, ctx.site, ctx.seed, ctx.trajectory, gst=gst))
    atomic_write_text(ctx.out_dir / GNSS_FILE, text)
    return {"gnss": {"file": GNSS_FILE, "rate_hz": float(rate_hz), "gst": gst}}
