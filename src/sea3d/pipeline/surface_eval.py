"""A mesh against a reference mesh (``sea3d eval surface``): how the two are brought into one
frame, then the accuracy and completeness figures (:func:`sea3d.eval.surface.surface_metrics`).

The alignment, by ``align``:

- ``auto``: a mesh of ``sea3d process`` whose ``summary.json`` says it is in the ground truth's
  frame is taken as is; else the estimated ``trajectory.tum`` beside the mesh and the ground
  truth's ``poses_left.tum`` that the summary names (or ``trajectories`` when given) give an
  SE(3) by Umeyama on the paired poses; nothing found: no alignment, with a warning.
- ``se3`` / ``sim3``: from ``trajectories`` (or the ones found as for ``auto``); ``sim3`` also
  fits scale. Only frames the status file beside the estimate trusts are used (when at least
  three are).
- ``icp``: ICP, started from the trajectories' alignment when there is one.
- ``none``: the surfaces are taken to be in one frame.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sea3d.errors import ReconError

__all__ = ["SurfaceEvaluation", "align_mesh_to_reference", "evaluate_surface"]

log = logging.getLogger(__name__)


def _process_summary(mesh: Path) -> tuple[Path, dict[str, Any]]:
    from sea3d.io.process_outputs import read_summary_json

    path = mesh.parent / "summary.json"
    return path, read_summary_json(path) or {}


def _from_trajectories(trajectories: tuple[Path, Path], align: str, max_diff_s: float) -> Any:
    from sea3d.eval.surface import align_by_trajectories
    from sea3d.eval.trajectory import associate
    from sea3d.io.odometry_outputs import read_trusted_stamps
    from sea3d.io.trajectory_files import read_trajectory

    te, tr = read_trajectory(trajectories[0]), read_trajectory(trajectories[1])
    t_e, T_e = te.t_ns, te.T_world_x
    trusted = read_trusted_stamps(Path(trajectories[0]).parent / "status.csv")
    if trusted is not None and te.timed:
        keep = np.isin(t_e, trusted)
        if keep.sum() >= 3:
            t_e, T_e = t_e[keep], T_e[keep]
    by_index = not (te.timed and tr.timed)
    if not by_index and len(te.t_ns) == len(tr.t_ns):
        # Same count but stamps that mostly do not meet (frame indices against a camera
        # clock): frame order, as 'sea3d fuse' pairs poses with frames.
        n_timed = len(associate(te.t_ns, tr.t_ns, round(max_diff_s * 1e9))[0])
        if n_timed < max(3, len(te.t_ns) // 2):
            by_index = True
            t_e, T_e = te.t_ns, te.T_world_x
            log.info("the trajectories' stamps do not pair up; paired in frame order")
    return align_by_trajectories(t_e, T_e, tr.t_ns, tr.T_world_x, with_scale=align == "sim3",
                                 by_index=by_index, max_diff_s=max_diff_s)


def align_mesh_to_reference(
    mesh_path: str | os.PathLike[str],
    est: Any,
    ref: Any,
    *,
    align: str = "auto",
    trajectories: tuple[str | os.PathLike[str], str | os.PathLike[str]] | None = None,
    max_diff_s: float = 0.01,
    icp_max_distance_m: float | None = None,
    reference_name: str = "the reference",
) -> tuple[Any, str]:
    """The transform of the mesh into the reference's frame (see the module docstring), and a
    line saying how it was found.

    Args:
        mesh_path: the mesh file (its folder holds a process run's summary and trajectory).
        est, ref: the meshes (``vertices``, ``triangles``).
        align: ``auto``, ``none``, ``se3``, ``sim3`` or ``icp``.
        trajectories: (estimate in the mesh's world, reference in the reference's).
        max_diff_s: largest stamp difference of a pose pair, seconds.
        icp_max_distance_m: ICP's largest correspondence distance (None: its default).
        reference_name: the reference as the warning names it.

    Returns:
        ``(SurfaceAlignment, how)``.

    Raises:
        ReconError: ``se3``/``sim3`` with no trajectories given or found.
    """
    from sea3d.eval.surface import NO_ALIGNMENT, align_by_icp

    mesh = Path(mesh_path)
    found = None if trajectories is None else (Path(trajectories[0]), Path(trajectories[1]))
    summary_path, summary = _process_summary(mesh)
    frames = summary.get("frame_of_file")
    frame = frames.get(mesh.name, "") if isinstance(frames, dict) else ""
    if found is None and align != "none":
        if "ground truth" in frame and align == "auto":
            return NO_ALIGNMENT, f"{mesh.name} is in the ground truth's frame ({summary_path})"
        gt_root = summary.get("ground_truth")
        if (gt_root and (Path(gt_root) / "poses_left.tum").is_file()
                and (mesh.parent / "trajectory.tum").is_file()):
            found = (mesh.parent / "trajectory.tum", Path(gt_root) / "poses_left.tum")
    if found is None and align in ("se3", "sim3"):
        raise ReconError(f"align {align} needs trajectories EST GT")
    result = NO_ALIGNMENT
    if found is not None and align != "none":
        result = _from_trajectories(found, align, max_diff_s)
    if align == "icp":
        result = align_by_icp(est.vertices, est.triangles, ref.vertices, ref.triangles,
                              init=result, max_distance_m=icp_max_distance_m)
    if result.method == "none":
        if align == "none":
            return result, "not aligned (align none)"
        log.warning("nothing aligns %s with %s: the figures assume both are in one frame. A "
                    "mesh of 'sea3d process' is in the odometry's world: give trajectories "
                    "EST GT, or align by ICP for surfaces that already roughly overlap", mesh,
                    reference_name)
        return result, "not aligned"
    how = (f"aligned {result.method} from {found[0]} and {found[1]}"
           if found is not None else f"aligned {result.method}")
    how += (f" ({result.pairs} pairs, residual {1000 * (result.residual_m or 0):.1f} mm: "
            f"{result.residual_of}" + (f"; fitness {100 * result.fitness:.0f} %"
                                       if result.fitness is not None else "")
            + (f"; scale {result.scale:.4f}" if result.scale != 1.0 else "") + ")")
    return result, how


@dataclass(frozen=True, kw_only=True, eq=False)
class SurfaceEvaluation:
    """A mesh against a reference.

    Attributes:
        metrics: accuracy, completeness, precision/recall/F-score
            (:class:`~sea3d.eval.surface.SurfaceMetrics`).
        alignment: the transform applied to the mesh (``SurfaceAlignment``).
        how: a line saying how the alignment was found.
    """

    metrics: Any
    alignment: Any
    how: str


def evaluate_surface(
    mesh_path: str | os.PathLike[str],
    reference_path: str | os.PathLike[str],
    *,
    align: str = "auto",
    trajectories: tuple[str | os.PathLike[str], str | os.PathLike[str]] | None = None,
    max_diff_s: float = 0.01,
    icp_max_distance_m: float | None = None,
    samples: int = 200_000,
    thresholds_m: tuple[float, ...] | None = None,
    crop_margin_m: float | None = None,
) -> SurfaceEvaluation:
    """Read both meshes, align (:func:`align_mesh_to_reference`) and measure.

    Raises:
        ReconError: unreadable meshes, or an alignment that needs trajectories.
    """
    from sea3d.eval.surface import DEFAULT_THRESHOLDS_M, surface_metrics
    from sea3d.io.mesh_files import read_mesh

    est, ref = read_mesh(mesh_path), read_mesh(reference_path)
    alignment, how = align_mesh_to_reference(
        mesh_path, est, ref, align=align, trajectories=trajectories, max_diff_s=max_diff_s,
        icp_max_distance_m=icp_max_distance_m, reference_name=str(reference_path))
    m = surface_metrics(alignment.apply(est.vertices), est.triangles, ref.vertices,
                        ref.triangles, samples=samples,
                        thresholds_m=DEFAULT_THRESHOLDS_M if thresholds_m is None
                        else thresholds_m, crop_margin_m=crop_margin_m)
    return SurfaceEvaluation(metrics=m, alignment=alignment, how=how)
