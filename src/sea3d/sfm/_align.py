"""A minimal Umeyama alignment for sea3d.sfm's own tests and benchmarks.

Private on purpose: the public trajectory metrics (ATE with SE(3)/Sim(3) alignment) belong to
``sea3d.eval.trajectory``; switch to it once both exist on one branch.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]


def umeyama(src: F64, dst: F64, with_scale: bool) -> tuple[float, F64, F64]:
    """``(s, R, t)`` minimising ``sum |dst - (s R src + t)|^2`` (Umeyama 1991, eqs. 40-42)."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(xd.T @ xs / len(src))
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    s = float((S * np.diag(D)).sum() / xs.var(axis=0).sum()) if with_scale else 1.0
    return s, R, mu_d - s * R @ mu_s


def ate_rmse(est: F64, gt: F64, with_scale: bool) -> tuple[float, float]:
    """``(ATE RMSE in metres, scale)`` of positions ``(N, 3)`` after Umeyama alignment."""
    s, R, t = umeyama(est, gt, with_scale)
    err = s * est @ R.T + t - gt
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))), s
