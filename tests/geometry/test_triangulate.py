"""Midpoint triangulation: exact for intersecting rays, gap for skew rays."""

import numpy as np
import pytest

from sea3d.errors import GeometryError
from sea3d.geometry import Rays, triangulate_midpoint


def test_intersecting_rays_give_the_point_and_zero_gap(rng):
    pts = rng.uniform(-2, 2, (100, 3)) + [0, 0, 5]
    a = np.zeros((100, 3))
    b = np.tile([0.1, 0.0, 0.0], (100, 1))
    da = pts - a
    db = pts - b
    ra = Rays(a, da / np.linalg.norm(da, axis=1, keepdims=True))
    rb = Rays(b, db / np.linalg.norm(db, axis=1, keepdims=True))
    out, gap = triangulate_midpoint(ra, rb)
    np.testing.assert_allclose(out, pts, atol=1e-9)
    np.testing.assert_allclose(gap, 0.0, atol=1e-9)


def test_skew_rays_report_their_gap():
    ra = Rays(np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]))
    rb = Rays(np.array([[1.0, 0.02, 5.0]]), np.array([[-1.0, 0.0, 0.0]]))
    out, gap = triangulate_midpoint(ra, rb)
    np.testing.assert_allclose(gap, [0.02], atol=1e-12)
    np.testing.assert_allclose(out, [[0.0, 0.01, 5.0]], atol=1e-12)


def test_parallel_or_backward_rays_are_nan():
    ra = Rays(np.zeros((2, 3)), np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]))
    rb = Rays(
        np.array([[0.1, 0.0, 0.0], [0.1, 0.0, 0.0]]),
        np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]),
    )
    out, gap = triangulate_midpoint(ra, rb)
    assert np.isnan(out).all() and np.isnan(gap).all()


def test_length_mismatch_raises():
    r1 = Rays(np.zeros((2, 3)), np.ones((2, 3)))
    r2 = Rays(np.zeros((3, 3)), np.ones((3, 3)))
    with pytest.raises(GeometryError, match="differ in length"):
        triangulate_midpoint(r1, r2)


# The midpoint of two exactly intersecting rays is exact up to float64 rounding of a 2x2 solve
# with coordinates of a few metres: 1e-9 m is a millionth of a millimetre.
EXACT_M = 1e-9


def test_point_does_not_depend_on_the_directions_length(rng):
    # The 2x2 system carries u.u and v.v: directions scaled by 0.3 and 4 (an un-normalised ray
    # from a caller) must give the same point as unit ones.
    pts = rng.uniform(-1, 1, (20, 3)) + [0, 0, 3]
    a, b = np.zeros((20, 3)), np.tile([0.12, 0.0, 0.0], (20, 1))
    ua = (pts - a) / np.linalg.norm(pts - a, axis=1, keepdims=True)
    ub = (pts - b) / np.linalg.norm(pts - b, axis=1, keepdims=True)
    out, gap = triangulate_midpoint(Rays(a, 0.3 * ua), Rays(b, 4.0 * ub))
    np.testing.assert_allclose(out, pts, atol=EXACT_M)
    np.testing.assert_allclose(gap, 0.0, atol=EXACT_M)


def test_a_point_behind_either_camera_alone_is_nan_and_near_points_are_kept():
    # Row 0: the rays' lines meet 0.5 m in front of both origins (s = t = 0.5 m, under one
    # metre: a "s > 1" slip would drop it). Row 1: they meet behind a only (s < 0 < t);
    # row 2: behind b only (t < 0 < s). Each alone must make the row NaN.
    a = np.zeros((3, 3))
    b = np.array([[0.5, 0.0, 0.0]] * 3)
    target = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, -0.5], [0.0, 0.0, 0.5]])
    ua = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    vb = target - b
    vb[2] *= -1.0  # b looks away from the meeting point
    vb /= np.linalg.norm(vb, axis=1, keepdims=True)
    out, gap = triangulate_midpoint(Rays(a, ua), Rays(b, vb))
    np.testing.assert_allclose(out[0], [0.0, 0.0, 0.5], atol=EXACT_M)
    assert gap[0] == pytest.approx(0.0, abs=EXACT_M)
    assert np.isnan(out[1:]).all() and np.isnan(gap[1:]).all()
