"""NMEA 0183 v4.10 sentences as a GPS + BeiDou receiver writes them (RMC, GGA, GSA, GSV).

Per epoch, in the order a u-blox receiver emits them:

* ``$GNRMC`` — time, status, position, speed (knots), course, date, mode
  indicator (N/A/D/R/F) and navigational status (4.10).
* ``$GNGGA`` — time, position, fix quality (0/1/2/4/5), satellites used, HDOP,
  altitude, geoid separation, age of corrections and station id.
* ``$GNGSA`` — one or more per system (system id 1 = GPS, 4 = BeiDou, the
  4.10 trailing field), at most 12 satellites each; the PRNs are each system's
  own numbers. The GGA count equals the number of PRNs listed in all GSA lines.
* ``$GNGST`` (when the receiver model sends it) — RMS of the residuals, the
  horizontal error ellipse and σ of latitude, longitude and altitude
  (:mod:`simulation.gnss.gst`), empty fields without a fix.
* ``$GPGSV`` / ``$GBGSV`` — satellites in view, four per sentence, with the
  signal id field (1 = GPS L1 C/A, 1 = BeiDou B1I); tracked satellites carry
  their C/N0 in dB-Hz, in-view untracked ones an empty SNR field.

Latitude and longitude carry 7 decimals of minutes (≈ 0.2 mm) as
high-precision RTK receivers write them, so centimetre errors survive.
Checksums (XOR of the characters between ``$`` and ``*``) are computed for all
lines at once with numpy; lines end with CRLF.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

__all__ = ["NmeaEpochs", "format_nmea", "nmea_checksum", "NMEA_SYSTEM_GPS", "NMEA_SYSTEM_BDS"]

NMEA_SYSTEM_GPS = 1
NMEA_SYSTEM_BDS = 4
_TALKER = {NMEA_SYSTEM_GPS: "GP", NMEA_SYSTEM_BDS: "GB"}
_SIGNAL_ID = {NMEA_SYSTEM_GPS: "1", NMEA_SYSTEM_BDS: "1"}
_RMC_MODE = {0: "N", 1: "A", 2: "D", 4: "R", 5: "F"}
_MS_TO_KNOTS = 3600.0 / 1852.0


@dataclass(frozen=True, eq=False)
class NmeaEpochs:
    """What the receiver reports, per epoch (n) and satellite (k).

    unix_s : (n,) UTC POSIX seconds of each epoch
    lat_deg, lon_deg, alt_m : (n,) fix position, WGS-84 (alt above the geoid); NaN without a fix
    quality : (n,) int GGA fix quality (0, 1, 2, 4, 5)
    hdop, vdop, pdop : (n,)
    speed_m_s, course_deg : (n,) speed over ground and course (from north, clockwise); course NaN = empty
    sat_system : (k,) NMEA system id (1 GPS, 4 BeiDou); sat_prn : (k,) the system's own number
    el_deg, az_deg : (n, k); in_view, used : (n, k) bool
    snr_dbhz : (n, k) reported C/N0, NaN where untracked
    gst : (n, 7) GST fields 2–8 (rms, semi-major, semi-minor, orientation deg, σ lat, σ lon, σ alt; metres), or
        None when the receiver sends no GST
    """

    unix_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    quality: np.ndarray
    hdop: np.ndarray
    vdop: np.ndarray
    pdop: np.ndarray
    speed_m_s: np.ndarray
    course_deg: np.ndarray
    sat_system: np.ndarray
    sat_prn: np.ndarray
    el_deg: np.ndarray
    az_deg: np.ndarray
    in_view: np.ndarray
    used: np.ndarray
    snr_dbhz: np.ndarray
    geoid_sep_m: float = 0.0
    diff_age_s: float = 1.0
    station_id: int = 0
    gst: np.ndarray | None = None

    def __post_init__(self):
        n = len(self.unix_s)
        k = len(self.sat_prn)
        for name in ("lat_deg", "lon_deg", "alt_m", "quality", "hdop", "vdop", "pdop", "speed_m_s", "course_deg"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"NmeaEpochs.{name} has shape {np.shape(getattr(self, name))}, expected ({n},)")
        for name in ("el_deg", "az_deg", "in_view", "used", "snr_dbhz"):
            if np.shape(getattr(self, name)) != (n, k):
                raise ValueError(f"NmeaEpochs.{name} has shape {np.shape(getattr(self, name))}, expected ({n}, {k})")
        if self.gst is not None and np.shape(self.gst) != (n, 7):
            raise ValueError(f"NmeaEpochs.gst has shape {np.shape(self.gst)}, expected ({n}, 7)")
        if np.any(self.used & ~self.in_view):
            raise ValueError("NmeaEpochs: a used satellite must be in view")
        if not set(np.unique(self.sat_system)) <= set(_TALKER):
            raise ValueError(f"NmeaEpochs.sat_system must hold ids {sorted(_TALKER)}")


def nmea_checksum(body: str) -> str:
    """Two-hex-digit XOR checksum of the characters between ``$`` and ``*``.

    >>> nmea_checksum("GNGSA,A,3,13,16,21,15,10,29,27,20,,,,,1.05,0.64,0.83,1")
    '03'
    """
    x = 0
    for b in body.encode("ascii"):
        x ^= b
    return f"{x:02X}"


def _lat_field(lat: float) -> tuple[str, str]:
    mins = round(abs(lat) * 60.0, 7)
    d = int(mins // 60.0)
    return f"{d:02d}{mins - 60.0 * d:010.7f}", ("N" if lat >= 0 else "S")


def _lon_field(lon: float) -> tuple[str, str]:
    mins = round(abs(lon) * 60.0, 7)
    d = int(mins // 60.0)
    return f"{d:03d}{mins - 60.0 * d:010.7f}", ("E" if lon >= 0 else "W")


def _dop(x: float) -> str:
    return "" if x != x else f"{min(x, 99.99):.2f}"


def _time_fields(unix_s: np.ndarray) -> tuple[list[str], list[str]]:
    """UTC ``hhmmss.ss`` and ``ddmmyy`` strings per epoch."""
    cs = np.round(np.asarray(unix_s, float) * 100.0).astype(np.int64)
    day = cs // 8_640_000
    hh, rem = np.divmod(cs - day * 8_640_000, 360_000)
    mm, rem = np.divmod(rem, 6000)
    ss, cc = np.divmod(rem, 100)
    times = [f"{a:02d}{b:02d}{c:02d}.{d:02d}" for a, b, c, d in zip(hh.tolist(), mm.tolist(), ss.tolist(), cc.tolist())]
    day_str = {d: datetime.fromtimestamp(d * 86400, tz=timezone.utc).strftime("%d%m%y") for d in np.unique(day).tolist()}
    return times, [day_str[d] for d in day.tolist()]


def _gsv_groups(ep: NmeaEpochs, prn_str: list[str]) -> tuple[list[str], np.ndarray]:
    """The ``,prn,el,az,snr`` group of every (epoch, satellite), each distinct one formatted once.

    Returns (groups, index (n, k) into groups).
    """
    el_i = np.clip(np.rint(ep.el_deg), 0, 90).astype(np.int64)
    az_i = np.mod(np.rint(ep.az_deg), 360).astype(np.int64)
    snr_i = np.where(np.isfinite(ep.snr_dbhz), np.clip(np.rint(np.nan_to_num(ep.snr_dbhz)), 0, 99), -1).astype(np.int64)
    code = ((np.arange(len(prn_str))[None, :] * 91 + el_i) * 360 + az_i) * 101 + (snr_i + 1)
    uniq, inv = np.unique(code, return_inverse=True)
    snr_tab = [f"{v:02d}" for v in range(100)] + [""]  # index −1 → empty
    groups = [f",{prn_str[c]},{e:02d},{a:03d},{snr_tab[q]}" for c, e, a, q in zip(
        (uniq // (101 * 360 * 91)).tolist(), ((uniq // (101 * 360)) % 91).tolist(),
        ((uniq // 101) % 360).tolist(), (uniq % 101 - 1).tolist())]
    return groups, inv.reshape(code.shape)


def format_nmea(ep: NmeaEpochs) -> str:
    """All sentences of all epochs as one string with CRLF line ends (see the module docstring)."""
    n = len(ep.unix_s)
    times, dates = _time_fields(ep.unix_s)
    prn_str = [f"{p:02d}" for p in np.asarray(ep.sat_prn, int).tolist()]
    groups, gidx = _gsv_groups(ep, prn_str)
    quality = np.asarray(ep.quality, int)
    has_fix = (quality > 0) & np.isfinite(ep.lat_deg) & np.isfinite(ep.lon_deg)
    fix_l = has_fix.tolist()
    q_l = np.where(has_fix, quality, 0).tolist()
    lat = np.where(has_fix, ep.lat_deg, 0.0).tolist()
    lon = np.where(has_fix, ep.lon_deg, 0.0).tolist()
    alt = np.where(has_fix, ep.alt_m, 0.0).tolist()
    spd = (np.nan_to_num(ep.speed_m_s) * _MS_TO_KNOTS).tolist()
    crs = ep.course_deg.tolist()
    hdop, vdop, pdop = ep.hdop.tolist(), ep.vdop.tolist(), ep.pdop.tolist()
    n_used = np.where(has_fix, ep.used.sum(axis=1), 0).tolist()
    systems = [s for s in (NMEA_SYSTEM_GPS, NMEA_SYSTEM_BDS) if np.any(ep.sat_system == s)]
    sys_cols = {s: np.flatnonzero(ep.sat_system == s) for s in systems}
    sys_cols = {s: c[np.argsort(np.asarray(ep.sat_prn)[c], kind="stable")] for s, c in sys_cols.items()}
    sep = f"{ep.geoid_sep_m:.1f}"
    age = f"{ep.diff_age_s:.1f}"
    sid = f"{ep.station_id:04d}"
    empty12 = [""] * 12
    gst_text = _gst_bodies(ep.gst, times, has_fix) if ep.gst is not None else None
    bodies: list[str] = []
    add = bodies.append
    for i in range(n):
        t = times[i]
        if fix_l[i]:
            q = q_l[i]
            la, ns = _lat_field(lat[i])
            lo, ew = _lon_field(lon[i])
            c = crs[i]
            add(f"GNRMC,{t},A,{la},{ns},{lo},{ew},{spd[i]:.3f},{'' if c != c else f'{c:.2f}'},{dates[i]},,,"
                f"{_RMC_MODE.get(q, 'A')},V")
            diff = q in (2, 4, 5)
            add(f"GNGGA,{t},{la},{ns},{lo},{ew},{q},{n_used[i]:02d},{_dop(hdop[i])},{alt[i]:.3f},M,{sep},M,"
                f"{age if diff else ''},{sid if diff else ''}")
            tail = f"{_dop(pdop[i])},{_dop(hdop[i])},{_dop(vdop[i])}"
            used_i = ep.used[i]
            for s in systems:
                cols = sys_cols[s]
                prns = [prn_str[c] for c in cols[used_i[cols]].tolist()]
                for j0 in range(0, max(1, len(prns)), 12):
                    chunk = prns[j0:j0 + 12]
                    add(f"GNGSA,A,3,{','.join(chunk + empty12[len(chunk):])},{tail},{s}")
            if gst_text is not None:
                add(gst_text[i])
        else:
            add(f"GNRMC,{t},V,,,,,,,{dates[i]},,,N,V")
            add(f"GNGGA,{t},,,,,0,00,,,,,,,")
            for s in systems:
                add(f"GNGSA,A,1,,,,,,,,,,,,,,,,{s}")
            if gst_text is not None:
                add(gst_text[i])
        g_r, view_r = gidx[i], ep.in_view[i]
        for s in systems:
            cols = sys_cols[s]
            grp = [groups[g] for g in g_r[cols[view_r[cols]]].tolist()]
            n_view = len(grp)
            n_msg = max(1, -(-n_view // 4))
            head = f"{_TALKER[s]}GSV,{n_msg},"
            tail_sig = _SIGNAL_ID[s]
            for mnum in range(n_msg):
                add(f"{head}{mnum + 1},{n_view:02d}{''.join(grp[4 * mnum:4 * mnum + 4])},{tail_sig}")
    return _finish(bodies)


def _gst_bodies(gst: np.ndarray, times: list[str], has_fix: np.ndarray) -> list[str]:
    """``GNGST`` bodies per epoch: 3 decimals of metres, orientation 1 decimal; empty fields without a fix."""
    out = []
    for t, row, f in zip(times, np.asarray(gst, float).tolist(), has_fix.tolist()):
        if not f or not all(v == v for v in row):
            out.append(f"GNGST,{t},,,,,,,")
            continue
        rms, smaj, smin, orient, s_lat, s_lon, s_alt = row
        out.append(f"GNGST,{t},{rms:.3f},{smaj:.3f},{smin:.3f},{orient:.1f},{s_lat:.3f},{s_lon:.3f},{s_alt:.3f}")
    return out


def _finish(bodies: list[str]) -> str:
    """Add ``$``, ``*hh`` and CRLF to every body; checksums by XOR-reduce over each line's bytes."""
    if not bodies:
        return ""
    joined = ("\n".join(bodies) + "\n").encode("ascii")
    buf = np.frombuffer(joined, np.uint8)
    lengths = np.fromiter((len(b) + 1 for b in bodies), np.int64, len(bodies))
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    # Each segment holds one trailing "\n" (0x0A); XOR it out again.
    sums = np.bitwise_xor.reduceat(buf, starts) ^ 0x0A
    hexes = [f"{v:02X}" for v in range(256)]
    return "".join(f"${b}*{hexes[c]}\r\n" for b, c in zip(bodies, sums.tolist()))
