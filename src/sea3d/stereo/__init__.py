"""Stereo matching: sea3d's own SGM, the OpenCV reference, post-filters, disparity files.

Start with :func:`match` and a config (:class:`SgmConfig` or :class:`OpenCVSgbmConfig`).
Heavy modules (numba kernels, OpenCV) load on first use.
"""

import os

# numba's OpenMP threads spin between parallel regions by default, which cost the SGM a third
# more CPU time than the work itself (measured at 1080p); let idle threads sleep instead
# unless the user chose otherwise. Must be set before numba starts its thread pool.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

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
