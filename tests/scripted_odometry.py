"""A scripted odometry for pipeline tests: ground-truth poses with planted trouble.

- keyframes every ``keyframe_every`` frames;
- ``lost`` frames report LOST with a pose 0.5 m off (fusing them would spoil the mesh);
- from ``drift_from`` on, poses (and keyframes) drift by ``drift`` until the frame
  ``loop_at``, which closes a loop: every keyframe pose is corrected to the truth, and the
  final trajectory is the truth; ``forget_loop`` makes the odometry not report the
  correction (what fusion would see if it ignored loop closures).
"""

from __future__ import annotations

import numpy as np

from sea3d.odometry.types import FrameObservation, LoopChecks, OdometryEstimate, TrackingStatus


class ScriptedOdometry:
    name = "scripted test odometry"
    loop_closures = 0  # the pipeline counts the closures it is told of
    relinks = 0
    imu_disabled_reason = None

    def __init__(self, t_ns, T_world_left, *, keyframe_every=3, lost=(), drift_from=None,
                 loop_at=None, drift=None, forget_loop=False):
        self.truth = {int(t): T for t, T in zip(t_ns, T_world_left, strict=True)}
        self.keyframe_every = keyframe_every
        self.lost = set(lost)
        self.drift_from, self.loop_at = drift_from, loop_at
        self.drift = np.eye(4) if drift is None else drift
        self.forget_loop = forget_loop
        self.k = -1
        self.kf_est: dict[int, np.ndarray] = {}
        self.kf_true: dict[int, np.ndarray] = {}
        self.closed = False
        self.frames: list[int] = []
        self.anchor: int | None = None
        self.loop_checks = LoopChecks(enabled=False)

    @property
    def keyframe_count(self):
        return len(self.kf_est)

    def step(self, frame: FrameObservation) -> OdometryEstimate:
        self.k += 1
        t = int(frame.t_ns)
        self.frames.append(t)
        T_true = self.truth[t]
        drifting = (self.drift_from is not None and self.k >= self.drift_from
                    and (self.loop_at is None or self.k < self.loop_at))
        T = self.drift @ T_true if drifting else T_true
        if self.k in self.lost:
            off = T_true.copy()
            off[:3, 3] += 0.5
            return OdometryEstimate(t_ns=t, T_world_left=off, status=TrackingStatus.LOST)
        kf = None
        if self.k % self.keyframe_every == 0:
            kf = len(self.kf_est)
            self.kf_est[kf] = T
            self.kf_true[kf] = T_true
            self.anchor = kf
        loop = self.loop_at is not None and self.k == self.loop_at
        if loop:
            self.closed = True
        return OdometryEstimate(t_ns=t, T_world_left=T, status=TrackingStatus.TRACKING,
                                keyframe_id=kf, anchor_keyframe_id=self.anchor,
                                loop_closure=loop and not self.forget_loop)

    def keyframe_poses(self):
        if self.closed and not self.forget_loop:
            return {k: v.copy() for k, v in self.kf_true.items()}
        return {k: v.copy() for k, v in self.kf_est.items()}

    def trajectory(self):
        return np.asarray(self.frames, np.int64), np.stack([self.truth[t] for t in self.frames])


def tint_red(image):
    """An 'enhancement' for tests: halves green and blue (a visible, checkable change)."""
    out = image.copy()
    if out.ndim == 3:
        out[..., 1:] //= 2
    return out
