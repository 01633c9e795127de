"""The contract between the process pipeline and the odometry (ordered stage).

The pipeline feeds frames in time order to an :class:`Odometry` and gets one
:class:`OdometryEstimate` back per frame; fusion reads keyframe poses from the estimates and,
after a loop closure, the re-optimised keyframe poses from :meth:`Odometry.keyframe_poses`, so
that submaps anchored to keyframes move instead of being re-integrated.

Frames (see docs/conventions.md): ``world`` is the odometry's world (gravity along -z once the
IMU is initialised; the first left camera otherwise), ``left`` the raw left camera, ``rect_left``
the rectified left camera (``p_rect_left = R_rect_left_left @ p_left``, same origin), ``body``
the IMU. Poses are 4x4 float64 ``T_world_left`` (maps left-camera points into the world).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64

__all__ = [
    "FrameObservation",
    "ImuChunk",
    "LoopChecks",
    "LoopRecord",
    "Odometry",
    "OdometryEstimate",
    "TrackingStatus",
]


class TrackingStatus(enum.StrEnum):
    """What the odometry could do with a frame."""

    INITIALISING = "initialising"
    """Not enough information yet (first frames, IMU not initialised); pose is a best guess."""
    TRACKING = "tracking"
    """Pose from vision (and IMU where present)."""
    IMU_ONLY = "imu_only"
    """Vision failed; pose propagated by the IMU alone (bounded time, then LOST)."""
    LOST = "lost"
    """No trustworthy pose; a new segment starts at the next frame that tracks."""
    RELOCALISED = "relocalised"
    """A new segment was joined to an earlier one by a loop closure or relocalisation."""


@dataclass(frozen=True, kw_only=True, eq=False)
class LoopRecord:
    """One geometrically verified loop and what became of it.

    Attributes:
        t_query_ns: the stamp of the keyframe that saw the place again.
        t_candidate_ns: the stamp of the earlier keyframe.
        T_candidate_query: 4x4, the measured pose of the query's ``rect_left`` in the
            candidate's ``rect_left``.
        inliers: the verification's inliers.
        outcome: ``accepted``, ``rejected_odometry``, ``rejected_graph`` or
            ``rejected_solver`` (see :class:`LoopChecks`).
    """

    t_query_ns: int
    t_candidate_ns: int
    T_candidate_query: F64
    inliers: int
    outcome: str


@dataclass(kw_only=True)
class LoopChecks:
    """What became of the loop candidates of a run (counters, updated as it goes).

    Attributes:
        enabled: whether the odometry searches for loops at all (``--no-loop-closure``: no).
        candidates: keyframes proposed by place recognition (or, for a segment not yet
            joined, the other segments' last keyframes) and checked geometrically.
        verified: candidates whose geometry held (:func:`~sea3d.odometry.loop.verify_loop`).
        accepted: loops added to the pose graph (closures and re-links).
        rejected_odometry: verified loops whose relative pose disagreed with the pose graph's
            prediction before anything moved (chi-square test).
        rejected_graph: loops undone after the solve, because the optimised graph still
            disagreed with them.
        rejected_solver: loops undone because the pose graph optimisation failed.
        rejected_unconfirmed: verified loops that no keyframe just before the query confirmed
            (the same candidate verified from there, with a relative pose that agrees).
    """

    enabled: bool = True
    candidates: int = 0
    verified: int = 0
    accepted: int = 0
    rejected_odometry: int = 0
    rejected_graph: int = 0
    rejected_solver: int = 0
    rejected_unconfirmed: int = 0
    verified_loops: list[LoopRecord] = field(default_factory=list)
    """Every verified loop, in the order met (for checks against a ground truth)."""

    def record(self, loop_query_ns: int, loop_candidate_ns: int, T_candidate_query: F64,
               inliers: int, outcome: str) -> None:
        """Count a verified loop's outcome and keep its record."""
        if outcome == "accepted":
            self.accepted += 1
        elif outcome == "rejected_odometry":
            self.rejected_odometry += 1
        elif outcome == "rejected_graph":
            self.rejected_graph += 1
        elif outcome == "rejected_solver":
            self.rejected_solver += 1
        elif outcome == "rejected_unconfirmed":
            self.rejected_unconfirmed += 1
        else:
            raise ValueError(f"unknown loop outcome {outcome!r}")
        self.verified_loops.append(LoopRecord(
            t_query_ns=loop_query_ns, t_candidate_ns=loop_candidate_ns,
            T_candidate_query=np.asarray(T_candidate_query, dtype=np.float64), inliers=inliers,
            outcome=outcome))

    def as_dict(self) -> dict[str, int | bool]:
        """The counters by name (for summaries)."""
        return {
            "enabled": self.enabled,
            "candidates": self.candidates,
            "verified": self.verified,
            "accepted": self.accepted,
            "rejected_geometry": self.candidates - self.verified,
            "rejected_odometry": self.rejected_odometry,
            "rejected_graph": self.rejected_graph,
            "rejected_solver": self.rejected_solver,
            "rejected_unconfirmed": self.rejected_unconfirmed,
        }


@dataclass(frozen=True, kw_only=True)
class ImuChunk:
    """IMU samples between the previous frame and this one (inclusive of this frame's time).

    Attributes:
        t_ns: (N,) int64 stamps, strictly increasing, integer nanoseconds.
        accel_mps2: (N, 3) float64 specific force in the IMU (``body``) frame, m/s^2.
        gyro_radps: (N, 3) float64 angular rate in the IMU frame, rad/s.
    """

    t_ns: NDArray[np.int64]
    accel_mps2: F64
    gyro_radps: F64


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameObservation:
    """What the per-frame stages hand to the odometry for one stereo frame.

    Attributes:
        t_ns: the left image's stamp, integer nanoseconds.
        rect_left, rect_right: rectified images (H, W) uint8 grey or (H, W, 3) uint8 RGB.
        depth_m: (H, W) float32 metres along ``rect_left``'s z axis, NaN invalid. For
            refractive rigs this is the exactly triangulated depth (refracted rays), not
            ``f B / d``.
        K_rect: (3, 3) float64 intrinsics of the rectified (virtual pinhole) left camera.
        baseline_m: rectified baseline, metres.
        R_rect_left_left: (3, 3) float64 rotation raw left -> rectified left.
        imu: IMU samples since the previous frame, or None for a session without IMU.
    """

    t_ns: int
    rect_left: NDArray[np.uint8]
    rect_right: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    K_rect: F64
    baseline_m: float
    R_rect_left_left: F64
    imu: ImuChunk | None = None


@dataclass(frozen=True, kw_only=True, eq=False)
class OdometryEstimate:
    """The odometry's answer for one frame.

    Attributes:
        t_ns: the frame's stamp.
        T_world_left: (4, 4) float64 pose of the raw left camera in the world, metres.
        status: see :class:`TrackingStatus`. Fusion integrates only ``TRACKING`` and
            ``RELOCALISED`` keyframes.
        segment: index of the connected segment this frame belongs to (0 first; a new one
            after LOST; segments are merged by loop closures).
        keyframe_id: the keyframe this frame created, or None if it is not a keyframe.
        anchor_keyframe_id: the keyframe this frame's pose is expressed against (its own id
            for a keyframe); fusion anchors submaps to it.
        loop_closure: True when this frame closed a loop (keyframe poses changed: call
            :meth:`Odometry.keyframe_poses`).
        relink: True when that closure was a re-link: a keyframe joined to a neighbouring
            keyframe (near in time) of another segment across a lost stretch, not a place
            seen again. Keyframe poses changed all the same; counted apart from loops.
        tracked_features: number of inlier features used for this frame's pose.
        info: free-form per-frame figures (timings, inlier ratios) for reports.
    """

    t_ns: int
    T_world_left: F64
    status: TrackingStatus
    segment: int = 0
    keyframe_id: int | None = None
    anchor_keyframe_id: int | None = None
    loop_closure: bool = False
    relink: bool = False
    tracked_features: int = 0
    info: dict[str, float] = field(default_factory=dict)


class Odometry(Protocol):
    """An ordered stage: one state, fed in time order.

    Besides the three methods, an odometry keeps the counters a run's summary reports (read
    after the run, or at any time for a live status).
    """

    @property
    def name(self) -> str:
        """What it is, for the run's summary (``known poses``, ``dense RGB-D`` ...)."""
        ...

    @property
    def keyframe_count(self) -> int:
        """Keyframes made so far."""
        ...

    @property
    def loop_closures(self) -> int:
        """Loops closed so far (re-links not counted)."""
        ...

    @property
    def relinks(self) -> int:
        """Segments re-linked to a neighbouring keyframe across a lost stretch so far."""
        ...

    @property
    def loop_checks(self) -> LoopChecks:
        """What became of the loop candidates (``enabled=False`` for an odometry that keeps
        no such counters)."""
        ...

    @property
    def imu_disabled_reason(self) -> str | None:
        """Why the IMU is not used, or None when it is (or when the odometry takes no
        measurements at all, as known poses)."""
        ...

    def step(self, frame: FrameObservation) -> OdometryEstimate:
        """Process the next frame (stamps strictly increasing) and return its estimate.

        Never raises for frames that are merely hard (no texture, no IMU, a gap): it reports
        a status instead. Raises :class:`~sea3d.errors.OdometryError` for invalid input
        (wrong shapes, stamps going back).
        """
        ...

    def keyframe_poses(self) -> dict[int, F64]:
        """Current (re-optimised) ``T_world_left`` of every keyframe, by keyframe id."""
        ...

    def trajectory(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Final ``(t_ns (N,), T_world_left (N, 4, 4))`` of every frame seen, after the last
        optimisation (frames re-expressed against their anchor keyframes' final poses)."""
        ...
