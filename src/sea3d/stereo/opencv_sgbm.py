"""OpenCV's StereoSGBM as sea3d's reference engine, descaled and with NaN for invalid.

OpenCV returns int16 disparities in 1/16 pixel (fixed point, 4 fractional bits) and marks
invalid pixels with ``(minDisparity - 1) * 16``; both are undone here, so the result is float32
pixels like every other engine's. ``numDisparities`` must be a multiple of 16: the range
``0..max_disparity_px`` is widened to the next multiple.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from sea3d.errors import StereoError
from sea3d.stereo._images import check_pair, to_rgb_uint8
from sea3d.stereo.types import DisparityResult, OpenCVSgbmConfig

__all__ = ["create_sgbm", "match_opencv"]

_MODES = {
    "sgbm": cv2.StereoSGBM_MODE_SGBM,
    "hh": cv2.StereoSGBM_MODE_HH,
    "sgbm_3way": cv2.StereoSGBM_MODE_SGBM_3WAY,
    "hh4": cv2.StereoSGBM_MODE_HH4,
}


def create_sgbm(config: OpenCVSgbmConfig, channels: int) -> cv2.StereoSGBM:
    """A configured ``cv2.StereoSGBM`` with ``P1 = 8*C*w^2`` and ``P2 = 32*C*w^2``."""
    w = config.block_size_px
    return cv2.StereoSGBM_create(  # type: ignore[attr-defined]
        minDisparity=0,
        numDisparities=config.num_disparities,
        blockSize=w,
        P1=8 * channels * w * w,
        P2=32 * channels * w * w,
        disp12MaxDiff=config.disp12_max_diff_px,
        preFilterCap=config.pre_filter_cap,
        uniquenessRatio=config.uniqueness_ratio,
        speckleWindowSize=config.speckle_window_px,
        speckleRange=config.speckle_range_px,
        mode=_MODES[config.mode],
    )


def match_opencv(left: np.ndarray, right: np.ndarray, config: OpenCVSgbmConfig) -> DisparityResult:
    """Match a rectified pair with OpenCV's StereoSGBM.

    Args:
        left, right: ``(H, W)`` or ``(H, W, 3)`` RGB, uint8/uint16/float, same shape.
        config: OpenCV settings.

    Returns:
        :class:`DisparityResult`: disparity (H, W) float32 px (value / 16, NaN invalid),
        confidence 1 on valid pixels, ``match_s``.

    Raises:
        StereoError: bad input, or numDisparities not smaller than the image width.
    """
    check_pair(left, right, config.max_disparity_px)
    if config.num_disparities >= left.shape[1]:
        raise StereoError(
            f"OpenCV numDisparities {config.num_disparities} (max_disparity_px "
            f"{config.max_disparity_px} rounded up to a multiple of 16) must be below the image "
            f"width {left.shape[1]}"
        )
    t0 = time.perf_counter()
    a, b = to_rgb_uint8(left, right)
    if a.ndim == 3:
        if config.use_color:
            a, b = cv2.cvtColor(a, cv2.COLOR_RGB2BGR), cv2.cvtColor(b, cv2.COLOR_RGB2BGR)
        else:
            a, b = cv2.cvtColor(a, cv2.COLOR_RGB2GRAY), cv2.cvtColor(b, cv2.COLOR_RGB2GRAY)
    channels = 3 if a.ndim == 3 else 1
    matcher = create_sgbm(config, channels)
    t1 = time.perf_counter()
    raw = matcher.compute(a, b)
    t2 = time.perf_counter()
    disp = raw.astype(np.float32) / np.float32(16.0)  # OpenCV fixed point: 4 fractional bits
    disp[raw < 0] = np.nan  # invalid is (minDisparity - 1) * 16 = -16
    conf = np.isfinite(disp).astype(np.float32)
    t3 = time.perf_counter()
    timings = {"compute_s": t2 - t1, "match_s": t3 - t0}
    return DisparityResult(disparity_px=disp, confidence=conf, timings_s=timings, engine="opencv")
