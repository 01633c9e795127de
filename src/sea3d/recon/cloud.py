"""Point-cloud clean-up with Open3D: voxel downsampling and statistical outlier removal.

Downsampling comes first (one point per occupied voxel: the mean of its points, colours and
normals), so the outlier search runs on a bounded number of points. A point is an outlier
when its mean distance to its ``neighbors`` nearest neighbours exceeds the mean of that
figure over the cloud by more than ``std_ratio`` standard deviations (Rusu et al. 2008).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ReconError

__all__ = ["CleanCloud", "CloudConfig", "clean_point_cloud"]


@dataclass(frozen=True, kw_only=True)
class CloudConfig:
    """Clean-up parameters."""

    voxel_m: float = 0.01
    """Downsampling voxel, metres (0 keeps every point)."""
    neighbors: int = 20
    """Neighbours of the outlier statistic (0 disables outlier removal)."""
    std_ratio: float = 2.0
    """Outlier threshold in standard deviations."""

    def __post_init__(self) -> None:
        if self.voxel_m < 0 or self.neighbors < 0 or not self.std_ratio > 0:
            raise ReconError("need voxel_m >= 0, neighbors >= 0 and std_ratio > 0")


@dataclass(frozen=True, kw_only=True, eq=False)
class CleanCloud:
    """A cleaned cloud: ``points`` (N, 3) m, ``colors`` (N, 3) uint8, ``normals`` (N, 3), and
    how many points came in, survived downsampling, and were removed as outliers."""

    points: F64
    colors: NDArray[np.uint8]
    normals: F64
    input_points: int
    downsampled_points: int
    outliers: int


def clean_point_cloud(
    points: F64,
    colors: NDArray[np.uint8] | None = None,
    normals: F64 | None = None,
    config: CloudConfig | None = None,
) -> CleanCloud:
    """Voxel-downsample, then remove statistical outliers.

    Args:
        points: (N, 3) metres. colors: (N, 3) uint8 or None. normals: (N, 3) or None.
        config: :class:`CloudConfig`.

    Returns:
        :class:`CleanCloud` (colours zero and normals zero when none were given).

    Raises:
        ReconError: mismatched shapes.
    """
    import open3d as o3d

    cfg = config or CloudConfig()
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ReconError(f"points must be (N, 3), got {p.shape}")
    for name, a in (("colours", colors), ("normals", normals)):
        if a is not None and np.asarray(a).shape != p.shape:
            raise ReconError(f"{name} {np.asarray(a).shape} do not match points {p.shape}")
    n_in = len(p)
    if n_in == 0:
        return CleanCloud(points=p, colors=np.zeros((0, 3), np.uint8), normals=np.zeros((0, 3)),
                          input_points=0, downsampled_points=0, outliers=0)
    # Open3D's voxel averages sum in input order, and the merged TSDF's points come in hash
    # map order: sorted first, the same points give the same colours (a float sum in another
    # order flipped one 8-bit level in a rerun from the cache).
    order = np.lexsort(p.T[::-1])
    p = p[order]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    if colors is not None:
        pc.colors = o3d.utility.Vector3dVector(np.asarray(colors, np.float64)[order] / 255.0)
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.asarray(normals, np.float64)[order])
    if cfg.voxel_m > 0:
        pc = pc.voxel_down_sample(cfg.voxel_m)
    n_ds = len(pc.points)
    outliers = 0
    if cfg.neighbors > 0 and n_ds > cfg.neighbors:
        pc, kept = pc.remove_statistical_outlier(nb_neighbors=cfg.neighbors,
                                                 std_ratio=cfg.std_ratio)
        outliers = n_ds - len(kept)
    out_p = np.asarray(pc.points, np.float64)
    out_c = (np.clip(np.rint(np.asarray(pc.colors) * 255), 0, 255).astype(np.uint8)
             if pc.has_colors() else np.zeros((len(out_p), 3), np.uint8))
    out_n = np.asarray(pc.normals, np.float64) if pc.has_normals() else np.zeros_like(out_p)
    if pc.has_normals():
        nn = np.linalg.norm(out_n, axis=1, keepdims=True)
        out_n = np.divide(out_n, nn, out=np.zeros_like(out_n), where=nn > 0)
    return CleanCloud(points=out_p, colors=out_c, normals=out_n, input_points=n_in,
                      downsampled_points=n_ds, outliers=outliers)
