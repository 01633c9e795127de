"""Stereo(-inertial) odometry with keyframes, fixed-lag smoothing and loop closure.

:class:`StereoInertialOdometry` implements the :class:`~sea3d.odometry.types.Odometry`
protocol. Per frame: predict the pose (IMU preintegration from the last keyframe, or a constant
velocity), track the features (KLT), match them into the right image, and solve the pose by PnP
RANSAC against the landmarks. A keyframe is made when tracking thins out or every
``keyframe_max_interval_s``; keyframes go to the fixed-lag smoother
(:class:`~sea3d.odometry.backend.SmootherBackend`), get new features, and are searched for loops
(:mod:`sea3d.odometry.loop`); a verified loop re-optimises the keyframe pose graph
(:class:`~sea3d.odometry.posegraph.PoseGraph`).

Every frame gets a status. When vision fails, the IMU carries the pose (``IMU_ONLY``) for up to
``imu_bridge_s`` while the front end tries to re-acquire features; without an IMU, or past that
time, the frame is ``LOST`` and the next frame that has enough features starts a new *segment*
from the last pose (no jump), which a later loop closure joins to an earlier one (that frame is
``RELOCALISED``). Frames are stored relative to their anchor keyframe, so :meth:`trajectory`
gives every frame after the last optimisation.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._text import plural
from sea3d._typing import F64
from sea3d.errors import OdometryError, SmootherFailure
from sea3d.geometry.rig import ImuSpec
from sea3d.geometry.se3 import invert_T
from sea3d.odometry.backend import KeyframeState, SmootherBackend
from sea3d.odometry.config import OdometryConfig
from sea3d.odometry.frontend import (
    StereoPoints,
    detect_corners,
    predicted_affine,
    sample_depth,
    solve_pnp,
    stereo_points,
    to_grey,
    track_klt,
    track_warped,
)
from sea3d.odometry.imu import ImuBuffer, gravity_aligned_rotation, preintegration_params
from sea3d.odometry.loop import (
    KeyframeDatabase,
    LoopCandidate,
    PlaceFeatures,
    QueryMatcher,
    Vocabulary,
    confirm_loop,
    verify_loop,
)
from sea3d.odometry.posegraph import PoseGraph
from sea3d.odometry.stereo_geometry import RectifiedStereo
from sea3d.odometry.types import FrameObservation, LoopChecks, OdometryEstimate, TrackingStatus

__all__ = ["StereoInertialOdometry"]

log = logging.getLogger(__name__)


def _rotation_angle(R: F64) -> float:
    c = (float(np.trace(R)) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


@dataclass
class _Keyframe:
    id: int
    t_ns: int
    segment: int
    T_odom: F64  # T_odomworld_rect: the pose in its segment's smoother frame
    correction: F64  # T_world_odomworld from the last pose-graph solution
    place: PlaceFeatures | None = None
    bow: tuple[NDArray[np.int64], NDArray[np.float32]] | None = None

    @property
    def T_world_rect(self) -> F64:
        return self.correction @ self.T_odom


@dataclass
class _Segment:
    id: int
    backend: SmootherBackend
    correction: F64
    track_ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    track_uv: F64 = field(default_factory=lambda: np.zeros((0, 2)))
    track_X: F64 = field(default_factory=lambda: np.zeros((0, 3)))
    prev_grey: NDArray[np.uint8] | None = None
    last_kf: int = -1
    kf_t_ns: int = 0
    kf_tracks: int = 0
    kf_ids: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    kf_uv: F64 = field(default_factory=lambda: np.zeros((0, 2)))  # at the keyframe, sorted ids
    kf_grey: NDArray[np.uint8] | None = None  # the keyframe's left image
    state: KeyframeState | None = None
    pim: object | None = None
    imu_link_ok: bool = True
    last_T_odom: F64 | None = None  # last frame's T_odomworld_rect
    prev_T_odom: F64 | None = None
    last_t_ns: int = 0
    prev_t_ns: int = 0
    last_vision_t_ns: int = 0
    keyframes: list[int] = field(default_factory=list)
    loops_since: int = 10**9
    frames_since_kf: int = 0


class StereoInertialOdometry:
    """The odometry (see the module docstring).

    Args:
        geometry: the rectified stereo pair (:meth:`RectifiedStereo.from_maps`), or the RGB-D
            camera with its virtual baseline (:meth:`RectifiedStereo.pinhole`).
        imu: the rig's IMU, or None for visual-only.
        config: :class:`OdometryConfig`.
        use_right: match features into the right image (False: RGB-D, depth only).
    """

    name = "sea3d stereo odometry"

    def __init__(
        self,
        geometry: RectifiedStereo,
        *,
        imu: ImuSpec | None = None,
        config: OdometryConfig | None = None,
        use_right: bool = True,
    ) -> None:
        self.geometry = geometry
        self.config = config or OdometryConfig()
        self.imu = imu
        self.use_right = use_right
        R1 = geometry.R_rect_left_left if geometry.R_rect_left_left is not None else np.eye(3)
        self.T_rect_left = np.eye(4)
        self.T_rect_left[:3, :3] = R1
        self.T_left_rect = invert_T(self.T_rect_left)
        if imu is not None:
            self.T_body_rect = imu.T_imu_left @ self.T_left_rect
            self._imu_params = preintegration_params(imu, self.config.imu_noise_scale)
            self._buffer = ImuBuffer(offset_ns=round(imu.time_offset_s * 1e9))
        else:
            self.T_body_rect = np.eye(4)
            self._imu_params = None
            self._buffer = ImuBuffer()
        self.T_rect_body = invert_T(self.T_body_rect)
        self.imu_disabled_reason: str | None = None if imu is not None else "the rig has no IMU"
        # state
        self._seg: _Segment | None = None
        self._segments_started = 0
        self._parent: dict[int, int] = {}
        self._keyframes: dict[int, _Keyframe] = {}
        self._kf_order: list[int] = []
        self._next_kf = 0
        self._next_landmark = 0
        self._continuity_world: F64 = np.eye(4)  # last known T_world_rect (corrected)
        self._continuity_set = False
        self._last_t_ns: int | None = None
        self._frames_t: list[int] = []
        self._frames_anchor: list[int] = []
        self._frames_rel: list[F64] = []
        self._frames_status: list[TrackingStatus] = []
        # loop closure
        self._graph = PoseGraph(
            rotation_sigma_rad=self.config.pose_graph_rotation_sigma_rad,
            translation_sigma_m=self.config.pose_graph_translation_sigma_m,
            drift_per_m=self.config.pose_graph_drift_per_m,
            loop_rotation_sigma_rad=self.config.loop_rotation_sigma_rad,
            loop_translation_sigma_m=self.config.loop_translation_sigma_m,
        )
        self._vocab: Vocabulary | None = None
        self._db: KeyframeDatabase | None = None
        self._orb = cv2.ORB_create(  # type: ignore[attr-defined]
            nfeatures=self.config.orb_features, fastThreshold=7
        )
        self._clahe = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8))
        self.loop_closures = 0
        self.relinks = 0
        self.loop_checks = LoopChecks(enabled=self.config.loop_closure)
        self._last_relink = False
        self.frames_lost = 0
        self.seconds = 0.0
        self.imu_frames_without_samples = 0
        self._imu_missing_run = 0

    # ------------------------------------------------------------------ public API
    @property
    def inertial(self) -> bool:
        """True while the IMU is used."""
        return self.imu is not None and self.imu_disabled_reason is None

    def step(self, frame: FrameObservation) -> OdometryEstimate:
        """See :meth:`sea3d.odometry.types.Odometry.step`.

        Raises:
            OdometryError: wrong image shapes or dtypes, or a stamp not after the previous one.
        """
        t0 = time.perf_counter()
        self._validate(frame)
        self._last_t_ns = int(frame.t_ns)
        grey = to_grey(frame.rect_left)
        right = to_grey(frame.rect_right) if self.use_right else None
        depth = np.asarray(frame.depth_m, dtype=np.float32)
        self._feed_imu(frame)
        if self._seg is None:
            est = self._start(frame.t_ns, grey, right, depth)
        else:
            est = self._track(frame.t_ns, grey, right, depth)
        dt = time.perf_counter() - t0
        self.seconds += dt
        est.info["step_s"] = dt
        if est.status is TrackingStatus.LOST:
            self.frames_lost += 1
        return est

    def keyframe_poses(self) -> dict[int, F64]:
        """Current ``T_world_left`` of every keyframe (after the last loop closure)."""
        return {k: kf.T_world_rect @ self.T_rect_left for k, kf in self._keyframes.items()}

    def trajectory(self) -> tuple[NDArray[np.int64], F64]:
        """``(t_ns (N,), T_world_left (N, 4, 4))`` of every frame seen."""
        n = len(self._frames_t)
        T = np.zeros((n, 4, 4))
        for i in range(n):
            a = self._frames_anchor[i]
            base = self._keyframes[a].T_world_rect if a >= 0 else np.eye(4)
            T[i] = base @ self._frames_rel[i] @ self.T_rect_left
        return np.asarray(self._frames_t, dtype=np.int64), T

    def statuses(self) -> list[TrackingStatus]:
        """The status of every frame seen, in order."""
        return list(self._frames_status)

    @property
    def keyframe_count(self) -> int:
        """Keyframes made so far."""
        return len(self._keyframes)

    def memory_bytes(self) -> int:
        """Approximate memory held by the per-frame and per-keyframe records, bytes."""
        per_frame = 8 + 8 + 16 * 8 + 8
        kf = sum(
            (k.place.nbytes if k.place is not None else 0)
            + (k.bow[0].nbytes + k.bow[1].nbytes if k.bow is not None else 0)
            + 2 * 128
            for k in self._keyframes.values()
        )
        return len(self._frames_t) * per_frame + kf

    # ------------------------------------------------------------------ input
    def _validate(self, frame: FrameObservation) -> None:
        g = self.geometry
        shape = (g.height, g.width)
        for name in ("rect_left", "rect_right", "depth_m"):
            arr = getattr(frame, name)
            if name == "rect_right" and not self.use_right:
                continue
            if not isinstance(arr, np.ndarray) or arr.shape[:2] != shape:
                got = getattr(arr, "shape", type(arr).__name__)
                raise OdometryError(
                    f"frame t_ns={frame.t_ns}: {name} must be {g.width}x{g.height}, got {got}"
                )
        for name in ("rect_left", "rect_right"):
            arr = getattr(frame, name)
            if name == "rect_right" and not self.use_right:
                continue
            if arr.dtype != np.uint8 or arr.ndim not in (2, 3):
                raise OdometryError(
                    f"frame t_ns={frame.t_ns}: {name} must be uint8 grey or RGB, got "
                    f"{arr.dtype} {arr.shape}"
                )
        if frame.depth_m.ndim != 2:
            raise OdometryError(f"frame t_ns={frame.t_ns}: depth_m must be (H, W)")
        if self._last_t_ns is not None and int(frame.t_ns) <= self._last_t_ns:
            raise OdometryError(
                f"frame t_ns={frame.t_ns} is not after the previous frame ({self._last_t_ns}); "
                "frames must come in strictly increasing time (sort them, drop duplicates)"
            )

    def _feed_imu(self, frame: FrameObservation) -> None:
        if self.imu is None or self.imu_disabled_reason is not None:
            return
        chunk = frame.imu
        if chunk is None or len(chunk.t_ns) == 0:
            self.imu_frames_without_samples += 1
            self._imu_missing_run += 1
            if self._imu_missing_run * 1.0 >= 20 and self._buffer.last_t_ns is None:
                self.imu_disabled_reason = "the frames carry no IMU samples"
                log.warning("odometry runs visual-only: %s", self.imu_disabled_reason)
            return
        self._imu_missing_run = 0
        t = np.asarray(chunk.t_ns, dtype=np.int64) - self._buffer.offset_ns
        tol = int(self.config.imu_max_clock_offset_s * 1e9)
        if self._buffer.last_t_ns is None and not self._buffer.t_ns:
            # first samples: they must lie near the camera's clock
            if t.min() > frame.t_ns + tol or t.max() < frame.t_ns - tol - int(2e9):
                self.imu_disabled_reason = (
                    f"IMU stamps ({t.min() * 1e-9:.3f}..{t.max() * 1e-9:.3f} s) are far from the "
                    f"camera's (frame at {frame.t_ns * 1e-9:.3f} s): clocks not synchronised"
                )
                log.warning("odometry runs visual-only: %s", self.imu_disabled_reason)
                if self._seg is not None:
                    self._seg.pim = None
                return
        self._buffer.push(chunk)

    def _integrate(self, seg: _Segment, t_ns: int) -> None:
        """Preintegrate the buffered IMU samples up to ``t_ns`` into the segment's factor."""
        if not seg.backend.inertial or seg.pim is None:
            return
        if not self.inertial:  # the IMU was switched off during this segment
            seg.imu_link_ok = False
            return
        samples, gap = self._buffer.consume(t_ns)
        for a, g, dt in samples:
            seg.pim.integrateMeasurement(a, g, dt)  # type: ignore[attr-defined]
        if gap > self.config.imu_max_gap_s:
            if seg.imu_link_ok:
                log.warning(
                    "IMU gap of %.3f s before t=%.3f s: IMU link cut until the next keyframe",
                    gap,
                    t_ns * 1e-9,
                )
            seg.imu_link_ok = False

    # ------------------------------------------------------------------ helpers
    def _estimate(
        self,
        t_ns: int,
        T_odom: F64 | None,
        status: TrackingStatus,
        seg: _Segment | None,
        *,
        keyframe: int | None = None,
        loop: bool = False,
        features: int = 0,
        info: dict[str, float] | None = None,
    ) -> OdometryEstimate:
        """Record the frame and build its estimate."""
        if seg is not None and T_odom is not None:
            T_world = seg.correction @ T_odom
            anchor = seg.last_kf
        else:
            T_world = self._continuity_world
            anchor = self._kf_order[-1] if self._kf_order else -1
        if anchor >= 0:
            rel = invert_T(self._keyframes[anchor].T_world_rect) @ T_world
        else:
            rel = T_world.copy()
        if status is not TrackingStatus.LOST or not self._continuity_set:
            self._continuity_world = T_world
            self._continuity_set = True
        self._frames_t.append(int(t_ns))
        self._frames_anchor.append(anchor)
        self._frames_rel.append(rel)
        self._frames_status.append(status)
        segment_id = (
            self._root(seg.id) if seg is not None else self._root(self._segments_started - 1)
        )
        return OdometryEstimate(
            t_ns=int(t_ns),
            T_world_left=T_world @ self.T_rect_left,
            status=status,
            segment=max(segment_id, 0),
            keyframe_id=keyframe,
            anchor_keyframe_id=anchor if anchor >= 0 else None,
            loop_closure=loop,
            relink=loop and self._last_relink,
            tracked_features=int(features),
            info=dict(info or {}),
        )

    def _root(self, s: int) -> int:
        if s < 0:
            return s
        while self._parent.get(s, s) != s:
            s = self._parent[s]
        return s

    def _new_backend(self) -> SmootherBackend:
        c = self.config
        return SmootherBackend(
            self.geometry,
            T_body_rect=self.T_body_rect if self.inertial else np.eye(4),
            imu_params=self._imu_params if self.inertial else None,
            lag_s=c.smoother_lag_s,
            pixel_sigma_px=c.pixel_sigma_px,
            huber_k=c.huber_k,
        )

    def _body(self, seg: _Segment, T_odom_rect: F64) -> F64:
        """The smoother's state pose for a camera pose (the segment decides: IMU or not)."""
        return T_odom_rect @ self.T_rect_body if seg.backend.inertial else T_odom_rect

    def _rect(self, seg: _Segment, T_odom_body: F64) -> F64:
        return T_odom_body @ self.T_body_rect if seg.backend.inertial else T_odom_body

    def _corrected_uv(self, uv: F64, points_rect: F64) -> F64:
        """Left pixels made consistent with the virtual pinhole, from exact points where known
        (refractive geometry only: a pinhole's pixels are already consistent)."""
        if not self.geometry.refractive:
            return uv
        out = uv.copy()
        ok = np.isfinite(points_rect).all(axis=1)
        if ok.any():
            m = self.geometry.project(points_rect[ok])
            out[ok, 0] = m[:, 0]
            out[ok, 1] = m[:, 2]
        return out

    def _new_features(
        self,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
        existing: F64,
        count: int,
    ) -> tuple[F64, F64, F64]:
        """Detect, match and triangulate new features: ``uv, points_rect, measurements``."""
        valid = np.isfinite(depth)
        uv = detect_corners(grey, existing, count, self.config, valid_mask=valid)
        if uv.shape[0] == 0:
            return uv, np.zeros((0, 3)), np.zeros((0, 3))
        sp = stereo_points(grey, right, depth, uv, self.geometry, self.config)
        return uv[sp.ok], sp.points_rect[sp.ok], sp.measurement[sp.ok]

    # ------------------------------------------------------------------ segments
    def _start(
        self,
        t_ns: int,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
    ) -> OdometryEstimate:
        c = self.config
        uv, P, meas = self._new_features(grey, right, depth, np.zeros((0, 2)), c.max_features)
        need = max(2 * c.min_inliers, 30)
        never = not self._keyframes
        status_fail = TrackingStatus.INITIALISING if never else TrackingStatus.LOST
        if uv.shape[0] < need:
            if self.inertial:  # keep the last half second for the gravity estimate
                self._buffer.trim(t_ns - int(0.5e9))
            return self._estimate(
                t_ns,
                None,
                status_fail,
                None,
                features=int(uv.shape[0]),
                info={"new_features": float(uv.shape[0])},
            )
        seg_id = self._segments_started
        self._segments_started += 1
        self._parent[seg_id] = seg_id
        T_world_rect0 = self._continuity_world.copy()
        prior = {"rotation_rad": 1e-3, "translation_m": 1e-3}
        seg = _Segment(id=seg_id, backend=self._new_backend(), correction=np.eye(4))
        velocity = np.zeros(3)
        bias = (np.zeros(3), np.zeros(3))
        if self.inertial:
            prior["rotation_rad"] = c.prior_rotation_sigma_rad
            prior["velocity_mps"] = c.prior_velocity_sigma_mps
            prior["accel_bias_mps2"] = c.prior_accel_bias_sigma_mps2
            prior["gyro_bias_radps"] = c.prior_gyro_bias_sigma_radps
            if never:
                f = self._buffer.mean_accel(t_ns, int(0.5e9))
                if f is not None:
                    R_wb = gravity_aligned_rotation(f)
                    T_wb = np.eye(4)
                    T_wb[:3, :3] = R_wb
                    T_world_rect0 = T_wb @ self.T_body_rect
        # the segment's odometry frame starts at the continuity pose (no jump)
        T_odom0 = T_world_rect0
        self._buffer.start(t_ns)
        k = self._next_kf
        self._next_kf += 1
        ids = np.arange(self._next_landmark, self._next_landmark + uv.shape[0], dtype=np.int64)
        self._next_landmark += uv.shape[0]
        X_world = P @ T_odom0[:3, :3].T + T_odom0[:3, 3]
        try:
            seg.backend.add_keyframe(
                k,
                t_ns * 1e-9,
                self._body(seg, T_odom0),
                [(int(j), m) for j, m in zip(ids, meas, strict=True)],
                {int(j): X for j, X in zip(ids, X_world, strict=True)},
                velocity_mps=velocity,
                bias=bias,
                prior_sigmas=prior,
            )
        except SmootherFailure as err:
            log.warning("could not start a segment at t=%.3f s: %s", t_ns * 1e-9, err)
            self._segments_started -= 1
            del self._parent[seg_id]
            self._next_kf -= 1
            return self._estimate(t_ns, None, status_fail, None)
        self._seg = seg
        seg.state = seg.backend.state(k)
        if self.inertial:
            seg.pim = seg.backend.new_preintegration(
                seg.state.accel_bias_mps2, seg.state.gyro_bias_radps
            )
            seg.imu_link_ok = True
        T_odom = self._rect(seg, seg.state.T_world_body)
        kf = _Keyframe(
            id=k, t_ns=int(t_ns), segment=seg_id, T_odom=T_odom, correction=seg.correction.copy()
        )
        self._keyframes[k] = kf
        self._kf_order.append(k)
        seg.keyframes.append(k)
        seg.last_kf = k
        seg.kf_t_ns = int(t_ns)
        seg.frames_since_kf = 0
        seg.track_ids, seg.track_uv = ids, uv
        seg.track_X = np.array([seg.backend.landmark(int(j)) for j in ids]).reshape(-1, 3)
        self._mark_keyframe_tracks(seg, grey)
        seg.prev_grey = grey
        seg.last_T_odom = T_odom
        seg.prev_T_odom = None
        seg.last_t_ns = seg.prev_t_ns = seg.last_vision_t_ns = int(t_ns)
        loop, relocalised = self._loop_closure(k, grey, depth)
        status = TrackingStatus.RELOCALISED if relocalised else TrackingStatus.TRACKING
        if seg_id > 0 and not relocalised:
            log.info("segment %d starts at t=%.3f s", seg_id, t_ns * 1e-9)
        return self._estimate(
            t_ns,
            self._seg.last_T_odom if self._seg else T_odom,
            status,
            self._seg,
            keyframe=k,
            loop=loop,
            features=int(ids.size),
        )

    def _end_segment(self, reason: str, t_ns: int) -> None:
        seg = self._seg
        if seg is None:
            return
        log.warning(
            "tracking lost at t=%.3f s (%s); a new segment starts when features return",
            t_ns * 1e-9,
            reason,
        )
        self._seg = None

    def _solve(
        self,
        seg: _Segment,
        t_ns: int,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
        ids: NDArray[np.int64],
        X: F64,
        uv: F64,
        pred: F64 | None,
    ) -> tuple[StereoPoints | None, F64 | None, NDArray[np.int64]]:
        """The frame's pose by PnP against the tracked pixels' landmarks ``X``: ``(stereo
        points of the pixels or None, T_odomworld_rect or None, inlier indices)``; the pose is
        None when PnP fails or disagrees with the IMU's prediction. A refractive rig matches
        the stereo points here, for its pinhole correction; a pinhole rig needs none before
        PnP, and a keyframe matches its inliers alone (:meth:`_track`)."""
        c = self.config
        sp: StereoPoints | None = None
        if not self.geometry.refractive:
            uv_c = uv
        else:
            sp = stereo_points(grey, right, depth, uv, self.geometry, c)
            # pixels consistent with the virtual pinhole: from the stereo point, else from the
            # landmark's predicted depth (the landmark's depth alone tried instead of the
            # stereo point: 0.81 deg RMS orientation error on the lake dive against 0.29)
            P_for_corr = sp.points_rect.copy()
            if pred is not None:
                miss = ~sp.ok
                if miss.any():
                    T = invert_T(pred)
                    z = (X[miss] @ T[:3, :3].T + T[:3, 3])[:, 2]
                    Pm, okm = self.geometry.points_from_depth(uv[miss], z)
                    Pm[~okm] = np.nan
                    P_for_corr[miss] = Pm
            uv_c = self._corrected_uv(uv, P_for_corr)
        T_rw_guess = invert_T(pred) if pred is not None else None
        T_rect_world, inl = solve_pnp(X, uv_c, self.geometry.K, T_rw_guess, c)
        if T_rect_world is None:
            return sp, None, inl
        T_odom = invert_T(T_rect_world)
        if (
            pred is not None
            and seg.backend.inertial
            and seg.imu_link_ok
            and inl.size < 3 * c.min_inliers  # a well-supported PnP pose is trusted as it is
        ):
            dtr = float(np.linalg.norm(T_odom[:3, 3] - pred[:3, 3]))
            drot = _rotation_angle(T_odom[:3, :3].T @ pred[:3, :3])
            gap_s = (t_ns - seg.kf_t_ns) * 1e-9
            if dtr > 0.15 + 0.5 * gap_s or drot > np.deg2rad(3.0 + 5.0 * gap_s):
                log.debug(
                    "vision disagrees with the IMU at t=%.3f s (%.3f m, %.2f deg)",
                    t_ns * 1e-9,
                    dtr,
                    np.degrees(drot),
                )
                return sp, None, inl
        return sp, T_odom, inl

    def _rescue(
        self,
        seg: _Segment,
        t_ns: int,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
        pred: F64 | None,
    ) -> tuple[NDArray[np.int64], F64, F64, StereoPoints | None, F64, NDArray[np.int64]] | None:
        """Search every landmark the last keyframe saw (still in the smoother) from the
        keyframe's image into this one, seeded by their projection at the predicted pose,
        with a window and a pyramid twice as deep as tracking's; then PnP RANSAC.

        Returns:
            ``(ids, X, uv, stereo points, T_odomworld_rect, inliers)`` or None.
        """
        c = self.config
        be = seg.backend
        if seg.kf_grey is None or seg.kf_ids.size == 0:
            return None
        live = np.array([be.has_landmark(int(j)) for j in seg.kf_ids], dtype=bool)
        if np.count_nonzero(live) < c.min_inliers:
            return None
        ids = seg.kf_ids[live]
        kf_uv = seg.kf_uv[live]
        X = np.array([be.landmark(int(j)) for j in ids]).reshape(-1, 3)
        wide = dataclasses.replace(
            c, klt_window_px=2 * c.klt_window_px - 1, klt_levels=c.klt_levels + 2
        )
        # seeded by the prediction, then (a prediction can be what failed) by the keyframe's
        # own pixels, which the deeper pyramid carries over the motion
        seeds: list[F64 | None] = [None]
        if pred is not None:
            projected = self._project(X, pred)
            bad = ~np.isfinite(projected).all(axis=1)
            projected[bad] = kf_uv[bad]
            seeds.insert(0, projected)
        for guess in seeds:
            uv, ok = track_klt(seg.kf_grey, grey, kf_uv, guess, wide)
            if np.count_nonzero(ok) < c.min_inliers:
                continue
            ids_ok = ids[ok]
            X_ok = np.asarray(X[ok], dtype=np.float64).reshape(-1, 3)
            sp, T_odom, inl = self._solve(seg, t_ns, grey, right, depth, ids_ok, X_ok, uv[ok],
                                          pred if guess is not None else None)
            if T_odom is not None:
                log.debug("tracking re-found %d landmarks of the keyframe at t=%.3f s",
                          inl.size, t_ns * 1e-9)
                return ids_ok, X_ok, uv[ok], sp, T_odom, inl
        return None

    # ------------------------------------------------------------------ keyframes
    def _mark_keyframe_tracks(self, seg: _Segment, grey: NDArray[np.uint8] | None) -> None:
        """Remember the new keyframe's image, features and their pixels (for overlap,
        parallax and the search before a frame is given up)."""
        seg.kf_tracks = int(seg.track_ids.size)
        seg.kf_grey = grey
        order = np.argsort(seg.track_ids, kind="stable")
        seg.kf_ids = seg.track_ids[order].copy()
        seg.kf_uv = np.asarray(seg.track_uv, dtype=np.float64).reshape(-1, 2)[order].copy()

    def _parallax_threshold_px(self, seg: _Segment, T_odom: F64) -> float:
        """Parallax that makes a keyframe, pixels: the motion since the keyframe has become a
        longer baseline than the rig's own (the motion parallax passes the median stereo
        disparity of the tracked points: ``t / z > B / z``), and at least
        ``keyframe_parallax_rad`` times the focal length."""
        g = self.geometry
        floor = self.config.keyframe_parallax_rad * g.fx
        if seg.track_X.shape[0] == 0:
            return floor
        T = invert_T(T_odom)
        z = (seg.track_X @ T[:3, :3].T + T[:3, 3])[:, 2]
        z = z[np.isfinite(z) & (z > 0)]
        if z.size == 0:
            return floor
        return max(floor, float(np.median(g.fx * g.baseline_m / z)))

    def _imu_interval_s(self, parallax_px: float) -> float:
        """Longest time to the next keyframe with an IMU: ``keyframe_max_interval_s`` while
        the camera moves, up to half the smoother's window while it is still."""
        c = self.config
        still = parallax_px < 0.25 * c.keyframe_parallax_rad * self.geometry.fx
        return max(c.keyframe_max_interval_s, 0.5 * c.smoother_lag_s) if still else (
            c.keyframe_max_interval_s)

    def _parallax_px(self, seg: _Segment, T_odom: F64) -> float:
        """Median rotation-compensated motion, pixels, of the features tracked since the last
        keyframe: each keyframe pixel is turned by the camera's rotation since the keyframe
        (the infinite homography ``K R K^-1``), so only the motion that triangulates is left.
        0 when none is shared."""
        if seg.kf_ids.size == 0 or seg.track_ids.size == 0 or seg.last_kf not in self._keyframes:
            return 0.0
        pos = np.searchsorted(seg.kf_ids, seg.track_ids)
        pos = np.minimum(pos, seg.kf_ids.size - 1)
        shared = seg.kf_ids[pos] == seg.track_ids
        if not shared.any():
            return 0.0
        g = self.geometry
        R_kf = self._keyframes[seg.last_kf].T_odom[:3, :3]
        R = T_odom[:3, :3].T @ R_kf  # keyframe camera -> current camera
        uv0 = seg.kf_uv[pos[shared]]
        rays = np.stack([(uv0[:, 0] - g.cx) / g.fx, (uv0[:, 1] - g.cy) / g.fy,
                         np.ones(uv0.shape[0])], axis=1) @ R.T
        with np.errstate(invalid="ignore", divide="ignore"):
            turned = np.stack([g.fx * rays[:, 0] / rays[:, 2] + g.cx,
                               g.fy * rays[:, 1] / rays[:, 2] + g.cy], axis=1)
        d = np.linalg.norm(seg.track_uv[shared] - turned, axis=1)
        d = d[np.isfinite(d)]
        return float(np.median(d)) if d.size else 0.0

    # ------------------------------------------------------------------ tracking
    def _predict(self, seg: _Segment, t_ns: int) -> F64 | None:
        """Predicted ``T_odomworld_rect`` at ``t_ns`` (IMU, else constant velocity)."""
        if (
            seg.backend.inertial
            and seg.pim is not None
            and seg.imu_link_ok
            and seg.state is not None
        ):
            import gtsam

            nav = gtsam.NavState(gtsam.Pose3(seg.state.T_world_body), seg.state.velocity_mps)
            bias = gtsam.imuBias.ConstantBias(seg.state.accel_bias_mps2, seg.state.gyro_bias_radps)
            pred = seg.pim.predict(nav, bias)  # type: ignore[attr-defined]
            return self._rect(seg, np.asarray(pred.pose().matrix(), dtype=np.float64))
        if seg.last_T_odom is None:
            return None
        if seg.prev_T_odom is None or seg.last_t_ns == seg.prev_t_ns:
            return seg.last_T_odom
        delta = invert_T(seg.prev_T_odom) @ seg.last_T_odom
        ratio = (t_ns - seg.last_t_ns) / max(seg.last_t_ns - seg.prev_t_ns, 1)
        if abs(ratio - 1.0) > 1e-6:
            from scipy.spatial.transform import Rotation

            rv = Rotation.from_matrix(delta[:3, :3]).as_rotvec() * ratio
            d = np.eye(4)
            d[:3, :3] = Rotation.from_rotvec(rv).as_matrix()
            d[:3, 3] = delta[:3, 3] * ratio
            delta = d
        return seg.last_T_odom @ delta

    def _redetected_pose(
        self, seg: _Segment, grey: NDArray[np.uint8], depth: NDArray[np.float32]
    ) -> F64 | None:
        """``T_odomworld_rect`` of this frame from its ORB features matched to the last
        keyframe's (every one of its features with a depth: :func:`verify_loop`), or None."""
        kf = self._keyframes.get(seg.last_kf)
        if kf is None or kf.place is None or kf.place.descriptors.shape[0] == 0:
            return None
        found = verify_loop(self._place(grey, depth), kf.place, kf.id, self.geometry.K,
                            min_inliers=self.config.min_inliers)
        if found is None:
            return None
        return kf.T_odom @ found.T_cand_query

    def _track_warped(
        self,
        seg: _Segment,
        grey: NDArray[np.uint8],
        pred: F64,
        guess: F64,
        uv: F64,
        ok: NDArray[np.bool_],
    ) -> None:
        """Search the features KLT lost once more, each patch warped by the local affine map
        that the predicted motion and its landmark's depth give (a step towards a near point
        magnifies it, a roll turns it); ``uv`` and ``ok`` are updated in place."""
        assert seg.prev_grey is not None and seg.last_T_odom is not None
        miss = np.flatnonzero(~ok)
        T_prev = invert_T(seg.last_T_odom)
        z_prev = (seg.track_X[miss] @ T_prev[:3, :3].T + T_prev[:3, 3])[:, 2]
        A = predicted_affine(seg.track_uv[miss], z_prev, invert_T(pred) @ seg.last_T_odom,
                             self.geometry.K)
        uv_w, ok_w = track_warped(seg.prev_grey, grey, seg.track_uv[miss], A, guess[miss],
                                  self.config)
        uv[miss[ok_w]] = uv_w[ok_w]
        ok[miss[ok_w]] = True

    def _project(self, X_world: F64, T_odom_rect: F64) -> F64:
        T = invert_T(T_odom_rect)
        P = X_world @ T[:3, :3].T + T[:3, 3]
        g = self.geometry
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.stack([g.fx * P[:, 0] / P[:, 2] + g.cx, g.fy * P[:, 1] / P[:, 2] + g.cy], 1)

    def _track(
        self,
        t_ns: int,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
    ) -> OdometryEstimate:
        seg = self._seg
        assert seg is not None
        c = self.config
        self._integrate(seg, t_ns)
        pred = self._predict(seg, t_ns)
        info: dict[str, float] = {}
        # --- track
        guess = None
        if pred is not None and seg.track_X.shape[0]:
            guess = self._project(seg.track_X, pred)
            bad = ~np.isfinite(guess).all(axis=1)
            guess[bad] = seg.track_uv[bad]
        assert seg.prev_grey is not None
        uv, ok = track_klt(seg.prev_grey, grey, seg.track_uv, guess, c)
        info["tracked"] = float(ok.sum())
        if pred is not None and guess is not None and c.warped_tracking and not ok.all():
            self._track_warped(seg, grey, pred, guess, uv, ok)
            info["warped"] = float(ok.sum()) - info["tracked"]
        ids, X = seg.track_ids[ok], seg.track_X[ok]
        uv = uv[ok]
        sp, T_odom, inl = self._solve(seg, t_ns, grey, right, depth, ids, X, uv, pred)
        rescued = False
        if T_odom is None and c.rescue_search:
            # before the frame is given up: every landmark of the last keyframe, searched
            # from the keyframe's image with a wider pyramid seeded by the prediction
            found = self._rescue(seg, t_ns, grey, right, depth, pred)
            if found is not None:
                ids, X, uv, sp, T_odom, inl = found
                rescued = True
                info["rescued"] = float(inl.size)
        if T_odom is None and c.loop_closure:
            # last: a prior from ORB re-detected against the keyframe's features (all its
            # stereo points), then the tracks searched again from that prior
            prior = self._redetected_pose(seg, grey, depth)
            if prior is not None:
                guess = self._project(seg.track_X, prior)
                bad = ~np.isfinite(guess).all(axis=1)
                guess[bad] = seg.track_uv[bad]
                uv, ok = track_klt(seg.prev_grey, grey, seg.track_uv, guess, c)
                if c.warped_tracking and not ok.all():
                    self._track_warped(seg, grey, prior, guess, uv, ok)
                ids, X, uv = seg.track_ids[ok], seg.track_X[ok], uv[ok]
                sp, T_odom, inl = self._solve(seg, t_ns, grey, right, depth, ids, X, uv, prior)
                if T_odom is not None:
                    info["redetected"] = float(inl.size)
        if T_odom is None:
            return self._vision_failed(seg, t_ns, grey, right, depth, pred, info)
        info["inliers"] = float(inl.size)
        seg.track_ids, seg.track_uv, seg.track_X = ids[inl], uv[inl], X[inl]
        seg.prev_grey = grey
        seg.prev_T_odom, seg.prev_t_ns = seg.last_T_odom, seg.last_t_ns
        seg.last_T_odom, seg.last_t_ns = T_odom, int(t_ns)
        seg.last_vision_t_ns = int(t_ns)
        n = int(inl.size)
        seg.frames_since_kf += 1
        parallax_px = self._parallax_px(seg, T_odom)
        info["parallax_px"] = parallax_px
        make_kf = (
            rescued  # the tracks were re-found from the keyframe: refresh them
            # track overlap: the keyframe's features are thinning out
            or n < c.keyframe_track_ratio * seg.kf_tracks
            # too few features, where the keyframe had enough (an image that offers fewer
            # features than this is no reason for a keyframe every frame)
            or (n < c.keyframe_min_features <= seg.kf_tracks)
            # parallax: the view has changed enough to triangulate anew
            or parallax_px >= self._parallax_threshold_px(seg, T_odom)
            or seg.frames_since_kf >= c.keyframe_max_frames
            or (
                seg.backend.inertial
                and (
                    (t_ns - seg.kf_t_ns) * 1e-9 >= self._imu_interval_s(parallax_px) - 1e-6
                    or not seg.imu_link_ok
                )
            )
        )
        if not make_kf:
            return self._estimate(t_ns, T_odom, TrackingStatus.TRACKING, seg, features=n, info=info)
        if sp is not None:
            sp_ok, sp_P, sp_meas = sp.ok[inl], sp.points_rect[inl], sp.measurement[inl]
        else:  # matched into the right image only now, and only the inliers
            sp_in = stereo_points(grey, right, depth, seg.track_uv, self.geometry, c)
            sp_ok, sp_P, sp_meas = sp_in.ok, sp_in.points_rect, sp_in.measurement
        return self._keyframe(
            seg,
            t_ns,
            grey,
            right,
            depth,
            T_odom,
            sp_ok,
            sp_P,
            sp_meas,
            info,
            TrackingStatus.TRACKING,
        )

    def _keyframe(
        self,
        seg: _Segment,
        t_ns: int,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
        T_odom: F64,
        sp_ok: NDArray[np.bool_],
        sp_P: F64,
        sp_meas: F64,
        info: dict[str, float],
        status: TrackingStatus,
    ) -> OdometryEstimate:
        c = self.config
        be = seg.backend
        obs: list[tuple[int, F64]] = []
        new_lm: dict[int, F64] = {}
        keep = np.ones(seg.track_ids.size, dtype=bool)
        R, t = T_odom[:3, :3], T_odom[:3, 3]
        for i, j in enumerate(seg.track_ids.tolist()):
            if not sp_ok[i]:
                if not be.has_landmark(j):
                    keep[i] = False
                continue
            if be.has_landmark(j) and not be.expiring(j, t_ns * 1e-9):
                obs.append((j, sp_meas[i]))
            else:  # marginalised while tracked: a fresh landmark takes its place
                nj = self._next_landmark
                self._next_landmark += 1
                seg.track_ids[i] = nj
                Xw = R @ sp_P[i] + t
                seg.track_X[i] = Xw
                new_lm[nj] = Xw
                obs.append((nj, sp_meas[i]))
        seg.track_ids, seg.track_uv, seg.track_X = (
            seg.track_ids[keep],
            seg.track_uv[keep],
            seg.track_X[keep],
        )
        n_old = len(obs)
        room = c.max_features - seg.track_ids.size
        uvn, Pn, mn = self._new_features(grey, right, depth, seg.track_uv, room)
        idn = np.arange(self._next_landmark, self._next_landmark + uvn.shape[0], dtype=np.int64)
        self._next_landmark += uvn.shape[0]
        Xn = Pn @ R.T + t
        for j, X, m in zip(idn.tolist(), Xn, mn, strict=True):
            new_lm[j] = X
            obs.append((j, m))
        info["new_features"] = float(uvn.shape[0])
        if n_old < max(6, c.min_inliers // 2) and not (be.inertial and seg.imu_link_ok):
            # too little to tie this keyframe to the window: the segment cannot go on
            self._end_segment("too few features shared with the window", t_ns)
            return self._estimate(t_ns, T_odom, TrackingStatus.LOST, seg, info=info)
        k = self._next_kf
        self._next_kf += 1
        kw: dict[str, object] = {}
        if be.inertial and seg.state is not None:
            v_guess = seg.state.velocity_mps
            if seg.pim is not None and seg.imu_link_ok:
                import gtsam

                nav = gtsam.NavState(gtsam.Pose3(seg.state.T_world_body), seg.state.velocity_mps)
                bias = gtsam.imuBias.ConstantBias(
                    seg.state.accel_bias_mps2, seg.state.gyro_bias_radps
                )
                v_guess = np.asarray(seg.pim.predict(nav, bias).velocity())  # type: ignore[attr-defined]
                kw["preintegrated"] = seg.pim
            else:
                dt = max((t_ns - seg.kf_t_ns) * 1e-9, 1e-3)
                assert self.imu is not None
                kw["imu_gap_bias_sigma"] = (
                    3 * self.imu.accel_random_walk_mps2_sqrts * np.sqrt(dt) + 1e-4,
                    3 * self.imu.gyro_random_walk_radps_sqrts * np.sqrt(dt) + 1e-5,
                )
            kw["velocity_mps"] = v_guess
            kw["bias"] = (seg.state.accel_bias_mps2, seg.state.gyro_bias_radps)
        try:
            be.add_keyframe(k, t_ns * 1e-9, self._body(seg, T_odom), obs, new_lm, **kw)  # type: ignore[arg-type]
        except SmootherFailure as err:
            self._next_kf -= 1
            self._end_segment(f"smoother failed: {err}", t_ns)
            return self._estimate(t_ns, T_odom, TrackingStatus.LOST, seg, info=info)
        seg.state = be.state(k)
        if be.inertial:
            seg.pim = be.new_preintegration(seg.state.accel_bias_mps2, seg.state.gyro_bias_radps)
            seg.imu_link_ok = True
        # refresh poses of the window and the landmark positions
        for q, Tb in be.window_poses().items():
            if q in self._keyframes:
                self._keyframes[q].T_odom = self._rect(seg, Tb)
        T_new = self._rect(seg, seg.state.T_world_body)
        kf = _Keyframe(
            id=k, t_ns=int(t_ns), segment=seg.id, T_odom=T_new, correction=seg.correction.copy()
        )
        self._keyframes[k] = kf
        self._kf_order.append(k)
        seg.keyframes.append(k)
        seg.last_kf = k
        seg.kf_t_ns = int(t_ns)
        seg.frames_since_kf = 0
        ids = np.concatenate([seg.track_ids, idn])
        uv_all = np.concatenate([seg.track_uv, uvn.reshape(-1, 2)])
        live = np.array([be.has_landmark(int(j)) for j in ids], dtype=bool)
        seg.track_ids, seg.track_uv = ids[live], uv_all[live]
        seg.track_X = np.array([be.landmark(int(j)) for j in seg.track_ids]).reshape(-1, 3)
        self._mark_keyframe_tracks(seg, grey)
        seg.last_T_odom = T_new
        seg.prev_grey = grey
        seg.loops_since += 1
        loop, relocalised = self._loop_closure(k, grey, depth)
        if relocalised:
            status = TrackingStatus.RELOCALISED
        return self._estimate(
            t_ns,
            seg.last_T_odom,
            status,
            seg,
            keyframe=k,
            loop=loop,
            features=int(seg.track_ids.size),
            info=info,
        )

    def _vision_failed(
        self,
        seg: _Segment,
        t_ns: int,
        grey: NDArray[np.uint8],
        right: NDArray[np.uint8] | None,
        depth: NDArray[np.float32],
        pred: F64 | None,
        info: dict[str, float],
    ) -> OdometryEstimate:
        c = self.config
        bridging = (
            seg.backend.inertial
            and seg.pim is not None
            and seg.imu_link_ok
            and pred is not None
            and (t_ns - seg.last_vision_t_ns) * 1e-9 <= c.imu_bridge_s
        )
        if not bridging:
            reason = "vision failed" + ("" if self.inertial else " and there is no IMU")
            if self.inertial and not seg.imu_link_ok:
                reason = "vision failed during an IMU gap"
            elif self.inertial and pred is not None:
                reason = f"vision failed for over {c.imu_bridge_s:.1f} s"
            if pred is not None:
                self._continuity_world = seg.correction @ pred
            self._end_segment(reason, t_ns)
            return self._estimate(t_ns, None, TrackingStatus.LOST, None, info=info)
        assert pred is not None
        # IMU-only: keep the predicted pose, try to re-acquire features right away
        seg.track_ids = np.zeros(0, np.int64)
        seg.track_uv = np.zeros((0, 2))
        seg.track_X = np.zeros((0, 3))
        seg.prev_grey = grey
        seg.prev_T_odom, seg.prev_t_ns = seg.last_T_odom, seg.last_t_ns
        seg.last_T_odom, seg.last_t_ns = pred, int(t_ns)
        uv, P, meas = self._new_features(grey, right, depth, np.zeros((0, 2)), c.max_features)
        if uv.shape[0] >= max(2 * c.min_inliers, 30):
            # a keyframe tied to the last one by the IMU factor alone, with fresh landmarks
            est = self._keyframe_fresh(seg, t_ns, grey, depth, pred, uv, P, meas, info)
            if est is not None:
                return est
        return self._estimate(t_ns, pred, TrackingStatus.IMU_ONLY, seg, info=info)

    def _keyframe_fresh(
        self,
        seg: _Segment,
        t_ns: int,
        grey: NDArray[np.uint8],
        depth: NDArray[np.float32],
        T_odom: F64,
        uv: F64,
        P: F64,
        meas: F64,
        info: dict[str, float],
    ) -> OdometryEstimate | None:
        be = seg.backend
        assert seg.state is not None and seg.pim is not None
        import gtsam

        R, t = T_odom[:3, :3], T_odom[:3, 3]
        ids = np.arange(self._next_landmark, self._next_landmark + uv.shape[0], dtype=np.int64)
        self._next_landmark += uv.shape[0]
        Xw = P @ R.T + t
        nav = gtsam.NavState(gtsam.Pose3(seg.state.T_world_body), seg.state.velocity_mps)
        bias = gtsam.imuBias.ConstantBias(seg.state.accel_bias_mps2, seg.state.gyro_bias_radps)
        v_guess = np.asarray(seg.pim.predict(nav, bias).velocity())  # type: ignore[attr-defined]
        k = self._next_kf
        self._next_kf += 1
        try:
            be.add_keyframe(
                k,
                t_ns * 1e-9,
                self._body(seg, T_odom),
                [(int(j), m) for j, m in zip(ids, meas, strict=True)],
                {int(j): X for j, X in zip(ids, Xw, strict=True)},
                velocity_mps=v_guess,
                bias=(seg.state.accel_bias_mps2, seg.state.gyro_bias_radps),
                preintegrated=seg.pim,
            )
        except SmootherFailure as err:
            # the smoother is unusable after a failed update: end the segment (a new one starts
            # from the IMU prediction, to be joined by a later loop closure)
            self._next_kf -= 1
            self._continuity_world = seg.correction @ T_odom
            self._end_segment(f"smoother failed on re-acquisition: {err}", t_ns)
            return self._estimate(t_ns, None, TrackingStatus.LOST, None, info=info)
        seg.state = be.state(k)
        seg.pim = be.new_preintegration(seg.state.accel_bias_mps2, seg.state.gyro_bias_radps)
        for q, Tb in be.window_poses().items():
            if q in self._keyframes:
                self._keyframes[q].T_odom = self._rect(seg, Tb)
        T_new = self._rect(seg, seg.state.T_world_body)
        self._keyframes[k] = _Keyframe(
            id=k, t_ns=int(t_ns), segment=seg.id, T_odom=T_new, correction=seg.correction.copy()
        )
        self._kf_order.append(k)
        seg.keyframes.append(k)
        seg.last_kf = k
        seg.kf_t_ns = int(t_ns)
        seg.frames_since_kf = 0
        live = np.array([be.has_landmark(int(j)) for j in ids], dtype=bool)
        seg.track_ids, seg.track_uv = ids[live], uv[live]
        seg.track_X = np.array([be.landmark(int(j)) for j in seg.track_ids]).reshape(-1, 3)
        self._mark_keyframe_tracks(seg, grey)
        seg.last_T_odom = T_new
        seg.last_vision_t_ns = int(t_ns)
        info["reacquired"] = float(ids.size)
        log.info("features re-acquired at t=%.3f s after an IMU-only bridge", t_ns * 1e-9)
        loop, _ = self._loop_closure(k, grey, depth)
        return self._estimate(
            t_ns,
            T_new,
            TrackingStatus.IMU_ONLY,
            seg,
            keyframe=k,
            loop=loop,
            features=int(ids.size),
            info=info,
        )

    # ------------------------------------------------------------------ loop closure
    def _place(self, grey: NDArray[np.uint8], depth: NDArray[np.float32]) -> PlaceFeatures:
        kps, desc = self._orb.detectAndCompute(self._clahe.apply(grey), None)
        if desc is None or not kps:
            return PlaceFeatures(
                uv=np.zeros((0, 2), np.float32),
                descriptors=np.zeros((0, 32), np.uint8),
                points_rect=np.zeros((0, 3), np.float32),
            )
        uv = np.array([k.pt for k in kps], dtype=np.float64)
        z = sample_depth(depth, uv)
        P, okp = self.geometry.points_from_depth(uv, z)
        P[~okp] = np.nan
        uvc = self._corrected_uv(uv, P)
        return PlaceFeatures(
            uv=uvc.astype(np.float32),
            descriptors=np.asarray(desc, np.uint8),
            points_rect=P.astype(np.float32),
        )

    def _loop_closure(
        self, k: int, grey: NDArray[np.uint8], depth: NDArray[np.float32]
    ) -> tuple[bool, bool]:
        """Search and close a loop at keyframe ``k``: ``(closed, joined another segment)``."""
        c = self.config
        if not c.loop_closure:
            return False, False
        kf = self._keyframes[k]
        kf.place = self._place(grey, depth)
        seg = self._seg
        if seg is None:
            return False, False
        if self._vocab is None:
            with_place = [q for q in self._kf_order if self._keyframes[q].place is not None]
            if len(with_place) >= c.vocabulary_train_keyframes:
                self._train_vocabulary(with_place)
        elif kf.place.descriptors.shape[0]:
            kf.bow = self._vocab.bow(kf.place.descriptors)
        candidates: list[int] = []
        root = self._root(seg.id)
        if self._vocab is not None and kf.bow is not None and self._db is not None:
            if seg.loops_since >= c.loop_cooldown_keyframes or (
                self._root(seg.id) == seg.id and seg.id > 0
            ):
                scores = self._db.query(kf.bow, self._next_kf)
                order = np.argsort(-scores)
                for q in order[: 20 * c.loop_candidates].tolist():
                    if scores[q] < c.loop_min_score or q == k or q not in self._keyframes:
                        break
                    other = self._keyframes[q]
                    same = self._root(other.segment) == root
                    if same and abs(other.t_ns - kf.t_ns) * 1e-9 < c.loop_min_gap_s:
                        continue
                    candidates.append(q)
                    if len(candidates) >= c.loop_candidates:
                        break
        # a segment not yet joined also tries the last keyframes of the other segments
        if seg.id > 0 and self._root(seg.id) == seg.id:
            others = [
                q
                for q in reversed(self._kf_order)
                if self._root(self._keyframes[q].segment) != root
            ][:5]
            candidates = others + [q for q in candidates if q not in others]
        if self._db is not None and kf.bow is not None:
            self._db.add(k, kf.bow)
        found: LoopCandidate | None = None
        matcher = QueryMatcher(kf.place)
        covered: set[int] = set()  # keyframes whose places a failed verification has used
        for q in candidates:
            other = self._keyframes[q]
            if other.place is None or q in covered:
                # a neighbour of an earlier candidate: its place was in that one's local map
                continue
            neighbours = self._neighbours(q)
            covered.add(q)
            covered.update(neighbours)
            self.loop_checks.candidates += 1
            keys, local = self._local_map(q, neighbours)
            found = verify_loop(
                kf.place, other.place, q, self.geometry.K, min_inliers=c.loop_min_inliers,
                local_map=local, min_spread=c.loop_min_spread, matcher=matcher,
                place_keys=[q, *keys],
            )
            if found is None:
                log.debug("loop candidate: keyframe %d with %d rejected: its geometry does not "
                          "hold", k, q)
                continue
            self.loop_checks.verified += 1
            if self._agrees_with_graph(found, k) and self._confirmed(found, k, local):
                break
            found = None
        if found is None:
            return False, False
        joined = self._root(self._keyframes[found.candidate].segment) != root
        # a keyframe of another segment that is near in time is a neighbour across a lost
        # stretch, not a place seen again: a re-link, counted apart from the loop closures
        cand = self._keyframes[found.candidate]
        relink = (
            joined
            and abs(cand.t_ns - kf.t_ns) * 1e-9 < c.loop_min_gap_s
            and found.candidate
            in [q for q in self._kf_order if self._keyframes[q].segment == cand.segment][-5:]
        )
        if not self._close_loop(found, k, relink=relink):
            return False, False
        seg.loops_since = 0
        return True, joined

    def _graph_inputs(self) -> tuple[dict[int, F64], dict[int, int], dict[int, F64]]:
        """The pose graph's odometry, segments and current poses, per keyframe."""
        odometry = {q: kf.T_odom for q, kf in self._keyframes.items()}
        segments = {q: kf.segment for q, kf in self._keyframes.items()}
        poses = {q: kf.T_world_rect for q, kf in self._keyframes.items()}
        return odometry, segments, poses

    def _agrees_with_graph(self, loop: LoopCandidate, k: int) -> bool:
        """The consistency test before a verified loop moves anything: its relative pose
        against the graph's prediction (:meth:`PoseGraph.loop_chi2`)."""
        chi2 = self._graph.loop_chi2(loop.candidate, k, loop.T_cand_query, loop.covariance,
                                     *self._graph_inputs())
        if chi2 is None:
            log.debug("loop: keyframe %d with %d: the graph cannot predict their relative pose "
                      "(a segment not joined yet); judged after the solve", k, loop.candidate)
            return True
        if chi2 <= self.config.loop_max_chi2:
            log.debug("loop: keyframe %d with %d agrees with the odometry (chi-square %.1f)",
                      k, loop.candidate, chi2)
            return True
        self._record_loop(loop, k, "rejected_odometry")
        log.info(
            "loop rejected: keyframe %d with %d (%d inliers) disagrees with the odometry "
            "(chi-square %.1f > %.1f)", k, loop.candidate, loop.inliers, chi2,
            self.config.loop_max_chi2,
        )
        return False

    def _confirmed(self, loop: LoopCandidate, k: int, local: list[PlaceFeatures]) -> bool:
        """A loop within one joined map is confirmed when one of the query's previous
        keyframes (``loop_confirm_keyframes``, its segment) verifies the same candidate against
        the same local map with a relative pose that agrees with the loop's: ``T_cand_query @
        T_query_prev`` (the odometry between the two query keyframes) against the second loop,
        under both loops' covariances (:meth:`PoseGraph.loop_covariance`), chi-square at most
        ``loop_max_chi2``. Loops that join segments (the graph cannot predict them) are judged
        after the solve instead, as before."""
        c = self.config
        q = loop.candidate
        cand = self._keyframes[q]
        if c.loop_confirm_keyframes <= 0 or self._root(cand.segment) != self._root(
                self._keyframes[k].segment) or cand.place is None:
            return True
        seg = self._keyframes[k].segment
        earlier = [o for o in self._kf_order if o != k and self._keyframes[o].segment == seg]
        T_query_world = invert_T(self._keyframes[k].T_world_rect)
        views = [(self._keyframes[o].place, T_query_world @ self._keyframes[o].T_world_rect)
                 for o in reversed(earlier[-c.loop_confirm_keyframes:])]
        ok, best = confirm_loop(loop, views, cand.place, local, self.geometry.K, self._graph,
                                min_inliers=c.loop_min_inliers, min_spread=c.loop_min_spread,
                                max_chi2=c.loop_max_chi2)
        if ok:
            log.debug("loop: keyframe %d with %d confirmed (chi-square %.1f)", k, q, best)
            return True
        self._record_loop(loop, k, "rejected_unconfirmed")
        log.info(
            "loop rejected: keyframe %d with %d (%d inliers) is not confirmed by the %s before "
            "it (%s)", k, q, loop.inliers, plural(c.loop_confirm_keyframes, "keyframe"),
            "none verified the candidate" if best == float("inf")
            else f"best chi-square {best:.1f} > {c.loop_max_chi2:.1f}",
        )
        return False

    def _neighbours(self, q: int) -> list[int]:
        """Keyframe ``q``'s neighbours in its segment, ``loop_local_keyframes`` on each side."""
        n = self.config.loop_local_keyframes
        if n <= 0:
            return []
        seg = self._keyframes[q].segment
        same = [o for o in self._kf_order if self._keyframes[o].segment == seg]
        i = same.index(q)
        return same[max(0, i - n): i] + same[i + 1: i + 1 + n]

    def _local_map(self, q: int, neighbours: list[int]
                   ) -> tuple[list[int], list[PlaceFeatures]]:
        """Places of keyframe ``q``'s ``neighbours`` (:meth:`_neighbours`), their points moved
        into ``q``'s frame by the poses between them, and their keyframe ids."""
        cand = self._keyframes[q]
        T_q_world = invert_T(cand.T_world_rect)
        ids, out = [], []
        for o in neighbours:
            place = self._keyframes[o].place
            if place is None or place.descriptors.shape[0] == 0:
                continue
            T = T_q_world @ self._keyframes[o].T_world_rect
            P = place.points_rect.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
            ids.append(o)
            out.append(PlaceFeatures(uv=place.uv, descriptors=place.descriptors,
                                     points_rect=P.astype(np.float32)))
        return ids, out

    def _train_vocabulary(self, kf_ids: list[int]) -> None:
        c = self.config
        descs, docs, start = [], [], 0
        for q in kf_ids:
            place = self._keyframes[q].place
            assert place is not None
            d = place.descriptors
            descs.append(d)
            docs.append(np.arange(start, start + d.shape[0]))
            start += d.shape[0]
        all_desc = np.concatenate(descs) if descs else np.zeros((0, 32), np.uint8)
        if all_desc.shape[0] < c.vocabulary_branching**2:
            return
        t0 = time.perf_counter()
        self._vocab = Vocabulary.train(
            all_desc, docs, branching=c.vocabulary_branching, depth=c.vocabulary_depth
        )
        self._db = KeyframeDatabase(self._vocab.words)
        for q in kf_ids:
            place = self._keyframes[q].place
            assert place is not None
            if place.descriptors.shape[0]:
                self._keyframes[q].bow = self._vocab.bow(place.descriptors)
                self._db.add(q, self._keyframes[q].bow)  # type: ignore[arg-type]
        log.info(
            "vocabulary of %d words trained on %d descriptors of %d keyframes in %.2f s",
            self._vocab.words,
            all_desc.shape[0],
            len(kf_ids),
            time.perf_counter() - t0,
        )

    def _record_loop(self, loop: LoopCandidate, k: int, outcome: str) -> None:
        self.loop_checks.record(self._keyframes[k].t_ns, self._keyframes[loop.candidate].t_ns,
                                loop.T_cand_query, loop.inliers, outcome)

    def _close_loop(self, loop: LoopCandidate, k: int, *, relink: bool = False) -> bool:
        """Add a loop and re-optimise; undo it when the solve fails or the optimised graph
        still disagrees with it. Returns True when the loop was kept."""
        self._graph.add_loop(loop.candidate, k, loop.T_cand_query, loop.covariance)
        odometry, segments, initial = self._graph_inputs()
        try:
            solved = self._graph.optimise(odometry, segments, initial)
        except RuntimeError as err:
            log.warning("pose graph optimisation failed (%s); loop ignored", err)
            self._graph.loops.pop()
            self._record_loop(loop, k, "rejected_solver")
            return False
        chi2 = self._graph.loop_chi2(loop.candidate, k, loop.T_cand_query, loop.covariance,
                                     odometry, segments, solved, marginal=False)
        if chi2 is not None and not chi2 <= self.config.loop_max_chi2:
            self._graph.loops.pop()
            self._record_loop(loop, k, "rejected_graph")
            log.info(
                "loop rejected: keyframe %d with %d (%d inliers): the optimised graph still "
                "disagrees with it (chi-square %.1f > %.1f); the graph is left as it was",
                k, loop.candidate, loop.inliers, chi2, self.config.loop_max_chi2,
            )
            return False
        self._record_loop(loop, k, "accepted")
        for q, T in solved.items():
            kf = self._keyframes[q]
            kf.correction = T @ invert_T(kf.T_odom)
        if self._seg is not None:
            last = self._keyframes[self._seg.last_kf]
            self._seg.correction = last.correction.copy()
        a = self._root(self._keyframes[loop.candidate].segment)
        b = self._root(self._keyframes[k].segment)
        if a != b:
            self._parent[max(a, b)] = min(a, b)
        self._last_relink = relink
        if relink:
            self.relinks += 1
        else:
            self.loop_closures += 1
        log.info("loop closed: keyframe %d with %d (%d inliers)", k, loop.candidate, loop.inliers)
        return True
