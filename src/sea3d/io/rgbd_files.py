"""RGB-D frames from files: colour images and depth images in any common format.

Depth: integer images (16-bit PNG as Kinect, RealSense, OAK-D and 7-Scenes write them) hold
``metres * depth_scale`` (``depth_scale`` 1000 for millimetres, 5000 for the TUM RGB-D
benchmark), 0 invalid; float images (``.tif``/``.tiff``, ``.npy``, ``.pfm``) hold metres,
NaN or non-positive invalid. Returned depth is float32 metres, NaN invalid. 8-bit images are
refused: 256 levels are no metric depth (they are a visualisation, or a colour image given as
depth).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
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
    """A depth image as (H, W) float32 metres, NaN invalid (see the module docstring).

    Raises:
        ReconError: missing or unreadable file, several channels, 8-bit values, or a bad
            scale.
    """
    p = Path(path)
    if not depth_scale > 0:
        raise ReconError(f"depth scale must be > 0, got {depth_scale}")
    suffix = p.suffix.lower()
    if not p.is_file():
        raise ReconError(f"depth image {p} does not exist")
    if suffix == ".npy":
        try:
            d: NDArray[Any] = np.load(p, allow_pickle=False)
        except (OSError, ValueError) as err:
            raise ReconError(f"cannot read depth {p}: {err}") from err
    elif suffix == ".pfm":
        from sea3d.errors import StereoError
        from sea3d.io.depth_files import read_pfm

        try:
            d = read_pfm(p)
        except StereoError as err:
            raise ReconError(str(err)) from err
    else:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if img is None:
            raise ReconError(f"cannot read depth image {p}")
        d = img
    if d.ndim != 2:
        raise ReconError(f"{p}: a depth image has one channel, got shape {d.shape}")
    if d.dtype.itemsize == 1:
        raise ReconError(
            f"{p}: 8-bit depth ({d.dtype}) holds only 256 levels and is no metric depth; give "
            "16-bit depth (units of 1/depth_scale m) or float depth in metres"
        )
    if d.dtype.kind in "ui":
        z = d.astype(np.float32) / np.float32(depth_scale)
        z[d == 0] = np.nan
    else:
        z = np.asarray(d, np.float32).copy()
        with np.errstate(invalid="ignore"):
            z[~np.isfinite(z) | (z <= 0)] = np.nan
    return z
