"""numba kernel for inverting OpenCV's lens distortion (see :mod:`sea3d.geometry.pinhole`)."""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sea3d._typing import FloatArray

__all__ = ["undistort", "undistort_point"]

_NAN = math.nan


@nb.njit(cache=True)
def undistort_point(
    xd: float, yd: float, k: FloatArray, tilt_inv: FloatArray
) -> tuple[float, float, bool]:
    """Invert OpenCV's distortion for one normalised point (14 coefficients, ``tilt_inv`` the
    inverse tilt homography, identity if none). Newton's method with the analytic Jacobian,
    stopped at a residual of 1e-14; ``ok`` is False unless the residual is below 1e-12."""
    # Undo the tilt first: it is applied after the radial/tangential model.
    hx = tilt_inv[0, 0] * xd + tilt_inv[0, 1] * yd + tilt_inv[0, 2]
    hy = tilt_inv[1, 0] * xd + tilt_inv[1, 1] * yd + tilt_inv[1, 2]
    hz = tilt_inv[2, 0] * xd + tilt_inv[2, 1] * yd + tilt_inv[2, 2]
    tx = hx / hz
    ty = hy / hz
    x = tx
    y = ty
    ex = math.inf
    ey = math.inf
    for _ in range(50):
        r2 = x * x + y * y
        r4 = r2 * r2
        r6 = r4 * r2
        num = 1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6
        den = 1.0 + k[5] * r2 + k[6] * r4 + k[7] * r6
        rad = num / den
        fx = x * rad + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x) + k[8] * r2 + k[9] * r4
        fy = y * rad + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y + k[10] * r2 + k[11] * r4
        ex = fx - tx
        ey = fy - ty
        if abs(ex) < 1e-14 and abs(ey) < 1e-14:
            return x, y, True
        # Analytic Jacobian of the distortion.
        dnum = k[0] + 2.0 * k[1] * r2 + 3.0 * k[4] * r4
        dden = k[5] + 2.0 * k[6] * r2 + 3.0 * k[7] * r4
        drad = (dnum * den - num * dden) / (den * den)  # d rad / d r2
        dr2x = 2.0 * x
        dr2y = 2.0 * y
        a = rad + x * drad * dr2x + 2.0 * k[2] * y + k[3] * (dr2x + 4.0 * x)
        a += k[8] * dr2x + 2.0 * k[9] * r2 * dr2x
        b = x * drad * dr2y + 2.0 * k[2] * x + k[3] * dr2y + k[8] * dr2y
        b += 2.0 * k[9] * r2 * dr2y
        c = y * drad * dr2x + k[2] * dr2x + 2.0 * k[3] * y + k[10] * dr2x
        c += 2.0 * k[11] * r2 * dr2x
        d = rad + y * drad * dr2y + k[2] * (dr2y + 4.0 * y) + 2.0 * k[3] * x
        d += k[10] * dr2y + 2.0 * k[11] * r2 * dr2y
        det = a * d - b * c
        if det == 0.0 or not math.isfinite(det):
            break
        x -= (d * ex - b * ey) / det
        y -= (-c * ex + a * ey) / det
    ok = abs(ex) < 1e-12 and abs(ey) < 1e-12
    return x, y, ok


@nb.njit(cache=True, parallel=True)
def undistort(xd: FloatArray, yd: FloatArray, k: FloatArray, tilt_inv: FloatArray) -> FloatArray:
    """:func:`undistort_point` for every point; ``(N, 2)``, NaN rows where it failed."""
    n = xd.shape[0]
    out = np.empty((n, 2))
    for i in nb.prange(n):
        x, y, ok = undistort_point(xd[i], yd[i], k, tilt_inv)
        if ok:
            out[i, 0] = x
            out[i, 1] = y
        else:
            out[i, 0] = _NAN
            out[i, 1] = _NAN
    return out
