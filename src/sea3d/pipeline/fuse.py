"""``sea3d fuse``: RGB-D frames with known poses into one coloured TSDF mesh.

Frames are colour and depth files listed in natural order (``frame2`` before ``frame10``);
poses come from a trajectory file (TUM, KITTI or EuRoC CSV of ``T_world_cam``): pose ``k``
goes with frame ``k`` when the counts agree, otherwise frames are matched by the stamp in
their file names (integer nanoseconds, the session layout) within ``max_diff_s``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.recon.tsdf import TsdfConfig, TsdfVolume

__all__ = ["FuseResult", "fuse_rgbd", "match_frames_to_poses"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True, eq=False)
class FuseResult:
    """What :func:`fuse_rgbd` made.

    Attributes:
        mesh: the mesh, world frame.
        volume: the TSDF volume (for point clouds or more meshes).
        frames: frames integrated. skipped: frames without a pose.
        integrate_ms: per-frame integration times (TSDF only, no file reading), milliseconds.
        read_s: seconds spent reading files.
    """

    mesh: Mesh
    volume: TsdfVolume
    frames: int
    skipped: int
    integrate_ms: list[float] = field(default_factory=list)
    read_s: float = 0.0


def match_frames_to_poses(paths: list[Path], poses: Any, *, max_diff_s: float = 0.01
                          ) -> list[int | None]:
    """For each frame file, the index of its pose (None where none matches).

    Raises:
        ReconError: counts differ and the file names carry no stamps.
    """
    n = len(paths)
    if len(poses) == n:
        return list(range(n))
    try:
        stamps = np.array([int(p.stem) for p in paths], np.int64)
    except ValueError as err:
        raise ReconError(
            f"{n} frames but {len(poses)} poses, and the file names are not nanosecond "
            f"stamps to match them by (e.g. {paths[0].name})"
        ) from err
    out: list[int | None] = []
    tol = round(max_diff_s * 1e9)
    t = poses.t_ns
    for s in stamps:
        j = int(np.searchsorted(t, s))
        best = min((k for k in (j - 1, j) if 0 <= k < len(t)), key=lambda k: abs(int(t[k]) - s))
        out.append(best if abs(int(t[best]) - int(s)) <= tol else None)
    return out


def fuse_rgbd(
    color_paths: list[Path],
    depth_paths: list[Path],
    poses: Any,
    K: NDArray[np.float64],
    config: TsdfConfig,
    *,
    depth_scale: float = 1000.0,
    progress: Any = None,
) -> FuseResult:
    """Integrate every frame that has a pose.

    Args:
        color_paths, depth_paths: the frames' files, in order, equal in number.
        poses: :class:`~sea3d.io.trajectory_files.TrajectoryFile` of ``T_world_cam``.
        K: (3, 3) depth (and colour) intrinsics, pixels.
        config: :class:`~sea3d.recon.tsdf.TsdfConfig`.
        depth_scale: integer depth images hold metres times this.
        progress: called with 1 after each frame.

    Raises:
        ReconError: mismatched lists, an unreadable colour image, frames of other sizes.
        StereoError: an unreadable depth image (or 8-bit, or of several channels), a depth
            file whose grid sidecar says another grid than ``K``.
    """
    from sea3d.io.depth_files import DepthGrid, check_depth_pinhole, read_depth
    from sea3d.io.rgbd_files import read_color

    if len(color_paths) != len(depth_paths):
        raise ReconError(f"{len(color_paths)} colour images but {len(depth_paths)} depth images")
    if not color_paths:
        raise ReconError("no frames to fuse")
    which = match_frames_to_poses(depth_paths, poses)
    vol = TsdfVolume(config)
    times: list[float] = []
    read_s = 0.0
    skipped = 0
    shape: tuple[int, ...] | None = None
    grid: DepthGrid | None = None
    for cp, dp, k in zip(color_paths, depth_paths, which, strict=True):
        if k is None:
            skipped += 1
            if progress is not None:
                progress(1)
            continue
        t0 = time.perf_counter()
        depth = read_depth(dp, depth_scale)
        color = read_color(cp)
        read_s += time.perf_counter() - t0
        grid = check_depth_pinhole(dp, depth.shape, K, first=grid, consumer="fuse")
        if color.shape[:2] != depth.shape:
            raise ReconError(f"{cp} is {color.shape[1]}x{color.shape[0]} but {dp} is "
                             f"{depth.shape[1]}x{depth.shape[0]}")
        if shape is None:
            shape = depth.shape
        elif depth.shape != shape:
            raise ReconError(f"{dp} is {depth.shape[1]}x{depth.shape[0]}, the first frame "
                             f"{shape[1]}x{shape[0]}")
        t1 = time.perf_counter()
        vol.integrate(depth, color, K, poses.T_world_x[k])
        times.append(1000.0 * (time.perf_counter() - t1))
        if progress is not None:
            progress(1)
    if vol.frames == 0:
        raise ReconError("no frame had a pose")
    return FuseResult(mesh=vol.extract_mesh(), volume=vol, frames=vol.frames, skipped=skipped,
                      integrate_ms=times, read_s=read_s)
