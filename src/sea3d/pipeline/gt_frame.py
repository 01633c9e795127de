"""Outputs of ``sea3d process`` in the ground truth's frame, beside those in the odometry's.

The odometry's world is its first left camera; a simulated (or surveyed) scene mesh lives in
the ground truth's world. When a session has ground-truth poses, ``process`` fits the rigid
``T_gt_world`` between the two trajectories and writes the mesh and trajectory through it as
well, so that ``sea3d eval surface OUT/mesh_gt_frame.ply SCENE`` compares like with like.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["FRAME_GT", "FRAME_ODOMETRY", "write_in_ground_truth_frame"]

FRAME_ODOMETRY = "the odometry's world (the first left camera)"
FRAME_GT = "the ground truth's world"


def write_in_ground_truth_frame(result: Any, T_gt_world: NDArray[np.float64]) -> dict[str, Any]:
    """Write ``mesh_gt_frame.ply`` and ``trajectory_gt_frame.tum`` into ``result.out_dir``.

    Args:
        result: the :class:`~sea3d.pipeline.process.ProcessResult` (its ``files`` gains the
            two paths, as ``mesh_gt_frame`` and ``trajectory_gt_frame``).
        T_gt_world: (4, 4) rigid transform from the odometry's world to the ground truth's.

    Returns:
        ``{"frame_of_file": {file name: frame}, "T_gt_world": 4x4 list}`` for summary.json.
    """
    from sea3d.io.mesh_files import write_mesh
    from sea3d.io.trajectory_files import write_tum

    T = np.asarray(T_gt_world, dtype=np.float64)
    out = result.out_dir
    mesh_path = out / "mesh_gt_frame.ply"
    traj_path = out / "trajectory_gt_frame.tum"
    write_mesh(mesh_path, result.mesh.transformed(T))
    write_tum(traj_path, result.t_ns, T[None] @ result.T_world_left,
              header="t x y z qx qy qz qw: T_gt_left, trajectory.tum moved into the ground "
                     "truth's world by summary.json's T_gt_world")
    result.files["mesh_gt_frame"] = mesh_path
    result.files["trajectory_gt_frame"] = traj_path
    return {
        "frame_of_file": {
            "trajectory.tum": FRAME_ODOMETRY, "mesh.ply": FRAME_ODOMETRY,
            "cloud.ply": FRAME_ODOMETRY, "results.mcap": FRAME_ODOMETRY,
            mesh_path.name: FRAME_GT, traj_path.name: FRAME_GT,
        },
        "T_gt_world": T.tolist(),
    }
