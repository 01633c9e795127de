"""Depth against ground truth: compare estimated 3D points with a ground-truth depth map."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import GeometryError
from sea3d.geometry.camera import CameraModel

__all__ = ["DepthErrors", "point_depth_errors"]


@dataclass(frozen=True, kw_only=True)
class DepthErrors:
    """Errors of estimated points against ground-truth depth, over points that both have.

    Attributes:
        count: points compared.
        median_abs_m: median of ``|z_est - z_gt|``, metres.
        median_rel: median of ``|z_est - z_gt| / z_gt``.
        p90_rel: 90th percentile of the relative error.
        mean_signed_rel: mean of ``(z_est - z_gt) / z_gt`` (a scale bias shows here).
        within_1pct: fraction of points with relative error below 1 %.
        by_range: ``(lo_m, hi_m, count, median_rel)`` per ground-truth depth band.
    """

    count: int
    median_abs_m: float
    median_rel: float
    p90_rel: float
    mean_signed_rel: float
    within_1pct: float
    by_range: tuple[tuple[float, float, int, float], ...]

    def as_dict(self) -> dict[str, object]:
        """Plain values for JSON."""
        return {
            "count": self.count,
            "median_abs_m": self.median_abs_m,
            "median_rel": self.median_rel,
            "p90_rel": self.p90_rel,
            "mean_signed_rel": self.mean_signed_rel,
            "within_1pct": self.within_1pct,
            "by_range": [
                {"lo_m": lo, "hi_m": hi, "count": n, "median_rel": m}
                for lo, hi, n, m in self.by_range
            ],
        }


def point_depth_errors(
    points_cam: NDArray[np.float64],
    camera: CameraModel,
    gt_depth_m: NDArray[np.floating],
    *,
    bands_m: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0, 5.0, 10.0),
) -> DepthErrors:
    """Compare points in a camera's frame with that camera's ground-truth depth map.

    Each point is projected through ``camera`` (refraction included) to its nearest pixel; its
    ``z`` is compared with the ground-truth depth (``z`` of the true surface point) there.

    Args:
        points_cam: ``(N, 3)`` estimated points in the camera frame, metres.
        camera: the camera model the ground truth was rendered with.
        gt_depth_m: ``(H, W)`` ground-truth depth along the camera's z axis, NaN where unknown.
        bands_m: edges of the depth bands for ``by_range``.

    Raises:
        GeometryError: a depth map of another size than the camera's image.
    """
    gt = np.asarray(gt_depth_m, dtype=np.float64)
    if gt.shape != (camera.height, camera.width):
        raise GeometryError(
            f"ground-truth depth is {gt.shape[1]}x{gt.shape[0]}, the camera "
            f"{camera.width}x{camera.height}"
        )
    uv, ok = camera.project(points_cam)
    u = np.rint(np.where(ok, uv[:, 0], -1)).astype(np.int64)
    v = np.rint(np.where(ok, uv[:, 1], -1)).astype(np.int64)
    inside = ok & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    z_gt = np.full(len(points_cam), np.nan)
    z_gt[inside] = gt[v[inside], u[inside]]
    z = points_cam[:, 2]
    both = np.isfinite(z_gt) & np.isfinite(z) & (z_gt > 0)
    if not np.any(both):
        nan = float("nan")
        return DepthErrors(
            count=0,
            median_abs_m=nan,
            median_rel=nan,
            p90_rel=nan,
            mean_signed_rel=nan,
            within_1pct=nan,
            by_range=(),
        )
    err = z[both] - z_gt[both]
    rel = np.abs(err) / z_gt[both]
    bands = []
    for lo, hi in itertools.pairwise(bands_m):
        sel = (z_gt[both] >= lo) & (z_gt[both] < hi)
        if np.any(sel):
            bands.append((lo, hi, int(sel.sum()), float(np.median(rel[sel]))))
    return DepthErrors(
        count=int(both.sum()),
        median_abs_m=float(np.median(np.abs(err))),
        median_rel=float(np.median(rel)),
        p90_rel=float(np.percentile(rel, 90)),
        mean_signed_rel=float(np.mean(err / z_gt[both])),
        within_1pct=float(np.mean(rel < 0.01)),
        by_range=tuple(bands),
    )
