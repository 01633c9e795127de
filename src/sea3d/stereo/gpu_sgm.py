"""Semi-global matching on an NVIDIA GPU with CuPy (optional; ``pip install cupy-cuda12x``).

The same method as sea3d's CPU engine at full resolution, written as CUDA kernels:

1. census transform of both images (``census_width_px`` x ``census_height_px`` window, 64 bits);
2. matching cost = Hamming distance of census signatures, ``(H, W, D)`` uint8;
3. aggregation along 8 paths (Hirschmueller 2008): one CUDA block per scanline and one thread
   per disparity, ``L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d+-1) + P1, min_k L(p-r, k) + P2')
   - min_k L(p-r, k)`` with ``P2' = max(P1 + 1, P2 * tau / (tau + |I(p) - I(p-r)|))`` lowered
   across image edges; the 8 paths are summed into one uint16 volume;
4. winner-take-all with a uniqueness margin, parabola subpixel fit, and a left-right check
   against the disparities of the right view read from the same volume.

The whole range is searched at once (GPU memory holds 1080p x 256 disparities easily: 0.5 GB of
costs and 1 GB of sums), so there is no coarse-to-fine band that could miss thin structures.
Invalid pixels are NaN, as everywhere in sea3d.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError, StereoError

__all__ = ["GpuSgmConfig", "gpu_available", "match_gpu_sgm"]


@dataclass(frozen=True, kw_only=True)
class GpuSgmConfig:
    """sea3d's GPU semi-global matcher; search range ``0 <= d <= max_disparity_px``."""

    max_disparity_px: int = 63
    """Largest disparity searched, pixels (inclusive); at most 1023."""
    census_width_px: int = 9
    """Census window width, pixels (odd; width * height <= 64 + 1)."""
    census_height_px: int = 7
    """Census window height, pixels (odd)."""
    p1: int = 9
    """Penalty for a one-pixel disparity change between path neighbours."""
    p2: int = 100
    """Penalty for larger changes on a flat image; lowered across intensity edges."""
    p2_edge_tau: float = 12.0
    """Intensity step (grey levels) at which P2 halves."""
    uniqueness: float = 0.03
    """Minimum relative margin of the winner over the best non-neighbouring disparity."""
    lr_max_diff_px: int = 1
    """Left-right consistency tolerance, pixels; negative disables the check."""
    median_px: int = 3
    """NaN-aware median filter size applied to the result (0 or 1 disables)."""

    def __post_init__(self) -> None:
        if int(self.max_disparity_px) != self.max_disparity_px or not (
            1 <= self.max_disparity_px <= 1023
        ):
            raise ConfigError(
                f"max_disparity_px must be an integer in 1..1023, got {self.max_disparity_px!r}"
            )
        for name in ("census_width_px", "census_height_px"):
            v = getattr(self, name)
            if v < 1 or v % 2 == 0:
                raise ConfigError(f"{name} must be an odd positive integer, got {v}")
        if self.census_width_px * self.census_height_px > 65:
            raise ConfigError("census window too large for 64-bit signatures")
        if not (0 < self.p1 < self.p2 < 4000):
            raise ConfigError(f"need 0 < p1 < p2 < 4000, got p1={self.p1}, p2={self.p2}")


_KERNELS = r"""
extern "C" {

__global__ void census(const unsigned char* img, unsigned long long* out, int h, int w,
                       int rh, int rw) {
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y * blockDim.y + threadIdx.y;
    if (x >= w || y >= h) return;
    unsigned char c = img[y * w + x];
    unsigned long long sig = 0;
    for (int dy = -rh; dy <= rh; ++dy) {
        int yy = min(max(y + dy, 0), h - 1);
        for (int dx = -rw; dx <= rw; ++dx) {
            if (dx == 0 && dy == 0) continue;
            int xx = min(max(x + dx, 0), w - 1);
            sig = (sig << 1) | (img[yy * w + xx] < c ? 1ull : 0ull);
        }
    }
    out[y * w + x] = sig;
}

__global__ void hamming_cost(const unsigned long long* cl, const unsigned long long* cr,
                             unsigned char* cost, int h, int w, int nd, int maxc) {
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y;
    if (x >= w) return;
    unsigned long long a = cl[y * w + x];
    unsigned char* row = cost + ((size_t)y * w + x) * nd;
    for (int d = 0; d < nd; ++d) {
        int xr = x - d;
        row[d] = xr >= 0 ? (unsigned char)__popcll(a ^ cr[y * w + xr]) : (unsigned char)maxc;
    }
}

// One block per scanline of direction (dx, dy); thread d owns disparity d. Paths start on the
// image border; blockIdx.x enumerates start pixels.
__global__ void aggregate(const unsigned char* cost, const unsigned char* img,
                          unsigned short* sum, int h, int w, int nd, int dx, int dy,
                          int p1, int p2, float tau) {
    extern __shared__ int sh[];
    int* prev = sh;              // nd + 2 entries, padded with large values at both ends
    int* red = sh + nd + 2;      // reduction buffer, blockDim.x entries
    int d = threadIdx.x;
    int s = blockIdx.x;
    // Start pixel of this path.
    int x, y;
    if (dy == 0) { y = s; x = dx > 0 ? 0 : w - 1; }
    else if (dx == 0) { x = s; y = dy > 0 ? 0 : h - 1; }
    else {
        // Diagonals start on the top/bottom row (s < w) or the left/right column (s >= w).
        if (s < w) { x = s; y = dy > 0 ? 0 : h - 1; }
        else { x = dx > 0 ? 0 : w - 1; y = dy > 0 ? s - w + 1 : h - 2 - (s - w); }
        if (y < 0 || y >= h) return;
    }
    const int BIG = 1 << 20;
    if (d == 0) { prev[0] = BIG; prev[nd + 1] = BIG; }
    int prev_min = 0;
    int prev_i = -1;
    bool first = true;
    while (x >= 0 && x < w && y >= 0 && y < h) {
        size_t p = (size_t)y * w + x;
        int L = BIG;
        if (d >= nd) {
            // Padding thread: only takes part in the reduction.
        } else if (first) {
            L = cost[p * nd + d];
        } else {
            int c = cost[p * nd + d];
            int ip = img[p];
            int grad = abs(ip - prev_i);
            int p2a = (int)(p2 * tau / (tau + (float)grad));
            if (p2a < p1 + 1) p2a = p1 + 1;
            int best = prev[d + 1];
            int t = prev[d] + p1; if (t < best) best = t;
            t = prev[d + 2] + p1; if (t < best) best = t;
            t = prev_min + p2a; if (t < best) best = t;
            L = c + best - prev_min;
        }
        __syncthreads();
        if (d < nd) {
            prev[d + 1] = L;
            unsigned int acc = sum[p * nd + d] + (unsigned int)L;
            sum[p * nd + d] = (unsigned short)(acc > 65535u ? 65535u : acc);
        }
        red[d] = d < nd ? L : BIG;
        __syncthreads();
        for (int o = blockDim.x / 2; o > 0; o >>= 1) {
            if (d < o && red[d + o] < red[d]) red[d] = red[d + o];
            __syncthreads();
        }
        prev_min = red[0];
        prev_i = img[p];
        first = false;
        __syncthreads();
        x += dx; y += dy;
    }
}

__global__ void select_left(const unsigned short* sum, float* disp, int h, int w, int nd,
                            float uniqueness) {
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y;
    if (x >= w) return;
    const unsigned short* s = sum + ((size_t)y * w + x) * nd;
    int dmax = min(nd - 1, x);
    int best = 0; unsigned int bv = 0xFFFFFFFFu;
    for (int d = 0; d <= dmax; ++d) { if (s[d] < bv) { bv = s[d]; best = d; } }
    unsigned int second = 0xFFFFFFFFu;
    for (int d = 0; d <= dmax; ++d) {
        if (d < best - 1 || d > best + 1) { if (s[d] < second) second = s[d]; }
    }
    float out = (float)best;
    if (second != 0xFFFFFFFFu && (float)second * (1.0f - uniqueness) < (float)bv) {
        out = nanf("");
    } else if (best > 0 && best < dmax) {
        float a = s[best - 1], b = s[best], c = s[best + 1];
        float den = a - 2.0f * b + c;
        if (den > 0.0f) out += 0.5f * (a - c) / den;
    }
    disp[y * w + x] = out;
}

__global__ void select_right(const unsigned short* sum, int* disp, int h, int w, int nd) {
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y;
    if (x >= w) return;
    int best = 0; unsigned int bv = 0xFFFFFFFFu;
    for (int d = 0; d < nd && x + d < w; ++d) {
        unsigned int v = sum[((size_t)y * w + x + d) * nd + d];
        if (v < bv) { bv = v; best = d; }
    }
    disp[y * w + x] = best;
}

__global__ void lr_check(float* disp, const int* disp_r, int h, int w, int tol) {
    int x = blockIdx.x * blockDim.x + threadIdx.x;
    int y = blockIdx.y;
    if (x >= w) return;
    float d = disp[y * w + x];
    if (isnan(d)) return;
    int xr = (int)floorf((float)x - d + 0.5f);
    if (xr < 0 || xr >= w || fabsf((float)disp_r[y * w + xr] - d) > (float)tol + 0.5f) {
        disp[y * w + x] = nanf("");
    }
}

}
"""

_module: Any = None


def gpu_available() -> bool:
    """True if CuPy is installed and sees a CUDA device."""
    try:
        import cupy

        return bool(cupy.cuda.runtime.getDeviceCount() > 0)
    except Exception:  # any import or driver failure means "no GPU"
        return False


def _kernels() -> Any:
    global _module
    if _module is None:
        import cupy

        _module = cupy.RawModule(code=_KERNELS, options=("-std=c++14",))
    return _module


def _check_image(img: NDArray[Any], name: str) -> NDArray[Any]:
    arr = np.asarray(img)
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise StereoError(f"{name} image must be (H, W) or (H, W, 3), got shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise StereoError(f"{name} image has non-finite values")
    return arr


def _gray_on_device(arr: NDArray[Any]) -> Any:
    """Upload as stored (uint8 RGB is 3 bytes a pixel) and convert to uint8 grey on the GPU."""
    import cupy as cp

    dev = cp.asarray(arr)
    if dev.ndim == 3:
        dev = dev.astype(cp.float32) @ cp.asarray([0.299, 0.587, 0.114], cp.float32)
    if arr.dtype == np.uint16:
        dev = dev / 257.0
    if dev.dtype != cp.uint8:
        dev = cp.clip(cp.rint(dev), 0, 255).astype(cp.uint8)
    return cp.ascontiguousarray(dev)


def match_gpu_sgm(
    left: NDArray[Any], right: NDArray[Any], config: GpuSgmConfig
) -> tuple[NDArray[np.float32], dict[str, float]]:
    """Match a rectified pair on the GPU.

    Args:
        left, right: ``(H, W)`` or ``(H, W, 3)`` RGB images of equal shape, rectified.
        config: :class:`GpuSgmConfig`.

    Returns:
        ``(disparity, timings_s)``: ``(H, W)`` float32 disparity of the left view (NaN invalid)
        and seconds per stage (``upload_s`` with the grey conversion, ``match_s`` on the device,
        ``download_s``).

    Raises:
        StereoError: no usable GPU, images of different shapes, a range wider than the image.
    """
    if not gpu_available():
        raise StereoError("the GPU engine needs CuPy and an NVIDIA GPU; use engine 'sea3d'")
    import cupy as cp
    from cupyx.scipy import ndimage as cnd

    al, ar = _check_image(left, "left"), _check_image(right, "right")
    if al.shape != ar.shape:
        raise StereoError(f"left and right images differ in size: {al.shape} and {ar.shape}")
    h, w = al.shape[:2]
    nd = config.max_disparity_px + 1
    if nd >= w:
        raise StereoError(f"disparity range 0..{nd - 1} is as wide as the image ({w} px)")
    mod = _kernels()
    t0 = time.perf_counter()
    il, ir = _gray_on_device(al), _gray_on_device(ar)
    cp.cuda.Device().synchronize()
    t1 = time.perf_counter()
    rh, rw = config.census_height_px // 2, config.census_width_px // 2
    cl = cp.empty((h, w), cp.uint64)
    cr = cp.empty((h, w), cp.uint64)
    grid2 = ((w + 31) // 32, (h + 7) // 8)
    census = mod.get_function("census")
    census(grid2, (32, 8), (il, cl, np.int32(h), np.int32(w), np.int32(rh), np.int32(rw)))
    census(grid2, (32, 8), (ir, cr, np.int32(h), np.int32(w), np.int32(rh), np.int32(rw)))
    maxc = config.census_width_px * config.census_height_px - 1
    cost = cp.empty((h, w, nd), cp.uint8)
    rows = ((w + 127) // 128, h)
    mod.get_function("hamming_cost")(
        rows, (128,), (cl, cr, cost, np.int32(h), np.int32(w), np.int32(nd), np.int32(maxc))
    )
    total = cp.zeros((h, w, nd), cp.uint16)
    threads = 1 << (nd - 1).bit_length()  # power of two for the reduction
    shared = (nd + 2 + threads) * 4
    agg = mod.get_function("aggregate")
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, 1), (1, -1), (-1, -1)):
        starts = h if dy == 0 else (w if dx == 0 else w + h - 1)
        agg(
            (starts,),
            (threads,),
            (
                cost,
                il,
                total,
                np.int32(h),
                np.int32(w),
                np.int32(nd),
                np.int32(dx),
                np.int32(dy),
                np.int32(config.p1),
                np.int32(config.p2),
                np.float32(config.p2_edge_tau),
            ),
            shared_mem=shared,
        )
    disp = cp.empty((h, w), cp.float32)
    mod.get_function("select_left")(
        rows,
        (128,),
        (total, disp, np.int32(h), np.int32(w), np.int32(nd), np.float32(config.uniqueness)),
    )
    if config.lr_max_diff_px >= 0:
        disp_r = cp.empty((h, w), cp.int32)
        mod.get_function("select_right")(
            rows, (128,), (total, disp_r, np.int32(h), np.int32(w), np.int32(nd))
        )
        mod.get_function("lr_check")(
            rows, (128,), (disp, disp_r, np.int32(h), np.int32(w), np.int32(config.lr_max_diff_px))
        )
    if config.median_px > 1:
        # NaN-aware median: medians of valid neighbours only, invalid pixels stay invalid.
        valid = ~cp.isnan(disp)
        filled = cp.where(valid, disp, cp.float32(-1.0))
        med = cnd.median_filter(filled, size=config.median_px, mode="nearest")
        disp = cp.where(valid & (med >= 0), med, cp.float32(np.nan))
    cp.cuda.Device().synchronize()
    t2 = time.perf_counter()
    out = cp.asnumpy(disp).astype(np.float32)
    t3 = time.perf_counter()
    return out, {"upload_s": t1 - t0, "match_s": t2 - t1, "download_s": t3 - t2}
