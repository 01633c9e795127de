"""What enhancement does to the tasks that use the images: dense stereo and sparse features.

The stages run here; the figures come from :mod:`sea3d.eval`, which runs none.

- :func:`stereo_with_enhancement`: disparity figures (bad-2, density, ...) of a matcher on a
  stereo pair, raw and after each enhancement method (white balances shared by the pair).
- :func:`correct_feature_matches`: ratio-test SIFT matches from one view to another, judged
  against ground-truth geometry by :func:`sea3d.eval.enhance_tasks.judge_feature_matches`.

``benchmarks/bench_enhance.py`` prints both on simulated underwater scenes (docs/enhance.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from sea3d.enhance.api import enhance_pair
from sea3d.errors import EnhanceError
from sea3d.eval.disparity import DisparityMetrics, disparity_metrics
from sea3d.eval.enhance_tasks import FeatureMatchCount, judge_feature_matches
from sea3d.geometry.camera import CameraModel

__all__ = ["FeatureMatchCount", "correct_feature_matches", "stereo_with_enhancement"]


def stereo_with_enhancement(
    left: np.ndarray,
    right: np.ndarray,
    gt_disparity_px: np.ndarray,
    engine: Any,
    methods: Sequence[str] = (
        "none",
        "grey-world",
        "shades-of-grey",
        "red-comp",
        "clahe",
        "udcp",
    ),
) -> dict[str, DisparityMetrics]:
    """Disparity figures of ``engine`` on a rectified pair, raw (``none``) and enhanced.

    Args:
        left, right: rectified RGB pair, uint8.
        gt_disparity_px: ``(H, W)`` float32 true left disparity, NaN (or 0) unknown.
        engine: a matching config for :func:`sea3d.stereo.match` (e.g. ``SgmConfig``).
        methods: ``none`` and names of :data:`sea3d.enhance.METHODS` except ``seathru``
            (which needs the depth that matching produces).

    Returns:
        ``{method: DisparityMetrics}`` in the order of ``methods``.

    Raises:
        EnhanceError: ``seathru`` among the methods.
    """
    from sea3d.stereo import match

    out: dict[str, DisparityMetrics] = {}
    for m in methods:
        if m == "seathru":
            raise EnhanceError("seathru needs depth: it cannot run before matching")
        a, b = (left, right) if m == "none" else enhance_pair(left, right, m).images
        out[m] = disparity_metrics(match(a, b, engine).disparity_px, gt_disparity_px)
    return out


def correct_feature_matches(
    image_a: np.ndarray,
    image_b: np.ndarray,
    depth_a_m: np.ndarray,
    camera: CameraModel,
    T_b_a: np.ndarray,
    *,
    tol_px: float = 3.0,
    n_features: int = 3000,
    ratio: float = 0.8,
) -> FeatureMatchCount:
    """Count correct SIFT matches between two views of a known scene (OpenCV SIFT, brute-force
    L2 matching, Lowe's ratio test).

    Args:
        image_a, image_b: RGB (or grey) uint8 views, the camera's size.
        depth_a_m: ``(H, W)`` true depth of view a (z in the camera frame), NaN unknown.
        camera: the camera of both views (any :class:`CameraModel`, ports included).
        T_b_a: 4x4 pose mapping view a's camera frame into view b's.
        tol_px: reprojection threshold of a correct match, pixels.
        n_features: SIFT keypoints per image at most.
        ratio: Lowe's ratio.

    Raises:
        EnhanceError: depth of another size than the camera's image.
    """
    empty = np.zeros((0, 2))
    # the depth is checked before any feature work
    judge_feature_matches(empty, empty, depth_a_m, camera, T_b_a, tol_px=tol_px)
    sift = cv2.SIFT_create(nfeatures=n_features)  # type: ignore[attr-defined]

    def grey(img: np.ndarray) -> np.ndarray:
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img

    ka, da = sift.detectAndCompute(grey(image_a), None)
    kb, db = sift.detectAndCompute(grey(image_b), None)
    good = []
    if da is not None and db is not None and len(ka) >= 2 and len(kb) >= 2:
        pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    uv_a = np.array([ka[m.queryIdx].pt for m in good], np.float64).reshape(-1, 2)
    uv_b = np.array([kb[m.trainIdx].pt for m in good], np.float64).reshape(-1, 2)
    return judge_feature_matches(uv_a, uv_b, depth_a_m, camera, T_b_a, tol_px=tol_px)
