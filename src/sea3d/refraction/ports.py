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

from sea3d._typing import BoolArray, FloatArray
from sea3d.errors import RefractionError
from sea3d.geometry.camera import Rays, as_pixels, as_points
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.refraction import _kernels

__all__ = [
    "N_ACRYLIC",
    "N_AIR",
    "N_WATER",
    "DomePort",
    "DomePortCamera",
    "FlatPort",
    "FlatPortCamera",
]


# Indices from the paper's Table 2.4 (air, sea water, acrylic).
N_AIR = 1.000292
N_WATER = 1.333
N_ACRYLIC = 1.492


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


class _AxialPortCamera:
    """Shared machinery of dome and flat ports: a pinhole plus an axial refracting port."""

    pinhole: PinholeCamera
    port: DomePort | FlatPort

    def __init__(self, pinhole: PinholeCamera) -> None:
        if not isinstance(pinhole, PinholeCamera):
            raise RefractionError(f"a port camera needs a PinholeCamera, got {type(pinhole)}")
        self.pinhole = pinhole

    # Subclasses provide these two.
    def _axis(self) -> FloatArray:
        raise NotImplementedError

    @property
    def _params(self) -> FloatArray:
        """Parameter vector of :mod:`sea3d.refraction._kernels` for this port."""
        raise NotImplementedError

    # ------------------------------------------------------------------ lens and port
    @property
    def lens(self) -> PinholeCamera:
        """The pinhole (with distortion) behind the port."""
        return self.pinhole

    @property
    def is_refractive(self) -> bool:
        """False when the port bends no ray (see the port's ``is_identity``): the camera is
        then exactly its lens."""
        return not self.port.is_identity

    def with_lens(self, lens: PinholeCamera) -> _AxialPortCamera:
        """The same port in front of ``lens``."""
        return type(self)(lens, self.port)  # type: ignore[call-arg]

    def scaled(self, width: int, height: int) -> _AxialPortCamera:
        """The camera for images resized to ``width x height``: the lens scaled (see
        :meth:`PinholeCamera.scaled`), the port kept (it lives in metres, not pixels).

        Raises:
            CameraModelError: a non-positive size.
        """
        lens = self.pinhole.scaled(width, height)
        return self if lens is self.pinhole else self.with_lens(lens)

    # ------------------------------------------------------------------ protocol
    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.pinhole.width

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.pinhole.height

    def unproject(self, uv: object) -> Rays:
        """Water rays of ``(N, 2)`` pixels: origins on the outer port surface, unit directions
        into the water, in the camera frame (metres). NaN rows where there is no ray (distortion
        not invertible, total internal reflection)."""
        pix = np.ascontiguousarray(as_pixels(uv))
        pin = self.pinhole
        k, tilt_inv = pin.distortion_kernel_args()
        rays = _kernels.unproject_port(
            pix,
            np.array([pin.fx, pin.fy, pin.cx, pin.cy]),
            k,
            tilt_inv,
            pin.has_distortion,
            self._axis(),
            self._params,
        )
        origins, directions = rays[:, :3], rays[:, 3:]
        if not self.is_refractive:
            # Exactly the pinhole's directions (the traced ones differ by rounding only).
            directions = pin.unproject(pix).directions
        return Rays(
            origins=np.ascontiguousarray(origins), directions=np.ascontiguousarray(directions)
        )

    def project(self, points_cam: object) -> tuple[FloatArray, BoolArray]:
        """Pixels of ``(N, 3)`` water points in the camera frame (metres).

        Solves for the in-air ray whose refracted water ray passes through each point (Newton
        and secant steps on one angle per point, converged to 1e-14 rad). Invalid (NaN) where the
        point is inside the port, behind the camera, or has no refracted path.
        """
        pts = as_points(points_cam, "points_cam")
        if not self.is_refractive:
            return self.pinhole.project(pts)
        air = _kernels.project_port(np.ascontiguousarray(pts), self._axis(), self._params)
        return self.pinhole.project(air)


class DomePortCamera(_AxialPortCamera):
    """A pinhole camera behind a :class:`DomePort`; implements :class:`CameraModel`.

    With the dome centred (zero ``center_m``) or all indices equal, ``project`` is exactly the
    pinhole's and ``unproject`` gives the pinhole's directions.
    """

    port: DomePort

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

    def _axis(self) -> FloatArray:
        return self._a

    @property
    def _params(self) -> FloatArray:
        p = self.port
        return np.array(
            [
                _kernels.KIND_DOME,
                self._c,
                p.inner_radius_m,
                p.outer_radius_m,
                p.n_air / p.n_glass,
                p.n_glass / p.n_water,
            ]
        )


class FlatPortCamera(_AxialPortCamera):
    """A pinhole camera behind a :class:`FlatPort`; implements :class:`CameraModel`.

    With all indices equal, ``project`` is exactly the pinhole's.
    """

    port: FlatPort

    def __init__(self, pinhole: PinholeCamera, port: FlatPort) -> None:
        super().__init__(pinhole)
        if not isinstance(port, FlatPort):
            raise RefractionError(f"FlatPortCamera needs a FlatPort, got {type(port)}")
        self.port = port

    def __repr__(self) -> str:
        return f"FlatPortCamera({self.pinhole!r}, {self.port!r})"

    def _axis(self) -> FloatArray:
        return self.port.normal

    @property
    def _params(self) -> FloatArray:
        p = self.port
        return np.array(
            [
                _kernels.KIND_FLAT,
                p.distance_m,
                p.thickness_m,
                p.n_air / p.n_glass,
                p.n_glass / p.n_water,
                0.0,
            ]
        )
