"""numba kernel of the water-model inversion: one pass per pixel through range tables."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, parallel=True)
def invert_u8(
    img: NDArray[np.uint8],
    z: NDArray[np.float32],
    decode: NDArray[np.float32],
    gain: NDArray[np.float32],
    offset: NDArray[np.float32],
    z_step: float,
    encode: NDArray[np.uint8],
    fallback: NDArray[np.float32],
) -> NDArray[np.uint8]:
    """``out = encode(max(decode(img) * gain[k] - offset[k], 0))`` with ``k`` the range bin
    of the pixel (``z / z_step``); pixels with ``z <= 0`` or NaN get ``decode(img) *
    fallback``. ``gain``, ``offset``: ``(K, 3)``; ``encode``: 65536 entries over [0, 1]."""
    h, w = z.shape
    n_k = gain.shape[0]
    out = np.empty((h, w, 3), np.uint8)
    for v in numba.prange(h):
        for u in range(w):
            zz = z[v, u]
            ok = zz > 0  # False for NaN
            k = 0
            if ok:
                k = int(zz / z_step + 0.5)
                if k >= n_k:
                    k = n_k - 1
            for c in range(3):
                x = decode[img[v, u, c]]
                y = x * gain[k, c] - offset[k, c] if ok else x * fallback[c]
                if y < 0.0:
                    y = 0.0
                elif y > 1.0:
                    y = 1.0
                out[v, u, c] = encode[int(y * 65535.0 + 0.5)]
    return out
