"""The real urban figures the GNSS simulator is calibrated against, computed here from the files (not copied).

smartLoc (TU Chemnitz, Reisdorf et al. 2016–2022, CC BY-SA 4.0), two parts in ../shared/data:

* ``nmea/gnss_lib_py/smartloc_tu_chemnitz_berlin_1_raw.csv`` — 31 epochs of a u-blox receiver in Berlin with a
  LOS/NLOS label per satellite (from the dataset's 3-D city model): :func:`los_nlos_cn0` gives the C/N0 mean and
  (population) standard deviation of each label and the NLOS share among the tracked satellites.
* ``gnss_urban_smartloc/`` — the first 170 s of the Potsdamer Platz drive, pseudoranges with C/N0 and a NovAtel
  reference: :func:`berlin_residuals` gives each satellite's pseudorange residual against the reference
  (Earth-rotation (Sagnac) correction applied, the receiver clock of each system and epoch taken as the median of
  its satellites' pseudorange-minus-range, robust to the NLOS ones) and :func:`residual_by_cn0` their median
  absolute value per C/N0 bin.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent.parent / "shared" / "data"
SMARTLOC_CSV = SHARED / "nmea" / "gnss_lib_py" / "smartloc_tu_chemnitz_berlin_1_raw.csv"
BERLIN = SHARED / "gnss_urban_smartloc"
OMEGA_E_RAD_S = 7.2921151467e-5
"""Earth rotation rate, rad/s (WGS-84, IS-GPS-200 Table 30-II)."""
C_M_S = 299_792_458.0
CN0_BINS_DBHZ = (30.0, 35.0, 40.0, 45.0)
"""Edges of the C/N0 bins of :func:`residual_by_cn0`: < 30, 30–35, 35–40, 40–45, ≥ 45 dB-Hz."""


def _shared(path: Path) -> Path:
    for base in (path, Path("/work/shared/data") / path.relative_to(SHARED)):
        if base.exists():
            return base
    raise FileNotFoundError(f"smartLoc data not found at {path}")


def los_nlos_cn0(path: Path = SMARTLOC_CSV) -> dict:
    """{'los': (mean, sd, n), 'nlos': (mean, sd, n), 'nlos_share_tracked': share} from the labelled sample."""
    with open(_shared(path), newline="") as fh:
        rows = list(csv.reader(fh, delimiter=";"))
    head = rows[0]
    j = next(i for i, h in enumerate(head) if "(cno)" in h)
    cn0 = np.array([float(r[j]) for r in rows[1:]])
    flag = np.array([r[-1].strip() for r in rows[1:]])
    out = {}
    for name, f in (("los", "0"), ("nlos", "1")):
        v = cn0[flag == f]
        out[name] = (float(v.mean()), float(v.std()), int(v.size))
    known = np.isin(flag, ("0", "1"))
    out["nlos_share_tracked"] = float(np.mean(flag[known] == "1"))
    return out


def berlin_residuals(directory: Path = BERLIN) -> tuple[np.ndarray, np.ndarray]:
    """Per-satellite pseudorange residuals (m) against the reference, and their C/N0 (dB-Hz); each (m,)."""
    d = _shared(directory)
    gt = {}
    for line in open(d / "Berlin_Potsdamer_Platz_GT.txt"):
        f = line.split()
        if f and f[0] == "point3":
            gt[round(float(f[1]), 3)] = np.array([float(f[2]), float(f[3]), float(f[4])])
    by_epoch: dict = {}
    for line in open(d / "Berlin_Potsdamer_Platz_Input.txt"):
        f = line.split()
        if f and f[0] == "pseudorange3":
            t = round(float(f[1]), 3)
            by_epoch.setdefault(t, []).append((float(f[2]), float(f[4]), float(f[5]), float(f[6]), int(f[8]),
                                               float(f[10])))
    res, cn0 = [], []
    for t, meas in by_epoch.items():
        x = gt.get(t)
        if x is None:
            continue
        m = np.array(meas)
        pr, sat, system, c = m[:, 0], m[:, 1:4], m[:, 4], m[:, 5]
        rho = np.linalg.norm(sat - x, axis=1)
        # Sagnac: the satellite position at emission rotated by ω_E·τ into the frame at reception.
        ang = OMEGA_E_RAD_S * rho / C_M_S
        rot = np.column_stack([sat[:, 0] * np.cos(ang) + sat[:, 1] * np.sin(ang),
                               -sat[:, 0] * np.sin(ang) + sat[:, 1] * np.cos(ang), sat[:, 2]])
        rho = np.linalg.norm(rot - x, axis=1)
        r = pr - rho
        for s in np.unique(system):
            sel = system == s
            if sel.sum() >= 2:
                res.append(r[sel] - np.median(r[sel]))
                cn0.append(c[sel])
    return np.concatenate(res), np.concatenate(cn0)


def residual_by_cn0(residual_m: np.ndarray, cn0_dbhz: np.ndarray, edges=CN0_BINS_DBHZ) -> list[tuple[int, float]]:
    """(count, median |residual| m) per C/N0 bin (< e0, e0–e1, …, ≥ e_last).

    >>> residual_by_cn0(np.array([10.0, -20.0, 1.0, 3.0]), np.array([25.0, 28.0, 46.0, 50.0]), (30.0,))
    [(2, 15.0), (2, 2.0)]
    """
    b = np.searchsorted(np.asarray(edges), np.asarray(cn0_dbhz), side="right")
    out = []
    for i in range(len(edges) + 1):
        v = np.abs(np.asarray(residual_m)[b == i])
        out.append((int(v.size), float(np.median(v)) if v.size else float("nan")))
    return out
