"""Pinhole camera with OpenCV's lens distortion models.

Distortion coefficients follow OpenCV's order exactly (``cv2.projectPoints``):
``k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tau_x, tau_y]]]]`` with 4, 5, 8, 12 or 14
values (0 for none). For a normalised point ``(x, y) = (X/Z, Y/Z)`` and ``r^2 = x^2 + y^2``::

    radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
    x' = x radial + 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4
    y' = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4

then the tilted-sensor homography of ``tau_x, tau_y`` and finally ``u = fx x'' + cx``,
``v = fy y'' + cy``. ``unproject`` inverts the distortion by Newton iterations with the analytic
Jacobian to machine precision (OpenCV's ``undistortPoints`` stops after 5 fixed-point steps by
default). See ``docs/conventions.md`` for frames and pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sea3d._typing import BoolArray, FloatArray
from sea3d.errors import CameraModelError
from sea3d.geometry._kernels import undistort as undistort_kernel
from sea3d.geometry.camera import Rays, as_pixels, as_points

__all__ = ["DISTORTION_LENGTHS", "PinholeCamera"]


DISTORTION_LENGTHS = (0, 4, 5, 8, 12, 14)


def _tilt_matrix(tau_x: float, tau_y: float) -> FloatArray:
    """OpenCV's tilted-sensor projection matrix (``computeTiltProjectionMatrix``)."""
    cx, sx = np.cos(tau_x), np.sin(tau_x)
    cy, sy = np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array(
        [[rot_xy[2, 2], 0.0, -rot_xy[0, 2]], [0.0, rot_xy[2, 2], -rot_xy[1, 2]], [0.0, 0.0, 1.0]]
    )
    return proj_z @ rot_xy


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """A pinhole camera with optional OpenCV distortion; implements :class:`CameraModel`.

    Args:
        fx: focal length along u in pixels (> 0).
        fy: focal length along v in pixels (> 0).
        cx: principal point's u in pixels.
        cy: principal point's v in pixels.
        width: image width in pixels (> 0).
        height: image height in pixels (> 0).
        dist: distortion coefficients in OpenCV's order; length 0, 4, 5, 8, 12 or 14.

    Raises:
        CameraModelError: non-positive focal length or size, non-finite values, or a distortion
            vector of another length.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: FloatArray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if dist.size not in DISTORTION_LENGTHS:
            raise CameraModelError(
                f"distortion must have one of {DISTORTION_LENGTHS} coefficients (OpenCV order), "
                f"got {dist.size}"
            )
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(values)) or not np.all(np.isfinite(dist)):
            raise CameraModelError(f"camera parameters must be finite: {values}, dist {dist}")
        if self.fx <= 0 or self.fy <= 0:
            raise CameraModelError(f"focal lengths must be > 0 px, got fx={self.fx}, fy={self.fy}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CameraModelError(f"image size must be positive, got {self.width}x{self.height}")
        dist.setflags(write=False)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))

    # ----------------------------------------------------------------- construction helpers
    @classmethod
    def from_K(cls, K: object, width: int, height: int, dist: object = ()) -> PinholeCamera:
        """Build from a 3x3 camera matrix (zero skew expected).

        Raises:
            CameraModelError: ``K`` is not 3x3, has skew, or a last row other than [0, 0, 1].
        """
        K_arr = np.asarray(K, dtype=np.float64)
        if K_arr.shape != (3, 3):
            raise CameraModelError(f"camera matrix must be 3x3, got shape {K_arr.shape}")
        if abs(K_arr[0, 1]) > 1e-9 or not np.allclose(K_arr[2], [0.0, 0.0, 1.0]):
            raise CameraModelError(
                f"camera matrix must have zero skew and last row [0, 0, 1], got {K_arr.tolist()}"
            )
        return cls(
            fx=K_arr[0, 0],
            fy=K_arr[1, 1],
            cx=K_arr[0, 2],
            cy=K_arr[1, 2],
            width=width,
            height=height,
            dist=np.asarray(dist, dtype=np.float64),
        )

    @property
    def K(self) -> FloatArray:
        """3x3 camera matrix in pixels."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        """True if any distortion coefficient is non-zero."""
        return bool(np.any(self.dist != 0.0))

    def with_dist(self, dist: object) -> PinholeCamera:
        """A copy with other distortion coefficients."""
        return PinholeCamera(
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            width=self.width,
            height=self.height,
            dist=np.asarray(dist, dtype=np.float64),
        )

    # ------------------------------------------------------------------ lens and port
    @property
    def lens(self) -> PinholeCamera:
        """The camera itself: a pinhole is its own lens."""
        return self

    @property
    def port(self) -> None:
        """None: a pinhole camera has no port."""
        return None

    @property
    def is_refractive(self) -> bool:
        """False: a pinhole camera bends no rays."""
        return False

    def with_lens(self, lens: PinholeCamera) -> PinholeCamera:
        """``lens`` itself (there is no port to keep)."""
        return lens

    def scaled(self, width: int, height: int) -> PinholeCamera:
        """The camera for images resized to ``width x height``: ``f' = f s``,
        ``c' = (c + 0.5) s - 0.5`` per axis (pixel centres stay pixel centres, see
        ``docs/conventions.md``); the distortion is kept (it acts on normalised coordinates).

        Raises:
            CameraModelError: a non-positive size.
        """
        w, h = int(width), int(height)
        if w <= 0 or h <= 0:
            raise CameraModelError(f"image size must be positive, got {width}x{height}")
        if (w, h) == (self.width, self.height):
            return self
        sx, sy = w / self.width, h / self.height
        return PinholeCamera(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=w,
            height=h,
            dist=self.dist,
        )

    # ------------------------------------------------------------------ distortion maths
    def _coeffs(self) -> FloatArray:
        c = np.zeros(14)
        c[: self.dist.size] = self.dist
        return c

    def distortion_kernel_args(self) -> tuple[FloatArray, FloatArray]:
        """The 14 coefficients and the inverse tilt homography, as the numba kernels take them."""
        k = self._coeffs()
        return k, np.asarray(np.linalg.inv(_tilt_matrix(k[12], k[13])), dtype=np.float64)

    def distort(self, xy: FloatArray) -> FloatArray:
        """Apply distortion to ``(N, 2)`` normalised coordinates (``X/Z, Y/Z``)."""
        k = self._coeffs()
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        r4 = r2 * r2
        r6 = r4 * r2
        radial = (1.0 + k[0] * r2 + k[1] * r4 + k[4] * r6) / (
            1.0 + k[5] * r2 + k[6] * r4 + k[7] * r6
        )
        xd = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x) + k[8] * r2 + k[9] * r4
        yd = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y + k[10] * r2 + k[11] * r4
        if k[12] != 0.0 or k[13] != 0.0:
            tilt = _tilt_matrix(k[12], k[13])
            hom = np.stack([xd, yd, np.ones_like(xd)], axis=1) @ tilt.T
            xd = hom[:, 0] / hom[:, 2]
            yd = hom[:, 1] / hom[:, 2]
        return np.stack([xd, yd], axis=1)

    def undistort(self, xy_distorted: FloatArray) -> tuple[FloatArray, BoolArray]:
        """Invert :meth:`distort` for ``(N, 2)`` distorted normalised coordinates.

        Returns:
            ``xy`` ``(N, 2)`` and ``converged`` ``(N,)``: False where Newton's method did not
            reach a residual of 1e-12 (outside the distortion model's invertible domain); those
            rows are NaN.
        """
        target = np.asarray(xy_distorted, dtype=np.float64)
        if not self.has_distortion:
            return target.copy(), np.asarray(np.isfinite(target).all(axis=1), dtype=np.bool_)
        k, tilt_inv = self.distortion_kernel_args()
        xy = undistort_kernel(
            np.ascontiguousarray(target[:, 0]), np.ascontiguousarray(target[:, 1]), k, tilt_inv
        )
        converged = np.isfinite(xy).all(axis=1)
        return xy, np.asarray(converged, dtype=np.bool_)

    # ------------------------------------------------------------------ camera protocol
    def project(self, points_cam: object) -> tuple[FloatArray, BoolArray]:
        """Pixels of ``(N, 3)`` points in the camera frame (metres); see :class:`CameraModel`.

        Agrees with ``cv2.projectPoints`` (identity pose) for points in front of the camera.
        Points with ``Z <= 0`` are invalid (NaN).
        """
        pts = as_points(points_cam, "points_cam")
        valid = pts[:, 2] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pts[:, :2] / pts[:, 2:3]
        xy[~valid] = np.nan
        return self.normalized_to_pixels(xy), valid & np.isfinite(xy).all(axis=1)

    def normalized_to_pixels(self, xy: FloatArray) -> FloatArray:
        """Distort and scale ``(N, 2)`` normalised coordinates to pixels."""
        xy_d = self.distort(xy) if self.has_distortion else xy
        return np.stack([self.fx * xy_d[:, 0] + self.cx, self.fy * xy_d[:, 1] + self.cy], axis=1)

    def pixels_to_normalized(self, uv: FloatArray) -> tuple[FloatArray, BoolArray]:
        """Undistorted normalised coordinates ``(N, 2)`` of pixels, and where that succeeded."""
        xy_d = np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy], axis=1)
        return self.undistort(xy_d)

    def unproject(self, uv: object) -> Rays:
        """Rays through ``(N, 2)`` pixels: origins at the optical centre (zero), unit directions.

        Agrees with ``cv2.undistortPoints`` run to convergence. Rows where the distortion cannot
        be inverted are NaN.
        """
        pix = as_pixels(uv)
        xy, _ = self.pixels_to_normalized(pix)
        dirs = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return Rays(origins=np.zeros_like(dirs), directions=dirs)

    def pixel_grid(self, step: int = 1) -> FloatArray:
        """``(H*W, 2)`` pixel centres ``(u, v)`` of the whole image, row by row."""
        u, v = np.meshgrid(
            np.arange(0, self.width, step, dtype=np.float64),
            np.arange(0, self.height, step, dtype=np.float64),
        )
        return np.stack([u.ravel(), v.ravel()], axis=1)
