"""Analytic depth images of simple scenes, for fusion tests (no renderer needed).

The scene: a floor ``z = floor_z_m`` with a box standing on it, seen by a pinhole camera
looking down. Depth is computed by exact ray casting in numpy.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from sea3d.geometry.se3 import look_at

F64 = NDArray[np.float64]

W, H, F = 160, 120, 130.0
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])
BOX_LO = np.array([-0.25, -0.2, 0.0])
BOX_HI = np.array([0.25, 0.2, 0.3])


def rays(K: F64 = K, w: int = W, h: int = H) -> F64:
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    return d.reshape(-1, 3)


def floor_colour(p: F64) -> NDArray[np.uint8]:
    """A checker texture, so colours can be checked too."""
    c = ((np.floor(p[:, 0] / 0.1) + np.floor(p[:, 1] / 0.1)) % 2).astype(np.uint8)
    out = np.zeros((len(p), 3), np.uint8)
    out[:, 0] = 60 + 150 * c
    out[:, 1] = 90
    out[:, 2] = 200 - 150 * c
    return out


def render(T_world_cam: F64, *, box: bool = True, K: F64 = K, w: int = W, h: int = H
           ) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Depth (H, W) float32 metres along z (NaN where nothing is hit) and colours (H, W, 3)."""
    d_cam = rays(K, w, h)
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = d_cam @ R.T
    t_best = np.full(len(d), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = (0.0 - o[2]) / d[:, 2]
    t_best = np.where(t_floor > 0, t_floor, np.inf)
    col = np.zeros((len(d), 3), np.uint8)
    hit = np.isfinite(t_best)
    col[hit] = floor_colour(o + d[hit] * t_best[hit, None])
    if box:
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (BOX_LO - o) / d
            t2 = (BOX_HI - o) / d
        tmin = np.nanmax(np.minimum(t1, t2), axis=1)
        tmax = np.nanmin(np.maximum(t1, t2), axis=1)
        inbox = (tmax >= tmin) & (tmin > 0) & (tmin < t_best)
        t_best = np.where(inbox, tmin, t_best)
        col[inbox] = (230, 200, 40)
    z = t_best  # d_cam has unit z, so the ray parameter is the depth
    depth = np.where(np.isfinite(z), z, np.nan).reshape(h, w).astype(np.float32)
    return depth, col.reshape(h, w, 3)


def survey_poses(n: int, *, height_m: float = 1.2, span_m: float = 1.0) -> list[F64]:
    """Cameras at ``height_m`` over the floor moving along x, looking down and forward."""
    out = []
    for x in np.linspace(-span_m / 2, span_m / 2, n):
        eye = np.array([x, -0.6, height_m])
        out.append(look_at(eye, np.array([x, 0.0, 0.0]), up=(0.0, 1.0, 0.0)))
    return out
