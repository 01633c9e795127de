"""Rectified stereo geometry for the odometry, exact through dome and flat ports.

The front end tracks features in the rectified (virtual pinhole) images. For a pinhole rig the
virtual pinhole *is* the camera. For a refractive rig it is only the best fit over the working
range (:class:`sea3d.rectify.VirtualPinholeReport`: about 0.2 px RMS and 0.6 px at worst for the
paper's domes at 640x360), so the odometry never uses it to make 3D points:

- a rectified pixel is mapped back to the raw image as the rectification tables do and
  unprojected through the port (the camera protocol) into its true water ray; these rays are
  precomputed on a grid and interpolated bilinearly (the ray field is smooth: the error is
  checked in the tests);
- a stereo match is triangulated with the two true rays, and a pixel with a depth from
  :func:`sea3d.stereo.depth.compute_depth` (itself triangulated with true rays) is put where its
  true ray crosses that depth;
- the measurement given to the back end is the *virtual* stereo projection of that exact point
  (:meth:`RectifiedStereo.project`). So the back end's pinhole stereo factors see measurements
  that a pinhole would have made of the true point, and the virtual pinhole's residual never
  enters the estimate (what is left is the residual's change over the depth error of a point,
  far below a hundredth of a pixel).

Frames: ``rect_left`` (the rectified left camera: x right, y down, z forward), ``rect_right``
(``rect_left`` shifted by the baseline along x for the virtual pair).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import OdometryError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.rectify.maps import RectifyMaps

__all__ = ["RectifiedStereo"]

B = NDArray[np.bool_]


def _bilinear(grid: F64, step: float, uv: F64) -> F64:
    """Bilinear lookup of a ``(Gh, Gw, C)`` field sampled every ``step`` px at pixels ``uv``."""
    gh, gw = grid.shape[:2]
    x = np.clip(uv[:, 0] / step, 0.0, gw - 1.000001)
    y = np.clip(uv[:, 1] / step, 0.0, gh - 1.000001)
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    ax = (x - x0)[:, None]
    ay = (y - y0)[:, None]
    g00 = grid[y0, x0]
    g01 = grid[y0, x0 + 1]
    g10 = grid[y0 + 1, x0]
    g11 = grid[y0 + 1, x0 + 1]
    return np.asarray(
        (1 - ay) * ((1 - ax) * g00 + ax * g01) + ay * ((1 - ax) * g10 + ax * g11), dtype=np.float64
    )


def _ray_grid(
    camera: CameraModel,
    virtual: PinholeCamera,
    K_rect: F64,
    R_rect_cam: F64,
    width: int,
    height: int,
    step: int,
) -> F64:
    """True rays of a rectified image on a grid: ``(Gh, Gw, 6)`` origin and unit direction in the
    rectified frame (NaN where the pixel has no ray).

    A rectified pixel is taken back to the raw image the way the rectification tables were
    built (``cv2.initUndistortRectifyMap``: the virtual pinhole's ray, rotated out of the
    rectified frame and distorted), then unprojected through the camera's own model.
    """
    import cv2

    us = np.arange(0, width - 1 + step, step, dtype=np.float64)
    vs = np.arange(0, height - 1 + step, step, dtype=np.float64)
    uu, vv = np.meshgrid(us, vs)
    pix = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)
    rays_rect = pix @ np.linalg.inv(K_rect).T
    rays_cam = rays_rect @ R_rect_cam  # R^T applied row-wise
    raw, _ = cv2.projectPoints(
        rays_cam.reshape(-1, 1, 3),
        np.zeros(3),
        np.zeros(3),
        virtual.K,
        np.asarray(virtual.dist, dtype=np.float64),
    )
    rays = camera.unproject(raw.reshape(-1, 2).astype(np.float64))
    o = rays.origins @ R_rect_cam.T
    d = rays.directions @ R_rect_cam.T
    return np.concatenate([o, d], axis=1).reshape(uu.shape[0], uu.shape[1], 6)


@dataclass(frozen=True, kw_only=True, eq=False)
class RectifiedStereo:
    """The rectified stereo pair as the odometry sees it.

    Attributes:
        fx, fy, cx, cy: rectified (virtual pinhole) intrinsics of both views, pixels.
        baseline_m: rectified baseline, metres.
        width, height: image size, pixels.
        refractive: True when the rays come from a port model (see the module docstring).
        ray_step_px: spacing of the precomputed ray grids, pixels.
        rays_left, rays_right: ``(Gh, Gw, 6)`` ray grids in ``rect_left`` / ``rect_right``
            (None for pinhole geometry).
        T_rectleft_rectright: 4x4, maps ``rect_right`` points into ``rect_left``.
        R_rect_left_left: 3x3, raw left to rectified left.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    width: int
    height: int
    refractive: bool = False
    ray_step_px: int = 4
    rays_left: F64 | None = None
    rays_right: F64 | None = None
    T_rectleft_rectright: F64 | None = None
    R_rect_left_left: F64 | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_maps(cls, maps: RectifyMaps, *, ray_step_px: int = 4) -> RectifiedStereo:
        """Geometry of a rectified rig (:func:`sea3d.rectify.rectify_rig`).

        Raises:
            OdometryError: refractive maps that carry no rig.
        """
        P = maps.P_left
        R1 = np.asarray(maps.R_rect_left_left, dtype=np.float64)
        common = {
            "fx": float(P[0, 0]),
            "fy": float(P[1, 1]),
            "cx": float(P[0, 2]),
            "cy": float(P[1, 2]),
            "baseline_m": float(maps.baseline_m),
            "width": int(maps.width),
            "height": int(maps.height),
            "R_rect_left_left": R1,
        }
        if not maps.refractive:
            return cls(**common)  # type: ignore[arg-type]
        rig = maps.rig
        if rig is None:
            raise OdometryError("refractive rectification maps carry no rig; use rectify_rig")
        R2 = np.asarray(maps.R_rect_right_right, dtype=np.float64)
        T_rl_rr = np.eye(4)
        # rect_right -> right -> left -> rect_left
        T_left_right = rig.T_left_right
        T_rl_rr[:3, :3] = R1 @ T_left_right[:3, :3] @ R2.T
        T_rl_rr[:3, 3] = R1 @ T_left_right[:3, 3]
        K1 = np.asarray(maps.P_left[:3, :3], dtype=np.float64)
        K2 = np.asarray(maps.P_right[:3, :3], dtype=np.float64)
        w, h = int(maps.width), int(maps.height)
        rays_l = _ray_grid(rig.left, maps.virtual_left, K1, R1, w, h, ray_step_px)
        rays_r = _ray_grid(rig.right, maps.virtual_right, K2, R2, w, h, ray_step_px)
        return cls(
            **common,  # type: ignore[arg-type]
            refractive=True,
            ray_step_px=ray_step_px,
            rays_left=rays_l,
            rays_right=rays_r,
            T_rectleft_rectright=T_rl_rr,
        )

    @classmethod
    def pinhole(
        cls, fx: float, fy: float, cx: float, cy: float, width: int, height: int, baseline_m: float
    ) -> RectifiedStereo:
        """A plain pinhole (RGB-D mode: ``baseline_m`` is the virtual baseline of the depth)."""
        if not (fx > 0 and fy > 0 and baseline_m > 0 and width > 0 and height > 0):
            raise OdometryError(
                f"intrinsics and baseline must be positive, got fx={fx} fy={fy} "
                f"baseline={baseline_m} size={width}x{height}"
            )
        return cls(
            fx=float(fx),
            fy=float(fy),
            cx=float(cx),
            cy=float(cy),
            baseline_m=float(baseline_m),
            width=int(width),
            height=int(height),
            R_rect_left_left=np.eye(3),
        )

    # ------------------------------------------------------------------ maths
    @property
    def K(self) -> F64:
        """3x3 rectified intrinsics."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def focal_baseline(self) -> float:
        """``fx * B``: disparity (px) times depth (m)."""
        return self.fx * self.baseline_m

    def rays_rect_left(self, uv: F64) -> tuple[F64, F64]:
        """True rays of rectified left pixels: origins and unit directions ``(N, 3)`` in
        ``rect_left`` (the pinhole's rays from the origin for pinhole geometry)."""
        if self.rays_left is None:
            d = np.stack(
                [(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy, np.ones(len(uv))],
                axis=1,
            )
            return np.zeros_like(d), d / np.linalg.norm(d, axis=1, keepdims=True)
        g = _bilinear(self.rays_left, float(self.ray_step_px), uv)
        d = g[:, 3:]
        return g[:, :3], d / np.linalg.norm(d, axis=1, keepdims=True)

    def points_from_depth(self, uv: F64, depth_m: F64) -> tuple[F64, B]:
        """Exact 3D points of rectified left pixels with a depth along ``rect_left``'s z.

        Args:
            uv: ``(N, 2)`` rectified left pixels.
            depth_m: ``(N,)`` depths along the rectified z axis, metres (NaN invalid).

        Returns:
            ``points_rect (N, 3)`` metres in ``rect_left`` and ``ok (N,)``.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth_m, dtype=np.float64).reshape(-1)
        if self.rays_left is None:
            pts = np.stack(
                [(uv[:, 0] - self.cx) / self.fx * z, (uv[:, 1] - self.cy) / self.fy * z, z], axis=1
            )
        else:
            o, d = self.rays_rect_left(uv)
            with np.errstate(invalid="ignore", divide="ignore"):
                s = (z - o[:, 2]) / d[:, 2]
            pts = o + s[:, None] * d
        ok = np.isfinite(pts).all(axis=1) & (pts[:, 2] > 0)
        return pts, ok

    def points_from_stereo(self, uv_left: F64, uv_right: F64) -> tuple[F64, B]:
        """Exact 3D points of stereo matches ``uv_left <-> uv_right`` in the rectified pair: the
        true rays' midpoint for refractive rigs (whose true matches may sit a fraction of a
        pixel off the row), ``z = f B / d`` for pinholes.

        Returns:
            ``points_rect (N, 3)`` in ``rect_left`` and ``ok (N,)`` (positive depth, rays that
            pass within 1 cm of each other).
        """
        uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
        uv_r = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
        if self.rays_left is None or self.rays_right is None or self.T_rectleft_rectright is None:
            disp = uv_left[:, 0] - uv_r[:, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                z = np.where(disp > 0, self.focal_baseline / disp, np.nan)
            return self.points_from_depth(uv_left, z)
        oa, da = self.rays_rect_left(uv_left)
        g = _bilinear(self.rays_right, float(self.ray_step_px), uv_r)
        T = self.T_rectleft_rectright
        ob = g[:, :3] @ T[:3, :3].T + T[:3, 3]
        db = g[:, 3:] @ T[:3, :3].T
        db = db / np.linalg.norm(db, axis=1, keepdims=True)
        w = oa - ob
        uv_ = np.einsum("ij,ij->i", da, db)
        uw = np.einsum("ij,ij->i", da, w)
        vw = np.einsum("ij,ij->i", db, w)
        denom = 1.0 - uv_ * uv_
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (uv_ * vw - uw) / denom
            t = (vw - uv_ * uw) / denom
        pa = oa + s[:, None] * da
        pb = ob + t[:, None] * db
        pts = 0.5 * (pa + pb)
        gap = np.linalg.norm(pa - pb, axis=1)
        ok = np.isfinite(pts).all(axis=1) & (s > 0) & (t > 0) & (gap < 0.01) & (pts[:, 2] > 0)
        return pts, ok

    def project(self, points_rect: F64) -> F64:
        """Virtual stereo projection ``(u_left, u_right, v)`` of points in ``rect_left``,
        ``(N, 3)`` pixels (the back end's measurement model)."""
        p = np.asarray(points_rect, dtype=np.float64).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            ul = self.fx * p[:, 0] / z + self.cx
            ur = self.fx * (p[:, 0] - self.baseline_m) / z + self.cx
            v = self.fy * p[:, 1] / z + self.cy
        return np.stack([ul, ur, v], axis=1)
