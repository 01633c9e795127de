"""The virtual pinhole at the rays' closest point, and the exact remap into it.

References: OpenCV's ``initUndistortRectifyMap`` for a pinhole with distortion (the remap must
be the same undistortion); geometry for the rest (lines through one point meet there; a dome
decentred along the optical axis is rotationally symmetric, so its rays pass closest on that
axis; a point at the nominal depth lands exactly where the remap says).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sea3d.errors import RectifyError
from sea3d.geometry import PinholeCamera
from sea3d.rectify import closest_point_of_rays, fit_virtual_pinhole
from sea3d.rectify.virtual import virtual_pinhole_maps
from sea3d.refraction.presets import paper_rig

CLOSEST_POINT_M = 1e-12  # exact lines through one point (linear solve)
OPENCV_MAP_PX = 5e-3  # our bilinear table (nodes every 4 px) vs OpenCV per pixel; measured 2.3e-3
NOMINAL_DEPTH_PX = 2e-3  # remap vs exact projection at the nominal depth (table interpolation)
PAPER_DOME_PARALLAX_PX = 0.01  # paper dome at 480x270 over 0.5-5 m (measured 0.0005 px)


def test_closest_point_of_lines_through_one_point() -> None:
    rng = np.random.default_rng(0)
    p = np.array([0.01, -0.02, 0.003])
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = p + rng.uniform(-2, 2, (50, 1)) * d  # origins anywhere along each line
    np.testing.assert_allclose(closest_point_of_rays(o, d), p, atol=CLOSEST_POINT_M)
    with pytest.raises(RectifyError, match="parallel"):
        closest_point_of_rays(o, np.tile(d[:1], (50, 1)))


def test_axially_decentred_dome_centre_on_axis_and_smaller_residual() -> None:
    rig = paper_rig("dome", size_px=(320, 180), dome_center_left_m=(0.0, 0.0, 0.010))
    _, at_camera = fit_virtual_pinhole(rig.left, (0.5, 5.0))
    _, at_rays = fit_virtual_pinhole(rig.left, (0.5, 5.0), center="rays")
    assert at_camera.center_m == (0.0, 0.0, 0.0)
    cx, cy, cz = at_rays.center_m
    assert abs(cx) < 1e-6 and abs(cy) < 1e-6 and 0.0 < cz < 0.010  # on the axis, inside
    assert at_rays.rms_px < 0.1 * at_camera.rms_px


def test_remap_of_distorted_pinhole_is_opencv_undistortion() -> None:
    cam = PinholeCamera(fx=300.0, fy=302.0, cx=158.0, cy=91.0, width=320, height=180,
                        dist=(-0.12, 0.05, 0.001, -0.0005, 0.0))
    vm = virtual_pinhole_maps(cam, (0.5, 5.0))
    np.testing.assert_allclose(vm.center_m, 0.0, atol=1e-9)  # a pinhole's rays meet at 0
    assert vm.report.max_px < 1e-9  # no parallax for a central camera
    mx, my = cv2.initUndistortRectifyMap(cam.K, cam.dist, None, vm.virtual.K, (320, 180),
                                         cv2.CV_32FC1)
    inside = (mx > 0) & (mx < 319) & (my > 0) & (my < 179)
    assert inside.mean() > 0.9
    err = np.hypot(vm.map_x - mx, vm.map_y - my)[inside]
    assert float(err.max()) < OPENCV_MAP_PX


def test_paper_dome_remap_exact_at_nominal_depth_and_tiny_parallax() -> None:
    rng = np.random.default_rng(0)
    rig = paper_rig("dome", size_px=(480, 270))
    vm = virtual_pinhole_maps(rig.left, (0.5, 5.0))
    assert vm.report.rms_px < PAPER_DOME_PARALLAX_PX
    assert len(vm.report.rms_by_depth_px) == 6
    # Points at the nominal depth: the virtual projection from the centre, looked up in the
    # table, must give the true refractive projection.
    q = rng.uniform([20, 20], [460, 250], (200, 2))
    K = vm.virtual.K
    ray = np.column_stack([(q[:, 0] - K[0, 2]) / K[0, 0], (q[:, 1] - K[1, 2]) / K[1, 1],
                           np.ones(200)])
    pts = vm.center_m + ((vm.nominal_depth_m - vm.center_m[2]) / ray[:, 2])[:, None] * ray
    uv_true, ok = rig.left.project(pts)
    assert ok.all()
    np.testing.assert_allclose(vm.to_raw(q), uv_true, atol=1e-9)
    table = np.stack([cv2.remap(m, q[:, :1].astype(np.float32), q[:, 1:].astype(np.float32),
                                cv2.INTER_LINEAR)[:, 0] for m in (vm.map_x, vm.map_y)], axis=1)
    # cv2.remap's own sampling of the table is quantised to 1/32 px of the table position
    # (slope about 1 px/px), so compare with a matching tolerance.
    np.testing.assert_allclose(table, uv_true, atol=NOMINAL_DEPTH_PX + 1 / 32)
    img = (rng.uniform(0, 255, (270, 480, 3))).astype(np.uint8)
    assert vm.remap(img).shape == img.shape
    with pytest.raises(RectifyError, match="320x180"):
        vm.remap(np.zeros((180, 320), np.uint8))


def test_bad_centre_and_step_are_refused() -> None:
    rig = paper_rig("dome", size_px=(160, 90))
    with pytest.raises(RectifyError, match="center"):
        fit_virtual_pinhole(rig.left, center="middle")
    with pytest.raises(RectifyError, match="center"):
        fit_virtual_pinhole(rig.left, center=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(RectifyError, match="map_step_px"):
        virtual_pinhole_maps(rig.left, map_step_px=0)
