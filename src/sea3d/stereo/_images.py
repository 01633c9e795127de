"""Input checks and conversions shared by the engines (private)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import StereoError

__all__ = ["check_pair", "to_grey_float", "to_rgb_uint8"]


def check_pair(left: np.ndarray, right: np.ndarray, max_disparity_px: int) -> None:
    """Raise :class:`StereoError` unless ``left``/``right`` form a matchable rectified pair.

    Raises:
        StereoError: different shapes, not (H, W) or (H, W, 3), unsupported dtype, non-finite
            values, or a disparity range as wide as the image.
    """
    for name, img in (("left", left), ("right", right)):
        if not isinstance(img, np.ndarray):
            raise StereoError(f"{name} image must be a numpy array, got {type(img).__name__}")
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
            raise StereoError(f"{name} image must be (H, W) or (H, W, 3), got shape {img.shape}")
        if img.dtype not in (np.uint8, np.uint16, np.float32, np.float64):
            raise StereoError(f"{name} image dtype must be uint8, uint16 or float, got {img.dtype}")
        if img.shape[0] < 2 or img.shape[1] < 2:
            raise StereoError(f"{name} image is too small: {img.shape}")
        if img.dtype.kind == "f" and not np.isfinite(img).all():
            raise StereoError(f"{name} image holds non-finite values (NaN or inf)")
    if left.shape != right.shape:
        raise StereoError(
            f"left and right images differ in size: {left.shape} vs {right.shape}; "
            "a rectified pair must have equal shapes"
        )
    if max_disparity_px >= left.shape[1]:
        raise StereoError(
            f"disparity range 0..{max_disparity_px} px is as wide as the image "
            f"({left.shape[1]} px); lower max_disparity_px"
        )


def _scale(left: np.ndarray, right: np.ndarray) -> float:
    if left.dtype == np.uint8:
        return 1.0
    top = float(max(left.max(), right.max()))
    return 255.0 / top if top > 0 else 1.0


def to_grey_float(
    left: np.ndarray, right: np.ndarray
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Both images as (H, W) float32 grey on a common 0-255 scale (RGB weights of OpenCV)."""
    s = _scale(left, right)
    out = []
    for img in (left, right):
        f: NDArray[np.float32] = img.astype(np.float32) * np.float32(s)
        if f.ndim == 3:
            f = f[..., 0] if f.shape[2] == 1 else np.asarray(
                cv2.cvtColor(f, cv2.COLOR_RGB2GRAY), dtype=np.float32
            )
        out.append(np.ascontiguousarray(f, dtype=np.float32))
    return out[0], out[1]


def to_rgb_uint8(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both images as uint8 on a common 0-255 scale, keeping their channels."""
    s = _scale(left, right)
    out = []
    for img in (left, right):
        u = img if img.dtype == np.uint8 else np.clip(img * s + 0.5, 0, 255).astype(np.uint8)
        if u.ndim == 3 and u.shape[2] == 1:
            u = u[..., 0]
        out.append(np.ascontiguousarray(u))
    return out[0], out[1]
