"""Per-cell GNSS statistics read straight from a simulated survey's files (test helper).

Reads the NMEA with pynmea2 and the capture point from cell.toml, so it checks
what a receiver would have written, not simulator internals.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pymap3d
import pynmea2

from features.site import load_site


def cref_dbhz(el_deg):
    """Nominal open-sky C/N0 (docs/design.md §6: ≈ 38 dB-Hz at 5°, ≈ 50 at zenith), linear in sin(el)."""
    s5 = np.sin(np.radians(5.0))
    return 38.0 + 12.0 * (np.sin(np.radians(el_deg)) - s5) / (1.0 - s5)


def cell_stats(cell_dir: Path, origin, mask_deg: float = 10.0) -> dict:
    cell = tomllib.loads((cell_dir / "cell.toml").read_text())
    untracked, att, err, quality = [], [], [], []
    epoch_untracked = 0
    for line in (cell_dir / "gnss.nmea").read_text().splitlines():
        msg = pynmea2.parse(line, check=True)
        if isinstance(msg, pynmea2.types.talker.GGA):
            untracked.append(epoch_untracked)
            epoch_untracked = 0
            q = int(msg.gps_qual or 0)
            quality.append(q)
            if q > 0:
                e, n, _ = pymap3d.geodetic2enu(msg.latitude, msg.longitude, float(msg.altitude), origin.lat_deg,
                                               origin.lon_deg, origin.alt_m)
                err.append(np.hypot(e - cell["east_m"], n - cell["north_m"]))
        elif isinstance(msg, pynmea2.types.talker.GSV):
            for k in (1, 2, 3, 4):
                el = getattr(msg, f"elevation_deg_{k}", "")
                if el in ("", None):
                    continue
                el = float(el)
                if el < mask_deg:
                    continue
                snr = getattr(msg, f"snr_{k}", "")
                if snr in ("", None):
                    epoch_untracked += 1
                else:
                    att.append(max(0.0, cref_dbhz(el) - float(snr)))
    quality = np.array(quality)
    return {"label": cell["map_label"], "untracked": float(np.mean(untracked[1:] or [0])),
            "att_db": float(np.mean(att)) if att else np.nan,
            "err_m": float(np.median(err)) if err else np.nan,
            "rtk_fixed": float(np.mean(quality == 4)), "no_fix": float(np.mean(quality == 0))}


def survey_stats(survey_dir: Path) -> list[dict]:
    origin = load_site(survey_dir).origin
    return [cell_stats(d, origin) for d in sorted((survey_dir / "cells").iterdir())]


def class_medians(stats: list[dict], key: str) -> dict:
    out = {}
    for c in ("open", "light", "heavy"):
        vals = np.array([s[key] for s in stats if s["label"] == c], float)
        out[c] = float(np.nanmedian(vals)) if np.isfinite(vals).any() else np.nan
    return out
