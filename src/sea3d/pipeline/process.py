"""``sea3d process``: a whole session into a trajectory, a coloured mesh and a report.

::

    session ──► raw pairs in time order ──► per-frame stage (any order, any machine):
                                            [enhance] ─► rectify ─► match ─► exact depth
                                            ─► depth for the virtual pinhole
            ◄── results stream back, cached in OUT/cache/frames/<t_ns>.s3c as they arrive
    ordered stages, in time order:  odometry ─► fusion into keyframe-anchored TSDF submaps
                                    (finished submaps spilled to OUT/submaps/)
    after the last frame:           final keyframe poses ─► merged mesh and cloud
    ──► OUT/trajectory.tum, mesh.ply, cloud.ply, status.csv, summary.json, report.html,
        results.mcap (Foxglove)

Memory: at most ``in_flight`` frames are between the reader and the ordered stages at any
time (submitted, running, or finished and waiting for their turn), and fusion holds one
active submap; finished ones live on disk. A killed run loses at most the frames in flight:
a rerun with the same ``-o`` takes every cached frame from disk and runs the per-frame stage
only for the rest (the ordered stages, much cheaper, run again from the start).

The odometry is chosen in one place, :func:`make_odometry`: known poses (``--poses``) or
sea3d's stereo-inertial odometry (``sea3d.odometry.create_odometry``).

:func:`run_process` wires small stages together: the frame source
(:mod:`sea3d.pipeline.frame_source`), the depth scheduler over an executor and the cache
(:mod:`sea3d.pipeline.depth_scheduler`), the ordered stages (:mod:`sea3d.pipeline.ordered`,
the same that ``sea3d live`` runs) and the finish step (:mod:`sea3d.pipeline.finish`). Files
are written by :mod:`sea3d.io.process_outputs`; the comparison with ground truth is
:mod:`sea3d.eval.process_eval`.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError, SessionError
from sea3d.odometry.types import Odometry, TrackingStatus
from sea3d.pipeline.depth_scheduler import StageTimer
from sea3d.pipeline.frame_stage import FrameStageConfig, install_geometry, rectify_pair, stage_depth
from sea3d.pipeline.lock import locks_out_dir
from sea3d.pipeline.ordered import TRUSTED, OrderedStages
from sea3d.recon.submaps import FusionConfig
from sea3d.recon.tsdf import TsdfConfig
from sea3d.stereo.recipe import DepthConfig

__all__ = [
    "ProcessConfig",
    "ProcessResult",
    "ProgressFactory",
    "make_odometry",
    "run_process",
]

log = logging.getLogger(__name__)



class ProgressBar(Protocol):
    """What the pipeline needs of a progress bar (tqdm has it)."""

    def update(self, n: int = 1) -> Any: ...

    def close(self) -> None: ...


ProgressFactory = Callable[[str, int], ProgressBar]
"""``factory(stage, total)`` makes one bar per stage; the CLI passes tqdm."""


class _NoBar:
    def update(self, n: int = 1) -> None:
        return None

    def close(self) -> None:
        return None


def _no_progress(stage: str, total: int) -> ProgressBar:
    return _NoBar()


@dataclass(frozen=True, kw_only=True)
class ProcessConfig:
    """Options of ``sea3d process`` (the CLI's flags map one to one)."""

    out_dir: Path
    """Output folder (created); also holds the cache that makes reruns resume."""
    rig_path: Path | None = None
    """Rig file; None uses the rig stored with the session."""
    size_px: tuple[int, int] | None = None
    """Process at this ``(width, height)`` instead of the recorded size."""
    voxel_m: float = 0.02
    """TSDF voxel edge, metres."""
    use_imu: bool = True
    """Give the IMU to the odometry (``--no-imu``: visual only)."""
    workers: int | None = None
    """Local worker processes for the per-frame stage; None: one per core; 0: inline."""
    scheduler: str | Any | None = None
    """A Dask scheduler address (``tcp://HOST:PORT``) or ``distributed.Client``."""
    poses_path: Path | None = None
    """Known poses (TUM, KITTI or EuRoC CSV of ``T_world_left``) instead of odometry."""
    engine: str = "sea3d"
    """Stereo matching engine."""
    min_depth_m: float | None = None
    """Nearest depth resolved, metres; None: from the rig and the disparity range
    (:mod:`sea3d.stereo.recipe`)."""
    max_depth_m: float | None = None
    """Farthest depth used (stereo and TSDF), metres; None: from the rig (the smallest useful
    disparity, :mod:`sea3d.stereo.recipe`)."""
    max_disparity_px: int | None = None
    """Disparity range; None derives it from ``min_depth_m``, else from the image width."""
    integrate: Literal["trusted", "keyframes"] = "trusted"
    """Fuse every frame with a trusted pose, or keyframes only."""
    keyframes_per_submap: int = 20
    """Keyframes per TSDF submap."""
    max_submap_blocks: int = 20_000
    """Voxel blocks after which a submap is finished (bounds memory: 10 KB per block of 8^3
    voxels)."""
    in_flight: int | None = None
    """Frames between reader and ordered stages at most; None: 2 per worker + 2."""
    fresh: bool = False
    """Ignore (delete) cached per-frame results instead of resuming."""
    enhance: Any = None
    """Enhancement hook of the per-frame stage (see :class:`FrameStageConfig`)."""
    restore_colours: Literal["none", "seathru"] = "none"
    """Sea-thru on the output colours after depth (see :class:`FrameStageConfig`)."""
    cloud_voxel_m: float | None = None
    """Voxel of cloud.ply's downsampling; None: half ``voxel_m``."""
    merge_tile_m: float | None = 8.0
    """Edge of the tiles the final merge works through (bounds its memory)."""
    evaluate: bool = True
    """Compare with the simulator's ground truth when the session has one."""
    report: bool = True
    """Write report.html."""
    odometry_config: Any = None
    """Passed to ``create_odometry``."""
    max_frames: int | None = None
    """Process only the first N stereo pairs."""
    depth_rate: str | int = "all"
    """Which frames get stereo depth of their own (:mod:`sea3d.pipeline.depth_rate`):
    ``all``; ``auto`` (when the predicted motion since the last depth frame needs it); or
    every N-th frame. The odometry sees every frame (a frame without depth takes the latest
    depth map as its stereo seeds); fusion integrates the depth frames."""

    def frame_stage(self, rig: Any) -> FrameStageConfig:
        """The per-frame stage's configuration for ``rig`` (at the recorded size; threads per
        worker: the cores shared among the local workers; a Dask worker keeps its own)."""
        n_local = self.workers if self.workers is not None else min(os.cpu_count() or 1, 8)
        return FrameStageConfig(
            rig=rig, size_px=self.size_px,
            depth=DepthConfig(engine=self.engine, max_disparity_px=self.max_disparity_px,
                              min_depth_m=self.min_depth_m, max_depth_m=self.max_depth_m),
            enhance=self.enhance,
            restore_colours=self.restore_colours,
            threads=max(1, (os.cpu_count() or 1) // max(1, n_local))
            if self.scheduler is None else None)

    def fusion(self, depth_range_m: tuple[float, float]) -> FusionConfig:
        """The fusion stage's configuration (its TSDF over the stereo depth's range)."""
        return FusionConfig(tsdf=TsdfConfig(voxel_m=self.voxel_m, depth_min_m=depth_range_m[0],
                                            depth_max_m=depth_range_m[1]),
                            integrate=self.integrate,
                            keyframes_per_submap=self.keyframes_per_submap,
                            max_blocks=self.max_submap_blocks)

    def __post_init__(self) -> None:
        if not self.voxel_m > 0:
            raise ConfigError(f"--voxel-m must be > 0, got {self.voxel_m}")
        if self.workers is not None and self.scheduler is not None:
            raise ConfigError("give either --workers or --scheduler, not both")
        if self.workers is not None and self.workers < 0:
            raise ConfigError(f"--workers must be >= 0, got {self.workers}")
        if self.in_flight is not None and self.in_flight < 1:
            raise ConfigError(f"in_flight must be >= 1, got {self.in_flight}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ConfigError(f"--max-frames must be >= 1, got {self.max_frames}")
        from sea3d.pipeline.depth_rate import parse_depth_rate

        object.__setattr__(self, "depth_rate", parse_depth_rate(self.depth_rate))


@dataclass(frozen=True, kw_only=True, eq=False)
class ProcessResult:
    """What :func:`run_process` made (all of it is also on disk in ``out_dir``).

    Attributes:
        out_dir: the output folder.
        t_ns: (N,) stamps of every processed stereo frame.
        T_world_left: (N, 4, 4) final poses.
        statuses: (N,) tracking status of each frame.
        mesh: the merged mesh (world frame).
        cloud_points, cloud_colors: cloud.ply's points (M, 3) and colours (M, 3) uint8.
        summary: summary.json's content.
        files: output files by name.
    """

    out_dir: Path
    t_ns: NDArray[np.int64]
    T_world_left: F64
    statuses: list[TrackingStatus]
    mesh: Any
    cloud_points: F64
    cloud_colors: NDArray[np.uint8]
    summary: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)


def make_odometry(rig: Any, maps: Any, *, use_imu: bool, poses: Any | None,
                  config: Any = None) -> tuple[Odometry, str]:
    """The one place that chooses the ordered pose stage.

    Args:
        rig: the (scaled) stereo rig. maps: its rectification.
        use_imu: let the odometry use the IMU.
        poses: a :class:`~sea3d.io.trajectory_files.TrajectoryFile` of known ``T_world_left``
            (then no odometry runs), or None.
        config: the odometry's own configuration.

    Returns:
        ``(odometry, description)``.
    """
    if poses is not None:
        from sea3d.odometry.reference import KnownPoses

        return KnownPoses(poses.t_ns, poses.T_world_x), f"known poses from {poses.path}"
    from sea3d.odometry import create_odometry

    odo = create_odometry(rig, maps, use_imu=use_imu, config=config)
    reason = odo.imu_disabled_reason
    mode = "stereo-inertial" if use_imu and reason is None else "visual"
    return odo, f"sea3d {mode} odometry" + (f" ({reason})" if mode == "visual" and reason else "")


def _rss_mb(who: int) -> float:
    return float(resource.getrusage(who).ru_maxrss) / 1024.0


def _rig(session: Any, config: ProcessConfig) -> Any:
    """``--rig``'s rig, else the session's stored one (:func:`~sea3d.io.rig_file.resolve_rig`)."""
    from sea3d.io.rig_file import resolve_rig

    return resolve_rig(config.rig_path, session)


def _frame_cache(out: Path, stage: FrameStageConfig, session_path: Path, fresh: bool) -> Any:
    from sea3d.io.result_cache import FrameCache

    cache = FrameCache(out / "cache", {"stage": stage.fingerprint(),
                                       "session": str(session_path.resolve())})
    if fresh:
        cache.clear()
    if not cache.check_fingerprint():
        raise ConfigError(f"{out} holds cached results of another configuration or session; "
                          "use another -o, or --fresh to discard them")
    return cache


def _odometry(config: ProcessConfig, stereo: Any, session_path: Path, has_imu: bool,
              factory: Callable[[Any, Any], Odometry] | None) -> tuple[Odometry, str, bool]:
    """The pose stage, its description, and whether it gets the IMU."""
    from sea3d.io.trajectory_files import read_trajectory

    use_imu = config.use_imu and has_imu
    if config.use_imu and not has_imu:
        log.warning("%s has no IMU samples: the odometry runs visual-only", session_path)
    if factory is not None:
        odo = factory(stereo.rig, stereo.maps)
        return odo, str(getattr(odo, "name", type(odo).__name__)), use_imu
    poses = read_trajectory(config.poses_path) if config.poses_path else None
    odo, name = make_odometry(stereo.rig, stereo.maps, use_imu=use_imu, poses=poses,
                              config=config.odometry_config)
    return odo, name, use_imu and poses is None


def _depth_rate(config: ProcessConfig, stereo: Any) -> Any:
    """The :class:`~sea3d.pipeline.depth_rate.DepthRate` of ``config`` (None: every frame)."""
    from sea3d.pipeline.depth_rate import DepthRate

    if config.depth_rate in ("all", 1):
        return None
    maps = stereo.maps
    return DepthRate(config.depth_rate, K=np.asarray(maps.P_left[:3, :3], np.float64),
                     width_px=int(maps.width), trusted=TRUSTED)


@locks_out_dir  # two runs into one folder: the second is refused (OutputInUseError)
def run_process(
    session_path: str | os.PathLike[str],
    config: ProcessConfig,
    *,
    progress: ProgressFactory | None = None,
    on_result: Callable[[ProcessResult], None] | None = None,
    odometry: Callable[[Any, Any], Odometry] | None = None,
) -> ProcessResult:
    """Process a recorded session into a trajectory, mesh, cloud and report (see the module).

    Args:
        session_path: an MCAP file or session folder.
        config: :class:`ProcessConfig`.
        progress: progress-bar factory (the CLI's tqdm); None shows nothing.
        on_result: called with the result at the end.
        odometry: ``factory(rig, maps) -> Odometry`` to use instead of :func:`make_odometry`
            (another estimator, or a test double).

    Returns:
        :class:`ProcessResult`.

    Raises:
        SessionError: unreadable session, no stereo pairs, no rig.
        ConfigError: bad options, a cache made with another configuration (without
            ``fresh``).
        OdometryError, ReconError: invalid data reaching those stages.
    """
    from sea3d.io.session import open_session
    from sea3d.pipeline.depth_scheduler import DepthScheduler
    from sea3d.pipeline.executors import make_executor
    from sea3d.pipeline.frame_source import SessionFrames, imu_between
    from sea3d.pipeline.submap_store import DiskSubmapStore
    from sea3d.recon.submaps import SubmapFusion

    bar = progress or _no_progress
    t_start = time.perf_counter()
    timer = StageTimer()
    session_path, out = Path(session_path), Path(config.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SessionError(f"cannot create the output folder {out}: {err}") from err
    with open_session(session_path) as session:
        source = SessionFrames(session, session_path, _rig(session, config),
                               max_frames=config.max_frames)
        stage_cfg = config.frame_stage(source.native_rig)
        t0 = time.perf_counter()
        stereo = stage_depth(stage_cfg)
        timer.add("rectify_maps_s", time.perf_counter() - t0)
        executor = make_executor(config.workers, config.scheduler,
                                 setup=(install_geometry, (stage_cfg, stereo)))
        try:
            odo, odometry_name, imu_used = _odometry(config, stereo, session_path,
                                                     len(source.imu) > 0, odometry)
            cache = _frame_cache(out, stage_cfg, session_path, config.fresh)
            fusion_cfg = config.fusion(stereo.depth_range_m)
            store = DiskSubmapStore(out / "submaps")
            store.clear()
            stages = OrderedStages(odo, SubmapFusion(fusion_cfg), store, stereo.maps,
                                   use_imu=config.use_imu and len(source.imu) > 0, timer=timer)
            window = config.in_flight or 2 * max(1, executor.workers) + 2
            bars = [bar(name, len(source)) for name in ("depth", "odometry", "fusion")]
            rate = _depth_rate(config, stereo)
            depth = DepthScheduler(source, executor, stage_cfg, executor.share(stereo), cache,
                                   window=window, timer=timer, on_depth=bars[0].update,
                                   depth_rate=rate,
                                   rectify=functools.partial(rectify_pair, stereo))
            t_loop, t_prev = time.perf_counter(), None
            try:
                for _pair, res in depth.results():
                    if res is None:
                        continue
                    if res.seeded and rate is not None:  # seeds moved to where it looks
                        seed = rate.seed(res.depth_m)
                        res = dataclasses.replace(res, depth_m=seed, valid_fraction=float(
                            np.isfinite(seed).mean()))
                    est = stages.step(res, imu_between(source.imu, t_prev, res.t_ns),
                                      fuse=not res.seeded)
                    if est is None:
                        continue
                    if rate is not None:
                        rate.observe(res.t_ns, est.status,
                                     np.asarray(est.T_world_left) @ stages.T_left_rect,
                                     own_depth=not res.seeded)
                    t_prev = res.t_ns
                    bars[1].update(1)
                    bars[2].update(1)
            finally:
                for b in bars:
                    b.close()
            timer.add("frame_loop_wall_s", time.perf_counter() - t_loop)
        finally:
            executor.close()
    stages.finish_fusion()
    if not stages.estimates:
        raise SessionError(f"{session_path}: no frame could be processed "
                           f"({depth.unreadable} unreadable, {stages.failed} failed)")
    return _finish(session_path, out, config, stages, store, fusion_cfg, stereo, source,
                   depth, executor, window, odometry_name, imu_used, timer, t_start, bar,
                   on_result)


def _finish(session_path: Path, out: Path, config: ProcessConfig, stages: OrderedStages,
            store: Any, fusion_cfg: Any, stereo: Any, source: Any, depth: Any, executor: Any,
            window: int, odometry_name: str, imu_used: bool, timer: StageTimer,
            t_start: float, bar: ProgressFactory,
            on_result: Callable[[ProcessResult], None] | None) -> ProcessResult:
    """Merge, write the outputs, evaluate, report (the finish step of :func:`run_process`)."""
    from sea3d.io.process_outputs import write_process_outputs, write_summary_json
    from sea3d.pipeline.finish import finish_reconstruction, frame_rows, run_summary
    from sea3d.pipeline.groundtruth import evaluate_against_ground_truth

    maps = stereo.maps
    rec = finish_reconstruction(stages, store, fusion_cfg.tsdf, tile_m=config.merge_tile_m,
                                cloud_voxel_m=config.cloud_voxel_m or config.voxel_m / 2,
                                progress=bar, timer=timer)
    tw = time.perf_counter()
    files = write_process_outputs(out, t_ns=rec.t_ns, T_world_left=rec.T_world_left,
                                  rows=frame_rows(stages), mesh=rec.mesh, cloud=rec.cloud,
                                  rig=stereo.rig)
    timer.add("write_s", time.perf_counter() - tw)
    summary = run_summary(
        stages, rec, session=str(session_path), pairs_in_session=source.pairs_in_session,
        frames_unreadable=depth.unreadable, frames_from_cache=depth.from_cache,
        depth_rate=config.depth_rate, frames_with_depth=len(stages.estimates) - depth.seeded,
        odometry=odometry_name, imu_used=imu_used,
        executor={"kind": executor.name, "workers": executor.workers, "in_flight": window},
        image_size_px=[int(maps.width), int(maps.height)], refractive=bool(maps.refractive),
        depth_range_m=list(stereo.depth_range_m), max_disparity_px=stereo.max_disparity_px,
        virtual_pinhole_rms_px=(maps.report_left.rms_px if maps.report_left else 0.0),
        voxel_m=config.voxel_m, integrate=config.integrate)
    summary["colours"] = {"enhance": str(config.enhance or "none"),
                          "restore": config.restore_colours,
                          "restore_status": stages.colour_status,
                          "per_frame": stages.colour_frames}
    summary["timings_s"] = {}
    summary["worker_timings_s"] = stages.worker_timings_s
    summary["cache_mb_written"] = depth.cache.bytes_written / 2**20
    statuses = [e.status for e in stages.estimates]
    result = ProcessResult(
        out_dir=out, t_ns=rec.t_ns, T_world_left=rec.T_world_left, statuses=statuses,
        mesh=rec.mesh, cloud_points=rec.cloud.points, cloud_colors=rec.cloud.colors,
        summary=summary, files=files)
    if config.evaluate:
        te = time.perf_counter()
        metrics = evaluate_against_ground_truth(
            session_path, t_ns=rec.t_ns, T_world_left=rec.T_world_left,
            trusted=np.array([s in TRUSTED for s in statuses]), mesh=rec.mesh,
            camera=source.native_rig.left, max_depth_m=stereo.max_depth_m)
        T_gt_world = metrics.pop("T_gt_world", None)
        summary.update(metrics)
        if T_gt_world is not None:  # the mesh and trajectory in the ground truth's frame too
            from sea3d.pipeline.gt_frame import write_in_ground_truth_frame

            summary.update(write_in_ground_truth_frame(result, np.asarray(T_gt_world)))
        timer.add("evaluate_s", time.perf_counter() - te)
    timings = dict(timer.s)
    timings["total_s"] = time.perf_counter() - t_start
    summary["timings_s"] = timings
    summary["one_off_s"] = {"warmup_s (kernel compilation, once per worker)":
                            stages.worker_timings_s.get("warmup_s", 0.0),
                            "rectify_maps_s": timings.get("rectify_maps_s", 0.0)}
    loop_wall = timings.get("frame_loop_wall_s", 0.0)
    summary["frames_per_second"] = len(stages.estimates) / loop_wall if loop_wall > 0 else None
    summary["peak_rss_mb"] = {"client": _rss_mb(resource.RUSAGE_SELF),
                              "workers": _rss_mb(resource.RUSAGE_CHILDREN)}
    if config.report:
        from sea3d.pipeline.report import write_process_report

        tr = time.perf_counter()
        files["report"] = write_process_report(out / "report.html", result,
                                               colour_pictures=stages.colour_pictures)
        summary["timings_s"]["report_s"] = time.perf_counter() - tr
    write_summary_json(files["summary"], summary)
    if on_result is not None:
        on_result(result)
    return result
