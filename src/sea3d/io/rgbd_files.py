"""RGB-D frames from files: colour images and depth images in any common format.

Depth: integer images (16-bit PNG as Kinect, RealSense, OAK-D and 7-Scenes write them) hold
``metres * depth_scale`` (``depth_scale`` 1000 for millimetres, 5000 for the TUM RGB-D
benchmark), 0 invalid; float images (``.tif``/``.tiff``, ``.npy``, ``.pfm``) hold metres,
NaN or non-positive invalid. Returned depth is float32 metres, NaN invalid. 8-bit images are
refused: 256 levels are no metric depth (they are a visualisation, or a colour image given as
depth). The one depth reader is :func:`sea3d.io.depth_files.read_depth`; this module gives it
the frames' scale and raises ``ReconError``.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError, StereoError
from sea3d.io import depth_files
from sea3d.io.image_files import natural_key

__all__ = ["natural_key", "read_color", "read_depth"]


def read_color(path: str | os.PathLike[str]) -> NDArray[np.uint8]:
    """An image as (H, W, 3) uint8 RGB (grey expanded, 16-bit scaled down, alpha dropped).

    Raises:
        ReconError: missing or unreadable file.
    """
    p = Path(path)
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED) if p.is_file() else None
    if img is None:
        raise ReconError(f"cannot read colour image {p}")
    if img.dtype == np.uint16:
        img = (np.asarray(img, np.uint16) // 256).astype(np.uint8)
    if img.dtype != np.uint8:
        raise ReconError(f"{p}: colour images must be 8 or 16 bit, got {img.dtype}")
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=2)
    if img.shape[2] == 4:
        return np.ascontiguousarray(cv2.cvtColor(img, cv2.COLOR_BGRA2RGB))
    return np.ascontiguousarray(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))


def read_depth(path: str | os.PathLike[str], depth_scale: float = 1000.0) -> NDArray[np.float32]:
    """A depth image as (H, W) float32 metres, NaN invalid: :func:`sea3d.io.depth_files.read_depth`
    with the RGB-D frames' ``depth_scale`` (integer units per metre) and their error class.

    Raises:
        ReconError: missing or unreadable file, several channels, 8-bit values, or a bad
            scale.
    """
    try:
        return depth_files.read_depth(path, depth_scale=depth_scale)
    except StereoError as err:
        raise ReconError(str(err)) from err
