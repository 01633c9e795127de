"""One entry point for every matching engine: :func:`match`."""

from __future__ import annotations

import numpy as np

from sea3d.errors import ConfigError
from sea3d.stereo.gpu_sgm import GpuSgmConfig
from sea3d.stereo.types import DisparityResult, OpenCVSgbmConfig, SgmConfig

__all__ = ["EngineConfig", "make_config", "match"]

EngineConfig = SgmConfig | OpenCVSgbmConfig | GpuSgmConfig


def match(left: np.ndarray, right: np.ndarray, config: EngineConfig) -> DisparityResult:
    """Match a rectified pair with the engine that ``config`` selects.

    Args:
        left: ``(H, W)`` or ``(H, W, 3)`` RGB image, rectified.
        right: the right image, rectified, of the same shape.
        config: :class:`SgmConfig` (sea3d's SGM) or :class:`OpenCVSgbmConfig` (reference).

    Returns:
        :class:`DisparityResult` (disparity float32 px, NaN invalid; confidence; timings).

    Raises:
        StereoError: invalid images or disparity range.
        ConfigError: an unknown config type.
    """
    if isinstance(config, SgmConfig):
        from sea3d.stereo.sgm import match_sgm

        return match_sgm(left, right, config)
    if isinstance(config, OpenCVSgbmConfig):
        from sea3d.stereo.opencv_sgbm import match_opencv

        return match_opencv(left, right, config)
    if isinstance(config, GpuSgmConfig):
        from sea3d.stereo.gpu_sgm import match_gpu_sgm

        disparity, timings = match_gpu_sgm(left, right, config)
        confidence = np.isfinite(disparity).astype(np.float32)
        return DisparityResult(
            disparity_px=disparity, confidence=confidence, timings_s=timings, engine="sea3d-gpu"
        )
    raise ConfigError(f"unknown stereo engine config {type(config).__name__}")


def make_config(engine: str, max_disparity_px: int, **overrides: object) -> EngineConfig:
    """Build the default config of engine ``"sea3d"``, ``"sea3d-gpu"`` (CuPy, NVIDIA GPUs) or
    ``"opencv"`` (``opencv-hh``, ``opencv-3way`` select OpenCV modes) for a search range
    ``0..max_disparity_px``.

    Raises:
        ConfigError: unknown engine name or invalid values.
    """
    if engine == "sea3d":
        return SgmConfig(max_disparity_px=max_disparity_px, **overrides)  # type: ignore[arg-type]
    if engine == "sea3d-gpu":
        return GpuSgmConfig(max_disparity_px=max_disparity_px, **overrides)  # type: ignore[arg-type]
    modes = {
        "opencv": "sgbm",
        "opencv-sgbm": "sgbm",
        "opencv-hh": "hh",
        "opencv-3way": "sgbm_3way",
        "opencv-hh4": "hh4",
    }
    if engine in modes:
        kw = {"mode": modes[engine], **overrides}
        return OpenCVSgbmConfig(max_disparity_px=max_disparity_px, **kw)  # type: ignore[arg-type]
    raise ConfigError(
        f"unknown engine {engine!r}; choose sea3d, sea3d-gpu, opencv, opencv-hh, opencv-3way"
    )
