"""Rectification maps for pinhole and refractive (dome/flat-port) stereo rigs."""

from sea3d.rectify.maps import (
    RectifyMaps,
    VirtualPinholeReport,
    fit_virtual_pinhole,
    rectify_images,
    rectify_rig,
)

__all__ = [
    "RectifyMaps",
    "VirtualPinholeReport",
    "fit_virtual_pinhole",
    "rectify_images",
    "rectify_rig",
]
