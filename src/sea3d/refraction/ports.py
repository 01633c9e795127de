"""Dome- and flat-port cameras: a pinhole behind a refracting glass port.

Both are *axial* cameras: every refracted viewing ray stays in the plane that holds the camera
centre, the port's axis and the ray itself (the dome's axis runs through the dome centre; the flat
port's axis is its normal through the camera centre). Tracing is therefore done in 2D plane
coordinates ``(along axis, across axis)``, which is exact and fast, and ``project`` is a 1D
root-finding problem per point (a safeguarded Newton iteration on the in-air ray's angle): there is
no closed form (a flat port needs a 12th-degree polynomial, Agrawal et al. 2012; the paper's
Sec. 1.2.2).

Dome-port ray model (paper eqs. 2.11-2.16): the in-air ray ``K^-1 p / |K^-1 p|`` (eq. 2.12, with
lens distortion removed first) meets the inner sphere (radius ``r``, centre ``dome_center_m``,
eqs. 2.13-2.15), is refracted air -> glass, meets the outer sphere (radius ``r + thickness``,
eq. 2.16) and is refracted glass -> water. The water ray starts on the outer surface.

See ``docs/conventions.md`` for worked examples with the paper's dome.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import RefractionError
from sea3d.geometry.camera import Rays, as_pixels, as_points
from sea3d.geometry.pinhole import PinholeCamera

__all__ = [
    "N_ACRYLIC",
    "N_AIR",
    "N_WATER",
    "DomePort",
    "DomePortCamera",
    "FlatPort",
    "FlatPortCamera",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

# Indices from the paper's Table 2.4 (air, sea water, acrylic).
N_AIR = 1.000292
N_WATER = 1.333
N_ACRYLIC = 1.492

_NEWTON_MAX_ITER = 40
_ANGLE_TOL_RAD = 1e-14
_FD_STEP_RAD = 1e-7


def _check_indices(where: str, n_air: float, n_glass: float, n_water: float) -> None:
    for name, value in (("n_air", n_air), ("n_glass", n_glass), ("n_water", n_water)):
        if not math.isfinite(value) or value < 1.0:
            raise RefractionError(f"{where}: {name} must be a finite index >= 1, got {value}")


@dataclass(frozen=True, kw_only=True, eq=False)
class DomePort:
    """A spherical glass dome in front of a camera.

    Attributes:
        center_m: ``(3,)`` dome centre in the camera frame, metres (the paper's delta-C_dome,
            refractive COLMAP's Cx, Cy, Cz). Zero means a perfectly centred camera.
        inner_radius_m: inner radius of the glass shell, metres (> 0).
        thickness_m: glass thickness, metres (> 0).
        n_air, n_glass, n_water: refractive indices inside, of the glass, and outside.

    Raises:
        RefractionError: non-positive sizes, indices below 1, or a centre outside the dome
            (``|center_m| >= inner_radius_m``: the camera would not sit inside the shell).
    """

    center_m: FloatArray
    inner_radius_m: float
    thickness_m: float
    n_air: float = N_AIR
    n_glass: float = N_ACRYLIC
    n_water: float = N_WATER

    def __post_init__(self) -> None:
        c = np.asarray(self.center_m, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise RefractionError(f"dome center_m must be 3 finite values, got {self.center_m!r}")
        c.setflags(write=False)
        object.__setattr__(self, "center_m", c)
        for name in ("inner_radius_m", "thickness_m"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value <= 0:
                raise RefractionError(f"dome {name} must be > 0 m, got {value}")
            object.__setattr__(self, name, value)
        _check_indices("dome", self.n_air, self.n_glass, self.n_water)
        if float(np.linalg.norm(c)) >= self.inner_radius_m:
            raise RefractionError(
                f"dome centre {c.tolist()} m is outside the dome (|c| = "
                f"{np.linalg.norm(c) * 1e3:.2f} mm >= inner radius {self.inner_radius_m * 1e3:.2f}"
                " mm)"
            )

    @property
    def outer_radius_m(self) -> float:
        """Outer radius, metres."""
        return self.inner_radius_m + self.thickness_m

    @property
    def is_identity(self) -> bool:
        """True if the dome does not bend any ray: centred, or all indices equal."""
        return bool(np.all(self.center_m == 0.0)) or (self.n_air == self.n_glass == self.n_water)


@dataclass(frozen=True, kw_only=True, eq=False)
class FlatPort:
    """A flat glass window in front of a camera.

    Attributes:
        normal: ``(3,)`` unit normal of the interface in the camera frame, pointing away from
            the camera into the water (normalised on construction; must point forward, z > 0).
        distance_m: distance from the camera centre to the inner glass surface along the normal.
        thickness_m: glass thickness, metres.
        n_air, n_glass, n_water: refractive indices.

    Raises:
        RefractionError: a zero or backward normal, non-positive sizes, or indices below 1.
    """

    normal: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    distance_m: float = 0.01
    thickness_m: float = 0.01
    n_air: float = N_AIR
    n_glass: float = N_ACRYLIC
    n_water: float = N_WATER

    def __post_init__(self) -> None:
        n: FloatArray = np.asarray(self.normal, dtype=np.float64).reshape(-1)
        norm = float(np.linalg.norm(n)) if n.shape == (3,) else 0.0
        if n.shape != (3,) or not math.isfinite(norm) or norm < 1e-12:
            raise RefractionError(f"flat-port normal must be 3 finite non-zero values, got {n}")
        n = n / norm
        if n[2] <= 0:
            raise RefractionError(f"flat-port normal must point forward (z > 0), got {n.tolist()}")
        n.setflags(write=False)
        object.__setattr__(self, "normal", n)
        for name in ("distance_m", "thickness_m"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value <= 0:
                raise RefractionError(f"flat port {name} must be > 0 m, got {value}")
            object.__setattr__(self, name, value)
        _check_indices("flat port", self.n_air, self.n_glass, self.n_water)

    @property
    def is_identity(self) -> bool:
        """True if all indices are equal: the window does not bend rays."""
        return self.n_air == self.n_glass == self.n_water


def _refract2(
    dx: FloatArray, dy: FloatArray, nx: FloatArray, ny: FloatArray, eta: float
) -> tuple[FloatArray, FloatArray]:
    """2D Snell's law (eq. 2.11); ``n`` faces the incident side. NaN on total reflection."""
    cos_i = -(nx * dx + ny * dy)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    with np.errstate(invalid="ignore"):
        coef = eta * cos_i - np.sqrt(1.0 - sin2_t)
    bad = (sin2_t > 1.0) | (cos_i < 0.0)
    rx = eta * dx + coef * nx
    ry = eta * dy + coef * ny
    rx = np.where(bad, np.nan, rx)
    ry = np.where(bad, np.nan, ry)
    return rx, ry


class _AxialPortCamera:
    """Shared machinery of dome and flat ports: a pinhole plus an axial refracting port."""

    pinhole: PinholeCamera

    def __init__(self, pinhole: PinholeCamera) -> None:
        if not isinstance(pinhole, PinholeCamera):
            raise RefractionError(f"a port camera needs a PinholeCamera, got {type(pinhole)}")
        self.pinhole = pinhole

    # Subclasses provide these three.
    def _axis(self) -> FloatArray:
        raise NotImplementedError

    def _trace_plane(
        self, theta: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """In-air ray at angle ``theta`` from the axis -> water ray origin and direction (2D)."""
        raise NotImplementedError

    def _initial_angle(self, px: FloatArray, py: FloatArray) -> FloatArray:
        raise NotImplementedError

    def _outside_port(self, px: FloatArray, py: FloatArray) -> BoolArray:
        raise NotImplementedError

    @property
    def _identity(self) -> bool:
        raise NotImplementedError

    # ------------------------------------------------------------------ protocol
    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.pinhole.width

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.pinhole.height

    def _plane_basis(self, vectors: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Coordinates along the axis, across it, and the unit 'across' vector per row."""
        a = self._axis()
        along = vectors @ a
        perp = vectors - along[:, None] * a
        across = np.linalg.norm(perp, axis=1)
        b = np.empty_like(perp)
        ok = across > 1e-300
        b[ok] = perp[ok] / across[ok, None]
        if np.any(~ok):
            # Any direction perpendicular to the axis will do for rays on the axis.
            helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            fallback = np.cross(a, helper)
            b[~ok] = fallback / np.linalg.norm(fallback)
        return along, across, b

    def unproject(self, uv: object) -> Rays:
        """Water rays of ``(N, 2)`` pixels: origins on the outer port surface, unit directions
        into the water, in the camera frame (metres). NaN rows where there is no ray (distortion
        not invertible, total internal reflection)."""
        pix = as_pixels(uv)
        air = self.pinhole.unproject(pix).directions
        along, across, b = self._plane_basis(air)
        theta = np.arctan2(across, along)
        ox, oy, dx, dy = self._trace_plane(theta)
        a = self._axis()
        origins = ox[:, None] * a + oy[:, None] * b
        directions = dx[:, None] * a + dy[:, None] * b
        if self._identity:
            directions = air.copy()
        norms = np.linalg.norm(directions, axis=1, keepdims=True)
        directions = directions / norms
        bad = ~np.isfinite(origins).all(axis=1) | ~np.isfinite(directions).all(axis=1)
        origins[bad] = np.nan
        directions[bad] = np.nan
        return Rays(origins=origins, directions=directions)

    def project(self, points_cam: object) -> tuple[FloatArray, BoolArray]:
        """Pixels of ``(N, 3)`` water points in the camera frame (metres).

        Solves for the in-air ray whose refracted water ray passes through each point (a
        safeguarded Newton iteration on one angle per point, converged to 1e-14 rad). Invalid
        (NaN) where the point is inside the port, behind the camera, or has no refracted path.
        """
        pts = as_points(points_cam, "points_cam")
        if self._identity:
            return self.pinhole.project(pts)
        px, py, b = self._plane_basis(pts)
        theta = self._initial_angle(px, py)

        def residual(th: FloatArray, qx: FloatArray, qy: FloatArray) -> FloatArray:
            ox, oy, dx, dy = self._trace_plane(th)
            return dx * (qy - oy) - dy * (qx - ox)

        active = np.isfinite(theta)
        for _ in range(_NEWTON_MAX_ITER):
            if not np.any(active):
                break
            th, qx, qy = theta[active], px[active], py[active]
            f = residual(th, qx, qy)
            fp = (residual(th + _FD_STEP_RAD, qx, qy) - residual(th - _FD_STEP_RAD, qx, qy)) / (
                2 * _FD_STEP_RAD
            )
            with np.errstate(divide="ignore", invalid="ignore"):
                step = f / fp
            # Damp steps larger than 0.2 rad so that a poor start cannot jump past the domain.
            step = np.clip(step, -0.2, 0.2)
            new = th - step
            theta[active] = new
            done = ~(np.abs(step) > _ANGLE_TOL_RAD)
            idx = np.flatnonzero(active)
            active[idx[done]] = False
        ox, oy, dx, dy = self._trace_plane(theta)
        f = dx * (py - oy) - dy * (px - ox)
        ahead = dx * (px - ox) + dy * (py - oy)
        dist = np.hypot(px - ox, py - oy)
        valid = (
            np.isfinite(f)
            & (np.abs(f) <= 1e-9 * np.maximum(dist, 1.0))
            & (ahead > 0)
            & self._outside_port(px, py)
        )
        a = self._axis()
        air = np.cos(theta)[:, None] * a + np.sin(theta)[:, None] * b
        air[~valid] = np.nan
        uv, ok = self.pinhole.project(air)
        valid &= ok
        uv[~valid] = np.nan
        return uv, valid


class DomePortCamera(_AxialPortCamera):
    """A pinhole camera behind a :class:`DomePort`; implements :class:`CameraModel`.

    With the dome centred (zero ``center_m``) or all indices equal, ``project`` is exactly the
    pinhole's and ``unproject`` gives the pinhole's directions.
    """

    def __init__(self, pinhole: PinholeCamera, port: DomePort) -> None:
        super().__init__(pinhole)
        if not isinstance(port, DomePort):
            raise RefractionError(f"DomePortCamera needs a DomePort, got {type(port)}")
        self.port = port
        c = float(np.linalg.norm(port.center_m))
        self._c = c
        self._a = port.center_m / c if c > 0 else np.array([0.0, 0.0, 1.0])

    def __repr__(self) -> str:
        return f"DomePortCamera({self.pinhole!r}, {self.port!r})"

    @property
    def _identity(self) -> bool:
        return self.port.is_identity

    def _axis(self) -> FloatArray:
        return self._a

    def _trace_plane(
        self, theta: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        port, c = self.port, self._c
        r1, r2 = port.inner_radius_m, port.outer_radius_m
        dx, dy = np.cos(theta), np.sin(theta)
        # Inner sphere, centred at (c, 0): the far root, since the camera is inside (eq. 2.15).
        dc = c * dx
        lam1 = dc + np.sqrt(dc * dc - c * c + r1 * r1)
        p1x, p1y = lam1 * dx, lam1 * dy
        q1x, q1y = (p1x - c) / r1, p1y / r1
        gx, gy = _refract2(dx, dy, -q1x, -q1y, port.n_air / port.n_glass)
        # Outer sphere from p1 (eq. 2.16).
        dq = gx * (p1x - c) + gy * p1y
        with np.errstate(invalid="ignore"):
            lam2 = -dq + np.sqrt(dq * dq - r1 * r1 + r2 * r2)
        p2x, p2y = p1x + lam2 * gx, p1y + lam2 * gy
        q2x, q2y = (p2x - c) / r2, p2y / r2
        wx, wy = _refract2(gx, gy, -q2x, -q2y, port.n_glass / port.n_water)
        return p2x, p2y, wx, wy

    def _initial_angle(self, px: FloatArray, py: FloatArray) -> FloatArray:
        # The pinhole direction to the point; the offset is millimetres against metres of range.
        return np.arctan2(py, px)

    def _outside_port(self, px: FloatArray, py: FloatArray) -> BoolArray:
        return np.hypot(px - self._c, py) > self.port.outer_radius_m


class FlatPortCamera(_AxialPortCamera):
    """A pinhole camera behind a :class:`FlatPort`; implements :class:`CameraModel`.

    With all indices equal, ``project`` is exactly the pinhole's.
    """

    def __init__(self, pinhole: PinholeCamera, port: FlatPort) -> None:
        super().__init__(pinhole)
        if not isinstance(port, FlatPort):
            raise RefractionError(f"FlatPortCamera needs a FlatPort, got {type(port)}")
        self.port = port

    def __repr__(self) -> str:
        return f"FlatPortCamera({self.pinhole!r}, {self.port!r})"

    @property
    def _identity(self) -> bool:
        return self.port.is_identity

    def _axis(self) -> FloatArray:
        return self.port.normal

    def _trace_plane(
        self, theta: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        port = self.port
        dx, dy = np.cos(theta), np.sin(theta)
        with np.errstate(divide="ignore", invalid="ignore"):
            forward = dx > 1e-12
            lam1 = np.where(forward, port.distance_m / dx, np.nan)
            p1x, p1y = lam1 * dx, lam1 * dy
            gx, gy = _refract2(
                dx, dy, -np.ones_like(dx), np.zeros_like(dx), port.n_air / port.n_glass
            )
            lam2 = port.thickness_m / gx
            p2x, p2y = p1x + lam2 * gx, p1y + lam2 * gy
            wx, wy = _refract2(
                gx, gy, -np.ones_like(gx), np.zeros_like(gx), port.n_glass / port.n_water
            )
        return p2x, p2y, wx, wy

    def _initial_angle(self, px: FloatArray, py: FloatArray) -> FloatArray:
        # Treat the port as infinitely close: Snell's law between water and air angles.
        port = self.port
        phi = np.arctan2(py, px - port.distance_m - port.thickness_m)
        s = np.clip(port.n_water / port.n_air * np.sin(phi), -0.999, 0.999)
        return np.arcsin(s)

    def _outside_port(self, px: FloatArray, py: FloatArray) -> BoolArray:
        return px > self.port.distance_m + self.port.thickness_m
