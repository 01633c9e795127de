"""Caustic (sunlight flicker) removal over several registered frames.

In shallow water the sunlight refracted by surface waves paints moving bright ridges on the
floor. They move from frame to frame while the floor does not, so the floor as seen by the
neighbouring frames, registered into the frame to clean, shows what it looks like without this
frame's ridges (Gracias, Negahdaripour, Neumann, Prados and Garcia, "A motion compensated
filtering approach to remove sunlight flicker in shallow water images", OCEANS 2008, and
Shihavuddin, Gracias, Garcia et al. 2012 for the ratio formulation). Here:

1. every neighbour ``j`` is warped into the reference frame with the reference depth and the
   poses: each reference pixel is unprojected to its 3D point (the camera model's ray at the
   given depth), moved by ``T_j_ref`` and projected into frame ``j`` (bilinear sampling);
2. on linear luminance ``Y``, the caustic-free estimate is the per-pixel median over the
   reference and its registered neighbours;
3. the caustic field is the low-passed ratio ``C = G_sigma * (Y_ref / median)`` (Gaussian of
   ``sigma_px``, normalised over the pixels where the ratio is defined; a pixel seen by fewer
   than ``min_frames`` frames gets ``C = 1``), clipped to ``[1 / max_ratio, max_ratio]``;
4. the reference frame's linear RGB is divided by ``C``.

The ratio treats the whole signal as sunlit; lamp light and backscatter are not modulated by
caustics, so strong backscatter makes the correction a little too strong. Poses are
``T_world_cam`` of each frame (camera frame to world), depth is the reference frame's float32
depth in metres (z along the camera axis, NaN invalid).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32, F64
from sea3d.enhance._image import (
    Encoding,
    as_unit_float,
    from_linear,
    from_unit_float,
    luminance,
    require_rgb,
    to_linear,
)
from sea3d.errors import EnhanceError
from sea3d.geometry.camera import CameraModel

__all__ = ["CausticConfig", "CausticResult", "points_from_depth", "remove_caustics", "warp_to"]


@dataclass(frozen=True, kw_only=True)
class CausticConfig:
    """Settings of :func:`remove_caustics`."""

    sigma_px: float = 1.0
    """Gaussian low-pass of the ratio, pixels (ridges are thin: keep it small)."""
    min_frames: int = 3
    """Least number of frames (reference included) that must see a pixel to correct it."""
    max_ratio: float = 4.0
    """Largest correction factor either way."""
    encoding: Encoding = "srgb"
    """Encoding of the frames: ``srgb`` or ``linear``."""

    def __post_init__(self) -> None:
        if not (self.sigma_px >= 0 and self.min_frames >= 2 and self.max_ratio > 1):
            raise EnhanceError("need sigma_px >= 0, min_frames >= 2 and max_ratio > 1")


@dataclass(frozen=True, kw_only=True, eq=False)
class CausticResult:
    """Caustic removal of one frame.

    Attributes:
        image: the corrected frame, input dtype.
        caustic_map: ``(H, W)`` float32 estimated caustic factor (1 = none).
        frames_seen: ``(H, W)`` int32, frames (reference included) that saw each pixel.
    """

    image: np.ndarray
    caustic_map: F32
    frames_seen: NDArray[np.int32]


def points_from_depth(camera: CameraModel, depth_m: np.ndarray) -> tuple[F64, NDArray[np.bool_]]:
    """3D points of every pixel at its depth, in the camera frame.

    Each pixel centre's ray (``camera.unproject``, so port cameras work too) is followed to the
    point whose camera-frame z equals the depth.

    Returns:
        ``(H * W, 3)`` float64 points (NaN where invalid) and the ``(H * W,)`` valid mask.

    Raises:
        EnhanceError: depth of another size than the camera's image.
    """
    z = np.asarray(depth_m, dtype=np.float64)
    if z.shape != (camera.height, camera.width):
        raise EnhanceError(
            f"depth map is {z.shape[1]}x{z.shape[0]} but the camera is "
            f"{camera.width}x{camera.height}"
        )
    vv, uu = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    rays = camera.unproject(np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64))
    zr = z.ravel()
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (zr - rays.origins[:, 2]) / rays.directions[:, 2]
        ok = np.isfinite(zr) & (zr > 0) & np.isfinite(t) & (t > 0) & rays.valid
    pts = rays.origins + t[:, None] * rays.directions
    pts[~ok] = np.nan
    return pts, ok


def warp_to(
    image: np.ndarray,
    camera: CameraModel,
    points_ref: F64,
    valid_ref: NDArray[np.bool_],
    T_src_ref: F64,
    shape: tuple[int, int],
) -> tuple[F32, NDArray[np.bool_]]:
    """Sample a source frame at the projections of the reference frame's 3D points.

    Args:
        image: ``(H, W)`` or ``(H, W, C)`` float32 source frame.
        camera: the source camera model.
        points_ref: ``(N, 3)`` points in the reference camera frame (:func:`points_from_depth`).
        valid_ref: ``(N,)`` bool.
        T_src_ref: ``(4, 4)`` reference camera frame to source camera frame.
        shape: ``(H, W)`` of the reference frame (``N = H * W``).

    Returns:
        The warped image in the reference grid and the mask of pixels that land inside the
        source image.
    """
    h, w = shape
    p = points_ref @ T_src_ref[:3, :3].T + T_src_ref[:3, 3]
    uv = np.full((h * w, 2), -1e6)
    ok = valid_ref & (p[:, 2] > 0)
    if ok.any():
        uv_ok, vis = camera.project(p[ok])
        uv[ok] = np.where(vis[:, None], uv_ok, -1e6)
    mx = uv[:, 0].reshape(h, w).astype(np.float32)
    my = uv[:, 1].reshape(h, w).astype(np.float32)
    src_h, src_w = image.shape[:2]
    inside = (mx >= 0) & (mx <= src_w - 1) & (my >= 0) & (my <= src_h - 1)
    out = cv2.remap(
        np.asarray(image, dtype=np.float32), mx, my, cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0,
    )
    return np.asarray(out, dtype=np.float32), inside


def remove_caustics(
    frames: Sequence[np.ndarray],
    reference_index: int,
    depth_ref_m: np.ndarray,
    camera: CameraModel,
    T_world_cam: Sequence[np.ndarray],
    config: CausticConfig | None = None,
) -> CausticResult:
    """Remove caustics from one frame with the help of its registered neighbours.

    Args:
        frames: ``(H, W, 3)`` RGB frames of one camera (same size and dtype).
        reference_index: which frame to clean.
        depth_ref_m: ``(H, W)`` depth of the reference frame, metres, NaN invalid.
        camera: the camera model of all frames.
        T_world_cam: ``(4, 4)`` pose of each frame.
        config: :class:`CausticConfig`.

    Returns:
        :class:`CausticResult`.

    Raises:
        EnhanceError: fewer than two frames, mismatched sizes or counts, a bad index, depth of
            another size, or a depth map with no valid pixel.
    """
    config = config or CausticConfig()
    if len(frames) < 2 or len(frames) != len(T_world_cam):
        raise EnhanceError(
            f"need at least two frames and one pose per frame, got {len(frames)} frames and "
            f"{len(T_world_cam)} poses"
        )
    if not 0 <= reference_index < len(frames):
        raise EnhanceError(f"reference_index {reference_index} outside 0..{len(frames) - 1}")
    f_ref, dtype = as_unit_float(frames[reference_index], "reference frame")
    require_rgb(f_ref, "caustic removal")
    h, w = f_ref.shape[:2]
    pts, ok = points_from_depth(camera, depth_ref_m)
    if not ok.any():
        raise EnhanceError("reference depth has no valid pixel; cannot register the frames")
    lin_ref = to_linear(f_ref, config.encoding)
    y_ref = luminance(lin_ref)
    T_world_ref = np.asarray(T_world_cam[reference_index], dtype=np.float64)
    stack = [np.where(ok.reshape(h, w), y_ref, np.nan)]
    for j, frame in enumerate(frames):
        if j == reference_index:
            continue
        f_j, _ = as_unit_float(frame, f"frame {j}")
        if f_j.shape != f_ref.shape:
            raise EnhanceError(f"frame {j} is {f_j.shape}, the reference is {f_ref.shape}")
        y_j = luminance(to_linear(f_j, config.encoding))
        T_j_ref: F64 = np.linalg.inv(np.asarray(T_world_cam[j], dtype=np.float64)) @ T_world_ref
        warped, inside = warp_to(y_j, camera, pts, ok, T_j_ref, (h, w))
        stack.append(np.where(inside, warped, np.nan))
    ys = np.stack(stack, axis=0)
    seen = np.sum(np.isfinite(ys), axis=0).astype(np.int32)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pixels no frame saw: NaN, handled
        med = np.nanmedian(ys, axis=0)
        ratio = y_ref / med
    good = (seen >= config.min_frames) & np.isfinite(ratio) & (med > 1e-4)
    r: F32 = np.where(good, ratio, 0.0).astype(np.float32)
    wgt: F32 = good.astype(np.float32)
    if config.sigma_px > 0:
        r = np.asarray(
            cv2.GaussianBlur(r, (0, 0), config.sigma_px, borderType=cv2.BORDER_REFLECT),
            dtype=np.float32,
        )
        wgt = np.asarray(
            cv2.GaussianBlur(wgt, (0, 0), config.sigma_px, borderType=cv2.BORDER_REFLECT),
            dtype=np.float32,
        )
    with np.errstate(all="ignore"):
        c = np.where(good & (wgt > 1e-3), r / wgt, 1.0)
    c = np.clip(c, 1.0 / config.max_ratio, config.max_ratio).astype(np.float32)
    out = lin_ref / c[..., None]
    return CausticResult(
        image=from_unit_float(from_linear(out, config.encoding), dtype),
        caustic_map=c,
        frames_seen=seen,
    )
