"""Issue 12, items 3 and 4: leading digital silence and frames shorter than the start uncertainty.

Item 4: three seconds of exact zeros before a recording pulled the noise-scale quantile to 0:
the first chirp after them read 2935 dB SNR, and the first noise after the silence passed
for a chirp (56 detections against 55). Now the silence is left out of the estimate:
57.8 dB, as without the silence, and no extra detection.

Item 3: one beacon 2 m away, 40 ms frames (a phone FMCW system), ±0.05 s stated start
uncertainty: 99 chirps gave 102 detections of only 50 distinct arrivals (one emission
counted in two frames, arrivals assigned to wrong frames). Now the uncertainty is clamped
to (frame − r_max/c)/2 with a warning: 99 detections, 99 distinct.
"""

from __future__ import annotations

import numpy as np
import pytest

from features.acoustic.audio import AudioWarning
from features.acoustic.detection import AudioTiming, DetectorConfig, detect_frames
from features.errors import ConfigError
from features.site import AcousticConfig, Beacon, Grid, Origin, Site
from tests.acoustic_synth import C_20C_M_S, add_chirp, square_site, static_capture, write_wav


def _detections(path, site, u=0.01, config=DetectorConfig()):
    return [d for fr in detect_frames(path, site, AudioTiming(0.0, u, 0.0), config) for d in fr.detections]


def test_leading_digital_silence_does_not_inflate_snr(tmp_path):
    site = square_site(5)
    x = static_capture(site, 20.0, 25.0, 12.0, noise_rms=0.002, seed=1).samples
    write_wav(tmp_path / "plain.wav", x)
    x = x.copy()
    x[: 3 * 48_000] = 0.0
    write_wav(tmp_path / "silent.wav", x)
    plain = _detections(tmp_path / "plain.wav", site)
    silent = _detections(tmp_path / "silent.wav", site)
    snr_plain = max(d.snr_db for d in plain)
    assert 50.0 < snr_plain < 65.0                                    # 57.8 dB measured
    assert max(d.snr_db for d in silent) == pytest.approx(snr_plain, abs=2.0)   # before: 2935 dB
    # Every detection after the silence is one of the plain recording's (no noise onset "chirp").
    plain_t = np.array([d.arrival_s for d in plain])
    late = [d for d in silent if d.arrival_s > 3.0]
    assert len(late) == sum(1 for t in plain_t if t > 3.0)
    assert all(np.min(np.abs(plain_t - d.arrival_s)) < 1e-4 for d in late)


def _fmcw_site(slot_s=0.04, chirp_s=0.010):
    return Site(name="fmcw", origin=Origin(31.0, 118.0), device_height_m=1.0,
                grid=Grid(cell_size_m=1.0, east_min_m=-3.0, east_max_m=3.0, north_min_m=-3.0, north_max_m=3.0),
                acoustic=AcousticConfig(slot_s=slot_s, n_slots=1, chirp_duration_s=chirp_s),
                beacons=(Beacon(id=1, east_m=2.0, north_m=0.0, up_m=1.0, slot=0),))


def test_one_chirp_is_never_counted_in_two_frames(tmp_path):
    site = _fmcw_site()
    rng = np.random.default_rng(0)
    x = rng.normal(0, 0.002, 48_000 * 4)
    for k in range(99):
        add_chirp(x, k * 0.04 + 2.0 / C_20C_M_S, 0.1)
    write_wav(tmp_path / "fmcw.wav", x)
    with pytest.warns(AudioWarning, match=r"clamped to ±0\.011"):
        dets = _detections(tmp_path / "fmcw.wav", site, u=0.05)
    arrivals = np.round([d.arrival_s for d in dets], 4)
    assert len(dets) == 99                                        # before: 102
    assert len(np.unique(arrivals)) == 99                         # before: 50 distinct
    frames = [d.frame for d in dets]
    assert len(set(frames)) == len(frames)                        # one chirp per frame


def test_frames_shorter_than_the_propagation_delay_are_refused(tmp_path):
    site = _fmcw_site(slot_s=0.012, chirp_s=0.005)                 # 12 ms frames, 5.8 m = 17 ms
    write_wav(tmp_path / "x.wav", np.zeros(4800))
    with pytest.raises(ConfigError, match="shorter than the longest propagation delay"):
        _detections(tmp_path / "x.wav", site)
