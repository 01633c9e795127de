"""The camera model protocol shared by pinhole, dome-port and flat-port cameras.

Every later stage (rectify, triangulate, calibrate, simulate, fuse) works through
:class:`CameraModel`, so a refractive camera is never a special case. Conventions (frames, pixel
centres, units) are in ``docs/conventions.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from sea3d._typing import BoolArray, FloatArray
from sea3d.errors import GeometryError

if TYPE_CHECKING:  # annotations only: geometry never imports refraction at run time
    from sea3d.geometry.pinhole import PinholeCamera
    from sea3d.refraction.ports import DomePort, FlatPort

__all__ = ["CameraModel", "Rays", "as_pixels", "as_points"]


@dataclass(frozen=True, eq=False)
class Rays:
    """A bundle of rays in one frame.

    Attributes:
        origins: ``(N, 3)`` float64, metres. For a pinhole camera the zero vector; for a port
            camera the point where the ray leaves the outer port surface into the water.
        directions: ``(N, 3)`` float64, unit vectors. NaN rows mark pixels that have no ray
            (outside the lens model's domain, or total internal reflection in the port).
    """

    origins: FloatArray
    directions: FloatArray

    def __post_init__(self) -> None:
        if (
            self.origins.shape != self.directions.shape
            or self.origins.ndim != 2
            or (self.origins.shape[1] != 3)
        ):
            raise GeometryError(
                f"Rays need origins and directions of equal shape (N, 3); got "
                f"{self.origins.shape} and {self.directions.shape}"
            )

    def __len__(self) -> int:
        return int(self.origins.shape[0])

    @property
    def valid(self) -> BoolArray:
        """``(N,)`` bool: rows whose origin and direction are finite."""
        ok = np.isfinite(self.origins).all(axis=1) & np.isfinite(self.directions).all(axis=1)
        return np.asarray(ok, dtype=np.bool_)

    def at(self, distance_m: FloatArray | float) -> FloatArray:
        """Points ``origins + distance_m * directions``, ``(N, 3)`` metres."""
        dist = np.asarray(distance_m, dtype=np.float64)
        if dist.ndim == 1:
            dist = dist[:, None]
        return self.origins + dist * self.directions


@runtime_checkable
class CameraModel(Protocol):
    """What every camera model provides. Everything is in the camera's own frame (x right,
    y down, z forward; metres), and pixel ``(u, v)`` = (column, row) with integer values at pixel
    centres.

    A camera is a lens (a :class:`~sea3d.geometry.pinhole.PinholeCamera` with OpenCV
    distortion) composed with an optional refracting port (dome or flat). Stages ask the camera
    for its parts (:attr:`lens`, :attr:`port`, :attr:`is_refractive`) and for resized copies
    (:meth:`scaled`, :meth:`with_lens`); none reaches into a camera's attributes.
    """

    @property
    def width(self) -> int:
        """Image width in pixels."""
        ...

    @property
    def height(self) -> int:
        """Image height in pixels."""
        ...

    @property
    def lens(self) -> PinholeCamera:
        """The pinhole with lens distortion behind the port (a pinhole camera is its own)."""
        ...

    @property
    def port(self) -> DomePort | FlatPort | None:
        """The refracting port in front of the lens, or None for a camera in air."""
        ...

    @property
    def is_refractive(self) -> bool:
        """True if the port bends rays: False for a pinhole, and for a port camera that
        reduces to its lens exactly (dome centred, or all indices equal)."""
        ...

    def scaled(self, width: int, height: int) -> CameraModel:
        """The same camera for images resized to ``width x height`` pixels.

        Focal lengths and principal points scale so that pixel centres stay pixel centres:
        ``f' = f s``, ``c' = (c + 0.5) s - 0.5`` with ``s = width / self.width`` (and
        ``height / self.height`` for ``fy, cy``); distortion (a function of normalised
        coordinates) and the port are kept.

        Raises:
            CameraModelError: a non-positive size.
        """
        ...

    def with_lens(self, lens: PinholeCamera) -> CameraModel:
        """The same port (if any) in front of another lens."""
        ...

    def project(self, points_cam: FloatArray) -> tuple[FloatArray, BoolArray]:
        """Pixels of 3D points.

        Args:
            points_cam: ``(N, 3)`` float64 points in the camera frame, metres.

        Returns:
            ``uv`` ``(N, 2)`` float64 pixels and ``valid`` ``(N,)`` bool: False where the point
            cannot be imaged (behind the camera, no refracted path). Invalid rows of ``uv`` are
            NaN. Points outside the image bounds are still valid; callers crop.
        """
        ...

    def unproject(self, uv: FloatArray) -> Rays:
        """Rays of pixels.

        Args:
            uv: ``(N, 2)`` float64 pixel coordinates.

        Returns:
            :class:`Rays` in the camera frame; for port cameras they start on the outer port
            surface and point into the water.
        """
        ...


def as_points(points: object, name: str = "points") -> FloatArray:
    """Validate and convert to an ``(N, 3)`` float64 array; raise :class:`GeometryError`."""
    return _as_rows(points, 3, name)


def as_pixels(uv: object, name: str = "uv") -> FloatArray:
    """Validate and convert to an ``(N, 2)`` float64 array; raise :class:`GeometryError`."""
    return _as_rows(uv, 2, name)


def _as_rows(values: object, width: int, name: str) -> FloatArray:
    """``values`` as an ``(N, width)`` float64 array (one row of ``width`` becomes N = 1)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == width:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise GeometryError(f"{name} must have shape (N, {width}), got {arr.shape}")
    return arr
