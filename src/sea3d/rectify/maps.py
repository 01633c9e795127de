"""Rectification maps for pinhole and refractive stereo rigs.

Pinhole rigs go through OpenCV's ``stereoRectify`` (with ``CALIB_ZERO_DISPARITY``, so both
rectified views share one principal point and ``d = u_left - u_right``); the remap tables come
from ``initUndistortRectifyMap`` with the *rectified* projection matrices ``P1``/``P2``, never
the raw ``K`` (a classic bug that leaves rows unaligned).

Refractive rigs (dome or flat ports) have no single centre of projection. They are rectified as
the best-fitting *virtual pinhole* pair for the working range: for each camera, pixels on a
grid are unprojected through the port into water rays, points along them at depths across the
range are taken, and a pinhole with OpenCV distortion placed at the camera centre is fitted to
those (point, pixel) pairs by least squares. :class:`VirtualPinholeReport` gives the residual of
that fit in pixels over the image and the range; metric depth for refractive rigs is then
triangulated with the true refracted rays (:mod:`sea3d.stereo.depth`), so it stays right where
the approximation is not.

Frames: ``left``/``right`` are the raw cameras; ``rect_left``/``rect_right`` the rectified ones,
``p_rect_left = R_rect_left_left @ p_left`` (OpenCV's ``R1``), same origin.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from sea3d._typing import F32, F64
from sea3d.errors import RectifyError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig

__all__ = [
    "RectifyMaps",
    "VirtualPinholeReport",
    "closest_point_of_rays",
    "fit_virtual_pinhole",
    "rectify_images",
    "rectify_rig",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class VirtualPinholeReport:
    """How well a virtual pinhole reproduces a refractive camera over the working range.

    Residuals are ``|project_virtual(X) - uv|`` in pixels, for points ``X`` on the true
    refracted ray of pixel ``uv`` at each depth.
    """

    depths_m: tuple[float, ...]
    """Depths (along the camera's z axis) at which the fit was evaluated, metres."""
    rms_px: float
    """Root mean square residual over the image grid and all depths, pixels."""
    max_px: float
    """Largest residual, pixels."""
    rms_by_depth_px: tuple[float, ...]
    """RMS residual at each depth, pixels."""
    max_by_depth_px: tuple[float, ...]
    """Largest residual at each depth, pixels."""
    center_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Where the virtual pinhole sits in the camera frame, metres (zero: at the camera centre)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class RectifyMaps:
    """Remap tables and rectified geometry of a stereo rig.

    Attributes:
        map_left_x, map_left_y, map_right_x, map_right_y: ``(H, W)`` float32: the raw pixel
            sampled for every rectified pixel (``cv2.remap`` tables).
        R_rect_left_left, R_rect_right_right: 3x3, raw camera frame to rectified frame.
        P_left, P_right: 3x4 rectified projection matrices (pixels); ``P_right[0, 3] = -f B``.
        Q: 4x4 disparity-to-depth matrix of OpenCV.
        focal_px: rectified focal length, pixels.
        baseline_m: distance between the rectified camera centres, metres.
        width, height: image size, pixels.
        virtual_left, virtual_right: the pinholes the maps were built from (the rig's own
            pinholes for pinhole rigs, fitted virtual pinholes for refractive rigs).
        refractive: True when the rig has ports (then depth is triangulated with true rays).
        report_left, report_right: virtual-pinhole residuals (refractive rigs only).
    """

    map_left_x: F32
    map_left_y: F32
    map_right_x: F32
    map_right_y: F32
    R_rect_left_left: F64
    R_rect_right_right: F64
    P_left: F64
    P_right: F64
    Q: F64
    focal_px: float
    baseline_m: float
    width: int
    height: int
    virtual_left: PinholeCamera
    virtual_right: PinholeCamera
    refractive: bool = False
    report_left: VirtualPinholeReport | None = None
    report_right: VirtualPinholeReport | None = None
    rig: StereoRig | None = field(default=None, repr=False)

    @property
    def cx_px(self) -> float:
        """Rectified principal point x, pixels (both views)."""
        return float(self.P_left[0, 2])

    @property
    def cy_px(self) -> float:
        """Rectified principal point y, pixels (both views)."""
        return float(self.P_left[1, 2])


def _project_pinhole(points: F64, K: F64, dist: F64) -> F64:
    uv, _ = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return np.asarray(uv.reshape(-1, 2), dtype=np.float64)


def closest_point_of_rays(rays_origins: F64, rays_directions: F64) -> F64:
    """The point nearest to a bundle of lines in the least-squares sense.

    Minimises ``sum_i |(I - d_i d_i^T)(c - o_i)|^2`` over ``c``: the normal equations
    ``(sum_i P_i) c = sum_i P_i o_i`` with the projectors ``P_i = I - d_i d_i^T``.

    Args:
        rays_origins: ``(N, 3)`` points on the lines, metres.
        rays_directions: ``(N, 3)`` unit directions.

    Returns:
        ``(3,)`` float64, the closest point, metres (same frame as the rays).

    Raises:
        RectifyError: fewer than two lines, or the lines are all parallel (no unique point).
    """
    o = np.asarray(rays_origins, dtype=np.float64)
    d = np.asarray(rays_directions, dtype=np.float64)
    if o.shape != d.shape or o.ndim != 2 or o.shape[1] != 3 or o.shape[0] < 2:
        raise RectifyError(f"need (N >= 2, 3) origins and directions, got {o.shape}, {d.shape}")
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = P.sum(axis=0)
    b = np.einsum("nij,nj->i", P, o)
    if np.linalg.cond(A) > 1e12:
        raise RectifyError("the rays are (nearly) parallel: no closest point")
    return np.asarray(np.linalg.solve(A, b), dtype=np.float64)


def fit_virtual_pinhole(
    camera: CameraModel,
    depth_range_m: tuple[float, float] = (0.5, 10.0),
    *,
    grid_step_px: int = 40,
    n_depths: int = 6,
    center: str | F64 = "camera",
    name: str = "camera",
) -> tuple[PinholeCamera, VirtualPinholeReport]:
    """Best-fitting pinhole (with 5-term OpenCV distortion) for a refractive camera.

    The virtual pinhole has the camera's axes. By default (``center="camera"``) it sits at the
    camera's own centre, so the rig's extrinsics carry over unchanged (what rectification
    needs). With ``center="rays"`` it sits where the water rays of the pixel grid pass closest
    (:func:`closest_point_of_rays`): for a decentred dome that is the apparent centre of
    projection, and the residual over a working range is smaller (what structure from motion
    wants; the caller then moves the pose by ``report.center_m``). An explicit ``(3,)`` centre
    in the camera frame (metres) is accepted too. Points on the true water rays of a pixel
    grid, at ``n_depths`` depths spaced evenly in inverse depth over ``depth_range_m``, are
    fitted by least squares (scipy) in the image.

    Args:
        camera: any :class:`CameraModel` (pinhole, dome- or flat-port).
        depth_range_m: nearest and farthest working depth along z, metres (0 < near < far).
        grid_step_px: pixel grid spacing.
        n_depths: number of depths sampled.
        center: ``"camera"``, ``"rays"`` or a ``(3,)`` point in the camera frame, metres.
        name: how the log line names the camera (``left``, ``right``).

    Returns:
        The fitted :class:`PinholeCamera` (in the frame of the virtual centre) and its
        :class:`VirtualPinholeReport` (``center_m`` says where it sits).

    Raises:
        RectifyError: bad range or centre, or too few pixels have water rays.
    """
    from scipy.optimize import least_squares

    near, far = float(depth_range_m[0]), float(depth_range_m[1])
    if not (0 < near < far and np.isfinite(far)):
        raise RectifyError(f"depth range must satisfy 0 < near < far, got {depth_range_m}")
    w, h = camera.width, camera.height
    us = np.arange(0, w, grid_step_px, dtype=np.float64)
    vs = np.arange(0, h, grid_step_px, dtype=np.float64)
    us = np.unique(np.append(us, w - 1))
    vs = np.unique(np.append(vs, h - 1))
    uu, vv = np.meshgrid(us, vs)
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    rays = camera.unproject(uv)
    ok = rays.valid & (rays.directions[:, 2] > 1e-6)
    if ok.sum() < 20:
        raise RectifyError(f"only {int(ok.sum())} grid pixels have water rays; cannot fit")
    uv, o, dvec = uv[ok], rays.origins[ok], rays.directions[ok]
    c: F64
    if isinstance(center, str):
        if center == "camera":
            c = np.zeros(3)
        elif center == "rays":
            c = closest_point_of_rays(o, dvec)
        else:
            raise RectifyError(f"center must be 'camera', 'rays' or a 3-vector, got {center!r}")
    else:
        c = np.asarray(center, dtype=np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise RectifyError(f"center must be 3 finite values in metres, got {center!r}")
    depths = 1.0 / np.linspace(1.0 / near, 1.0 / far, n_depths)
    pts, obs = [], []
    for z in depths:
        s = (z - o[:, 2]) / dvec[:, 2]
        pts.append(o + s[:, None] * dvec - c)
        obs.append(uv)
    points = np.concatenate(pts)
    observed = np.concatenate(obs)
    pin0 = camera.lens
    x0 = np.array([pin0.fx, pin0.fy, pin0.cx, pin0.cy, 0, 0, 0, 0, 0], dtype=np.float64)

    def residual(x: F64) -> F64:
        K = np.array([[x[0], 0, x[2]], [0, x[1], x[3]], [0, 0, 1]])
        return (_project_pinhole(points, K, x[4:9]) - observed).ravel()

    sol = least_squares(residual, x0, method="lm", x_scale="jac")
    x = sol.x
    virtual = PinholeCamera(fx=float(x[0]), fy=float(x[1]), cx=float(x[2]), cy=float(x[3]),
                            width=w, height=h, dist=x[4:9].copy())
    err = np.linalg.norm(residual(x).reshape(-1, 2), axis=1).reshape(len(depths), -1)
    report = VirtualPinholeReport(
        depths_m=tuple(float(z) for z in depths),
        rms_px=float(np.sqrt(np.mean(err**2))),
        max_px=float(err.max()),
        rms_by_depth_px=tuple(float(np.sqrt(np.mean(e**2))) for e in err),
        max_by_depth_px=tuple(float(e.max()) for e in err),
        center_m=(float(c[0]), float(c[1]), float(c[2])),
    )
    log.info("virtual pinhole of the %s camera: fx %.1f px at %s mm, residual RMS %.3f px, "
             "max %.3f px over %.2f-%.2f m", name, virtual.fx, np.round(c * 1e3, 3).tolist(),
             report.rms_px, report.max_px, near, far)
    return virtual, report


def rectify_rig(
    rig: StereoRig,
    *,
    depth_range_m: tuple[float, float] = (0.5, 10.0),
    alpha: float = 0.0,
) -> RectifyMaps:
    """Rectification maps for any rig: pinhole rigs directly, refractive rigs through
    best-fitting virtual pinholes (see the module docstring).

    Args:
        rig: the stereo rig (``T_left_right`` in metres).
        depth_range_m: working range for the virtual-pinhole fit of refractive cameras.
        alpha: OpenCV's free scaling (0: only valid pixels, 1: all raw pixels kept).

    Returns:
        :class:`RectifyMaps`.

    Raises:
        RectifyError: the cameras are not side by side (rectification would flip or fail), or
            the virtual-pinhole fit fails.
    """
    # A port that reduces to its lens exactly is rectified as the lens.
    pin_l = None if rig.left.is_refractive else rig.left.lens
    pin_r = None if rig.right.is_refractive else rig.right.lens
    refractive = pin_l is None or pin_r is None
    rep_l = rep_r = None
    if pin_l is None:
        pin_l, rep_l = fit_virtual_pinhole(rig.left, depth_range_m, name="left")
    if pin_r is None:
        pin_r, rep_r = fit_virtual_pinhole(rig.right, depth_range_m, name="right")
    T_right_left = rig.T_right_left
    R = T_right_left[:3, :3]
    t = T_right_left[:3, 3]
    if abs(t[0]) < 2 * max(abs(t[1]), abs(t[2])):
        raise RectifyError(
            f"cameras are not side by side (t_right_left = {np.round(t, 4).tolist()} m); "
            "horizontal rectification needs the baseline mostly along x"
        )
    size = (rig.width, rig.height)
    try:
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            pin_l.K, pin_l.dist, pin_r.K, pin_r.dist, size, R, t,
            flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha,
        )
        m1x, m1y = cv2.initUndistortRectifyMap(pin_l.K, pin_l.dist, R1, P1, size, cv2.CV_32FC1)
        m2x, m2y = cv2.initUndistortRectifyMap(pin_r.K, pin_r.dist, R2, P2, size, cv2.CV_32FC1)
    except cv2.error as err:
        raise RectifyError(f"OpenCV stereoRectify failed: {err}") from err
    focal = float(P1[0, 0])
    baseline = float(-P2[0, 3] / P2[0, 0])
    if baseline <= 0:
        raise RectifyError(
            f"rectified baseline {baseline:.4f} m is not positive: is the right camera on the "
            "left? (T_left_right should have a positive x translation)"
        )
    return RectifyMaps(
        map_left_x=np.asarray(m1x, np.float32), map_left_y=np.asarray(m1y, np.float32),
        map_right_x=np.asarray(m2x, np.float32), map_right_y=np.asarray(m2y, np.float32),
        R_rect_left_left=np.asarray(R1, np.float64), R_rect_right_right=np.asarray(R2, np.float64),
        P_left=np.asarray(P1, np.float64), P_right=np.asarray(P2, np.float64),
        Q=np.asarray(Q, np.float64), focal_px=focal, baseline_m=baseline,
        width=rig.width, height=rig.height, virtual_left=pin_l, virtual_right=pin_r,
        refractive=refractive, report_left=rep_l, report_right=rep_r, rig=rig,
    )


def rectify_images(
    maps: RectifyMaps, left: np.ndarray, right: np.ndarray, interpolation: int = cv2.INTER_LINEAR
) -> tuple[np.ndarray, np.ndarray]:
    """Remap a raw pair into the rectified views (same dtype and channels).

    Raises:
        RectifyError: the images' size differs from the rig's.
    """
    for name, img in (("left", left), ("right", right)):
        if img.shape[:2] != (maps.height, maps.width):
            raise RectifyError(
                f"{name} image is {img.shape[1]}x{img.shape[0]} but the rig is "
                f"{maps.width}x{maps.height}"
            )
    rl = cv2.remap(left, maps.map_left_x, maps.map_left_y, interpolation,
                   borderMode=cv2.BORDER_CONSTANT)
    rr = cv2.remap(right, maps.map_right_x, maps.map_right_y, interpolation,
                   borderMode=cv2.BORDER_CONSTANT)
    return rl, rr
