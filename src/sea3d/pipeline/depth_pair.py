"""Stereo depth of one pair (``sea3d depth --left L --right R``): the checks, the recipe, the
depth on the pixel grid asked for and its figures; the caller reads the images and writes the
files (:mod:`sea3d.io.depth_files`)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import StereoError
from sea3d.geometry.rig import StereoRig
from sea3d.io.depth_files import DepthGrid
from sea3d.stereo.depth import DepthResult
from sea3d.stereo.recipe import DepthConfig

if TYPE_CHECKING:
    from sea3d.rectify.maps import RectifyMaps

__all__ = ["DepthPair", "depth_on_grid", "depth_pair", "rectified_grid"]


def rectified_grid(maps: RectifyMaps, rig: StereoRig) -> DepthGrid:
    """The :class:`~sea3d.io.depth_files.DepthGrid` of depth as matched (rectified left)."""
    from sea3d.io.depth_files import rig_identity
    from sea3d.io.rig_file import rig_to_yaml

    K = maps.P_left[:3, :3]
    return DepthGrid(kind="rectified-left", width_px=int(maps.width),
                     height_px=int(maps.height), K=tuple(tuple(float(x) for x in r) for r in K),
                     rig_id=rig_identity(rig_to_yaml(rig)))


def depth_on_grid(depth_rect_m: NDArray[np.floating], maps: RectifyMaps, rig: StereoRig,
                  grid: str) -> tuple[NDArray[np.floating], DepthGrid]:
    """Depth on the asked grid: ``rectified`` (as matched) or ``raw`` (resampled onto the raw
    left camera's pixels), with its :class:`~sea3d.io.depth_files.DepthGrid`.

    Raises:
        StereoError: an unknown grid.
    """
    if grid == "rectified":
        return depth_rect_m, rectified_grid(maps, rig)
    if grid != "raw":
        raise StereoError(f"depth grid must be 'rectified' or 'raw', got {grid!r}")
    from sea3d.io.depth_files import rig_identity
    from sea3d.io.rig_file import rig_to_yaml
    from sea3d.rectify.depth_grid import rectified_depth_to_raw

    K_rect = np.asarray(maps.P_left[:3, :3], dtype=np.float64)
    depth = rectified_depth_to_raw(depth_rect_m, K_rect, maps.R_rect_left_left, rig.left)
    pin = rig.left.lens
    K = np.array([[pin.fx, 0.0, pin.cx], [0.0, pin.fy, pin.cy], [0.0, 0.0, 1.0]])
    g = DepthGrid(kind="raw-left", width_px=rig.width, height_px=rig.height,
                  K=tuple(tuple(float(x) for x in r) for r in K),
                  rig_id=rig_identity(rig_to_yaml(rig)))
    return depth, g


@dataclass(frozen=True, kw_only=True, eq=False)
class DepthPair:
    """Depth of one pair.

    Attributes:
        depth_m: (H, W) float32 metres (NaN invalid) on ``grid``.
        grid: the pixel grid of ``depth_m``.
        result: the matcher's result on the rectified grid (points, colours, timings).
        summary: figures: ``n_points``, ``valid_fraction``, ``median_depth_m``, ``refractive``,
            ``focal_px``, ``baseline_m``, ``max_disparity_px``, ``depth_range_m``, ``match_s``,
            ``rectify_s``, ``depth_s``, ``rectify_maps_s``, ``compile_s`` and, for a refractive
            rig, the virtual pinholes' fit errors.
    """

    depth_m: NDArray[np.floating]
    grid: DepthGrid
    result: DepthResult
    summary: dict[str, Any]


def depth_pair(rig: StereoRig, left: NDArray[Any], right: NDArray[Any], config: DepthConfig,
               *, grid: str = "rectified", names: tuple[str, str, str] = ("left", "right", "rig")
               ) -> DepthPair:
    """Match one raw stereo pair of ``rig`` into depth.

    Args:
        rig: the rig the images come from.
        left, right: raw images (H, W[, 3]) of the rig's size.
        config: the stereo depth recipe's settings.
        grid: ``rectified`` or ``raw`` (see :func:`depth_on_grid`).
        names: the left image, right image and rig as the messages name them (file names).

    Raises:
        StereoError: images of another size than the rig's; an unknown grid.
    """
    from sea3d.stereo.recipe import StereoDepth

    for side, img, name in (("left", left, names[0]), ("right", right, names[1])):
        if img.shape[:2] != (rig.height, rig.width):
            raise StereoError(
                f"{side} image {name} is {img.shape[1]}x{img.shape[0]} but the rig "
                f"{names[2]} is {rig.width}x{rig.height}"
            )
    t0 = time.perf_counter()
    stereo = StereoDepth(rig, config)
    rectify_maps_s = time.perf_counter() - t0
    maps = stereo.maps
    compile_s = stereo.warm_up()
    res = stereo.compute(left, right)
    depth, g = depth_on_grid(res.depth_m, maps, rig, grid)
    valid_fraction = float(np.isfinite(res.depth_m).mean())
    summary: dict[str, Any] = {
        "n_points": len(res.points_left),
        "valid_fraction": valid_fraction,
        "median_depth_m": float(np.nanmedian(res.depth_m)) if valid_fraction > 0 else None,
        "refractive": maps.refractive,
        "focal_px": maps.focal_px,
        "baseline_m": maps.baseline_m,
        "max_disparity_px": stereo.max_disparity_px,
        "depth_range_m": list(stereo.depth_range_m),
        "match_s": res.timings_s["match_s"],
        "rectify_s": res.timings_s["rectify_s"],
        "depth_s": res.timings_s["depth_s"],
        "rectify_maps_s": rectify_maps_s,
        "compile_s": compile_s,
    }
    for side, rep in (("left", maps.report_left), ("right", maps.report_right)):
        if rep is not None:
            summary[f"virtual_pinhole_{side}_rms_px"] = rep.rms_px
            summary[f"virtual_pinhole_{side}_max_px"] = rep.max_px
    return DepthPair(depth_m=depth, grid=g, result=res, summary=summary)
