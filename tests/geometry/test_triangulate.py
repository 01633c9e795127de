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
