"""Random textures for synthetic views: a seeded generator in, a float32 image out.

Stereo matching, feature tracking and image metrics all need surfaces with structure at the
scale they look at. Each test composes the same few pieces: uniform noise blurred to a grain
(``smooth_noise``), stretched to [0, 1] (``stretch``), and bilinear blobs of one value per
cell (``coarse_noise``). Values are drawn in one fixed order, so a test's texture depends only
on its generator's seed.
"""

from __future__ import annotations

import cv2
import numpy as np

from sea3d.geometry.camera import CameraModel


def smooth_noise(rng: np.random.Generator, shape: tuple[int, ...], sigma_px: float,
                 scale: float = 1.0) -> np.ndarray:
    """Uniform noise in [0, ``scale``) blurred by a Gaussian of ``sigma_px`` pixels.

    ``shape`` is ``(H, W)`` or ``(H, W, C)`` (each channel blurred on its own); float32.
    """
    noise = rng.random(shape).astype(np.float32)
    if scale != 1.0:
        noise = noise * np.float32(scale)
    return cv2.GaussianBlur(noise, (0, 0), sigma_px)


def stretch(img: np.ndarray) -> np.ndarray:
    """``img`` mapped linearly onto [0, 1] (its minimum to 0, its maximum to 1)."""
    return (img - img.min()) / (img.max() - img.min())


def coarse_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: int,
                 scale: float = 1.0) -> np.ndarray:
    """Uniform noise in [0, ``scale``) drawn once per ``cell_px`` square, bilinearly resized to
    ``shape`` ``(H, W)``; float32."""
    h, w = shape
    cells = rng.random((h // cell_px, w // cell_px)).astype(np.float32)
    if scale != 1.0:
        cells = cells * np.float32(scale)
    return cv2.resize(cells, (w, h))


def grain_over_blobs(rng: np.random.Generator, n: int = 1024) -> np.ndarray:
    """An ``(n, n)`` texture of fine grain (70 %) over 32 px blobs (30 %), float32 0-255."""
    base = stretch(smooth_noise(rng, (n, n), 1.5))
    return (255 * (0.7 * base + 0.3 * coarse_noise(rng, (n, n), 32))).astype(np.float32)


def textured_plane_view(cam: CameraModel, T_left_cam: np.ndarray, depth_m: float,
                        tex: np.ndarray, half_extent_m: float) -> np.ndarray:
    """Ray-cast a camera's uint8 image of the plane z = ``depth_m`` (left frame, metres) that
    carries the square texture ``tex`` over ``[-half_extent_m, half_extent_m]`` in x and y."""
    h, w = cam.height, cam.width
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = cam.unproject(np.column_stack([uu.ravel(), vv.ravel()]))
    o = rays.origins @ T_left_cam[:3, :3].T + T_left_cam[:3, 3]
    dvec = rays.directions @ T_left_cam[:3, :3].T
    s = (depth_m - o[:, 2]) / dvec[:, 2]
    x = o[:, 0] + s * dvec[:, 0]
    y = o[:, 1] + s * dvec[:, 1]
    n = tex.shape[0]
    map_x = ((x / half_extent_m + 1) * 0.5 * (n - 1)).reshape(h, w).astype(np.float32)
    map_y = ((y / half_extent_m + 1) * 0.5 * (n - 1)).reshape(h, w).astype(np.float32)
    img = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return np.clip(img, 0, 255).astype(np.uint8)
