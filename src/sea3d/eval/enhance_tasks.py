"""What enhancement does to the tasks that use the images, measured from given arrays.

- :func:`judge_feature_matches`: matched keypoints from one view to another, each judged
  against ground-truth geometry (the first view's depth and the relative pose): a match is
  correct when the keypoint, lifted to 3D with the true depth and projected into the second
  view, lands within ``tol_px`` of the matched keypoint.
- Disparity figures against ground truth are :func:`sea3d.eval.disparity.disparity_metrics`.

Eval runs no stage: the part that enhances, matches and detects features is
:mod:`sea3d.pipeline.enhance_tasks` (``stereo_with_enhancement``, ``correct_feature_matches``);
``benchmarks/bench_enhance.py`` prints both on simulated underwater scenes (docs/enhance.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sea3d.errors import EnhanceError
from sea3d.geometry.camera import CameraModel

__all__ = ["FeatureMatchCount", "judge_feature_matches"]


@dataclass(frozen=True, kw_only=True)
class FeatureMatchCount:
    """Matches from view a to view b, judged by ground truth.

    Attributes:
        correct: matches whose reprojection error is at most ``tol_px``.
        judged: matches whose keypoint in a has true depth (and projects into b).
        matches: all matches given.
        tol_px: the threshold used.
    """

    correct: int
    judged: int
    matches: int
    tol_px: float

    @property
    def precision(self) -> float:
        """Correct share of the judged matches (0 when none)."""
        return self.correct / self.judged if self.judged else 0.0


def judge_feature_matches(
    uv_a: np.ndarray,
    uv_b: np.ndarray,
    depth_a_m: np.ndarray,
    camera: CameraModel,
    T_b_a: np.ndarray,
    *,
    tol_px: float = 3.0,
) -> FeatureMatchCount:
    """Judge matched keypoints by the true depth of view a and the true pose of b.

    Each keypoint of view a takes the true depth of its nearest pixel; that pixel centre's ray
    (``camera.unproject``, so port cameras work too) is followed to the point whose
    camera-frame z equals the depth, moved into view b and projected.

    Args:
        uv_a, uv_b: ``(N, 2)`` pixel coordinates of the N matches in views a and b.
        depth_a_m: ``(H, W)`` true depth of view a (z in the camera frame), NaN unknown.
        camera: the camera of both views (any :class:`CameraModel`, ports included).
        T_b_a: 4x4 pose mapping view a's camera frame into view b's.
        tol_px: reprojection threshold of a correct match, pixels.

    Raises:
        EnhanceError: depth of another size than the camera's image, or keypoint arrays
            that are not two matching ``(N, 2)`` arrays.
    """
    z = np.asarray(depth_a_m, dtype=np.float64)
    if z.shape != (camera.height, camera.width):
        raise EnhanceError(
            f"depth map is {z.shape[1]}x{z.shape[0]} but the camera is "
            f"{camera.width}x{camera.height}"
        )
    uv_a = np.asarray(uv_a, np.float64).reshape(-1, 2)
    uv_b = np.asarray(uv_b, np.float64).reshape(-1, 2)
    if len(uv_a) != len(uv_b):
        raise EnhanceError(f"{len(uv_a)} keypoints in view a but {len(uv_b)} in view b")
    if not len(uv_a):
        return FeatureMatchCount(correct=0, judged=0, matches=0, tol_px=tol_px)
    h, w = z.shape
    col = np.clip(np.rint(uv_a[:, 0]).astype(np.int64), 0, w - 1)
    row = np.clip(np.rint(uv_a[:, 1]).astype(np.int64), 0, h - 1)
    zk = z[row, col]
    rays = camera.unproject(np.stack([col, row], axis=1).astype(np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (zk - rays.origins[:, 2]) / rays.directions[:, 2]
        has = np.isfinite(zk) & (zk > 0) & np.isfinite(t) & (t > 0) & rays.valid
    pts = rays.origins[has] + t[has, None] * rays.directions[has]
    T = np.asarray(T_b_a, np.float64)
    p_b = pts @ T[:3, :3].T + T[:3, 3]
    proj, vis = camera.project(p_b)
    err = np.linalg.norm(proj - uv_b[has], axis=1)
    good_mask = vis & (err <= tol_px)
    return FeatureMatchCount(
        correct=int(good_mask.sum()), judged=int(vis.sum()), matches=len(uv_a), tol_px=tol_px
    )
