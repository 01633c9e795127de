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


def _plane_depth_result(port: str):
    """A DepthResult of a plane z = 2 m (left frame) valid on every rectified pixel, built from
    the rectified rays of the real, rotated Sea3D rig."""
    from _rigs import real_sea3d_rig
    from sea3d.rectify import rectify_rig
    from sea3d.stereo.depth import DepthResult

    rig = real_sea3d_rig(port)
    maps = rectify_rig(rig, depth_range_m=(1.0, 4.0))
    h, w = maps.height, maps.width
    raw = np.c_[maps.map_left_x.ravel(), maps.map_left_y.ravel()].astype(np.float64)
    rays = rig.left.unproject(raw)
    s = (2.0 - rays.origins[:, 2]) / rays.directions[:, 2]
    pts = rays.at(s)
    inside = (raw[:, 0] >= 0) & (raw[:, 0] <= w - 1) & (raw[:, 1] >= 0) & (raw[:, 1] <= h - 1)
    depth = np.full(h * w, np.nan, np.float32)
    depth[inside] = (pts[inside] @ maps.R_rect_left_left.T)[:, 2]
    colors = np.zeros((int(inside.sum()), 3), np.uint8)
    res = DepthResult(depth_m=depth.reshape(h, w), disparity_px=depth.reshape(h, w),
                      points_left=pts[inside], colors_rgb=colors,
                      rect_left=np.zeros((h, w), np.uint8), maps=maps)
    return res, np.full((h, w), 2.0)


@pytest.mark.parametrize("port", ["none", "dome"])
def test_depth_error_map_loses_no_raw_pixel_the_rectified_view_covers(port):
    from sea3d.eval.depth_gt import depth_error_map, raw_left_coordinates

    res, gt = _plane_depth_result(port)
    ru, rv = raw_left_coordinates(res.maps)
    covered = np.isfinite(ru)
    assert covered.mean() > 0.9
    err = depth_error_map(res, gt, (ru, rv))
    # every covered raw pixel gets a value (drawing points at their nearest raw pixel instead
    # leaves one-pixel curves of holes where the grids' spacing differs)
    np.testing.assert_array_equal(np.isfinite(err), covered)
    assert np.nanmax(np.abs(err)) < 1e-4  # and the value is the plane's


@pytest.mark.parametrize("port", ["none", "dome"])
def test_raw_left_coordinates_invert_the_rectification_maps(port):
    from sea3d.eval.depth_gt import raw_left_coordinates

    res, _ = _plane_depth_result(port)
    maps = res.maps
    ru, rv = raw_left_coordinates(maps)
    ok = np.isfinite(ru)
    # bilinear lookup of the map tables at the inverse gives the raw pixel back
    _, u = np.nonzero(ok)
    x, y = ru[ok].astype(np.float64), rv[ok].astype(np.float64)
    x0 = np.minimum(np.floor(x).astype(int), maps.width - 2)
    y0 = np.minimum(np.floor(y).astype(int), maps.height - 2)
    fx, fy = x - x0, y - y0
    m = maps.map_left_x.astype(np.float64)
    back = ((1 - fx) * (1 - fy) * m[y0, x0] + fx * (1 - fy) * m[y0, x0 + 1]
            + (1 - fx) * fy * m[y0 + 1, x0] + fx * fy * m[y0 + 1, x0 + 1])
    assert np.abs(back - u).max() < 1e-3
