"""numba kernels for axial port cameras: tracing in the ray's plane and per-point projection.

The geometry is documented in :mod:`sea3d.refraction.ports`; these kernels compute exactly the
same quantities one point at a time in registers, in parallel over points.

Parameter vector layout (float64):
    dome: [kind=0, c, r_inner, r_outer, n_air/n_glass, n_glass/n_water]
    flat: [kind=1, d_inner, thickness, n_air/n_glass, n_glass/n_water, 0]
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sea3d._typing import FloatArray
from sea3d.geometry._kernels import undistort_point

KIND_DOME = 0.0
KIND_FLAT = 1.0

_MAX_ITER = 40
_ANGLE_TOL = 1e-14
_FD = 1e-7
_NAN = math.nan


@nb.njit(cache=True, inline="always")
def _refract2(dx: float, dy: float, nx: float, ny: float, eta: float) -> tuple[float, float]:
    cos_i = -(nx * dx + ny * dy)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    if sin2_t > 1.0 or cos_i < 0.0:
        return _NAN, _NAN
    coef = eta * cos_i - math.sqrt(1.0 - sin2_t)
    return eta * dx + coef * nx, eta * dy + coef * ny


@nb.njit(cache=True)
def trace(theta: float, p: FloatArray) -> tuple[float, float, float, float]:
    """In-air ray at angle ``theta`` from the axis -> water ray (origin x, y, direction x, y)."""
    return trace_dir(math.cos(theta), math.sin(theta), p)


@nb.njit(cache=True)
def trace_dir(dx: float, dy: float, p: FloatArray) -> tuple[float, float, float, float]:
    """:func:`trace` for the unit in-air direction ``(dx, dy)`` in plane coordinates."""
    if p[0] == KIND_DOME:
        c, r1, r2 = p[1], p[2], p[3]
        dc = c * dx
        lam1 = dc + math.sqrt(dc * dc - c * c + r1 * r1)
        p1x = lam1 * dx
        p1y = lam1 * dy
        gx, gy = _refract2(dx, dy, -(p1x - c) / r1, -p1y / r1, p[4])
        dq = gx * (p1x - c) + gy * p1y
        disc = dq * dq - r1 * r1 + r2 * r2
        if not disc >= 0.0:
            return _NAN, _NAN, _NAN, _NAN
        lam2 = -dq + math.sqrt(disc)
        p2x = p1x + lam2 * gx
        p2y = p1y + lam2 * gy
        wx, wy = _refract2(gx, gy, -(p2x - c) / r2, -p2y / r2, p[5])
        return p2x, p2y, wx, wy
    # flat port: planes x = d and x = d + t in plane coordinates
    if dx <= 1e-12:
        return _NAN, _NAN, _NAN, _NAN
    d, t = p[1], p[2]
    p1x = d
    p1y = d * dy / dx
    gx, gy = _refract2(dx, dy, -1.0, 0.0, p[3])
    if not gx > 0.0:
        return _NAN, _NAN, _NAN, _NAN
    lam2 = t / gx
    p2x = p1x + lam2 * gx
    p2y = p1y + lam2 * gy
    wx, wy = _refract2(gx, gy, -1.0, 0.0, p[4])
    return p2x, p2y, wx, wy


@nb.njit(cache=True, inline="always")
def _residual(theta: float, px: float, py: float, p: FloatArray) -> float:
    ox, oy, wx, wy = trace(theta, p)
    return wx * (py - oy) - wy * (px - ox)


@nb.njit(cache=True)
def _solve_angle(x: float, y: float, th: float, p: FloatArray) -> float:
    """Angle of the in-air ray whose water ray passes through plane point ``(x, y)``.

    Newton's first step takes a central-difference slope; later steps are secant steps (one
    trace each), clipped to 0.2 rad. Converged when the step is below 1e-14 rad; then checked:
    the residual must be below 1e-9 m per metre of range and the point ahead of the water ray.
    NaN if there is no solution.
    """
    f = _residual(th, x, y, p)
    fp = (_residual(th + _FD, x, y, p) - _residual(th - _FD, x, y, p)) / (2.0 * _FD)
    for _ in range(_MAX_ITER):
        step = f / fp
        if not math.isfinite(step):
            return _NAN
        if step > 0.2:
            step = 0.2
        elif step < -0.2:
            step = -0.2
        th_new = th - step
        if abs(step) <= _ANGLE_TOL:
            th = th_new
            break
        f_new = _residual(th_new, x, y, p)
        if f_new == f:
            th = th_new
            break
        fp = (f_new - f) / (th_new - th)
        th = th_new
        f = f_new
    ox, oy, wx, wy = trace(th, p)
    f = wx * (y - oy) - wy * (x - ox)
    ahead = wx * (x - ox) + wy * (y - oy)
    dist = math.hypot(x - ox, y - oy)
    if not (abs(f) <= 1e-9 * max(dist, 1.0) and ahead > 0.0):
        return _NAN
    return th


@nb.njit(cache=True, inline="always")
def _perpendicular(a: FloatArray) -> tuple[float, float, float]:
    """A unit vector perpendicular to unit ``a``."""
    if abs(a[0]) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    cx = a[1] * hz - a[2] * hy
    cy = a[2] * hx - a[0] * hz
    cz = a[0] * hy - a[1] * hx
    n = math.sqrt(cx * cx + cy * cy + cz * cz)
    return cx / n, cy / n, cz / n


@nb.njit(cache=True, parallel=True)
def unproject_port(
    uv: FloatArray,
    intrinsics: FloatArray,
    k: FloatArray,
    tilt_inv: FloatArray,
    distorted: bool,
    a: FloatArray,
    p: FloatArray,
) -> FloatArray:
    """Water rays of pixels ``uv`` ``(N, 2)``.

    ``intrinsics`` is ``[fx, fy, cx, cy]``; ``k`` the 14 OpenCV distortion coefficients and
    ``tilt_inv`` the inverse tilt homography (used only if ``distorted``); ``a`` the port's
    unit axis. Returns ``(N, 6)``: origin on the outer port surface and unit direction, camera
    frame; NaN rows where there is no ray.
    """
    n = uv.shape[0]
    out = np.empty((n, 6))
    for i in nb.prange(n):
        xn = (uv[i, 0] - intrinsics[2]) / intrinsics[0]
        yn = (uv[i, 1] - intrinsics[3]) / intrinsics[1]
        if distorted:
            xn, yn, ok = undistort_point(xn, yn, k, tilt_inv)
            if not ok:
                for j in range(6):
                    out[i, j] = _NAN
                continue
        inv = 1.0 / math.sqrt(xn * xn + yn * yn + 1.0)
        dx, dy, dz = xn * inv, yn * inv, inv
        along = dx * a[0] + dy * a[1] + dz * a[2]
        bx, by, bz = dx - along * a[0], dy - along * a[1], dz - along * a[2]
        across = math.sqrt(bx * bx + by * by + bz * bz)
        if across > 1e-300:
            bx, by, bz = bx / across, by / across, bz / across
        else:
            bx, by, bz = _perpendicular(a)
        ox, oy, wx, wy = trace_dir(along, across, p)
        out[i, 0] = ox * a[0] + oy * bx
        out[i, 1] = ox * a[1] + oy * by
        out[i, 2] = ox * a[2] + oy * bz
        ux = wx * a[0] + wy * bx
        uy = wx * a[1] + wy * by
        uz = wx * a[2] + wy * bz
        un = math.sqrt(ux * ux + uy * uy + uz * uz)
        out[i, 3] = ux / un
        out[i, 4] = uy / un
        out[i, 5] = uz / un
        if not (math.isfinite(out[i, 0]) and math.isfinite(out[i, 3])):
            for j in range(6):
                out[i, j] = _NAN
    return out


@nb.njit(cache=True, parallel=True)
def project_port(points: FloatArray, a: FloatArray, p: FloatArray) -> FloatArray:
    """In-air unit directions ``(N, 3)`` whose refracted rays pass through ``points``.

    NaN rows where a point is inside the port or has no refracted path.
    """
    n = points.shape[0]
    out = np.empty((n, 3))
    for i in nb.prange(n):
        X, Y, Z = points[i, 0], points[i, 1], points[i, 2]
        px = X * a[0] + Y * a[1] + Z * a[2]
        bx, by, bz = X - px * a[0], Y - px * a[1], Z - px * a[2]
        py = math.sqrt(bx * bx + by * by + bz * bz)
        if py > 1e-300:
            bx, by, bz = bx / py, by / py, bz / py
        else:
            bx, by, bz = _perpendicular(a)
        if p[0] == KIND_DOME:
            inside = math.hypot(px - p[1], py) <= p[3]
            th0 = math.atan2(py, px)
        else:
            inside = px <= p[1] + p[2]
            # Treat the port as infinitely thin at the camera: Snell between the two media.
            s = math.sin(math.atan2(py, px - p[1] - p[2])) / (p[3] * p[4])
            s = min(max(s, -0.999), 0.999)
            th0 = math.asin(s)
        th = _NAN if inside or not math.isfinite(px + py) else _solve_angle(px, py, th0, p)
        c, s2 = math.cos(th), math.sin(th)
        out[i, 0] = c * a[0] + s2 * bx
        out[i, 1] = c * a[1] + s2 * by
        out[i, 2] = c * a[2] + s2 * bz
    return out
