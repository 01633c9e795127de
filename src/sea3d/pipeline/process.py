"""``sea3d process``: a whole session into a trajectory, a coloured mesh and a report.

::

    session ──► raw pairs in time order ──► per-frame stage (any order, any machine):
                                            [enhance] ─► rectify ─► match ─► exact depth
                                            ─► depth for the virtual pinhole
            ◄── results stream back, cached in OUT/cache/frames/<t_ns>.s3c as they arrive
    [--restore-colours seathru: the dive's one water model, fitted in the client from the
     first frames, restores every frame's colours (held until it exists)]
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

The odometry is chosen in one place, :func:`sea3d.pipeline.pose_stage.make_odometry`: known
poses (``--poses``) or sea3d's stereo-inertial odometry (``sea3d.odometry.create_odometry``).

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
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError, SessionError
from sea3d.odometry.types import TrackingStatus
from sea3d.pipeline.colour_stage import DiveColours
from sea3d.pipeline.config import ColourConfig, ExecutorConfig, MapConfig, PoseConfig
from sea3d.pipeline.depth_scheduler import StageTimer
from sea3d.pipeline.frame_stage import FrameStageConfig, install_geometry, rectify_pair, stage_depth
from sea3d.pipeline.lock import clear_stale_temps, locks_out_dir
from sea3d.pipeline.ordered import TRUSTED, OrderedStages
from sea3d.pipeline.pose_stage import OdometryFactory, choose_session_odometry
from sea3d.pipeline.progress import ProgressFactory, no_progress
from sea3d.recon.submaps import FusionConfig
from sea3d.stereo.recipe import DepthConfig

if TYPE_CHECKING:
    from sea3d.geometry.mesh import Mesh
    from sea3d.geometry.rig import StereoRig
    from sea3d.io.result_cache import FrameCache
    from sea3d.pipeline.depth_rate import DepthRate
    from sea3d.pipeline.depth_scheduler import DepthScheduler
    from sea3d.pipeline.executors import Executor
    from sea3d.pipeline.frame_source import SessionFrames
    from sea3d.pipeline.frame_stage import FrameResult
    from sea3d.recon.submaps import SubmapStore
    from sea3d.stereo.recipe import StereoDepth

__all__ = [
    "ColourConfig",
    "ExecutorConfig",
    "MapConfig",
    "PoseConfig",
    "ProcessConfig",
    "ProcessResult",
    "ProgressFactory",
    "run_process",
]

log = logging.getLogger(__name__)



@dataclass(frozen=True, kw_only=True)
class ProcessConfig:
    """Options of ``sea3d process``: the run's own, then one nested config per stage (the
    CLI's flags map one to one onto their fields)."""

    out_dir: Path
    """Output folder (created); also holds the cache that makes reruns resume."""
    rig_path: Path | None = None
    """Rig file; None uses the rig stored with the session."""
    size_px: tuple[int, int] | None = None
    """Process at this ``(width, height)`` instead of the recorded size."""
    depth: DepthConfig = field(default_factory=DepthConfig)
    """Stereo depth (engine, disparity and depth range; :class:`DepthConfig`)."""
    map: MapConfig = field(default_factory=MapConfig)
    """Fusion and merge (:class:`MapConfig`)."""
    poses: PoseConfig = field(default_factory=PoseConfig)
    """Odometry or known poses (:class:`PoseConfig`)."""
    colours: ColourConfig = field(default_factory=ColourConfig)
    """Enhancement and colour restoration (:class:`ColourConfig`)."""
    executor: ExecutorConfig = field(default_factory=ExecutorConfig)
    """Workers or a Dask scheduler (:class:`ExecutorConfig`)."""
    fresh: bool = False
    """Ignore (delete) cached per-frame results instead of resuming."""
    rebuild_cache_config: bool = False
    """Write a damaged cache ``config.json`` again for this configuration and keep the cached
    frames (each is still checked as it is read); for a rerun of the configuration and
    session that made them."""
    evaluate: bool = True
    """Compare with the simulator's ground truth when the session has one."""
    report: bool = True
    """Write report.html."""
    max_frames: int | None = None
    """Process only the first N stereo pairs."""
    depth_rate: str | int = "all"
    """Which frames get stereo depth of their own (:mod:`sea3d.pipeline.depth_rate`):
    ``all``; ``auto`` (when the predicted motion since the last depth frame needs it); or
    every N-th frame. The odometry sees every frame (a frame without depth takes the latest
    depth map as its stereo seeds); fusion integrates the depth frames."""

    def frame_stage(self, rig: StereoRig) -> FrameStageConfig:
        """The per-frame stage's configuration for ``rig`` (at the recorded size; threads per
        worker: the cores shared among the local workers; a Dask worker keeps its own)."""
        ex = self.executor
        n_local = ex.workers if ex.workers is not None else min(os.cpu_count() or 1, 8)
        return FrameStageConfig(
            rig=rig, size_px=self.size_px, depth=self.depth,
            enhance=self.colours.enhance,
            # The dive's water model restores in the client, after the fit: the per-frame
            # stage (and its cache) stays as without restoration.
            restore_colours="seathru" if self.colours.per_image else "none",
            threads=max(1, (os.cpu_count() or 1) // max(1, n_local))
            if ex.scheduler is None else None)

    def fusion(self, depth_range_m: tuple[float, float],
               focal_baseline_px_m: float | None = None) -> FusionConfig:
        """The fusion stage's configuration (:meth:`MapConfig.fusion`)."""
        return self.map.fusion(depth_range_m, focal_baseline_px_m=focal_baseline_px_m)

    def __post_init__(self) -> None:
        for name, cls in (("depth", DepthConfig), ("map", MapConfig), ("poses", PoseConfig),
                          ("colours", ColourConfig), ("executor", ExecutorConfig)):
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"{name} must be a {cls.__name__}, got "
                                  f"{type(getattr(self, name)).__name__}")
        if self.max_frames is not None and self.max_frames < 1:
            raise ConfigError(f"max_frames must be >= 1, got {self.max_frames}")
        if self.fresh and self.rebuild_cache_config:
            raise ConfigError("either fresh or rebuild_cache_config, not both")
        from sea3d.pipeline.depth_rate import parse_depth_rate

        object.__setattr__(self, "depth_rate", parse_depth_rate(self.depth_rate))
        if self.colours.per_dive and self.depth_rate not in ("all", 1):
            raise ConfigError(f"restore_colours {self.colours.restore_colours} (the dive's "
                              "water model) needs depth of every frame's own "
                              f"(depth_rate all), got depth_rate {self.depth_rate!r}")


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
    mesh: Mesh
    cloud_points: F64
    cloud_colors: NDArray[np.uint8]
    summary: dict[str, Any]
    files: dict[str, Path] = field(default_factory=dict)


def _per_frame_costs(worker_timings_s: dict[str, float], computed: int,
                     restored: int) -> dict[str, float]:
    """Mean seconds per frame of matching (over the ``computed`` frames: a cached one matched
    nothing in this run) and of the colour restoration (what ``--restore-colours`` adds, over
    the ``restored`` frames)."""
    return {"match_s": worker_timings_s.get("match_s", 0.0) / max(computed, 1),
            "restore_colours_s": (worker_timings_s.get("restore_colours_s", 0.0)
                                  / max(restored, 1))}


def _rss_mb(who: int) -> float:
    return float(resource.getrusage(who).ru_maxrss) / 1024.0


def _frame_cache(out: Path, stage: FrameStageConfig, session_path: Path, fresh: bool,
                 rebuild: bool = False) -> FrameCache:
    from sea3d.io.result_cache import FrameCache

    cache = FrameCache(out / "cache", {"stage": stage.fingerprint(),
                                       "session": str(session_path.resolve())})
    if fresh:
        cache.clear()
    if not cache.check_fingerprint(rebuild=rebuild):
        raise ConfigError(f"{out} holds cached results of another configuration or session; "
                          "use another output folder, or fresh to discard them")
    return cache


def _depth_rate(config: ProcessConfig, stereo: StereoDepth) -> DepthRate | None:
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
    odometry: OdometryFactory | None = None,
) -> ProcessResult:
    """Process a recorded session into a trajectory, mesh, cloud and report (see the module).

    Args:
        session_path: an MCAP file or session folder.
        config: :class:`ProcessConfig`.
        progress: progress-bar factory (the CLI's tqdm); None shows nothing.
        on_result: called with the result at the end.
        odometry: ``factory(rig, maps) -> Odometry`` to use instead of
            :func:`~sea3d.pipeline.pose_stage.make_odometry`
            (another estimator, or a test double).

    Returns:
        :class:`ProcessResult`.

    Raises:
        SessionError: unreadable session, no stereo pairs, no rig.
        ConfigError: bad options, a cache made with another configuration (without
            ``fresh``).
        CacheEntryError: a damaged cache ``config.json`` (without ``fresh`` or
            ``rebuild_cache_config``).
        OdometryError, ReconError: invalid data reaching those stages.
    """
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session
    from sea3d.pipeline.depth_scheduler import DepthScheduler
    from sea3d.pipeline.executors import make_executor
    from sea3d.pipeline.frame_source import SessionFrames, imu_between
    from sea3d.pipeline.submap_store import DiskSubmapStore
    from sea3d.recon.submaps import SubmapFusion

    bar = progress or no_progress
    t_start = time.perf_counter()
    timer = StageTimer()
    session_path, out = Path(session_path), Path(config.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SessionError(f"cannot create the output folder {out}: {err}") from err
    clear_stale_temps(out)
    with open_session(session_path) as session:
        source = SessionFrames(session, session_path, resolve_rig(config.rig_path, session),
                               max_frames=config.max_frames)
        stage_cfg = config.frame_stage(source.native_rig)
        t0 = time.perf_counter()
        stereo = stage_depth(stage_cfg)
        timer.add("rectify_maps_s", time.perf_counter() - t0)
        executor = make_executor(config.executor.workers, config.executor.scheduler,
                                 setup=(install_geometry, (stage_cfg, stereo)))
        try:
            odo, odometry_name, imu_used, imu_note = choose_session_odometry(
                config.poses, stereo, source, odometry)
            cache = _frame_cache(out, stage_cfg, session_path, config.fresh,
                                 config.rebuild_cache_config)
            fusion_cfg = config.fusion(stereo.depth_range_m,
                                       stereo.maps.focal_px * stereo.maps.baseline_m)
            store = DiskSubmapStore(out / "submaps")
            store.clear()
            stages = OrderedStages(odo, SubmapFusion(fusion_cfg), store, stereo.maps,
                                   use_imu=imu_used, timer=timer)
            window = config.executor.in_flight or 2 * max(1, executor.workers) + 2
            bars = [bar(name, len(source)) for name in ("depth", "odometry", "fusion")]
            rate = _depth_rate(config, stereo)
            depth = DepthScheduler(source, executor, stage_cfg, executor.share(stereo), cache,
                                   window=window, timer=timer, on_depth=bars[0].update,
                                   depth_rate=rate,
                                   rectify=functools.partial(rectify_pair, stereo))
            colours = (DiveColours(stereo.maps, config.colours.dive_colours)
                       if config.colours.per_dive else None)
            t_loop, t_prev = time.perf_counter(), None

            def step(res: FrameResult) -> None:
                nonlocal t_prev
                if res.seeded and rate is not None:  # seeds moved to where it looks
                    seed = rate.seed(res.depth_m)
                    res = dataclasses.replace(res, depth_m=seed, valid_fraction=float(
                        np.isfinite(seed).mean()))
                est = stages.step(res, imu_between(source.imu, t_prev, res.t_ns),
                                  fuse=not res.seeded)
                if est is None:
                    return
                if rate is not None:
                    rate.observe(res.t_ns, est.status,
                                 np.asarray(est.T_world_left) @ stages.T_left_rect,
                                 own_depth=not res.seeded)
                t_prev = res.t_ns
                bars[1].update(1)
                bars[2].update(1)

            try:
                for _pair, res in depth.results():
                    if res is None:
                        continue
                    for ready in [res] if colours is None else colours.push(res):
                        step(ready)
                for ready in [] if colours is None else colours.flush():
                    step(ready)
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
    if colours is not None:
        timer.add("water_fit_s", colours.fit_s)
    return _finish(session_path, out, config, stages, store, fusion_cfg, stereo, source,
                   depth, executor, window, odometry_name, (imu_used, imu_note), timer, t_start,
                   bar, on_result, colours)


def _finish(session_path: Path, out: Path, config: ProcessConfig, stages: OrderedStages,
            store: SubmapStore, fusion_cfg: FusionConfig, stereo: StereoDepth,
            source: SessionFrames, depth: DepthScheduler, executor: Executor,
            window: int, odometry_name: str, imu: tuple[bool, str | None], timer: StageTimer,
            t_start: float, bar: ProgressFactory,
            on_result: Callable[[ProcessResult], None] | None,
            colours: DiveColours | None = None) -> ProcessResult:
    """Merge, write the outputs, evaluate, report (the finish step of :func:`run_process`)."""
    from sea3d.io.process_outputs import write_summary_json
    from sea3d.pipeline.finish import FinishOptions, finish_run, fusion_summary
    from sea3d.pipeline.groundtruth import evaluate_against_ground_truth

    maps = stereo.maps
    done = finish_run(
        stages, store, fusion_cfg.tsdf, out, stereo.rig, FinishOptions.of_map(config.map),
        progress=bar, timer=timer, summary_extra=dict(
            session=str(session_path), pairs_in_session=source.pairs_in_session,
            frames_unreadable=depth.unreadable, frames_from_cache=depth.from_cache,
            depth_rate=config.depth_rate,
            frames_with_depth=len(stages.estimates) - depth.seeded,
            odometry=odometry_name, imu_used=imu[0], imu_note=imu[1],
            executor={"kind": executor.name, "workers": executor.workers, "in_flight": window},
            image_size_px=[int(maps.width), int(maps.height)],
            refractive=bool(maps.refractive), depth_range_m=list(stereo.depth_range_m),
            max_disparity_px=stereo.max_disparity_px,
            virtual_pinhole_rms_px=(maps.report_left.rms_px if maps.report_left else 0.0),
            voxel_m=config.map.voxel_m, integrate=config.map.integrate))
    rec, files, summary = done.rec, done.files, done.summary
    summary["colours"] = {"enhance": str(config.colours.enhance or "none"),
                          "restore": config.colours.restore_colours,
                          "restore_status": stages.colour_status,
                          "per_frame": stages.colour_frames}
    if colours is not None:
        summary["colours"]["water_model"] = colours.summary()
    summary["fusion"] = fusion_summary(config.map, fusion_cfg.tsdf)
    computed = len(stages.estimates) - depth.from_cache
    if config.colours.restore_colours != "none":
        summary["colours"]["per_frame_s"] = _per_frame_costs(
            stages.worker_timings_s, computed,
            len(stages.estimates) if colours is not None else computed)
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
