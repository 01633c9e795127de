"""Dense frame-to-keyframe RGB-D odometry (depth from any source).

Each frame is aligned to the current *keyframe* (not to the previous frame) with Open3D's
multi-scale dense RGB-D odometry (point-to-plane by default; ``Hybrid`` adds a photometric
term and needs colour registered to depth), started from
the constant-velocity guess (the last frame-to-frame motion applied once more). Errors then
grow only when a new keyframe is taken, not at every frame, which is why it drifts less than
chaining frame-to-frame alignments (the paper's method).

A new keyframe is taken when the motion from the keyframe exceeds ``keyframe_m`` or
``keyframe_deg``, when the alignment's fitness (share of the frame's valid pixels that found a
correspondence) falls below ``keyframe_min_fitness``, or every ``keyframe_max_frames`` frames.
When the alignment against the keyframe fails (Open3D raises, too few valid depth pixels,
fitness below ``min_fitness``, or an implausible jump), the frame is retried against the
previous frame; if that fails as well the frame is ``LOST``: its pose is bridged by constant
velocity, and the next frame that tracks starts a new segment (and a keyframe) from there.

Poses are ``T_world_left`` with the world the first frame's camera.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import OdometryError
from sea3d.odometry.types import FrameObservation, OdometryEstimate, TrackingStatus

__all__ = ["DenseRgbdConfig", "DenseRgbdOdometry"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class DenseRgbdConfig:
    """Tunables of :class:`DenseRgbdOdometry` (tuned on 7-Scenes chess, see docs/odometry.md)."""

    keyframe_m: float = 0.10
    """Translation from the keyframe that makes the frame a new keyframe, metres."""
    keyframe_deg: float = 10.0
    """Rotation from the keyframe that makes the frame a new keyframe, degrees."""
    keyframe_min_fitness: float = 0.5
    """Fitness against the keyframe below which the frame becomes a new keyframe."""
    keyframe_max_frames: int = 1000
    """Most frames between keyframes."""
    min_fitness: float = 0.15
    """Fitness below which an alignment counts as failed."""
    min_valid_depth: float = 0.05
    """Smallest share of pixels with valid depth for a frame to be aligned."""
    max_step_m: float = 0.30
    """Largest plausible motion between consecutive frames, metres (beyond: failed)."""
    max_step_deg: float = 30.0
    """Largest plausible rotation between consecutive frames, degrees."""
    min_depth_m: float = 0.1
    """Nearest depth used, metres."""
    max_depth_m: float = 4.0
    """Farthest depth used, metres."""
    depth_diff_m: float = 0.07
    """Largest depth difference of a correspondence, metres (Open3D's ``depth_outlier_trunc``)."""
    iterations: tuple[int, ...] = (10, 5, 3)
    """Gauss-Newton iterations per pyramid level, finest first."""
    use_velocity: bool = True
    """Start each alignment from the constant-velocity guess (False: from the last pose)."""
    method: str = "point_to_plane"
    """Open3D's residual: ``hybrid`` (photometric + geometric), ``point_to_plane`` or
    ``intensity``. Point-to-plane beat Hybrid on 7-Scenes chess (its colour is not
    registered to its depth)."""

    def __post_init__(self) -> None:
        if not (self.keyframe_m > 0 and self.keyframe_deg > 0 and self.keyframe_max_frames >= 1
                and 0 <= self.min_fitness <= 1 and 0 < self.min_depth_m < self.max_depth_m
                and self.depth_diff_m > 0 and len(self.iterations) >= 1
                and all(i >= 1 for i in self.iterations)):
            raise OdometryError("dense RGB-D config: thresholds out of range")


def _angle_deg(T: F64) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1.0, 1.0))))


@dataclass
class _Keyframe:
    kf_id: int
    image: object  # o3d.t.geometry.RGBDImage
    T_world: F64


class DenseRgbdOdometry:
    """Dense frame-to-keyframe RGB-D odometry (see the module docstring); an
    :class:`~sea3d.odometry.types.Odometry`.

    Args:
        K: (3, 3) intrinsics of the depth-registered colour camera.
        config: :class:`DenseRgbdConfig`.
    """

    name = "dense RGB-D"

    def __init__(self, K: F64, config: DenseRgbdConfig | None = None) -> None:
        import open3d as o3d

        self._o3d = o3d
        self.config = config or DenseRgbdConfig()
        self.K = np.asarray(K, np.float64).reshape(3, 3)
        self._K_t = o3d.core.Tensor.from_numpy(np.ascontiguousarray(self.K))
        c = self.config
        self._criteria = [o3d.t.pipelines.odometry.OdometryConvergenceCriteria(i)
                          for i in c.iterations]
        self._params = o3d.t.pipelines.odometry.OdometryLossParams(
            depth_outlier_trunc=c.depth_diff_m)
        methods = {"hybrid": o3d.t.pipelines.odometry.Method.Hybrid,
                   "point_to_plane": o3d.t.pipelines.odometry.Method.PointToPlane,
                   "intensity": o3d.t.pipelines.odometry.Method.Intensity}
        if c.method not in methods:
            raise OdometryError(f"dense RGB-D method must be one of {sorted(methods)}, "
                                f"got {c.method!r}")
        self._method = methods[c.method]
        self.imu_disabled_reason: str | None = "RGB-D mode"
        self.keyframe_count = 0
        self.loop_closures = 0
        self._kf: _Keyframe | None = None
        self._kf_poses: dict[int, F64] = {}
        self._prev_image: object | None = None
        self._prev_T: F64 | None = None
        self._velocity = np.eye(4)  # T_prev_cur of the last step
        self._since_kf = 0
        self._segment = -1
        self._lost = True
        self._last_t: int | None = None
        self._t: list[int] = []
        self._T: list[F64] = []

    # ------------------------------------------------------------------ helpers
    def _image(self, frame: FrameObservation) -> tuple[object, float]:
        o3d = self._o3d
        img = frame.rect_left
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        depth = np.asarray(frame.depth_m, np.float32)
        valid = np.isfinite(depth) & (depth > self.config.min_depth_m) & (
            depth < self.config.max_depth_m)
        d = np.where(valid, depth, np.float32(0.0)).astype(np.float32)
        rgbd = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.ascontiguousarray(img)),
                                        o3d.t.geometry.Image(np.ascontiguousarray(d)))
        return rgbd, float(valid.mean())

    def _align(self, src: object, dst: object, init: F64) -> tuple[F64, float] | None:
        """``T_dst_src`` and the fitness, or None when Open3D fails."""
        o3d = self._o3d
        try:
            r = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                src, dst, self._K_t, o3d.core.Tensor.from_numpy(np.ascontiguousarray(init)), 1.0,
                self.config.max_depth_m,
                self._criteria, self._method, self._params)
        except RuntimeError as e:  # Open3D raises when too few correspondences remain
            log.debug("dense RGB-D alignment failed: %s", e)
            return None
        T = np.asarray(r.transformation.numpy(), np.float64)
        if not np.all(np.isfinite(T)):
            return None
        return T, float(r.fitness)

    def _plausible(self, step: F64) -> bool:
        c = self.config
        return (float(np.linalg.norm(step[:3, 3])) <= c.max_step_m
                and _angle_deg(step) <= c.max_step_deg)

    def _new_keyframe(self, image: object, T: F64) -> int:
        kf_id = self.keyframe_count
        self.keyframe_count += 1
        self._kf = _Keyframe(kf_id, image, T.copy())
        self._kf_poses[kf_id] = T.copy()
        self._since_kf = 0
        return kf_id

    # ------------------------------------------------------------------ Odometry
    def step(self, frame: FrameObservation) -> OdometryEstimate:
        t = int(frame.t_ns)
        if self._last_t is not None and t <= self._last_t:
            raise OdometryError(f"frame stamps must increase: {t} after {self._last_t}")
        if frame.depth_m.shape != frame.rect_left.shape[:2]:
            raise OdometryError(f"depth {frame.depth_m.shape} and image "
                                f"{frame.rect_left.shape[:2]} differ in size")
        self._last_t = t
        c = self.config
        image, valid_share = self._image(frame)
        guess_T = (self._prev_T @ self._velocity if self._prev_T is not None
                   else np.eye(4))
        depth_ok = valid_share >= c.min_valid_depth
        info: dict[str, float] = {"valid_depth": valid_share}

        if self._kf is None or self._lost:
            if not depth_ok:
                return self._emit_lost(t, guess_T, info)
            # first frame, or first frame after a loss: start a segment here
            self._segment += 1
            self._lost = False
            kf_id = self._new_keyframe(image, guess_T)
            return self._emit(t, guess_T, image, TrackingStatus.TRACKING, kf_id, kf_id, info)

        kf = self._kf
        assert self._prev_T is not None
        T_kf_guess = np.linalg.inv(kf.T_world) @ guess_T
        if not c.use_velocity:
            T_kf_guess = np.linalg.inv(kf.T_world) @ self._prev_T
        res = self._align(image, kf.image, T_kf_guess) if depth_ok else None
        T_new: F64 | None = None
        fitness = 0.0
        if res is not None:
            T_kf_cur, fitness = res
            T_cand = kf.T_world @ T_kf_cur
            if fitness >= c.min_fitness and self._plausible(np.linalg.inv(self._prev_T) @ T_cand):
                T_new = T_cand
        if T_new is None and depth_ok and self._prev_image is not None and (
                self._prev_image is not kf.image):
            # retry against the previous frame, then make this frame a keyframe
            res2 = self._align(image, self._prev_image,
                               np.linalg.inv(self._prev_T) @ guess_T)
            if res2 is not None and res2[1] >= c.min_fitness and self._plausible(res2[0]):
                T_new = self._prev_T @ res2[0]
                fitness = 0.0  # force a keyframe
        info["fitness"] = fitness
        if T_new is None:
            return self._emit_lost(t, guess_T, info)
        self._velocity = np.linalg.inv(self._prev_T) @ T_new
        self._since_kf += 1
        rel = np.linalg.inv(kf.T_world) @ T_new
        make_kf = (float(np.linalg.norm(rel[:3, 3])) >= c.keyframe_m
                   or _angle_deg(rel) >= c.keyframe_deg
                   or fitness < c.keyframe_min_fitness
                   or self._since_kf >= c.keyframe_max_frames)
        new_kf: int | None = self._new_keyframe(image, T_new) if make_kf else None
        anchor = new_kf if new_kf is not None else kf.kf_id
        return self._emit(t, T_new, image, TrackingStatus.TRACKING, new_kf, anchor, info)

    def _emit(self, t: int, T: F64, image: object, status: TrackingStatus, kf_id: int | None,
              anchor: int | None, info: dict[str, float]) -> OdometryEstimate:
        self._prev_T = T
        self._prev_image = image
        self._t.append(t)
        self._T.append(T.copy())
        return OdometryEstimate(t_ns=t, T_world_left=T.copy(), status=status,
                                segment=self._segment, keyframe_id=kf_id,
                                anchor_keyframe_id=anchor, info=info)

    def _emit_lost(self, t: int, T_guess: F64, info: dict[str, float]) -> OdometryEstimate:
        # constant-velocity bridge; the next frame that tracks starts a new segment
        self._lost = True
        self._prev_T = T_guess
        self._prev_image = None
        self._t.append(t)
        self._T.append(T_guess.copy())
        return OdometryEstimate(t_ns=t, T_world_left=T_guess.copy(), status=TrackingStatus.LOST,
                                segment=max(self._segment, 0), info=info)

    def keyframe_poses(self) -> dict[int, F64]:
        return {k: v.copy() for k, v in self._kf_poses.items()}

    def trajectory(self) -> tuple[NDArray[np.int64], F64]:
        if not self._t:
            return np.zeros(0, np.int64), np.zeros((0, 4, 4))
        return np.asarray(self._t, np.int64), np.stack(self._T)

    def memory_bytes(self) -> int:
        """Bytes of state held (the poses; one keyframe image and the previous frame)."""
        return 16 * 8 * len(self._T)
