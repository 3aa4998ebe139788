"""The body's (waist's) horizontal track from a foot-mounted INS's track: the mid-stance rule.

A foot INS tracks its foot; the person — and every other method's output, and truth — is the body. In
walking the body's centre of mass passes over the stance foot at mid-stance: it vaults over the stance
leg as an inverted pendulum, behind the foot at heel strike and ahead of it at toe-off, and is directly
above it (in the direction of travel) when the leg is vertical at mid-stance (Winter 2009, *Biomechanics
and Motor Control of Human Movement*, 4th ed., §1.2.5 and ch. 10 on the gait cycle and the centre of
mass over the base of support; Perry & Burnfield 2010, *Gait Analysis*, 2nd ed., ch. 2, mid-stance "the
body advances over the stationary foot"). Across the direction of travel the body stays between the feet:
each foot is set half the step width (the walking base) to its side of the line of progression.

So, from the foot INS's positions at the middle of each stance spell of the instrumented foot,

    b_j = p_foot(t_j) − s · (w / 2) · r̂(ψ_j),    r̂(ψ) = (cos ψ, −sin ψ)  (east, north: the walker's right)

with s = +1 for a right foot, −1 for a left one, w the step width and ψ_j the direction of travel at
footfall j (from north, clockwise; the direction from footfall j − 1 to j + 1, the stride's chord; when
the neighbours are closer than :data:`MIN_CHORD_M` — standing, turning on the spot — the last direction
known), and the body between mid-stances is interpolated linearly in time (a standing stop, a stance
spell many times a walking one, anchors the body half a stance after its start and before its end:
:data:`LONG_SPELL`) (the body's forward speed varies
by a few per cent over a stride; Winter 2009 §10). Before the first and after the last mid-stance the body
holds the nearest anchor.

The step width is an assumption, not an estimate: ``step_width_m`` defaults to 0.08 m, the stride width
(heel centre to heel centre) of normal men walking freely, 8 ± 3.5 cm (Murray, Drought & Kory 1964,
"Walking patterns of normal men", J. Bone Joint Surg. 46-A(2):335–360); a crew that knows its walkers'
base (safety boots widen it) sets it. One foot alone cannot measure it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from models.foot.stance import StanceConfig, stance_spells

__all__ = ["BodyFromFoot", "mid_stance", "body_from_foot", "MIN_CHORD_M", "LONG_SPELL"]

MIN_CHORD_M = 0.3
"""Two footfalls of the same foot closer than this (m) give no direction of travel (a stride is ≈ 1.4 m)."""

LONG_SPELL = 2.0
"""A stance spell longer than this many times the walk's median spell is a stop (the walker stands): it is
anchored from half a median stance after its start to half a stance before its end, every half stance, so
the body stands over it (following the foot estimate's corrections) instead of drifting from the last
footfall to the stop's middle."""


@dataclass(frozen=True)
class BodyFromFoot:
    """The mid-stance rule's settings (module docstring): ``step_width_m`` the walking base w, m (Murray et
    al. 1964); ``side`` +1 for a right foot, −1 for a left one."""

    step_width_m: float = 0.08
    side: int = 1

    def __post_init__(self):
        if not (np.isfinite(self.step_width_m) and 0.0 <= self.step_width_m <= 0.6):
            raise ValueError(f"BodyFromFoot.step_width_m must lie in [0, 0.6] m, got {self.step_width_m}")
        if self.side not in (1, -1):
            raise ValueError(f"BodyFromFoot.side must be +1 (right foot) or -1 (left foot), got {self.side}")


def mid_stance(t_s: np.ndarray, en_m: np.ndarray, stance: np.ndarray, rate_hz: float,
               cfg: StanceConfig = StanceConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Times (m,) and foot positions (m, 2) at the middle sample of every stance spell (after
    :func:`models.foot.stance.stance_spells` closes a heel strike's jolt and drops flickers); a stop
    (:data:`LONG_SPELL`) gives one every half median stance from half a stance inside each of its ends."""
    spells = stance_spells(stance, rate_hz, cfg)
    if not len(spells):
        return np.zeros(0), np.zeros((0, 2))
    dur = spells[:, 1] - spells[:, 0]
    # half a walking stance, samples: the median spell is a walking one (stops are few and long)
    h = max(int(np.median(dur)) // 2, 1)
    idx = []
    for (a, b), d in zip(spells, dur):
        if d > LONG_SPELL * 2 * h:
            # a stop: the body arrives over the foot half a stance after foot-flat and leaves half a stance
            # before toe-off, and stands there in between — anchored every half stance, so that the body
            # follows the corrections (UWB) the foot's estimate gets while it stands
            idx += list(range(a + h, b - 1 - h, h)) + [b - 1 - h]
        else:
            idx.append((a + b - 1) // 2)
    idx = np.asarray(idx)
    return np.asarray(t_s, float)[idx], np.asarray(en_m, float)[idx, :2]


def _travel_direction(en_m: np.ndarray, fallback_rad: float) -> np.ndarray:
    """ψ_j (m,) from north clockwise: the chord from footfall j − 1 to j + 1 (one-sided at the ends); the last
    known direction where the chord is shorter than :data:`MIN_CHORD_M`, ``fallback_rad`` before any."""
    m = len(en_m)
    psi = np.empty(m)
    last = fallback_rad
    for j in range(m):
        d = en_m[min(j + 1, m - 1)] - en_m[max(j - 1, 0)]
        if np.hypot(d[0], d[1]) >= MIN_CHORD_M:
            last = float(np.arctan2(d[0], d[1]))
        psi[j] = last
    if m and not np.any(np.isfinite(psi)):
        psi[:] = 0.0
    return psi


def body_from_foot(t_s: np.ndarray, en_m: np.ndarray, stance: np.ndarray, rate_hz: float,
                   cfg: BodyFromFoot = BodyFromFoot(), stance_cfg: StanceConfig = StanceConfig(),
                   fallback_heading_rad: float = 0.0) -> np.ndarray:
    """The body's east/north (n, 2) at the foot INS's times ``t_s`` (n,) from its foot positions ``en_m``
    (n, ≥ 2) and stance flags (n,) by the mid-stance rule (module docstring). ``fallback_heading_rad``: the
    direction of travel when no two footfalls are :data:`MIN_CHORD_M` apart (e.g. the foot's own yaw).
    With no stance spell at all the foot track is returned unchanged."""
    t = np.asarray(t_s, float)
    en = np.asarray(en_m, float)[:, :2]
    t_mid, p_mid = mid_stance(t, en, stance, rate_hz, stance_cfg)
    if not len(t_mid):
        return en.copy()
    psi = _travel_direction(p_mid, fallback_heading_rad)
    # b_j = p_j − s (w/2) r̂(ψ_j),  r̂ = (cos ψ, −sin ψ): the walker's right in (east, north)
    half = 0.5 * cfg.step_width_m * cfg.side
    b = p_mid - half * np.column_stack([np.cos(psi), -np.sin(psi)])
    return np.column_stack([np.interp(t, t_mid, b[:, 0]), np.interp(t, t_mid, b[:, 1])])
