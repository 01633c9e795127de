"""sea3d.odometry: stereo(-inertial) odometry, loop closure and RGB-D odometry.

:func:`create_odometry` builds the odometry of a rig for the process pipeline (the contract is
in :mod:`sea3d.odometry.types`); :func:`create_dense_rgbd_odometry` dense frame-to-keyframe
RGB-D odometry (depth from any source; the default of ``sea3d odometry rgbd``);
:func:`create_rgbd_odometry` the stereo engine's sparse features on RGB-D frames;
:mod:`sea3d.odometry.observe` turns raw stereo pairs into :class:`FrameObservation` s one at a
time. See ``docs/odometry.md``.
"""

from __future__ import annotations

import logging

import numpy as np

from sea3d.geometry.rig import StereoRig
from sea3d.odometry.config import OdometryConfig
from sea3d.odometry.rgbd_dense import DenseRgbdConfig, DenseRgbdOdometry
from sea3d.odometry.stereo_geometry import RectifiedStereo
from sea3d.odometry.types import (
    FrameObservation,
    ImuChunk,
    Odometry,
    OdometryEstimate,
    TrackingStatus,
)
from sea3d.odometry.vio import StereoInertialOdometry
from sea3d.rectify.maps import RectifyMaps

__all__ = [
    "DenseRgbdConfig",
    "DenseRgbdOdometry",
    "FrameObservation",
    "ImuChunk",
    "Odometry",
    "OdometryConfig",
    "OdometryEstimate",
    "RectifiedStereo",
    "StereoInertialOdometry",
    "TrackingStatus",
    "create_dense_rgbd_odometry",
    "create_odometry",
    "create_rgbd_odometry",
]

log = logging.getLogger(__name__)


def create_odometry(
    rig: StereoRig,
    maps: RectifyMaps,
    *,
    use_imu: bool = True,
    config: OdometryConfig | None = None,
) -> StereoInertialOdometry:
    """The stereo(-inertial) odometry of a rig.

    Args:
        rig: the rig (its ``imu`` block places and weighs the IMU).
        maps: its rectification (:func:`sea3d.rectify.rectify_rig`); the frames' images and
            depth live in these rectified views.
        use_imu: use the IMU when the rig has one (False: visual-only).
        config: :class:`OdometryConfig` (default settings when None).

    Returns:
        A :class:`StereoInertialOdometry` (an :class:`Odometry`); its ``imu_disabled_reason``
        says why it runs visual-only when it does.
    """
    geometry = RectifiedStereo.from_maps(maps)
    imu = rig.imu if use_imu else None
    odo = StereoInertialOdometry(geometry, imu=imu, config=config)
    if use_imu and rig.imu is None:
        log.info("the rig has no IMU: odometry runs visual-only")
    elif not use_imu:
        odo.imu_disabled_reason = "the IMU was switched off (use_imu=False)"
    return odo


def create_rgbd_odometry(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    *,
    config: OdometryConfig | None = None,
) -> StereoInertialOdometry:
    """Keyframe-based odometry for RGB-D frames (depth from any source).

    The depth of a feature becomes a stereo measurement of a virtual pinhole pair whose
    baseline makes one pixel of disparity one standard deviation of the depth
    (``config.rgbd_depth_noise_m_at_1m``, noise growing with depth squared as for
    structured-light and stereo sensors), so the same back end weighs it correctly. Frames'
    ``rect_right`` is ignored.
    """
    cfg = config or OdometryConfig()
    baseline = cfg.pixel_sigma_px / (fx * cfg.rgbd_depth_noise_m_at_1m)
    geometry = RectifiedStereo.pinhole(fx, fy, cx, cy, width, height, baseline)
    odo = StereoInertialOdometry(geometry, imu=None, config=cfg, use_right=False)
    odo.imu_disabled_reason = "RGB-D mode"
    return odo


def create_dense_rgbd_odometry(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    *,
    config: DenseRgbdConfig | None = None,
) -> DenseRgbdOdometry:
    """Dense frame-to-keyframe RGB-D odometry (:mod:`sea3d.odometry.rgbd_dense`) for a
    depth-registered camera with these intrinsics (pixels)."""
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return DenseRgbdOdometry(K, config)
