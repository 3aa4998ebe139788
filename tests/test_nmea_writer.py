"""NMEA writer: checksums, pynmea2 parsing, GGA/GSA/GSV consistency, round trip through the reader."""

from datetime import datetime, timezone

import numpy as np
import pynmea2
import pytest

from features.gnss.nmea import read_nmea
from features.site import Box, Origin, Site
from simulation.gnss.stream import simulate_gnss, to_nmea_epochs
from simulation.gnss.nmea_writer import NmeaEpochs, format_nmea, nmea_checksum
from simulation.site.route import static_trajectory

START = datetime(2026, 5, 1, 23, 59, 58, tzinfo=timezone.utc)  # crosses midnight: the date must roll over


@pytest.fixture(scope="module")
def site():
    wall = Box("firewall", "concrete", False, 10.0, 10.4, -20.0, 20.0, 10.0)
    bld = Box("building", "concrete", False, -20.0, -2.0, -20.0, 20.0, 8.0)
    return Site("nmea-test", Origin(35.0, 115.0, 50.0), layout=(wall, bld))


@pytest.fixture(scope="module")
def sim_and_text(site):
    traj = static_trajectory(9.0, 0.0, 1.0, 6.0, START)
    sim = simulate_gnss(site, traj, seed=7)
    return sim, format_nmea(to_nmea_epochs(sim, site, 7, traj))


def _sentences(text):
    return [pynmea2.parse(line, check=True) for line in text.split("\r\n") if line]


def test_crlf_checksums_and_pynmea2(sim_and_text):
    _, text = sim_and_text
    assert text.endswith("\r\n") and "\n" not in text.replace("\r\n", "")
    lines = text.split("\r\n")[:-1]
    for line in lines:
        body, cs = line[1:].split("*")
        assert line[0] == "$" and cs == nmea_checksum(body)
    msgs = _sentences(text)
    assert len(msgs) == len(lines)
    kinds = {type(m).__name__ for m in msgs}
    assert kinds == {"RMC", "GGA", "GSA", "GSV"}


def test_checksum_of_a_real_receiver_line():
    # From gpsd's ZED-F9P log (../shared/data/nmea/gpsd/ublox-zed-f9p-nmea.log).
    line = "$GNGGA,003956.00,4552.65403,S,17030.00668,E,1,12,0.64,14.2,M,1.8,M,,*56"
    assert nmea_checksum(line[1:-3]) == "56"


def _per_epoch(msgs):
    """Group sentences per epoch (each epoch starts with RMC)."""
    epochs = []
    for m in msgs:
        if m.sentence_type == "RMC":
            epochs.append([])
        epochs[-1].append(m)
    return epochs


def test_counts_agree_between_gga_gsa_gsv_and_the_simulation(sim_and_text):
    sim, text = sim_and_text
    epochs = _per_epoch(_sentences(text))
    assert len(epochs) == len(sim.t_s) == 31
    for i, ep in enumerate(epochs):
        gga = [m for m in ep if m.sentence_type == "GGA"][0]
        gsa = [m for m in ep if m.sentence_type == "GSA"]
        listed = [getattr(g, f"sv_id{j:02d}") for g in gsa for j in range(1, 13)]
        listed = [p for p in listed if p]
        assert int(gga.num_sats) == len(listed) == int(sim.n_used[i])
        assert {g.data[-1] for g in gsa} == {"1", "4"}  # NMEA 4.10 system ids
        for talker, system in (("GP", "GPS"), ("GB", "BDS")):
            gsv = [m for m in ep if m.sentence_type == "GSV" and m.talker == talker]
            n_view = int(sim.in_view[i, sim.system == system].sum())
            assert all(int(m.num_sv_in_view) == n_view for m in gsv)
            assert int(gsv[0].num_messages) == len(gsv) == max(1, -(-n_view // 4))
            assert [int(m.msg_num) for m in gsv] == list(range(1, len(gsv) + 1))
            # Every in-view satellite is listed once; untracked ones with an empty SNR.
            assert all(len(m.data[3:]) % 4 == 1 and m.data[-1] == "1" for m in gsv)  # groups + signal id
            raw = [x for m in gsv for x in m.data[3:-1]]
            groups = [raw[j:j + 4] for j in range(0, len(raw), 4)]
            assert len(groups) == n_view
            cols = np.flatnonzero(sim.in_view[i] & (sim.system == system))
            for (prn, _el, _az, snr), c in zip(groups, cols[np.argsort(sim.prn[cols])]):
                assert int(prn) == sim.prn[c]
                assert (snr == "") == (not sim.tracked[i, c])
                if snr:
                    assert int(snr) == sim.cn0_reported_dbhz[i, c]
    # The capture crosses midnight: the RMC date advances by exactly one day, once, at 00:00:00
    # (issue 12 item 26: this checked only that there were two dates).
    rmc = [(m.datestamp, m.timestamp) for m in _sentences(text) if m.sentence_type == "RMC"]
    assert rmc[0][0] == START.date()
    changes = [k for k in range(1, len(rmc)) if rmc[k][0] != rmc[k - 1][0]]
    assert len(changes) == 1
    k = changes[0]
    assert (rmc[k][0] - rmc[k - 1][0]).days == 1
    assert rmc[k][1].hour == 0 and rmc[k][1].minute == 0 and rmc[k][1].second == 0
    assert rmc[k - 1][1].hour == 23 and rmc[k - 1][1].minute == 59


def test_heavy_site_lists_untracked_satellites(sim_and_text):
    sim, text = sim_and_text
    empty = sum(1 for m in _sentences(text) if m.sentence_type == "GSV"
                for j in (1, 2, 3, 4) if getattr(m, f"sv_prn_num_{j}", "") and getattr(m, f"elevation_deg_{j}", "")
                and not getattr(m, f"snr_{j}", ""))
    assert empty == int((sim.in_view & ~sim.tracked).sum()) > 0


def test_round_trip_through_the_reader(sim_and_text, tmp_path, site):
    sim, text = sim_and_text
    path = tmp_path / "gnss.nmea"
    path.write_bytes(text.encode("ascii"))
    epochs = read_nmea(path)
    epochs = epochs[0] if isinstance(epochs, tuple) else epochs
    assert len(epochs) == len(sim.t_s)
    o = site.origin
    for i, ep in enumerate(epochs):
        assert ep.fix.quality == sim.quality[i]
        assert ep.n_in_view == int(sim.in_view[i].sum())
        assert ep.n_tracked == int(sim.tracked[i].sum())
        if sim.quality[i] > 0:
            import pymap3d
            e, n, u = pymap3d.geodetic2enu(ep.fix.lat_deg, ep.fix.lon_deg, ep.fix.alt_m + ep.fix.geoid_sep_m,
                                           o.lat_deg, o.lon_deg, o.alt_m)
            assert np.allclose([e, n, u], sim.fix_enu_m[i], atol=2e-3)
            assert ep.fix.hdop == pytest.approx(round(float(sim.hdop[i]), 2))


def _hand_epochs(quality, lat=(-33.8568, 51.5), lon=(151.2153, -0.1276)):
    n = len(quality)
    k = 3
    el = np.array([[45.0, 10.0, 80.0]] * n)
    return NmeaEpochs(
        unix_s=np.array([1_700_000_000.0 + 0.2 * i for i in range(n)]), lat_deg=np.array(lat[:n]),
        lon_deg=np.array(lon[:n]), alt_m=np.full(n, 12.345), quality=np.array(quality),
        hdop=np.full(n, 0.9), vdop=np.full(n, 1.2), pdop=np.full(n, 1.5), speed_m_s=np.full(n, 1.0),
        course_deg=np.array([90.0, np.nan][:n]), sat_system=np.array([1, 1, 4]), sat_prn=np.array([7, 30, 59]),
        el_deg=el, az_deg=np.array([[10.0, 359.6, 200.0]] * n), in_view=np.ones((n, k), bool),
        used=np.array([[True, False, True]] * n), snr_dbhz=np.array([[45.0, np.nan, 38.0]] * n))


def test_hand_built_epochs_parse_back_exactly():
    text = format_nmea(_hand_epochs([4, 0], lat=(-33.8568, np.nan), lon=(151.2153, np.nan)))
    msgs = _sentences(text)
    rmc, gga = msgs[0], msgs[1]
    assert gga.latitude == pytest.approx(-33.8568, abs=1e-9) and gga.longitude == pytest.approx(151.2153, abs=1e-9)
    assert gga.gps_qual == 4 and gga.num_sats == "02" and gga.altitude == pytest.approx(12.345)
    assert gga.age_gps_data == "1.0" and rmc.mode_indicator == "R" and rmc.status == "A"
    assert float(rmc.spd_over_grnd) == pytest.approx(1.0 * 3600 / 1852, abs=1e-3)
    gsv = [m for m in msgs[:8] if m.sentence_type == "GSV"]
    assert gsv[0].sv_prn_num_2 == "30" and gsv[0].azimuth_2 == "000" and gsv[0].snr_2 == ""
    # The second epoch has no fix: empty position, quality 0, GSA mode 1 with no PRNs.
    second = _per_epoch(msgs)[1]
    gga2 = [m for m in second if m.sentence_type == "GGA"][0]
    assert gga2.gps_qual == 0 and gga2.lat == "" and gga2.num_sats == "00"
    assert all(m.mode_fix_type == "1" and not m.sv_id01 for m in second if m.sentence_type == "GSA")
    assert [m for m in second if m.sentence_type == "RMC"][0].status == "V"


def test_more_than_twelve_used_in_one_system_splits_gsa():
    n, k = 1, 14
    ep = NmeaEpochs(
        unix_s=np.array([1_700_000_000.0]), lat_deg=np.array([30.0]), lon_deg=np.array([110.0]),
        alt_m=np.array([5.0]), quality=np.array([2]), hdop=np.array([0.6]), vdop=np.array([0.9]),
        pdop=np.array([1.1]), speed_m_s=np.zeros(1), course_deg=np.array([np.nan]),
        sat_system=np.full(k, 4), sat_prn=np.arange(19, 19 + k), el_deg=np.full((n, k), 40.0),
        az_deg=np.full((n, k), 100.0), in_view=np.ones((n, k), bool), used=np.ones((n, k), bool),
        snr_dbhz=np.full((n, k), 44.0))
    msgs = _sentences(format_nmea(ep))
    gsa = [m for m in msgs if m.sentence_type == "GSA"]
    assert len(gsa) == 2 and sum(bool(getattr(g, f"sv_id{j:02d}")) for g in gsa for j in range(1, 13)) == 14
    assert int([m for m in msgs if m.sentence_type == "GGA"][0].num_sats) == 14


def test_inconsistent_shapes_are_refused():
    good = _hand_epochs([1, 1])
    with pytest.raises(ValueError, match="el_deg"):
        NmeaEpochs(**{**good.__dict__, "el_deg": good.el_deg[:, :2]})
    with pytest.raises(ValueError, match="used satellite must be in view"):
        NmeaEpochs(**{**good.__dict__, "in_view": np.zeros_like(good.in_view)})
