"""Pictures of point clouds without a display: a z-buffered splat renderer in numpy."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
from sea3d.geometry.se3 import invert_T, transform_points

__all__ = ["render_points"]


def render_points(
    points: NDArray[np.float64],
    colors_rgb: NDArray[np.uint8],
    T_world_view: NDArray[np.float64],
    *,
    size_px: tuple[int, int] = (960, 540),
    fov_deg: float = 60.0,
    splat_px: int = 2,
    background_rgb: tuple[int, int, int] = (24, 24, 28),
) -> NDArray[np.uint8]:
    """Render coloured points from a virtual pinhole camera (OpenCV axes) with a z-buffer.

    Args:
        points: ``(N, 3)`` points in the world frame, metres.
        colors_rgb: ``(N, 3)`` uint8 colours.
        T_world_view: 4x4 pose of the virtual camera.
        size_px: ``(width, height)`` of the picture.
        fov_deg: horizontal field of view.
        splat_px: side of the square each point covers, pixels.
        background_rgb: colour where no point lands.

    Returns:
        ``(H, W, 3)`` uint8 RGB picture; nearer points hide farther ones.

    Raises:
        ReconError: mismatched points and colours.
    """
    if points.ndim != 2 or points.shape[1] != 3 or colors_rgb.shape != points.shape:
        raise ReconError(
            f"render_points needs points (N, 3) and colours (N, 3); got {points.shape}, "
            f"{colors_rgb.shape}"
        )
    w, h = size_px
    f = 0.5 * w / np.tan(np.deg2rad(fov_deg) / 2)
    p = transform_points(invert_T(T_world_view), points)
    front = p[:, 2] > 1e-3
    p, c = p[front], colors_rgb[front]
    u = np.rint(f * p[:, 0] / p[:, 2] + (w - 1) / 2).astype(np.int64)
    v = np.rint(f * p[:, 1] / p[:, 2] + (h - 1) / 2).astype(np.int64)
    offsets = [(du, dv) for dv in range(splat_px) for du in range(splat_px)]
    uu = np.concatenate([u + du for du, _ in offsets])
    vv = np.concatenate([v + dv for _, dv in offsets])
    zz = np.tile(p[:, 2], len(offsets))
    cc = np.tile(c, (len(offsets), 1))
    ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
    uu, vv, zz, cc = uu[ok], vv[ok], zz[ok], cc[ok]
    # z-buffer: for each pixel keep the nearest point (sort by pixel, then depth).
    pix = vv * w + uu
    order = np.lexsort((zz, pix))
    first = np.unique(pix[order], return_index=True)[1]
    keep = order[first]
    img = np.empty((h, w, 3), np.uint8)
    img[:] = background_rgb
    img[vv[keep], uu[keep]] = cc[keep]
    return img
