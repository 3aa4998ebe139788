"""The site description ``site.toml``: frozen dataclasses, validated on load.

Format (docs/design.md §4)::

    name = "sim-0007"
    device_height_m = 1.0
    [origin]      lat_deg, lon_deg, alt_m
    [atmosphere]  temperature_c, relative_humidity_pct, pressure_kpa
    [grid]        cell_size_m, east_min_m, east_max_m, north_min_m, north_max_m
    [acoustic]    f0_hz, f1_hz, chirp_duration_s, taper_fraction, slot_s, n_slots, source_level_db
    [[beacons]]   id, east_m, north_m, up_m, slot  (optional f0_hz, f1_hz, chirp_duration_s)
    [[layout]]    kind, material, porous, east_min_m, east_max_m, north_min_m, north_max_m, height_m
    [[emi_zones]] east_m, north_m, radius_m, loss_db
    [[uwb_anchors]] id, east_m, north_m, up_m, boresight_deg

``uwb_anchors`` are UWB anchors as an installer surveyed them (positions to survey precision, the
boresight of each anchor's PDoA antenna pair, degrees clockwise from north); a site without UWB omits them.

``layout`` and ``emi_zones`` describe a simulated site; only the simulator and
the map-label baseline use them. A real site's ``site.toml`` omits them.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

from features.errors import ConfigError
from features.fileio import read_toml, write_toml

__all__ = [
    "Origin", "Atmosphere", "Grid", "AcousticConfig", "Beacon", "Box", "EmiZone", "UwbAnchor", "Site",
    "load_site", "save_site", "ENV_CLASSES", "BOX_KINDS",
]

ENV_CLASSES = ("open", "light", "heavy")
"""Environment class names, in order of increasing occlusion (docs/design.md §4)."""

BOX_KINDS = ("transformer", "firewall", "building", "gantry", "equipment")

SLOT_REUSE_MIN_M = 145.0
"""Least horizontal distance between two beacons sharing a TDMA slot, m: twice the ≈ 70 m free-field
detection range, so no receiver hears two slot-mates (README, "Beacon protocol")."""

_TOML_TABLE = {"Origin": "origin", "Atmosphere": "atmosphere", "Grid": "grid", "AcousticConfig": "acoustic",
               "Beacon": "", "Box": "", "EmiZone": "", "UwbAnchor": "", "Site": ""}
"""The site.toml table each dataclass is read from, so messages name the key the user wrote (entries of
[[beacons]], [[layout]], [[emi_zones]] are named by the loader: "[[beacons]] #2 (id 7): east_m ...")."""


def _key(obj, name: str) -> str:
    table = _TOML_TABLE.get(type(obj).__name__, type(obj).__name__)
    return f"{table}.{name}" if table else name


def _require_finite(obj, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ConfigError(f"{_key(obj, name)} must be a finite number, got {value!r}")


@dataclass(frozen=True)
class Origin:
    """Site origin, WGS-84 geodetic."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self):
        _require_finite(self, "lat_deg", "lon_deg", "alt_m")
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ConfigError(f"origin.lat_deg must lie in [-90, 90], got {self.lat_deg}")
        if not -180.0 <= self.lon_deg <= 360.0:
            raise ConfigError(f"origin.lon_deg must lie in [-180, 360], got {self.lon_deg}")


@dataclass(frozen=True)
class Atmosphere:
    """Air state used for the speed of sound and ISO 9613-1 absorption."""

    temperature_c: float = 20.0
    relative_humidity_pct: float = 60.0
    pressure_kpa: float = 101.325

    def __post_init__(self):
        _require_finite(self, "temperature_c", "relative_humidity_pct", "pressure_kpa")
        if not -40.0 <= self.temperature_c <= 60.0:
            raise ConfigError(f"atmosphere.temperature_c must lie in [-40, 60], got {self.temperature_c}")
        if not 0.0 < self.relative_humidity_pct <= 100.0:
            raise ConfigError(f"atmosphere.relative_humidity_pct must lie in (0, 100], got {self.relative_humidity_pct}")
        if not 50.0 <= self.pressure_kpa <= 110.0:
            raise ConfigError(f"atmosphere.pressure_kpa must lie in [50, 110], got {self.pressure_kpa}")


@dataclass(frozen=True)
class Grid:
    """Survey grid: square cells of ``cell_size_m`` over the site's extent (ENU metres)."""

    cell_size_m: float = 5.0
    east_min_m: float = 0.0
    east_max_m: float = 120.0
    north_min_m: float = 0.0
    north_max_m: float = 80.0

    def __post_init__(self):
        _require_finite(self, "cell_size_m", "east_min_m", "east_max_m", "north_min_m", "north_max_m")
        if self.cell_size_m <= 0:
            raise ConfigError(f"grid.cell_size_m must be positive, got {self.cell_size_m}")
        if self.east_max_m <= self.east_min_m or self.north_max_m <= self.north_min_m:
            raise ConfigError("grid extent is empty: need east_max_m > east_min_m and north_max_m > north_min_m")


@dataclass(frozen=True)
class AcousticConfig:
    """Beacon chirp and TDMA frame parameters (defaults: docs/design.md §6)."""

    f0_hz: float = 17_000.0
    f1_hz: float = 23_000.0
    chirp_duration_s: float = 0.010
    taper_fraction: float = 0.2
    slot_s: float = 0.1
    n_slots: int = 8
    source_level_db: float = 100.0

    def __post_init__(self):
        _require_finite(self, "f0_hz", "f1_hz", "chirp_duration_s", "taper_fraction", "slot_s", "source_level_db")
        if not 0 < self.f0_hz < self.f1_hz <= 24_000.0:
            raise ConfigError(f"acoustic band must satisfy 0 < f0_hz < f1_hz <= 24000, got {self.f0_hz}..{self.f1_hz}")
        if not 0 < self.chirp_duration_s < self.slot_s:
            raise ConfigError(f"acoustic.chirp_duration_s must lie in (0, slot_s), got {self.chirp_duration_s}")
        if not 0.0 <= self.taper_fraction <= 1.0:
            raise ConfigError(f"acoustic.taper_fraction must lie in [0, 1], got {self.taper_fraction}")
        if not isinstance(self.n_slots, int) or self.n_slots < 1:
            raise ConfigError(f"acoustic.n_slots must be a positive integer, got {self.n_slots!r}")

    @property
    def frame_s(self) -> float:
        """TDMA frame period, s: every beacon transmits once per frame."""
        return self.n_slots * self.slot_s


@dataclass(frozen=True)
class Beacon:
    """An acoustic beacon on a pole (ENU metres); ``slot`` is its TDMA slot index."""

    id: int
    east_m: float
    north_m: float
    up_m: float
    slot: int
    f0_hz: float | None = None
    f1_hz: float | None = None
    chirp_duration_s: float | None = None

    def __post_init__(self):
        _require_finite(self, "east_m", "north_m", "up_m")
        if not isinstance(self.id, int) or not isinstance(self.slot, int) or self.slot < 0:
            raise ConfigError(f"beacon id and slot must be integers (slot >= 0), got id={self.id!r} slot={self.slot!r}")


@dataclass(frozen=True)
class Box:
    """An axis-aligned structure standing on the ground (ENU metres).

    ``porous`` structures (lattice gantries) attenuate but do not block.
    """

    kind: str
    material: str
    porous: bool
    east_min_m: float
    east_max_m: float
    north_min_m: float
    north_max_m: float
    height_m: float

    def __post_init__(self):
        _require_finite(self, "east_min_m", "east_max_m", "north_min_m", "north_max_m", "height_m")
        if self.kind not in BOX_KINDS:
            raise ConfigError(f"layout kind must be one of {BOX_KINDS}, got {self.kind!r}")
        if self.east_max_m <= self.east_min_m or self.north_max_m <= self.north_min_m or self.height_m <= 0:
            raise ConfigError(f"layout box {self.kind} has an empty extent")

    @property
    def centre_en(self) -> tuple[float, float]:
        return (0.5 * (self.east_min_m + self.east_max_m), 0.5 * (self.north_min_m + self.north_max_m))


@dataclass(frozen=True)
class EmiZone:
    """A zone of electromagnetic interference lowering every C/N0 by up to ``loss_db`` at its centre."""

    east_m: float
    north_m: float
    radius_m: float
    loss_db: float

    def __post_init__(self):
        _require_finite(self, "east_m", "north_m", "radius_m", "loss_db")
        if self.radius_m <= 0 or self.loss_db < 0:
            raise ConfigError(f"emi zone needs radius_m > 0 and loss_db >= 0, got {self.radius_m}, {self.loss_db}")


@dataclass(frozen=True)
class UwbAnchor:
    """A UWB anchor as surveyed (ENU metres) with the boresight of its PDoA antenna pair.

    ``boresight_deg`` is the azimuth of the array's normal, degrees clockwise from north (the navigation
    convention of headings); the anchor measures a tag's angle of arrival relative to it
    (:mod:`features.uwb.reader` states the sign).
    """

    id: int
    east_m: float
    north_m: float
    up_m: float
    boresight_deg: float = 0.0

    def __post_init__(self):
        _require_finite(self, "east_m", "north_m", "up_m", "boresight_deg")
        if isinstance(self.id, bool) or not isinstance(self.id, int) or self.id < 0:
            raise ConfigError(f"uwb anchor id must be a non-negative integer, got {self.id!r}")
        if not -360.0 <= self.boresight_deg <= 360.0:
            raise ConfigError(f"uwb anchor {self.id}: boresight_deg must lie in [-360, 360], got {self.boresight_deg}")


@dataclass(frozen=True)
class Site:
    """A substation: origin, grid, acoustic beacons and (simulated sites) layout."""

    name: str
    origin: Origin
    device_height_m: float = 1.0
    atmosphere: Atmosphere = field(default_factory=Atmosphere)
    grid: Grid = field(default_factory=Grid)
    acoustic: AcousticConfig = field(default_factory=AcousticConfig)
    beacons: tuple[Beacon, ...] = ()
    layout: tuple[Box, ...] = ()
    emi_zones: tuple[EmiZone, ...] = ()
    seed: int | None = None
    uwb_anchors: tuple[UwbAnchor, ...] = ()

    def __post_init__(self):
        _require_finite(self, "device_height_m")
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError("site name must be a non-empty string")
        if not 0.0 < self.device_height_m < 5.0:
            raise ConfigError(f"device_height_m must lie in (0, 5), got {self.device_height_m}")
        ids = [b.id for b in self.beacons]
        if len(set(ids)) != len(ids):
            raise ConfigError("beacon ids must be unique")
        for b in self.beacons:
            if b.slot >= self.acoustic.n_slots:
                raise ConfigError(f"beacon {b.id} slot {b.slot} >= acoustic.n_slots {self.acoustic.n_slots}")
        _check_beacon_protocol(self.beacons, self.acoustic)
        uwb_ids = [a.id for a in self.uwb_anchors]
        if len(set(uwb_ids)) != len(uwb_ids):
            raise ConfigError("uwb anchor ids must be unique")

    @functools.cached_property
    def beacon_by_id(self) -> dict:
        """Beacon id → :class:`Beacon` (built once per site; the receiver looks beacons up every frame)."""
        return {b.id: b for b in self.beacons}

    def to_dict(self) -> dict:
        """Plain-dict form for TOML (``None`` fields omitted)."""
        def clean(d):
            return {k: v for k, v in d.items() if v is not None}
        out = {"name": self.name, "device_height_m": self.device_height_m}
        if self.seed is not None:
            out["seed"] = self.seed
        out["origin"] = asdict(self.origin)
        out["atmosphere"] = asdict(self.atmosphere)
        out["grid"] = asdict(self.grid)
        out["acoustic"] = asdict(self.acoustic)
        out["beacons"] = [clean(asdict(b)) for b in self.beacons]
        if self.layout:
            out["layout"] = [asdict(b) for b in self.layout]
        if self.emi_zones:
            out["emi_zones"] = [asdict(z) for z in self.emi_zones]
        if self.uwb_anchors:
            out["uwb_anchors"] = [asdict(a) for a in self.uwb_anchors]
        return out


def _check_beacon_protocol(beacons, acoustic: AcousticConfig) -> None:
    """Per-beacon chirps fit their slot and band; slot-mates whose bands overlap stand at least
    :data:`SLOT_REUSE_MIN_M` apart (frequency-divided beacons, in disjoint bands, may share a slot anywhere)."""
    for b in beacons:
        for name in ("f0_hz", "f1_hz", "chirp_duration_s"):
            v = getattr(b, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
                raise ConfigError(f"[[beacons]] id {b.id}: {name} must be a finite number, got {v!r}")
        if b.chirp_duration_s is not None and not 0 < b.chirp_duration_s < acoustic.slot_s:
            raise ConfigError(f"[[beacons]] id {b.id}: chirp_duration_s {b.chirp_duration_s:g} must lie in "
                              f"(0, acoustic.slot_s = {acoustic.slot_s:g}): a chirp longer than its slot "
                              f"overlaps the next beacon's")
        f0 = acoustic.f0_hz if b.f0_hz is None else b.f0_hz
        f1 = acoustic.f1_hz if b.f1_hz is None else b.f1_hz
        if not 0 < f0 < f1 <= 24_000.0:
            raise ConfigError(f"[[beacons]] id {b.id}: band must satisfy 0 < f0_hz < f1_hz <= 24000, got {f0:g}..{f1:g}")
    def band(b):
        return (acoustic.f0_hz if b.f0_hz is None else b.f0_hz, acoustic.f1_hz if b.f1_hz is None else b.f1_hz)

    for i, a in enumerate(beacons):
        for b in beacons[i + 1:]:
            (a0, a1), (b0, b1) = band(a), band(b)
            if a.slot == b.slot and a0 < b1 and b0 < a1:  # same slot, overlapping bands: they would collide
                d = math.hypot(a.east_m - b.east_m, a.north_m - b.north_m)
                if d < SLOT_REUSE_MIN_M:
                    raise ConfigError(f"[[beacons]] id {a.id} and id {b.id} share slot {a.slot} and band but "
                                      f"stand {d:.1f} m apart; a slot is reused only by beacons at least "
                                      f"{SLOT_REUSE_MIN_M:g} m apart or in disjoint bands (give one of them "
                                      f"another slot)")


def _build(cls, data, where: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {type(data).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}")
    try:
        return cls(**data)
    except TypeError as exc:
        from dataclasses import MISSING

        required = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING}
        missing = sorted(required - set(data))
        raise ConfigError(f"{where}: missing key(s) {missing}" if missing else f"{where}: {exc}") from None
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def site_from_dict(data: dict, where: str = "site.toml") -> Site:
    """Build a validated :class:`Site` from the parsed TOML mapping."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table")
    if "origin" not in data:
        raise ConfigError(f"{where}: missing [origin] table (lat_deg, lon_deg, alt_m)")
    if "name" not in data:
        raise ConfigError(f"{where}: missing 'name'")
    known = {"name", "device_height_m", "seed", "origin", "atmosphere", "grid", "acoustic", "beacons", "layout", "emi_zones",
             "uwb_anchors"}
    unknown = set(data) - known
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}")

    def listed(key, cls):
        items = data.get(key, [])
        if not isinstance(items, list):
            raise ConfigError(f"{where}: '{key}' must be an array of tables")
        return tuple(_build(cls, it, f"{where} [[{key}]] #{i + 1}"
                            + (f" (id {it['id']})" if isinstance(it, dict) and "id" in it else ""))
                     for i, it in enumerate(items))

    try:
        return Site(
            name=data["name"],
            origin=_build(Origin, data["origin"], f"{where} [origin]"),
            device_height_m=data.get("device_height_m", 1.0),
            atmosphere=_build(Atmosphere, data.get("atmosphere", {}), f"{where} [atmosphere]"),
            grid=_build(Grid, data.get("grid", {}), f"{where} [grid]"),
            acoustic=_build(AcousticConfig, data.get("acoustic", {}), f"{where} [acoustic]"),
            beacons=listed("beacons", Beacon),
            layout=listed("layout", Box),
            emi_zones=listed("emi_zones", EmiZone),
            seed=data.get("seed"),
            uwb_anchors=listed("uwb_anchors", UwbAnchor),
        )
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None


def load_site(path: str | os.PathLike) -> Site:
    """Load ``site.toml`` (or a directory holding one)."""
    path = Path(path)
    if path.is_dir():
        path = path / "site.toml"
    return site_from_dict(read_toml(path), where=str(path))


def save_site(site: Site, path: str | os.PathLike) -> None:
    """Write ``site.toml`` atomically."""
    write_toml(path, site.to_dict())
