"""Refractive port calibration: the dome centre (or flat-port normal and distance) of each camera
from in-water board images, then the stereo extrinsics in water.

This is what CALIBMAR does (the paper's Sec. 2.3.4, eq. 2.21, Table 3.7). Given the in-air
pinhole intrinsics, the port's geometry and refractive indices, and board corners detected in
``m`` in-water images, the ``6m + 3`` parameters ``Theta = (C_dome, P_1 ... P_m)`` (dome centre
in the camera frame and the board pose of every view) are estimated jointly by nonlinear least
squares. Unlike eq. 2.21, which compares back-projected points on the board, we minimise the
reprojection error in pixels through the refractive model (``DomePortCamera.project``), the
statistically right error for pixel noise. Board poses start from a pinhole ``solvePnP``; the
Jacobian is exact in the pose parameters (chain rule through a central-difference derivative of
the projection with respect to the 3D point) and central differences in the port parameters.
Standard deviations come from ``sigma^2 (J^T J)^-1`` with ``sigma^2 = cost / (2N - P)``.

Flat ports: the parameters are the interface normal (two components, ``n = (nx, ny, 1) /
|.|``) and the distance from the camera centre to the inner glass surface. Optionally the focal
length (one scale on fx and fy) is refined too.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._text import plural
from sea3d._typing import FloatArray
from sea3d.calib._lm import levenberg_marquardt
from sea3d.calib._verdict import verdict as calibration_verdict
from sea3d.calib.stereo import orient_consistently
from sea3d.calib.targets import Detection
from sea3d.errors import CalibrationError, ConfigError, RefractionError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.refraction import DomePort, DomePortCamera, FlatPort, FlatPortCamera

__all__ = [
    "PortCalibConfig",
    "PortCalibration",
    "PortRigCalibration",
    "assess_port",
    "calibrate_port",
    "calibrate_port_rig",
]

log = logging.getLogger(__name__)

PortCamera = DomePortCamera | FlatPortCamera


class PortStatus(enum.StrEnum):
    """Outcome of a port fit."""

    OK = "ok"
    FAILED = "failed"


@dataclass(frozen=True, kw_only=True)
class PortCalibConfig:
    """Settings of the port fits (one object for the library call and the CLI).

    Attributes:
        refine_focal: also estimate one scale on fx and fy (the focal length).
        max_iter: most Levenberg-Marquardt steps per fit.
        max_rms_px: a converged fit with a larger reprojection RMS is reported as failed.
        min_views: fewest usable views per camera.
        min_corners: fewest corners for a view to be used.
        point_step_m: central-difference step on 3D points for the projection's derivative.
        port_step_m: central-difference step on port parameters (metres; unitless for the
            flat-port normal components and the focal scale).
        reject_outliers: leave out views (and, for the extrinsics, pairs) whose RMS is above
            ``max(median + mad_k * 1.4826 * MAD, min_ratio * median, min_reject_px)``, one at
            a time,
            refitting after each, at most ``max_rejected_fraction`` of them.
        joint_refinement: stereo: after the extrinsics with fixed ports, refine both ports,
            the extrinsics and all board poses together.
    """

    refine_focal: bool = False
    max_iter: int = 60
    max_rms_px: float = 3.0
    min_views: int = 3
    min_corners: int = 6
    point_step_m: float = 1e-6
    port_step_m: float = 1e-6
    reject_outliers: bool = True
    joint_refinement: bool = True
    mad_k: float = 3.0
    min_ratio: float = 2.0
    min_reject_px: float = 0.25
    max_rejected_fraction: float = 0.3

    def __post_init__(self) -> None:
        if self.max_iter < 1:
            raise ConfigError(f"max_iter must be >= 1; got {self.max_iter}")
        if self.min_views < 1 or self.min_corners < 4:
            raise ConfigError("min_views must be >= 1 and min_corners >= 4")
        if not self.max_rms_px > 0:
            raise ConfigError(f"max_rms_px must be > 0; got {self.max_rms_px}")


@dataclass(frozen=True, kw_only=True, eq=False)
class PortCalibration:
    """Result of :func:`calibrate_port` for one camera.

    Attributes:
        status: ``"ok"`` or ``"failed"``; ``message`` says why.
        camera: the calibrated port camera (None on failure).
        dome_center_m: ``(3,)`` dome centre in the camera frame, metres (dome ports; else NaN).
        dome_center_std_m: ``(3,)`` its standard deviations, metres.
        normal: ``(3,)`` flat-port unit normal (flat ports; else NaN).
        distance_m: flat-port distance to the inner surface, metres (flat ports; else NaN).
        port_std: standard deviations of the port parameters as fitted: dome ``(cx, cy, cz)``
            metres, flat ``(nx, ny, d)``.
        focal_scale: estimated fx/fy scale relative to the in-air intrinsics (1 unless refined).
        focal_scale_std: its standard deviation (0 unless refined).
        rms_px: reprojection RMS over all used corners, pixels.
        per_view_rms_px: ``(m,)`` reprojection RMS of each used view.
        residuals_px: ``(N, 2)`` projected minus detected, all used corners in view order.
        corners_px: ``(N, 2)`` the detected corners of the used views, in the same order.
        T_cam_board: ``(m, 4, 4)`` board poses in the camera frame (metres).
        views: names of the used views.
        views_rejected: ``(name, reason)`` of the views left out.
        iterations: LM steps taken.
        initial_rms_px: RMS of the pinhole start (port ignored), pixels.
    """

    status: PortStatus
    message: str
    camera: PortCamera | None = None
    dome_center_m: FloatArray = field(default_factory=lambda: np.full(3, np.nan))
    dome_center_std_m: FloatArray = field(default_factory=lambda: np.full(3, np.nan))
    normal: FloatArray = field(default_factory=lambda: np.full(3, np.nan))
    distance_m: float = math.nan
    port_std: FloatArray = field(default_factory=lambda: np.full(3, np.nan))
    focal_scale: float = 1.0
    focal_scale_std: float = 0.0
    rms_px: float = math.nan
    per_view_rms_px: FloatArray = field(default_factory=lambda: np.zeros(0))
    residuals_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    corners_px: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    T_cam_board: FloatArray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    views: tuple[str, ...] = ()
    views_rejected: tuple[tuple[str, str], ...] = ()
    iterations: int = 0
    initial_rms_px: float = math.nan

    @property
    def ok(self) -> bool:
        return self.status is PortStatus.OK

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary."""
        def fl(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        out: dict[str, Any] = {"status": str(self.status), "message": self.message,
                               "rms_px": fl(self.rms_px), "initial_rms_px": fl(self.initial_rms_px),
                               "views_used": len(self.views),
                               "views_rejected": [{"image": n, "reason": r}
                                                  for n, r in self.views_rejected],
                               "iterations": self.iterations}
        if isinstance(self.camera, DomePortCamera) or np.isfinite(self.dome_center_m).all():
            out["dome_center_m"] = [fl(v) for v in self.dome_center_m]
            out["dome_center_std_m"] = [fl(v) for v in self.dome_center_std_m]
        if isinstance(self.camera, FlatPortCamera) or np.isfinite(self.normal).all():
            out["normal"] = [fl(v) for v in self.normal]
            out["distance_m"] = fl(self.distance_m)
            out["port_std"] = [fl(v) for v in self.port_std]
        out["focal_scale"] = self.focal_scale
        out["focal_scale_std"] = self.focal_scale_std
        if self.camera is not None:
            pin = self.camera.pinhole
            out["fx"], out["fy"] = pin.fx, pin.fy
        return out


@dataclass(frozen=True, kw_only=True, eq=False)
class PortRigCalibration:
    """Result of :func:`calibrate_port_rig`: both port fits and the in-water extrinsics.

    Attributes:
        status: ``"ok"`` only when both port fits and the stereo fit succeeded.
        message: what happened.
        left, right: the per-camera port fits.
        T_left_right: ``(4, 4)`` in-water extrinsics (right-camera points into the left frame).
        rms_px: stereo reprojection RMS through both port models, pixels.
        T_left_right_std: ``(6,)`` standard deviations of the extrinsics (rotation vector, rad;
            translation, m).
        views: names ``(left, right)`` of the pairs used for the extrinsics.
        per_pair_rms_px: ``(len(views),)`` stereo reprojection RMS of each used pair.
        views_rejected: ``(left, right, reason)`` of every pair left out of the extrinsics:
            unreadable images, boards not found, views left out of a port fit, pairs whose
            two images disagree.
    """

    status: PortStatus
    message: str
    left: PortCalibration
    right: PortCalibration
    T_left_right: FloatArray = field(default_factory=lambda: np.eye(4))
    rms_px: float = math.nan
    T_left_right_std: FloatArray = field(default_factory=lambda: np.full(6, np.nan))
    views: tuple[tuple[str, str], ...] = ()
    per_pair_rms_px: FloatArray = field(default_factory=lambda: np.zeros(0))
    views_rejected: tuple[tuple[str, str, str], ...] = ()

    @property
    def ok(self) -> bool:
        return self.status is PortStatus.OK

    @property
    def rig(self) -> StereoRig:
        """The calibrated rig.

        Raises:
            CalibrationError: a fit failed.
        """
        if not self.ok or self.left.camera is None or self.right.camera is None:
            raise CalibrationError(f"no rig: port calibration failed ({self.message})")
        return StereoRig(left=self.left.camera, right=self.right.camera,
                         T_left_right=self.T_left_right)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the ``--json`` output)."""
        return {"status": str(self.status), "message": self.message,
                "rms_px": float(self.rms_px) if math.isfinite(self.rms_px) else None,
                "baseline_m": float(np.linalg.norm(self.T_left_right[:3, 3])),
                "T_left_right": self.T_left_right.tolist(),
                "T_left_right_std": [float(v) for v in self.T_left_right_std],
                "views_used": len(self.views),
                "views": [{"left": a, "right": b, "rms_px": float(r)}
                          for (a, b), r in zip(self.views, self.per_pair_rms_px, strict=False)],
                "views_rejected": [{"left": a, "right": b, "reason": r}
                                   for a, b, r in self.views_rejected],
                "left": self.left.to_dict(), "right": self.right.to_dict()}


# ---------------------------------------------------------------------- model plumbing
def _port_params(cam: PortCamera | DomePort | FlatPort) -> FloatArray:
    port = cam.port if isinstance(cam, DomePortCamera | FlatPortCamera) else cam
    if isinstance(port, DomePort):
        return np.asarray(port.center_m, dtype=np.float64).copy()
    n = np.asarray(port.normal, dtype=np.float64)
    return np.array([n[0] / n[2], n[1] / n[2], port.distance_m])


def _camera_factory(pinhole: PinholeCamera, port: DomePort | FlatPort,
                    refine_focal: bool) -> Callable[[FloatArray], PortCamera]:
    """``theta -> camera``: theta = port parameters (3) [+ focal scale]."""
    def make(theta: FloatArray) -> PortCamera:
        pin = pinhole
        if refine_focal:
            s = float(theta[3])
            pin = PinholeCamera(fx=pinhole.fx * s, fy=pinhole.fy * s, cx=pinhole.cx,
                                cy=pinhole.cy, width=pinhole.width, height=pinhole.height,
                                dist=pinhole.dist)
        if isinstance(port, DomePort):
            return DomePortCamera(pin, DomePort(
                center_m=np.asarray(theta[:3], dtype=np.float64),
                inner_radius_m=port.inner_radius_m, thickness_m=port.thickness_m,
                n_air=port.n_air, n_glass=port.n_glass, n_water=port.n_water))
        return FlatPortCamera(pin, FlatPort(
            normal=np.array([theta[0], theta[1], 1.0]), distance_m=float(theta[2]),
            thickness_m=port.thickness_m, n_air=port.n_air, n_glass=port.n_glass,
            n_water=port.n_water))
    return make


def _project_with_point_jac(cam: CameraModel, points: FloatArray,
                            h: float) -> tuple[FloatArray, NDArray[Any] | None]:
    """Pixels ``(N, 2)`` of ``points`` and their derivatives ``(N, 2, 3)`` with respect to the
    points (central differences; projection is per point, so 6 calls give every derivative)."""
    uv, valid = cam.project(points)
    if not valid.all():
        return uv, None
    D = np.empty((points.shape[0], 2, 3))
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        up, vp = cam.project(points + step)
        um, vm = cam.project(points - step)
        if not (vp.all() and vm.all()):
            return uv, None
        D[:, :, k] = (up - um) / (2 * h)
    return uv, D


def _rodrigues_jac(rvec: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``R (3, 3)`` and ``dR/drvec (3, 3, 3)`` (last index: rvec component)."""
    R, J = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    # OpenCV's J is (3, 9): row k = d vec(R) / d rvec_k, vec row-major.
    return (np.asarray(R, dtype=np.float64),
            np.asarray(J, dtype=np.float64).reshape(3, 3, 3).transpose(1, 2, 0))


@dataclass
class _View:
    name: str
    obj: FloatArray  # (N, 3) board points, metres
    uv: FloatArray  # (N, 2) detected pixels


def _usable_views(dets: Sequence[Detection], cfg: PortCalibConfig,
                  side: str) -> tuple[list[_View], list[tuple[str, str]]]:
    views, rejected = [], []
    for i, d in enumerate(dets):
        name = d.name or f"{side}[{i}]"
        if not d.ok:
            rejected.append((name, f"{d.status} ({d.message})"))
        elif len(d) < cfg.min_corners:
            rejected.append((name, f"only {len(d)} corners (need {cfg.min_corners})"))
        else:
            views.append(_View(name=name, obj=d.points_board_m.astype(np.float64),
                               uv=d.corners_px.astype(np.float64)))
    return views, rejected


def _initial_pose(view: _View, pinhole: PinholeCamera) -> FloatArray:
    ok, rvec, tvec = cv2.solvePnP(view.obj, view.uv.reshape(-1, 1, 2), pinhole.K, pinhole.dist,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        ok, rvec, tvec = cv2.solvePnP(view.obj, view.uv.reshape(-1, 1, 2), pinhole.K,
                                      pinhole.dist, flags=cv2.SOLVEPNP_SQPNP)
    return np.concatenate([np.ravel(rvec), np.ravel(tvec)]).astype(np.float64)


def _T(pose: FloatArray) -> FloatArray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(pose[:3].reshape(3, 1))[0]
    T[:3, 3] = pose[3:6]
    return T


def _covariance(J: FloatArray, residuals: FloatArray) -> FloatArray:
    m, p = J.shape
    dof = max(m - p, 1)
    sigma2 = float(residuals @ residuals) / dof
    try:
        return np.asarray(sigma2 * np.linalg.inv(J.T @ J), dtype=np.float64)
    except np.linalg.LinAlgError:
        return np.full((p, p), np.nan)


def _fail(message: str, rejected: Sequence[tuple[str, str]] = (), **kw: Any) -> PortCalibration:
    log.warning("port calibration failed: %s", message)
    return PortCalibration(status=PortStatus.FAILED, message=message,
                           views_rejected=tuple(rejected), **kw)


def _port_steps(port: DomePort | FlatPort, cfg: PortCalibConfig) -> FloatArray:
    """Central-difference steps of the port parameters (+ focal scale)."""
    steps = np.full(4 if cfg.refine_focal else 3, cfg.port_step_m)
    if isinstance(port, FlatPort):
        steps[:2] = 1e-6  # normal components are unitless
    if cfg.refine_focal:
        steps[3] = 1e-7
    return steps


def _per_view_rms(residuals: FloatArray, offs: NDArray[Any]) -> FloatArray:
    r = residuals.reshape(-1, 2)
    return np.array([float(np.sqrt(np.mean(r[offs[v]:offs[v + 1]] ** 2) * 2))
                     for v in range(len(offs) - 1)])


def _robust_limit(errors: FloatArray, cfg: PortCalibConfig) -> tuple[float, float, float]:
    med = float(np.median(errors))
    mad = 1.4826 * float(np.median(np.abs(errors - med)))
    return max(med + cfg.mad_k * mad, cfg.min_ratio * med, cfg.min_reject_px), med, mad


def _solve_port(views: Sequence[_View], make: Callable[[FloatArray], PortCamera], x0: FloatArray,
                n_theta: int, steps: FloatArray, cfg: PortCalibConfig
                ) -> tuple[Any, NDArray[Any], float] | None:
    """One LM fit of the port parameters and the board poses of ``views``.

    Returns:
        ``(LMResult, offsets of each view's corners, starting RMS px)``, or None when the
        start cannot image every corner.
    """
    counts = [len(v.obj) for v in views]
    offs = np.concatenate([[0], np.cumsum(counts)]).astype(int)
    n_pts = int(offs[-1])
    obj_all = np.concatenate([v.obj for v in views])
    uv_all = np.concatenate([v.uv for v in views])
    n_par = n_theta + 6 * len(views)

    def points_cam(x: FloatArray) -> tuple[FloatArray, list[tuple[FloatArray, FloatArray]]]:
        pts = np.empty((n_pts, 3))
        rots = []
        for v in range(len(views)):
            pose = x[n_theta + 6 * v:n_theta + 6 * v + 6]
            R, dR = _rodrigues_jac(pose[:3])
            a, b = offs[v], offs[v + 1]
            pts[a:b] = obj_all[a:b] @ R.T + pose[3:]
            rots.append((R, dR))
        return pts, rots

    def evaluate(x: FloatArray, want_jac: bool) -> tuple[FloatArray, FloatArray | None]:
        bad = np.full(2 * n_pts, np.inf)
        try:
            cam = make(x[:n_theta])
        except RefractionError:
            return bad, None
        pts, rots = points_cam(x)
        if not want_jac:
            uv, valid = cam.project(pts)
            if not valid.all():
                return bad, None
            return (uv - uv_all).ravel(), None
        uv, D = _project_with_point_jac(cam, pts, cfg.point_step_m)
        if D is None:
            return bad, None
        J = np.zeros((2 * n_pts, n_par))
        for v in range(len(views)):
            a, b = offs[v], offs[v + 1]
            _R, dR = rots[v]
            col = n_theta + 6 * v
            Dv = D[a:b]  # (n, 2, 3)
            for k in range(3):
                dP = obj_all[a:b] @ dR[:, :, k].T  # (n, 3)
                J[2 * a:2 * b, col + k] = np.einsum("nij,nj->ni", Dv, dP).ravel()
            J[2 * a:2 * b, col + 3:col + 6] = Dv.reshape(-1, 3)
        for k in range(n_theta):
            tp, tm = x[:n_theta].copy(), x[:n_theta].copy()
            tp[k] += steps[k]
            tm[k] -= steps[k]
            try:
                up, vp = make(tp).project(pts)
                um, vm = make(tm).project(pts)
            except RefractionError:
                return bad, None
            if not (vp.all() and vm.all()):
                return bad, None
            J[:, k] = ((up - um) / (2 * steps[k])).ravel()
        return (uv - uv_all).ravel(), J

    r0, _ = evaluate(x0, False)
    if not np.all(np.isfinite(r0)):
        return None
    initial_rms = float(np.sqrt(np.mean(r0.reshape(-1, 2) ** 2) * 2))
    sol = levenberg_marquardt(evaluate, x0, max_iter=cfg.max_iter, ftol=1e-10, xtol=1e-10)
    return sol, offs, initial_rms


def calibrate_port(detections: Sequence[Detection], pinhole: PinholeCamera,
                   port: DomePort | FlatPort, config: PortCalibConfig | None = None
                   ) -> PortCalibration:
    """Estimate one camera's port parameters and every board pose from in-water detections.

    Args:
        detections: board detections in in-water images of this camera.
        pinhole: the camera's in-air intrinsics (kept fixed unless ``refine_focal``).
        port: the port's geometry and indices; its centre (dome) or normal and distance (flat)
            are the starting values (zero centre: a centred camera).
        config: settings.

    Returns:
        A :class:`PortCalibration`; ``FAILED`` with the reason when the fit does not converge,
        gives an RMS above ``config.max_rms_px``, or leaves the port's valid range.

    Raises:
        CalibrationError: fewer than ``config.min_views`` usable views (names the images),
            or detections of mixed image sizes or of another size than ``pinhole``.
    """
    cfg = config or PortCalibConfig()
    views, rejected = _usable_views(detections, cfg, "image")
    for d in detections:
        if d.image_size not in ((0, 0), (pinhole.width, pinhole.height)):
            raise CalibrationError(
                f"{d.name or 'an image'} is {d.image_size[0]}x{d.image_size[1]} but the camera "
                f"is {pinhole.width}x{pinhole.height}")
    if len(views) < cfg.min_views:
        raise CalibrationError(
            f"port calibration needs at least {cfg.min_views} views with the board; got "
            f"{len(views)} of {len(detections)} (" + ", ".join(
                f"{n}: {r}" for n, r in rejected[:4]) + ")")
    make = _camera_factory(pinhole, port, cfg.refine_focal)
    theta0 = _port_params(port)
    if cfg.refine_focal:
        theta0 = np.append(theta0, 1.0)
    n_theta = theta0.size
    poses0 = [_initial_pose(v, pinhole) for v in views]
    steps = _port_steps(port, cfg)
    x0 = np.concatenate([theta0, *poses0])
    solved = _solve_port(views, make, x0, n_theta, steps, cfg)
    if solved is None:
        return _fail("the starting port parameters cannot image every corner (a corner lies "
                     "inside the port or behind the camera)", rejected)
    sol, offs, initial_rms = solved
    n_outliers, max_reject = 0, math.floor(cfg.max_rejected_fraction * len(views))
    while cfg.reject_outliers:
        per_view = _per_view_rms(sol.residuals, offs)
        thr, med, mad = _robust_limit(per_view, cfg)
        worst = int(np.argmax(per_view))
        if per_view[worst] <= thr or n_outliers >= max_reject or len(views) - 1 < (
                cfg.min_views):
            break
        reason = (f"reprojection RMS {per_view[worst]:.2f} px through the port is above the "
                  f"outlier limit {thr:.2f} px (median {med:.2f} px + {cfg.mad_k:g} x robust "
                  f"spread {mad:.2f} px); a misdetected board (cut at the image edge?), blur "
                  f"or a bent board")
        log.info("port calibration: rejecting %s: %s", views[worst].name, reason)
        rejected.append((views[worst].name, reason))
        keep = [k for k in range(len(views)) if k != worst]
        x_keep = np.concatenate([sol.x[:n_theta], *[
            sol.x[n_theta + 6 * k:n_theta + 6 * k + 6] for k in keep]])
        views = [views[k] for k in keep]
        n_outliers += 1
        solved = _solve_port(views, make, x_keep, n_theta, steps, cfg)
        if solved is None:
            return _fail("the port fit failed after rejecting outliers", rejected)
        sol, offs, _ = solved
    res = sol.residuals
    rms = float(np.sqrt(np.mean(res.reshape(-1, 2) ** 2) * 2))
    theta = sol.x[:n_theta]
    per_view = _per_view_rms(res, offs)
    poses = np.stack([_T(sol.x[n_theta + 6 * v:n_theta + 6 * v + 6])
                      for v in range(len(views))])
    cov = _covariance(sol.jac, res)
    std = np.sqrt(np.clip(np.diag(cov)[:n_theta], 0, None))
    common: dict[str, Any] = {"rms_px": rms, "per_view_rms_px": per_view,
                              "residuals_px": res.reshape(-1, 2),
                              "corners_px": np.concatenate([v.uv for v in views]),
                              "T_cam_board": poses,
                              "views": tuple(v.name for v in views),
                              "iterations": sol.iterations, "initial_rms_px": initial_rms}
    if not sol.converged:
        return _fail(f"the port fit did not converge within {cfg.max_iter} iterations "
                     f"(RMS {rms:.3f} px, {sol.message})", rejected, **common)
    if not math.isfinite(rms) or rms > cfg.max_rms_px:
        return _fail(f"the port fit converged to an RMS of {rms:.2f} px, above the "
                     f"{cfg.max_rms_px:g} px limit: wrong port geometry, indices or in-air "
                     f"intrinsics, or bad detections", rejected, **common)
    if not np.all(np.isfinite(std)):
        return _fail("the port parameters are not determined by these views (singular "
                     "normal matrix); add views at several ranges and tilts", rejected,
                     **common)
    try:
        cam = make(theta)
    except RefractionError as err:
        return _fail(f"the fit left the port's valid range: {err}", rejected, **common)
    kw: dict[str, Any] = dict(common)
    kw.update(_port_fields(cam, port, theta, std, with_focal=cfg.refine_focal))
    message = (f"converged in {sol.iterations} steps: RMS {rms:.3f} px (pinhole start "
               f"{initial_rms:.3f} px) over {plural(len(views), 'view')}")
    log.info("port calibration %s", message)
    return PortCalibration(status=PortStatus.OK, message=message, camera=cam,
                           views_rejected=tuple(rejected), **kw)


@dataclass
class _PortModel:
    """A port camera as a function of its parameters (for joint refinement)."""

    make: Callable[[FloatArray], PortCamera]
    theta: FloatArray
    steps: FloatArray


def _stereo_in_water(left: _PortModel, right: _PortModel, pairs: list[tuple[_View, _View]],
                     poses_left: list[FloatArray], T_right_left0: FloatArray,
                     cfg: PortCalibConfig, refine_ports: bool
                     ) -> dict[str, Any]:
    """Fit ``T_right_left`` and the board poses (and, with ``refine_ports``, both cameras' port
    parameters) to the pairs' corners through both port models.

    Parameters: ``[rvec, t]`` of ``T_right_left``, the board pose in the left camera for every
    pair, then the port parameters of the left and right camera when refined.

    Returns:
        A dict: ``T_right_left``, ``rms_px``, ``std`` (all parameters), ``converged``,
        ``message``, ``per_pair_rms_px``, ``poses`` (rvec + t per pair), ``theta_left``,
        ``theta_right``.
    """
    V = len(pairs)
    n_tl = left.theta.size if refine_ports else 0
    n_tr = right.theta.size if refine_ports else 0
    col_tl = 6 + 6 * V
    col_tr = col_tl + n_tl
    n_par = col_tr + n_tr
    rig0 = np.concatenate([cv2.Rodrigues(T_right_left0[:3, :3])[0].ravel(), T_right_left0[:3, 3]])
    x0 = np.concatenate([rig0, *poses_left, left.theta[:n_tl], right.theta[:n_tr]])
    n_l = [len(p[0].obj) for p in pairs]
    n_r = [len(p[1].obj) for p in pairs]
    h = cfg.point_step_m
    off_l = np.concatenate([[0], np.cumsum(n_l)]).astype(int)
    off_r = np.concatenate([[0], np.cumsum(n_r)]).astype(int)
    uv_obs = np.concatenate([np.concatenate([p[0].uv for p in pairs]),
                             np.concatenate([p[1].uv for p in pairs])])
    n_left = int(off_l[-1])
    n_all = n_left + int(off_r[-1])
    fixed_l = None if refine_ports else left.make(left.theta)
    fixed_r = None if refine_ports else right.make(right.theta)

    def cameras(x: FloatArray) -> tuple[PortCamera, PortCamera]:
        if not refine_ports:
            assert fixed_l is not None and fixed_r is not None
            return fixed_l, fixed_r
        return left.make(x[col_tl:col_tr]), right.make(x[col_tr:n_par])

    def evaluate(x: FloatArray, want_jac: bool) -> tuple[FloatArray, FloatArray | None]:
        bad = np.full(2 * n_all, np.inf)
        try:
            cam_l, cam_r = cameras(x)
        except RefractionError:
            return bad, None
        R_rig, dR_rig = _rodrigues_jac(x[:3])
        t_rig = x[3:6]
        rots = []
        pl = np.empty((n_left, 3))
        pr_left = np.empty((n_all - n_left, 3))
        for v, (vl, vr) in enumerate(pairs):
            pose = x[6 + 6 * v:12 + 6 * v]
            R, dR = _rodrigues_jac(pose[:3])
            rots.append(dR)
            pl[off_l[v]:off_l[v + 1]] = vl.obj @ R.T + pose[3:]
            pr_left[off_r[v]:off_r[v + 1]] = vr.obj @ R.T + pose[3:]
        pr = pr_left @ R_rig.T + t_rig
        if not want_jac:
            uv_l, ok_l = cam_l.project(pl)
            uv_r, ok_r = cam_r.project(pr)
            if not (ok_l.all() and ok_r.all()):
                return bad, None
            return (np.concatenate([uv_l, uv_r]) - uv_obs).ravel(), None
        uv_l, Dl = _project_with_point_jac(cam_l, pl, h)
        uv_r, Dr = _project_with_point_jac(cam_r, pr, h)
        if Dl is None or Dr is None:
            return bad, None
        J = np.zeros((2 * n_all, n_par))
        Jl, Jr = J[:2 * n_left], J[2 * n_left:]
        for v, (vl, vr) in enumerate(pairs):
            dR = rots[v]
            col = 6 + 6 * v
            a, b = off_l[v], off_l[v + 1]
            c, d = off_r[v], off_r[v + 1]
            for k in range(3):
                dPl = vl.obj @ dR[:, :, k].T
                Jl[2 * a:2 * b, col + k] = np.einsum("nij,nj->ni", Dl[a:b], dPl).ravel()
                dPr = (vr.obj @ dR[:, :, k].T) @ R_rig.T
                Jr[2 * c:2 * d, col + k] = np.einsum("nij,nj->ni", Dr[c:d], dPr).ravel()
            Jl[2 * a:2 * b, col + 3:col + 6] = Dl[a:b].reshape(-1, 3)
            Jr[2 * c:2 * d, col + 3:col + 6] = np.einsum("nij,jk->nik", Dr[c:d],
                                                         R_rig).reshape(-1, 3)
        for k in range(3):
            Jr[:, k] = np.einsum("nij,nj->ni", Dr, pr_left @ dR_rig[:, :, k].T).ravel()
        Jr[:, 3:6] = Dr.reshape(-1, 3)
        for model, pts, rows, col0, n_t in ((left, pl, Jl, col_tl, n_tl),
                                            (right, pr, Jr, col_tr, n_tr)):
            theta = x[col0:col0 + n_t]
            for k in range(n_t):
                tp, tm = theta.copy(), theta.copy()
                tp[k] += model.steps[k]
                tm[k] -= model.steps[k]
                try:
                    up, vp = model.make(tp).project(pts)
                    um, vm = model.make(tm).project(pts)
                except RefractionError:
                    return bad, None
                if not (vp.all() and vm.all()):
                    return bad, None
                rows[:, col0 + k] = ((up - um) / (2 * model.steps[k])).ravel()
        return (np.concatenate([uv_l, uv_r]) - uv_obs).ravel(), J

    sol = levenberg_marquardt(evaluate, x0, max_iter=cfg.max_iter, ftol=1e-10, xtol=1e-10)
    rms = float(np.sqrt(np.mean(sol.residuals.reshape(-1, 2) ** 2) * 2))
    std = np.sqrt(np.clip(np.diag(_covariance(sol.jac, sol.residuals)), 0, None))
    r = sol.residuals.reshape(-1, 2)
    r_l, r_r = r[:n_left], r[n_left:]
    per_pair = np.array([float(np.sqrt(np.mean(np.concatenate(
        [r_l[off_l[v]:off_l[v + 1]], r_r[off_r[v]:off_r[v + 1]]]) ** 2) * 2)) for v in range(V)])
    return {
        "T_right_left": _T(sol.x[:6]), "rms_px": rms, "std": std,
        "converged": sol.converged, "message": sol.message, "per_pair_rms_px": per_pair,
        "poses": [sol.x[6 + 6 * v:12 + 6 * v].copy() for v in range(V)],
        "theta_left": sol.x[col_tl:col_tr].copy() if refine_ports else left.theta,
        "theta_right": sol.x[col_tr:n_par].copy() if refine_ports else right.theta,
        "std_left": std[col_tl:col_tr], "std_right": std[col_tr:n_par],
    }


def calibrate_port_rig(air_rig: StereoRig, left_port: DomePort | FlatPort,
                       right_port: DomePort | FlatPort, left: Sequence[Detection],
                       right: Sequence[Detection], config: PortCalibConfig | None = None
                       ) -> PortRigCalibration:
    """Calibrate both cameras' ports, then the stereo extrinsics in water.

    Args:
        air_rig: the in-air calibration (pinhole cameras; port cameras give their pinholes).
        left_port: the left port's geometry and indices (its centre / normal and distance
            are starting values).
        right_port: the right port's, likewise.
        left: in-water detections of the left camera, ``left[i]`` taken with ``right[i]``.
        right: in-water detections of the right camera.
        config: settings.

    Returns:
        A :class:`PortRigCalibration`; ``FAILED`` with a reason when a fit fails.

    Raises:
        CalibrationError: left and right counts differ, too few views, mixed image sizes.
    """
    cfg = config or PortCalibConfig()
    if len(left) != len(right):
        raise CalibrationError(f"got {len(left)} left and {len(right)} right in-water images; "
                               f"calibration needs pairs")
    pins = [air_rig.left.lens, air_rig.right.lens]
    # Checkerboard corners can come back in either of two orders; make each pair agree.
    right = [orient_consistently(dl, dr) for dl, dr in zip(left, right, strict=True)]
    res_l = calibrate_port(left, pins[0], left_port, cfg)
    res_r = calibrate_port(right, pins[1], right_port, cfg)
    if not (res_l.ok and res_r.ok):
        why = "; ".join(f"{side}: {r.message}" for side, r in (("left", res_l), ("right", res_r))
                        if not r.ok)
        return PortRigCalibration(status=PortStatus.FAILED, message=why, left=res_l, right=res_r)
    assert res_l.camera is not None and res_r.camera is not None
    # Pairs seen by both fits, with the corners both images hold.
    idx_l = {n: k for k, n in enumerate(res_l.views)}
    idx_r = {n: k for k, n in enumerate(res_r.views)}
    pairs: list[tuple[_View, _View]] = []
    poses_left: list[FloatArray] = []
    rels: list[FloatArray] = []
    names: list[tuple[str, str]] = []
    # Every pair the extrinsics cannot use, with the reason of each side.
    why_l, why_r = dict(res_l.views_rejected), dict(res_r.views_rejected)
    left_out: list[tuple[str, str, str]] = []
    for i, (dl, dr) in enumerate(zip(left, right, strict=True)):
        nl, nr = dl.name or f"image[{i}]", dr.name or f"image[{i}]"
        if nl not in idx_l or nr not in idx_r:
            reasons = [f"{side} image: {why.get(n, 'not used by its port fit')}"
                       for side, n, idx, why in (("left", nl, idx_l, why_l),
                                                 ("right", nr, idx_r, why_r)) if n not in idx]
            left_out.append((nl, nr, "; ".join(reasons)))
            continue
        Tl = res_l.T_cam_board[idx_l[nl]]
        Tr = res_r.T_cam_board[idx_r[nr]]
        pairs.append((_View(name=nl, obj=dl.points_board_m, uv=dl.corners_px),
                      _View(name=nr, obj=dr.points_board_m, uv=dr.corners_px)))
        poses_left.append(np.concatenate([cv2.Rodrigues(Tl[:3, :3])[0].ravel(), Tl[:3, 3]]))
        T_rl = Tr @ np.linalg.inv(Tl)
        rels.append(np.concatenate([cv2.Rodrigues(T_rl[:3, :3])[0].ravel(), T_rl[:3, 3]]))
        names.append((nl, nr))
    if len(pairs) < max(1, cfg.min_views):
        return PortRigCalibration(status=PortStatus.FAILED,
                                  message=f"only {plural(len(pairs), 'pair')} "
                                          f"{'has' if len(pairs) == 1 else 'have'} the board "
                                          f"in both images", left=res_l, right=res_r,
                                  views_rejected=tuple(left_out))
    T0 = _T(np.median(np.asarray(rels), axis=0))
    swapped = _swapped_against_air(T0, air_rig.T_left_right)
    if swapped:
        return PortRigCalibration(status=PortStatus.FAILED, message=swapped, left=res_l,
                                  right=res_r, T_left_right=invert_T(T0),
                                  views=tuple(names), views_rejected=tuple(left_out))
    models = []
    for pin, port, res in ((pins[0], left_port, res_l), (pins[1], right_port, res_r)):
        theta = _port_params(res.camera) if res.camera is not None else _port_params(port)
        if cfg.refine_focal:
            theta = np.append(theta, res.focal_scale)
        models.append(_PortModel(make=_camera_factory(pin, port, cfg.refine_focal), theta=theta,
                                 steps=_port_steps(port, cfg)))
    # First the extrinsics with both ports fixed (robust start, outlier pairs), then everything
    # jointly so that the dome centres' uncertainty enters the extrinsics' and vice versa.
    fit = _stereo_in_water(models[0], models[1], pairs, poses_left, T0, cfg, refine_ports=False)
    rejected: list[tuple[str, str, str]] = list(left_out)
    max_reject = len(left_out) + math.floor(cfg.max_rejected_fraction * len(pairs))
    while cfg.reject_outliers and fit["converged"]:
        per_pair = fit["per_pair_rms_px"]
        thr, med, mad = _robust_limit(per_pair, cfg)
        worst = int(np.argmax(per_pair))
        if per_pair[worst] <= thr or len(rejected) >= max_reject or len(pairs) - 1 < max(
                1, cfg.min_views):
            break
        reason = (f"stereo reprojection RMS {per_pair[worst]:.2f} px is above the outlier "
                  f"limit {thr:.2f} px (median {med:.2f} px + {cfg.mad_k:g} x robust spread "
                  f"{mad:.2f} px): the two images disagree (a board misdetected in one of them, "
                  f"e.g. cut at the image edge, or images not taken together)")
        log.info("in-water extrinsics: rejecting %s / %s: %s", *names[worst], reason)
        rejected.append((*names[worst], reason))
        poses_fit = fit["poses"]
        del pairs[worst], names[worst], poses_fit[worst]
        fit = _stereo_in_water(models[0], models[1], pairs, poses_fit, fit["T_right_left"], cfg,
                               refine_ports=False)
    joint = cfg.joint_refinement and fit["converged"]
    if joint:
        fit = _stereo_in_water(models[0], models[1], pairs, fit["poses"], fit["T_right_left"],
                               cfg, refine_ports=True)
    rms, converged = fit["rms_px"], fit["converged"]
    T_left_right = np.linalg.inv(fit["T_right_left"])
    if not converged or not math.isfinite(rms) or rms > cfg.max_rms_px:
        return PortRigCalibration(
            status=PortStatus.FAILED,
            message=f"in-water extrinsics did not converge ({fit['message']}, RMS {rms:.3f} px)",
            left=res_l, right=res_r, T_left_right=T_left_right, rms_px=rms,
            views=tuple(names), views_rejected=tuple(rejected))
    if joint:
        try:
            res_l = _with_joint(res_l, models[0], fit["theta_left"], fit["std_left"], left_port)
            res_r = _with_joint(res_r, models[1], fit["theta_right"], fit["std_right"],
                                right_port)
        except RefractionError as err:
            return PortRigCalibration(
                status=PortStatus.FAILED, message=f"joint refinement left the port's valid "
                                                  f"range: {err}", left=res_l, right=res_r)
    return PortRigCalibration(
        status=PortStatus.OK,
        message=f"both ports and the extrinsics calibrated from {plural(len(pairs), 'pair')} "
                f"of {len(left)} (stereo RMS {rms:.3f} px{', refined jointly' if joint else ''})",
        left=res_l, right=res_r, T_left_right=T_left_right, rms_px=rms,
        T_left_right_std=fit["std"][:6], views=tuple(names),
        per_pair_rms_px=np.asarray(fit["per_pair_rms_px"], dtype=np.float64),
        views_rejected=tuple(rejected))


def _swapped_against_air(T_right_left_water: FloatArray, T_left_right_air: FloatArray) -> str:
    """A one-line explanation when the in-water images put the right camera on the other side
    of the left one than the in-air rig does (left and right exchanged), else ``""``."""
    t_water = -T_right_left_water[:3, :3].T @ T_right_left_water[:3, 3]  # right centre in left
    t_air = np.asarray(T_left_right_air)[:3, 3]
    axis = int(np.argmax(np.abs(t_air)))
    if t_air[axis] * t_water[axis] >= 0 or abs(t_water[axis]) < 0.5 * np.linalg.norm(t_water):
        return ""
    return (f"left and right look swapped: in water the camera of the right images sits at "
            f"{'xyz'[axis]} = {t_water[axis] * 1e3:.1f} mm in the left camera frame, in the "
            f"in-air rig at {t_air[axis] * 1e3:.1f} mm; exchange the left and right images")


def _with_joint(res: PortCalibration, model: _PortModel, theta: FloatArray, std: FloatArray,
                port: DomePort | FlatPort) -> PortCalibration:
    """``res`` with the port parameters (and focal scale) of the joint stereo refinement."""
    cam = model.make(theta)
    kw: dict[str, Any] = {"camera": cam}
    kw.update(_port_fields(cam, port, theta, std, with_focal=theta.size > 3))
    return dataclasses.replace(res, **kw)


def _port_fields(cam: Any, port: DomePort | FlatPort, theta: FloatArray, std: FloatArray,
                 *, with_focal: bool) -> dict[str, Any]:
    """The result fields of fitted port parameters ``theta`` (and their ``std``)."""
    kw: dict[str, Any] = {"port_std": std[:3].copy()}
    if isinstance(port, DomePort):
        kw["dome_center_m"] = theta[:3].copy()
        kw["dome_center_std_m"] = std[:3].copy()
    else:
        assert isinstance(cam, FlatPortCamera)
        kw["normal"] = np.asarray(cam.port.normal).copy()
        kw["distance_m"] = float(cam.port.distance_m)
    if with_focal:
        kw["focal_scale"] = float(theta[3])
        kw["focal_scale_std"] = float(std[3])
    return kw


def assess_port(result: PortRigCalibration) -> tuple[str, list[str]]:
    """Plain-words guidance for a port calibration: how far to trust it and what to capture.

    Returns:
        ``(verdict, sentences)``; verdict is ``"trusted"``, ``"usable with care"`` or
        ``"not trusted"`` (as for stereo calibration).
    """
    if not result.ok:
        return "not trusted", [f"Port calibration failed: {result.message}"]
    notes: list[str] = []
    severity = 0
    for side, r in (("left", result.left), ("right", result.right)):
        if len(r.T_cam_board):
            dist = np.linalg.norm(r.T_cam_board[:, :3, 3], axis=1)
            if dist.max() < 2.0 * dist.min():
                notes.append(
                    f"The {side} camera saw the board at {dist.min():.2f}-{dist.max():.2f} m "
                    f"only; the dome centre's position along the optical axis is fixed by "
                    f"views at several ranges: add some at two to three times the distance.")
                severity = max(severity, 1)
        if np.isfinite(r.dome_center_std_m).all():
            worst_mm = float(np.max(r.dome_center_std_m)) * 1e3
            if worst_mm > 0.2:
                notes.append(f"The {side} dome centre is uncertain (standard deviation up to "
                             f"{worst_mm:.2f} mm); add views at several ranges and tilts.")
                severity = max(severity, 2 if worst_mm > 1.0 else 1)
        if r.rms_px > 1.0:
            notes.append(f"The {side} camera's RMS through the port is {r.rms_px:.2f} px; check "
                         f"the port geometry and indices, the in-air intrinsics and focus.")
            severity = max(severity, 2 if r.rms_px > 2.0 else 1)
    per_camera = max(result.left.rms_px, result.right.rms_px)
    if math.isfinite(result.rms_px) and result.rms_px > 1.5 * per_camera and (
            result.rms_px > 0.3):
        notes.append(f"The stereo RMS ({result.rms_px:.2f} px) is well above each camera's "
                     f"({per_camera:.2f} px): the two images of some pairs disagree (taken at "
                     f"different times?) or the in-air extrinsics do not hold.")
        severity = max(severity, 1)
    return calibration_verdict(
        notes, severity, subject="port calibration",
        trusted_because="low error through the port models and well-determined port parameters",
        n_pairs=len(result.views), pairs_to_capture="15-25 in-water pairs",
        n_rejected=len(result.views_rejected))
