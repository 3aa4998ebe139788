"""Hand-built acoustic test signals: beacon chirps placed at exact (fractional) delays.

Independent of ``simulation/`` on purpose: the receiver is tested against
closed-form geometry (straight-line delays, 1/r amplitudes), not against the
channel simulator. The chirp is the documented beacon waveform
(docs/beacon_protocol.md): s(t) = w(t)·sin(2π(f0·t + ½·k·t²)), w Tukey.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf

from features.site import AcousticConfig, Beacon, Grid, Origin, Site

FS_HZ = 48_000
C_20C_M_S = 331.3 * math.sqrt(1.0 + 20.0 / 273.15)


def chirp_at(t_s: np.ndarray, f0_hz=17_000.0, f1_hz=23_000.0, duration_s=0.010, taper=0.2,
             fs_hz=FS_HZ) -> np.ndarray:
    """Chirp value at times ``t_s`` after its start (0 outside [0, T)); continuous Tukey taper."""
    n_ref = int(round(duration_s * fs_hz))
    x = t_s * fs_hz / (n_ref - 1)
    w = np.zeros_like(t_s)
    inside = (x >= 0) & (x <= 1)
    w[inside] = 1.0
    half = taper / 2
    lo = inside & (x < half)
    hi = inside & (x > 1 - half)
    w[lo] = 0.5 * (1 - np.cos(np.pi * x[lo] / half))
    w[hi] = 0.5 * (1 - np.cos(np.pi * (1 - x[hi]) / half))
    k = (f1_hz - f0_hz) / duration_s
    return w * np.sin(2 * np.pi * (f0_hz * t_s + 0.5 * k * t_s * t_s))


def add_chirp(x: np.ndarray, start_s: float, gain: float, fs_hz=FS_HZ, duration_s=0.010) -> None:
    """Add ``gain·s(t − start_s)`` into ``x`` in place (sample n at time n/fs)."""
    n0 = max(0, int(math.floor(start_s * fs_hz)) - 1)
    n1 = min(len(x), int(math.ceil((start_s + duration_s) * fs_hz)) + 2)
    if n1 <= n0:
        return
    t = np.arange(n0, n1) / fs_hz - start_s
    x[n0:n1] += gain * chirp_at(t, duration_s=duration_s, fs_hz=fs_hz)


def square_site(n_beacons: int = 5, spacing_m: float = 30.0, slot_s: float = 0.1, n_slots: int = 8) -> Site:
    """Beacons on poles (3 m) round a 60 × 60 m yard, one slot each."""
    pos = [(0.0, 0.0), (60.0, 0.0), (60.0, 60.0), (0.0, 60.0), (30.0, 30.0), (30.0, 0.0), (0.0, 30.0), (60.0, 30.0)]
    beacons = tuple(Beacon(id=i + 1, east_m=e, north_m=n, up_m=3.0, slot=i) for i, (e, n) in enumerate(pos[:n_beacons]))
    return Site(name="synthetic", origin=Origin(31.0, 118.0), device_height_m=1.0,
                grid=Grid(cell_size_m=5.0, east_min_m=0.0, east_max_m=60.0, north_min_m=0.0, north_max_m=60.0),
                acoustic=AcousticConfig(slot_s=slot_s, n_slots=n_slots), beacons=beacons)


@dataclass(frozen=True)
class Capture:
    """What the synthetic receiver heard: samples and the truth behind them."""

    samples: np.ndarray
    east_m: float
    north_m: float
    clock_offset_s: float


def static_capture(site: Site, east_m: float, north_m: float, duration_s: float, *, clock_offset_s: float = 0.0,
                   frame_phase_s: float = 0.0, noise_rms: float = 0.002, seed: int = 0,
                   amplitude_at_1m: float = 2.0, nlos_bias_m: dict | None = None,
                   echoes: tuple = ((0.004, 0.3),), fs_hz=FS_HZ) -> Capture:
    """A static receiver: every beacon's chirp at its straight-line delay (1/r amplitude) plus echoes.

    ``clock_offset_s`` δ: sample n is stamped ``n/fs`` on the receiver clock, the
    true time being ``n/fs − δ``. ``nlos_bias_m`` adds extra path (and removes
    the direct path) for the given beacon ids. ``echoes`` are (extra delay s,
    relative gain) added after each arrival.
    """
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * fs_hz))
    x = rng.normal(0.0, noise_rms, n)
    ac = site.acoustic
    nlos_bias_m = nlos_bias_m or {}
    for b in site.beacons:
        d = math.dist((east_m, north_m, site.device_height_m), (b.east_m, b.north_m, b.up_m))
        d_path = d + nlos_bias_m.get(b.id, 0.0)
        k = 0
        while True:
            tx = frame_phase_s + k * ac.frame_s + b.slot * ac.slot_s
            if tx > duration_s:
                break
            arrival_stamp = tx + d_path / C_20C_M_S + clock_offset_s
            add_chirp(x, arrival_stamp, amplitude_at_1m / d_path, fs_hz)
            for extra_s, g in echoes:
                add_chirp(x, arrival_stamp + extra_s, g * amplitude_at_1m / d_path, fs_hz)
            k += 1
    return Capture(x, east_m, north_m, clock_offset_s)


def write_wav(path, samples: np.ndarray, fs_hz: int = FS_HZ, subtype: str = "PCM_16") -> None:
    """Write float samples in [-1, 1) as a WAV file (clipped to full scale)."""
    sf.write(str(path), np.clip(samples, -1.0, 32767 / 32768), fs_hz, subtype=subtype)


def moving_capture(site: Site, start_en: tuple, velocity_en: tuple, duration_s: float, *,
                   clock_offset_s: float = 0.0, noise_rms: float = 0.002, seed: int = 0,
                   amplitude_at_1m: float = 2.0, fs_hz=FS_HZ) -> np.ndarray:
    """A receiver walking a straight line at constant velocity (m/s); each chirp's delay from the
    position when it arrives (fixed point of t_a = t_e + |p(t_a) − s|/c, two iterations)."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, noise_rms, int(round(duration_s * fs_hz)))
    ac = site.acoustic
    for b in site.beacons:
        k = 0
        while True:
            tx = k * ac.frame_s + b.slot * ac.slot_s
            if tx > duration_s:
                break
            t_a = tx
            for _ in range(3):
                e, n = start_en[0] + velocity_en[0] * t_a, start_en[1] + velocity_en[1] * t_a
                d = math.dist((e, n, site.device_height_m), (b.east_m, b.north_m, b.up_m))
                t_a = tx + d / C_20C_M_S
            add_chirp(x, t_a + clock_offset_s, amplitude_at_1m / d, fs_hz)
            add_chirp(x, t_a + clock_offset_s + 0.004, 0.3 * amplitude_at_1m / d, fs_hz)
            k += 1
    return x


SINGLE_PATH_NOISE_RMS = 0.002
SINGLE_PATH_RANGE_M = 20.0


def one_beacon_site() -> Site:
    return Site(name="single", origin=Origin(31.0, 118.0), device_height_m=1.0,
                grid=Grid(cell_size_m=5.0, east_min_m=-30.0, east_max_m=30.0, north_min_m=-30.0, north_max_m=30.0),
                acoustic=AcousticConfig(slot_s=0.1, n_slots=1),
                beacons=(Beacon(id=1, east_m=SINGLE_PATH_RANGE_M, north_m=0.0, up_m=1.0, slot=0),))


def single_path_run(gain: float, seconds: float, seed: int, tmp, echoes: tuple = ()):
    """One beacon 20 m away, one chirp every 0.1 s of amplitude ``gain`` in white noise of rms
    0.002, plus ``echoes`` ((extra delay s, relative gain), ...); through the receiver
    (:func:`features.acoustic.detection.detect_frames`). Returns (features (n, 9), snr_db (n,),
    first-arrival error s (n,)) of every chirp detected."""
    from features.acoustic.detection import AudioTiming, DetectorConfig, detect_frames

    site = one_beacon_site()
    rng = np.random.default_rng(seed)
    n = int(seconds * FS_HZ)
    x = rng.normal(0.0, SINGLE_PATH_NOISE_RMS, n)
    true_arrivals = []
    k = 0
    while k * 0.1 + 0.2 < seconds:
        t = k * 0.1 + SINGLE_PATH_RANGE_M / C_20C_M_S
        add_chirp(x, t, gain)
        for extra_s, g in echoes:
            add_chirp(x, t + extra_s, g * gain)
        true_arrivals.append(t)
        k += 1
    path = Path(tmp) / f"single_{seed}_{gain:.6f}_{len(echoes)}.wav"
    write_wav(path, x, subtype="FLOAT")
    # 0.1 s frames: ranges up to 30 m (87 ms) leave ±6 ms of start uncertainty (detection._frame_safe_timing).
    timing = AudioTiming(start_s=0.0, start_uncertainty_s=0.005, frame_phase_s=0.0)
    feats, snr, err = [], [], []
    true_arrivals = np.array(true_arrivals)
    for fr in detect_frames(path, site, timing, DetectorConfig(max_range_m=30.0)):
        for d in fr.detections:
            j = int(np.argmin(np.abs(true_arrivals - d.arrival_s)))
            feats.append(d.features.as_array())
            snr.append(d.snr_db)
            err.append(d.arrival_s - true_arrivals[j])
    return np.array(feats).reshape(-1, 9), np.array(snr), np.array(err)
