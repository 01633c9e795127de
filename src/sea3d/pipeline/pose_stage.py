"""The ordered pose stage of ``sea3d process`` and ``sea3d live``: which odometry runs, and
whether it gets the IMU.

:func:`make_odometry` is the one place that chooses the pose stage: known poses (``--poses``)
or sea3d's stereo-inertial odometry (``sea3d.odometry.create_odometry``).
:func:`choose_odometry` adds the IMU decision (:func:`sea3d.pipeline.odometry.imu_decision`,
the same as ``sea3d odometry``'s) and says in the run's summary why the IMU was left out.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from sea3d.odometry.types import Odometry
from sea3d.pipeline.config import PoseConfig
from sea3d.pipeline.frame_source import SessionFrames

if TYPE_CHECKING:
    from sea3d.geometry.rig import StereoRig
    from sea3d.io.trajectory_files import TrajectoryFile
    from sea3d.odometry.config import OdometryConfig
    from sea3d.rectify.maps import RectifyMaps
    from sea3d.stereo.recipe import StereoDepth

__all__ = ["OdometryChoice", "choose_odometry", "choose_session_odometry", "make_odometry"]

log = logging.getLogger(__name__)

OdometryFactory = Callable[["StereoRig", "RectifyMaps"], Odometry]
"""``factory(rig, maps) -> Odometry``: a pose stage of the caller's own (tests)."""

OdometryChoice = tuple[Odometry, str, bool, str | None]
"""``(odometry, description, imu_used, imu_note)``: the pose stage, what it is, whether it
gets the IMU, and why not (None when it does, or when nothing was left out)."""


def make_odometry(rig: StereoRig, maps: RectifyMaps, *, use_imu: bool,
                  poses: TrajectoryFile | None,
                  config: OdometryConfig | None = None) -> tuple[Odometry, str]:
    """The one place that chooses the ordered pose stage.

    Args:
        rig: the (scaled) stereo rig.
        maps: its rectification.
        use_imu: let the odometry use the IMU.
        poses: a :class:`~sea3d.io.trajectory_files.TrajectoryFile` of known ``T_world_left``
            (then no odometry runs), or None.
        config: the odometry's own configuration.

    Returns:
        ``(odometry, description)``.
    """
    if poses is not None:
        from sea3d.odometry.reference import KnownPoses

        return KnownPoses(poses.t_ns, poses.T_world_x), f"known poses from {poses.path}"
    from sea3d.odometry import create_odometry

    odo = create_odometry(rig, maps, use_imu=use_imu, config=config)
    reason = odo.imu_disabled_reason
    mode = "stereo-inertial" if use_imu and reason is None else "visual"
    return odo, f"sea3d {mode} odometry" + (f" ({reason})" if mode == "visual" and reason else "")


def choose_odometry(poses: PoseConfig, stereo: StereoDepth, frame_t_ns: NDArray[np.int64] | None,
                    imu_t_ns: NDArray[np.int64] | None, *, where: str,
                    factory: OdometryFactory | None = None) -> OdometryChoice:
    """The pose stage of a run, with the IMU decision of every command.

    The IMU is used only when it is switched on, the rig has an ``imu`` block and the IMU
    covers the frames in time (:func:`sea3d.pipeline.odometry.imu_decision`): otherwise the
    odometry runs visual-only (right for the camera data), a warning names ``where``, and the
    summary says why.

    Args:
        poses: where the poses come from.
        stereo: the run's :class:`~sea3d.stereo.recipe.StereoDepth` (its rig and maps).
        frame_t_ns: the camera stamps to be run; None when not known yet (live cameras).
        imu_t_ns: the IMU stamps; None when they are still to come (a live IMU stream, whose
            clock is checked on its first samples).
        where: the input, as the warning names it.
        factory: ``factory(rig, maps) -> Odometry`` to use instead of :func:`make_odometry`
            (tests).

    Returns:
        ``(odometry, description, imu_used, imu_note)``.
    """
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.pipeline.odometry import imu_decision

    use_imu, note = imu_decision(poses.use_imu, stereo.rig.imu, frame_t_ns, imu_t_ns,
                                 tolerance_s=poses.imu_max_clock_offset_s)
    if poses.use_imu and note is not None:
        log.warning("%s: %s", where, note)
    if factory is not None:
        odo = factory(stereo.rig, stereo.maps)
        return odo, odo.name, use_imu, note
    known = read_trajectory(poses.poses_path) if poses.poses_path else None
    odo, name = make_odometry(stereo.rig, stereo.maps, use_imu=use_imu, poses=known,
                              config=poses.odometry_config)
    disabled = odo.imu_disabled_reason
    return odo, name, use_imu and known is None and disabled is None, note or disabled


def choose_session_odometry(poses: PoseConfig, stereo: StereoDepth, source: SessionFrames,
                            factory: OdometryFactory | None = None
                            ) -> OdometryChoice:
    """:func:`choose_odometry` for a recorded session's pairs and IMU samples (``sea3d
    process``, and ``sea3d live`` replaying a session).

    Args:
        poses: where the poses come from.
        stereo: the run's :class:`~sea3d.stereo.recipe.StereoDepth`.
        source: the session's pairs to be run.
        factory: ``factory(rig, maps) -> Odometry`` to use instead of :func:`make_odometry`.

    Returns:
        ``(odometry, description, imu_used, imu_note)``.
    """
    return choose_odometry(poses, stereo, np.array([p.t_ns for p in source.pairs], np.int64),
                           np.asarray(source.imu.t_ns, np.int64), where=str(source.path),
                           factory=factory)
