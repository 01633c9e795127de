"""Geometry: SE(3) helpers, the camera protocol, the pinhole camera, rays and triangulation.

Maths only, no I/O. Conventions: ``docs/conventions.md``.
"""

from sea3d.geometry.camera import CameraModel, Rays
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.triangulate import triangulate_midpoint

__all__ = ["CameraModel", "PinholeCamera", "Rays", "triangulate_midpoint"]
