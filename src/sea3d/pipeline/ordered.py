"""The ordered stages of the process pipeline: odometry, then fusion, one frame at a time.

:class:`OrderedStages` is fed per-frame results in time order, offline (``sea3d process``) or
live (``sea3d live``), and keeps what stays per frame: the odometry's estimate, the depth and
fusion statuses and the valid-depth fraction; never images or depth. Finished TSDF submaps go
to a store (on disk in ``process``), so fusion holds one active submap.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.eval.trajectory import path_length_m
from sea3d.odometry.types import (
    FrameObservation,
    ImuChunk,
    LoopChecks,
    Odometry,
    OdometryEstimate,
)
from sea3d.odometry.types import TrackingStatus as TS
from sea3d.pipeline.depth_scheduler import StageTimer
from sea3d.pipeline.frame_stage import FrameResult

if TYPE_CHECKING:
    from sea3d.recon.submaps import SubmapFusion, SubmapStore
    from sea3d.rectify.maps import RectifyMaps

__all__ = ["TRUSTED", "OrderedStages", "T_left_rect", "trusted_path_length_m"]

log = logging.getLogger(__name__)

TRUSTED = (TS.TRACKING, TS.RELOCALISED)


def trusted_path_length_m(T_world_left: F64, statuses: Sequence[TS],
                          segments: Sequence[int] | NDArray[np.int64]) -> float:
    """The ``path_length_m`` every run's summary reports (process, live and odometry).

    The camera path counted between consecutive frames that are both trusted (tracking or
    relocalised: :data:`TRUSTED`) and in the same segment
    (:func:`sea3d.eval.trajectory.path_length_m`): lost, initialising and IMU-only frames and
    the jumps between segments add nothing.

    Args:
        T_world_left: (N, 4, 4) poses, in time order.
        statuses: (N) each frame's tracking status.
        segments: (N) each frame's segment id, as reported when the frame was processed.

    Returns:
        The length, metres; 0 for fewer than two frames.
    """
    T = np.asarray(T_world_left, np.float64)
    if len(T) < 2:
        return 0.0
    return path_length_m(T[:, :3, 3], np.array([s in TRUSTED for s in statuses], dtype=bool),
                         np.asarray(segments, np.int64))


def T_left_rect(maps: RectifyMaps) -> F64:
    """``T_left_rect``: the rectified left camera in the raw left camera's frame."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(maps.R_rect_left_left, np.float64).T
    return T


class OrderedStages:
    """Odometry and fusion over per-frame results in time order.

    Args:
        odometry: the pose stage (:func:`sea3d.pipeline.pose_stage.make_odometry`).
        fusion: a :class:`~sea3d.recon.submaps.SubmapFusion`.
        store: where finished submaps go (a :class:`~sea3d.recon.submaps.SubmapStore`).
        maps: the rectification the results live on.
        use_imu: hand the odometry the IMU between frames.
        timer: where ``odometry_s`` and ``fusion_s`` are added.
    """

    def __init__(self, odometry: Odometry, fusion: SubmapFusion, store: SubmapStore,
                 maps: RectifyMaps, *,
                 use_imu: bool, timer: StageTimer) -> None:
        self.odometry, self.fusion, self.store = odometry, fusion, store
        self.use_imu, self.timer = use_imu, timer
        self.K = np.asarray(maps.P_left[:3, :3], np.float64)
        self.baseline_m = float(maps.baseline_m)
        self.R_rect = np.asarray(maps.R_rect_left_left, np.float64)
        self.T_left_rect = T_left_rect(maps)
        self.kf_rect: dict[int, F64] = {}
        self.estimates: list[OdometryEstimate] = []
        self.fuse_status: list[str] = []
        self.frame_status: list[str] = []
        self.valid_fraction: list[float] = []
        self.colour_status: dict[str, int] = {}
        self.colour_frames: list[tuple[int, str]] = []  # (t_ns, colour status) for report.html
        self.colour_pictures: list[NDArray[np.uint8]] = []  # a rectified left, before and after
        self.worker_timings_s: dict[str, float] = {}
        self.failed = 0
        self.loop_closures = 0
        self.relinks = 0  # closures that re-link neighbouring keyframes across a lost stretch

    @property
    def loop_checks(self) -> LoopChecks:
        """What became of the odometry's loop candidates (``enabled=False`` for an odometry
        that closes no loops: known poses)."""
        return self.odometry.loop_checks

    def step(self, res: FrameResult, imu: ImuChunk | None, *, fuse: bool = True
             ) -> OdometryEstimate | None:
        """One frame: odometry (every frame with images), then fusion (trusted poses; not
        when ``fuse`` is False: live, a frame whose depth was dropped to keep up, whose
        ``depth_m`` is only the odometry's seed, is recorded as ``no-depth``).

        Returns:
            The odometry's estimate, or None for a frame whose per-frame stage failed (no
            images: the odometry cannot see it; counted in ``failed``).
        """
        for k, v in res.timings_s.items():
            self.worker_timings_s[k] = self.worker_timings_s.get(k, 0.0) + v
        if res.status == "failed":
            self.failed += 1
            log.warning("frame t_ns=%d: %s", res.t_ns, res.message)
            return None
        self.frame_status.append("seeded" if res.seeded else res.status)
        self.valid_fraction.append(res.valid_fraction)
        to = time.perf_counter()
        obs = FrameObservation(
            t_ns=res.t_ns, rect_left=res.rect_left, rect_right=res.rect_right,
            depth_m=res.depth_m, K_rect=self.K, baseline_m=self.baseline_m,
            R_rect_left_left=self.R_rect, imu=imu if self.use_imu else None)
        est = self.odometry.step(obs)
        self.estimates.append(est)
        if est.loop_closure:
            if est.relink:
                self.relinks += 1
            else:
                self.loop_closures += 1
            self.kf_rect = {k: T @ self.T_left_rect
                            for k, T in self.odometry.keyframe_poses().items()}
        if est.keyframe_id is not None:
            self.kf_rect[est.keyframe_id] = np.asarray(est.T_world_left) @ self.T_left_rect
        self.timer.add("odometry_s", time.perf_counter() - to)
        self.fuse_status.append("no-depth" if not fuse else self._fuse(res, est, None))
        return est

    def fuse_late(self, index: int, res: FrameResult, est: OdometryEstimate,
                  T_world_cam: F64 | None = None) -> str:
        """Fuse frame ``index`` (stepped before with ``fuse=False`` on seeded depth) once its
        own depth ``res`` has come (live: the odometry did not wait for it), at
        ``T_world_cam`` (its pose now; None: the estimate's); its statuses are updated.
        Frames must be fused in time order. Returns the fusion status."""
        for k, v in res.timings_s.items():
            self.worker_timings_s[k] = self.worker_timings_s.get(k, 0.0) + v
        self.frame_status[index] = res.status
        self.valid_fraction[index] = res.valid_fraction
        if res.status != "failed":
            self.fuse_status[index] = self._fuse(res, est, T_world_cam)
        return self.fuse_status[index]

    def _fuse(self, res: FrameResult, est: OdometryEstimate, T_world_cam: F64 | None) -> str:
        tf = time.perf_counter()
        if res.colour_status:
            self.colour_status[res.colour_status] = (
                self.colour_status.get(res.colour_status, 0) + 1)
            self.colour_frames.append((int(res.t_ns), res.colour_status))
            if not self.colour_pictures and res.color_left.size:
                self.colour_pictures = [res.rect_left, res.color_left]
        fused = self.fusion.step(
            t_ns=res.t_ns, trusted=est.status in TRUSTED, keyframe_id=est.keyframe_id,
            depth_m=res.fusion_depth_m, color_rgb=res.colors(), K=self.K,
            T_world_cam=(np.asarray(est.T_world_left) @ self.T_left_rect if T_world_cam is None
                         else T_world_cam),
            keyframe_poses=self.kf_rect,
            confidence=res.fusion_confidence if res.fusion_confidence.size else None)
        for sm in fused.finished:
            self.store.put(sm)
        self.timer.add("fusion_s", time.perf_counter() - tf)
        return str(fused.status)

    def finish_fusion(self) -> None:
        """Hand the active submap to the store (after the last frame)."""
        last = self.fusion.finish()
        if last is not None:
            self.store.put(last)

    def final_trajectory(self) -> tuple[NDArray[np.int64], F64]:
        """One pose per processed frame, in frame order: the odometry's final (re-optimised)
        pose, or its per-frame estimate for a frame its trajectory lacks."""
        t_final, T_final = self.odometry.trajectory()
        final = {int(t): np.asarray(T, np.float64) for t, T in zip(t_final, T_final,
                                                                   strict=True)}
        missing = sum(1 for e in self.estimates if int(e.t_ns) not in final)
        if missing:
            log.warning("the odometry's trajectory lacks %d of %d frames; their per-frame "
                        "estimates are used", missing, len(self.estimates))
        t = np.array([e.t_ns for e in self.estimates], np.int64)
        T = np.stack([final.get(int(e.t_ns), np.asarray(e.T_world_left, np.float64))
                      for e in self.estimates])
        return t, T

    def final_keyframes_rect(self) -> dict[int, F64]:
        """Final ``T_world_rect`` of every keyframe (the submaps' anchors)."""
        return {k: T @ self.T_left_rect for k, T in self.odometry.keyframe_poses().items()}
