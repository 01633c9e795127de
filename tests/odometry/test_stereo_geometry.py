"""The odometry's rectified stereo geometry stays exact through dome and flat ports."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sea3d.odometry.stereo_geometry import RectifiedStereo
from sea3d.rectify import rectify_rig
from sea3d.refraction.presets import paper_rig

# Ray grids every 4 px, interpolated bilinearly: the point error this leaves, measured over
# 0.8-4 m with the paper's domes at 640x360 (about 0.04 mm by depth, 0.9 mm by stereo at 4 m,
# i.e. 0.002 px of disparity), with margin.
DEPTH_POINT_TOL_M = 2e-4
STEREO_POINT_TOL_M = 3e-3
# The virtual pinhole's own residual for these domes (VirtualPinholeReport: RMS 0.19 px, max
# 0.62 px): a test that used it for 3D would fail these tolerances by far.
VIRTUAL_RESIDUAL_MIN_PX = 0.05


def _truth(rig, maps, rng, n=400):
    """True points in the left frame and their exact rectified pixels in both views."""
    X_left = np.c_[rng.uniform(-0.8, 0.8, (n, 2)), rng.uniform(0.8, 4.0, n)]
    uv_raw, ok_l = rig.left.project(X_left)
    T_right_left = np.linalg.inv(rig.T_left_right)
    X_right = X_left @ T_right_left[:3, :3].T + T_right_left[:3, 3]
    uvr_raw, ok_r = rig.right.project(X_right)
    w, h = rig.width, rig.height
    for uv, ok in ((uv_raw, ok_l), (uvr_raw, ok_r)):
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        uv[~ok] = 0.0  # no pixel: left out by `seen` below
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rect_l = cv2.undistortPointsIter(
        uv_raw.reshape(-1, 1, 2),
        maps.virtual_left.K,
        maps.virtual_left.dist,
        maps.R_rect_left_left,
        maps.P_left,
        crit,
    ).reshape(-1, 2)
    rect_r = cv2.undistortPointsIter(
        uvr_raw.reshape(-1, 1, 2),
        maps.virtual_right.K,
        maps.virtual_right.dist,
        maps.R_rect_right_right,
        maps.P_right,
        crit,
    ).reshape(-1, 2)
    seen = ok_l & ok_r  # imaged inside both raw images
    inside = seen & (
        (rect_l[:, 0] > 1)
        & (rect_l[:, 0] < w - 2)
        & (rect_l[:, 1] > 1)
        & (rect_l[:, 1] < h - 2)
        & (rect_r[:, 0] > 1)
        & (rect_r[:, 0] < w - 2)
    )
    X_rect = X_left @ maps.R_rect_left_left.T
    return X_rect[inside], rect_l[inside], rect_r[inside]


@pytest.fixture(scope="module", params=["dome", "flat"])
def rig_maps(request):
    rig = paper_rig(request.param, size_px=(640, 360))
    return request.param, rig, rectify_rig(rig)


def test_points_from_depth_and_stereo_are_exact_through_ports(rig_maps, rng) -> None:
    _, rig, maps = rig_maps
    g = RectifiedStereo.from_maps(maps)
    assert g.refractive
    X, uv_l, uv_r = _truth(rig, maps, rng)
    assert len(X) > 100
    P, ok = g.points_from_depth(uv_l, X[:, 2])
    assert ok.all()
    assert np.abs(P - X).max() < DEPTH_POINT_TOL_M
    S, ok = g.points_from_stereo(uv_l, uv_r)
    assert ok.all()
    assert np.linalg.norm(S - X, axis=1).max() < STEREO_POINT_TOL_M
    # the virtual pinhole alone is off by far more than that: the correction is doing work
    proj = g.project(X)
    assert np.abs(proj[:, [0, 2]] - uv_l).max() > VIRTUAL_RESIDUAL_MIN_PX


def test_rays_follow_opencvs_rectification_tables(rig_maps, rng) -> None:
    """At integer pixels the rectified image shows the raw pixel of OpenCV's remap tables: the
    point at depth z on that raw pixel's true ray is what points_from_depth must return."""
    _, rig, maps = rig_maps
    g = RectifiedStereo.from_maps(maps)
    u = rng.integers(0, rig.width, 500)
    v = rng.integers(0, rig.height, 500)
    raw = np.stack([maps.map_left_x[v, u], maps.map_left_y[v, u]], axis=1).astype(np.float64)
    rays = rig.left.unproject(raw)
    o = rays.origins @ maps.R_rect_left_left.T
    d = rays.directions @ maps.R_rect_left_left.T
    z = rng.uniform(0.6, 5.0, 500)
    X = o + ((z - o[:, 2]) / d[:, 2])[:, None] * d
    P, ok = g.points_from_depth(np.stack([u, v], axis=1).astype(np.float64), z)
    assert ok.all()
    # float32 tables (about 3e-5 px) and the ray grid's interpolation
    assert np.abs(P - X).max() < DEPTH_POINT_TOL_M


def test_pinhole_geometry_is_plain_triangulation(rng) -> None:
    rig = paper_rig("none", size_px=(640, 360))
    maps = rectify_rig(rig)
    g = RectifiedStereo.from_maps(maps)
    assert not g.refractive
    X, uv_l, uv_r = _truth(rig, maps, rng)
    S, ok = g.points_from_stereo(uv_l, uv_r)
    assert ok.all()
    assert np.linalg.norm(S - X, axis=1).max() < 1e-6
    m = g.project(S)
    np.testing.assert_allclose(m[:, 0] - m[:, 1], g.focal_baseline / S[:, 2], rtol=1e-12)


def test_rgbd_pinhole_rejects_bad_intrinsics() -> None:
    from sea3d.errors import OdometryError

    with pytest.raises(OdometryError, match="positive"):
        RectifiedStereo.pinhole(0.0, 585, 320, 240, 640, 480, 0.3)
