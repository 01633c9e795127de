"""Reconstruction-side use of a session's ground truth (found and read through
:mod:`sea3d.io.ground_truth`, which owns where it lives and what its files are called)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import Sea3dError
from sea3d.geometry.camera import CameraModel
from sea3d.io.ground_truth import GroundTruth, find_ground_truth, gt_depth_path, read_gt_depth

__all__ = ["GroundTruth", "evaluate_against_ground_truth", "find_ground_truth",
           "observed_surface_points"]

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
    max_frames: int = 200,
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
        max_frames: at most this many depth maps are read (the frame stride grows past
            ``frame_stride`` for longer runs), so the points stay bounded whatever the
            length of the dive: a long survey over the same ground sees the same surface
            again, and the surface metrics draw a fixed number of samples from these
            points anyway (200,000, :func:`~sea3d.eval.surface.surface_metrics`).

    Returns:
        (M, 3) float64 world points (empty when no depth map was found).
    """
    out = []
    v, u = np.mgrid[0:camera.height:pixel_stride, 0:camera.width:pixel_stride]
    uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    rays = camera.unproject(uv)
    stride = max(int(frame_stride), -(-len(t_ns) // max(int(max_frames), 1)))
    for k in range(0, len(t_ns), stride):
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


def evaluate_against_ground_truth(session: Path, *, t_ns: NDArray[np.int64],
                                  T_world_left: NDArray[np.float64],
                                  trusted: NDArray[np.bool_], mesh: object, camera: CameraModel,
                                  max_depth_m: float) -> dict[str, object]:
    """Load the ground truth beside ``session`` (if any) and compare a run with it
    (:func:`sea3d.eval.process_eval.process_metrics`): ``{"ground_truth": None}`` without
    one, else its folder, ``trajectory_vs_gt`` and ``mesh_vs_gt``.

    Args:
        session: the processed session.
        t_ns, T_world_left, trusted: (N,) stamps, (N, 4, 4) final poses, (N,) trusted flags.
        mesh: the run's mesh (world frame). camera: the (scaled) left camera.
        max_depth_m: farthest depth fused (the observed surface is cut there too).
    """
    from sea3d.eval.process_eval import process_metrics
    from sea3d.io.mesh_files import read_mesh
    from sea3d.io.trajectory_files import read_trajectory

    gt = find_ground_truth(session)
    if gt is None:
        return {"ground_truth": None}
    out: dict[str, object] = {"ground_truth": str(gt.root)}
    gt_t = gt_T = scene = observed = None
    if gt.poses_left is not None:
        try:
            traj = read_trajectory(gt.poses_left)
            gt_t, gt_T = traj.t_ns, traj.T_world_x
        except Sea3dError as err:
            out["trajectory_vs_gt"] = {"error": str(err)}
    if gt.scene_mesh is not None:
        try:
            scene = read_mesh(gt.scene_mesh)
        except Sea3dError as err:
            out["mesh_vs_gt"] = {"error": str(err)}
        if scene is not None and gt.depth_dir is not None and gt_t is not None and \
                gt_T is not None:
            observed = observed_surface_points(gt.depth_dir, camera, gt_t, gt_T,
                                               max_depth_m=max_depth_m)
            if len(observed) == 0:
                observed = None
    out.update(process_metrics(t_ns=t_ns, T_world_left=T_world_left, trusted=trusted,
                               mesh=mesh, gt_t_ns=gt_t, gt_T_world_left=gt_T, scene=scene,
                               observed_points=observed))
    return out
