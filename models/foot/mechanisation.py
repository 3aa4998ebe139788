"""Strapdown mechanisation of a foot-mounted IMU: quaternion attitude, gravity removed in the local frame.

Frames
    Navigation frame: local east-north-up (ENU), metres about the start (docs/design.md §3); gravity
    g_n = (0, 0, −g). Body frame: the IMU's own axes, whatever they are (the filter never assumes a
    mounting). Attitude: the unit quaternion q = (w, x, y, z) rotating body vectors into the navigation
    frame, v_n = C(q) v_b.

Per sample k (interval Δt, specific force f_b, angular rate ω_b):

1. attitude: q ← q ⊗ Δq(θ) with θ = (ω_b − Cᵀ ω_ie,n) Δt and Δq(θ) = (cos |θ|/2, sin(|θ|/2) θ/|θ|),
   the exact quaternion of a rotation vector held constant over the interval (Titterton & Weston 2004,
   *Strapdown Inertial Navigation Technology*, 2nd ed., ch. 11; Savage 1998, JGCD 21(1));
2. specific force to the local frame and gravity removed: a_n = C(q) f_b + g_n;
3. velocity and position: v ← v + a_n Δt, p ← p + v Δt + ½ a_n Δt² (the OpenShoe navigation equations,
   Nilsson, Skog, Händel & Hari 2012, "Foot-mounted INS for everybody — an open-source embedded
   implementation", IEEE/ION PLANS, §III; the transport rate and gravity's variation over a walk are
   below the MEMS noise and left out, as there).

The initial roll and pitch come from the mean specific force of a still spell (the accelerometer then
reads −g in the body frame: leveling, Groves 2013, *Principles of GNSS, Inertial, and Multisensor
Integrated Navigation Systems*, 2nd ed., ch. 5); the initial yaw from a tilt-compensated magnetic
heading when there is a magnetometer, else given.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["quat_mul", "quat_from_rotvec", "quat_to_dcm", "dcm_to_quat", "skew", "strapdown_step", "level_attitude",
           "yaw_of", "GRAVITY_ENU_M_S2"]

GRAVITY_ENU_M_S2 = np.array([0.0, 0.0, -9.80665])
"""Gravity in the local ENU frame, m/s² (standard gravity, BIPM; the local value differs by < 0.3 %)."""


@njit(cache=True)
def quat_mul(p, q):
    """Hamilton product p ⊗ q of quaternions (w, x, y, z), shape (4,)."""
    return np.array([p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
                     p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
                     p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
                     p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]])


@njit(cache=True)
def quat_from_rotvec(theta):
    """Quaternion of the rotation vector θ (3,), rad: (cos |θ|/2, sin(|θ|/2) θ/|θ|) (Titterton & Weston
    ch. 11); the first-order form (1, θ/2) normalised below 1e-12 rad."""
    a = math.sqrt(theta[0] ** 2 + theta[1] ** 2 + theta[2] ** 2)
    if a < 1e-12:
        q = np.array([1.0, 0.5 * theta[0], 0.5 * theta[1], 0.5 * theta[2]])
        return q / math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    s = math.sin(0.5 * a) / a
    return np.array([math.cos(0.5 * a), s * theta[0], s * theta[1], s * theta[2]])


@njit(cache=True)
def quat_to_dcm(q):
    """Direction-cosine matrix C (3, 3) of the unit quaternion q: v_n = C v_b (Titterton & Weston ch. 3)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    C = np.empty((3, 3))
    C[0, 0] = w * w + x * x - y * y - z * z
    C[0, 1] = 2.0 * (x * y - w * z)
    C[0, 2] = 2.0 * (x * z + w * y)
    C[1, 0] = 2.0 * (x * y + w * z)
    C[1, 1] = w * w - x * x + y * y - z * z
    C[1, 2] = 2.0 * (y * z - w * x)
    C[2, 0] = 2.0 * (x * z - w * y)
    C[2, 1] = 2.0 * (y * z + w * x)
    C[2, 2] = w * w - x * x - y * y + z * z
    return C


@njit(cache=True)
def dcm_to_quat(C):
    """Unit quaternion (w ≥ 0) of a rotation matrix, by the largest-diagonal branch (Shepperd 1978, JGC 1(3))."""
    tr = C[0, 0] + C[1, 1] + C[2, 2]
    if tr > C[0, 0] and tr > C[1, 1] and tr > C[2, 2]:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = np.array([0.25 * s, (C[2, 1] - C[1, 2]) / s, (C[0, 2] - C[2, 0]) / s, (C[1, 0] - C[0, 1]) / s])
    elif C[0, 0] > C[1, 1] and C[0, 0] > C[2, 2]:
        s = 2.0 * math.sqrt(1.0 + C[0, 0] - C[1, 1] - C[2, 2])
        q = np.array([(C[2, 1] - C[1, 2]) / s, 0.25 * s, (C[0, 1] + C[1, 0]) / s, (C[0, 2] + C[2, 0]) / s])
    elif C[1, 1] > C[2, 2]:
        s = 2.0 * math.sqrt(1.0 + C[1, 1] - C[0, 0] - C[2, 2])
        q = np.array([(C[0, 2] - C[2, 0]) / s, (C[0, 1] + C[1, 0]) / s, 0.25 * s, (C[1, 2] + C[2, 1]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + C[2, 2] - C[0, 0] - C[1, 1])
        q = np.array([(C[1, 0] - C[0, 1]) / s, (C[0, 2] + C[2, 0]) / s, (C[1, 2] + C[2, 1]) / s, 0.25 * s])
    if q[0] < 0:
        q = -q
    return q / math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)


@njit(cache=True)
def skew(v):
    """[v×] (3, 3): skew(v) @ u = v × u."""
    S = np.zeros((3, 3))
    S[0, 1] = -v[2]
    S[0, 2] = v[1]
    S[1, 0] = v[2]
    S[1, 2] = -v[0]
    S[2, 0] = -v[1]
    S[2, 1] = v[0]
    return S


@njit(cache=True)
def strapdown_step(q, v, p, f_b, w_b, dt, g_n, w_ie_n):
    """One strapdown step (module docstring, steps 1–3). Returns (q, v, p, f_n) after the interval ``dt`` (s);
    ``f_b`` m/s², ``w_b`` rad/s (body), ``g_n`` and ``w_ie_n`` (3,) gravity (m/s²) and Earth rate (rad/s) in
    the local frame; f_n the specific force in the local frame (the error model's F needs it)."""
    C = quat_to_dcm(q)
    # θ = (ω_b − Cᵀ ω_ie,n) Δt
    w = w_b - C.T @ w_ie_n
    # q ← q ⊗ Δq(θ), renormalised against rounding
    qn = quat_mul(q, quat_from_rotvec(w * dt))
    qn = qn / math.sqrt(qn[0] ** 2 + qn[1] ** 2 + qn[2] ** 2 + qn[3] ** 2)
    # a_n = C f_b + g_n   (with the attitude at the interval's end, as OpenShoe)
    f_n = quat_to_dcm(qn) @ f_b
    a = f_n + g_n
    # p ← p + v Δt + ½ a Δt²;  v ← v + a Δt
    pn = p + v * dt + 0.5 * a * dt * dt
    vn = v + a * dt
    return qn, vn, pn, f_n


def level_attitude(f_b: np.ndarray, yaw_rad: float = 0.0) -> np.ndarray:
    """Quaternion of a still IMU whose mean specific force is ``f_b`` (3,), with heading ``yaw_rad``.

    Roll and pitch level the body so that C f_b points up (an accelerometer at rest measures −g, i.e. +g·up
    in ENU; Groves 2013 ch. 5); the yaw is the heading, rad from north clockwise, of the body's x axis
    (its horizontal projection; when x is near vertical, of the body's y axis minus 90°).
    """
    f = np.asarray(f_b, float)
    if not np.all(np.isfinite(f)) or np.linalg.norm(f) < 1e-6:
        raise ValueError(f"leveling needs a finite, non-zero mean specific force, got {f}")
    up_b = f / np.linalg.norm(f)
    # a body axis that is not vertical gives the horizontal reference
    ref = np.array([1.0, 0.0, 0.0]) if abs(up_b[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_h = ref - up_b * (ref @ up_b)
    x_h /= np.linalg.norm(x_h)
    y_h = np.cross(up_b, x_h)
    # rows: the body-frame coordinates of the levelled frame's x (the reference's horizontal part), y, up
    C_level = np.vstack([x_h, y_h, up_b])          # body → levelled (x_h east-like, up)
    psi = yaw_rad if ref[0] == 1.0 else yaw_rad - 0.5 * math.pi
    # heading ψ from north clockwise: the reference points at east = sin ψ, north = cos ψ
    # rotation about up taking levelled x (ENU east) to (sin ψ, cos ψ, 0): angle α = π/2 − ψ counter-clockwise
    a = 0.5 * math.pi - psi
    Rz = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return dcm_to_quat(Rz @ C_level)


def yaw_of(q: np.ndarray) -> float:
    """Heading of the body's x axis, rad from north clockwise (ENU frame: atan2(east, north))."""
    C = quat_to_dcm(np.asarray(q, float))
    return float(math.atan2(C[0, 0], C[1, 0]))
