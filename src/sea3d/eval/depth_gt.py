"""Depth against ground truth: compare estimated 3D points with a ground-truth depth map.

Stereo depth lives on the rectified left grid; ground truth on the raw left camera's. Drawing
estimates into the raw view by projecting each point to its nearest raw pixel leaves raw pixels
that no rectified pixel lands on (thin curves of holes where the two grids' spacing differs).
:func:`raw_left_coordinates` inverts the rectification instead, so that
:func:`resample_to_raw_left` and :func:`depth_error_map` give every raw pixel the view covers a
value.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d.errors import GeometryError
from sea3d.geometry.camera import CameraModel

if TYPE_CHECKING:
    from sea3d.rectify.maps import RectifyMaps
    from sea3d.stereo.depth import DepthResult

__all__ = [
    "DepthErrors",
    "depth_error_map",
    "point_depth_errors",
    "raw_left_coordinates",
    "rectified_coordinates",
    "resample_to_raw_left",
]


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


def raw_left_coordinates(
    maps: RectifyMaps, *, iterations: int = 3
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Rectified left coordinates ``(u, v)`` of every raw left pixel (see
    :func:`rectified_coordinates`)."""
    return rectified_coordinates(maps, "left", iterations=iterations)


def rectified_coordinates(
    maps: RectifyMaps, side: str = "left", *, iterations: int = 3,
    points_px: np.ndarray | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Rectified coordinates ``(u, v)`` of raw pixels of one camera: the inverse of its
    ``maps.map_<side>_x/y``, for every raw pixel (or only ``points_px``, (N, 2)).

    Starts from OpenCV's ``undistortPointsIter`` through the (virtual) pinhole and polishes each
    pixel with Newton steps on the remap tables themselves, so the result inverts exactly the
    maps the images were rectified with (to about 1e-3 px). Raw pixels that the rectified view
    does not show get NaN.
    """
    if side not in ("left", "right"):
        raise GeometryError(f"side must be 'left' or 'right', got {side!r}")
    h, w = maps.height, maps.width
    if points_px is None:
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        target = np.stack([uu.ravel(), vv.ravel()], axis=1)
    else:
        target = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    left = side == "left"
    pin = maps.virtual_left if left else maps.virtual_right
    rot = maps.R_rect_left_left if left else maps.R_rect_right_right
    proj = maps.P_left if left else maps.P_right
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6)
    r = cv2.undistortPointsIter(target.reshape(-1, 1, 2), pin.K, pin.dist, rot, proj,
                                crit).reshape(-1, 2)
    mx, my = (maps.map_left_x, maps.map_left_y) if left else (maps.map_right_x, maps.map_right_y)
    gxx, gxy = np.gradient(mx, axis=1), np.gradient(mx, axis=0)
    gyx, gyy = np.gradient(my, axis=1), np.gradient(my, axis=0)

    def at(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
        # float64 bilinear: cv2.remap quantises the fraction to 1/32 px, too coarse here
        x = np.clip(pts[:, 0], 0, w - 1.000001)
        y = np.clip(pts[:, 1], 0, h - 1.000001)
        x = np.where(np.isfinite(x), x, 0.0)
        y = np.where(np.isfinite(y), y, 0.0)
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        fx, fy = x - x0, y - y0
        im = img.astype(np.float64)
        return ((1 - fx) * (1 - fy) * im[y0, x0] + fx * (1 - fy) * im[y0, x0 + 1]
                + (1 - fx) * fy * im[y0 + 1, x0] + fx * fy * im[y0 + 1, x0 + 1])

    for _ in range(iterations):
        fx, fy = at(mx, r) - target[:, 0], at(my, r) - target[:, 1]
        a, b, c, d = at(gxx, r), at(gxy, r), at(gyx, r), at(gyy, r)
        det = a * d - b * c
        det = np.where(np.abs(det) > 1e-9, det, 1e-9)
        r = r - np.stack([(d * fx - b * fy) / det, (a * fy - c * fx) / det], axis=1)
    inside = (r[:, 0] >= 0) & (r[:, 0] <= w - 1) & (r[:, 1] >= 0) & (r[:, 1] <= h - 1)
    inside &= np.isfinite(r).all(axis=1)
    # raw pixels the rectified view does not cover map outside it or onto its black border
    back = np.hypot(at(mx, r) - target[:, 0], at(my, r) - target[:, 1])
    inside &= back < 0.05
    r[~inside] = np.nan
    shape = (h, w) if points_px is None else (len(target),)
    return (r[:, 0].reshape(shape).astype(np.float32), r[:, 1].reshape(shape).astype(np.float32))


def resample_to_raw_left(
    maps: RectifyMaps, values: np.ndarray,
    coords: tuple[NDArray[np.float32], NDArray[np.float32]] | None = None,
) -> NDArray[np.float64]:
    """A map on the rectified left grid (NaN invalid) sampled at every raw left pixel.

    Bilinear where the four rectified neighbours are valid, else the nearest valid one among
    them (so depth steps are not blurred into invented depths); NaN where none is valid or the
    raw pixel lies outside the rectified view. ``coords`` may pass a cached
    :func:`raw_left_coordinates`.

    Raises:
        GeometryError: ``values`` is not the rig's size.
    """
    h, w = maps.height, maps.width
    vals = np.asarray(values, dtype=np.float64)
    if vals.shape != (h, w):
        raise GeometryError(f"values are {vals.shape[1]}x{vals.shape[0]}, the rig {w}x{h}")
    ru, rv = coords if coords is not None else raw_left_coordinates(maps)
    ok = np.isfinite(ru) & np.isfinite(rv)
    u = np.where(ok, ru, 0.0).astype(np.float64)
    v = np.where(ok, rv, 0.0).astype(np.float64)
    u0 = np.clip(np.floor(u).astype(np.int64), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, h - 2)
    fu, fv = u - u0, v - v0
    corners = [(v0, u0, (1 - fu) * (1 - fv)), (v0, u0 + 1, fu * (1 - fv)),
               (v0 + 1, u0, (1 - fu) * fv), (v0 + 1, u0 + 1, fu * fv)]
    samples = np.stack([vals[a, b] for a, b, _ in corners])
    weights = np.stack([wt for _, _, wt in corners])
    good = np.isfinite(samples)
    all_good = good.all(axis=0)
    with np.errstate(invalid="ignore"):
        bilinear = np.sum(np.where(good, samples, 0.0) * weights, axis=0)
    # nearest valid neighbour where some are missing
    pick = np.argmax(np.where(good, weights + 1.0, 0.0), axis=0)
    nearest = np.take_along_axis(samples, pick[None], axis=0)[0]
    out = np.where(all_good, bilinear, nearest)
    out[~(ok & good.any(axis=0))] = np.nan
    return out


def depth_error_map(
    depth: DepthResult, gt_depth_m: np.ndarray,
    coords: tuple[NDArray[np.float32], NDArray[np.float32]] | None = None,
) -> NDArray[np.float64]:
    """Signed depth error ``z_est - z_gt`` (metres, left camera frame) at every raw left pixel.

    The estimated points' ``z`` (left camera frame) is laid on the rectified grid where each was
    matched and resampled into the raw view (:func:`resample_to_raw_left`), so no raw pixel the
    rectified view covers is lost; ``gt_depth_m`` is the raw left camera's ground-truth depth.
    This is what the demo's depth-error picture should draw.

    Raises:
        GeometryError: a ground-truth map of another size than the rig's.
    """
    maps = depth.maps
    gt = np.asarray(gt_depth_m, dtype=np.float64)
    if gt.shape != (maps.height, maps.width):
        raise GeometryError(
            f"ground-truth depth is {gt.shape[1]}x{gt.shape[0]}, the rig "
            f"{maps.width}x{maps.height}"
        )
    valid = np.isfinite(depth.depth_m)
    if int(valid.sum()) != len(depth.points_left):
        raise GeometryError(
            f"{len(depth.points_left)} points for {int(valid.sum())} valid depth pixels; "
            "pass a DepthResult from compute_depth"
        )
    z_rect = np.full((maps.height, maps.width), np.nan)
    z_rect[valid] = depth.points_left[:, 2]
    return resample_to_raw_left(maps, z_rect, coords) - gt
