"""Reconstruction-side use of a session's ground truth (found and read through
:mod:`sea3d.io.ground_truth`, which owns where it lives and what its files are called)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.geometry.camera import CameraModel
from sea3d.io.ground_truth import GroundTruth, find_ground_truth, gt_depth_path, read_gt_depth

__all__ = ["GroundTruth", "find_ground_truth", "observed_surface_points"]

log = logging.getLogger(__name__)


def observed_surface_points(
    depth_dir: Path,
    camera: CameraModel,
    t_ns: NDArray[np.int64],
    T_world_left: NDArray[np.float64],
    *,
    max_depth_m: float,
    frame_stride: int = 5,
    pixel_stride: int = 4,
) -> NDArray[np.float64]:
    """World points of the surface the left camera saw, from ground-truth depth maps.

    Ground-truth depth is metres along the raw left camera's z axis; each sampled pixel is
    unprojected through ``camera`` (refraction included) to the point of that depth.

    Args:
        depth_dir: ``gt/depth`` with ``<t_ns>.tiff`` (:attr:`GroundTruth.depth_folder`).
        camera: the raw left camera, at the ground truth's image size.
        t_ns, T_world_left: (N,) stamps and (N, 4, 4) true poses of the frames to use.
        max_depth_m: farther points are left out (what the reconstruction could not see).
        frame_stride, pixel_stride: subsampling.

    Returns:
        (M, 3) float64 world points (empty when no depth map was found).
    """
    out = []
    v, u = np.mgrid[0:camera.height:pixel_stride, 0:camera.width:pixel_stride]
    uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    rays = camera.unproject(uv)
    for k in range(0, len(t_ns), frame_stride):
        p = gt_depth_path(depth_dir, int(t_ns[k]))
        if not p.is_file():
            continue
        depth = read_gt_depth(p)
        if depth.shape != (camera.height, camera.width):
            log.warning("%s is %s, not the camera's %dx%d; skipped", p, depth.shape,
                        camera.width, camera.height)
            continue
        z = depth[v.ravel(), u.ravel()].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = (z - rays.origins[:, 2]) / rays.directions[:, 2]
        ok = np.isfinite(s) & (s > 0) & (z <= max_depth_m) & rays.valid
        pts = rays.origins[ok] + s[ok, None] * rays.directions[ok]
        T = T_world_left[k]
        out.append(pts @ T[:3, :3].T + T[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))
