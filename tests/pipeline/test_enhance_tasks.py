"""Task metrics of enhancement (sea3d.pipeline.enhance_tasks runs the stages; the figures come
from sea3d.eval): disparity figures with and without each method, and feature matches judged
by ground-truth geometry."""

from __future__ import annotations

import numpy as np
import pytest

from _textures import smooth_noise, stretch
from sea3d.enhance import enhance_pair
from sea3d.errors import EnhanceError
from sea3d.eval import disparity_metrics
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.pipeline.enhance_tasks import correct_feature_matches, stereo_with_enhancement
from sea3d.stereo import SgmConfig, match

W, H = 192, 144
F_PX = 150.0
Z_M = 2.0
SHIFT_PX = 6  # view b sees the plane 6 px to the left: camera moved +x by SHIFT * Z / f
# A pure shift of a textured plane: SIFT matches are exact to a fraction of a pixel, so nearly
# every judged match is correct with the true pose (measured 100 %), and nearly none with a
# pose 6 px off (the threshold is 3 px).
CORRECT_SHARE_MIN = 0.9
WRONG_POSE_SHARE_MAX = 0.05
DISPARITY_PX = 5  # the random-dot pair's true disparity


def _water_texture(rng: np.random.Generator, h: int = H, w: int = W) -> np.ndarray:
    """Smooth noise in blue-green, like water; uint8 RGB."""
    return (stretch(smooth_noise(rng, (h, w, 3), 1.5)) * np.array([60, 200, 180])
            + 10).astype(np.uint8)


def test_feature_matches_are_judged_by_the_true_geometry(rng: np.random.Generator) -> None:
    cam = PinholeCamera(fx=F_PX, fy=F_PX, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)
    a = _water_texture(rng)
    b = np.roll(a, -SHIFT_PX, axis=1)
    depth = np.full((H, W), Z_M, np.float32)
    depth[:, W - SHIFT_PX - 4 :] = np.nan  # the wrapped columns have no true correspondence
    T_b_a = np.eye(4)
    T_b_a[0, 3] = -SHIFT_PX * Z_M / F_PX
    right = correct_feature_matches(a, b, depth, cam, T_b_a)
    assert right.matches > 50 and right.judged <= right.matches
    assert right.correct >= CORRECT_SHARE_MIN * right.judged
    wrong = correct_feature_matches(a, b, depth, cam, np.eye(4))
    assert wrong.judged == right.judged
    assert wrong.correct <= WRONG_POSE_SHARE_MAX * wrong.judged
    # A looser threshold forgives the wrong pose: the error is measured in pixels of view b.
    assert correct_feature_matches(a, b, depth, cam, np.eye(4), tol_px=7.0).correct >= (
        CORRECT_SHARE_MIN * right.judged)
    # No true depth: nothing can be judged.
    none = correct_feature_matches(a, b, np.full((H, W), np.nan, np.float32), cam, T_b_a)
    assert none.judged == 0 and none.precision == 0.0
    with pytest.raises(EnhanceError, match="96x72"):
        correct_feature_matches(a, b, depth[::2, ::2], cam, T_b_a)


def test_stereo_with_and_without_each_method(rng: np.random.Generator) -> None:
    left = _water_texture(rng, 96, 128)
    right = np.roll(left, -DISPARITY_PX, axis=1)
    gt = np.full(left.shape[:2], float(DISPARITY_PX), np.float32)
    gt[:, :24] = np.nan  # left of the search range's reach, and the wrapped border
    gt[:, -8:] = np.nan
    cfg = SgmConfig(max_disparity_px=16)
    got = stereo_with_enhancement(left, right, gt, cfg, ("none", "grey-world", "udcp"))
    assert list(got) == ["none", "grey-world", "udcp"]
    assert got["none"] == disparity_metrics(match(left, right, cfg).disparity_px, gt)
    a, b = enhance_pair(left, right, "grey-world").images  # gains shared by the pair
    assert got["grey-world"] == disparity_metrics(match(a, b, cfg).disparity_px, gt)
    assert got["none"].bad_2 < 1.0 and got["none"].density > 95.0
    with pytest.raises(EnhanceError, match="seathru"):
        stereo_with_enhancement(left, right, gt, cfg, ("seathru",))
