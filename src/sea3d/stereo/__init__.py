"""Stereo matching: sea3d's own SGM, the OpenCV reference, post-filters, disparity files.

Start with :func:`match` and a config (:class:`SgmConfig` or :class:`OpenCVSgbmConfig`).
Heavy modules (numba kernels, OpenCV) load on first use.
"""

from sea3d.stereo.engine import EngineConfig, make_config, match
from sea3d.stereo.types import DisparityResult, OpenCVSgbmConfig, SgmConfig

__all__ = [
    "DisparityResult",
    "EngineConfig",
    "OpenCVSgbmConfig",
    "SgmConfig",
    "make_config",
    "match",
]
