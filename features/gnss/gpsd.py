"""Epochs as gpsd's own JSON (TPV and SKY objects, one per line), so gpsd's tools read what envfuse read.

Field names and units follow gpsd's JSON protocol (``gpsd_json(5)``): TPV
``mode`` (1 no fix, 2 2-D, 3 3-D), ``status`` (1 GPS, 2 DGPS, 3 RTK fixed,
4 RTK float, 5 dead reckoning), ``time`` (ISO 8601 UTC, milliseconds),
``lat``/``lon`` (degrees), ``altMSL``, ``altHAE`` (ellipsoidal) and
``geoidSep`` (m); SKY ``hdop``/``pdop``/``vdop``, ``nSat``, ``uSat`` and per
satellite ``PRN``, ``gnssid``, ``svid``, ``el``, ``az``, ``ss`` (C/N0, dB-Hz,
absent when not tracked) and ``used``. PRNs use gpsd's numbering (the same as
in gpsd's test logs ``*.log.chk``): GPS 1-32, SBAS svid−87, Galileo 300+svid,
BeiDou 400+svid, QZSS 192+svid, GLONASS 64+svid.
"""

from __future__ import annotations

import json

__all__ = ["GNSS_IDS", "gpsd_prn", "epoch_to_gpsd", "gpsd_json_lines", "iso_utc_ms"]

GNSS_IDS = {"GPS": 0, "SBAS": 1, "Galileo": 2, "BeiDou": 3, "QZSS": 5, "GLONASS": 6, "NavIC": 7}
"""gpsd's (u-blox's) gnssid per system."""

_STATUS_FROM_QUALITY = {1: 1, 2: 2, 3: 1, 4: 3, 5: 4, 6: 5, 7: 1, 8: 1}


def iso_utc_ms(when) -> str | None:
    """ISO 8601 UTC with exactly three decimals, ``Z``-suffixed (None → None).

    >>> import datetime as dt
    >>> iso_utc_ms(dt.datetime(2024, 6, 15, 12, 0, 0, 500000, tzinfo=dt.timezone.utc))
    '2024-06-15T12:00:00.500Z'
    """
    if when is None:
        return None
    return f"{when.year:04d}-" + when.strftime("%m-%dT%H:%M:%S.") + f"{when.microsecond // 1000:03d}Z"


def gpsd_prn(system: str, svid: int) -> int:
    """gpsd's PRN for a satellite (system, number as envfuse reads it).

    >>> gpsd_prn("BeiDou", 3), gpsd_prn("Galileo", 2), gpsd_prn("GLONASS", 1), gpsd_prn("SBAS", 123)
    (403, 302, 65, 36)
    """
    if system == "Galileo":
        return 300 + svid
    if system == "BeiDou":
        return 400 + svid
    if system == "GLONASS":
        return svid + 64 if svid < 65 else svid
    if system == "QZSS":
        return svid + 192 if svid < 193 else svid
    if system == "SBAS":
        return svid - 87 if svid >= 120 else svid
    return svid


def _svid(system: str, prn: int) -> int:
    if system == "GLONASS" and prn >= 65:
        return prn - 64
    if system == "QZSS" and prn >= 193:
        return prn - 192
    return prn


def epoch_to_gpsd(epoch) -> list[dict]:
    """One epoch as gpsd objects: a TPV, and a SKY when the epoch reported its sky."""
    f = epoch.fix
    if f.has_position:
        mode = f.mode if f.mode in (2, 3) else (3 if f.alt_m is not None else 2)
    else:
        mode = 1
    tpv = {"class": "TPV", "device": "envfuse", "mode": mode}
    time = iso_utc_ms(epoch.time_utc)
    if time is not None:
        tpv["time"] = time
    if f.has_position:
        tpv["status"] = _STATUS_FROM_QUALITY.get(f.quality, 1)
        tpv["lat"] = round(f.lat_deg, 9)
        tpv["lon"] = round(f.lon_deg, 9)
        if f.alt_m is not None:
            tpv["altMSL"] = round(f.alt_m, 4)
            tpv["altHAE"] = round(f.alt_m + (f.geoid_sep_m or 0.0), 4)
        if f.geoid_sep_m is not None:
            tpv["geoidSep"] = round(f.geoid_sep_m, 3)
    out = [tpv]
    if epoch.sky_reported:
        sky = {"class": "SKY", "device": "envfuse"}
        if time is not None:
            sky["time"] = time
        for key, value in (("hdop", f.hdop), ("pdop", f.pdop), ("vdop", f.vdop)):
            if value is not None:
                sky[key] = value
        sats = []
        for s in epoch.satellites:
            svid = _svid(s.system, s.prn)
            sat = {"PRN": gpsd_prn(s.system, svid), "gnssid": GNSS_IDS.get(s.system, 0), "svid": svid}
            if s.az_deg is not None:
                sat["az"] = float(s.az_deg)
            if s.el_deg is not None:
                sat["el"] = float(s.el_deg)
            if s.cn0_dbhz is not None:
                sat["ss"] = float(s.cn0_dbhz)
            sat["used"] = bool(s.used)
            sats.append(sat)
        sky["nSat"] = len(sats)
        sky["uSat"] = sum(s["used"] for s in sats)
        sky["satellites"] = sats
        out.append(sky)
    return out


def gpsd_json_lines(epochs) -> str:
    """Every epoch's TPV (and SKY) as JSON lines, compact as gpsd writes them."""
    return "".join(json.dumps(obj, separators=(",", ":")) + "\n" for e in epochs for obj in epoch_to_gpsd(e))
