"""Array type aliases shared by every module (one place, so they cannot drift apart).

Shapes, frames and units are given where each array is used (docstrings); these aliases say
only the dtype.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["F32", "F64", "I64", "U8", "BoolArray", "FloatArray"]

F64 = NDArray[np.float64]
"""float64 array (points, rays, transforms, metres)."""
F32 = NDArray[np.float32]
"""float32 array (depth and disparity maps, remap tables)."""
FloatArray = F64
"""Another name of :data:`F64` (used by the geometry and refraction modules)."""
BoolArray = NDArray[np.bool_]
"""bool array (masks)."""
I64 = NDArray[np.int64]
"""int64 array (nanosecond stamps, indices)."""
U8 = NDArray[np.uint8]
"""uint8 array (8-bit images)."""
