"""Sea-thru's range for one image (``sea3d enhance IMAGE --method seathru --depth D``): the
depth map read, brought onto the image's own pixel grid, and turned into range along each
pixel's line of sight; the caller reads the image and writes the result."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import EnhanceError

__all__ = ["range_for_image"]

log = logging.getLogger(__name__)


def _range_from_rectified(depth_path: Path, depth: NDArray[np.floating], shape: tuple[int, int],
                          image_name: str, rig_path: str | os.PathLike[str] | None,
                          depth_range_m: tuple[float | None, float | None],
                          ) -> NDArray[np.floating] | None:
    """Range on the raw image's grid when the depth's grid sidecar says it lives on the
    rectified left view (resampled with the rig; refused without it or with another rig).
    None when the depth is on the raw grid (or its sidecar says nothing)."""
    from sea3d.io.depth_files import read_depth_grid, rig_identity

    grid = read_depth_grid(depth_path)
    if grid is None or grid.kind == "raw-left":
        if grid is not None and (grid.width_px, grid.height_px) != (shape[1], shape[0]):
            raise EnhanceError(f"depth {depth_path} lives on the {grid.describe()} grid but "
                               f"image {image_name} is {shape[1]}x{shape[0]}")
        return None
    if rig_path is None:
        raise EnhanceError(
            f"depth {depth_path} lives on the {grid.describe()} grid, not on the raw image's "
            "pixels: give the rig to resample it; write raw-view depth (the raw grid) with "
            "sea3d depth"
        )
    from sea3d.io.rig_file import load_rig, rig_to_yaml
    from sea3d.rectify.depth_grid import rectified_depth_to_raw
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    rig = load_rig(rig_path)
    if grid.rig_id and grid.rig_id != rig_identity(rig_to_yaml(rig)):
        raise EnhanceError(f"depth {depth_path} came from another rig than {rig_path}")
    if (rig.width, rig.height) != (shape[1], shape[0]):
        raise EnhanceError(f"rig {rig_path} is {rig.width}x{rig.height} but image "
                           f"{image_name} is {shape[1]}x{shape[0]}")
    # the rectification sea3d depth uses with this rig and depth range (fitted over the
    # rig's own range where none is given)
    near, far = depth_range_m
    maps = StereoDepth(rig, DepthConfig(min_depth_m=near, max_depth_m=far)).maps
    K = np.asarray(grid.K, dtype=np.float64)
    return rectified_depth_to_raw(depth, K, maps.R_rect_left_left, rig.left, quantity="range")


def range_for_image(
    depth_path: str | os.PathLike[str],
    shape: tuple[int, int],
    *,
    image_name: str,
    rig_path: str | os.PathLike[str] | None = None,
    is_range: bool = False,
    focal_px: float | None = None,
    depth_range_m: tuple[float | None, float | None] = (None, None),
) -> NDArray[np.floating]:
    """The (H, W) range map, metres along each pixel's line of sight, of an image from a depth
    file (float32 m ``.npy``/``.tiff`` or 16-bit mm PNG, with its grid sidecar if any).

    Depth on the rectified left grid is resampled onto the raw image with the rig; depth on
    the image's grid becomes range with the rig's intrinsics, else a centred pinhole of
    ``focal_px``, else it is used as range as it is (with a warning: too short by 1/cos of the
    off-axis angle).

    Args:
        depth_path: the depth file.
        shape: the image's ``(H, W)``.
        image_name: the image, for messages.
        rig_path: the rig file (intrinsics, and the rectification of rectified-grid depth).
        is_range: the file holds range already.
        focal_px: the focal length of a centred pinhole when there is no rig.
        depth_range_m: the depth range ``sea3d depth`` was given (None: from the rig), for
            the rectification of rectified-grid depth.

    Raises:
        EnhanceError: depth on another grid or from another rig, sizes that disagree;
            StereoError from reading the depth file.
    """
    from sea3d.enhance.seathru import depth_to_range
    from sea3d.io.depth_files import read_depth

    p = Path(depth_path)
    depth = read_depth(p)  # names the file in its errors
    h, w = shape
    from_rect = _range_from_rectified(p, depth, (h, w), image_name, rig_path, depth_range_m)
    if from_rect is not None:
        return from_rect
    if depth.shape != (h, w):
        raise EnhanceError(
            f"depth {depth_path} is {depth.shape[1]}x{depth.shape[0]} but image {image_name} "
            f"is {w}x{h}; the depth must be in the image's pixel grid"
        )
    if is_range:
        return depth
    if rig_path is not None:
        from sea3d.io.rig_file import load_rig

        pin = load_rig(rig_path).left.lens
        if (pin.width, pin.height) != (w, h):
            raise EnhanceError(
                f"rig {rig_path} is {pin.width}x{pin.height} but image {image_name} is {w}x{h}"
            )
        return depth_to_range(depth, pin.fx, pin.fy, pin.cx, pin.cy)
    if focal_px is not None:
        return depth_to_range(depth, focal_px, focal_px, (w - 1) / 2, (h - 1) / 2)
    log.warning(
        "no intrinsics (neither a rig nor focal_px): the depth is used as range along the line "
        "of sight (too short by 1/cos of the off-axis angle)"
    )
    return depth
