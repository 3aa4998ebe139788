"""Per-satellite agreement of the NMEA reader with gpsd's own decode (``*.log.chk``), the independent reference.

gpsd's regression files (ntpsec/gpsd ``test/daemon``, BSD-2-Clause) pair every receiver log
``X.log`` with ``X.log.chk``: the raw sentences echoed, each followed by the JSON gpsd
decoded from it. A SKY object lists one entry per satellite *per signal* (``sigid`` present
for signals other than the first, u-blox numbering), with ``el``/``az`` absent when the
sentence left them empty and ``ss`` (C/N0) absent when not tracked.

Comparison, per fix time: gpsd's last SKY report with satellites (the whole cycle), against
the reader's epoch of that time of day. Entries are paired by (gnssid, svid) and rank: the
k-th listing of a satellite in gpsd with the k-th in the epoch (both keep GSV order, so the
L1 entry pairs with the L1 entry and the L5 one with the L5 one). An entry *agrees* when
elevation, azimuth, C/N0 and ``used`` are all equal; *differs* otherwise; is *missing* when
the epoch lists the satellite fewer times than gpsd; *extra* counts entries of the epoch
that gpsd did not list; *no_epoch* counts gpsd entries of a fix time the reader has no epoch
for. Used by ``tests/test_nmea_reader.py`` and ``bench/gsv_gpsd_agreement.py``.

This module imports nothing from the reader's internals (it takes epochs as read).
"""

from __future__ import annotations

import collections
import json
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["GNSSID", "Agreement", "gpsd_cycles", "compare_with_gpsd"]

GNSSID = {"GPS": 0, "SBAS": 1, "Galileo": 2, "BeiDou": 3, "QZSS": 5, "GLONASS": 6, "NavIC": 7}
"""gpsd's (u-blox's) gnssid per constellation name (gpsd_json(5), ``gnssid``)."""

_TIMED = ("GGA", "RMC", "GNS", "ZDA", "GST", "GBS")


def _time_of_day_s(text: str) -> float | None:
    """``hhmmss[.ss]`` → seconds of the day (written here, not imported, to stay independent)."""
    if len(text) < 6 or not text[:6].isdigit():
        return None
    try:
        return int(text[0:2]) * 3600.0 + int(text[2:4]) * 60.0 + float(text[4:])
    except ValueError:
        return None


def gpsd_cycles(chk: Path) -> list[tuple[float, list[dict]]]:
    """gpsd's last SKY satellite list per fix time, the time read from the raw sentences the .chk echoes."""
    out: list = []
    tod = None
    for line in Path(chk).read_text(encoding="latin-1").splitlines():
        if line.startswith("$") and line[3:6] in _TIMED:
            parts = line.split(",")
            t = _time_of_day_s(parts[1]) if len(parts) > 1 else None
            tod = t if t is not None else tod
        elif line.startswith("{") and '"satellites"' in line and tod is not None:
            try:
                sats = json.loads(line)["satellites"]
            except (ValueError, KeyError):
                continue
            if out and out[-1][0] == tod:
                out[-1] = (tod, sats)
            else:
                out.append((tod, sats))
    return out


@dataclass
class Agreement:
    """Counts of one comparison (see the module docstring)."""

    agree: int = 0
    differ: int = 0
    missing: int = 0
    extra: int = 0
    no_epoch: int = 0
    cycles_without_epoch: list = field(default_factory=list)

    @property
    def gpsd_entries(self) -> int:
        """Entries gpsd listed: the denominator of :attr:`share`."""
        return self.agree + self.differ + self.missing + self.no_epoch

    @property
    def share(self) -> float:
        """Agreeing entries over gpsd's entries (NaN without any)."""
        n = self.gpsd_entries
        return self.agree / n if n else float("nan")

    def __iadd__(self, other: "Agreement") -> "Agreement":
        for name in ("agree", "differ", "missing", "extra", "no_epoch"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.cycles_without_epoch += other.cycles_without_epoch
        return self


def compare_with_gpsd(epochs, cycles) -> Agreement:
    """Agreement of ``epochs`` (as the reader returns them, in time order) with gpsd's ``cycles``."""
    result = Agreement()
    j = 0
    for tod, sats in cycles:
        k = j
        while k < len(epochs) and epochs[k].time_of_day_s != tod:
            k += 1
        if k == len(epochs):
            result.no_epoch += len(sats)
            result.cycles_without_epoch.append((tod, len(sats)))
            continue
        j = k
        ours = collections.defaultdict(list)
        for s in epochs[k].satellites:
            ours[(GNSSID[s.system], s.prn)].append(s)
        rank: collections.Counter = collections.Counter()
        for g in sats:
            key = (g["gnssid"], g["svid"])
            r = rank[key]
            rank[key] += 1
            if r >= len(ours[key]):
                result.missing += 1
                continue
            s = ours[key][r]
            same = (s.el_deg, s.az_deg, s.cn0_dbhz, s.used) == (g.get("el"), g.get("az"), g.get("ss"), g["used"])
            if same:
                result.agree += 1
            else:
                result.differ += 1
        result.extra += sum(len(v) - rank[key] for key, v in ours.items() if len(v) > rank[key])
    return result
