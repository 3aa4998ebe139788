"""Raw pseudoranges, vehicle odometry and a reference track from smartLoc text files, as column tables.

The smartLoc format (Reisdorf et al., TU Chemnitz, 2016-2022; the libRSF ``datasets/smartLoc``
files; ``README.source.txt`` of ``../shared/data/gnss_urban_smartloc``) holds one record a line,
whitespace-separated, the first field naming its type:

=================  ======================================================================
record             fields after the type (units)
=================  ======================================================================
``pseudorange3``   t (s), pseudorange (m), its variance (m²), satellite ECEF X, Y, Z at
                   emission (m), satellite id, system code, elevation (deg), C/N0 (dB-Hz)
``odom3``          t (s), velocity x y z (m/s, body frame), turn rate x y z (rad/s), their
                   six variances ((m/s)², (rad/s)²)
``point3``         t (s), ECEF X, Y, Z (m), 3×3 covariance row-major (m², zeros in smartLoc)
=================  ======================================================================

The system code is RTKLIB's system bit mask (``rtklib.h``: SYS_GPS 0x01, SYS_SBS 0x02, SYS_GLO 0x04,
SYS_GAL 0x08, SYS_QZS 0x10, SYS_CMP 0x20, SYS_IRN 0x40); the tables carry the RINEX 3 system letter
instead (G, S, R, E, J, C, I; RINEX 3.05 §3.5). smartLoc's pseudoranges have the satellite clock and
the atmospheric delays removed but **not** the Earth-rotation (Sagnac) correction: the table says so
in ``corrections`` and the solver (:mod:`features.gnss.wls`) applies what is missing.

**Toward RINEX.** A RINEX 3 observation file (C1C pseudoranges, S1C C/N0) with broadcast
ephemerides (RINEX navigation file) reaches the solver through the same :class:`PseudorangeTable`:
an ephemeris stage computes each satellite's ECEF position at emission time (IS-GPS-200 Table
20-IV; GLONASS ICD §A.3.1.2 Runge–Kutta), its clock offset with the relativistic term and group
delay, the broadcast ionosphere (Klobuchar, IS-GPS-200 §20.3.3.5.2.5) and a troposphere model
(Saastamoinen), subtracts them from the raw pseudorange, takes the elevation from an approximate
receiver position, and fills ``pseudorange_m``, ``sat_ecef_m``, ``elevation_deg``, ``cn0_dbhz``
with ``corrections = {"satellite_clock", "ionosphere", "troposphere"}`` and a variance (e.g.
RTKLIB's ionosphere/ephemeris terms) in ``pseudorange_var_m2``. Everything downstream (solver,
RAIM, per-satellite features) reads only the table. The same ephemerides also give the positions
of satellites *not* tracked, which is what the invisible ratio ζ needs
(:mod:`features.gnss.sat_features`); this format lacks them.

**In a walk folder** the tables would be written as ``gnss_pseudoranges.csv`` (one row per
satellite and epoch: ``t_s, system, svid, pseudorange_m, pseudorange_var_m2, sat_x_m, sat_y_m,
sat_z_m, elevation_deg, cn0_dbhz``; ``[gnss_pseudoranges]`` in ``walk.toml`` with ``file`` and
``corrections``), ``odometry.csv`` (``t_s, speed_m_s, yaw_rate_rad_s, speed_var_m2_s2,
yaw_rate_var_rad2_s2``, ``[odometry]`` in ``walk.toml``) and the reference as the walk's
``truth.csv`` in site ENU (its ``env_class`` unknown for a drive).

**Bad input.** A malformed line — unknown field count, a field that is not a finite number, an
impossible value (variance ≤ 0, elevation beyond ±90°, a satellite not at orbital distance, an
unknown system code), time running backwards, the same satellite twice in one epoch — raises one
:class:`~features.errors.PseudorangeError` naming the file, the line number and the line. This
differs on purpose from the NMEA reader, which skips and counts damaged sentences: NMEA carries a
checksum per sentence, so a damaged sentence is known to be a transmission error and the rest is
trustworthy; this text has none, and a malformed line more likely means a different column layout
or an edited file, where skipping would give a silently wrong answer. ``strict=False`` skips such
lines and counts them (:class:`SmartLocReadStats`) for a user who has looked. Blank lines and ``#``
comments are skipped; lines of other record types are counted by type and ignored. A file without
any record of the asked type raises :class:`~features.errors.PseudorangeError`.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from features.errors import PseudorangeError

__all__ = ["SYSTEM_LETTER_BY_RTKLIB_CODE", "PseudorangeTable", "OdometryTable", "ReferenceTrack",
           "SmartLocReadStats", "SmartLocLog", "read_smartloc"]

SYSTEM_LETTER_BY_RTKLIB_CODE = {1: "G", 2: "S", 4: "R", 8: "E", 16: "J", 32: "C", 64: "I"}
"""RTKLIB system bit (``rtklib.h`` SYS_*) → RINEX 3 system letter (RINEX 3.05 §3.5)."""

SMARTLOC_CORRECTIONS = frozenset({"satellite_clock", "ionosphere", "troposphere"})
"""What smartLoc's pseudoranges already have removed (README.source.txt); Earth rotation is not among them."""

_SAT_RADIUS_RANGE_M = (1.0e7, 1.0e8)
"""Distance of a GNSS satellite from Earth's centre, m: MEO ≈ 2.6e7, GEO/IGSO ≈ 4.2e7 (a value outside says
the position is not in metres or not ECEF)."""

_FIELDS = {"pseudorange3": 10, "odom3": 13, "point3": 13}
"""Number of fields after the record type."""


def _col(name: str, value, n: int | None = None, dtype=float, shape_tail: tuple = ()) -> np.ndarray:
    a = np.asarray(value, dtype=dtype)
    want = (a.shape[0] if n is None and a.ndim else n,) + shape_tail
    if a.shape != want:
        raise PseudorangeError(f"{name} must have shape {want}, got {a.shape}")
    return a


@dataclass(frozen=True)
class PseudorangeTable:
    """One row per (epoch, satellite); every array of length n, rows in non-decreasing ``t_s``.

    t_s : (n,) receive time, s, on the log's time base;
    pseudorange_m : (n,) with the ``corrections`` removed; pseudorange_var_m2 : (n,) its variance as the
    source states it (NaN when it states none);
    sat_ecef_m : (n, 3) satellite position at emission, ECEF (WGS-84), m;
    svid : (n,) int satellite id within its system; system : (n,) RINEX letter (G, R, E, C, J, S, I);
    elevation_deg : (n,) as the receiver computed it (NaN when absent); cn0_dbhz : (n,) (NaN when absent);
    corrections : what the pseudoranges already have removed (``satellite_clock``, ``ionosphere``,
    ``troposphere``, ``earth_rotation``); source : where the table came from.
    """

    t_s: np.ndarray
    pseudorange_m: np.ndarray
    pseudorange_var_m2: np.ndarray
    sat_ecef_m: np.ndarray
    svid: np.ndarray
    system: np.ndarray
    elevation_deg: np.ndarray
    cn0_dbhz: np.ndarray
    corrections: frozenset = SMARTLOC_CORRECTIONS
    source: str = ""

    def __post_init__(self):
        t = _col("t_s", self.t_s)
        n = t.shape[0]
        for name in ("pseudorange_m", "pseudorange_var_m2", "elevation_deg", "cn0_dbhz"):
            object.__setattr__(self, name, _col(name, getattr(self, name), n))
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "sat_ecef_m", _col("sat_ecef_m", self.sat_ecef_m, n, shape_tail=(3,)))
        object.__setattr__(self, "svid", _col("svid", self.svid, n, dtype=np.int64))
        object.__setattr__(self, "system", _col("system", self.system, n, dtype="<U1"))
        object.__setattr__(self, "corrections", frozenset(self.corrections))
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(self.pseudorange_m))
                and np.all(np.isfinite(self.sat_ecef_m))):
            raise PseudorangeError("t_s, pseudorange_m and sat_ecef_m must be finite")
        if n and np.any(np.diff(t) < 0):
            raise PseudorangeError("PseudorangeTable rows must be in non-decreasing t_s")

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def epochs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_s of each epoch, first row, one past the last row), each of shape (n_epochs,).

        An epoch is a run of rows with the same ``t_s`` (one receiver measurement time).
        """
        if len(self) == 0:
            z = np.zeros(0, dtype=np.intp)
            return np.zeros(0), z, z
        start = np.flatnonzero(np.r_[True, self.t_s[1:] != self.t_s[:-1]])
        stop = np.r_[start[1:], len(self)]
        return self.t_s[start], start, stop

    @property
    def sat_keys(self) -> list[tuple[str, int]]:
        """(system letter, svid) of every row."""
        return list(zip(self.system.tolist(), self.svid.tolist()))


@dataclass(frozen=True)
class OdometryTable:
    """Vehicle odometry, one row per sample, strictly increasing ``t_s``.

    velocity_body_m_s, rate_body_rad_s : (n, 3) in the vehicle's body frame (x forward, y left,
    z up, as libRSF's ``odom3``: a positive z rate turns left, counter-clockwise seen from above);
    velocity_var_m2_s2, rate_var_rad2_s2 : (n, 3) their variances as the file states them.
    """

    t_s: np.ndarray
    velocity_body_m_s: np.ndarray
    rate_body_rad_s: np.ndarray
    velocity_var_m2_s2: np.ndarray
    rate_var_rad2_s2: np.ndarray
    source: str = ""

    def __post_init__(self):
        t = _col("t_s", self.t_s)
        n = t.shape[0]
        object.__setattr__(self, "t_s", t)
        for name in ("velocity_body_m_s", "rate_body_rad_s", "velocity_var_m2_s2", "rate_var_rad2_s2"):
            object.__setattr__(self, name, _col(name, getattr(self, name), n, shape_tail=(3,)))
        if n and np.any(np.diff(t) <= 0):
            raise PseudorangeError("OdometryTable rows must be in strictly increasing t_s")

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def speed_m_s(self) -> np.ndarray:
        """Forward speed (body x), m/s, shape (n,)."""
        return self.velocity_body_m_s[:, 0]

    @property
    def yaw_rate_rad_s(self) -> np.ndarray:
        """Turn rate about body z (up), rad/s, counter-clockwise positive, shape (n,)."""
        return self.rate_body_rad_s[:, 2]


@dataclass(frozen=True)
class ReferenceTrack:
    """Reference positions: t_s (n,), ecef_m (n, 3), cov_ecef_m2 (n, 3, 3) (zeros when not given)."""

    t_s: np.ndarray
    ecef_m: np.ndarray
    cov_ecef_m2: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return int(np.asarray(self.t_s).shape[0])


@dataclass
class SmartLocReadStats:
    """What the reader saw: line and record counts, skipped lines (only with ``strict=False``)."""

    lines: int = 0
    blank_or_comment: int = 0
    records: Counter = field(default_factory=Counter)
    other_types: Counter = field(default_factory=Counter)
    malformed: int = 0
    first_malformed: str | None = None

    def summary(self) -> str:
        """One line, e.g. ``13034 lines: 12211 pseudorange3, 823 odom3``."""
        parts = [f"{v} {k}" for k, v in sorted(self.records.items())]
        text = f"{self.lines} lines: " + (", ".join(parts) if parts else "no record")
        if self.other_types:
            text += "; other types " + ", ".join(f"{k} {v}" for k, v in sorted(self.other_types.items()))
        if self.malformed:
            text += f"; skipped {self.malformed} malformed (first: {self.first_malformed})"
        return text


@dataclass(frozen=True)
class SmartLocLog:
    """The tables of one smartLoc file; a table is None when the file holds none of its records."""

    pseudoranges: PseudorangeTable | None
    odometry: OdometryTable | None
    reference: ReferenceTrack | None
    stats: SmartLocReadStats


class _LineError(ValueError):
    """A malformed line (message without the location; the reader adds file and line)."""


def _numbers(parts: list[str], tag: str) -> list[float]:
    want = _FIELDS[tag]
    if len(parts) != want:
        raise _LineError(f"{tag} needs {want} fields after the type, got {len(parts)}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        bad = next(p for p in parts if not _is_float(p))
        raise _LineError(f"{tag} field {parts.index(bad) + 2} is not a number: {bad!r}") from None
    for k, v in enumerate(values):
        if not math.isfinite(v):
            raise _LineError(f"{tag} field {k + 2} is not finite: {parts[k]!r}")
    return values


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _check_pseudorange(v: list[float]) -> tuple:
    t, pr, var, x, y, z, svid, code, el, cn0 = v
    if var <= 0:
        raise _LineError(f"pseudorange3 variance must be > 0 m², got {var:g}")
    radius = math.sqrt(x * x + y * y + z * z)
    if not _SAT_RADIUS_RANGE_M[0] <= radius <= _SAT_RADIUS_RANGE_M[1]:
        raise _LineError(f"pseudorange3 satellite position is {radius:.4g} m from Earth's centre, not an orbit "
                         "(ECEF metres expected)")
    if svid != int(svid) or svid < 0:
        raise _LineError(f"pseudorange3 satellite id must be a non-negative integer, got {svid:g}")
    if code not in SYSTEM_LETTER_BY_RTKLIB_CODE:
        raise _LineError(f"pseudorange3 system code {code:g} is none of "
                         f"{sorted(SYSTEM_LETTER_BY_RTKLIB_CODE)} (RTKLIB SYS_* bits)")
    if not -90.0 <= el <= 90.0:
        raise _LineError(f"pseudorange3 elevation must lie in [-90, 90] deg, got {el:g}")
    if not 0.0 < cn0 < 100.0:
        raise _LineError(f"pseudorange3 C/N0 must lie in (0, 100) dB-Hz, got {cn0:g}")
    return t, pr, var, x, y, z, int(svid), SYSTEM_LETTER_BY_RTKLIB_CODE[int(code)], el, cn0


def _check_odometry(v: list[float]) -> tuple:
    if any(x < 0 for x in v[7:]):
        raise _LineError("odom3 variances must be >= 0")
    return tuple(v)


def _check_point(v: list[float]) -> tuple:
    radius = math.sqrt(v[1] ** 2 + v[2] ** 2 + v[3] ** 2)
    if not 6.0e6 <= radius <= 7.0e6:
        raise _LineError(f"point3 position is {radius:.4g} m from Earth's centre, not on Earth (ECEF metres expected)")
    return tuple(v)


_CHECK = {"pseudorange3": _check_pseudorange, "odom3": _check_odometry, "point3": _check_point}


class _Order:
    """Per record type: time order and, for pseudoranges, one row per satellite and epoch."""

    def __init__(self):
        self.last_t: dict[str, float] = {}
        self.epoch_sats: set = set()

    def check(self, tag: str, row: tuple):
        t = row[0]
        last = self.last_t.get(tag)
        if last is not None:
            if t < last or (t == last and tag != "pseudorange3"):
                raise _LineError(f"{tag} time {t:g} s does not follow the previous {tag} time {last:g} s")
        if tag == "pseudorange3":
            if last is None or t != last:
                self.epoch_sats = set()
            key = (row[7], row[6])
            if key in self.epoch_sats:
                raise _LineError(f"satellite {key[0]}{key[1]} appears twice at t = {t:g} s")
            self.epoch_sats.add(key)
        self.last_t[tag] = t


def read_smartloc(path: str | os.PathLike, *, strict: bool = True) -> SmartLocLog:
    """Read a smartLoc text file (``*_Input.txt`` or ``*_GT.txt``) into tables (module docstring).

    Raises :class:`~features.errors.PseudorangeError` on the first malformed line (``strict``) naming
    ``path:line``, or when the file holds no pseudorange3, odom3 or point3 record at all.
    """
    path = os.fspath(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as exc:
        raise PseudorangeError(f"{path}: cannot read ({exc.strerror})") from None
    rows: dict[str, list] = {tag: [] for tag in _FIELDS}
    stats = SmartLocReadStats()
    order = _Order()
    for lineno, line_b in enumerate(raw.splitlines(), start=1):
        stats.lines += 1
        line = line_b.decode("utf-8", "replace").strip()
        if not line or line.startswith("#"):
            stats.blank_or_comment += 1
            continue
        parts = line.split()
        tag = parts[0]
        if tag not in _FIELDS:
            stats.other_types[tag] += 1
            continue
        try:
            row = _CHECK[tag](_numbers(parts[1:], tag))
            order.check(tag, row)
        except _LineError as exc:
            where = f"{path}:{lineno}: {exc} (line: {line[:96]!r})"
            if strict:
                raise PseudorangeError(where) from None
            stats.malformed += 1
            stats.first_malformed = stats.first_malformed or where
            continue
        rows[tag].append(row)
        stats.records[tag] += 1
    if not any(rows.values()):
        raise PseudorangeError(f"{path}: no pseudorange3, odom3 or point3 record in {stats.lines} lines"
                               + (f" (skipped {stats.malformed} malformed)" if stats.malformed else ""))
    return SmartLocLog(_pseudoranges(rows["pseudorange3"], path), _odometry(rows["odom3"], path),
                       _reference(rows["point3"], path), stats)


def _pseudoranges(rows: list, source: str) -> PseudorangeTable | None:
    if not rows:
        return None
    t, pr, var, x, y, z, svid, system, el, cn0 = zip(*rows)
    return PseudorangeTable(t_s=np.array(t), pseudorange_m=np.array(pr), pseudorange_var_m2=np.array(var),
                            sat_ecef_m=np.stack([x, y, z], axis=1), svid=np.array(svid, dtype=np.int64),
                            system=np.array(system, dtype="<U1"), elevation_deg=np.array(el),
                            cn0_dbhz=np.array(cn0), corrections=SMARTLOC_CORRECTIONS, source=source)


def _odometry(rows: list, source: str) -> OdometryTable | None:
    if not rows:
        return None
    a = np.array(rows, dtype=float)
    return OdometryTable(t_s=a[:, 0], velocity_body_m_s=a[:, 1:4], rate_body_rad_s=a[:, 4:7],
                         velocity_var_m2_s2=a[:, 7:10], rate_var_rad2_s2=a[:, 10:13], source=source)


def _reference(rows: list, source: str) -> ReferenceTrack | None:
    if not rows:
        return None
    a = np.array(rows, dtype=float)
    return ReferenceTrack(t_s=a[:, 0], ecef_m=a[:, 1:4], cov_ecef_m2=a[:, 4:13].reshape(-1, 3, 3), source=source)
