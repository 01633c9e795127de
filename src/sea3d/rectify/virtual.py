"""Remap a refractive camera's images into one ideal virtual pinhole.

A dome-port camera with a small decentring is nearly central: its water rays pass within a
fraction of a millimetre of one point, which is not the physical camera centre. Placing an ideal
pinhole (no distortion) there and remapping the images *exactly* through the refractive model at
one nominal depth leaves only the parallax of the rays' spread, which is what a pinhole tool such
as COLMAP then sees as error. :func:`virtual_pinhole_maps` builds that remap; its
:class:`~sea3d.rectify.maps.VirtualPinholeReport` gives the residual in pixels over the working
range, so a user can tell whether the pinhole approximation is good enough (the paper's dome at
1920x1080: about 0.001 px) or whether refractive bundle adjustment is needed (flat ports close
up, large dome offsets).

The intrinsics come from :func:`~sea3d.rectify.maps.fit_virtual_pinhole` at the same centre
(its focal length and principal point; the distortion it fits is not used: the remap replaces
it exactly). Frames: the virtual camera has the raw camera's axes and sits at ``center_m`` in
the raw camera frame, so ``T_camera_virtual`` is a pure translation.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32, F64
from sea3d.errors import RectifyError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.rectify.maps import VirtualPinholeReport, fit_virtual_pinhole

__all__ = ["VirtualPinholeMaps", "virtual_pinhole_maps"]


@dataclass(frozen=True, kw_only=True, eq=False)
class VirtualPinholeMaps:
    """An exact remap from a (refractive) camera into an ideal virtual pinhole.

    Attributes:
        camera: the raw camera model the maps were built for.
        virtual: the ideal pinhole (no distortion), the raw image's size.
        center_m: ``(3,)`` the virtual pinhole's centre in the raw camera frame, metres.
        nominal_depth_m: depth (along z) at which the remap is exact, metres.
        map_x, map_y: ``(H, W)`` float32: the raw pixel sampled for every virtual pixel
            (``cv2.remap`` tables); outside the raw image for virtual pixels it does not see.
        report: parallax residual of the virtual pinhole over the working range, pixels.
    """

    camera: CameraModel
    virtual: PinholeCamera
    center_m: F64
    nominal_depth_m: float
    map_x: F32
    map_y: F32
    report: VirtualPinholeReport

    @property
    def T_camera_virtual(self) -> F64:
        """4x4: maps virtual-camera points into the raw camera frame (a translation)."""
        T = np.eye(4)
        T[:3, 3] = self.center_m
        return T

    def remap(self, image: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """The raw image seen by the virtual pinhole (same dtype and channels; black outside).

        Raises:
            RectifyError: the image's size differs from the camera's.
        """
        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise RectifyError(
                f"image is {image.shape[1]}x{image.shape[0]} but the camera is "
                f"{self.camera.width}x{self.camera.height}"
            )
        return cv2.remap(image, self.map_x, self.map_y, interpolation,
                         borderMode=cv2.BORDER_CONSTANT)

    def to_raw(self, uv_virtual: F64) -> F64:
        """Raw pixels that the remap puts at ``(N, 2)`` virtual pixels, computed exactly (the
        refractive projection of the virtual ray's point at the nominal depth). NaN rows where
        there is no refracted path."""
        uv = np.asarray(uv_virtual, dtype=np.float64).reshape(-1, 2)
        return _raw_of_virtual(self.camera, self.virtual, self.center_m, self.nominal_depth_m,
                               uv)


def _raw_of_virtual(
    camera: CameraModel, virtual: PinholeCamera, c: F64, z0: float, uv: F64
) -> F64:
    ray = np.column_stack(
        [(uv[:, 0] - virtual.cx) / virtual.fx, (uv[:, 1] - virtual.cy) / virtual.fy,
         np.ones(len(uv))]
    )
    s = (z0 - c[2]) / ray[:, 2]
    pts = c[None, :] + s[:, None] * ray
    raw, ok = camera.project(pts)
    raw = np.where(ok[:, None], raw, np.nan)
    return np.asarray(raw, dtype=np.float64)


def _parallax_report(
    camera: CameraModel,
    virtual: PinholeCamera,
    c: F64,
    z0: float,
    depths: F64,
    grid_step_px: int,
) -> VirtualPinholeReport:
    """Residual ``|K pi(X - c) - K pi(Y - c)|`` for points ``X`` at each depth on the true water
    ray of a raw pixel and ``Y`` on the same ray at the nominal depth (where the remapped image
    shows that raw pixel)."""
    w, h = camera.width, camera.height
    us = np.unique(np.append(np.arange(0, w, grid_step_px, dtype=np.float64), w - 1))
    vs = np.unique(np.append(np.arange(0, h, grid_step_px, dtype=np.float64), h - 1))
    uu, vv = np.meshgrid(us, vs)
    rays = camera.unproject(np.stack([uu.ravel(), vv.ravel()], axis=1))
    ok = rays.valid & (rays.directions[:, 2] > 1e-6)
    o, d = rays.origins[ok], rays.directions[ok]

    def project(points: F64) -> F64:
        q = points - c
        return np.stack([virtual.fx * q[:, 0] / q[:, 2] + virtual.cx,
                         virtual.fy * q[:, 1] / q[:, 2] + virtual.cy], axis=1)

    def at(z: float) -> F64:
        return o + ((z - o[:, 2]) / d[:, 2])[:, None] * d

    ref = project(at(z0))
    err = np.stack([np.linalg.norm(project(at(float(z))) - ref, axis=1) for z in depths])
    return VirtualPinholeReport(
        depths_m=tuple(float(z) for z in depths),
        rms_px=float(np.sqrt(np.mean(err**2))),
        max_px=float(err.max()),
        rms_by_depth_px=tuple(float(np.sqrt(np.mean(e**2))) for e in err),
        max_by_depth_px=tuple(float(e.max()) for e in err),
        center_m=(float(c[0]), float(c[1]), float(c[2])),
    )


def _bilinear_upsample(nodes: F64, step: int, w: int, h: int) -> F64:
    """Values at every pixel from nodes every ``step`` pixels (node ``(j, i)`` at pixel
    ``(i step, j step)``), bilinear, separable."""
    def weights(n: int) -> tuple[NDArray[np.intp], F64]:
        x = np.arange(n, dtype=np.float64) / step
        i0 = np.floor(x).astype(np.intp)
        return i0, x - i0

    iu, fu = weights(w)
    iv, fv = weights(h)
    cols = nodes[:, iu] * (1.0 - fu)[None, :] + nodes[:, iu + 1] * fu[None, :]
    out: F64 = cols[iv, :] * (1.0 - fv)[:, None] + cols[iv + 1, :] * fv[:, None]
    return out


def virtual_pinhole_maps(
    camera: CameraModel,
    depth_range_m: tuple[float, float] = (0.5, 10.0),
    *,
    center: str | F64 = "rays",
    map_step_px: int = 4,
    grid_step_px: int = 40,
    n_depths: int = 6,
) -> VirtualPinholeMaps:
    """Exact remap of a camera (pinhole with distortion, dome or flat port) into an ideal
    pinhole placed where its water rays pass closest.

    The virtual pixel ``q`` samples the raw pixel ``project(c + s r_q)``: the true (refractive)
    projection of the point at the nominal depth ``z0`` (the middle of ``depth_range_m`` in
    inverse depth) on the virtual ray ``r_q = K^-1 q`` from the centre ``c``. The tables are
    computed exactly every ``map_step_px`` pixels and interpolated bilinearly in between (the
    maps are smooth; the interpolation error is far below a hundredth of a pixel for the
    paper's dome).

    Args:
        camera: any :class:`~sea3d.geometry.camera.CameraModel`.
        depth_range_m: working range (near, far) along z, metres.
        center: ``"rays"`` (closest point of the water rays), ``"camera"`` or a ``(3,)`` point.
        map_step_px: spacing of the exactly computed table nodes, pixels (1 = every pixel).
        grid_step_px: pixel grid of the intrinsics fit and of the residual report.
        n_depths: depths of the residual report, evenly spaced in inverse depth.

    Returns:
        :class:`VirtualPinholeMaps`.

    Raises:
        RectifyError: bad range, step or centre, or too few pixels with water rays.
    """
    if map_step_px < 1:
        raise RectifyError(f"map_step_px must be >= 1, got {map_step_px}")
    fitted, fit_report = fit_virtual_pinhole(
        camera, depth_range_m, grid_step_px=grid_step_px, n_depths=n_depths, center=center
    )
    c = np.asarray(fit_report.center_m, dtype=np.float64)
    near, far = float(depth_range_m[0]), float(depth_range_m[1])
    z0 = 2.0 / (1.0 / near + 1.0 / far)
    w, h = camera.width, camera.height
    virtual = PinholeCamera(fx=fitted.fx, fy=fitted.fy, cx=fitted.cx, cy=fitted.cy, width=w,
                            height=h)
    # Table nodes every map_step_px pixels, covering the image (one node past the last pixel).
    nu = (w - 1) // map_step_px + 2
    nv = (h - 1) // map_step_px + 2
    gu, gv = np.meshgrid(np.arange(nu) * float(map_step_px), np.arange(nv) * float(map_step_px))
    raw = _raw_of_virtual(camera, virtual, c, z0, np.stack([gu.ravel(), gv.ravel()], axis=1))
    raw = np.where(np.isfinite(raw), raw, -1e6)  # no refracted path: sample outside the image
    node_x = raw[:, 0].reshape(nv, nu)
    node_y = raw[:, 1].reshape(nv, nu)
    if map_step_px == 1:
        map_x, map_y = node_x[:h, :w], node_y[:h, :w]
    else:
        # Bilinear interpolation between nodes in float64 (cv2.remap quantises its weights to
        # 1/32 pixel, too coarse here): pixel u lies at node coordinate u / step.
        map_x = _bilinear_upsample(node_x, map_step_px, w, h)
        map_y = _bilinear_upsample(node_y, map_step_px, w, h)
    depths = np.asarray(1.0 / np.linspace(1.0 / near, 1.0 / far, n_depths), dtype=np.float64)
    report = _parallax_report(camera, virtual, c, z0, depths, grid_step_px)
    c.setflags(write=False)
    return VirtualPinholeMaps(
        camera=camera,
        virtual=virtual,
        center_m=c,
        nominal_depth_m=float(z0),
        map_x=np.ascontiguousarray(map_x, dtype=np.float32),
        map_y=np.ascontiguousarray(map_y, dtype=np.float32),
        report=report,
    )
