"""The colour images of RGB-D frames, in any common format (their depth images are read by
the one depth reader, :func:`sea3d.io.depth_files.read_depth`, with the frames'
``depth_scale``)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError

__all__ = ["read_color"]


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
