"""The receiver's own error statistics of its fix, as NMEA GST reports them.

GST ("GNSS pseudorange error statistics", NMEA 0183 v4.10): UTC time, the RMS
of the range residuals, the semi-major and semi-minor axes of the horizontal
error ellipse and the semi-major axis' orientation, and the σ of latitude,
longitude and altitude, all 1σ in metres. Receivers fill them from their
solution's covariance scaled by the a-posteriori variance factor of their own
residuals, so a bias the solution has absorbed (NLOS, a wrong integer fix)
leaves σ far too small — what the public low-cost RTK log shows (fixed epochs
scattered 0.85 m with GST σ 0.014 m).
"""

from __future__ import annotations

import numpy as np

__all__ = ["gst_fields"]


def gst_fields(cov_enu_m2: np.ndarray, var_factor: np.ndarray, rms_m: np.ndarray) -> np.ndarray:
    """NMEA GST fields 2–8 from a solution's covariance, shape (n, 7): RMS of the residuals, σ of the semi-major
    and semi-minor axes of the horizontal error ellipse, the semi-major axis' orientation (degrees from true
    north, clockwise, in [0, 180)), σ latitude (north), σ longitude (east), σ altitude (up); metres.

    The covariance is the receiver's (GᵀWG)⁻¹ scaled by its a-posteriori variance factor (``var_factor``,
    σ̂₀² = rᵀWr/(m − p); Teunissen 2000, *Adjustment Theory*, §1.3). NaN rows where either is NaN.

    >>> c = np.array([[[4.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 9.0]]])
    >>> gst_fields(c, np.array([1.0]), np.array([0.5])).round(3).tolist()
    [[0.5, 2.0, 1.0, 90.0, 1.0, 2.0, 3.0]]
    """
    c = np.asarray(cov_enu_m2, float) * np.asarray(var_factor, float)[:, None, None]
    cee, cnn, cen, cuu = c[:, 0, 0], c[:, 1, 1], c[:, 0, 1], c[:, 2, 2]
    half_tr = 0.5 * (cee + cnn)
    root = np.sqrt(np.maximum(0.25 * (cee - cnn) ** 2 + cen ** 2, 0.0))
    l1, l2 = half_tr + root, np.maximum(half_tr - root, 0.0)
    # Direction of the major axis: (e, n) ∝ (l1 − cnn, cen), or (cen, l1 − cee); azimuth from north, clockwise.
    ve = np.where(np.abs(l1 - cnn) + np.abs(cen) > 0, l1 - cnn, 0.0)
    vn = np.where(np.abs(l1 - cnn) + np.abs(cen) > 0, cen, 1.0)
    orient = np.mod(np.degrees(np.arctan2(ve, vn)), 180.0)
    return np.column_stack([rms_m, np.sqrt(np.maximum(l1, 0.0)), np.sqrt(l2), orient, np.sqrt(np.maximum(cnn, 0.0)),
                            np.sqrt(np.maximum(cee, 0.0)), np.sqrt(np.maximum(cuu, 0.0))])
