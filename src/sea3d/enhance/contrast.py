"""Local contrast: CLAHE on CIE L* (lightness only, so hue and chroma are kept).

Contrast-limited adaptive histogram equalisation (Zuiderveld, Graphics Gems IV, 1994) as
OpenCV implements it (``cv2.createCLAHE``), applied to the L* channel of CIELAB (D65, from sRGB):
the image goes to L*a*b*, L* is quantised to 256 levels (OpenCV's clip limit is defined for a
256-bin histogram), equalised per tile with the clip limit, and the image goes back to RGB with
its a*, b* unchanged. One-channel images are equalised directly.
"""

from __future__ import annotations

import cv2
import numpy as np

from sea3d.enhance._image import as_unit_float, from_unit_float
from sea3d.errors import EnhanceError

__all__ = ["clahe"]


def clahe(
    image: np.ndarray, *, clip_limit: float = 2.0, tile_grid: tuple[int, int] = (8, 8)
) -> np.ndarray:
    """CLAHE on L* of an sRGB image (or on the values of a grey image).

    Args:
        image: ``(H, W, 3)`` RGB or ``(H, W)`` grey, ``uint8``/``uint16``/float ``[0, 1]``.
        clip_limit: OpenCV's clip limit, relative to the mean histogram bin (2 is OpenCV's
            usual choice; 1 leaves the image nearly unchanged).
        tile_grid: tiles along (x, y).

    Returns:
        The equalised image, same dtype and shape.

    Raises:
        EnhanceError: bad image, ``clip_limit <= 0`` or a tile grid below 1x1.
    """
    if not clip_limit > 0:
        raise EnhanceError(f"clip_limit must be > 0, got {clip_limit}")
    tx, ty = (int(v) for v in tile_grid)
    if tx < 1 or ty < 1:
        raise EnhanceError(f"tile_grid must be at least 1x1, got {tile_grid}")
    img, dtype = as_unit_float(image)
    eq = cv2.createCLAHE(clipLimit=float(clip_limit), tileGridSize=(tx, ty))
    if img.ndim == 2:
        out8 = eq.apply((np.clip(img, 0, 1) * 255.0 + 0.5).astype(np.uint8))
        return from_unit_float(out8.astype(np.float32) / np.float32(255.0), dtype)
    lab = cv2.cvtColor(np.clip(img, 0.0, 1.0), cv2.COLOR_RGB2Lab)  # L* in [0, 100]
    l8 = np.clip(lab[..., 0] * np.float32(2.55) + np.float32(0.5), 0, 255).astype(np.uint8)
    lab[..., 0] = eq.apply(l8).astype(np.float32) * np.float32(100.0 / 255.0)
    rgb = cv2.cvtColor(lab, cv2.COLOR_Lab2RGB)
    return from_unit_float(rgb, dtype)
