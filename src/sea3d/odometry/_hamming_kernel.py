"""numba kernel of ratio-test matching of binary descriptors (brute-force Hamming)."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)


@numba.njit(cache=True, inline="always")
def _popcount(x: np.uint64) -> int:
    x = x - ((x >> np.uint64(1)) & _M1)
    x = (x & _M2) + ((x >> np.uint64(2)) & _M2)
    x = (x + (x >> np.uint64(4))) & _M4
    return int((x * _H01) >> np.uint64(56))


@numba.njit(cache=True)
def ratio_matches(
    query: NDArray[np.uint64], train: NDArray[np.uint64], ratio: float, max_distance: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Each query descriptor's nearest train descriptor by Hamming distance, kept when it is
    nearer than ``ratio`` times the second nearest and than ``max_distance`` bits.

    Args:
        query: (N, W) descriptors as 64-bit words.
        train: (M, W) descriptors as 64-bit words, ``M >= 2``.
        ratio: Lowe's ratio of the best to the second-best distance.
        max_distance: matches at this distance or more are dropped, bits.

    Returns:
        ``(query index, train index, distance)`` of the kept matches, in query order.
    """
    n, m, w = query.shape[0], train.shape[0], query.shape[1]
    qi = np.empty(n, np.int64)
    ti = np.empty(n, np.int64)
    dist = np.empty(n, np.int64)
    kept = 0
    for i in range(n):
        best, second, arg = 1 << 30, 1 << 30, -1
        for j in range(m):
            d = 0
            for k in range(w):
                d += _popcount(query[i, k] ^ train[j, k])
            if d < best:
                second = best
                best = d
                arg = j
            elif d < second:
                second = d
        if best < ratio * second and best < max_distance:
            qi[kept] = i
            ti[kept] = arg
            dist[kept] = best
            kept += 1
    return qi[:kept], ti[:kept], dist[:kept]
