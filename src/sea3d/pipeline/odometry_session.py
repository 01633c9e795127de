"""Odometry of a recording to files, and the camera-IMU calibration from it: what
``sea3d odometry`` and ``sea3d calibrate imu`` run; the CLI only parses, calls and prints.

- :func:`stereo_odometry_to_files` / :func:`rgbd_odometry_to_files`: run the odometry
  (:mod:`sea3d.pipeline.odometry`), refuse a run with no pose to report
  (:func:`check_poses`), write the TUM trajectory of ``T_world_left`` and, when asked, the
  per-frame status file (:mod:`sea3d.io.odometry_outputs`); return :class:`OdometryFiles`.
- :func:`calibrate_camera_imu`: visual-only odometry of a session, then the camera's angular
  velocity matched to the gyro's (:func:`sea3d.calib.imu.estimate_camera_imu`); returns
  :class:`CameraImuFromSession` with the rig carrying the estimated IMU block.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sea3d.errors import ConfigError, OdometryError
from sea3d.geometry.rig import StereoRig
from sea3d.odometry.config import OdometryConfig
from sea3d.odometry.types import TrackingStatus
from sea3d.pipeline.odometry import OdometryRun, OdometrySummary
from sea3d.stereo.recipe import DepthConfig

if TYPE_CHECKING:
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig

__all__ = [
    "CameraImuFromSession",
    "OdometryFiles",
    "calibrate_camera_imu",
    "check_poses",
    "rgbd_odometry_to_files",
    "save_odometry",
    "stereo_odometry_to_files",
]

TRAJECTORY_HEADER = "t tx ty tz qx qy qz qw (T_world_left; t in seconds)"

_TRUSTED = (TrackingStatus.TRACKING, TrackingStatus.RELOCALISED, TrackingStatus.IMU_ONLY)


@dataclass(frozen=True, kw_only=True, eq=False)
class OdometryFiles:
    """An odometry run and the files written from it.

    Attributes:
        run: the trajectory, statuses and summary.
        trajectory: the TUM file written.
        status_csv: the per-frame status file, or None when none was asked for.
        summary: ``run.summary`` with ``trajectory`` (the TUM path as text).
        untrusted_frames: frames with no trustworthy pose (status lost or initialising).
    """

    run: OdometryRun
    trajectory: Path
    status_csv: Path | None
    summary: OdometrySummary
    untrusted_frames: int


def _check_outputs(*paths: str | os.PathLike[str] | None) -> None:
    for path in paths:
        if path is not None and Path(path).is_dir():
            raise ConfigError(f"{path} is a folder; give a file name for the trajectory")


def check_poses(run: OdometryRun) -> None:
    """Refuse a run that has no pose to report (identity poses are not a trajectory).

    Raises:
        OdometryError: no frame with valid depth in the depth range, no frame tracked beyond
            the first, or every pose the identity.
    """
    n = len(run.statuses)
    trusted = [s in _TRUSTED for s in run.statuses]
    no_depth = run.summary.frames_without_depth or 0
    rng = run.summary.depth_range_m
    within = f" {rng[0]:.3g}..{rng[1]:.3g} m" if rng else ""
    if n and no_depth == n:
        raise OdometryError(
            f"no frame has valid depth in the depth range{within} ({n} frames): the range "
            "excludes the whole scene, or the images have nothing to track; set "
            "min_depth_m/max_depth_m; no trajectory written"
        )
    if n and not any(trusted[1:]):
        raise OdometryError(
            f"no frame could be tracked ({n} frames, none with a pose beyond the first): the "
            "images have nothing to track (black, flat or featureless), or the depth range"
            f"{within} holds too little of the scene (min_depth_m/max_depth_m); no trajectory "
            "written"
        )
    T = np.asarray(run.T_world_left)
    if n > 2 and np.allclose(T, np.eye(4), atol=1e-12):
        raise OdometryError(
            f"every one of the {n} poses is the identity: nothing was tracked; no trajectory "
            "written"
        )


def save_odometry(run: OdometryRun, trajectory: str | os.PathLike[str],
                  status_csv: str | os.PathLike[str] | None = None) -> OdometryFiles:
    """Check the run has poses to report, then write its TUM trajectory (and status file).

    Raises:
        OdometryError: a run with no pose to report (:func:`check_poses`; nothing is
            written), or an unwritable file.
    """
    check_poses(run)
    from sea3d.io.odometry_outputs import write_odometry_status
    from sea3d.io.trajectory_files import write_tum

    traj = Path(trajectory)
    write_tum(traj, run.t_ns, run.T_world_left, header=TRAJECTORY_HEADER)
    status = Path(status_csv) if status_csv is not None else None
    if status is not None:
        write_odometry_status(status, run.t_ns.tolist(), run.statuses, run.segments)
    summary = dataclasses.replace(run.summary, trajectory=str(traj))
    bad = summary.frames_lost + summary.statuses["initialising"]
    return OdometryFiles(run=run, trajectory=traj, status_csv=status, summary=summary,
                         untrusted_frames=bad)


def stereo_odometry_to_files(
    session: str | os.PathLike[str],
    *,
    trajectory: str | os.PathLike[str],
    status_csv: str | os.PathLike[str] | None = None,
    rig_path: str | os.PathLike[str] | None = None,
    use_imu: bool = True,
    depth: DepthConfig | None = None,
    config: OdometryConfig | None = None,
    max_frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    on_start: Callable[[int], None] | None = None,
) -> OdometryFiles:
    """Stereo(-inertial) odometry of a session or EuRoC folder, written to files.

    Args:
        session: the session (MCAP or folder) or EuRoC folder.
        trajectory: the TUM file to write.
        status_csv: also write ``t_ns,status,segment`` per frame here.
        rig_path: a rig file instead of the session's stored rig.
        use_imu: give the IMU to the odometry (when the rig and the stamps allow it).
        depth: the stereo depth of each frame.
        config: the odometry's settings.
        max_frames: stop after this many frames.
        progress: called with 1 after each frame.
        on_start: called with the number of frames to run, once the input is open.

    Raises:
        ConfigError: an output path that is a folder. SessionError, RigFileError,
        OdometryError: unusable input, or a run with no pose to report (nothing written).
    """
    from sea3d.pipeline.odometry import session_odometry

    _check_outputs(trajectory, status_csv)

    def on_open(src: Any, imu_ok: bool, why: str | None) -> None:
        if on_start is not None:
            n = src.t_ns.size if max_frames is None else min(src.t_ns.size, max_frames)
            on_start(int(n))

    run = session_odometry(session, rig_path=rig_path, use_imu=use_imu, observe=depth,
                           config=config, max_frames=max_frames, progress=progress,
                           on_open=on_open)
    return save_odometry(run, trajectory, status_csv)


def rgbd_odometry_to_files(
    color: str,
    depth: str,
    intrinsics: tuple[float, float, float, float],
    *,
    trajectory: str | os.PathLike[str],
    status_csv: str | os.PathLike[str] | None = None,
    depth_scale: float = 1000.0,
    method: str = "dense",
    config: OdometryConfig | None = None,
    progress: Callable[[int], None] | None = None,
    on_start: Callable[[int], None] | None = None,
    dense_config: DenseRgbdConfig | None = None,
) -> OdometryFiles:
    """RGB-D odometry over image files (:func:`sea3d.pipeline.odometry.rgbd_odometry`),
    written to files; ``on_start`` is called with the number of frames once the files are
    resolved and checked.

    Raises:
        ConfigError, ReconError: unusable files (see
        :func:`~sea3d.pipeline.odometry.rgbd_observations`), an output that is a folder.
        OdometryError: a run with no pose to report (nothing written).
    """
    from sea3d.pipeline.odometry import rgbd_observations, rgbd_odometry

    _check_outputs(trajectory, status_csv)
    if on_start is not None:
        cp, _, _, _ = rgbd_observations(color, depth, intrinsics, depth_scale=depth_scale)
        on_start(len(cp))
    run = rgbd_odometry(color, depth, intrinsics, depth_scale=depth_scale, config=config,
                        progress=progress, method=method, dense_config=dense_config)
    return save_odometry(run, trajectory, status_csv)


# ---------------------------------------------------------------------- camera-IMU
@dataclass(frozen=True, kw_only=True, eq=False)
class CameraImuFromSession:
    """The camera-IMU calibration of a session.

    Attributes:
        result: the estimate, with its status and advice
            (:class:`~sea3d.calib.imu.CameraImuCalibration`).
        rig: the session's rig with the estimated IMU block (the IMU's position on the rig
            kept from the rig, or zero), or None when the status is not OK.
        change_from_rig_deg: the rotation between the rig's IMU block and the estimate,
            degrees, or None when the rig has no IMU block.
        summary: ``result.as_dict()`` with ``change_from_rig_deg`` where known.
    """

    result: Any
    rig: StereoRig | None
    change_from_rig_deg: float | None
    summary: dict[str, Any]


def calibrate_camera_imu(
    session: str | os.PathLike[str],
    *,
    rig_path: str | os.PathLike[str] | None = None,
    depth: DepthConfig | None = None,
    max_offset_s: float = 0.5,
    max_frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    on_start: Callable[[int], None] | None = None,
) -> CameraImuFromSession:
    """Visual-only odometry of ``session``, then the camera-IMU rotation, time offset and gyro
    bias from its orientations and the gyro.

    Args:
        session: a session or EuRoC folder with IMU samples.
        rig_path: a rig file instead of the stored rig.
        depth: the stereo depth of the odometry.
        max_offset_s: the time offset searched, +- seconds.
        max_frames: use only the first frames.
        progress: called with 1 after each frame of the odometry.
        on_start: called with the number of frames before the odometry runs.

    Raises:
        CalibrationError: a session without IMU samples; SessionError, RigFileError,
        OdometryError: unusable input.
    """
    from sea3d.calib.imu import CameraImuStatus, estimate_camera_imu
    from sea3d.errors import CalibrationError
    from sea3d.geometry.rig import ImuSpec
    from sea3d.geometry.se3 import R_to_rotvec
    from sea3d.pipeline.odometry import open_stereo_source, session_odometry

    src = open_stereo_source(session, rig_path)
    rig = src.rig
    imu_t, gyro = src.imu_t_ns, src.gyro_radps
    src.close()
    if imu_t.size == 0:
        raise CalibrationError(f"{session}: the session has no IMU samples")
    n = src.t_ns.size if max_frames is None else min(src.t_ns.size, max_frames)
    if on_start is not None:
        on_start(int(n))
    run = session_odometry(session, rig_path=rig_path, use_imu=False,
                           observe=depth or DepthConfig(), max_frames=max_frames,
                           progress=progress)
    good = np.array([s in (TrackingStatus.TRACKING, TrackingStatus.RELOCALISED)
                     for s in run.statuses], dtype=bool)
    res = estimate_camera_imu(run.t_ns, run.T_world_left[:, :3, :3], imu_t, gyro,
                              max_offset_s=max_offset_s, valid=good)
    summary: dict[str, Any] = res.as_dict()
    change = None
    if rig.imu is not None:
        d = R_to_rotvec(rig.imu.T_left_imu[:3, :3].T @ res.R_cam_imu)
        change = float(np.degrees(np.linalg.norm(d)))
        summary["change_from_rig_deg"] = change
    out_rig = None
    if res.status is CameraImuStatus.OK:
        T = np.eye(4)
        T[:3, :3] = res.R_cam_imu
        if rig.imu is not None:
            T[:3, 3] = rig.imu.T_left_imu[:3, 3]
            imu = dataclasses.replace(rig.imu, T_left_imu=T, time_offset_s=res.time_offset_s)
        else:
            imu = ImuSpec(T_left_imu=T, time_offset_s=res.time_offset_s)
        out_rig = dataclasses.replace(rig, imu=imu)
    return CameraImuFromSession(result=res, rig=out_rig, change_from_rig_deg=change,
                                summary=summary)
