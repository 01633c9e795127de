"""Live reconstruction: the ordered stages of ``sea3d process`` over frames as they arrive.

Every frame goes through the odometry, in time order; none is dropped. Depth (the per-frame
stage, on a worker) runs on as many frames as it keeps up with: a frame that arrives while
``depth_in_flight`` depth frames are still computing gets no depth of its own; it is only
rectified, the odometry takes the latest depth map as its stereo seeds (the row search
refines them), and fusion skips it (``no-depth`` in status.csv). The drops are counted.

The source is a session replayed at its recorded rate (:class:`ReplayFrames`, ``sea3d live
--replay``); the recorder's cameras feed the same loop through any iterable of
:class:`LiveFrame`. When the source stops, what was fused so far is kept and the stop reason
is reported.

Latency is measured per fused frame, from its arrival to the end of its fusion step (when the
mesh holds it).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ConfigError, SessionError
from sea3d.odometry.types import ImuChunk, OdometryEstimate
from sea3d.pipeline.frame_source import SessionFrames, imu_between
from sea3d.pipeline.frame_stage import FrameResult, FrameStageConfig, process_frame, rectify_pair
from sea3d.pipeline.ordered import TRUSTED, OrderedStages

__all__ = ["LiveConfig", "LiveFrame", "LiveStats", "ReplayFrames", "run_live"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class LiveConfig:
    """How the live loop keeps up."""

    depth_in_flight: int = 1
    """Depth frames computing at once; a frame arriving when that many are busy gets none."""

    def __post_init__(self) -> None:
        if self.depth_in_flight < 1:
            raise ConfigError(f"depth_in_flight must be >= 1, got {self.depth_in_flight}")


@dataclass(frozen=True, kw_only=True, eq=False)
class LiveFrame:
    """One raw stereo pair as it arrives, with the IMU since the previous one."""

    t_ns: int
    left: NDArray[Any]
    right: NDArray[Any]
    imu: ImuChunk | None = None


@dataclass(kw_only=True)
class LiveStats:
    """What the live loop did (frames, drops, latency)."""

    frames: int = 0
    tracked: int = 0
    fused: int = 0
    depth_dropped: int = 0
    latency_s: list[float] = field(default_factory=list)
    stop_reason: str = ""
    cpu_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        lat = np.asarray(self.latency_s, np.float64)
        return {"frames": self.frames, "tracked": self.tracked, "fused": self.fused,
                "depth_dropped": self.depth_dropped,
                "fraction_tracked": self.tracked / self.frames if self.frames else 0.0,
                "fraction_fused": self.fused / self.frames if self.frames else 0.0,
                "latency_s": {"p50": float(np.percentile(lat, 50)) if lat.size else None,
                              "p99": float(np.percentile(lat, 99)) if lat.size else None},
                "cpu_s_per_frame": self.cpu_s / self.frames if self.frames else 0.0,
                "stop_reason": self.stop_reason}


class ReplayFrames:
    """A session's pairs at their recorded rate (``rate`` times faster), as a live source.

    Frames are never skipped: when the consumer is late, the next frame is handed on at once.
    ``stop_reason`` says why the source ended.
    """

    def __init__(self, source: SessionFrames, *, rate: float = 1.0,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], Any] = time.sleep) -> None:
        if not rate > 0:
            raise ConfigError(f"rate must be > 0, got {rate}")
        self.source, self.rate, self.clock, self.sleep = source, rate, clock, sleep
        self.stop_reason = ""

    def __iter__(self) -> Iterator[LiveFrame]:
        pairs = self.source.pairs
        t0_wall, t0 = self.clock(), pairs[0].t_ns
        t_prev: int | None = None
        for pair in pairs:
            due = t0_wall + (pair.t_ns - t0) * 1e-9 / self.rate
            wait = due - self.clock()
            if wait > 0:
                self.sleep(wait)
            try:
                left, right = self.source.read(pair)
            except SessionError as err:
                self.stop_reason = f"camera stopped: {err}"
                return
            yield LiveFrame(t_ns=pair.t_ns, left=left, right=right,
                            imu=imu_between(self.source.imu, t_prev, pair.t_ns))
            t_prev = pair.t_ns
        self.stop_reason = "replay ended"


@dataclass(eq=False)
class _Pending:
    frame: LiveFrame
    arrival: float
    future: Any = None
    rect: tuple[NDArray[np.uint8], NDArray[np.uint8]] | None = None


def run_live(frames: Iterable[LiveFrame], stage: FrameStageConfig, stereo: Any,
             stages: OrderedStages, executor: Any, config: LiveConfig | None = None, *,
             on_update: Callable[[OdometryEstimate, bool], Any] | None = None) -> LiveStats:
    """Odometry on every frame, depth and fusion on those the depth worker keeps up with.

    Args:
        frames: the source (:class:`ReplayFrames`, or cameras); its ``stop_reason`` (if it
            has one) is copied into the stats at the end.
        stage: the per-frame stage's configuration. stereo: its ``StereoDepth``.
        stages: the ordered stages (fed in time order).
        executor: where depth runs (a process pool: the loop must not wait for it).
        config: :class:`LiveConfig`.
        on_update: called after each frame with its estimate and whether it was fused (the
            hook for a live viewer).

    Returns:
        :class:`LiveStats`.
    """
    cfg = config or LiveConfig()
    stats = LiveStats()
    queue: deque[_Pending] = deque()
    last_depth: list[NDArray[np.float32]] = []
    c0 = time.process_time()
    shared = executor.share(stereo)

    def drain(block: bool) -> None:
        while queue:
            head = queue[0]
            if head.future is not None and not head.future.done() and not block:
                return
            queue.popleft()
            fused = head.future is not None
            if fused:
                res: FrameResult = head.future.result()
                if res.status == "ok":
                    last_depth[:] = [res.depth_m]
            else:
                assert head.rect is not None
                seed = last_depth[0] if last_depth else np.full(head.rect[0].shape[:2],
                                                                 np.nan, np.float32)
                res = FrameResult(t_ns=head.frame.t_ns, status="ok", rect_left=head.rect[0],
                                  rect_right=head.rect[1], depth_m=seed,
                                  valid_fraction=float(np.isfinite(seed).mean()))
            est = stages.step(res, head.frame.imu, fuse=fused)
            if est is None:
                continue
            stats.tracked += int(est.status in TRUSTED)
            if fused and stages.fuse_status[-1] == "integrated":
                stats.fused += 1
                stats.latency_s.append(time.monotonic() - head.arrival)
            if on_update is not None:
                on_update(est, fused)

    for frame in frames:
        arrival = time.monotonic()
        stats.frames += 1
        busy = sum(1 for p in queue if p.future is not None and not p.future.done())
        entry = _Pending(frame=frame, arrival=arrival)
        if busy < cfg.depth_in_flight:
            entry.future = executor.submit(process_frame, stage, frame.t_ns, frame.left,
                                           frame.right, shared)
        else:
            stats.depth_dropped += 1
            entry.rect = rectify_pair(stereo, frame.left, frame.right)
        queue.append(entry)
        drain(block=False)
    drain(block=True)
    stats.stop_reason = str(getattr(frames, "stop_reason", "") or "source ended")
    stats.cpu_s = time.process_time() - c0
    return stats


def run_live_replay(session_path: Any, config: Any, live: LiveConfig | None = None, *,
                    rate: float = 1.0) -> tuple[dict[str, Any], LiveStats]:
    """``sea3d live --replay``: a recorded session replayed at its rate through the live loop,
    depth on one worker process, then the finish step and the outputs of ``sea3d process``
    (trajectory, mesh, cloud, status.csv, results.mcap, summary.json with a ``live`` block).

    Args:
        session_path: an MCAP file or session folder.
        config: a :class:`~sea3d.pipeline.process.ProcessConfig` (depth, fusion, output).
        live: :class:`LiveConfig`. rate: replay speed (1: the recorded rate).

    Returns:
        ``(summary, stats)``.

    Raises:
        SessionError, ConfigError: as :func:`~sea3d.pipeline.process.run_process`.
    """
    from pathlib import Path

    from sea3d.io.process_outputs import write_process_outputs, write_summary_json
    from sea3d.io.session import open_session
    from sea3d.pipeline.depth_scheduler import StageTimer
    from sea3d.pipeline.executors import ProcessExecutor
    from sea3d.pipeline.finish import finish_reconstruction, frame_rows, run_summary
    from sea3d.pipeline.frame_stage import install_geometry, stage_depth
    from sea3d.pipeline.process import _no_progress, _odometry, _rig
    from sea3d.pipeline.submap_store import DiskSubmapStore
    from sea3d.recon.submaps import SubmapFusion

    path, out = Path(session_path), Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timer = StageTimer()
    with open_session(path) as session:
        source = SessionFrames(session, path, _rig(session, config),
                               max_frames=config.max_frames)
        stage = config.frame_stage(source.native_rig)
        stereo = stage_depth(stage)
        odo, odometry_name, imu_used, imu_note = _odometry(config, stereo, source, None)
        store = DiskSubmapStore(out / "submaps")
        store.clear()
        # every voxel seen: live fuses only the depth frames it keeps up with, so a surface
        # may reach one of them (process keeps voxels seen twice, MapConfig.min_observations)
        fusion_cfg = config.map.fusion(stereo.depth_range_m, min_observations=1)
        stages = OrderedStages(odo, SubmapFusion(fusion_cfg), store, stereo.maps,
                               use_imu=imu_used, timer=timer)
        executor = ProcessExecutor(1, setup=(install_geometry, (stage, stereo)))
        try:
            stats = run_live(ReplayFrames(source, rate=rate), stage, stereo, stages, executor,
                             live)
        finally:
            executor.close()
    stages.finish_fusion()
    rec = finish_reconstruction(stages, store, fusion_cfg.tsdf, tile_m=config.map.merge_tile_m,
                                cloud_voxel_m=config.map.cloud_voxel_m or config.map.voxel_m / 2,
                                progress=_no_progress, timer=timer)
    files = write_process_outputs(out, t_ns=rec.t_ns, T_world_left=rec.T_world_left,
                                  rows=frame_rows(stages), mesh=rec.mesh, cloud=rec.cloud,
                                  rig=stereo.rig)
    summary = run_summary(stages, rec, session=str(path),
                          pairs_in_session=source.pairs_in_session, odometry=odometry_name,
                          imu_used=imu_used, imu_note=imu_note, voxel_m=config.map.voxel_m)
    summary["live"] = {**stats.as_dict(), "rate": rate,
                       "depth_in_flight": (live or LiveConfig()).depth_in_flight}
    summary["timings_s"] = dict(timer.s)
    write_summary_json(files["summary"], summary)
    return summary, stats
