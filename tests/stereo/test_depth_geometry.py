"""Metric depth on a rotated real-world rig, checked against an independent 3D tracer.

The rig is the original Sea3D rig's in-air calibration (``tests/_rigs.py``), scaled to 480x270,
with the paper's dome ports or without. Its cameras are 0.5-0.6 degrees apart
and the baseline has a 1.5 mm forward component, so the rectifying rotation is about a degree:
unlike the presets (rectifying rotation = identity) it shows whether the rotations are applied,
and applied the right way round.

Truth comes from ``tests/_trace3d.py`` (OpenCV's pinhole plus sphere intersections and Snell's
law written out there): for a grid of rectified left pixels, the raw left pixel's traced ray hits
a tilted plane; the hit is traced into the right camera and back into the rectified right view,
which gives the disparity a perfect matcher would find. sea3d must turn that disparity into the
traced point.
"""

from __future__ import annotations

import numpy as np
import pytest

from _rigs import real_sea3d_rig
from _trace3d import project, trace
from sea3d.eval.depth_gt import rectified_coordinates
from sea3d.rectify import RectifyMaps, rectify_rig
from sea3d.stereo.depth import disparity_to_depth, disparity_to_points

# Tolerances. Pinhole rig: the only approximation between sea3d and the tracer is the float32
# remap tables (~1e-4 px), so points agree to 0.2 mm at 1.5-3 m. Dome rig: rectification uses
# the best-fitting virtual pinholes, whose residual leaves the true match up to ~0.05 px off the
# rectified row (the row the matcher searches); triangulating with the true rays then moves the
# point by up to ~1.5 mm. Either is 10-50x below what a dropped or transposed rotation costs.
ROW_TOL_PX = {"none": 0.002, "dome": 0.1}
POINT_TOL_M = {"none": 2e-4, "dome": 2e-3}
DEPTH_REL_TOL = {"none": 1e-4, "dome": 1e-3}


def _plane_hits(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Where rays (left frame) meet the plane n . X = c, tilted by about 20 degrees."""
    n = np.array([0.25, -0.2, 1.0])
    n /= np.linalg.norm(n)
    c = 2.0
    lam = (c - origins @ n) / (dirs @ n)
    return origins + lam[:, None] * dirs


def _traced_disparity(port: str) -> tuple[RectifyMaps, np.ndarray, np.ndarray, np.ndarray]:
    """Maps, the disparity a perfect matcher finds on a grid of rectified left pixels, and the
    traced points (left frame) and their grid pixels."""
    rig = real_sea3d_rig(port)
    maps = rectify_rig(rig, depth_range_m=(1.0, 4.0))
    vv, uu = np.mgrid[20:250:10, 20:460:10]
    u_r, v_r = uu.ravel().astype(np.float64), vv.ravel().astype(np.float64)
    raw_l = np.c_[maps.map_left_x[vv, uu].ravel(), maps.map_left_y[vv, uu].ravel()]
    o, d = trace(rig.left, raw_l)
    X = _plane_hits(o, d)
    T_rl = np.linalg.inv(rig.T_left_right)
    X_r = X @ T_rl[:3, :3].T + T_rl[:3, 3]
    raw_r = project(rig.right, X_r)
    ur, vr = rectified_coordinates(maps, "right", points_px=raw_r)
    assert np.isfinite(ur).all()
    assert np.abs(vr - v_r).max() < ROW_TOL_PX[port]  # rectified rows agree
    disp = np.full((maps.height, maps.width), np.nan, np.float32)
    disp[vv.ravel(), uu.ravel()] = (u_r - ur).astype(np.float32)
    return maps, disp, X, np.c_[uu.ravel(), vv.ravel()]


@pytest.mark.parametrize("port", ["none", "dome"])
def test_points_from_disparity_match_independent_trace_on_rotated_rig(port: str) -> None:
    maps, disp, X, grid = _traced_disparity(port)
    rect_angle = np.degrees(np.arccos((np.trace(maps.R_rect_left_left) - 1) / 2))
    assert rect_angle > 0.4  # the rig is not one of the parallel presets
    points, depth_rect, mask = disparity_to_points(maps, disp)
    # points come in the mask's row-major order, as the grid does
    v, u = np.nonzero(mask)
    assert len(points) == len(X)
    np.testing.assert_array_equal(np.c_[u, v], grid[np.lexsort((grid[:, 0], grid[:, 1]))])
    order = np.lexsort((grid[:, 0], grid[:, 1]))
    np.testing.assert_allclose(points, X[order], atol=POINT_TOL_M[port])
    # depth is along the rectified left axis
    z_rect = (X[order] @ maps.R_rect_left_left.T)[:, 2]
    np.testing.assert_allclose(depth_rect, z_rect, rtol=DEPTH_REL_TOL[port])
    # ... which differs from the raw left z by more than the tolerance on this rig
    assert np.abs(z_rect / X[order][:, 2] - 1).max() > 5 * DEPTH_REL_TOL[port]


def test_disparity_to_depth_keeps_only_positive_disparities() -> None:
    d = np.array([[2.0, 0.0, -1.0, np.nan, 0.5]], np.float32)
    z = disparity_to_depth(d, 500.0, 0.1)
    np.testing.assert_allclose(z[0, [0, 4]], [25.0, 100.0])
    assert np.isnan(z[0, 1:4]).all()  # zero, negative and missing disparities have no depth
