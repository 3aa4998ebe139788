"""Issue 14 (pipeline speed), GNSS side: the vectorised paths give what the per-epoch loops gave.

``fixes_to_enu`` used to loop over epochs (one :func:`epoch_attenuation` each); it is vectorised
over :class:`SkyArrays` now. The loop form is kept here as the reference and both must agree on a
simulated walk and on every real receiver log.
"""

import math

import numpy as np
import pytest

from features.gnss.features import sky_arrays
from features.gnss.nmea import read_nmea
from features.gnss.positions import (ASSUMED_HDOP, UERE_BY_QUALITY_M, UereTable, epoch_attenuation, fixes_to_enu,
                                     sky_attenuation)
from features.geodesy import geodetic_to_enu
from tests.conftest import SHARED_DATA

GPSD = SHARED_DATA / "nmea" / "gpsd"
ORIGIN = (31.2, 118.8, 20.0)


def _loop_fixes_to_enu(epochs, lat0, lon0, alt0, uere=None):
    """The per-epoch loop fixes_to_enu was before it was vectorised (σ columns and ENU)."""
    rows = []
    for e in epochs:
        f = e.fix
        if not f.has_position or f.quality not in UERE_BY_QUALITY_M:
            continue
        assumed = f.hdop is None
        hdop = ASSUMED_HDOP if assumed else f.hdop
        att, g = epoch_attenuation(e)
        fitted = uere.lookup(f.quality, att) if uere is not None else None
        if fitted is not None:
            u = fitted
        elif f.quality == 4:
            u = UERE_BY_QUALITY_M[4]
        else:
            u = UERE_BY_QUALITY_M[f.quality] * g
        s = u * hdop / math.sqrt(2.0)
        up = u * (f.vdop if f.vdop is not None else 1.5 * hdop)
        g_st = e.gst   # issue 21: the receiver's own GST σ wins where the epoch carries it, a fitted cell over it
        if g_st is not None and g_st.sigma_lat_m is not None and g_st.sigma_lon_m is not None and fitted is None:
            s = max(g_st.sigma_lat_m, g_st.sigma_lon_m)
            up = g_st.sigma_alt_m if g_st.sigma_alt_m is not None else up
        alt = (f.alt_m or 0.0) + (f.geoid_sep_m or 0.0) if f.alt_m is not None else alt0
        rows.append((e.t_s, f.lat_deg, f.lon_deg, alt, s, up, att, hdop))
    c = np.array(rows, float).reshape(-1, 8)
    east, north, upm = geodetic_to_enu(c[:, 1], c[:, 2], c[:, 3], lat0, lon0, alt0)
    return c, np.asarray(east), np.asarray(north)


def _check(epochs, uere=None):
    ref, east, north = _loop_fixes_to_enu(epochs, *ORIGIN, uere=uere)
    pos = fixes_to_enu(epochs, *ORIGIN, uere=uere)
    assert len(pos) == len(ref)
    np.testing.assert_array_equal(pos.t_s, ref[:, 0])
    np.testing.assert_allclose(pos.east_m, east, rtol=0, atol=1e-9)
    np.testing.assert_allclose(pos.north_m, north, rtol=0, atol=1e-9)
    np.testing.assert_allclose(pos.sigma_en_m, ref[:, 4], rtol=1e-12)
    np.testing.assert_allclose(pos.sigma_up_m, ref[:, 5], rtol=1e-12)
    np.testing.assert_allclose(pos.attenuation_db, ref[:, 6], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(pos.hdop, ref[:, 7])
    return pos


def test_vectorised_positions_equal_the_loop_on_a_simulated_walk(walk_dir):
    import dataclasses

    epochs, _ = read_nmea(walk_dir / "gnss.nmea")
    # Issue 21: the simulated RTK receiver sends GST, so its fixes carry the receiver's own σ, a fitted table's
    # cells over it ...
    assert (_check(epochs).sigma_source == "gst").mean() > 0.9
    table = UereTable({4: (0.02, 0.02, 0.02, 0.02)}, {})
    both = _check(epochs, table)
    assert ((both.sigma_source == "fitted") == (both.quality == 4)).all()
    # ... and without GST (another receiver model) the C/N0 and fitted rules, as before.
    epochs = [dataclasses.replace(e, gst=None) for e in epochs]
    pos = _check(epochs)
    assert len(pos) > 250 and (pos.sigma_source == "cn0").any()
    table = UereTable({5: (0.3, 0.5, 0.8, 1.5), 2: (None, 1.0, 2.0, 3.0)}, {})
    fitted = _check(epochs, table)
    assert (fitted.sigma_source == "fitted").any()
    # the sky handed in by the caller gives the same as computing it here
    again = fixes_to_enu(epochs, *ORIGIN, sky=sky_arrays(epochs))
    np.testing.assert_array_equal(again.sigma_en_m, pos.sigma_en_m)


def test_vectorised_positions_equal_the_loop_on_real_logs():
    if not GPSD.is_dir():
        pytest.skip(f"real NMEA logs not found at {GPSD}")
    n = 0
    for log in sorted(GPSD.glob("*.log")):
        epochs, _ = read_nmea(log)
        n += len(_check(epochs))
    assert n > 500


def test_sky_attenuation_equals_epoch_attenuation_and_counts_the_invisible(walk_dir):
    epochs, _ = read_nmea(walk_dir / "gnss.nmea")
    sky = sky_arrays(epochs)
    att, g, zeta = sky_attenuation(sky)
    loop = np.array([epoch_attenuation(e) for e in epochs if e.sky_reported])
    np.testing.assert_allclose(att, loop[:, 0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(g, loop[:, 1], rtol=1e-12)
    # ζ of one epoch by hand: satellites at or above 10° in view, share without C/N0
    e = next(e for e in epochs if e.sky_reported)
    best = {}
    for s in _primary(e):
        if s.el_deg is not None and s.el_deg >= 10.0:
            best[(s.system, s.prn)] = best.get((s.system, s.prn), False) or s.cn0_dbhz is not None
    assert zeta[0] == pytest.approx(1.0 - sum(best.values()) / len(best))
    assert np.nanmax(zeta) > 0.0


# Primary signal per NMEA 0183 v4.11 signal ids, written out here as the reference (issue 20): GPS/SBAS
# L1 C/A 1, QZSS L1 C/A 1 / L1C 2, 3, GLONASS G1 C/A 1, Galileo E1-BC 7 / E1-A 6, BeiDou B1I 1 / B1C 3,
# NavIC L5-SPS 1 / L1-SPS 5 first, then an entry stating no signal (None, or 0 "all signals"); every
# other id is a secondary signal.
_PRIMARY_IDS = {"GPS": [1], "SBAS": [1], "QZSS": [1, 2, 3], "GLONASS": [1], "Galileo": [7, 6], "BeiDou": [1, 3],
                "NavIC": [1, 5]}


def _primary(e):
    """Per (system, prn) the listed entry on the most primary signal (secondary-only satellites left out)."""
    best = {}
    for s in e.satellites:
        if s.signal in (None, 0):
            rank = 10
        elif s.signal in _PRIMARY_IDS[s.system]:
            rank = _PRIMARY_IDS[s.system].index(s.signal)
        else:
            continue
        if (s.system, s.prn) not in best or rank < best[(s.system, s.prn)][0]:
            best[(s.system, s.prn)] = (rank, s)
    return [v[1] for v in best.values()]


def _loop_sky(epochs):
    """sky_arrays as it was, one satellite at a time (the reference of the vectorised form), reading each
    satellite on its primary signal."""
    sky = [e for e in epochs if e.sky_reported]
    index: dict = {}
    for e in sky:
        for s in _primary(e):
            index.setdefault((s.system, s.prn), len(index))
    shape = (len(sky), len(index))
    el, az, cn0 = np.full(shape, np.nan), np.full(shape, np.nan), np.full(shape, np.nan)
    view, used = np.zeros(shape, bool), np.zeros(shape, bool)
    for i, e in enumerate(sky):
        for s in _primary(e):
            j = index[(s.system, s.prn)]
            if s.cn0_dbhz is not None:
                cn0[i, j] = np.fmax(cn0[i, j], s.cn0_dbhz)
            if s.el_deg is not None:
                el[i, j] = s.el_deg
            if s.az_deg is not None:
                az[i, j] = s.az_deg
            view[i, j] = True
            used[i, j] |= s.used
    return tuple(index), el, az, cn0, view, used


def test_vectorised_sky_arrays_equal_the_loop(walk_dir):
    logs = [walk_dir / "gnss.nmea"] + (sorted(GPSD.glob("*.log")) if GPSD.is_dir() else [])
    for log in logs:
        epochs, _ = read_nmea(log)
        keys, *arrays = _loop_sky(epochs)
        sky = sky_arrays(epochs)
        assert sky.sat_keys == keys, log.name
        for got, want in zip((sky.el_deg, sky.az_deg, sky.cn0_dbhz, sky.in_view, sky.used), arrays):
            np.testing.assert_array_equal(got, want, err_msg=log.name)
