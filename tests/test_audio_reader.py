"""Audio reader: int16 scaling, resampling path, channels, truncation, clipping, bad files."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.signal
import soundfile as sf

from features.acoustic.audio import AudioWarning, audio_info, iter_audio_blocks, read_audio
from features.errors import AudioError


def test_int16_read_exactly(tmp_path):
    x = np.array([0, 1, -1, 32767, -32768, 1234], dtype=np.int16)
    sf.write(tmp_path / "a.wav", x, 48_000, subtype="PCM_16")
    y, info = read_audio(tmp_path / "a.wav")
    assert info.fs_hz == 48_000 and info.subtype == "PCM_16" and not info.truncated
    np.testing.assert_array_equal(y, x.astype(np.float32) / 32768)


def test_blocks_cover_the_file_once(tmp_path):
    x = (np.random.default_rng(0).normal(size=100_003) * 3000).astype(np.int16)
    sf.write(tmp_path / "a.wav", x, 48_000, subtype="PCM_16")
    blocks = list(iter_audio_blocks(tmp_path / "a.wav", block_s=0.5))
    assert [b.start_index for b in blocks] == [i * 24_000 for i in range(5)]
    np.testing.assert_array_equal(np.concatenate([b.samples for b in blocks]), x / np.float32(32768))


def test_44k1_is_resampled_with_a_warning_and_matches_one_shot(tmp_path):
    fs = 44_100
    t = np.arange(int(2.3 * fs)) / fs
    x = 0.5 * np.sin(2 * np.pi * 20_000 * t)
    sf.write(tmp_path / "tone.wav", x, fs, subtype="PCM_16")
    with pytest.warns(AudioWarning, match="44100 Hz, resampling to 48000"):
        blocks = list(iter_audio_blocks(tmp_path / "tone.wav", block_s=0.4))
    y = np.concatenate([b.samples for b in blocks])
    assert len(y) == int(np.ceil(len(x) * 48_000 / fs))
    x16 = sf.read(tmp_path / "tone.wav", dtype="int16")[0] / 32768
    ref = scipy.signal.resample_poly(x16, 160, 147)
    np.testing.assert_allclose(y[500:-500], ref[500:-500], atol=2e-5)    # blockwise = one shot
    f, p = scipy.signal.welch(y, fs=48_000, nperseg=4096)
    assert f[np.argmax(p)] == pytest.approx(20_000, abs=12)           # the tone stays at 20 kHz


def test_stereo_takes_first_channel(tmp_path):
    x = np.stack([np.full(1000, 1000), np.full(1000, -2000)], axis=1).astype(np.int16)
    sf.write(tmp_path / "st.wav", x, 48_000, subtype="PCM_16")
    with pytest.warns(AudioWarning, match="2 channels, using the first"):
        y, _ = read_audio(tmp_path / "st.wav")
    assert np.all(y == np.float32(1000 / 32768))


def test_truncated_file_is_read_and_reported(tmp_path):
    x = (np.random.default_rng(1).normal(size=48_000) * 1000).astype(np.int16)
    sf.write(tmp_path / "a.wav", x, 48_000, subtype="PCM_16")
    data = (tmp_path / "a.wav").read_bytes()
    (tmp_path / "cut.wav").write_bytes(data[: len(data) // 2 + 1])
    info = audio_info(tmp_path / "cut.wav")
    assert info.truncated and 23_000 < info.n_frames < 24_100
    with pytest.warns(AudioWarning, match="truncated"):
        y, _ = read_audio(tmp_path / "cut.wav")
    np.testing.assert_array_equal(y, x[: len(y)] / np.float32(32768))


def test_clipped_samples_are_counted(tmp_path):
    x = np.zeros(10_000, dtype=np.int16)
    x[::100] = 32767
    x[50::100] = -32768
    sf.write(tmp_path / "c.wav", x, 48_000, subtype="PCM_16")
    assert sum(b.n_clipped for b in iter_audio_blocks(tmp_path / "c.wav")) == 200


def test_float_wav(tmp_path):
    x = np.linspace(-0.5, 0.5, 1000, dtype=np.float32)
    sf.write(tmp_path / "f.wav", x, 48_000, subtype="FLOAT")
    y, info = read_audio(tmp_path / "f.wav")
    assert info.subtype == "FLOAT"
    np.testing.assert_array_equal(y, x)


@pytest.mark.parametrize("content", [b"", b"RIFF\x00\x00", b"not audio at all" * 20])
def test_unreadable_files_raise_audio_error(tmp_path, content):
    (tmp_path / "bad.wav").write_bytes(content)
    with pytest.raises(AudioError, match="cannot be read as audio"):
        audio_info(tmp_path / "bad.wav")


def test_missing_file(tmp_path):
    with pytest.raises(AudioError, match="does not exist"):
        audio_info(tmp_path / "nope.wav")


def test_no_warning_for_a_plain_48k_mono_file(tmp_path):
    sf.write(tmp_path / "a.wav", np.zeros(100, dtype=np.int16), 48_000, subtype="PCM_16")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_audio(tmp_path / "a.wav")


def test_non_finite_float_samples_become_silence_with_one_warning(tmp_path):
    import warnings as _w

    import soundfile as _sf

    from features.acoustic.audio import AudioWarning, iter_audio_blocks
    x = np.full(48_000 * 2, np.nan, np.float32)
    x[:100] = 0.1
    x[500] = np.inf
    _sf.write(tmp_path / "nan.wav", x, 48_000, subtype="FLOAT")
    with _w.catch_warnings(record=True) as caught:
        _w.simplefilter("always")
        blocks = list(iter_audio_blocks(tmp_path / "nan.wav", block_s=0.5))
    got = np.concatenate([b.samples for b in blocks])
    assert np.isfinite(got).all() and got[500] == 0.0 and got[50] == pytest.approx(0.1)
    assert sum(issubclass(w.category, AudioWarning) and "non-finite" in str(w.message) for w in caught) == 1


@pytest.mark.parametrize("subtype, dtype, scale", [("PCM_24", "int32", 2.0 ** -31), ("PCM_16", "int16", 2.0 ** -15)])
def test_stereo_blocks_from_the_reused_read_buffer(tmp_path, subtype, dtype, scale):
    """Blocks are fresh arrays (a later read into the shared buffer leaves them alone), first
    channel, scaled exactly as one mixed-type multiply would: int → float32, times 2^-31 or 2^-15."""
    x = (np.random.default_rng(2).normal(size=(50_001, 2)) * 0.2).clip(-1, 1)
    sf.write(tmp_path / "s.wav", x, 48_000, subtype=subtype)
    with pytest.warns(AudioWarning, match="2 channels"):
        blocks = list(iter_audio_blocks(tmp_path / "s.wav", block_s=0.25))
    assert [b.start_index for b in blocks] == [i * 12_000 for i in range(5)]
    ints = sf.read(tmp_path / "s.wav", dtype=dtype)[0][:, 0]
    expected = np.multiply(ints, np.float32(scale), dtype=np.float32)
    assert all(b.samples.dtype == np.float32 and b.samples.flags.c_contiguous for b in blocks)
    np.testing.assert_array_equal(np.concatenate([b.samples for b in blocks]), expected)


def test_int16_clip_count_equals_the_float_count(tmp_path):
    """int16 blocks count clipping on the integers; the count must equal count_clipped of the floats."""
    from features.acoustic.audio import count_clipped

    x = np.r_[np.arange(32_700, 32_768), np.arange(-32_768, -32_700), np.zeros(100)].astype(np.int16)
    sf.write(tmp_path / "c.wav", x, 48_000, subtype="PCM_16")
    (block,) = iter_audio_blocks(tmp_path / "c.wav")
    assert block.n_clipped == count_clipped(x / np.float32(32768)) == 2 * 32 + 1
