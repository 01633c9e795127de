"""The finish step of the process pipeline: final poses, merged mesh and cloud, summary.

After the last frame the odometry's final keyframe poses re-anchor every stored submap; the
submaps are merged into one mesh (tile by tile, so memory stays bounded) and a cleaned cloud.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.io.process_outputs import FrameRow
from sea3d.odometry.types import TrackingStatus
from sea3d.pipeline.depth_scheduler import StageTimer
from sea3d.pipeline.ordered import OrderedStages, trusted_path_length_m

__all__ = ["Reconstruction", "finish_reconstruction", "frame_rows", "run_summary"]


@dataclass(frozen=True, kw_only=True, eq=False)
class Reconstruction:
    """Final poses, merged mesh and cleaned cloud of a run."""

    t_ns: NDArray[np.int64]
    T_world_left: F64
    mesh: Any
    cloud: Any
    submaps: int
    moved: int


def finish_reconstruction(stages: OrderedStages, store: Any, tsdf: Any, *,
                          tile_m: float | None, cloud_voxel_m: float, progress: Any,
                          timer: StageTimer, min_piece_triangles: int = 0) -> Reconstruction:
    """Final trajectory, merge of the stored submaps at the final keyframe poses, cloud.

    Args:
        stages: the ordered stages after the last frame (fusion finished).
        store: the submap store. tsdf: the TSDF configuration of the submaps.
        tile_m: edge of the merge's tiles. cloud_voxel_m: the cloud's downsampling voxel.
        progress: a progress bar factory ``(stage, total) -> bar``.
        timer: where ``merge_s`` and ``cloud_s`` are added.
        min_piece_triangles: mesh pieces of fewer triangles, and the cloud points nearest to
            them, are dropped (0 keeps all).
    """
    from sea3d.geometry.mesh import drop_small_pieces
    from sea3d.recon.cloud import CloudConfig, clean_point_cloud
    from sea3d.recon.submaps import merge_submaps

    t, T = stages.final_trajectory()
    tm = time.perf_counter()
    bar = progress("merge", len(store.ids()))
    try:
        merged = merge_submaps(store, stages.final_keyframes_rect(), tsdf, tile_m=tile_m,
                               progress=bar.update)
    finally:
        bar.close()
    mesh, kept = drop_small_pieces(merged.mesh, min_piece_triangles)
    points, colors, normals = merged.points, merged.colors, merged.normals
    if not kept.all() and len(points):
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(merged.mesh.vertices).query(points)
        on = kept[nearest]
        points, colors, normals = points[on], colors[on], normals[on]
    timer.add("merge_s", time.perf_counter() - tm)
    tc = time.perf_counter()
    cloud = clean_point_cloud(points, colors, normals, CloudConfig(voxel_m=cloud_voxel_m))
    timer.add("cloud_s", time.perf_counter() - tc)
    return Reconstruction(t_ns=t, T_world_left=T, mesh=mesh, cloud=cloud,
                          submaps=merged.submaps, moved=merged.moved)


def frame_rows(stages: OrderedStages) -> list[FrameRow]:
    """status.csv's rows: one per frame the ordered stages saw."""
    return [FrameRow(t_ns=int(e.t_ns), status=e.status.value, segment=int(e.segment),
                     keyframe_id=e.keyframe_id, anchor_keyframe_id=e.anchor_keyframe_id,
                     loop_closure=bool(e.loop_closure), tracked_features=int(e.tracked_features),
                     depth=st, valid_depth_fraction=float(vf), fusion=fs)
            for e, fs, st, vf in zip(stages.estimates, stages.fuse_status, stages.frame_status,
                                     stages.valid_fraction, strict=True)]


def run_summary(stages: OrderedStages, rec: Reconstruction, **extra: Any) -> dict[str, Any]:
    """summary.json's figures of the frames, odometry, fusion and outputs (``extra`` adds the
    run's own: session, executor, configuration...; their order is kept)."""
    statuses = [e.status for e in stages.estimates]
    seg = np.array([e.segment for e in stages.estimates], np.int64)
    counts = {s.value: int(sum(1 for x in statuses if x == s)) for s in TrackingStatus}
    head = {k: extra.pop(k) for k in ("session", "pairs_in_session") if k in extra}
    return {
        "session": head.get("session"),
        "frames": len(stages.estimates),
        "pairs_in_session": head.get("pairs_in_session"),
        "keyframes": int(sum(1 for e in stages.estimates if e.keyframe_id is not None)),
        "frames_lost": counts[TrackingStatus.LOST.value],
        "frames_imu_only": counts[TrackingStatus.IMU_ONLY.value],
        "frames_relocalised": counts[TrackingStatus.RELOCALISED.value],
        "frames_tracking": counts[TrackingStatus.TRACKING.value],
        "frames_initialising": counts[TrackingStatus.INITIALISING.value],
        "frames_unreadable": extra.pop("frames_unreadable", 0),
        "frames_failed": stages.failed,
        "frames_fused": int(sum(1 for s in stages.fuse_status if s == "integrated")),
        "frames_from_cache": extra.pop("frames_from_cache", 0),
        "loop_closures": stages.loop_closures,
        "relinks": stages.relinks,
        "loop_checks": stages.loop_checks.as_dict(),
        "segments": int(seg.max() + 1) if len(seg) else 0,
        "path_length_m": trusted_path_length_m(rec.T_world_left, statuses, seg),
        **extra,
        "submaps": rec.submaps,
        "submaps_moved_by_loop_closures": rec.moved,
        "active_submap_peak_mb": stages.fusion.peak_memory_bytes / 2**20,
        "mesh": {"vertices": len(rec.mesh.vertices), "triangles": len(rec.mesh.triangles)},
        "cloud": {"points": len(rec.cloud.points), "outliers_removed": rec.cloud.outliers},
        "mean_valid_depth_fraction": (float(np.mean(stages.valid_fraction))
                                      if stages.valid_fraction else 0.0),
    }
