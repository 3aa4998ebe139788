"""A walk's acoustic ranges, one row per associated beacon chirp, for tightly coupled fusion.

The acoustic receiver (:func:`features.acoustic.features.analyse_audio`) solves each TDMA frame's
pseudoranges for a fix; a frame with fewer than three associated beacons, or whose fix failed the
residual test, leaves no fix but still holds ranges. :func:`range_rows` turns every frame's associated
detections into :class:`models.graph.tight.RangeRows` with the receiver's own range model
(:func:`features.acoustic.frame_fix.frame_ranges`: c from the site's air temperature, the chirp's
range–Doppler lag, σ from the TOA Cramér–Rao bound and the air's path error; no motion or torso
correction — the graph knows the motion), each range's time its stated arrival less the clock offset of
the nearest fix in time.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from features.acoustic.detection import beacon_chirp_spec
from features.acoustic.frame_fix import frame_ranges
from features.acoustic.positions import PositionConfig
from features.acoustic.timing import speed_of_sound_m_s
from models.graph.tight import RangeRows

__all__ = ["range_rows"]


def range_rows(frames: list, fixes: list, site, config: PositionConfig | None = None) -> RangeRows:
    """Ranges of ``frames`` (:class:`features.acoustic.detection.FrameResult`), clock hints from ``fixes``
    (:class:`features.acoustic.positions.AcousticFix`), on ``site``."""
    # no motion term: the graph places each range at its own time on the track
    cfg = dataclasses.replace(config or PositionConfig(), motion_speed_m_s=0.0)
    c = speed_of_sound_m_s(site.atmosphere.temperature_c)
    specs = {b.id: beacon_chirp_spec(site, b) for b in site.beacons}
    bandwidth = {k: s.bandwidth_hz for k, s in specs.items()}
    lag = {k: s.range_doppler_lag_s for k, s in specs.items()}
    fix_t = np.array([f.t_s for f in fixes])
    fix_clock = np.array([f.clock_offset_s for f in fixes])
    rows = []
    for fr in frames:
        used = [d for d in fr.detections if d.associated]
        if not used:
            continue
        ranges, t_mean = frame_ranges(used, site, c, bandwidth, cfg, None, lag, 0.0, None)
        if fix_t.size:
            j = int(np.argmin(np.abs(fix_t - t_mean)))
            clock = float(fix_clock[j])
        else:
            clock = float("nan")
        for r in ranges:
            rows.append((fr.frame, r.arrival_s - (0.0 if np.isnan(clock) else clock), r.east_m, r.north_m, r.up_m,
                         r.pseudorange_m, r.sigma_m, c * clock))
    a = np.array(rows, float).reshape(-1, 8)
    return RangeRows(a[:, 0].astype(np.int64), a[:, 1], a[:, 2:5], a[:, 5], a[:, 6], a[:, 7],
                     float(site.device_height_m))
