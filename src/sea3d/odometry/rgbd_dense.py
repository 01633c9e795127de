"""Dense frame-to-keyframe RGB-D odometry (depth from any source).

Each frame is aligned to the current *keyframe* (not to the previous frame) with Open3D's
multi-scale dense RGB-D odometry (point-to-plane by default; ``Hybrid`` adds a photometric
term and needs colour registered to depth), started from
the constant-velocity guess (the last frame-to-frame motion applied once more) and, when they
disagree, also from a feature pose (ORB matches to the keyframe, PnP-RANSAC on the keyframe's
depth), keeping the alignment of higher fitness: a jump the velocity guess cannot foresee (12 cm
after ten slow frames on 7-Scenes chess) is then tracked instead of slipping. Errors then
grow only when a new keyframe is taken, not at every frame, which is why it drifts less than
chaining frame-to-frame alignments (the paper's method).

A new keyframe is taken when the motion from the keyframe exceeds ``keyframe_m`` or
``keyframe_deg``, when the alignment's fitness (share of the frame's valid pixels that found a
correspondence) falls below ``keyframe_min_fitness``, or every ``keyframe_max_frames`` frames.
When the alignment against the keyframe fails (Open3D raises, too few valid depth pixels,
fitness below ``min_fitness``, or an implausible jump), the frame is retried against the
previous frame; if that fails as well the frame is ``LOST``: its pose is bridged by constant
velocity, and the next frame that tracks starts a new segment (and a keyframe) from there.

With ``tracking="model"`` each frame is first aligned (from the same starts) against the fused
TSDF model ray-cast at the previous pose (:mod:`sea3d.odometry.rgbd_model`), falling back to
the keyframe when the ray-cast covers too little of the frame or the alignment fails; every
tracked frame is fused into the model. With ``loop_closure`` every new keyframe is searched
for a return to an earlier one (:mod:`sea3d.odometry.rgbd_loop`: the stereo engine's place
recognition, verification and pose graph, the loop refined by the dense alignment of the two
keyframes); the trajectory is re-expressed against the corrected keyframes.

Poses are ``T_world_left`` with the world the first frame's camera.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import OdometryError
from sea3d.odometry.types import FrameObservation, LoopChecks, OdometryEstimate, TrackingStatus

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
    feature_init: bool = True
    """Also start the alignment from a feature pose (ORB matches to the keyframe, PnP-RANSAC
    on the keyframe's depth) when it disagrees with the constant-velocity guess, keeping the
    alignment of higher fitness: a sudden change of speed (a dropped stretch of frames, a
    jerk of the hand) puts the velocity guess outside the dense alignment's basin."""
    orb_features: int = 1000
    """ORB features per frame for the feature pose."""
    min_pnp_inliers: int = 30
    """PnP-RANSAC inliers needed for a feature pose."""
    init_disagree_m: float = 0.02
    """The feature pose is tried only when it differs from the velocity guess by more than
    this translation, metres, ..."""
    init_disagree_deg: float = 2.0
    """... or this rotation, degrees."""
    method: str = "point_to_plane"
    """Open3D's residual: ``hybrid`` (photometric + geometric), ``point_to_plane`` or
    ``intensity``. Point-to-plane beat Hybrid on 7-Scenes chess (its colour is not
    registered to its depth)."""
    tracking: str = "keyframe"
    """``keyframe``: align each frame to the current keyframe's depth; ``model``: align it to
    the fused TSDF model ray-cast at the previous pose (:mod:`sea3d.odometry.rgbd_model`),
    falling back to the keyframe when the ray-cast covers too little of the frame or the
    alignment fails."""
    voxel_px: float = 1.25
    """Model voxel edge in pixel footprints at the first frame's median depth."""
    trunc_voxels: float = 4.0
    """Model truncation distance, voxels."""
    min_model_share: float = 0.5
    """The model is aligned against only when its ray-cast has depth on at least this share
    of the pixels where the frame has depth."""
    loop_closure: bool = True
    """Detect loops between keyframes and re-optimise the keyframe pose graph
    (:mod:`sea3d.odometry.rgbd_loop`); the tracking (and the model) stay in the odometry
    frame, the trajectory is re-expressed against the corrected keyframes. On chess it found
    no loop on the paths that go on (their results unchanged) and both returns on the path
    there and back (end error 1.14 -> 0.69 cm, benchmarks/bench_rgbd.py)."""

    def __post_init__(self) -> None:
        if not (self.keyframe_m > 0 and self.keyframe_deg > 0 and self.keyframe_max_frames >= 1
                and 0 <= self.min_fitness <= 1 and 0 < self.min_depth_m < self.max_depth_m
                and self.depth_diff_m > 0 and len(self.iterations) >= 1
                and all(i >= 1 for i in self.iterations)
                and self.voxel_px > 0 and self.trunc_voxels > 0
                and 0 <= self.min_model_share <= 1):
            raise OdometryError("dense RGB-D config: thresholds out of range")
        if self.tracking not in ("keyframe", "model"):
            raise OdometryError(f"dense RGB-D tracking must be 'keyframe' or 'model', "
                                f"got {self.tracking!r}")


def _angle_deg(T: F64) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1.0, 1.0))))


@dataclass
class _Keyframe:
    kf_id: int
    image: object  # o3d.t.geometry.RGBDImage
    T_world: F64
    features: tuple[F64, NDArray[np.uint8]] | None = None  # (N, 3) points, (N, 32) ORB


def _grey(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    import cv2

    if img.ndim == 2:
        return img
    return np.asarray(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), np.uint8)


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
        self.relinks = 0  # segments are never re-linked
        self.loop_checks = LoopChecks(enabled=False)  # loops are counted in loop_closures only
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
        self._orb_detector: Any = None
        self.feature_inits = 0
        """Frames whose alignment started from the feature pose won."""
        self.model_frames = 0
        """Frames tracked against the TSDF model (``tracking="model"``)."""
        self._model: Any = None
        self._anchor: list[int] = []  # per frame its keyframe (-1: none)
        self._loops: Any = None
        self._kf_images: dict[int, object] = {}  # keyframe images, kept for loop closure
        self._image_hw = (0, 0)
        if c.loop_closure:
            from sea3d.odometry.rgbd_loop import RgbdLoopCloser

            self._loops = RgbdLoopCloser(self.K)

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

    def _orb(self, grey: NDArray[np.uint8]) -> tuple[F64, NDArray[np.uint8] | None]:
        import cv2

        if self._orb_detector is None:
            self._orb_detector = cv2.ORB_create(  # type: ignore[attr-defined]
                nfeatures=self.config.orb_features)
        kps, desc = self._orb_detector.detectAndCompute(grey, None)
        if desc is None or not kps:
            return np.zeros((0, 2)), None
        return np.array([k.pt for k in kps], np.float64), desc

    def _keyframe_features(self, grey: NDArray[np.uint8], depth: NDArray[np.float32]
                           ) -> tuple[F64, NDArray[np.uint8]] | None:
        """3D points (keyframe camera, metres) and ORB descriptors of the keyframe's features
        with valid depth."""
        uv, desc = self._orb(grey)
        if desc is None:
            return None
        c = self.config
        u = np.clip(np.round(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
        v = np.clip(np.round(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
        z = depth[v, u].astype(np.float64)
        ok = np.isfinite(z) & (z > c.min_depth_m) & (z < c.max_depth_m)
        if np.count_nonzero(ok) < c.min_pnp_inliers:
            return None
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        X = np.stack([(uv[ok, 0] - cx) * z[ok] / fx, (uv[ok, 1] - cy) * z[ok] / fy, z[ok]], 1)
        return X, desc[ok]

    def _feature_pose(self, grey: NDArray[np.uint8]) -> F64 | None:
        """``T_kf_cur`` from ORB matches to the keyframe and PnP-RANSAC, or None."""
        import cv2

        kf = self._kf
        if kf is None or kf.features is None:
            return None
        X, desc_kf = kf.features
        uv, desc = self._orb(grey)
        if desc is None:
            return None
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        pairs = matcher.knnMatch(desc_kf, desc, k=2)
        good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
        if len(good) < self.config.min_pnp_inliers:
            return None
        obj = np.ascontiguousarray(X[[m.queryIdx for m in good]])
        img = np.ascontiguousarray(uv[[m.trainIdx for m in good]])
        no_dist = np.zeros(5)
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            obj, img, self.K, no_dist, iterationsCount=200, reprojectionError=3.0,
            confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
        if not ok or inl is None or len(inl) < self.config.min_pnp_inliers:
            return None
        idx = inl.ravel()
        ok, rvec, tvec = cv2.solvePnP(obj[idx], img[idx], self.K, no_dist, rvec, tvec,
                                      useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            return None
        T_cur_kf = np.eye(4)
        T_cur_kf[:3, :3] = cv2.Rodrigues(rvec)[0]
        T_cur_kf[:3, 3] = tvec.ravel()
        return np.asarray(np.linalg.inv(T_cur_kf), np.float64)

    def _new_keyframe(self, image: object, T: F64,
                      grey: NDArray[np.uint8] | None = None,
                      depth: NDArray[np.float32] | None = None) -> int:
        kf_id = self.keyframe_count
        self.keyframe_count += 1
        feats = (self._keyframe_features(grey, depth)
                 if self.config.feature_init and grey is not None and depth is not None
                 else None)
        self._kf = _Keyframe(kf_id, image, T.copy(), feats)
        self._kf_poses[kf_id] = T.copy()
        self._since_kf = 0
        if self._loops is not None and grey is not None and depth is not None:
            self._kf_images[kf_id] = image
            if self._loops.add_keyframe(kf_id, self._segment, T, grey, depth,
                                        refine=lambda q, T_q_k: self._refine_loop(q, kf_id, T_q_k)):
                self.loop_closures = self._loops.loop_closures
        return kf_id

    def _refine_loop(self, cand: int, query: int, T_cand_query: F64) -> F64 | None:
        """A verified loop's ``T_cand_query`` refined by the dense alignment of the two
        keyframes (started from the feature pose), or None when it fails or moves the feature
        pose by more than a plausible step."""
        res = self._align(self._kf_images[query], self._kf_images[cand], T_cand_query)
        if res is None or res[1] < self.config.min_fitness:
            return None
        if not self._plausible(np.linalg.inv(T_cand_query) @ res[0]):
            return None
        return res[0]

    def _new_model(self, depth: NDArray[np.float32]) -> Any:
        from sea3d.odometry.rgbd_model import TsdfModel, voxel_from_depth

        c = self.config
        ok = np.isfinite(depth) & (depth > c.min_depth_m) & (depth < c.max_depth_m)
        voxel = voxel_from_depth(np.where(ok, depth, np.float32(0)), float(self.K[0, 0]),
                                 c.voxel_px)
        h, w = depth.shape
        log.debug("TSDF model: %.1f mm voxels", 1e3 * voxel)
        return TsdfModel(self.K, w, h, voxel_m=voxel, trunc_voxels=c.trunc_voxels,
                         min_depth_m=c.min_depth_m, max_depth_m=c.max_depth_m)

    def _integrate(self, frame: FrameObservation, T: F64) -> None:
        if self._model is None:
            return
        c = self.config
        z = np.asarray(frame.depth_m, np.float32)
        ok = np.isfinite(z) & (z > c.min_depth_m) & (z < c.max_depth_m)
        rgb = np.asarray(frame.rect_left)
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[..., None], 3, axis=2)
        self._model.integrate(rgb, np.where(ok, z, np.float32(0)), T)

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
        self._image_hw = (int(frame.depth_m.shape[0]), int(frame.depth_m.shape[1]))
        image, valid_share = self._image(frame)
        grey = _grey(np.asarray(frame.rect_left))
        depth = np.asarray(frame.depth_m, np.float32)
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
            if c.tracking == "model":  # a new segment gets a new model
                self._model = self._new_model(depth)
            kf_id = self._new_keyframe(image, guess_T, grey, depth)
            self._integrate(frame, guess_T)
            return self._emit(t, guess_T, image, TrackingStatus.TRACKING, kf_id, kf_id, info)

        kf = self._kf
        assert self._prev_T is not None
        # starting poses, in the world: constant velocity, and the feature pose on disagreement
        starts = [guess_T if c.use_velocity else self._prev_T]
        if c.feature_init and depth_ok:
            T_feat = self._feature_pose(grey)
            if T_feat is not None:
                d = np.linalg.inv(np.linalg.inv(kf.T_world) @ starts[0]) @ T_feat
                if (float(np.linalg.norm(d[:3, 3])) > c.init_disagree_m
                        or _angle_deg(d) > c.init_disagree_deg):
                    starts.append(kf.T_world @ T_feat)
        # targets: the model ray-cast at the previous pose (when it covers the frame), then
        # the keyframe; the first target that gives a good alignment is kept
        targets: list[tuple[object, F64, bool]] = []
        if self._model is not None and depth_ok:
            rendered = self._model.render(self._prev_T)
            if rendered is not None:
                frame_px = max(valid_share * depth.size, 1.0)
                share = float(np.count_nonzero(rendered[1] > 0)) / frame_px
                info["model_share"] = share
                if share >= c.min_model_share:
                    targets.append((rendered[0], self._prev_T, True))
        targets.append((kf.image, kf.T_world, False))
        T_new: F64 | None = None
        fitness = 0.0
        for target, T_target, is_model in targets:
            from_feature = False
            for k, start in enumerate(starts):
                res = (self._align(image, target, np.linalg.inv(T_target) @ start)
                       if depth_ok else None)
                if res is None:
                    continue
                T_tgt_cur, fit = res
                T_cand = T_target @ T_tgt_cur
                if (fit >= c.min_fitness and fit > fitness
                        and self._plausible(np.linalg.inv(self._prev_T) @ T_cand)):
                    T_new, fitness, from_feature = T_cand, fit, k > 0
            if T_new is not None:
                self.feature_inits += int(from_feature)
                self.model_frames += int(is_model)
                info["model"] = float(is_model)
                break
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
        new_kf: int | None = (self._new_keyframe(image, T_new, grey, depth) if make_kf
                              else None)
        anchor = new_kf if new_kf is not None else kf.kf_id
        self._integrate(frame, T_new)
        return self._emit(t, T_new, image, TrackingStatus.TRACKING, new_kf, anchor, info)

    def _emit(self, t: int, T: F64, image: object, status: TrackingStatus, kf_id: int | None,
              anchor: int | None, info: dict[str, float]) -> OdometryEstimate:
        self._prev_T = T
        self._prev_image = image
        self._t.append(t)
        self._T.append(T.copy())
        self._anchor.append(-1 if anchor is None else anchor)
        T = self._corrected(T, anchor)
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
        anchor = self._kf.kf_id if self._kf is not None else -1
        self._anchor.append(anchor)
        T_guess = self._corrected(T_guess, anchor)
        return OdometryEstimate(t_ns=t, T_world_left=T_guess.copy(), status=TrackingStatus.LOST,
                                segment=max(self._segment, 0), info=info)

    def _corrected(self, T: F64, anchor: int | None) -> F64:
        """``T`` (odometry frame) re-expressed against its anchor keyframe's corrected pose."""
        if self._loops is None or anchor is None or anchor < 0:
            return T
        return np.asarray(self._loops.correction(anchor) @ T, np.float64)

    def keyframe_poses(self) -> dict[int, F64]:
        return {k: self._corrected(v, k) for k, v in self._kf_poses.items()}

    def trajectory(self) -> tuple[NDArray[np.int64], F64]:
        if not self._t:
            return np.zeros(0, np.int64), np.zeros((0, 4, 4))
        T = [self._corrected(Ti, a) for Ti, a in zip(self._T, self._anchor, strict=True)]
        return np.asarray(self._t, np.int64), np.stack(T)

    def memory_bytes(self) -> int:
        """Bytes of state held: the poses, the keyframe images kept for loop closure (about
        2 MB each at 640x480: colour and float depth) and the model's voxel blocks."""
        n = 16 * 8 * len(self._T)
        if self._kf_images:
            h, w = self._image_hw
            n += len(self._kf_images) * h * w * 7  # 3 colour bytes and 4 depth bytes a pixel
        if self._model is not None:
            vox = 8**3  # voxels a block
            n += self._model.blocks() * vox * 5 * 4  # tsdf, weight, colour (3): float32
        return n
