"""The finish step of ``process`` and ``live``: final poses, merged mesh and cloud, outputs,
summary.

After the last frame the odometry's final keyframe poses re-anchor every stored submap; the
submaps are merged into one mesh (tile by tile, so memory stays bounded) and a cleaned cloud;
the trajectory, mesh, cloud, status.csv and results.mcap are written and summary.json's figures
gathered (:func:`finish_run`, which both commands call).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.io.process_outputs import FrameRow
from sea3d.odometry.types import TrackingStatus
from sea3d.pipeline.depth_scheduler import StageTimer
from sea3d.pipeline.ordered import OrderedStages, trusted_path_length_m
from sea3d.pipeline.progress import ProgressFactory

if TYPE_CHECKING:
    from sea3d.geometry.mesh import Mesh
    from sea3d.geometry.rig import StereoRig
    from sea3d.pipeline.config import MapConfig
    from sea3d.recon.cloud import CleanCloud
    from sea3d.recon.submaps import SubmapStore
    from sea3d.recon.tsdf import TsdfConfig

__all__ = ["FinishOptions", "FinishedRun", "Reconstruction", "finish_reconstruction",
           "finish_run", "frame_rows", "fusion_summary", "run_summary"]


@dataclass(frozen=True, kw_only=True)
class FinishOptions:
    """How a run's map is merged and cleaned at the finish step.

    Attributes:
        tile_m: edge of the merge's tiles (None: one tile).
        cloud_voxel_m: the cloud's downsampling voxel.
        min_piece_triangles: mesh pieces of fewer triangles, and the cloud points nearest to
            them, are dropped (0 keeps all).
    """

    tile_m: float | None
    cloud_voxel_m: float
    min_piece_triangles: int = 0

    @classmethod
    def of_map(cls, map_cfg: MapConfig) -> FinishOptions:
        """The options of a run's map configuration (``ProcessConfig.map``); the cloud's voxel
        is half the TSDF's unless set."""
        return cls(tile_m=map_cfg.merge_tile_m,
                   cloud_voxel_m=map_cfg.cloud_voxel_m or map_cfg.voxel_m / 2,
                   min_piece_triangles=map_cfg.min_piece_triangles)


@dataclass(frozen=True, kw_only=True, eq=False)
class Reconstruction:
    """Final poses, merged mesh and cleaned cloud of a run."""

    t_ns: NDArray[np.int64]
    T_world_left: F64
    mesh: Mesh
    cloud: CleanCloud
    submaps: int
    moved: int


def finish_reconstruction(stages: OrderedStages, store: SubmapStore, tsdf: TsdfConfig,
                          options: FinishOptions, *, progress: ProgressFactory,
                          timer: StageTimer) -> Reconstruction:
    """Final trajectory, merge of the stored submaps at the final keyframe poses, cloud.

    Args:
        stages: the ordered stages after the last frame (fusion finished).
        store: the submap store. tsdf: the TSDF configuration of the submaps.
        options: the merge's tiles, the cloud's voxel, the smallest mesh piece kept.
        progress: a progress bar factory ``(stage, total) -> bar``.
        timer: where ``merge_s`` and ``cloud_s`` are added.
    """
    from sea3d.geometry.mesh import drop_small_pieces
    from sea3d.recon.cloud import CloudConfig, clean_point_cloud
    from sea3d.recon.submaps import merge_submaps

    t, T = stages.final_trajectory()
    tm = time.perf_counter()
    bar = progress("merge", len(store.ids()))
    try:
        merged = merge_submaps(store, stages.final_keyframes_rect(), tsdf, tile_m=options.tile_m,
                               progress=bar.update)
    finally:
        bar.close()
    mesh, kept = drop_small_pieces(merged.mesh, options.min_piece_triangles)
    points, colors, normals = merged.points, merged.colors, merged.normals
    if not kept.all() and len(points):
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(merged.mesh.vertices).query(points)
        on = kept[nearest]
        points, colors, normals = points[on], colors[on], normals[on]
    timer.add("merge_s", time.perf_counter() - tm)
    tc = time.perf_counter()
    cloud = clean_point_cloud(points, colors, normals, CloudConfig(voxel_m=options.cloud_voxel_m))
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


@dataclass(frozen=True, kw_only=True, eq=False)
class FinishedRun:
    """What the shared finish step made: the reconstruction, the files written, and
    summary.json's content so far (the caller adds its own blocks and writes it).

    Attributes:
        rec: the final poses, merged mesh and cloud.
        files: output files by name (``summary`` is where summary.json goes).
        summary: summary.json's content, not yet written.
    """

    rec: Reconstruction
    files: dict[str, Path]
    summary: dict[str, Any]


def finish_run(stages: OrderedStages, store: SubmapStore, tsdf: TsdfConfig, out: Path,
               rig: StereoRig, options: FinishOptions, *, progress: ProgressFactory,
               timer: StageTimer,
               summary_extra: dict[str, Any]) -> FinishedRun:
    """The finish step after the last frame: merge and cloud (:func:`finish_reconstruction`),
    the outputs (trajectory, mesh, cloud, status.csv, results.mcap; timed as ``write_s``)
    and summary.json's figures (:func:`run_summary`).

    Args:
        stages: the ordered stages after the last frame (fusion finished).
        store: the submap store.
        tsdf: the TSDF configuration of the submaps.
        out: the output folder.
        rig: the rectified rig written with the outputs.
        options: :class:`FinishOptions`.
        progress: a progress bar factory ``(stage, total) -> bar``.
        timer: where ``merge_s``, ``cloud_s`` and ``write_s`` are added.
        summary_extra: the run's own summary figures, in order (see :func:`run_summary`).
    """
    from sea3d.io.process_outputs import write_process_outputs

    rec = finish_reconstruction(stages, store, tsdf, options, progress=progress, timer=timer)
    tw = time.perf_counter()
    files = write_process_outputs(out, t_ns=rec.t_ns, T_world_left=rec.T_world_left,
                                  rows=frame_rows(stages), mesh=rec.mesh, cloud=rec.cloud,
                                  rig=rig)
    timer.add("write_s", time.perf_counter() - tw)
    return FinishedRun(rec=rec, files=files, summary=run_summary(stages, rec, **summary_extra))


def fusion_summary(map_cfg: MapConfig, tsdf: TsdfConfig) -> dict[str, Any]:
    """summary.json's ``fusion`` block: the settings that decided what the mesh keeps.

    Args:
        map_cfg: the run's map configuration (``ProcessConfig.map``).
        tsdf: the TSDF configuration of the submaps.
    """
    return {"min_observations": map_cfg.min_observations,
            "min_piece_triangles": map_cfg.min_piece_triangles,
            "hole_margin_px": tsdf.hole_margin_px,
            "carve_free_space": tsdf.carve_free_space,
            "depth_noise_per_m": tsdf.depth_noise_per_m,
            "min_confidence": tsdf.min_confidence,
            "confidence_full": tsdf.confidence_full}
