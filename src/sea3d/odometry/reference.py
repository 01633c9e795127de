"""Known poses as an :class:`~sea3d.odometry.types.Odometry`: process a session with a
trajectory from elsewhere (a navigation solution, USBL/DVL, COLMAP, the simulator's ground
truth) instead of estimating one.

Poses are looked up by frame stamp: exactly, or interpolated (linear in position, spherical
in rotation) between the two nearest poses when they are at most ``max_gap_s`` apart. A frame
outside the trajectory or in a longer gap is ``LOST`` (its pose is the nearest known one, and
nothing trusts it); the next frame with a pose starts a new segment. Keyframes are taken when
the camera has moved ``keyframe_m`` or turned ``keyframe_deg`` since the last keyframe, or
every ``keyframe_every`` frames, whichever comes first. No loop closures: known poses need
none.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from sea3d._typing import F64
from sea3d.errors import OdometryError
from sea3d.odometry.types import FrameObservation, LoopChecks, OdometryEstimate, TrackingStatus

__all__ = ["KnownPoses", "KnownPosesConfig"]


@dataclass(frozen=True, kw_only=True)
class KnownPosesConfig:
    """Lookup and keyframe rules of :class:`KnownPoses`."""

    max_gap_s: float = 0.5
    """Largest gap between two known poses that a frame may be interpolated across, seconds."""
    keyframe_m: float = 0.10
    """Translation since the last keyframe that makes a new one, metres."""
    keyframe_deg: float = 10.0
    """Rotation since the last keyframe that makes a new one, degrees."""
    keyframe_every: int = 10
    """Frames after which a keyframe is taken even without motion."""

    def __post_init__(self) -> None:
        if not (self.max_gap_s >= 0 and self.keyframe_m > 0 and self.keyframe_deg > 0
                and self.keyframe_every >= 1):
            raise OdometryError("known-poses config needs max_gap_s >= 0, keyframe_m > 0, "
                                "keyframe_deg > 0 and keyframe_every >= 1")


class KnownPoses:
    """An odometry that returns given poses (see the module docstring).

    Args:
        t_ns: (N,) int64 stamps of the known poses, increasing.
        T_world_left: (N, 4, 4) known ``T_world_left``.
        config: :class:`KnownPosesConfig`.

    Raises:
        OdometryError: mismatched shapes, fewer than one pose, or unsorted stamps.
    """

    name = "known poses"
    loop_closures = 0
    relinks = 0
    imu_disabled_reason: str | None = None
    """None: known poses take no measurements, so no IMU is left out."""

    def __init__(self, t_ns: NDArray[np.integer], T_world_left: F64,
                 config: KnownPosesConfig | None = None) -> None:
        self.config = config or KnownPosesConfig()
        self._t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        self._T = np.asarray(T_world_left, dtype=np.float64)
        if self._T.shape != (len(self._t), 4, 4) or len(self._t) == 0:
            raise OdometryError(f"known poses need (N,) stamps and (N, 4, 4) poses, N >= 1; got "
                                f"{self._t.shape} and {self._T.shape}")
        if np.any(np.diff(self._t) <= 0):
            raise OdometryError("known poses must have strictly increasing stamps")
        self._rot = Rotation.from_matrix(self._T[:, :3, :3])
        self._last_t: int | None = None
        self._frames_t: list[int] = []
        self._frames_T: list[F64] = []
        self._kf: dict[int, F64] = {}
        self._last_kf_T: F64 | None = None
        self._since_kf = 0
        self._segment = -1
        self._lost = True
        self._anchor: int | None = None
        self.loop_checks = LoopChecks(enabled=False)

    @property
    def keyframe_count(self) -> int:
        """Keyframes taken so far."""
        return len(self._kf)

    def _lookup(self, t: int) -> tuple[F64, bool]:
        j = int(np.searchsorted(self._t, t))
        if j < len(self._t) and self._t[j] == t:
            return self._T[j].copy(), True
        if j == 0 or j == len(self._t):
            return self._T[min(j, len(self._t) - 1)].copy(), False
        t0, t1 = int(self._t[j - 1]), int(self._t[j])
        if (t1 - t0) * 1e-9 > self.config.max_gap_s:
            near = j - 1 if t - t0 <= t1 - t else j
            return self._T[near].copy(), False
        a = (t - t0) / (t1 - t0)
        T = np.eye(4)
        T[:3, :3] = Slerp([0.0, 1.0], self._rot[[j - 1, j]])([a]).as_matrix()[0]
        T[:3, 3] = (1 - a) * self._T[j - 1, :3, 3] + a * self._T[j, :3, 3]
        return T, True

    def step(self, frame: FrameObservation) -> OdometryEstimate:
        t = int(frame.t_ns)
        if self._last_t is not None and t <= self._last_t:
            raise OdometryError(f"frame stamps must increase: {t} after {self._last_t}")
        self._last_t = t
        T, known = self._lookup(t)
        self._frames_t.append(t)
        self._frames_T.append(T)
        if not known:
            self._lost = True
            return OdometryEstimate(t_ns=t, T_world_left=T, status=TrackingStatus.LOST,
                                    segment=max(self._segment, 0))
        new_segment = self._lost
        if new_segment:
            self._segment += 1
            self._lost = False
        kf_id = None
        self._since_kf += 1
        if new_segment or self._last_kf_T is None or self._is_keyframe(T):
            kf_id = len(self._kf)
            self._kf[kf_id] = T
            self._last_kf_T = T
            self._since_kf = 0
            self._anchor = kf_id
        return OdometryEstimate(
            t_ns=t, T_world_left=T, status=TrackingStatus.TRACKING, segment=self._segment,
            keyframe_id=kf_id, anchor_keyframe_id=self._anchor,
        )

    def _is_keyframe(self, T: F64) -> bool:
        assert self._last_kf_T is not None
        rel = np.linalg.inv(self._last_kf_T) @ T
        moved = float(np.linalg.norm(rel[:3, 3]))
        turned = float(np.degrees(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1, 1))))
        c = self.config
        return moved >= c.keyframe_m or turned >= c.keyframe_deg or (
            self._since_kf >= c.keyframe_every)

    def keyframe_poses(self) -> dict[int, F64]:
        return {k: v.copy() for k, v in self._kf.items()}

    def trajectory(self) -> tuple[NDArray[np.int64], F64]:
        if not self._frames_t:
            return np.zeros(0, np.int64), np.zeros((0, 4, 4))
        return np.asarray(self._frames_t, np.int64), np.stack(self._frames_T)
