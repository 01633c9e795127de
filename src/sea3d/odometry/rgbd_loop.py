"""Loop closure for the dense RGB-D odometry's keyframes.

The stereo engine's place recognition and verification (:mod:`sea3d.odometry.loop`: a
vocabulary of ORB words trained on the sequence's own first keyframes, an inverted index,
PnP-RANSAC plus a 3D check) and its keyframe pose graph (:mod:`sea3d.odometry.posegraph`,
gtsam), fed with the RGB-D keyframes: every keyframe's ORB features with their depth. Only a
return to a place seen earlier counts as a loop, not the overlap of neighbouring views on a
path that goes on: a candidate must be at least ``min_gap_keyframes`` keyframes older than the
query, of the same segment, and the odometry path between the two (keyframe to keyframe) must
be at least ``min_path_ratio`` times the odometry distance between them (motion measured as
translation plus rotation times the query's median depth, so that turning away and back also
counts). Until ``vocabulary_train_keyframes`` keyframes have been seen (too few to train a
vocabulary) every eligible keyframe is verified, nearest first; afterwards the bag-of-words
score ranks them.

The tracker keeps running in its odometry frame; each keyframe gets a correction
``T_world_corrected @ inv(T_odom)`` that the trajectory applies to the frames anchored on it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import OdometryError
from sea3d.odometry.loop import (
    KeyframeDatabase,
    LoopCandidate,
    PlaceFeatures,
    Vocabulary,
    verify_loop,
)
from sea3d.odometry.posegraph import PoseGraph

__all__ = ["RgbdLoopCloser", "RgbdLoopConfig"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class RgbdLoopConfig:
    """Tunables of :class:`RgbdLoopCloser`."""

    orb_features: int = 1000
    """ORB features per keyframe."""
    vocabulary_train_keyframes: int = 6
    """Keyframes whose descriptors train the vocabulary (the search starts after them)."""
    min_gap_keyframes: int = 2
    """A candidate is at least this many keyframes older than the query."""
    min_path_ratio: float = 2.0
    """The odometry path from the candidate to the query is at least this many times the
    odometry distance between them (a return, not a path going on)."""
    min_score: float = 0.02
    """Smallest bag-of-words similarity of a candidate (0..1)."""
    candidates: int = 5
    """Candidates verified per keyframe, best score first."""
    min_inliers: int = 40
    """PnP-RANSAC inliers needed to accept a loop."""
    cooldown_keyframes: int = 0
    """Keyframes after an accepted loop before the next search."""
    loop_translation_sigma_m: float = 0.002
    """Standard deviation of a loop edge's translation, metres (a dense alignment of two
    depth maps, tighter than the stereo engine's PnP loops)."""
    loop_rotation_sigma_rad: float = 0.002
    """Standard deviation of a loop edge's rotation, radians."""

    def __post_init__(self) -> None:
        if not (self.orb_features >= 50 and self.vocabulary_train_keyframes >= 1
                and self.min_gap_keyframes >= 1 and self.min_path_ratio > 1
                and self.candidates >= 1
                and self.min_inliers >= 6 and self.cooldown_keyframes >= 0
                and self.loop_translation_sigma_m > 0 and self.loop_rotation_sigma_rad > 0):
            raise OdometryError("RGB-D loop config: thresholds out of range")


@dataclass
class _Kf:
    segment: int
    T_odom: F64
    place: PlaceFeatures
    depth_m: float  # median valid depth
    path_m: float  # odometry motion from the segment's first keyframe
    bow: tuple[NDArray[np.int64], NDArray[np.float32]] | None = None
    correction: F64 | None = None


def _motion(A: F64, B: F64, depth_m: float) -> float:
    """Motion between two poses: translation plus rotation times ``depth_m``, metres."""
    rel = np.linalg.inv(A) @ B
    angle = float(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return float(np.linalg.norm(rel[:3, 3])) + angle * depth_m


class RgbdLoopCloser:
    """Online loop detection and pose-graph correction of RGB-D keyframes.

    Args:
        K: (3, 3) intrinsics.
        config: :class:`RgbdLoopConfig`.
        graph: the pose graph (default: :class:`~sea3d.odometry.posegraph.PoseGraph`'s
            odometry sigmas with the loop sigmas of ``config``).
    """

    def __init__(self, K: F64, config: RgbdLoopConfig | None = None,
                 graph: PoseGraph | None = None) -> None:
        self.K = np.asarray(K, np.float64).reshape(3, 3)
        self.config = config or RgbdLoopConfig()
        self.graph = graph or PoseGraph(
            loop_rotation_sigma_rad=self.config.loop_rotation_sigma_rad,
            loop_translation_sigma_m=self.config.loop_translation_sigma_m)
        self._kfs: dict[int, _Kf] = {}
        self._vocab: Vocabulary | None = None
        self._db: KeyframeDatabase | None = None
        self._db_ids: set[int] = set()
        self._orb: Any = None
        self._since_loop = 10**9
        self.loop_closures = 0
        self.loops: list[tuple[int, int]] = []
        """Accepted loops, ``(earlier keyframe, query keyframe)``."""

    def _place(self, grey: NDArray[np.uint8], depth: NDArray[np.float32]) -> PlaceFeatures:
        import cv2

        if self._orb is None:
            self._orb = cv2.ORB_create(nfeatures=self.config.orb_features)  # type: ignore[attr-defined]
        kps, desc = self._orb.detectAndCompute(grey, None)
        if desc is None or not kps:
            return PlaceFeatures(uv=np.zeros((0, 2), np.float32),
                                 descriptors=np.zeros((0, 32), np.uint8),
                                 points_rect=np.zeros((0, 3), np.float32))
        uv = np.array([k.pt for k in kps], np.float32)
        u = np.clip(np.round(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
        v = np.clip(np.round(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
        z = depth[v, u].astype(np.float64)
        z[~(np.isfinite(z) & (z > 0))] = np.nan
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        P = np.stack([(uv[:, 0] - cx) * z / fx, (uv[:, 1] - cy) * z / fy, z], 1)
        return PlaceFeatures(uv=uv, descriptors=np.asarray(desc, np.uint8),
                             points_rect=P.astype(np.float32))

    def _train(self) -> None:
        descs, docs, start = [], [], 0
        for kf in self._kfs.values():
            d = kf.place.descriptors
            descs.append(d)
            docs.append(np.arange(start, start + d.shape[0]))
            start += d.shape[0]
        all_desc = np.concatenate(descs)
        if all_desc.shape[0] < 100:
            return
        self._vocab = Vocabulary.train(all_desc, docs)
        self._db = KeyframeDatabase(self._vocab.words)
        for k, kf in self._kfs.items():
            if kf.place.descriptors.shape[0]:
                kf.bow = self._vocab.bow(kf.place.descriptors)
                self._db.add(k, kf.bow)
                self._db_ids.add(k)

    def _candidates(self, kf_id: int) -> list[int]:
        """Keyframes that would close a true loop with ``kf_id``, most promising first."""
        c = self.config
        kf = self._kfs[kf_id]
        eligible = []
        for q, other in self._kfs.items():
            if q > kf_id - c.min_gap_keyframes or other.segment != kf.segment:
                continue
            dist = _motion(other.T_odom, kf.T_odom, kf.depth_m)
            if kf.path_m - other.path_m >= c.min_path_ratio * dist:
                eligible.append((q, dist))
        if self._vocab is None or self._db is None or kf.bow is None:
            return [q for q, _ in sorted(eligible, key=lambda e: e[1])][: c.candidates]
        scores = self._db.query(kf.bow, kf_id + 1)
        ranked = sorted((q for q, _ in eligible if scores[q] >= c.min_score),
                        key=lambda q: -scores[q])
        return ranked[: c.candidates]

    def add_keyframe(self, kf_id: int, segment: int, T_odom: F64, grey: NDArray[np.uint8],
                     depth: NDArray[np.float32],
                     refine: Callable[[int, F64], F64 | None] | None = None) -> bool:
        """Index keyframe ``kf_id`` (ids increasing; ``T_odom`` its odometry pose, ``grey``
        (H, W) uint8, ``depth`` (H, W) float32 metres, NaN or 0 invalid), search a loop for
        it and, when one is verified, re-optimise the graph. ``refine(candidate,
        T_cand_query)`` may refine a verified loop's relative pose (the dense alignment of
        the two keyframes); None from it drops the loop. Returns whether a loop closed."""
        c = self.config
        z = depth[np.isfinite(depth) & (depth > 0)]
        T_odom = np.asarray(T_odom, np.float64).copy()
        last = self._kfs[max(self._kfs)] if self._kfs else None
        same = last is not None and last.segment == segment
        z_med = float(np.median(z)) if z.size else 1.0
        path = last.path_m + _motion(last.T_odom, T_odom, z_med) if same and last else 0.0
        kf = _Kf(segment, T_odom, self._place(grey, depth), z_med, path)
        kf.correction = (last.correction.copy() if same and last and last.correction is not None
                         else np.eye(4))
        self._kfs[kf_id] = kf
        self._since_loop += 1
        if self._vocab is None and len(self._kfs) >= c.vocabulary_train_keyframes:
            self._train()
        elif self._vocab is not None and kf.place.descriptors.shape[0]:
            kf.bow = self._vocab.bow(kf.place.descriptors)
        found = None
        if self._since_loop > c.cooldown_keyframes and kf.place.descriptors.shape[0]:
            for q in self._candidates(kf_id):
                found = verify_loop(kf.place, self._kfs[q].place, q, self.K,
                                    min_inliers=c.min_inliers)
                if found is not None and refine is not None:
                    T_ref = refine(q, found.T_cand_query)
                    found = (None if T_ref is None else LoopCandidate(
                        candidate=q, T_cand_query=T_ref, inliers=found.inliers,
                        consistent_3d=found.consistent_3d))
                if found is not None:
                    break
        if self._db is not None and kf.bow is not None and kf_id not in self._db_ids:
            self._db.add(kf_id, kf.bow)
            self._db_ids.add(kf_id)
        if found is None:
            return False
        self.graph.add_loop(found.candidate, kf_id, found.T_cand_query)
        try:
            solved = self.graph.optimise(
                {k: v.T_odom for k, v in self._kfs.items()},
                {k: v.segment for k, v in self._kfs.items()},
                {k: self.correction(k) @ v.T_odom for k, v in self._kfs.items()})
        except RuntimeError as err:
            log.warning("pose graph optimisation failed (%s); loop ignored", err)
            self.graph.loops.pop()
            return False
        for k, T in solved.items():
            self._kfs[k].correction = T @ np.linalg.inv(self._kfs[k].T_odom)
        self.loop_closures += 1
        self.loops.append((found.candidate, kf_id))
        self._since_loop = 0
        log.info("RGB-D loop closed: keyframe %d with %d (%d inliers)", kf_id,
                 found.candidate, found.inliers)
        return True

    def correction(self, kf_id: int) -> F64:
        """``T_world_corrected @ inv(T_odom)`` of keyframe ``kf_id`` (identity before any
        loop, or for an unknown keyframe)."""
        kf = self._kfs.get(kf_id)
        if kf is None or kf.correction is None:
            return np.eye(4)
        return kf.correction
