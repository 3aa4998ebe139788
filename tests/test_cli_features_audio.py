"""``envfuse features audio``: outputs, flags for bad recordings, clean errors, real phone audio."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from features.acoustic.features import FEATURE_COLUMNS
from features.acoustic.positions import POSITION_COLUMNS
from features.fileio import write_toml
from features.site import save_site
from pipeline.cli import main
from tests.acoustic_synth import add_chirp, square_site, static_capture, write_wav
from tests.conftest import SHARED_DATA

ULTRASENSE = SHARED_DATA / "audio_ultrasense"


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture()
def site_path(tmp_path):
    site = square_site(5, slot_s=0.1, n_slots=8)
    save_site(site, tmp_path / "site.toml")
    return tmp_path / "site.toml"


def _walk(tmp_path, start_s=0.0, u=0.02, start_utc="2026-06-01T08:00:00Z"):
    write_toml(tmp_path / "walk.toml", {"name": "t", "start_utc": start_utc, "duration_s": 6.0,
                                        "audio": {"file": "audio.wav", "fs_hz": 48000, "start_s": start_s,
                                                  "start_uncertainty_s": u}})
    return tmp_path / "walk.toml"


def test_features_and_positions(tmp_path, site_path, capsys):
    from features.site import load_site
    site = load_site(site_path)
    # 08:00:00Z is a whole number of 0.8 s frames since 1970, so frames start at walk time 0.
    cap = static_capture(site, 31.0, 24.0, 6.0, clock_offset_s=0.006, seed=3, echoes=((0.003, 0.3),))
    write_wav(tmp_path / "audio.wav", cap.samples)
    walk = _walk(tmp_path)
    rc = main(["features", "audio", str(tmp_path / "audio.wav"), "--site", str(site_path), "--walk", str(walk),
               "--out", str(tmp_path / "f.csv"), "--positions", str(tmp_path / "p.csv")])
    assert rc == 0
    rows = _rows(tmp_path / "f.csv")
    assert list(rows[0]) == ["t_s", "time_utc", *FEATURE_COLUMNS[1:]]   # time_utc beside t_s (issue 12 item 19)
    assert [float(r["t_s"]) for r in rows] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert all(r["acoustic_available"] == "1" and r["flags"] == "" for r in rows)
    assert all(int(r["n_chirps"]) >= 8 for r in rows)
    # One strong echo 3 ms after each arrival at −10.5 dB: the mean excess delay is about
    # 0.3 ms and K about +10 dB, and no row is empty.
    excess = [float(r["mean_excess_delay_ms"]) for r in rows]
    assert all(0.1 < e < 0.6 for e in excess)
    assert all(5.0 < float(r["rician_k_db"]) < 14.0 for r in rows)
    pos = _rows(tmp_path / "p.csv")
    i = POSITION_COLUMNS.index("north_m") + 1
    assert list(pos[0]) == ["t_s", "time_utc", *POSITION_COLUMNS[1:i], "lat_deg", "lon_deg", "h_ell_m",
                            *POSITION_COLUMNS[i:]]
    assert len(pos) >= 5
    err = [math.hypot(float(p["east_m"]) - 31.0, float(p["north_m"]) - 24.0) for p in pos]
    assert np.median(err) < 0.05
    assert all(float(p["clock_offset_s"]) == pytest.approx(0.006, abs=3e-4) for p in pos)
    assert all(float(p["var_east_m2"]) > 0 and int(p["n_beacons"]) >= 3 for p in pos)
    assert "chirps detected" in capsys.readouterr().out


def test_silent_file_flags_every_window(tmp_path, site_path):
    sf.write(tmp_path / "s.wav", np.zeros(48_000 * 3, dtype=np.int16), 48_000, subtype="PCM_16")
    assert main(["features", "audio", str(tmp_path / "s.wav"), "--site", str(site_path),
                 "--out", str(tmp_path / "f.csv"), "--positions", str(tmp_path / "p.csv")]) == 0
    rows = _rows(tmp_path / "f.csv")
    assert len(rows) == 2
    assert all(r["flags"] == "no_chirp+silent" and r["rician_k_db"] == "" for r in rows)
    assert _rows(tmp_path / "p.csv") == []


def test_clipped_file_is_flagged_not_refused(tmp_path, site_path):
    from features.site import load_site
    cap = static_capture(load_site(site_path), 30.0, 30.0, 3.0, noise_rms=0.002, amplitude_at_1m=60.0)
    write_wav(tmp_path / "c.wav", cap.samples)       # 1/r amplitudes above full scale clip
    assert main(["features", "audio", str(tmp_path / "c.wav"), "--site", str(site_path),
                 "--out", str(tmp_path / "f.csv")]) == 0
    rows = _rows(tmp_path / "f.csv")
    assert all("clipped" in r["flags"] for r in rows)
    assert all(float(r["clipped_fraction"]) > 1e-3 for r in rows)


def test_truncated_file_flags_last_window(tmp_path, site_path, capsys):
    from features.site import load_site
    cap = static_capture(load_site(site_path), 30.0, 30.0, 4.0)
    write_wav(tmp_path / "a.wav", cap.samples)
    data = (tmp_path / "a.wav").read_bytes()
    (tmp_path / "t.wav").write_bytes(data[: int(len(data) * 0.8)])
    assert main(["features", "audio", str(tmp_path / "t.wav"), "--site", str(site_path),
                 "--out", str(tmp_path / "f.csv")]) == 0
    rows = _rows(tmp_path / "f.csv")
    assert rows[-1]["flags"].endswith("truncated")
    assert all("truncated" not in r["flags"] for r in rows[:-1])
    assert "truncated" in capsys.readouterr().err


def test_stereo_warns_and_uses_first_channel(tmp_path, site_path, capsys):
    from features.site import load_site
    cap = static_capture(load_site(site_path), 30.0, 30.0, 3.0)
    stereo = np.stack([cap.samples, np.zeros_like(cap.samples)], axis=1)
    sf.write(tmp_path / "st.wav", np.clip(stereo, -1, 0.99), 48_000, subtype="PCM_16")
    assert main(["features", "audio", str(tmp_path / "st.wav"), "--site", str(site_path),
                 "--out", str(tmp_path / "f.csv")]) == 0
    assert "2 channels, using the first" in capsys.readouterr().err
    assert all(r["acoustic_available"] == "1" for r in _rows(tmp_path / "f.csv"))


@pytest.mark.parametrize("content", [b"garbage" * 100, b""])
def test_unreadable_audio_is_one_clean_line(tmp_path, site_path, capsys, content):
    (tmp_path / "bad.wav").write_bytes(content)
    rc = main(["features", "audio", str(tmp_path / "bad.wav"), "--site", str(site_path),
               "--out", str(tmp_path / "f.csv")])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1 and err.startswith("envfuse: error:") and "Traceback" not in err
    assert not (tmp_path / "f.csv").exists()


def test_bad_arguments(tmp_path, site_path, capsys):
    assert main(["features", "audio", str(tmp_path / "none.wav"), "--site", str(site_path),
                 "--out", str(tmp_path / "f.csv")]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert main(["features", "audio", "x.wav", "--site", str(site_path), "--out", "f.csv", "--hop-s", "-1"]) == 2
    capsys.readouterr()
    assert main(["features", "audio", "x.wav", "--site", str(tmp_path / "nosite.toml"), "--out", "f.csv"]) == 1
    assert capsys.readouterr().err.startswith("envfuse: error:")


# --- real phone recordings: jkarolus/UltraSense (GPL-2.0), Samsung Galaxy S3, 44.1 kHz, 20 kHz tone ---

def _ultrasense_files():
    if not ULTRASENSE.is_dir():
        pytest.skip(f"real audio not found at {ULTRASENSE} (../shared/data/audio_ultrasense)")
    files = sorted(ULTRASENSE.glob("*.wav"))
    assert len(files) == 5
    return files


def test_real_phone_audio_reports_no_chirp(tmp_path, site_path, capsys):
    """A 20 kHz tone with hand/body Doppler, no chirps: the 44.1 kHz path resamples with a warning
    and every window says no chirp — no exception."""
    for f in _ultrasense_files():
        rc = main(["features", "audio", str(f), "--site", str(site_path), "--out", str(tmp_path / "f.csv"),
                   "--positions", str(tmp_path / "p.csv")])
        assert rc == 0
        err = capsys.readouterr().err
        assert "44100 Hz, resampling to 48000 Hz" in err
        rows = _rows(tmp_path / "f.csv")
        assert rows and all(r["acoustic_available"] == "0" and "no_chirp" in r["flags"] for r in rows)
        assert _rows(tmp_path / "p.csv") == []


def test_real_phone_audio_with_injected_chirps_is_detected(tmp_path, site_path):
    """The same recording with beacon chirps added at 44.1 kHz: now windows do report chirps, so the
    'no chirp' above is the detector's judgement, not a dead front end."""
    f = _ultrasense_files()[-1]
    x, fs = sf.read(f, dtype="float64")
    site = square_site(5)
    rms = float(np.std(x))
    for k in range(int(len(x) / fs / site.acoustic.frame_s)):
        for b in site.beacons:
            d = math.dist((30.0, 30.0, 1.0), (b.east_m, b.north_m, b.up_m))
            add_chirp(x, k * site.acoustic.frame_s + b.slot * site.acoustic.slot_s + d / 343.2, 3 * rms, fs_hz=fs)
    sf.write(tmp_path / "inj.wav", np.clip(x, -1, 0.99), fs, subtype="PCM_16")
    assert main(["features", "audio", str(tmp_path / "inj.wav"), "--site", str(site_path),
                 "--out", str(tmp_path / "f.csv")]) == 0
    rows = _rows(tmp_path / "f.csv")
    assert all(r["acoustic_available"] == "1" for r in rows)


def _tiny_site(tmp_path):
    from features.site import Beacon, Grid, Origin, Site, save_site
    site = Site(name="t", origin=Origin(31.0, 118.0), grid=Grid(5.0, 0.0, 40.0, 0.0, 40.0),
                beacons=(Beacon(1, 0.0, 0.0, 3.0, 0), Beacon(2, 30.0, 0.0, 3.0, 1)))
    save_site(site, tmp_path / "site.toml")
    return tmp_path / "site.toml"


@pytest.mark.parametrize("case,needle", [
    ("no_samples", "holds no audio samples"),
    ("fs_8k", "cannot carry the beacon band"),
    ("huge_uncertainty", "start_uncertainty_s must lie in [0, 2] s"),
    ("huge_start", "more than an hour outside the walk"),
    ("positions_unwritable", "cannot write /proc/p.csv"),
])
def test_unusable_audio_or_timing_refused_cleanly(tmp_path, capsys, case, needle):
    import soundfile as sf
    from pipeline.cli import main
    site = _tiny_site(tmp_path)
    wav = tmp_path / "a.wav"
    rng = np.random.default_rng(0)
    if case == "no_samples":
        sf.write(wav, np.zeros(0, np.int16), 48_000, subtype="PCM_16")
    elif case == "fs_8k":
        sf.write(wav, (rng.standard_normal(8_000) * 1000).astype(np.int16), 8_000, subtype="PCM_16")
    else:
        sf.write(wav, (rng.standard_normal(48_000) * 100).astype(np.int16), 48_000, subtype="PCM_16")
    audio = {"huge_uncertainty": "start_uncertainty_s = 1e9", "huge_start": "start_s = 1e300"}.get(case, "start_s = 0.0")
    (tmp_path / "walk.toml").write_text(f'start_utc = "2026-06-01T00:00:00Z"\nduration_s = 1.0\n'
                                        f'[audio]\nfile = "a.wav"\n{audio}\n')
    argv = ["features", "audio", str(wav), "--site", str(site), "--walk", str(tmp_path / "walk.toml"),
            "--out", str(tmp_path / "o.csv")]
    if case == "positions_unwritable":
        argv += ["--positions", "/proc/p.csv"]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 1 and needle in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o.csv").exists()  # all outputs or none
