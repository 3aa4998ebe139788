"""Receiver fixes → site ENU positions with a measurement standard deviation, for the fusion filter.

The ellipsoidal height is GGA's altitude above mean sea level plus its geoid
separation (NMEA 0183 GGA fields 9 and 11; when the separation is empty the
altitude is taken as ellipsoidal, as receivers without a geoid model report
it); ENU about the site origin via :mod:`features.geodesy` (pymap3d).

Standard deviation per horizontal axis, σ = UERE(quality) · HDOP / √2, from
the classic error model σ_position = UERE · DOP (Kaplan & Hegarty,
*Understanding GPS*, 2nd ed. 2006, ch. 7), the horizontal error split
equally between east and north. The UERE per fix mode are order-of-magnitude
values of typical error budgets and receiver datasheets, chosen here, not
measured: they only seed the fusion filter, whose per-class measurement
noise is learnt from training walks (docs/design.md §7).

=======  ==========================  ============  =========================================
quality  mode (GGA field 6)          UERE (1σ)     reasoning
=======  ==========================  ============  =========================================
1        autonomous (SPS)            4.0 m         single-frequency code, broadcast
                                                   ionosphere: metres
2, 9     DGNSS / SBAS                1.0 m         code corrections from a nearby base or
                                                   SBAS remove most common-mode error
3        PPS                         2.8 m         as autonomous, dual-frequency ionosphere
4        RTK fixed                   0.03 m        carrier phase, integer ambiguities:
                                                   datasheets quote ≈ 1 cm + 1 ppm
5        RTK float                   0.4 m         float ambiguities: decimetres
6        dead reckoning              15 m          estimated, not measured: weak update
=======  ==========================  ============  =========================================

so σ_axis = UERE·HDOP/√2 (e.g. RTK fixed ≈ 0.02 m·HDOP, DGNSS ≈ 0.7 m·HDOP).

**What the epoch shows.** The table cannot see NLOS: on simulated walks with
truth (6,004 fixes) the mean NEES was 0.49 / 12.8 / 119 in open / light /
heavy, RTK float 4.2 / 47 / 128. Each fix's σ is therefore scaled, in order
of preference, by:

1. **GST** (NMEA 0183 GST, "GNSS pseudorange error statistics": the
   receiver's own 1σ latitude and longitude errors from its residuals) when the
   receiver sends it for that epoch: σ_east, σ_north = GST's σ_lon, σ_lat, and
   σ_up = GST's σ_alt when given. The epoch reader keeps each epoch's GST
   (:attr:`features.gnss.nmea.Epoch.gst`), so every reader of fixes gets it;
   a ``gst`` table from :func:`read_gst` (matched by UTC time of day) overrides
   it. GST is what the receiver believes: under NLOS it is too small (issue 21),
   which is why the fusion's quality noise scales it, and why a fitted table
   (3.) wins over it where it holds the fix's cell;
2. otherwise the **C/N0 of the used satellites**: the SIGMA-ε variance model
   (Hartinger & Brunner 1999, "Variances of GPS phase observations: the
   SIGMA-ε model", GPS Solutions 2(4); Wieser & Brunner 2000) gives each
   satellite σᵢ² ∝ 10^(−C/N0ᵢ/10), so relative to open sky
   σᵢ²/σ²_open = 10^(aᵢ/10) with aᵢ = max(0, C_ref(elᵢ) − C/N0ᵢ) the
   attenuation of the GNSS features (:class:`features.gnss.features.Cn0Reference`).
   With equal geometry weights the position variance scales by the mean,
   g² = mean ᵢ 10^(aᵢ/10), and σ_axis = UERE·HDOP·g/√2 (not for RTK fixed,
   whose carrier-phase error the code's C/N0 does not describe: table only);
3. a **fitted table** (:class:`UereTable`, :func:`fit_uere`, ``envfuse features
   gnss --fit-uere``) replaces 1–2 for the fix modes (and attenuation bins) it holds: UERE per fix
   quality and per bin of the used satellites' mean attenuation, fitted from
   walks with truth as UERE² = mean(|e|²/HDOP²) (the maximum-likelihood
   estimate for a 2-D Gaussian error with per-axis σ = UERE·HDOP/√2, so the
   fitted fixes have mean NEES 2 by construction).

The epoch's invisible ratio ζ (in-view-but-untracked share above the mask,
``GnssPositions.invisible_ratio``) was tried as a further factor, variance ×
(1 + c_q·ζ) with c_q per quality fitted on site seeds 1–4, and left out: on
held-out walks (site seeds 41/52/63, 9 walks of 300 s, 13,500 fixes;
``bench/bench_gnss_sigma.py``) it pushed RTK float open/heavy and DGNSS heavy
far below NEES 2 (DGNSS heavy 0.22 → 0.01) while mending RTK float light
(3.3 → 1.1–2.1): the mean |ln(NEES/2)| over the quality × class cells went
1.04 → 1.45 (c_q by the cells' criterion) or 1.63 (by maximum likelihood). The
SIGMA-ε factor already sees most of what ζ shows (weak satellites are lost
first). GST's rms residual (field 2) adds nothing where GST's own σ_lat/σ_lon
are used.
Known limit of the built-in model: on walks without corrections (SPS, 3
held-out walks, 4,503 fixes) the SIGMA-ε factor over-inflates the code
solution (mean NEES 0.19 / 0.28 / 0.21 heavy / light / open, against 2.5 /
1.2 / 0.74 for the table alone), as it does DGNSS heavy (0.22): the 4 m / 1 m
UEREs already budget some multipath. A fitted table replaces it where it has
the cell.
Vertical: σ_up = UERE·VDOP when VDOP is known, else UERE·1.5·HDOP (VDOP ≈
1.5 HDOP for typical open-sky geometry). When HDOP is missing, 2.0 is assumed
(a middling geometry) and the row is flagged ``hdop_assumed``. Qualities 0
(no fix), 7 (manual input) and 8 (simulator) produce no row: they are not
measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from features.errors import DataError
from features.geodesy import geodetic_to_enu

__all__ = ["UERE_BY_QUALITY_M", "ASSUMED_HDOP", "GnssPositions", "fixes_to_enu", "sigma_axis_m", "UereTable",
           "fit_uere", "epoch_attenuation", "sky_attenuation", "read_gst", "ATTENUATION_BIN_EDGES_DB"]

ATTENUATION_BIN_EDGES_DB = (2.0, 4.0, 7.0)
"""Bins of the used satellites' mean attenuation (dB) of a fitted :class:`UereTable`: <2, 2–4, 4–7, ≥7."""

UERE_BY_QUALITY_M = {1: 4.0, 2: 1.0, 3: 2.8, 4: 0.03, 5: 0.4, 6: 15.0, 9: 1.0}
"""User-equivalent range error (1σ, metres) per GGA quality code (module docstring table)."""

ASSUMED_HDOP = 2.0
"""HDOP assumed when a fix reports none."""


def sigma_axis_m(quality: int, hdop: float) -> float:
    """Per-axis horizontal σ in metres: UERE(quality) · HDOP / √2.

    >>> round(sigma_axis_m(4, 1.0), 4), round(sigma_axis_m(2, 1.0), 3)
    (0.0212, 0.707)
    """
    return UERE_BY_QUALITY_M[quality] * hdop / math.sqrt(2.0)


def epoch_attenuation(epoch, reference=None) -> tuple[float, float]:
    """(mean attenuation of the used satellites in dB, SIGMA-ε factor g) of one epoch (module docstring).

    Used = flagged used by GSA and tracked with an elevation; without any, (0, 1) — nothing
    to say. A satellite listed on several signals is read on its primary one
    (:attr:`~features.gnss.nmea.Epoch.primary_satellites`), as the features read it.

    >>> from features.gnss.nmea import Epoch, Fix, Satellite
    >>> sats = (Satellite("GP", 1, None, 90.0, 0.0, 50.0, True), Satellite("GP", 2, None, 90.0, 0.0, 40.0, True))
    >>> a, g = epoch_attenuation(Epoch(0.0, None, 0.0, Fix(0, 0, 0, 0, 1, 2, 1.0, None, None, 3), sats, True))
    >>> round(a, 1), round(g, 3)
    (5.0, 2.345)
    """
    if reference is None:
        from features.gnss.features import Cn0Reference

        reference = _DEFAULT_REFERENCE or _default_reference()
    best = [(sat.el_deg, sat.cn0_dbhz) for sat in epoch.primary_satellites
            if sat.used and sat.cn0_dbhz is not None and sat.el_deg is not None]
    if not best:
        return 0.0, 1.0
    el = np.array([v[0] for v in best])
    cn0 = np.array([v[1] for v in best])
    att = np.maximum(0.0, reference.cref_dbhz(el) - cn0)
    return float(att.mean()), float(math.sqrt(np.mean(10.0 ** (att / 10.0))))


_DEFAULT_REFERENCE = None


def _default_reference():
    global _DEFAULT_REFERENCE
    from features.gnss.features import Cn0Reference

    _DEFAULT_REFERENCE = Cn0Reference()
    return _DEFAULT_REFERENCE


@dataclass(frozen=True)
class UereTable:
    """UERE (1σ, m) per GGA quality and attenuation bin, fitted from walks with truth (:func:`fit_uere`).

    ``uere_m`` maps a quality code to one UERE per bin of :attr:`bin_edges_db` (len(edges) + 1;
    None where a bin had too few fixes: the built-in model serves it); ``n_fixes`` the counts
    behind them. JSON via :meth:`to_dict` / :meth:`from_dict`.
    """

    uere_m: dict
    n_fixes: dict
    bin_edges_db: tuple = ATTENUATION_BIN_EDGES_DB
    source: str = ""

    def lookup(self, quality: int, attenuation_db: float) -> float | None:
        """The fitted UERE for a fix, or None (use the built-in model)."""
        row = self.uere_m.get(int(quality))
        if row is None:
            return None
        return row[int(np.searchsorted(np.asarray(self.bin_edges_db), attenuation_db, side="right"))]

    def to_dict(self) -> dict:
        return {"bin_edges_db": list(self.bin_edges_db),
                "uere_m": {str(q): list(v) for q, v in sorted(self.uere_m.items())},
                "n_fixes": {str(q): list(v) for q, v in sorted(self.n_fixes.items())}, "source": self.source}

    @classmethod
    def from_dict(cls, data: dict) -> "UereTable":
        from features.errors import ConfigError

        try:
            edges = tuple(float(x) for x in data["bin_edges_db"])
            uere = {int(q): tuple(None if v is None else float(v) for v in row) for q, row in data["uere_m"].items()}
            counts = {int(q): tuple(int(v) for v in row) for q, row in data.get("n_fixes", {}).items()}
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ConfigError(f"UERE table needs bin_edges_db and uere_m {{quality: [m per bin]}}: {exc}") from None
        for q, row in uere.items():
            if len(row) != len(edges) + 1 or any(v is not None and not (math.isfinite(v) and v > 0) for v in row):
                raise ConfigError(f"UERE table quality {q}: need {len(edges) + 1} positive values or nulls, got {row}")
        return cls(uere, counts, edges, str(data.get("source", "")))


def fit_uere(positions: Sequence, truths: Sequence, *, min_fixes: int = 20, source: str = "") -> UereTable:
    """Fit a :class:`UereTable` from GNSS positions with truth: UERE² = mean(|e|² / HDOP²) per cell.

    ``positions``: :class:`GnssPositions` of one or more walks (on the walks' time bases);
    ``truths``: one (t_s, east_m, north_m) triple of arrays per walk (truth.csv), the truth
    interpolated at each fix. Cells (quality, attenuation bin) with fewer than ``min_fixes``
    fixes get None. Fixes outside their walk's truth span are ignored.
    """
    if len(positions) != len(truths):
        raise DataError(f"fit_uere needs one truth per positions table, got {len(positions)} and {len(truths)}")
    edges = np.asarray(ATTENUATION_BIN_EDGES_DB)
    acc: dict = {}
    for pos, (tt, te, tn) in zip(positions, truths):
        tt, te, tn = (np.asarray(x, dtype=float) for x in (tt, te, tn))
        if len(pos) == 0 or len(tt) < 2:
            continue
        inside = (pos.t_s >= tt[0]) & (pos.t_s <= tt[-1])
        e2 = (pos.east_m - np.interp(pos.t_s, tt, te)) ** 2 + (pos.north_m - np.interp(pos.t_s, tt, tn)) ** 2
        ratio = e2 / pos.hdop ** 2
        bins = np.searchsorted(edges, pos.attenuation_db, side="right")
        for q, b, r in zip(pos.quality[inside].tolist(), bins[inside].tolist(), ratio[inside].tolist()):
            acc.setdefault(q, [[] for _ in range(len(edges) + 1)])[b].append(r)
    uere = {q: tuple(math.sqrt(float(np.mean(v))) if len(v) >= min_fixes else None for v in rows)
            for q, rows in acc.items()}
    counts = {q: tuple(len(v) for v in rows) for q, rows in acc.items()}
    return UereTable(uere, counts, tuple(float(x) for x in edges), source)


def read_gst(path) -> dict:
    """GST sentences of an NMEA file: {UTC time of day, s (rounded to ms): (σ_lat_m, σ_lon_m)}.

    NMEA 0183 GST ("GNSS pseudorange error statistics"): fields 6 and 7 are the 1σ errors of
    latitude and longitude in metres. Sentences with a bad checksum, empty or non-positive
    σ are skipped. A small reader of its own: the epoch reader does not keep GST's fields.

    >>> import functools, os, tempfile
    >>> body = "GPGST,082356.00,1.8,,,,1.7,1.3,2.2"
    >>> cs = functools.reduce(lambda x, ch: x ^ ord(ch), body, 0)
    >>> fh = tempfile.NamedTemporaryFile("w", suffix=".nmea", delete=False)
    >>> n = fh.write("$" + body + "*" + format(cs, "02X") + "\\r\\n"); fh.close()
    >>> read_gst(fh.name)
    {30236.0: (1.7, 1.3)}
    >>> os.unlink(fh.name)
    """
    out = {}
    with open(path, "rb") as fh:
        for raw in fh:
            line = raw.decode("ascii", "replace").strip()
            i = line.find("$")
            if i < 0 or line[i + 3: i + 6] != "GST":
                continue
            body, _, cs = line[i + 1:].partition("*")
            x = 0
            for ch in body:
                x ^= ord(ch)
            if len(cs) < 2 or cs[:2].upper() != f"{x:02X}":
                continue
            f = body.split(",")
            try:
                hh, mm, ss = int(f[1][0:2]), int(f[1][2:4]), float(f[1][4:])
                s_lat, s_lon = float(f[6]), float(f[7])
            except (IndexError, ValueError):
                continue
            if s_lat > 0 and s_lon > 0 and math.isfinite(s_lat + s_lon):
                out[round(hh * 3600 + mm * 60 + ss, 3)] = (s_lat, s_lon)
    return out


@dataclass(frozen=True)
class GnssPositions:
    """Fix positions on the site's ENU frame; every array of shape (n,).

    ``sigma_en_m`` is σ per horizontal axis (the larger of east and north when GST gives
    them apart), ``sigma_east_m`` / ``sigma_north_m`` per axis; ``attenuation_db`` the used
    satellites' mean attenuation and ``sigma_source`` how σ was found: ``gst``, ``cn0``
    (table × SIGMA-ε factor), ``table`` (RTK fixed) or ``fitted`` (:class:`UereTable`);
    ``invisible_ratio`` the epoch's in-view-but-untracked share above the mask (NaN without a sky).
    Fixes solved from pseudoranges (:func:`features.gnss.wls.wls_positions`) also carry
    ``cov_en_m2`` (n, 2, 2), the east/north covariance with its correlation, and ``quality_text``
    (n,), e.g. "SPS, WLS (rtklib), 14 satellites, excluded 2"; both None from NMEA. Neither is in
    :attr:`COLUMNS` (the per-fix scalar columns a table writer writes).
    """

    t_s: np.ndarray
    east_m: np.ndarray
    north_m: np.ndarray
    up_m: np.ndarray
    sigma_en_m: np.ndarray
    sigma_up_m: np.ndarray
    quality: np.ndarray
    n_used: np.ndarray
    hdop: np.ndarray
    hdop_assumed: np.ndarray
    sigma_east_m: np.ndarray | None = None
    sigma_north_m: np.ndarray | None = None
    attenuation_db: np.ndarray | None = None
    sigma_source: np.ndarray | None = None
    invisible_ratio: np.ndarray | None = None
    cov_en_m2: np.ndarray | None = None
    quality_text: np.ndarray | None = None

    COLUMNS = ("t_s", "east_m", "north_m", "up_m", "sigma_en_m", "sigma_up_m", "quality", "n_used", "hdop",
               "hdop_assumed", "sigma_east_m", "sigma_north_m", "attenuation_db", "sigma_source", "invisible_ratio")

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


def _sky_rows(t: np.ndarray, has: np.ndarray, sky) -> np.ndarray:
    """Row of ``sky`` (:class:`~features.gnss.features.SkyArrays` of these epochs) per epoch (times ``t``, (n,);
    ``has``, (n,) bool: the epoch reported a sky), −1 without a sky."""
    if sky.n_epochs == 0:
        return np.full(t.size, -1, dtype=np.intp)
    j = np.clip(np.searchsorted(sky.t_s, t), 0, sky.n_epochs - 1)
    if not np.array_equal(sky.t_s[j[has]], t[has]):
        raise DataError("fixes_to_enu: the sky arrays given are not those of these epochs (times differ)")
    return np.where(has, j, -1)


def sky_attenuation(sky, reference=None, elevation_mask_deg: float | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sky epoch: used satellites' mean attenuation (dB), SIGMA-ε factor g, invisible ratio; each (n,).

    The vectorised :func:`epoch_attenuation` over :class:`~features.gnss.features.SkyArrays`
    (equal to it on every epoch, a test), and the epoch's invisible ratio: in-view-but-untracked
    satellites above ``elevation_mask_deg`` (default the features' mask) over those in view
    (NaN when none is in view), the GNSS feature ζ of one epoch.
    """
    from features.constants import ELEVATION_MASK_DEG

    reference = reference or _DEFAULT_REFERENCE or _default_reference()
    mask = ELEVATION_MASK_DEG if elevation_mask_deg is None else elevation_mask_deg
    el, cn0 = sky.el_deg, sky.cn0_dbhz
    with np.errstate(invalid="ignore"):
        use = sky.used & np.isfinite(cn0) & np.isfinite(el)
        a = np.where(use, np.maximum(0.0, reference.cref_dbhz(np.where(use, el, 0.0)) - np.where(use, cn0, 0.0)), 0.0)
        n = use.sum(axis=1)
        att = np.where(n > 0, a.sum(axis=1) / np.maximum(n, 1), 0.0)
        g = np.where(n > 0, np.sqrt(np.where(use, 10.0 ** (a / 10.0), 0.0).sum(axis=1) / np.maximum(n, 1)), 1.0)
        view = sky.in_view & (el >= mask)
        n_view = view.sum(axis=1)
        n_trk = (view & np.isfinite(cn0)).sum(axis=1)
        zeta = np.where(n_view > 0, 1.0 - n_trk / np.maximum(n_view, 1), np.nan)
    return att, g, zeta


def fixes_to_enu(epochs: Sequence, lat0_deg: float, lon0_deg: float, alt0_m: float, *,
                 uere: UereTable | None = None, gst: dict | None = None, cn0_reference=None,
                 sky=None) -> GnssPositions:
    """Convert the epochs' fixes to ENU about (lat0, lon0, alt0 ellipsoidal); no fix → no row.

    σ per the module docstring: ``gst`` ({UTC time of day s: (σ_lat, σ_lon)}, :func:`read_gst`)
    where it has the epoch, else the epoch's own GST (:attr:`~features.gnss.nmea.Epoch.gst`), else a
    fitted ``uere`` table where it has the cell, else
    UERE(quality)·HDOP·g/√2 with the SIGMA-ε factor g of the used satellites' C/N0
    (``cn0_reference``: the open-sky C_ref, default built-in). ``sky``: the
    :class:`~features.gnss.features.SkyArrays` of these same epochs when the caller has them
    (computed here otherwise). Vectorised over fixes.
    """
    from features.gnss.features import sky_arrays

    for name, value in (("lat0_deg", lat0_deg), ("lon0_deg", lon0_deg), ("alt0_m", alt0_m)):
        if not math.isfinite(value):
            raise DataError(f"site origin {name} must be finite, got {value}")
    from features.gnss.nmea import epoch_columns

    cols = epoch_columns(epochs, satellites=sky is None)  # the satellites only to build the sky arrays
    quality = cols.col("quality")
    lat, lon = cols.col("lat_deg"), cols.col("lon_deg")
    # Fix.has_position, of a quality the UERE table knows
    fixed = np.flatnonzero(np.isin(quality, list(UERE_BY_QUALITY_M)) & (quality > 0)
                           & ~np.isnan(lat) & ~np.isnan(lon))
    n = fixed.size
    if n == 0:
        empty = np.zeros(0)
        return GnssPositions(empty, empty, empty, empty, empty, empty, np.zeros(0, int), np.zeros(0, int), empty,
                             np.zeros(0, bool), empty, empty, empty, np.zeros(0, dtype="<U6"), empty)
    if sky is None:
        sky = sky_arrays(cols)
    nan = float("nan")
    t, lat, lon, alt_msl, hdop, vdop, tod = (cols.col(name)[fixed] for name in (
        "t_s", "lat_deg", "lon_deg", "alt_m", "hdop", "vdop", "time_of_day_s"))
    sep = np.nan_to_num(cols.col("geoid_sep_m")[fixed], nan=0.0)
    quality = quality[fixed].astype(int)
    n_used = cols.col("n_used")[fixed].astype(float)
    assumed = np.isnan(hdop)
    hdop = np.where(assumed, ASSUMED_HDOP, hdop)
    att_sky, g_sky, zeta_sky = sky_attenuation(sky, cn0_reference)
    row = _sky_rows(t, cols.col("sky_reported")[fixed] != 0, sky)
    has = row >= 0
    att = np.where(has, att_sky[np.maximum(row, 0)] if sky.n_epochs else 0.0, 0.0)
    g = np.where(has, g_sky[np.maximum(row, 0)] if sky.n_epochs else 1.0, 1.0)
    zeta = np.where(has, zeta_sky[np.maximum(row, 0)] if sky.n_epochs else nan, nan)
    table = np.array([UERE_BY_QUALITY_M[q] for q in quality.tolist()])
    # RTK fixed: carrier phase, whose error the code's C/N0 model does not describe (a wrong
    # integer fix is a blunder, not a variance): the table alone. Others: table × SIGMA-ε factor.
    u = np.where(quality == 4, table, table * g)
    source = np.where(quality == 4, "table", "cn0").astype("<U6")
    if uere is not None:
        fitted = np.array([np.nan if v is None else v
                           for v in (uere.lookup(q, a) for q, a in zip(quality.tolist(), att.tolist()))])
        ok = np.isfinite(fitted)
        u = np.where(ok, fitted, u)
        source[ok] = "fitted"
    s_e = u * hdop / math.sqrt(2.0)
    s_n = s_e.copy()
    sigma_up = u * np.where(np.isnan(vdop), 1.5 * hdop, vdop)
    # The receiver's own GST where the epoch has it — unless a fitted table (calibrated against truth) holds the
    # fix's cell: GST is what the receiver believes, too small under NLOS.
    fitted_row = source == "fitted"
    sig_lat, sig_lon, sig_alt = (cols.col(name)[fixed] for name in (
        "gst_sigma_lat_m", "gst_sigma_lon_m", "gst_sigma_alt_m"))
    own = (cols.col("has_gst")[fixed] != 0) & ~np.isnan(sig_lat) & ~np.isnan(sig_lon) & ~fitted_row
    s_n[own], s_e[own] = sig_lat[own], sig_lon[own]
    own_up = own & ~np.isnan(sig_alt)
    sigma_up[own_up] = sig_alt[own_up]
    source[own] = "gst"
    if gst:
        for i, key in enumerate(np.round(tod, 3).tolist()):
            stats = gst.get(key)
            if stats is not None and not fitted_row[i]:
                s_n[i], s_e[i] = stats
                source[i] = "gst"
    alt = np.where(np.isnan(alt_msl), alt0_m, alt_msl + sep)
    e, nn, up = geodetic_to_enu(lat, lon, alt, lat0_deg, lon0_deg, alt0_m)
    return GnssPositions(
        t_s=t, east_m=np.asarray(e, float), north_m=np.asarray(nn, float), up_m=np.asarray(up, float),
        sigma_en_m=np.maximum(s_e, s_n), sigma_up_m=sigma_up, quality=quality, n_used=n_used.astype(int),
        hdop=hdop, hdop_assumed=assumed, sigma_east_m=s_e, sigma_north_m=s_n, attenuation_db=att,
        sigma_source=source, invisible_ratio=zeta,
    )
