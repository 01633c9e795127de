"""Point depth against a ground-truth depth map."""

import numpy as np
import pytest

from sea3d.errors import GeometryError
from sea3d.eval.depth_gt import point_depth_errors
from sea3d.refraction.presets import paper_rig


def test_exact_points_have_zero_error_and_a_scale_bias_shows():
    cam = paper_rig("dome", size_px=(320, 180)).left
    uv = cam.pinhole.pixel_grid(step=4)
    rays = cam.unproject(uv)
    depth = np.full((180, 320), 2.0)
    s = (2.0 - rays.origins[:, 2]) / rays.directions[:, 2]
    pts = rays.at(s)
    e = point_depth_errors(pts, cam, depth)
    assert e.count == len(uv)
    assert e.median_abs_m == pytest.approx(0.0, abs=1e-9)
    scaled = point_depth_errors(pts * 1.02, cam, depth)
    assert scaled.mean_signed_rel == pytest.approx(0.02, abs=1e-6)
    assert scaled.within_1pct == 0.0


def test_wrong_map_size_raises():
    cam = paper_rig("none", size_px=(320, 180)).left
    with pytest.raises(GeometryError, match="ground-truth depth"):
        point_depth_errors(np.zeros((1, 3)), cam, np.zeros((10, 10)))
