"""site.toml schema: round trip, validation messages, walk.toml reading."""

import math

import pytest

from features.errors import ConfigError
from features.fileio import atomic_directory, atomic_write_text
from features.site import Beacon, Box, Origin, Site, load_site, save_site, site_from_dict
from features.walk import load_walk


def _site(**kw):
    base = dict(name="t", origin=Origin(31.0, 118.0, 10.0),
                beacons=(Beacon(1, 0.0, 0.0, 2.5, 0), Beacon(2, 30.0, 0.0, 2.5, 1)),
                layout=(Box("transformer", "steel", False, 10, 18, 10, 15, 5.5),))
    base.update(kw)
    return Site(**base)


def test_round_trip(tmp_path):
    site = _site()
    save_site(site, tmp_path / "site.toml")
    assert load_site(tmp_path) == site
    assert load_site(tmp_path / "site.toml").acoustic.frame_s == pytest.approx(0.8)


@pytest.mark.parametrize("text,needle", [
    ("name = 't'\n", "missing [origin]"),
    ("name = 't'\n[origin]\nlat_deg = 95\nlon_deg = 1\n", "lat_deg must lie in [-90, 90], got 95"),
    ("name = 't'\n[origin]\nlat_deg = 1\nlon_deg = 1\n[[beacons]]\nid = 1\neast_m = 0\nnorth_m = 0\nup_m = 2\nslot = 9\n",
     "slot 9 >= acoustic.n_slots 8"),
    ("name = 't'\n[origin]\nlat_deg = 1\nlon_deg = 1\ncolour = 'red'\n", "unknown key(s) ['colour']"),
    ("name = 't'\n[origin\n", "malformed TOML"),
    ("name = 't'\n[origin]\nlat_deg = 1\nlon_deg = 1\n[[layout]]\nkind = 'castle'\nmaterial='x'\nporous=false\n"
     "east_min_m=0\neast_max_m=1\nnorth_min_m=0\nnorth_max_m=1\nheight_m=1\n", "layout kind must be one of"),
    ("name = 't'\n[origin]\nlat_deg = 1\nlon_deg = 1\n[acoustic]\nf0_hz = 23000\nf1_hz = 17000\n", "acoustic band"),
])
def test_bad_site_files_name_the_problem(tmp_path, text, needle):
    (tmp_path / "site.toml").write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_site(tmp_path)
    assert needle in str(exc.value)
    assert str(tmp_path / "site.toml") in str(exc.value)


def test_missing_file_is_config_error(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_site(tmp_path / "nope.toml")


def test_non_finite_rejected():
    with pytest.raises(ConfigError, match="finite"):
        site_from_dict({"name": "t", "origin": {"lat_deg": math.nan, "lon_deg": 0.0}})


def test_atomic_directory_keeps_old_on_failure(tmp_path):
    out = tmp_path / "out"
    with atomic_directory(out) as d:
        (d / "a.txt").write_text("first")
    with pytest.raises(RuntimeError):
        with atomic_directory(out, overwrite=True) as d:
            (d / "a.txt").write_text("second")
            raise RuntimeError("interrupted")
    assert (out / "a.txt").read_text() == "first"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no temporary left behind


def test_atomic_write_replaces_whole_file(tmp_path):
    p = tmp_path / "x.txt"
    atomic_write_text(p, "abc")
    atomic_write_text(p, "d")
    assert p.read_text() == "d"


def test_walk_toml_reading(tmp_path):
    (tmp_path / "walk.toml").write_text('name = "w"\nstart_utc = "2026-06-01T00:00:00Z"\nduration_s = 5.0\n'
                                        'site = "../s/site.toml"\n[gnss]\nfile = "gnss.nmea"\nrate_hz = 5.0\n')
    (tmp_path / "gnss.nmea").write_text("")
    w = load_walk(tmp_path)
    assert w.start_utc.hour == 0 and w.duration_s == 5.0
    assert w.path("gnss") == tmp_path / "gnss.nmea"
    assert w.path("audio") is None
    (tmp_path / "walk.toml").write_text('name = "w"\n[gnss]\nfile = "gnss.nmea"\n')
    with pytest.raises(ConfigError, match=r"missing start_utc \(needed by its \[gnss\] stream\)"):
        load_walk(tmp_path)
    # a walk without NMEA or audio (a drive whose files state relative times only) may leave it out
    (tmp_path / "walk.toml").write_text('name = "w"\n[odometry]\nfile = "odometry.csv"\n')
    assert load_walk(tmp_path).start_utc is None


def test_outputs_get_ordinary_permissions(tmp_path):
    import os
    import stat
    mask = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "f.txt", "x")
        with atomic_directory(tmp_path / "d") as d:
            (d / "a").write_text("y")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "f.txt").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755
