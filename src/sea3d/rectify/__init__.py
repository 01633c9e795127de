"""Rectification maps for pinhole and refractive (dome/flat-port) stereo rigs."""

from sea3d.rectify.maps import (
    RectifyMaps,
    VirtualPinholeReport,
    closest_point_of_rays,
    fit_virtual_pinhole,
    rectify_images,
    rectify_rig,
)
from sea3d.rectify.virtual import VirtualPinholeMaps, virtual_pinhole_maps

__all__ = [
    "RectifyMaps",
    "VirtualPinholeMaps",
    "VirtualPinholeReport",
    "closest_point_of_rays",
    "fit_virtual_pinhole",
    "rectify_images",
    "rectify_rig",
    "virtual_pinhole_maps",
]
