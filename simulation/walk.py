"""Simulated walk logs: ``walk.toml``, ``truth.csv`` and every sensor stream (docs/design.md §4)."""

from __future__ import annotations

import os
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from features.errors import ConfigError
from features.fileio import atomic_directory, write_toml
from features.site import ENV_CLASSES, load_site
from features.walk import parse_utc

from simulation.site.environment import blocked_share, classify_share
from simulation.progress import Progress
from simulation.rng import stream_rng
from simulation.site.route import RouteConfig, plan_route, route_trajectory
from simulation.streams import STREAM_WRITERS, StreamContext, run_stream_writers

__all__ = ["DEFAULT_EPOCH_UTC", "default_start_utc", "parse_utc", "format_utc", "write_truth_csv", "simulate_walk",
           "device_height_m"]

DEFAULT_EPOCH_UTC = datetime(2026, 1, 1, tzinfo=timezone.utc)
"""Start of the year within which simulated walks and surveys start unless told otherwise."""

START_SPAN_DAYS = 365
"""Days after :data:`DEFAULT_EPOCH_UTC` over which seeded start times are spread."""


def default_start_utc(seed: int) -> datetime:
    """A start time drawn from the seed: a day of :data:`START_SPAN_DAYS` and a time of day (10 s steps),
    so sites and walks see different constellations — GPS geometry repeats each sidereal day, shifting
    ≈ 4 min a day, and BeiDou MEO every 7 days, so the day matters as well as the hour."""
    rng = stream_rng(seed, "start-time")
    day = int(rng.integers(0, START_SPAN_DAYS))
    return DEFAULT_EPOCH_UTC + timedelta(days=day, seconds=int(rng.integers(0, 86_400 // 10)) * 10)


def format_utc(t: datetime) -> str:
    """ISO 8601 UTC with milliseconds and a ``Z``, as walk.toml and cell.toml store times."""
    return t.astimezone(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def write_truth_csv(path: Path, site, trajectory, rate_hz: float = 10.0) -> None:
    """``truth.csv``: t_s, east_m, north_m, env_class, blocked_sky_share at ``rate_hz`` (class by the
    blocked-sky rule of :mod:`simulation.site.environment`; the share beside it tells every error's distance
    from a class boundary)."""
    step = max(1, int(round(trajectory.rate_hz / rate_hz)))
    t = trajectory.t_s[::step]
    e = trajectory.east_m[::step]
    n = trajectory.north_m[::step]
    # A walker standing at an inspection stop repeats one position for minutes: the share is computed once per
    # distinct position (mm), which also keeps the sky test's per-tile arrays small.
    uniq, inverse = np.unique(np.round(np.column_stack([e, n]), 3), axis=0, return_inverse=True)
    share = blocked_share(site, uniq[:, 0], uniq[:, 1])[inverse.ravel()]
    cls = [ENV_CLASSES[i] for i in classify_share(share)]
    lines = ["t_s,east_m,north_m,env_class,blocked_sky_share"]
    lines += [f"{ti:.2f},{ei:.3f},{ni:.3f},{ci},{si:.4f}" for ti, ei, ni, ci, si in zip(t, e, n, cls, share)]
    path.write_text("\n".join(lines) + "\n")


def device_height_m(site, person: int, sigma_m: float = 0.07) -> float:
    """The waist-worn device's true height for this walker, m: the site's nominal height plus N(0, σ), clipped
    to ±2.5σ — waist height varies by ≈ ±7 cm (1σ) among adults (anthropometric tables, e.g. NASA-STD-3000
    Vol. I §3, waist height), and the belt is worn higher or lower. ``site.toml`` keeps the nominal value."""
    d = float(stream_rng(person, "device-height").normal(0.0, sigma_m))
    return float(site.device_height_m + np.clip(d, -2.5 * sigma_m, 2.5 * sigma_m))


def simulate_walk(site_path: str | os.PathLike, out_dir: str | os.PathLike, seed: int, duration_s: float = 300.0,
                  person: int | None = None, start_utc: datetime | None = None, overwrite: bool = False,
                  options: dict | None = None, writers: tuple[str, ...] = STREAM_WRITERS,
                  route: RouteConfig = RouteConfig(), progress: bool = True) -> Path:
    """Simulate one walk through the site at ``site_path`` into the directory ``out_dir``.

    The directory is built under a temporary name and renamed into place only
    when every stream is written. Returns the output path. ``progress`` reports the streams written and the
    audio seconds rendered on stderr (a bar on a terminal, plain lines in a log; issue 12 item 17).
    """
    if not (np.isfinite(duration_s) and duration_s >= 1.0):
        raise ConfigError(f"--duration must be at least 1 s, got {duration_s}")
    if duration_s > 6 * 3600:
        raise ConfigError(f"--duration {duration_s} s is longer than the 6 h a walk log may span")
    site_path = Path(site_path)
    site_file = site_path / "site.toml" if site_path.is_dir() else site_path
    site = load_site(site_file)
    if not site.layout:
        raise ConfigError(f"{site_file}: has no [[layout]]; walks can only be simulated on a simulated site")
    person = seed if person is None else person
    start = start_utc or default_start_utc(seed)
    poly, stops, speed = plan_route(site, stream_rng(seed, "route"), duration_s, route)
    traj = route_trajectory(poly, stops, speed, duration_s, start, device_height_m(site, person), route)
    out_dir = Path(out_dir)
    with atomic_directory(out_dir, overwrite=overwrite) as tmp:
        opts = dict(options or {})
        opts.setdefault("progress", progress)
        ctx = StreamContext(site=site, trajectory=traj, out_dir=tmp, seed=seed, kind="walk", person_seed=person,
                            options=opts)
        meta = {}
        with Progress(len(writers), f"simulate walk {out_dir.name!r}: streams written", enabled=bool(opts["progress"]),
                      every_fraction=1e-9) as bar:
            for spec in writers:
                meta.update(run_stream_writers(ctx, (spec,)))
                bar.update(1)
        write_truth_csv(tmp / "truth.csv", site, traj)
        walk = {
            "name": out_dir.name,
            "site": os.path.relpath(site_file.resolve(), out_dir.resolve()),
            "site_name": site.name,
            "start_utc": format_utc(start),
            "duration_s": float(duration_s),
            "seed": int(seed),
            "person": int(person),
            "device_placement": "waist",
        }
        walk.update(meta)
        write_toml(tmp / "walk.toml", walk)
    return out_dir
