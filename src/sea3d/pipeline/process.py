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
"""

from __future__ import annotations

import csv
import json
import logging
import os
import resource
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError, Sea3dError, SessionError
from sea3d.odometry.types import (
    FrameObservation,
    ImuChunk,
    Odometry,
    OdometryEstimate,
    TrackingStatus,
)
from sea3d.pipeline.frame_stage import (
    FrameResult,
    FrameStageConfig,
    install_geometry,
    process_frame,
    stage_depth,
)
from sea3d.stereo.recipe import DepthConfig

__all__ = [
    "ProcessConfig",
    "ProcessResult",
    "ProgressFactory",
    "make_odometry",
    "publish_results",
    "run_process",
]

log = logging.getLogger(__name__)

TRUSTED = (TrackingStatus.TRACKING, TrackingStatus.RELOCALISED)


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


def _write_results_mcap(path: Path, t_ns: NDArray[np.int64], T: F64, estimates: Sequence[Any],
                        mesh: Any, cloud: Any, rig: Any) -> None:
    """OUT/results.mcap: trajectory (with each frame's status), cloud and mesh in Foxglove
    schemas, so a finished dive opens in Foxglove beside its recording. Rewritten whole on
    every run (a resumed run replaces the previous file)."""
    from sea3d.io.foxglove_mcap import write_results_mcap

    tmp = path.with_name(path.name + ".partial")
    tmp.unlink(missing_ok=True)
    write_results_mcap(
        tmp,
        trajectory=(t_ns, T),
        status=[str(getattr(e.status, "value", e.status)) for e in estimates],
        cloud=(cloud.points, cloud.colors),
        mesh=(mesh.vertices, mesh.triangles, mesh.colors_rgb),
        rig=rig,
    )
    tmp.replace(path)


def publish_results(result: ProcessResult) -> None:
    """Hook for live viewers, called once per run with the final trajectory, mesh and cloud.

    Does nothing by default (the results are on disk, OUT/results.mcap for Foxglove);
    callers of :func:`run_process` can also pass ``on_result``.
    """
    return None


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

    Raises:
        ConfigError: no poses given and this build has no odometry.
    """
    if poses is not None:
        from sea3d.odometry.reference import KnownPoses

        return KnownPoses(poses.t_ns, poses.T_world_x), f"known poses from {poses.path}"
    try:
        from sea3d.odometry import create_odometry
    except ImportError as err:  # pragma: no cover - a build without the odometry package
        raise ConfigError(
            "this sea3d has no odometry yet (sea3d.odometry.create_odometry); give known poses "
            "with --poses TRAJ.tum"
        ) from err
    odo = create_odometry(rig, maps, use_imu=use_imu, config=config)
    reason = odo.imu_disabled_reason
    mode = "stereo-inertial" if use_imu and reason is None else "visual"
    return odo, f"sea3d {mode} odometry" + (f" ({reason})" if mode == "visual" and reason else "")


def odometry_available() -> bool:
    """True when this build has sea3d's own odometry (``sea3d.odometry.create_odometry``)."""
    try:
        from sea3d.odometry import create_odometry  # noqa: F401
    except ImportError:
        return False
    return True


# ----------------------------------------------------------------------------------- helpers


def _T_left_rect(maps: Any) -> F64:
    """``T_left_rect``: the rectified left camera in the raw left camera's frame."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(maps.R_rect_left_left, np.float64).T
    return T


def _imu_chunk(imu: Any, t_prev: int | None, t: int) -> ImuChunk | None:
    if imu is None or len(imu) == 0:
        return None
    lo = 0 if t_prev is None else int(np.searchsorted(imu.t_ns, t_prev, side="right"))
    hi = int(np.searchsorted(imu.t_ns, t, side="right"))
    return ImuChunk(t_ns=np.asarray(imu.t_ns[lo:hi], np.int64),
                    accel_mps2=np.asarray(imu.accel_mps2[lo:hi], np.float64),
                    gyro_radps=np.asarray(imu.gyro_radps[lo:hi], np.float64))


def _path_length(t_T: F64, trusted: NDArray[np.bool_], segments: NDArray[np.int64]) -> float:
    p = t_T[:, :3, 3]
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    ok = trusted[1:] & trusted[:-1] & (segments[1:] == segments[:-1])
    return float(step[ok].sum())


def _rss_mb(who: int) -> float:
    return float(resource.getrusage(who).ru_maxrss) / 1024.0


class _Timer:
    def __init__(self) -> None:
        self.s: dict[str, float] = {}

    def add(self, key: str, seconds: float) -> None:
        self.s[key] = self.s.get(key, 0.0) + float(seconds)


def _cached_result(cache: Any, t_ns: int) -> FrameResult | None:
    got = cache.get(t_ns)
    if got is None:
        return None
    try:
        return FrameResult.from_cache(t_ns, *got)
    except (KeyError, ValueError, TypeError) as err:
        log.warning("cache entry of frame %d is incomplete (%s); recomputing", t_ns, err)
        cache.path(t_ns).unlink(missing_ok=True)
        return None


# ------------------------------------------------------------------------------------ runner


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
        on_result: called with the result at the end (after :func:`publish_results`).
        odometry: ``factory(rig, maps) -> Odometry`` to use instead of :func:`make_odometry`
            (another estimator, or a test double).

    Returns:
        :class:`ProcessResult`.

    Raises:
        SessionError: unreadable session, no stereo pairs, no rig.
        ConfigError: bad options, a cache made with another configuration (without
            ``fresh``), no odometry and no ``--poses``.
        OdometryError, ReconError: invalid data reaching those stages.
    """
    from sea3d.io.mesh_files import write_mesh, write_point_cloud
    from sea3d.io.result_cache import DiskSubmapStore, FrameCache
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session
    from sea3d.io.trajectory_files import read_trajectory, write_tum
    from sea3d.pipeline.executors import make_executor
    from sea3d.recon.cloud import CloudConfig, clean_point_cloud
    from sea3d.recon.submaps import FusionConfig, SubmapFusion, merge_submaps
    from sea3d.recon.tsdf import TsdfConfig

    bar = progress or _no_progress
    t_start = time.perf_counter()
    timer = _Timer()
    session_path = Path(session_path)
    out = Path(config.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SessionError(f"cannot create the output folder {out}: {err}") from err

    with open_session(session_path) as session:
        # -- rig, geometry, frames ------------------------------------------------------
        native = resolve_rig(config.rig_path, session)
        match = session.match_pairs()
        n_pairs = len(match)
        if n_pairs == 0:
            raise SessionError(f"{session_path}: no stereo pairs to process")
        if config.max_frames is not None:
            n_pairs = min(n_pairs, config.max_frames)
        left_stamps = session.stamps("left")
        order = [int(left_stamps[i]) for i in match.left_index[:n_pairs]]
        n_local = config.workers if config.workers is not None else min(os.cpu_count() or 1, 8)
        stage_cfg = FrameStageConfig(
            rig=native, size_px=config.size_px,
            depth=DepthConfig(engine=config.engine, max_disparity_px=config.max_disparity_px,
                              min_depth_m=config.min_depth_m, max_depth_m=config.max_depth_m),
            enhance=config.enhance,
            restore_colours=config.restore_colours,
            threads=max(1, (os.cpu_count() or 1) // max(1, n_local))
            if config.scheduler is None else None,
        )
        executor: Any = None
        try:
            first = session.image("left", int(match.left_index[0]), by="index")
            if first.shape[:2] != (native.height, native.width):
                raise SessionError(
                    f"{session_path}: images are {first.shape[1]}x{first.shape[0]} but the rig "
                    f"is {native.width}x{native.height}; pass the rig of this camera with --rig"
                    " (--size then sets the processing size)"
                )
            t0 = time.perf_counter()
            stereo = stage_depth(stage_cfg)
            rig, maps = stereo.rig, stereo.maps
            timer.add("rectify_maps_s", time.perf_counter() - t0)
            executor = make_executor(config.workers, config.scheduler,
                                     setup=(install_geometry, (stage_cfg, stereo)))
            n_workers = max(1, executor.workers)
            geometry_arg = executor.share(stereo)
            imu = session.imu()
            has_imu = len(imu) > 0
            use_imu = config.use_imu and has_imu
            imu_note: str | None = None
            if config.use_imu and not has_imu:
                log.warning("%s has no IMU samples: the odometry runs visual-only", session_path)
            elif use_imu:
                # the same clock check as 'sea3d odometry': an IMU seconds away from the
                # cameras is not used (visual-only is right for the camera data), and said
                from sea3d.pipeline.odometry import imu_clock_check

                offset_s = rig.imu.time_offset_s if rig.imu is not None else 0.0
                tol_s = getattr(config.odometry_config, "imu_max_clock_offset_s", 1.0)
                imu_note = imu_clock_check(np.asarray(order, np.int64),
                                           np.asarray(imu.t_ns, np.int64), offset_s,
                                           tolerance_s=tol_s)
                if imu_note is not None:
                    log.warning("%s: %s: the odometry runs visual-only", session_path, imu_note)
                    use_imu = False
            poses = read_trajectory(config.poses_path) if config.poses_path else None
            if odometry is not None:
                odo = odometry(rig, maps)
                odometry_name = str(getattr(odo, "name", type(odo).__name__))
            else:
                odo, odometry_name = make_odometry(rig, maps, use_imu=use_imu, poses=poses,
                                                   config=config.odometry_config)
            # -- cache ------------------------------------------------------------------
            cache = FrameCache(out / "cache", {"stage": stage_cfg.fingerprint(),
                                               "session": str(session_path.resolve())})
            if config.fresh:
                cache.clear()
            if not cache.check_fingerprint():
                raise ConfigError(
                    f"{out} holds cached results of another configuration or session; use "
                    "another -o, or --fresh to discard them"
                )
            cached = cache.stamps()
            # -- ordered stages' state --------------------------------------------------
            tsdf_cfg = TsdfConfig(voxel_m=config.voxel_m, depth_min_m=stereo.min_depth_m,
                                  depth_max_m=stereo.max_depth_m)
            fusion = SubmapFusion(FusionConfig(
                tsdf=tsdf_cfg, integrate=config.integrate,
                keyframes_per_submap=config.keyframes_per_submap,
                max_blocks=config.max_submap_blocks))
            store = DiskSubmapStore(out / "submaps")
            store.clear()
            K = np.asarray(maps.P_left[:3, :3], np.float64)
            T_left_rect = _T_left_rect(maps)
            R_rect = np.asarray(maps.R_rect_left_left, np.float64)
            kf_rect: dict[int, F64] = {}
            estimates: list[OdometryEstimate] = []
            fuse_status: list[str] = []
            frame_status: list[str] = []
            valid_fraction: list[float] = []
            colour_status: dict[str, int] = {}
            worker_t: dict[str, float] = {}
            n_cached = n_failed = n_unreadable = loop_closures = 0
            window = config.in_flight or 2 * n_workers + 2

            bar_depth = bar("depth", n_pairs)
            bar_odo = bar("odometry", n_pairs)
            bar_fuse = bar("fusion", n_pairs)
            pending: dict[int, Any] = {}
            ready: dict[int, FrameResult | None] = {}
            submit_i = consume_i = 0
            t_prev: int | None = None
            t_stage0 = time.perf_counter()
            try:
                while consume_i < n_pairs:
                    while submit_i < n_pairs and len(pending) + len(ready) < window:
                        t = order[submit_i]
                        li = int(match.left_index[submit_i])
                        ri = int(match.right_index[submit_i])
                        submit_i += 1
                        if t in cached:
                            tr = time.perf_counter()
                            res = _cached_result(cache, t)
                            timer.add("cache_read_s", time.perf_counter() - tr)
                            if res is not None:
                                ready[t] = res
                                n_cached += 1
                                bar_depth.update(1)
                                continue
                        tr = time.perf_counter()
                        try:
                            left = session.image("left", li, by="index")
                            right = session.image("right", ri, by="index")
                        except SessionError as err:
                            log.warning("frame t_ns=%d cannot be read (%s); skipped", t, err)
                            ready[t] = None
                            n_unreadable += 1
                            bar_depth.update(1)
                            continue
                        finally:
                            timer.add("read_s", time.perf_counter() - tr)
                        pending[t] = executor.submit(process_frame, stage_cfg, t, left, right,
                                                     geometry_arg)
                    t_next = order[consume_i]
                    if t_next not in ready:
                        executor.wait_first(pending.values())
                        for t_done in [k for k, f in pending.items() if f.done()]:
                            res = pending.pop(t_done).result()
                            tw = time.perf_counter()
                            cache.put(t_done, *res.to_cache())
                            timer.add("cache_write_s", time.perf_counter() - tw)
                            ready[t_done] = res
                            bar_depth.update(1)
                        continue
                    res = ready.pop(t_next)
                    consume_i += 1
                    if res is None:
                        continue
                    for k, v in res.timings_s.items():
                        worker_t[k] = worker_t.get(k, 0.0) + v
                    frame_status.append(res.status)
                    valid_fraction.append(res.valid_fraction)
                    if res.status == "failed":
                        n_failed += 1
                        log.warning("frame t_ns=%d: %s", res.t_ns, res.message)
                        # No images: the odometry cannot see this frame.
                        frame_status.pop()
                        valid_fraction.pop()
                        continue
                    # -- odometry ---------------------------------------------------------
                    to = time.perf_counter()
                    obs = FrameObservation(
                        t_ns=res.t_ns, rect_left=res.rect_left, rect_right=res.rect_right,
                        depth_m=res.depth_m, K_rect=K, baseline_m=float(maps.baseline_m),
                        R_rect_left_left=R_rect,
                        imu=_imu_chunk(imu, t_prev, res.t_ns) if use_imu else None,
                    )
                    est = odo.step(obs)
                    t_prev = res.t_ns
                    estimates.append(est)
                    if est.loop_closure:
                        loop_closures += 1
                        kf_rect = {k: T @ T_left_rect
                                   for k, T in odo.keyframe_poses().items()}
                    if est.keyframe_id is not None:
                        kf_rect[est.keyframe_id] = np.asarray(est.T_world_left) @ T_left_rect
                    timer.add("odometry_s", time.perf_counter() - to)
                    bar_odo.update(1)
                    # -- fusion -----------------------------------------------------------
                    tf = time.perf_counter()
                    color = res.colors()
                    if res.colour_status:
                        colour_status[res.colour_status] = (
                            colour_status.get(res.colour_status, 0) + 1)
                    step = fusion.step(
                        t_ns=res.t_ns, trusted=est.status in TRUSTED,
                        keyframe_id=est.keyframe_id, depth_m=res.fusion_depth_m,
                        color_rgb=color, K=K,
                        T_world_cam=np.asarray(est.T_world_left) @ T_left_rect,
                        keyframe_poses=kf_rect,
                    )
                    fuse_status.append(step.status)
                    for sm in step.finished:
                        store.put(sm)
                    timer.add("fusion_s", time.perf_counter() - tf)
                    bar_fuse.update(1)
            finally:
                for f in pending.values():
                    f.cancel()
                executor.close()
                for b in (bar_depth, bar_odo, bar_fuse):
                    b.close()
            timer.add("frame_loop_wall_s", time.perf_counter() - t_stage0)
        except BaseException:
            if executor is not None:
                executor.close()
            raise
    last = fusion.finish()
    if last is not None:
        store.put(last)
    if not estimates:
        raise SessionError(f"{session_path}: no frame could be processed "
                           f"({n_unreadable} unreadable, {n_failed} failed)")

    # -- final poses, merge ---------------------------------------------------------------
    t_final, T_final = odo.trajectory()
    # One pose per processed frame, in frame order: the odometry's final (re-optimised) pose,
    # or its per-frame estimate for a frame its trajectory lacks.
    final = {int(t): np.asarray(T, np.float64) for t, T in zip(t_final, T_final, strict=True)}
    missing = sum(1 for e in estimates if int(e.t_ns) not in final)
    if missing:
        log.warning("the odometry's trajectory lacks %d of %d frames; their per-frame "
                    "estimates are used", missing, len(estimates))
    t_traj = np.array([e.t_ns for e in estimates], np.int64)
    T_traj = np.stack([final.get(int(e.t_ns), np.asarray(e.T_world_left, np.float64))
                       for e in estimates])
    final_kf = {k: T @ T_left_rect for k, T in odo.keyframe_poses().items()}
    tm = time.perf_counter()
    merge_bar = bar("merge", len(store.ids()))
    try:
        merged = merge_submaps(store, final_kf, tsdf_cfg, tile_m=config.merge_tile_m,
                               progress=merge_bar.update)
    finally:
        merge_bar.close()
    timer.add("merge_s", time.perf_counter() - tm)
    tc = time.perf_counter()
    cloud = clean_point_cloud(merged.points, merged.colors, merged.normals,
                              CloudConfig(voxel_m=config.cloud_voxel_m or config.voxel_m / 2))
    timer.add("cloud_s", time.perf_counter() - tc)

    # -- outputs ----------------------------------------------------------------------------
    tw = time.perf_counter()
    files = {
        "trajectory": out / "trajectory.tum",
        "mesh": out / "mesh.ply",
        "cloud": out / "cloud.ply",
        "status": out / "status.csv",
        "summary": out / "summary.json",
        "results_mcap": out / "results.mcap",
    }
    write_tum(files["trajectory"], t_traj, T_traj,
              header="t x y z qx qy qz qw: T_world_left of every stereo frame (t in seconds "
                     "of session time, metres); trust only frames tracking/relocalised in "
                     "status.csv")
    write_mesh(files["mesh"], merged.mesh)
    write_point_cloud(files["cloud"], cloud.points, cloud.colors, cloud.normals)
    _write_status_csv(files["status"], estimates, fuse_status, frame_status, valid_fraction)
    _write_results_mcap(files["results_mcap"], t_traj, T_traj, estimates, merged.mesh, cloud,
                        rig)
    timer.add("write_s", time.perf_counter() - tw)

    statuses = [e.status for e in estimates]
    trusted = np.array([s in TRUSTED for s in statuses])
    seg = np.array([e.segment for e in estimates], np.int64)
    est_T = T_traj
    counts = {s.value: int(sum(1 for x in statuses if x == s)) for s in TrackingStatus}
    summary: dict[str, Any] = {
        "session": str(session_path),
        "frames": len(estimates),
        "pairs_in_session": len(match),
        "keyframes": int(sum(1 for e in estimates if e.keyframe_id is not None)),
        "frames_lost": counts[TrackingStatus.LOST.value],
        "frames_imu_only": counts[TrackingStatus.IMU_ONLY.value],
        "frames_relocalised": counts[TrackingStatus.RELOCALISED.value],
        "frames_tracking": counts[TrackingStatus.TRACKING.value],
        "frames_initialising": counts[TrackingStatus.INITIALISING.value],
        "frames_unreadable": n_unreadable,
        "frames_failed": n_failed,
        "frames_fused": int(sum(1 for s in fuse_status if s == "integrated")),
        "frames_from_cache": n_cached,
        "loop_closures": loop_closures,
        "segments": int(seg.max() + 1) if len(seg) else 0,
        "path_length_m": _path_length(est_T, trusted, seg) if len(est_T) > 1 else 0.0,
        "odometry": odometry_name,
        "imu_used": bool(use_imu and poses is None
                         and getattr(odo, "imu_disabled_reason", None) is None),
        "imu_note": imu_note or getattr(odo, "imu_disabled_reason", None),
        "executor": {"kind": executor.name, "workers": executor.workers,
                     "in_flight": window},
        "image_size_px": [int(maps.width), int(maps.height)],
        "refractive": bool(maps.refractive),
        "depth_range_m": list(stereo.depth_range_m),
        "max_disparity_px": stereo.max_disparity_px,
        "virtual_pinhole_rms_px": (maps.report_left.rms_px if maps.report_left else 0.0),
        "voxel_m": config.voxel_m,
        "integrate": config.integrate,
        "submaps": merged.submaps,
        "submaps_moved_by_loop_closures": merged.moved,
        "active_submap_peak_mb": fusion.peak_memory_bytes / 2**20,
        "mesh": {"vertices": len(merged.mesh.vertices), "triangles": len(merged.mesh.triangles)},
        "cloud": {"points": len(cloud.points), "outliers_removed": cloud.outliers},
        "mean_valid_depth_fraction": float(np.mean(valid_fraction)) if valid_fraction else 0.0,
        "colours": {"enhance": str(config.enhance or "none"),
                    "restore": config.restore_colours, "restore_status": colour_status},
        "timings_s": {},
        "worker_timings_s": worker_t,
        "cache_mb_written": cache.bytes_written / 2**20,
    }
    result = ProcessResult(
        out_dir=out, t_ns=np.asarray(t_traj, np.int64), T_world_left=est_T, statuses=statuses,
        mesh=merged.mesh, cloud_points=cloud.points, cloud_colors=cloud.colors,
        summary=summary, files=files,
    )
    # -- evaluation against the simulator's ground truth -----------------------------------
    if config.evaluate:
        te = time.perf_counter()
        summary.update(_evaluate(session_path, result, native, stereo.max_depth_m))
        timer.add("evaluate_s", time.perf_counter() - te)
    timings = dict(timer.s)
    timings["total_s"] = time.perf_counter() - t_start
    summary["timings_s"] = timings
    summary["one_off_s"] = {"warmup_s (kernel compilation, once per worker)":
                            worker_t.get("warmup_s", 0.0),
                            "rectify_maps_s": timings.get("rectify_maps_s", 0.0)}
    loop_wall = timings.get("frame_loop_wall_s", 0.0)
    summary["frames_per_second"] = len(estimates) / loop_wall if loop_wall > 0 else None
    summary["peak_rss_mb"] = {"client": _rss_mb(resource.RUSAGE_SELF),
                              "workers": _rss_mb(resource.RUSAGE_CHILDREN)}
    if config.report:
        from sea3d.pipeline.report import write_process_report

        tr = time.perf_counter()
        files["report"] = write_process_report(out / "report.html", result)
        summary["timings_s"]["report_s"] = time.perf_counter() - tr
    _write_json(files["summary"], summary)
    publish_results(result)
    if on_result is not None:
        on_result(result)
    return result


def _write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    os.replace(tmp, path)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _write_status_csv(path: Path, estimates: list[OdometryEstimate], fuse: list[str],
                      frame: list[str], valid: list[float]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_ns", "status", "segment", "keyframe_id", "anchor_keyframe_id",
                    "loop_closure", "tracked_features", "depth", "valid_depth_fraction",
                    "fusion"])
        for e, fs, st, vf in zip(estimates, fuse, frame, valid, strict=True):
            w.writerow([e.t_ns, e.status.value, e.segment,
                        "" if e.keyframe_id is None else e.keyframe_id,
                        "" if e.anchor_keyframe_id is None else e.anchor_keyframe_id,
                        int(e.loop_closure), e.tracked_features, st, f"{vf:.4f}", fs])
    os.replace(tmp, path)


def _pose_alignment(t_est: NDArray[np.int64], T_est: F64, t_ref: NDArray[np.int64],
                    T_ref: F64, axis_m: float = 1.0) -> F64:
    """The rigid ``T_ref_est`` that puts the estimate's world (and its mesh) onto the reference's.

    The ATE's alignment fits positions only, and a short survey leg is nearly a straight line:
    the rotation about it is then undetermined (an 8-frame demo dive came out upside down, the
    mesh 2.6 m off). Here every matched pose also gives the tips of its three axes, ``axis_m``
    out, so orientations pin the rotation even when the positions are collinear.
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


def _evaluate(session_path: Path, result: ProcessResult, rig: Any,
              max_depth_m: float) -> dict[str, Any]:
    """Trajectory and surface figures against the simulator's ground truth, if present."""
    from sea3d.eval.surface import surface_metrics
    from sea3d.eval.trajectory import evaluate_trajectory
    from sea3d.io.mesh_files import read_mesh
    from sea3d.io.trajectory_files import read_trajectory
    from sea3d.pipeline.groundtruth import find_ground_truth, observed_surface_points

    gt = find_ground_truth(session_path)
    if gt is None:
        return {"ground_truth": None}
    out: dict[str, Any] = {"ground_truth": str(gt.root)}
    T_ref_est = np.eye(4)
    gt_traj = None
    if gt.poses_left is not None and len(result.t_ns) >= 3:
        try:
            gt_traj = read_trajectory(gt.poses_left)
            trusted = np.array([s in TRUSTED for s in result.statuses])
            m = evaluate_trajectory(result.t_ns[trusted], result.T_world_left[trusted],
                                    gt_traj.t_ns, gt_traj.T_world_x, align="se3",
                                    max_diff_s=0.001)
            out["trajectory_vs_gt"] = m.as_dict()
            T_ref_est = _pose_alignment(result.t_ns[trusted], result.T_world_left[trusted],
                                        gt_traj.t_ns, gt_traj.T_world_x)
        except Sea3dError as err:
            out["trajectory_vs_gt"] = {"error": str(err)}
    if gt.scene_mesh is not None and not result.mesh.empty:
        try:
            ref = read_mesh(gt.scene_mesh)
            mesh_gt = result.mesh.transformed(T_ref_est)
            observed = None
            if gt.depth_dir is not None and gt_traj is not None:
                observed = observed_surface_points(
                    gt.depth_dir, rig.left, gt_traj.t_ns, gt_traj.T_world_x,
                    max_depth_m=max_depth_m)
                if len(observed) == 0:
                    observed = None
            sm = surface_metrics(mesh_gt.vertices, mesh_gt.triangles, ref.vertices,
                                 ref.triangles, reference_points=observed, samples=100_000)
            out["mesh_vs_gt"] = sm.as_dict()
            out["mesh_vs_gt"]["completeness_reference"] = (
                "surface seen in the ground-truth depth maps" if observed is not None
                else "the whole scene mesh")
        except Sea3dError as err:
            out["mesh_vs_gt"] = {"error": str(err)}
    return out


__all__ += ["odometry_available"]
