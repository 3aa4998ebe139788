"""The simulated audio.wav: arrivals, levels, noise, clock, determinism and the stream-writer contract."""

from __future__ import annotations

import csv
import io
import math
import tomllib
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from scipy.signal import fftconvolve, hilbert, welch

from features.errors import ConfigError
from features.site import AcousticConfig, Atmosphere, Beacon, Box, Origin, Site, save_site
from simulation.acoustic.atmosphere import absorption_db_per_m
from simulation.acoustic.stream import AudioConfig, render_audio as _render_audio, write_audio
from simulation.acoustic.air import AirConfig
from simulation.acoustic.chirp import beacon_chirp, reference_chirp
from simulation.streams import StreamContext, Trajectory

FS = 48_000
START = datetime(2026, 6, 1, 8, 0, 0, tzinfo=timezone.utc)
QUIET = AudioConfig(noise_db_spl=-40.0, device_noise_dbfs=-160.0, hum_db_spl_1m=-200.0, corona_rate_hz=0.0)

BEACONS = (Beacon(1, 0.0, 0.0, 3.0, 0), Beacon(2, 30.0, 0.0, 2.8, 1), Beacon(3, 0.0, 30.0, 2.6, 2),
           Beacon(4, 30.0, 30.0, 3.0, 3))


def render_audio(*args, **kwargs):
    """The closed-form checks here test propagation, so the air is the site's stated air
    (simulation.acoustic.air is tested in test_acoustic_air.py)."""
    kwargs.setdefault("air", AirConfig(enabled=False))
    kwargs.setdefault("hardware", None)  # ideal beacons and recorder (simulation.acoustic.hardware tested apart)
    return _render_audio(*args, **kwargs)


def _site(layout=(), beacons=BEACONS) -> Site:
    return Site(name="t", origin=Origin(31.0, 118.0), beacons=beacons, acoustic=AcousticConfig(n_slots=4),
                layout=tuple(layout))


def _static(e: float, n: float, duration_s: float = 2.0) -> Trajectory:
    t = np.arange(0.0, duration_s + 1e-9, 0.01)
    return Trajectory(t_s=t, east_m=np.full_like(t, e), north_m=np.full_like(t, n), up_m=np.ones_like(t),
                      heading_rad=np.zeros_like(t), speed_m_s=np.zeros_like(t), start_utc=START, rate_hz=100.0)


def _truth(result) -> list[dict]:
    return list(csv.DictReader(io.StringIO(result.truth_csv)))


def _matched_filter(path: Path, site: Site) -> np.ndarray:
    x, fs = sf.read(path, dtype="int16")
    assert fs == FS
    ref = reference_chirp(beacon_chirp(site, site.beacons[0]), FS)
    return np.abs(hilbert(fftconvolve(x / 32768.0, ref[::-1])[len(ref) - 1:]))


def test_los_arrivals_in_the_wav_at_the_true_delay(tmp_path):
    """A static receiver 10–25 m from four beacons in the open: the matched-filter peak of every
    recorded chirp lies within one sample of the true direct-path arrival, and the peak ratio of
    two beacons follows spherical spreading with ISO 9613-1 absorption over the band."""
    site = _site()
    res = render_audio(site, _static(12.0, 14.0), 5, tmp_path / "a.wav", QUIET)
    mf = _matched_filter(tmp_path / "a.wav", site)
    rows = _truth(res)
    assert len(rows) >= 16 and {r["first_path"] for r in rows} == {"direct"}
    peaks = {}
    for r in rows:
        s = float(r["arrival_sample"])
        i0 = int(s)
        k = int(np.argmax(mf[i0 - 100:i0 + 100])) + i0 - 100
        assert abs(k - s) <= 1.0
        assert 10.0 <= float(r["direct_m"]) <= 25.0
        dm = float(r["direct_m"])
        want_level = 100.0 - 20 * math.log10(dm) - float(absorption_db_per_m(20_000.0, site.atmosphere)) * dm
        assert float(r["first_path_db_spl"]) == pytest.approx(want_level, abs=0.06)   # CSV keeps 0.1 dB
        peaks.setdefault(r["beacon_id"], []).append(mf[k])
    # closed form of the matched-filter peak for a real gain H(f): Σ|C(f)|²·H(f), H = 10^(−α(f)·d/20)/d
    spec = beacon_chirp(site, site.beacons[0])
    c_f = np.abs(np.fft.rfft(reference_chirp(spec, FS), 8192)) ** 2
    f = np.fft.rfftfreq(8192, 1.0 / FS)
    alpha = absorption_db_per_m(f, site.atmosphere)

    def expected(d):
        return (c_f * 10.0 ** (-alpha * d / 20.0)).sum() / d

    d = {r["beacon_id"]: float(r["direct_m"]) for r in rows}
    got_db = 20 * math.log10(np.median(peaks["1"]) / np.median(peaks["4"]))
    want_db = 20 * math.log10(expected(d["1"]) / expected(d["4"]))
    assert got_db == pytest.approx(want_db, abs=0.5)
    assert want_db > 20 * math.log10(d["4"] / d["1"])          # absorption adds to spreading


def test_clock_offset_and_drift_are_within_the_stated_bounds(tmp_path):
    cfg = replace(QUIET, start_s=0.5, start_uncertainty_s=0.03, clock_drift_ppm=50.0)
    starts = []
    for seed in range(4):
        res = render_audio(_site(), _static(12.0, 14.0), seed, tmp_path / f"{seed}.wav", cfg)
        assert abs(res.true_start_s - 0.5) <= 0.03 and abs(res.drift_ppm) <= 50.0
        starts.append(res.true_start_s)
        for r in _truth(res):
            want = (float(r["arrival_t_s"]) - res.true_start_s) * FS * (1.0 + res.drift_ppm * 1e-6)
            assert float(r["arrival_sample"]) == pytest.approx(want, abs=2e-3)
    assert len(set(starts)) == 4                                   # the offset really is random per seed


def test_same_seed_same_bytes_and_block_size_does_not_matter(tmp_path):
    site = _site([Box("transformer", "steel", False, 14.0, 22.0, 16.0, 21.0, 5.5)])
    traj = _static(12.0, 14.0, 1.5)
    cfg = replace(AudioConfig(), corona_rate_hz=30.0)
    render_audio(site, traj, 11, tmp_path / "a.wav", cfg)
    render_audio(site, traj, 11, tmp_path / "b.wav", replace(cfg, block_samples=16384))
    render_audio(site, traj, 12, tmp_path / "c.wav", cfg)
    a, b, c = ((tmp_path / n).read_bytes() for n in ("a.wav", "b.wav", "c.wav"))
    assert a == b
    assert a != c


def test_ambient_noise_and_hum_levels(tmp_path):
    """No beacons: the 17–23 kHz band holds the configured noise level, 100 Hz the hum at 1/r."""
    tank = Box("transformer", "steel", False, 20.0, 28.0, 0.0, 5.0, 5.5)
    site = _site([tank], beacons=())
    cfg = replace(AudioConfig(), corona_rate_hz=0.0, noise_db_spl=40.0, device_noise_dbfs=-160.0, hum_db_spl_1m=75.0)
    render_audio(site, _static(16.0, 2.5, 4.0), 3, tmp_path / "n.wav", cfg)     # 4 m from the tank
    x, _ = sf.read(tmp_path / "n.wav", dtype="int16")
    spec = np.fft.rfft(x / 32767.0)
    f = np.fft.rfftfreq(len(x), 1.0 / FS)
    power = 2.0 * np.abs(spec) ** 2 / len(x) ** 2                 # mean-square per bin (one-sided)

    def level_db(mask):
        return cfg.full_scale_db_spl + 10 * math.log10(power[mask].sum() * 2.0)   # full-scale sine ↔ FS dB

    assert level_db((f >= 17_000) & (f <= 23_000)) == pytest.approx(40.0, abs=0.5)
    assert level_db((f > 98) & (f < 102)) == pytest.approx(75.0 - 20 * math.log10(4.0), abs=0.5)


def test_device_noise_floor_reproduces_the_measured_phone_floor(tmp_path):
    """With the floor set to the UltraSense phone figure, the WAV shows −63 dB re. full scale² in the bands
    measured on the real files (17–19.5 and 20.5–22 kHz), and the default (−85 dB) stays below the ambient."""
    cfg = replace(AudioConfig(), noise_db_spl=-40.0, hum_db_spl_1m=-200.0, corona_rate_hz=0.0,
                  device_noise_dbfs=-63.0)
    render_audio(_site(beacons=()), _static(5.0, 5.0, 4.0), 8, tmp_path / "n.wav", cfg)
    x, _ = sf.read(tmp_path / "n.wav", dtype="int16")
    f, psd = welch(x / 32768.0, FS, nperseg=4096)
    band = (f > 17_000) & (f < 19_500) | (f > 20_500) & (f < 22_000)
    assert 10 * math.log10(psd[band].mean() * 6000.0) == pytest.approx(-63.0, abs=0.3)
    assert cfg.inband_noise_db_spl == pytest.approx(110.0 - 63.0 + 10 * math.log10(2.0), abs=0.01)
    default = AudioConfig()
    assert default.inband_noise_db_spl == pytest.approx(10 * math.log10(10 ** 3.5 + 10 ** 2.8), abs=0.01)


def _one_source(rate_hz=10.0, level=(60.0, 0.0), phase0=0.7):
    from simulation.acoustic.discharge import DischargeConfig, DischargeSources

    tank = Box("transformer", "steel", False, 20.0, 28.0, 0.0, 5.0, 5.5)     # 8 m long: one candidate source
    site = replace(_site([tank], beacons=()), seed=3)
    return DischargeSources(site, DischargeConfig(rate_hz=rate_hz, active_share=1.0, level_db_spl=level), FS,
                            phase0, 343.0)


def _pulses(src, seconds, rx, floor=-1e9, seed=0):
    rng = np.random.default_rng(seed)
    chunk = 16384
    out = np.zeros(int(seconds * FS) + 64)
    n = 0
    for i in range(0, int(seconds * FS), chunk):
        seg = np.zeros(chunk + 64)
        n += src.add_pulses(seg, rng, i / FS, (i + chunk) / FS, FS, rx, 110.0, floor)
        out[i: i + chunk + 64] += seg[: len(out) - i]
    return out, n


def test_discharge_pulses_come_at_the_rate_in_the_phase_windows():
    """One active source on a transformer's top: Poisson pulses at 10/s (60 s: 600 ± 4·√600), each emitted
    within ±30° of a voltage peak (90° or 270° of the 50 Hz phase; IEC 60270's phase windows), found again
    from the rendered samples by their arrival less the travel time."""
    src = _one_source()
    assert src.sources.shape == (1, 3) and src.sources[0, 2] == 5.5
    rx = src.sources[0] + np.array([0.0, -3.0, -4.5])               # 5.4 m away, at the tank's side
    out, n = _pulses(src, 60.0, rx)
    assert abs(n - 600) <= 4 * math.sqrt(600)
    d = float(np.linalg.norm(src.sources[0] - rx))
    # Each pulse's start: where the envelope first exceeds half of its 64-sample neighbourhood's peak.
    env = np.abs(out)
    starts = np.flatnonzero((env > 0.2 * env.max()) & (np.r_[0.0, env[:-1]] <= 0.2 * env.max()))
    starts = starts[np.r_[True, np.diff(starts) > 64]]
    phase = np.degrees((2 * np.pi * 50.0 * (starts / FS - d / 343.0) + 0.7) % (2 * np.pi))
    off_peak = np.minimum(np.abs(phase - 90.0), np.abs(phase - 270.0))
    assert len(starts) > 100 and np.percentile(off_peak, 98) <= 31.0
    assert np.mean(off_peak) == pytest.approx(15.0, abs=3.0)             # uniform within ±30°: mean 15°


def test_discharge_pulse_level_follows_spreading_and_absorption():
    """A pulse of 60 dB (17–23 kHz peak, re. 20 µPa at 1 m) heard 5.4 m away: its in-band envelope peaks at
    60 − 20·log10(5.4) − α(20 kHz)·5.4 dB, i.e. 10^((L − 113)/20) full-scale units (full-scale sine = 110 dB
    rms), within 0.3 dB (the ±2 of 16 fractional delays tabulated)."""
    src = _one_source(rate_hz=1.0)
    rx = src.sources[0] + np.array([0.0, -3.0, -4.5])
    out, n = _pulses(src, 20.0, rx, seed=2)
    d = float(np.linalg.norm(src.sources[0] - rx))
    alpha = float(absorption_db_per_m(20_000.0, Atmosphere()))
    want_db = 60.0 - 20 * math.log10(d) - alpha * d
    spec = np.fft.rfft(out)
    f = np.fft.rfftfreq(len(out), 1 / FS)
    spec[(f < 17_000) | (f > 23_000)] = 0
    env = np.abs(hilbert(np.fft.irfft(spec, len(out))))
    peaks = [env[i - 50: i + 50].max() for i in np.flatnonzero((env[1:-1] > env[:-2]) & (env[1:-1] >= env[2:])
                                                                & (env[1:-1] > 0.5 * env.max())) + 1]
    assert n >= 10 and len(peaks) >= 10
    got_db = 113.0 + 20 * np.log10(np.median(peaks))
    assert got_db == pytest.approx(want_db, abs=0.3)


def test_discharge_pulse_spectrum_is_the_derivative_of_a_double_exponential():
    """The template's closed-form spectrum against the pulse sampled in time at 20 MHz: p(t) = d/dt[e^(−t/τd) −
    e^(−t/τr)], |P(20 kHz)| / |P(10 kHz)| agree within 1 % (a sign or τ mix-up in the formula changes it)."""
    from simulation.acoustic.discharge import pulse_template

    tr, td, fs_hi = 2e-6, 15e-6, 20e6
    t = np.arange(int(0.01 * fs_hi)) / fs_hi
    p = np.gradient(np.exp(-t / td) - np.exp(-t / tr), 1 / fs_hi)
    spec = np.abs(np.fft.rfft(p))
    f = np.fft.rfftfreq(len(p), 1 / fs_hi)
    ratio_time = np.interp(20_000, f, spec) / np.interp(10_000, f, spec)

    def closed(fq):
        w = 2 * np.pi * fq
        return abs(1j * w * (td / (1 + 1j * w * td) - tr / (1 + 1j * w * tr)))

    assert ratio_time == pytest.approx(closed(20_000) / closed(10_000), rel=0.01)
    h = pulse_template(FS, tr, td)
    assert h.shape == (64,) and 6 <= int(np.argmax(np.abs(h))) <= 8       # starts at its 6th sample


def test_doppler_of_a_walker_closing_on_a_beacon(tmp_path):
    site = _site(beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),))
    t = np.arange(0.0, 2.0 + 1e-9, 0.01)
    traj = Trajectory(t_s=t, east_m=20.0 - 1.5 * t, north_m=np.zeros_like(t), up_m=np.ones_like(t),
                      heading_rad=np.full_like(t, -np.pi / 2), speed_m_s=np.full_like(t, 1.5), start_utc=START,
                      rate_hz=100.0)
    res = render_audio(site, traj, 1, tmp_path / "d.wav", QUIET)
    rows = _truth(res)
    c = 343.21
    for r in rows:
        e = float(r["rx_east_m"])
        cos_ = e / math.hypot(e, 2.0)                           # closing speed = 1.5·cos(elevation)
        assert float(r["doppler"]) == pytest.approx(1.0 + 1.5 * cos_ / c, abs=1e-5)
        # position at arrival time, not at emission
        assert e == pytest.approx(20.0 - 1.5 * float(r["arrival_t_s"]), abs=2e-3)


def test_clipping_only_when_really_loud(tmp_path):
    site = _site(beacons=(Beacon(1, 0.0, 0.0, 1.2, 0),))
    ok = render_audio(site, _static(5.0, 0.0, 1.0), 1, tmp_path / "a.wav", QUIET)
    assert ok.n_clipped == 0
    loud = replace(site, acoustic=replace(site.acoustic, source_level_db=125.0))
    res = render_audio(loud, _static(0.3, 0.0, 1.0), 1, tmp_path / "b.wav", QUIET)
    x, _ = sf.read(tmp_path / "b.wav", dtype="int16")
    assert res.n_clipped > 0 and int(np.abs(x.astype(int)).max()) >= 32767


def test_writer_contract(tmp_path):
    out = tmp_path / "walk"
    out.mkdir()
    ctx = StreamContext(site=_site(), trajectory=_static(12.0, 14.0, 1.0), out_dir=out, seed=3, kind="survey",
                        options={"audio": {"start_uncertainty_s": 0.05}})
    meta = write_audio(ctx)
    assert meta == {"audio": {"file": "audio.wav", "fs_hz": 48000, "start_s": 0.0, "start_uncertainty_s": 0.05}}
    info = sf.info(out / "audio.wav")
    assert (info.samplerate, info.channels, info.subtype, info.frames) == (48000, 1, "PCM_16", 48000)
    header = (out / "audio_truth.csv").read_text().splitlines()[0]
    assert header.startswith("beacon_id,slot,emit_t_s,arrival_t_s,arrival_sample,first_path")
    assert sorted(p.name for p in out.iterdir()) == ["audio.wav", "audio_truth.csv"]     # no temp files left
    with pytest.raises(ConfigError, match="unknown key"):
        write_audio(replace(ctx, options={"audio": {"noise_dbspl": 3}}))
    with pytest.raises(ConfigError, match="block_samples"):
        AudioConfig(block_samples=20000)


def test_simulated_walk_carries_audio(tmp_path):
    """The lead's walk generator with this writer: walk.toml [audio] and a WAV of the walk's length."""
    layout = pytest.importorskip("simulation.site.layout")
    walk = pytest.importorskip("simulation.walk")
    site = layout.generate_site(2)
    save_site(site, tmp_path / "site.toml")
    out = walk.simulate_walk(tmp_path / "site.toml", tmp_path / "w", seed=4, duration_s=6.0,
                             writers=("simulation.acoustic.stream:write_audio",))
    meta = tomllib.loads((out / "walk.toml").read_text())
    assert meta["audio"]["file"] == "audio.wav" and meta["audio"]["fs_hz"] == 48000
    info = sf.info(out / "audio.wav")
    assert info.frames == pytest.approx(6.0 * FS, abs=FS * 0.02)
    rows = list(csv.DictReader((out / "audio_truth.csv").open()))
    assert len(rows) > 10


def test_atmosphere_changes_arrival_through_sound_speed(tmp_path):
    cold = replace(_site(), atmosphere=Atmosphere(-10.0, 60.0, 101.325))
    warm = replace(_site(), atmosphere=Atmosphere(30.0, 60.0, 101.325))
    a = _truth(render_audio(cold, _static(12.0, 14.0, 0.5), 1, tmp_path / "c.wav", QUIET))
    b = _truth(render_audio(warm, _static(12.0, 14.0, 0.5), 1, tmp_path / "w.wav", QUIET))
    da = float(a[0]["arrival_t_s"]) - float(a[0]["emit_t_s"])
    db = float(b[0]["arrival_t_s"]) - float(b[0]["emit_t_s"])
    assert da / db == pytest.approx(math.sqrt(303.15 / 263.15), rel=1e-6)


def test_per_beacon_band_and_schedule_in_the_recording(tmp_path):
    """A beacon with its own band (frequency division) transmits in that band; every frame of the
    schedule that can reach the recording is counted, one emission per beacon per frame."""
    fdma = Beacon(2, 15.0, 0.0, 3.0, 0, f0_hz=18_000.0, f1_hz=20_000.0, chirp_duration_s=0.02)
    site = _site(beacons=(fdma,))
    res = render_audio(site, _static(5.0, 5.0, 2.0), 2, tmp_path / "f.wav", QUIET)
    x, _ = sf.read(tmp_path / "f.wav", dtype="int16")
    f, psd = welch(x / 32768.0, FS, nperseg=4096)
    assert psd[(f > 18_100) & (f < 19_900)].sum() / psd.sum() > 0.95
    frame = site.acoustic.frame_s                       # 0.4 s; emissions from 0.5 s before the start
    assert res.n_emissions == pytest.approx((2.0 + 0.5) / frame, abs=1.0)
    rows = _truth(res)
    assert all(0.0 <= float(r["arrival_sample"]) < res.n_samples for r in rows)   # rows: arrivals inside the file
    assert len(rows) == 5                               # 2 s of 0.4 s frames, 17 ms of flight
    emits = sorted(float(r["emit_t_s"]) for r in rows)
    assert np.diff(emits) == pytest.approx(np.full(len(emits) - 1, frame), abs=1e-9)


def test_wall_reflection_in_the_wav_at_image_source_delay_and_level(tmp_path):
    """A concrete wall: the matched filter shows the image-source echo at (L_refl − d)/c after the
    direct peak, at the level R·(d/L_refl) × the band-weighted absorption difference."""
    from simulation.acoustic.channel import ChannelConfig
    wall = Box("firewall", "concrete", False, 10.0, 10.4, -20.0, 20.0, 9.0)
    site = _site([wall], beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),))
    cfg = replace(QUIET, channel=ChannelConfig(clutter_radius_m=0.1))      # faint, short tail only
    res = render_audio(site, _static(5.0, 5.0, 1.2), 3, tmp_path / "w.wav", cfg)
    mf = _matched_filter(tmp_path / "w.wav", site)
    d = math.dist((0.0, 0.0, 3.0), (5.0, 5.0, 1.0))
    l_refl = math.dist((20.0, 0.0, 3.0), (5.0, 5.0, 1.0))
    lag = (l_refl - d) / 343.2146 * FS
    spec = beacon_chirp(site, site.beacons[0])
    c_f = np.abs(np.fft.rfft(reference_chirp(spec, FS), 8192)) ** 2
    alpha = absorption_db_per_m(np.fft.rfftfreq(8192, 1.0 / FS), site.atmosphere)

    def peak(length, gain):
        return gain * (c_f * 10.0 ** (-alpha * length / 20.0)).sum()

    want_db = 20 * math.log10(peak(l_refl, math.sqrt(0.95) / l_refl) / peak(d, 1.0 / d))
    rows = _truth(res)
    assert len(rows) >= 2
    for r in rows:
        s0 = float(r["arrival_sample"])
        i_dir = int(np.argmax(mf[int(s0) - 20:int(s0) + 20])) + int(s0) - 20
        i_ref = int(np.argmax(mf[int(s0 + lag) - 20:int(s0 + lag) + 20])) + int(s0 + lag) - 20
        assert abs(i_ref - (s0 + lag)) <= 1.0
        assert 20 * math.log10(mf[i_ref] / mf[i_dir]) == pytest.approx(want_db, abs=0.5)


def test_diffracted_arrival_in_the_wav_with_maekawa_loss(tmp_path):
    """Behind a wall: the only arrival is the over-the-top path, at its detour delay, weaker than the
    free field by Maekawa's frequency-dependent loss 10·log10(3 + 20N(f)) averaged by the matched filter."""
    from simulation.acoustic.channel import ChannelConfig
    from simulation.acoustic.atmosphere import maekawa_loss_db
    wall = Box("firewall", "concrete", False, 10.0, 10.4, -30.0, 30.0, 3.4)
    site = _site([wall], beacons=(Beacon(1, 0.0, 0.0, 3.0, 0),))
    rx = (20.0, 0.0, 1.0)
    cfg = replace(QUIET, channel=ChannelConfig(tail_offset_db=-100.0))
    res = render_audio(site, _static(rx[0], rx[1], 1.2), 3, tmp_path / "d.wav", cfg)
    free = replace(site, layout=())
    res_free = render_audio(free, _static(rx[0], rx[1], 1.2), 3, tmp_path / "f.wav", cfg)
    rows, rows_free = _truth(res), _truth(res_free)
    assert rows and all(r["first_path"] == "diffraction" for r in rows)
    d = math.dist((0.0, 0.0, 3.0), rx)
    over = math.hypot(10.0, 0.4) + 0.4 + math.hypot(9.6, 2.4)       # taut string over the wall top
    assert float(rows[0]["first_path_m"]) == pytest.approx(over, abs=1e-3)
    mf, mf_free = _matched_filter(tmp_path / "d.wav", site), _matched_filter(tmp_path / "f.wav", free)
    spec = beacon_chirp(site, site.beacons[0])
    f = np.fft.rfftfreq(8192, 1.0 / FS)
    c_f = np.abs(np.fft.rfft(reference_chirp(spec, FS), 8192)) ** 2
    alpha = absorption_db_per_m(f, site.atmosphere)
    loss = maekawa_loss_db(2.0 * (over - d) * f / 343.2146)
    want_db = 20 * math.log10((c_f * 10 ** (-(alpha * over + loss) / 20)).sum() / (c_f * 10 ** (-alpha * d / 20)).sum())
    s, s_free = float(rows[0]["arrival_sample"]), float(rows_free[0]["arrival_sample"])
    i = int(np.argmax(mf[int(s) - 20:int(s) + 20])) + int(s) - 20
    i_free = int(np.argmax(mf_free[int(s_free) - 20:int(s_free) + 20])) + int(s_free) - 20
    assert abs(i - s) <= 1.0
    assert s - s_free == pytest.approx((over - d) / 343.2146 * FS, abs=0.01)   # same seed, same clock
    assert 20 * math.log10(mf[i] / mf_free[i_free]) == pytest.approx(want_db, abs=0.5)
    assert want_db < -20.0
