"""Left-right matches refined on the row of a rectified pinhole pair.

In a rectified pinhole pair a point's two pixels share their row, so the match has one unknown,
the disparity. A 2D Lucas-Kanade match is free to move in ``v`` as well; on a corner whose
texture is partly an oblique edge it slides a fraction of a pixel along that edge, and the
slide carries ``u`` with it: a disparity error that does not average out (on the KITTI excerpt
of ``benchmarks/bench_real.py`` the 2D matches made the points 1-3 % too far at 8-24 px of
disparity, against depth triangulated over four frames of ground-truth motion, and the path
0.7 % too long). :func:`refine_on_row` solves for the disparity alone: Gauss-Newton on the
sum of squared differences of zero-mean, gain-normalised patches (the two cameras' exposures
differ), the right patch sampled on the left pixel's row.

A refractive rig's true matches sit a fraction of a pixel off the row (the virtual pinhole's
residual), so this applies to pinhole geometry only.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64

__all__ = ["refine_on_row"]

_STEP_DONE_PX = 0.05
"""A match has converged when its last Gauss-Newton step is below this, pixels (bilinear
sampling makes the last steps alternate by a few hundredths)."""


def refine_on_row(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    uv_left: F64,
    u_right: F64,
    *,
    window_px: int,
    iterations: int = 20,
) -> tuple[F64, NDArray[np.bool_]]:
    """Right-image columns of left pixels ``uv_left``, on their own rows.

    Args:
        left, right: the rectified grey pair.
        uv_left: ``(N, 2)`` left pixels.
        u_right: ``(N,)`` starting right columns (a 2D match).
        window_px: odd patch size.
        iterations: most Gauss-Newton steps.

    Returns:
        ``u_right (N,)`` refined, and ``ok (N,)``: converged (a flat patch does not).
    """
    n = uv_left.shape[0]
    if n == 0:
        return np.zeros(0), np.zeros(0, bool)
    offs = np.arange(-(window_px // 2), window_px // 2 + 1, dtype=np.float32)
    w = offs.size
    xs = np.repeat(uv_left[:, 0, None, None].astype(np.float32) + offs[None, None, :], w, axis=1)
    ys = np.repeat(uv_left[:, 1, None, None].astype(np.float32) + offs[None, :, None], w, axis=2)
    ys2 = ys.reshape(n * w, w)

    def sample(img: NDArray[np.float32], x: NDArray[np.float32]) -> NDArray[np.float32]:
        out = cv2.remap(img, x.reshape(n * w, w), ys2, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        return np.asarray(out, dtype=np.float32).reshape(n, w, w)

    L = sample(left.astype(np.float32), xs)
    Lz = L - L.mean(axis=(1, 2), keepdims=True)
    sL = np.sqrt((Lz * Lz).sum(axis=(1, 2)))
    Rf = right.astype(np.float32)
    d = (uv_left[:, 0] - u_right).astype(np.float32)
    step: NDArray[np.float32] = np.full(n, np.inf, np.float32)
    for _ in range(iterations):
        R = sample(Rf, xs - d[:, None, None])
        Rz = R - R.mean(axis=(1, 2), keepdims=True)
        sR = np.sqrt((Rz * Rz).sum(axis=(1, 2))) + 1e-6
        gain = (sL / sR)[:, None, None]
        resid = gain * Rz - Lz
        # d(resid)/d(d) = -gain * dR/dx (the right patch is sampled at x - d)
        J = -gain * np.gradient(Rz, axis=2)
        JJ = (J * J).sum(axis=(1, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            new = np.clip(-(J * resid).sum(axis=(1, 2)) / JJ, -1.0, 1.0)
        new = np.where(np.isfinite(new), new, np.inf).astype(np.float32)
        active = np.abs(step) >= _STEP_DONE_PX
        d = np.where(active & np.isfinite(new), d + new, d).astype(np.float32)
        step = np.where(active, new, step).astype(np.float32)
        if not (np.abs(step) >= _STEP_DONE_PX).any():
            break
    ok = np.abs(step) < _STEP_DONE_PX
    return (uv_left[:, 0] - d).astype(np.float64), ok
