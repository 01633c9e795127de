"""Depth from the rectified left view resampled onto the raw left camera's own pixel grid.

Stereo depth lives on the rectified left grid (the virtual pinhole ``K_rect``, frame
``rect_left``); a consumer of the raw image (Sea-thru of the camera's picture, a raw-view
depth file) needs it on the raw grid. Each rectified pixel with depth is lifted to 3D
(``p_rect = z K_rect^-1 [u, v, 1]``), rotated into the raw left frame
(``p_left = R_rect_left_left^T p_rect``) and projected by the left camera (ports and lens
distortion included); each raw pixel takes the nearest point that lands on it, pixels no point
reaches are NaN.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import StereoError

__all__ = ["rectified_depth_to_raw"]


def rectified_depth_to_raw(
    depth_rect_m: np.ndarray,
    K_rect: np.ndarray,
    R_rect_left_left: np.ndarray,
    camera_left: object,
    *,
    quantity: Literal["depth", "range"] = "depth",
) -> NDArray[np.float32]:
    """Resample rectified-left depth onto the raw left grid.

    Args:
        depth_rect_m: ``(H, W)`` float depth along the rectified z axis, metres, NaN invalid.
        K_rect: ``3x3`` virtual pinhole of the rectified grid.
        R_rect_left_left: ``3x3`` rotation from the raw left frame to the rectified one.
        camera_left: the raw left camera (``project(points) -> (uv, valid)``, ``width``,
            ``height``).
        quantity: ``depth`` (z along the raw left optical axis) or ``range`` (distance from
            the camera centre).

    Returns:
        ``(height, width)`` float32 metres on the raw left grid, NaN where no point lands.

    Raises:
        StereoError: a non-2-D depth map or a singular ``K_rect``.
    """
    z = np.asarray(depth_rect_m, dtype=np.float64)
    if z.ndim != 2:
        raise StereoError(f"rectified depth must be (H, W), got shape {z.shape}")
    k = np.asarray(K_rect, dtype=np.float64)
    if k.shape != (3, 3) or abs(np.linalg.det(k)) < 1e-12:
        raise StereoError(f"K_rect must be an invertible 3x3 pinhole, got {k.tolist()}")
    v, u = np.nonzero(np.isfinite(z) & (z > 0))
    rays = np.linalg.solve(k, np.stack([u, v, np.ones_like(u)]).astype(np.float64))
    p_rect = (rays * z[v, u]).T
    p_left = p_rect @ np.asarray(R_rect_left_left, dtype=np.float64)  # R^T p, row-wise
    w, h = int(camera_left.width), int(camera_left.height)  # type: ignore[attr-defined]
    out = np.full(h * w, np.inf)
    if len(p_left):
        uv, vis = camera_left.project(p_left)  # type: ignore[attr-defined]
        ur, vr = np.rint(uv[:, 0]), np.rint(uv[:, 1])
        ok = vis & (ur >= 0) & (ur < w) & (vr >= 0) & (vr < h) & (p_left[:, 2] > 0)
        idx = (vr[ok] * w + ur[ok]).astype(np.int64)
        val = p_left[ok, 2] if quantity == "depth" else np.linalg.norm(p_left[ok], axis=1)
        np.minimum.at(out, idx, val)
    out[~np.isfinite(out)] = np.nan
    return out.reshape(h, w).astype(np.float32)
