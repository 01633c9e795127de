"""Refraction: Snell's law, dome and flat ports, and refractive camera models."""

from sea3d.refraction.ports import DomePort, DomePortCamera, FlatPort, FlatPortCamera
from sea3d.refraction.snell import refract

__all__ = ["DomePort", "DomePortCamera", "FlatPort", "FlatPortCamera", "refract"]
