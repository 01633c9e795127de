"""Procedural noise evaluated at 3D points: the fine texture detail stereo matching needs.

Textures in the simulator are functions of position (metres), not images, so they have detail at
every scale the camera can resolve and never stretch on a height field. The noise is lattice
value noise (a hashed random value at every integer lattice point, blended with a quintic fade),
summed over octaves (fractional Brownian motion). Octaves finer than the pixel footprint are faded
out, a cheap band limit that keeps far-away sand from aliasing into salt and pepper.

The kernels are numba-compiled and run in parallel over points.
"""

from __future__ import annotations

import warnings

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["fbm", "rigid_transform", "value_noise"]

# numba falls back from TBB to OpenMP by itself when the installed TBB is too old; its warning
# about that says nothing actionable to a sea3d user.
warnings.filterwarnings(
    "ignore", message="The TBB threading layer requires", category=numba.NumbaWarning
)

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)


@numba.njit(cache=True, inline="always")
def _hash01(ix: np.int64, iy: np.int64, iz: np.int64, seed: np.uint64) -> float:
    # splitmix64-style mixing of the three lattice coordinates and the seed; uniform in [0, 1).
    h = np.uint64(ix) * _M1 ^ (np.uint64(iy) * _M2) ^ (np.uint64(iz) * _M3) ^ seed
    h ^= h >> np.uint64(30)
    h *= _M2
    h ^= h >> np.uint64(27)
    h *= _M3
    h ^= h >> np.uint64(31)
    return float(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, inline="always")
def _fade(t: float) -> float:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@numba.njit(cache=True)
def _noise1(x: float, y: float, z: float, seed: np.uint64) -> float:
    fx = np.floor(x)
    fy = np.floor(y)
    fz = np.floor(z)
    ix = np.int64(fx)
    iy = np.int64(fy)
    iz = np.int64(fz)
    u = _fade(x - fx)
    v = _fade(y - fy)
    w = _fade(z - fz)
    c000 = _hash01(ix, iy, iz, seed)
    c100 = _hash01(ix + 1, iy, iz, seed)
    c010 = _hash01(ix, iy + 1, iz, seed)
    c110 = _hash01(ix + 1, iy + 1, iz, seed)
    c001 = _hash01(ix, iy, iz + 1, seed)
    c101 = _hash01(ix + 1, iy, iz + 1, seed)
    c011 = _hash01(ix, iy + 1, iz + 1, seed)
    c111 = _hash01(ix + 1, iy + 1, iz + 1, seed)
    x00 = c000 + u * (c100 - c000)
    x10 = c010 + u * (c110 - c010)
    x01 = c001 + u * (c101 - c001)
    x11 = c011 + u * (c111 - c011)
    y0 = x00 + v * (x10 - x00)
    y1 = x01 + v * (x11 - x01)
    return y0 + w * (y1 - y0)


@numba.njit(cache=True, parallel=True)
def _value_noise(points: NDArray[np.float64], freq: float, seed: np.uint64) -> NDArray[np.float32]:
    n = points.shape[0]
    out = np.empty(n, dtype=np.float32)
    for i in numba.prange(n):
        out[i] = _noise1(points[i, 0] * freq, points[i, 1] * freq, points[i, 2] * freq, seed)
    return out


@numba.njit(cache=True)
def fbm1(
    x: float,
    y: float,
    z: float,
    fp: float,
    base_freq: float,
    octaves: int,
    gain: float,
    seed: np.uint64,
) -> float:
    """fBm at one point (see :func:`fbm`); callable from other numba kernels."""
    total = 0.0
    norm = 0.0
    amp = 1.0
    freq = base_freq
    for o in range(octaves):
        # Fade an octave out as its wavelength approaches two pixel footprints (Nyquist).
        ratio = freq * fp
        weight = 1.0
        if ratio > 0.25:
            weight = max(0.0, 1.0 - (ratio - 0.25) / 0.25)
        if weight > 0.0:
            s = seed + np.uint64(o) * np.uint64(1013904223)
            val = _noise1(x * freq, y * freq, z * freq, s)
            total += amp * weight * (val - 0.5)
        norm += amp
        amp *= gain
        freq *= 2.0
    return 0.5 + total / norm


@numba.njit(cache=True, parallel=True)
def _fbm(
    points: NDArray[np.float64],
    footprint_m: NDArray[np.float64],
    base_freq: float,
    octaves: int,
    gain: float,
    seed: np.uint64,
) -> NDArray[np.float32]:
    n = points.shape[0]
    out = np.empty(n, dtype=np.float32)
    for i in numba.prange(n):
        out[i] = fbm1(
            points[i, 0], points[i, 1], points[i, 2], footprint_m[i], base_freq, octaves, gain, seed
        )
    return out


def value_noise(
    points: NDArray[np.float64], *, freq_per_m: float, seed: int = 0
) -> NDArray[np.float32]:
    """One octave of value noise.

    Args:
        points: ``(N, 3)`` float64 positions, metres.
        freq_per_m: lattice points per metre.
        seed: selects an independent noise field.

    Returns:
        ``(N,)`` float32 in ``[0, 1]``, smooth (C2) in position.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return _value_noise(pts, float(freq_per_m), np.uint64(seed & 0xFFFFFFFF))


def fbm(
    points: NDArray[np.float64],
    *,
    base_freq_per_m: float,
    octaves: int,
    gain: float = 0.5,
    footprint_m: NDArray[np.float64] | float = 0.0,
    seed: int = 0,
) -> NDArray[np.float32]:
    """Fractional Brownian motion: ``octaves`` of value noise, frequency doubling each octave.

    Args:
        points: ``(N, 3)`` float64 positions, metres.
        base_freq_per_m: frequency of the first octave, 1/metres.
        octaves: number of octaves.
        gain: amplitude ratio between successive octaves.
        footprint_m: ``(N,)`` or scalar, the size of one pixel at each point (metres); octaves with
            a wavelength under about two footprints are faded out. 0 keeps every octave.
        seed: selects an independent noise field.

    Returns:
        ``(N,)`` float32 around 0.5, within ``[0, 1]``.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    fp = np.broadcast_to(np.asarray(footprint_m, dtype=np.float64), (pts.shape[0],))
    return _fbm(
        pts,
        np.ascontiguousarray(fp),
        float(base_freq_per_m),
        int(octaves),
        float(gain),
        np.uint64(seed & 0xFFFFFFFF),
    )


@numba.njit(cache=True, parallel=True)
def _rigid(
    points: NDArray[np.float64], R: NDArray[np.float64], t: NDArray[np.float64]
) -> NDArray[np.float64]:
    n = points.shape[0]
    out = np.empty((n, 3), dtype=np.float64)
    for i in numba.prange(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        for r in range(3):
            out[i, r] = R[r, 0] * x + R[r, 1] * y + R[r, 2] * z + t[r]
    return out


def rigid_transform(
    R: NDArray[np.float64], t: NDArray[np.float64], points: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``points @ R.T + t`` for ``(N, 3)`` points (float64 result), parallel and fast for large N
    (NumPy's small-matrix product is slow here)."""
    return _rigid(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(R, dtype=np.float64),
        np.ascontiguousarray(t, dtype=np.float64),
    )


# ---------------------------------------------------------------------------------------------
# Lattice-cached evaluation for the fused shading kernel.
#
# Neighbouring pixels of an image row usually fall into the same lattice cell of all but the
# finest octaves (an octave is only evaluated while its cell is at least two pixel footprints
# wide), so the eight hashed corner values of the previous pixel can be reused. ``cache`` holds
# one row per (field, octave) slot: [floor x, floor y, floor z, seed, c000, c100, c010, c110,
# c001, c101, c011, c111]. Results are bitwise identical to :func:`_noise1` / :func:`fbm1`.

CACHE_COLS = 12


@numba.njit(cache=True, inline="always")
def _noise1_cached(
    x: float, y: float, z: float, seed: np.uint64, cache: NDArray[np.float64], slot: int
) -> float:
    fx = np.floor(x)
    fy = np.floor(y)
    fz = np.floor(z)
    fs = float(seed)
    if not (
        cache[slot, 0] == fx
        and cache[slot, 1] == fy
        and cache[slot, 2] == fz
        and cache[slot, 3] == fs
    ):
        ix = np.int64(fx)
        iy = np.int64(fy)
        iz = np.int64(fz)
        cache[slot, 0] = fx
        cache[slot, 1] = fy
        cache[slot, 2] = fz
        cache[slot, 3] = fs
        cache[slot, 4] = _hash01(ix, iy, iz, seed)
        cache[slot, 5] = _hash01(ix + 1, iy, iz, seed)
        cache[slot, 6] = _hash01(ix, iy + 1, iz, seed)
        cache[slot, 7] = _hash01(ix + 1, iy + 1, iz, seed)
        cache[slot, 8] = _hash01(ix, iy, iz + 1, seed)
        cache[slot, 9] = _hash01(ix + 1, iy, iz + 1, seed)
        cache[slot, 10] = _hash01(ix, iy + 1, iz + 1, seed)
        cache[slot, 11] = _hash01(ix + 1, iy + 1, iz + 1, seed)
    u = _fade(x - fx)
    v = _fade(y - fy)
    w = _fade(z - fz)
    c000 = cache[slot, 4]
    c100 = cache[slot, 5]
    c010 = cache[slot, 6]
    c110 = cache[slot, 7]
    c001 = cache[slot, 8]
    c101 = cache[slot, 9]
    c011 = cache[slot, 10]
    c111 = cache[slot, 11]
    x00 = c000 + u * (c100 - c000)
    x10 = c010 + u * (c110 - c010)
    x01 = c001 + u * (c101 - c001)
    x11 = c011 + u * (c111 - c011)
    y0 = x00 + v * (x10 - x00)
    y1 = x01 + v * (x11 - x01)
    return y0 + w * (y1 - y0)


@numba.njit(cache=True)
def fbm1_cached(
    x: float,
    y: float,
    z: float,
    fp: float,
    base_freq: float,
    octaves: int,
    gain: float,
    seed: np.uint64,
    cache: NDArray[np.float64],
    slot0: int,
) -> float:
    """:func:`fbm1` with octave ``o`` cached in ``cache[slot0 + o]``; the same value."""
    total = 0.0
    norm = 0.0
    amp = 1.0
    freq = base_freq
    for o in range(octaves):
        ratio = freq * fp
        weight = 1.0
        if ratio > 0.25:
            weight = max(0.0, 1.0 - (ratio - 0.25) / 0.25)
        if weight > 0.0:
            s = seed + np.uint64(o) * np.uint64(1013904223)
            val = _noise1_cached(x * freq, y * freq, z * freq, s, cache, slot0 + o)
            total += amp * weight * (val - 0.5)
        norm += amp
        amp *= gain
        freq *= 2.0
    return 0.5 + total / norm
