"""A processed dive against its ground truth: trajectory (ATE) and mesh (accuracy, completeness).

Pure metrics on arrays: the caller loads the ground truth (``sea3d.pipeline.groundtruth``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import Sea3dError

__all__ = ["pose_alignment", "process_metrics"]


def pose_alignment(t_est: NDArray[np.int64], T_est: F64, t_ref: NDArray[np.int64],
                   T_ref: F64, axis_m: float = 1.0) -> F64:
    """The rigid ``T_ref_est`` that puts the estimate's world (and its mesh) onto the reference's.

    The ATE's alignment fits positions only, and a short survey leg is nearly a straight line:
    the rotation about it is then undetermined (an 8-frame demo dive came out upside down, the
    mesh 2.6 m off). Here every matched pose also gives the tips of its three axes, ``axis_m``
    out, so orientations pin the rotation even when the positions are collinear.

    Args:
        t_est, T_est: (N,) stamps and (N, 4, 4) ``T_world_left`` of the estimate.
        t_ref, T_ref: the same of the reference.
        axis_m: length of the axis tips, metres.

    Returns:
        (4, 4) ``T_ref_est`` (identity when no stamps match).
    """
    from sea3d.eval.trajectory import associate, umeyama

    i, j = associate(t_est, t_ref, 1_000_000)
    if i.size == 0:
        return np.eye(4)

    def points(T: F64) -> F64:
        p = T[:, :3, 3]
        tips = [p + axis_m * T[:, :3, a] for a in range(3)]
        return np.concatenate([p, *tips])

    R, t, _ = umeyama(points(T_est[i]), points(T_ref[j]), with_scale=False)
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = R, t
    return S


def process_metrics(
    *,
    t_ns: NDArray[np.int64],
    T_world_left: F64,
    trusted: NDArray[np.bool_],
    mesh: Any,
    gt_t_ns: NDArray[np.int64] | None,
    gt_T_world_left: F64 | None,
    scene: Any | None,
    observed_points: F64 | None,
) -> dict[str, Any]:
    """``trajectory_vs_gt`` (ATE of the trusted frames, SE(3)-aligned) and ``mesh_vs_gt``
    (the mesh moved by :func:`pose_alignment`, against the scene mesh; completeness against
    the surface seen in the ground-truth depth when ``observed_points`` is given).

    Args:
        t_ns, T_world_left, trusted: (N,) stamps, (N, 4, 4) poses, (N,) trusted flags.
        mesh: the estimate (``vertices``, ``triangles``, ``empty``, ``transformed``).
        gt_t_ns, gt_T_world_left: the reference trajectory, or None.
        scene: the reference mesh (``vertices``, ``triangles``), or None.
        observed_points: (M, 3) world points of the surface the cameras saw, or None.

    Returns:
        A dict with ``trajectory_vs_gt`` and/or ``mesh_vs_gt`` (each ``{"error": ...}`` when
        the metric cannot be computed), and ``T_gt_world``, the (4, 4) rigid transform from the
        estimate's world to the reference's, when the trajectories could be aligned.
    """
    from sea3d.eval.surface import surface_metrics
    from sea3d.eval.trajectory import evaluate_trajectory

    out: dict[str, Any] = {}
    T_ref_est = np.eye(4)
    if gt_t_ns is not None and gt_T_world_left is not None and len(t_ns) >= 3:
        try:
            m = evaluate_trajectory(t_ns[trusted], T_world_left[trusted], gt_t_ns,
                                    gt_T_world_left, align="se3", max_diff_s=0.001)
            out["trajectory_vs_gt"] = m.as_dict()
            T_ref_est = pose_alignment(t_ns[trusted], T_world_left[trusted], gt_t_ns,
                                       gt_T_world_left)
            out["T_gt_world"] = T_ref_est
        except Sea3dError as err:
            out["trajectory_vs_gt"] = {"error": str(err)}
    if scene is not None and not mesh.empty:
        try:
            moved = mesh.transformed(T_ref_est)
            sm = surface_metrics(moved.vertices, moved.triangles, scene.vertices,
                                 scene.triangles, reference_points=observed_points,
                                 samples=100_000)
            out["mesh_vs_gt"] = sm.as_dict()
            out["mesh_vs_gt"]["completeness_reference"] = (
                "surface seen in the ground-truth depth maps" if observed_points is not None
                else "the whole scene mesh")
        except Sea3dError as err:
            out["mesh_vs_gt"] = {"error": str(err)}
    return out
