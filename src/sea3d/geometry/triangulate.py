"""Triangulation of ray pairs."""

from __future__ import annotations

import numpy as np

from sea3d._typing import FloatArray
from sea3d.errors import GeometryError
from sea3d.geometry.camera import Rays

__all__ = ["triangulate_midpoint"]


def triangulate_midpoint(rays_a: Rays, rays_b: Rays) -> tuple[FloatArray, FloatArray]:
    """Closest-point midpoint of each pair of rays (both in the same frame).

    For rays ``a + s u`` and ``b + t v`` the parameters minimising the distance solve a 2x2
    linear system; the point returned is the midpoint of the two closest points, and the gap
    between them is a quality measure (0 for rays that truly intersect).

    Args:
        rays_a: :class:`Rays` of length N in one frame (metres, unit directions).
        rays_b: :class:`Rays` of the same length N in the same frame.

    Returns:
        ``points`` ``(N, 3)`` metres and ``gap_m`` ``(N,)``. Rows are NaN where the rays are
        parallel, a ray is invalid, or the closest point lies behind either ray's origin.

    Raises:
        GeometryError: the bundles differ in length.
    """
    if len(rays_a) != len(rays_b):
        raise GeometryError(f"ray bundles differ in length: {len(rays_a)} and {len(rays_b)}")
    a, u = rays_a.origins, rays_a.directions
    b, v = rays_b.origins, rays_b.directions
    w = a - b
    uu = np.einsum("ij,ij->i", u, u)
    vv = np.einsum("ij,ij->i", v, v)
    uv = np.einsum("ij,ij->i", u, v)
    uw = np.einsum("ij,ij->i", u, w)
    vw = np.einsum("ij,ij->i", v, w)
    denom = uu * vv - uv * uv
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (uv * vw - vv * uw) / denom
        t = (uu * vw - uv * uw) / denom
    pa = a + s[:, None] * u
    pb = b + t[:, None] * v
    points = 0.5 * (pa + pb)
    gap = np.linalg.norm(pa - pb, axis=1)
    bad = ~(np.abs(denom) > 1e-15) | ~(s > 0) | ~(t > 0)
    points[bad] = np.nan
    gap[bad] = np.nan
    return points, gap
