"""Judging given matches by true depth and pose (sea3d.eval.enhance_tasks): no stage runs."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.errors import EnhanceError
from sea3d.eval.enhance_tasks import judge_feature_matches
from sea3d.geometry.pinhole import PinholeCamera

W, H, F_PX, Z_M, SHIFT_PX = 160, 120, 100.0, 2.0, 6


def _camera() -> PinholeCamera:
    return PinholeCamera(fx=F_PX, fy=F_PX, cx=(W - 1) / 2, cy=(H - 1) / 2, width=W, height=H)


def test_matches_are_judged_by_the_true_geometry() -> None:
    # A plane at Z; view b moved +x by SHIFT * Z / f sees every pixel SHIFT px to the left.
    vv, uu = np.mgrid[10:110:10, 20:140:10]
    uv_a = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    uv_b = uv_a - [SHIFT_PX, 0]
    uv_b[:5] += [0.0, 4.0]  # five wrong matches, 4 px off (threshold 3 px)
    depth = np.full((H, W), Z_M, np.float32)
    depth[:, 130:] = np.nan  # the last column of keypoints (u = 130) has no true depth
    T_b_a = np.eye(4)
    T_b_a[0, 3] = -SHIFT_PX * Z_M / F_PX
    got = judge_feature_matches(uv_a, uv_b, depth, _camera(), T_b_a)
    n, no_depth = len(uv_a), int((uv_a[:, 0] >= 130).sum())
    assert (got.matches, got.judged) == (n, n - no_depth)
    assert got.correct == n - no_depth - 5
    assert got.precision == pytest.approx((n - no_depth - 5) / (n - no_depth))
    # the true pose is what makes them correct; a looser threshold forgives the 4 px
    assert judge_feature_matches(uv_a, uv_b, depth, _camera(), np.eye(4)).correct == 0
    assert judge_feature_matches(uv_a, uv_b, depth, _camera(), T_b_a, tol_px=5.0).correct == (
        n - no_depth
    )


def test_nothing_given_or_bad_shapes() -> None:
    depth = np.full((H, W), Z_M, np.float32)
    none = judge_feature_matches(np.zeros((0, 2)), np.zeros((0, 2)), depth, _camera(), np.eye(4))
    assert (none.matches, none.judged, none.precision) == (0, 0, 0.0)
    with pytest.raises(EnhanceError, match="80x60"):
        judge_feature_matches(
            np.zeros((0, 2)), np.zeros((0, 2)), depth[::2, ::2], _camera(), np.eye(4)
        )
    with pytest.raises(EnhanceError, match="3 keypoints in view a but 2"):
        judge_feature_matches(np.zeros((3, 2)), np.zeros((2, 2)), depth, _camera(), np.eye(4))
