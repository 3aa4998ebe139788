"""GNSS fixes → site ENU with σ from quality and HDOP."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from features.errors import DataError
from features.gnss.positions import ASSUMED_HDOP, UERE_BY_QUALITY_M, fixes_to_enu, sigma_axis_m
from features.gnss.nmea import Epoch, Fix, read_nmea

DATA = Path(__file__).resolve().parent / "data"


def _epoch(t_s, lat, lon, alt, quality, hdop=1.0, sep=0.0, vdop=None):
    return Epoch(t_s, None, t_s, Fix(lat, lon, alt, sep, quality, 8, hdop, None, vdop, 3), (), False)


def test_origin_maps_to_zero_and_offsets_match_pymap3d():
    lat0, lon0, h0 = 30.0, 120.0, 20.0
    epochs = [_epoch(0.0, lat0, lon0, 15.0, 4, sep=5.0),  # MSL 15 + geoid 5 = ellipsoidal 20
              _epoch(1.0, lat0 + 0.001, lon0 + 0.002, 25.0, 1, sep=5.0)]
    pos = fixes_to_enu(epochs, lat0, lon0, h0)
    assert np.allclose([pos.east_m[0], pos.north_m[0], pos.up_m[0]], 0.0, atol=1e-6)
    e, n, u = pymap3d.geodetic2enu(lat0 + 0.001, lon0 + 0.002, 30.0, lat0, lon0, h0)
    assert (pos.east_m[1], pos.north_m[1], pos.up_m[1]) == pytest.approx((e, n, u), abs=1e-6)
    assert pos.north_m[1] == pytest.approx(110.8, abs=0.3)  # 0.001° of latitude near 30° N
    assert pos.up_m[1] == pytest.approx(10.0, abs=0.01)


def test_sigma_table_and_rows_without_measurement():
    epochs = [_epoch(float(q), 30.0, 120.0, 0.0, q, hdop=1.6, vdop=2.0) for q in range(10)]
    pos = fixes_to_enu(epochs, 30.0, 120.0, 0.0)
    # no fix (0), manual (7) and simulator (8) are not measurements
    assert pos.quality.tolist() == [1, 2, 3, 4, 5, 6, 9]
    for q, s_en, s_up in zip(pos.quality, pos.sigma_en_m, pos.sigma_up_m):
        assert s_en == pytest.approx(UERE_BY_QUALITY_M[q] * 1.6 / math.sqrt(2))
        assert s_up == pytest.approx(UERE_BY_QUALITY_M[q] * 2.0)
    order = dict(zip(pos.quality.tolist(), pos.sigma_en_m.tolist()))
    assert order[4] < order[5] < order[2] < order[1] < order[6]  # RTK fixed < float < DGNSS < SPS < DR
    assert sigma_axis_m(4, 1.0) == pytest.approx(0.0212, abs=1e-4)  # "RTK fixed ≈ 0.02 m·HDOP"


def test_missing_hdop_is_assumed_and_flagged():
    pos = fixes_to_enu([_epoch(0.0, 30.0, 120.0, 0.0, 2, hdop=None)], 30.0, 120.0, 0.0)
    assert pos.hdop_assumed.tolist() == [True] and pos.hdop[0] == ASSUMED_HDOP
    assert pos.sigma_up_m[0] == pytest.approx(1.0 * 1.5 * ASSUMED_HDOP)


def test_real_file_positions_and_no_fix_file():
    epochs, _ = read_nmea(DATA / "good.nmea")
    pos = fixes_to_enu(epochs, 30.0, 120.0, 20.0)
    assert len(pos) == 2 and pos.quality.tolist() == [2, 2]
    # σ = UERE·HDOP·g/√2 with the SIGMA-ε factor g² = mean 10^(aᵢ/10) of the five used satellites,
    # aᵢ = C_ref(elᵢ) − C/N0ᵢ, C_ref = 38 dB-Hz at 5° to 50 at zenith, linear in sin(el) (worked here).
    b = 12.0 / (1.0 - math.sin(math.radians(5.0)))
    cref = lambda el: 38.0 + b * (math.sin(math.radians(el)) - math.sin(math.radians(5.0)))
    used = [(45.0, 44.0), (30.0, 40.0), (60.0, 48.0), (50.0, 41.0), (20.0, 33.0)]
    g = math.sqrt(np.mean([10 ** (max(0.0, cref(el) - c) / 10) for el, c in used]))
    assert g == pytest.approx(1.769, abs=1e-3)
    assert pos.sigma_en_m[0] == pytest.approx(1.0 * 1.2 * g / math.sqrt(2))   # was 0.849 before the factor
    assert pos.sigma_source.tolist() == ["cn0", "cn0"]
    assert pos.up_m[0] == pytest.approx(0.0, abs=1e-6)  # 15 m MSL + 5 m geoid = 20 m ellipsoidal
    epochs, _ = read_nmea(DATA / "no_fix.nmea")
    assert len(fixes_to_enu(epochs, 30.0, 120.0, 0.0)) == 0


def test_bad_origin_is_rejected():
    with pytest.raises(DataError):
        fixes_to_enu([], float("nan"), 0.0, 0.0)
