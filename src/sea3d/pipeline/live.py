"""Live reconstruction: the ordered stages of ``sea3d process`` over frames as they arrive.

Every frame goes through the odometry, in time order; none is dropped. Depth (the per-frame
stage, on a worker) runs on as many frames as it keeps up with: a frame gets no depth of its
own when ``depth_in_flight`` depth frames are still computing, or, with
``depth_max_backlog`` set, when it is stale, i.e. more frames than that already wait behind
it for the odometry (its depth would be fused late; the worker's core is left to the
odometry until it catches up), once a depth frame has been started (before that no depth map
exists to seed a frame without its own). Such a frame is only rectified, the odometry takes the
latest depth map as its stereo seeds (the row search refines them), and fusion skips it
(``no-depth`` in status.csv). The drops are counted (``depth_dropped``, of which
``depth_stale``).

A frame with depth of its own does not hold the odometry: once a depth map exists, its
odometry runs on seeds as a frame without depth does while its depth computes, and its depth
is fused when it comes, in time order (``LiveConfig.odometry_waits_for_depth`` for the loop
before; ``seed_max_age_s``: when the seeds grow older, the odometry waits for the oldest
depth in flight). The source is read and rectified ahead by a thread of its own.
``LiveConfig.depth_pick="newest"`` starts depth there, as each frame is read (the worker
gets the newest frame whenever it has room), ``depth_max_lag_s`` drops depth that would be
fused late (both options, not the default: docs/live.md, benchmarks/results/live.md).

A frame without depth of its own gets the latest depth map moved to its predicted pose
(:meth:`~sea3d.pipeline.depth_rate.DepthRate.seed`: constant velocity from the two previous
tracked frames), so its seeds point at the surface it sees; the unmoved map where nothing
lands, and before two tracked frames.

The source is a session replayed at its recorded rate (:class:`ReplayFrames`, ``sea3d live
--replay``) or the cameras of a running :class:`~sea3d.capture.recorder.Recorder`
(:class:`RecorderFrames`, fed by its listener hook while the recorder writes its session
exactly as it would without live: ``sea3d live --record``). When the source stops, what was
fused so far is kept and written, and the stop reason is reported.

Latency is measured per fused frame, from its arrival (the recorder's delivery, the replay's
due time: the time it waits for the odometry counts) to the end of its fusion step (when the
TSDF holds it), and, while a :class:`~sea3d.pipeline.live_publish.LiveFeed` publishes, to the
published mesh update that holds it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ConfigError, SessionError
from sea3d.odometry.types import ImuChunk, OdometryEstimate
from sea3d.pipeline.frame_source import SessionFrames, imu_between
from sea3d.pipeline.frame_stage import FrameResult, FrameStageConfig, process_frame, rectify_pair
from sea3d.pipeline.lock import locks_out_dir
from sea3d.pipeline.ordered import TRUSTED, OrderedStages
from sea3d.pipeline.pose_stage import OdometryChoice, choose_odometry, choose_session_odometry

if TYPE_CHECKING:
    from sea3d.capture.recorder import Recorder, RecordSummary
    from sea3d.geometry.rig import StereoRig
    from sea3d.pipeline.executors import Executor
    from sea3d.pipeline.live_publish import LiveFeed
    from sea3d.pipeline.process import ProcessConfig
    from sea3d.recon.submaps import SubmapStore
    from sea3d.stereo.recipe import StereoDepth

_Rect = tuple[NDArray[np.uint8], NDArray[np.uint8]]
"""A rectified pair ``(left, right)``."""

__all__ = ["CameraSource", "LiveConfig", "LiveFrame", "LiveSource", "LiveStats", "LiveSummary",
           "LiveUpdate", "Percentiles", "RecorderFrames", "ReplayFrames", "ReplaySource",
           "run_live", "run_live_cameras", "run_live_replay"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class LiveConfig:
    """How the live loop keeps up."""

    depth_in_flight: int = 1
    """Depth frames computing at once; a frame arriving when that many are busy gets none."""
    depth_pick: str = "in-order"
    """Which frames get depth. ``in-order`` (the default): a frame gets depth when the loop
    takes it, if the worker has room. ``newest``: depth starts as a frame is read, before
    the loop takes it (the read-ahead then reads every frame as it arrives, up to
    ``read_ahead_mb``), so the worker, whenever it has room, gets the newest frame and its
    depth is ready when the odometry reaches it. Not the default: on the 80-frame dive the
    eager read-ahead thread slowed the loop it runs beside (benchmarks/results/live.md)."""
    depth_max_lag_s: float | None = None
    """A frame gets no depth while the oldest frame waiting for the live loop (itself
    included) arrived more than this many seconds ago: its fusion would come at least that
    late, and the worker's core is left to the odometry (counted in ``depth_stale``). None:
    any lag (the default; benchmarks/results/live.md)."""
    read_ahead: int = 4
    """Frames the read-ahead thread holds for the loop at most (``in-order``; as before)."""
    read_ahead_mb: float = 256.0
    """With ``depth_pick="newest"``: images (raw and rectified) the read-ahead thread holds
    for the loop at most (at least one frame); the newest frame is read as it arrives only
    while this has room."""
    depth_max_backlog: int | None = None
    """A frame gets depth only while at most this many frames, itself included, wait in the
    source for the live loop (the source's ``backlog``): an older one is stale (not before
    the first depth frame has been started: there is nothing to seed it from). None: any
    (the default: on a loop that falls behind, 1 fused 3.8 % of the 80-frame dive at p50
    2.5 s instead of 17.5 % at 6.1 s; benchmarks/results/live.md)."""
    odometry_waits_for_depth: bool = False
    """A frame's odometry waits for its own depth (the loop holds every frame behind it
    while depth computes). False (the default): once a depth map exists, a frame whose depth
    is still computing goes through the odometry on the seeds a frame without depth gets, and
    its depth is fused when it comes (benchmarks/results/live.md: on the 80-frame dive the frames
    waited seconds behind depth for the loop otherwise)."""
    seed_max_age_s: float = 1.0
    """Oldest seeds (stamp of the frame, less that of the depth map they come from) the
    odometry takes; with older ones it waits for the oldest depth in flight (a depth worker
    starved of CPU: seeds seconds old left 14 of 80 frames IMU-only on a loaded machine).
    About the worker's depth time on a loaded core of this machine (0.6-1.5 s)."""

    behind_after_s: float = 1.0
    """A frame that waits longer than this for the live loop to take it means the loop (the
    odometry, fusion and the update hook) is behind the camera: said once, and named in the
    summary's ``behind``."""

    def __post_init__(self) -> None:
        if not self.behind_after_s > 0:
            raise ConfigError(f"behind_after_s must be > 0, got {self.behind_after_s}")
        if self.depth_in_flight < 1:
            raise ConfigError(f"depth_in_flight must be >= 1, got {self.depth_in_flight}")
        if not self.seed_max_age_s > 0:
            raise ConfigError(f"seed_max_age_s must be > 0, got {self.seed_max_age_s}")
        if self.depth_max_backlog is not None and self.depth_max_backlog < 1:
            raise ConfigError(f"depth_max_backlog must be >= 1 or None, got "
                              f"{self.depth_max_backlog}")
        if self.depth_pick not in ("newest", "in-order"):
            raise ConfigError(f"depth_pick must be 'newest' or 'in-order', got "
                              f"{self.depth_pick!r}")
        if self.depth_max_lag_s is not None and not self.depth_max_lag_s > 0:
            raise ConfigError(f"depth_max_lag_s must be > 0 or None, got "
                              f"{self.depth_max_lag_s}")
        if self.read_ahead < 1:
            raise ConfigError(f"read_ahead must be >= 1, got {self.read_ahead}")
        if not self.read_ahead_mb > 0:
            raise ConfigError(f"read_ahead_mb must be > 0, got {self.read_ahead_mb}")


@dataclass(frozen=True, kw_only=True, eq=False)
class LiveFrame:
    """One raw stereo pair as it arrives, with the IMU since the previous one."""

    t_ns: int
    left: NDArray[Any]
    right: NDArray[Any]
    imu: ImuChunk | None = None
    arrival_s: float | None = None
    """When the pair reached sea3d (``time.monotonic``): the recorder's delivery of its later
    image, the replay's due time; None: when the live loop takes it. Latency counts from it,
    so the time a frame waits for the odometry is in it."""


@dataclass(frozen=True, kw_only=True)
class Percentiles:
    """The median and 99th percentile of a per-frame figure (None: no frame had one)."""

    p50: float | None
    p99: float | None

    @classmethod
    def of(cls, values: list[float]) -> Percentiles:
        a = np.asarray(values, np.float64)
        return cls(p50=float(np.percentile(a, 50)) if a.size else None,
                   p99=float(np.percentile(a, 99)) if a.size else None)


@dataclass(frozen=True, kw_only=True)
class ReplaySource:
    """What ``sea3d live --replay`` adds to the live block: the replay's speed, the depth
    worker's warm-up and the frames that could not be read."""

    rate: float
    warmup_s: float
    frames_unreadable: int


@dataclass(frozen=True, kw_only=True)
class CameraSource:
    """What ``sea3d live --record`` adds to the live block: frames without a partner, the
    warm-up, and the IMU clock check's note (None: the clocks agree, or no IMU)."""

    unpaired_frames: int
    source: str = "cameras"
    warmup_s: float
    imu_clock: str | None


@dataclass(frozen=True, kw_only=True)
class LiveSummary:
    """summary.json's ``live`` block: what the live loop did (:class:`LiveStats`'s figures,
    per-frame lists as :class:`Percentiles`), what its source adds, and the depth frames
    in flight. :meth:`to_json` keeps the block's key order."""

    frames: int
    tracked: int
    fused: int
    depth_dropped: int
    depth_stale: int
    seeds_moved: int
    depth_after_odometry: int
    behind: tuple[str, ...]
    fraction_tracked: float
    fraction_fused: float
    latency_s: Percentiles
    mesh_latency_s: Percentiles
    wait_s: Percentiles
    depth_s: Percentiles
    hold_s: Percentiles
    pose_latency_s: Percentiles
    backlog_max: int
    depth_frames: int
    cpu_s_per_frame: float
    loop_thread_cpu_s_per_frame: float
    read_cpu_s_per_frame: float
    depth_cpu_s_per_depth_frame: float | None
    stop_reason: str
    source: ReplaySource | CameraSource | None = None
    """The source's own figures (None: a run of :func:`run_live` alone)."""
    depth_in_flight: int | None = None

    def to_json(self) -> dict[str, Any]:
        """The block as summary.json holds it: the loop's figures, the source's, then
        ``depth_in_flight`` (the last two left out when None)."""
        out = asdict(self)
        source, in_flight = out.pop("source"), out.pop("depth_in_flight")
        if source is not None:
            out.update(source)
        if in_flight is not None:
            out["depth_in_flight"] = in_flight
        return out


@dataclass(kw_only=True)
class LiveStats:
    """What the live loop did (frames, drops, latency)."""

    frames: int = 0
    tracked: int = 0
    fused: int = 0
    depth_dropped: int = 0
    depth_stale: int = 0
    """Of ``depth_dropped``: frames that got no depth because newer ones waited behind them."""
    seeds_moved: int = 0
    """Frames without depth whose seeds were moved to their predicted pose."""
    depth_after_odometry: int = 0
    """Frames with depth of their own whose odometry ran on seeds before it came."""
    latency_s: list[float] = field(default_factory=list)
    """Per fused frame: arrival to the end of its fusion step."""
    mesh_latency_s: list[float] = field(default_factory=list)
    """Per fused frame: arrival to the published mesh update that holds it (with a feed)."""
    backlog_max: int = 0
    """Most frames waiting for the odometry at once (none is dropped: they wait)."""
    wait_s: list[float] = field(default_factory=list)
    """Per frame: arrival to the live loop taking it (waiting behind earlier frames)."""
    depth_s: list[float] = field(default_factory=list)
    """Per fused frame: its depth on the worker, submitted to done (wall)."""
    hold_s: list[float] = field(default_factory=list)
    """Per fused frame: depth done to the end of its fusion (odometry of the frames before it,
    its own odometry and fusion)."""
    pose_latency_s: list[float] = field(default_factory=list)
    """Per frame with an estimate: arrival to the end of its odometry (the pose published)."""
    depth_frames: int = 0
    """Frames whose depth was started on the worker."""
    depth_cpu_s: list[float] = field(default_factory=list)
    """Per depth frame: the worker's CPU seconds for it (its process, all threads)."""
    stop_reason: str = ""
    cpu_s: float = 0.0
    """The live loop's process over the run (all its threads; not the depth worker)."""
    loop_thread_cpu_s: float = 0.0
    """Of ``cpu_s``: the loop's own thread (odometry, seeds, fusion, the update hook)."""
    read_cpu_s: float = 0.0
    """Of ``cpu_s``: the read-ahead thread (reading, decoding, rectifying)."""
    behind: list[str] = field(default_factory=list)
    """The stages that fell behind the camera, in the order they first did: ``depth`` (a
    frame got no depth because the worker was busy or the frame stale: tracked on seeds,
    not fused) and ``odometry`` (a frame waited longer than ``behind_after_s`` for the loop).
    Each is logged once, when it first happens."""

    def fell_behind(self, stage: str, why: str) -> None:
        """Note (and log, the first time) that ``stage`` is behind the camera."""
        if stage in self.behind:
            return
        self.behind.append(stage)
        log.warning("live: %s is behind the camera: %s", stage, why)

    def summary(self, source: ReplaySource | CameraSource | None = None,
                depth_in_flight: int | None = None) -> LiveSummary:
        """The figures so far as a :class:`LiveSummary` (with the source's own and the depth
        frames in flight, when given)."""
        n = max(self.frames, 1)
        return LiveSummary(
            frames=self.frames, tracked=self.tracked, fused=self.fused,
            depth_dropped=self.depth_dropped, depth_stale=self.depth_stale,
            seeds_moved=self.seeds_moved, depth_after_odometry=self.depth_after_odometry,
            behind=tuple(self.behind),
            fraction_tracked=self.tracked / self.frames if self.frames else 0.0,
            fraction_fused=self.fused / self.frames if self.frames else 0.0,
            latency_s=Percentiles.of(self.latency_s),
            mesh_latency_s=Percentiles.of(self.mesh_latency_s),
            wait_s=Percentiles.of(self.wait_s), depth_s=Percentiles.of(self.depth_s),
            hold_s=Percentiles.of(self.hold_s),
            pose_latency_s=Percentiles.of(self.pose_latency_s),
            backlog_max=self.backlog_max, depth_frames=self.depth_frames,
            cpu_s_per_frame=self.cpu_s / n,
            loop_thread_cpu_s_per_frame=self.loop_thread_cpu_s / n,
            read_cpu_s_per_frame=self.read_cpu_s / n,
            depth_cpu_s_per_depth_frame=(float(np.mean(self.depth_cpu_s))
                                         if self.depth_cpu_s else None),
            stop_reason=self.stop_reason, source=source, depth_in_flight=depth_in_flight)


@dataclass(frozen=True, kw_only=True, eq=False)
class LiveUpdate:
    """What :func:`run_live` hands its ``on_update`` hook after each frame (in the loop's
    thread: the TSDF may be read, not changed)."""

    estimate: OdometryEstimate
    fused: bool
    """The frame was integrated into the TSDF."""
    arrival_s: float
    """When it arrived (``time.monotonic``)."""
    frame: LiveFrame
    stats: LiveStats
    stages: OrderedStages
    late: bool = False
    """The frame's depth was fused after its odometry was handed on (its estimate and
    images came with an earlier update, ``fused`` False)."""


class LiveSource(ABC):
    """A live source of frames (:class:`ReplayFrames`, :class:`RecorderFrames`): iterated
    once by the live loop, which reads :attr:`backlog` after each frame and
    :attr:`stop_reason` at the end. :func:`run_live` takes any iterable of frames; one that
    is not a source is read as a source that hands one frame at a time and gives no reason
    to stop."""

    backlog: int = 1
    """Frames waiting to be handed on, the current one included."""
    stop_reason: str = ""
    """Why the source ended ("" until it has, or when it gives no reason)."""

    @abstractmethod
    def __iter__(self) -> Iterator[LiveFrame]:
        """The frames, in time order."""


class _PlainFrames(LiveSource):
    """An iterable of frames as a :class:`LiveSource`."""

    def __init__(self, frames: Iterable[LiveFrame]) -> None:
        self.frames = frames

    def __iter__(self) -> Iterator[LiveFrame]:
        return iter(self.frames)


def _as_source(frames: Iterable[LiveFrame]) -> LiveSource:
    return frames if isinstance(frames, LiveSource) else _PlainFrames(frames)


class ReplayFrames(LiveSource):
    """A session's pairs at their recorded rate (``rate`` times faster), as a live source.

    Frames are never skipped: when the consumer is late, the next frame is handed on at once.
    A pair that cannot be read (a damaged chunk) is skipped with a warning and counted in
    ``unreadable``, as ``sea3d process`` skips it. ``stop_reason`` says why the source ended.
    ``stop``, polled before each frame, returns a reason to end the replay early (Ctrl-C), or
    None; the frames handed on so far are finished as usual.
    """

    def __init__(self, source: SessionFrames, *, rate: float = 1.0,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], object] = time.sleep,
                 stop: Callable[[], str | None] | None = None) -> None:
        if not rate > 0:
            raise ConfigError(f"rate must be > 0, got {rate}")
        self.source, self.rate, self.clock, self.sleep = source, rate, clock, sleep
        self.stop = stop
        self.stop_reason = ""
        self.backlog = 0
        self.unreadable = 0

    def __iter__(self) -> Iterator[LiveFrame]:
        pairs = self.source.pairs
        stamps = np.array([p.t_ns for p in pairs], np.int64)
        t0_wall, t0 = self.clock(), pairs[0].t_ns
        t_prev: int | None = None
        for pair in pairs:
            due = t0_wall + (pair.t_ns - t0) * 1e-9 / self.rate
            wait = due - self.clock()
            if wait > 0:
                self.sleep(wait)
            reason = self.stop() if self.stop is not None else None
            if reason:
                self.stop_reason = reason
                return
            # frames already due and not yet handed on: what a camera's queue would hold
            now_stamp = t0 + (self.clock() - t0_wall) * self.rate * 1e9
            self.backlog = max(1, int(np.searchsorted(stamps, now_stamp, "right")) - pair.index)
            try:
                left, right = self.source.read(pair)
            except SessionError as err:
                log.warning("frame t_ns=%d cannot be read (%s); skipped", pair.t_ns, err)
                self.unreadable += 1
                continue
            yield LiveFrame(t_ns=pair.t_ns, left=left, right=right,
                            imu=imu_between(self.source.imu, t_prev, pair.t_ns),
                            arrival_s=min(due, self.clock()))
            t_prev = pair.t_ns
        self.stop_reason = "replay ended" + (
            f" ({self.unreadable} unreadable frames skipped)" if self.unreadable else "")


def _read_only(image: NDArray[Any]) -> NDArray[Any]:
    """A view of a recorder's image that live code cannot write into (the recorder encodes
    the same array)."""
    view = image.view()
    view.flags.writeable = False
    return view


class RecorderFrames(LiveSource):
    """Stereo pairs of a running :class:`~sea3d.capture.recorder.Recorder`, as a live source.

    Registered as the recorder's listener (``recorder.add_listener``): the capture threads
    hand every record on and return at once (a lock and a deque append), so the recording
    is exactly what it would be without live. Left and right frames are paired by
    mutual-nearest stamp within ``pair_tolerance_ns`` (default: half the median left frame
    interval seen so far, as :meth:`~sea3d.io.session.SessionReader.match_pairs` does; equal
    stamps pair at once); a frame without a partner is counted in ``unpaired``. The IMU
    samples in ``(previous pair, this pair]`` go with each pair; a pair waits at most
    ``imu_wait_s`` for the IMU to reach its stamp.

    The IMU's clock is checked against the cameras' once, at the first pair after the first
    IMU sample (:func:`~sea3d.pipeline.odometry.imu_clock_check`, the check of ``sea3d
    process``, on the samples seen so far): stamps more than ``imu_tolerance_s`` away are
    logged once as a warning naming the stream (``imu_clock_note``), and pairs no longer wait
    for an IMU that will not reach their stamps.

    No pair is dropped to keep up: those the consumer has not taken yet wait
    (``backlog``). Call :meth:`end` when the recorder has stopped (:func:`run_live_cameras`
    does): the pairs still waiting are handed on, then iteration ends with ``stop_reason``.

    Args:
        recorder: the recorder (it must not be running yet, or records before are missed).
        pair_tolerance_ns: largest stamp difference of a pair (None: from the data).
        imu_wait_s: wall seconds a pair waits for IMU samples up to its stamp.
        imu_time_offset_s: the rig's ``t_imu = t_cam + offset``.
        imu_tolerance_s: largest clock disagreement, seconds
            (:attr:`~sea3d.odometry.config.OdometryConfig.imu_max_clock_offset_s`).
        image_size: the rig's ``(width, height)``: a camera frame of another size is not
            reconstructed (it would be resized into a wrong geometry); the recording is
            stopped there, with one warning naming the frame and both sizes. None: no check.
    """

    def __init__(self, recorder: Recorder, *, pair_tolerance_ns: int | None = None,
                 imu_wait_s: float = 0.2, imu_time_offset_s: float = 0.0,
                 imu_tolerance_s: float = 1.0,
                 image_size: tuple[int, int] | None = None) -> None:
        if pair_tolerance_ns is not None and pair_tolerance_ns < 0:
            raise ConfigError(f"pair_tolerance_ns must be >= 0, got {pair_tolerance_ns}")
        self.pair_tolerance_ns = pair_tolerance_ns
        self.imu_wait_s = float(imu_wait_s)
        self.has_imu = "imu" in recorder.sources
        self.imu_time_offset_s, self.imu_tolerance_s = imu_time_offset_s, imu_tolerance_s
        self.imu_clock_note: str | None = None
        self._imu_first_t: int | None = None
        self._imu_checked = False
        self._cv = threading.Condition()
        self._left: deque[Any] = deque()
        self._right: deque[Any] = deque()
        self._imu: deque[Any] = deque()
        self._imu_last_t: int | None = None
        self._left_stamps: deque[int] = deque(maxlen=31)
        self._pairs: deque[tuple[Any, Any, float]] = deque()
        self._arrival: dict[int, float] = {}  # id(record): when the recorder handed it on
        self._ended = False
        self._end_reason = ""
        self.unpaired = 0
        self.pairs_made = 0
        self.backlog = 0
        self.stop_reason = ""
        self.image_size = image_size
        self._recorder = recorder
        self._size_fault: str | None = None
        recorder.add_listener(self.on_record)

    # -- the recorder's side (capture threads) ---------------------------------------------
    def on_record(self, stream: str, record: Any) -> None:
        """The listener: queue the record and return."""
        now = time.monotonic()
        if stream in ("left", "right") and not self._fits_rig(stream, record):
            return
        with self._cv:
            if stream in ("left", "right"):
                self._arrival[id(record)] = now
            if stream == "left":
                self._left.append(record)
                self._left_stamps.append(int(record.t_ns))
            elif stream == "right":
                self._right.append(record)
            elif stream == "imu":
                self._imu.append(record)
                self._imu_last_t = int(record.t_ns)
                if self._imu_first_t is None:
                    self._imu_first_t = self._imu_last_t
            else:
                return
            if stream in ("left", "right"):
                self._match(final=False)
            self._cv.notify_all()

    def _fits_rig(self, stream: str, record: Any) -> bool:
        """Whether a camera frame has the rig's size; the first that has not stops the
        recording (once, with one warning)."""
        if self.image_size is None:
            return True
        h, w = record.image.shape[:2]
        if (w, h) == tuple(self.image_size):
            return True
        fault = (f"{stream} frame t_ns={int(record.t_ns)} is {w}x{h}, not the rig's "
                 f"{self.image_size[0]}x{self.image_size[1]}; the recording stops there")
        with self._cv:
            first = self._size_fault is None
            if first:
                self._size_fault = fault
        if first:
            log.warning("live: %s", fault)
            self._recorder.request_stop(fault)
        return False

    def end(self, reason: str) -> None:
        """The recorder stopped (``reason``: its stop reason): pair what is left, then end."""
        with self._cv:
            self._ended = True
            self._end_reason = reason
            self._match(final=True)
            self._cv.notify_all()

    # -- pairing (under the lock) ------------------------------------------------------------
    def _tolerance(self) -> int | None:
        if self.pair_tolerance_ns is not None:
            return self.pair_tolerance_ns
        if len(self._left_stamps) < 2:
            return None
        dt = np.diff(np.asarray(self._left_stamps, np.int64))
        dt = dt[dt > 0]
        return int(np.median(dt) // 2) if dt.size else None

    def _match(self, *, final: bool) -> None:
        tol = self._tolerance()
        while self._left:
            left = self._left[0]
            t = int(left.t_ns)
            exact = next((r for r in self._right if int(r.t_ns) == t), None)
            if exact is None:
                if tol is None:
                    if not final:
                        return
                    tol = 0
                newest_right = int(self._right[-1].t_ns) if self._right else None
                waited = len(self._left) > 1 and int(self._left[-1].t_ns) - t > 20 * max(tol, 1)
                if not final and not waited and (newest_right is None or newest_right <= t + tol):
                    return  # a closer right frame may still come
            while self._right and int(self._right[0].t_ns) < t - (tol or 0):
                self._arrival.pop(id(self._right.popleft()), None)
                self.unpaired += 1
            best = exact
            if best is None and self._right:
                cand = min(self._right, key=lambda r: abs(int(r.t_ns) - t))
                if abs(int(cand.t_ns) - t) <= (tol or 0):
                    best = cand
            self._left.popleft()
            if best is None:
                self._arrival.pop(id(left), None)
                self.unpaired += 1
                continue
            nxt = self._left[0] if self._left else None
            if exact is None and nxt is not None and (
                    abs(int(nxt.t_ns) - int(best.t_ns)) < abs(t - int(best.t_ns))):
                self._arrival.pop(id(left), None)
                self.unpaired += 1  # the right frame is the next left frame's partner
                continue
            while self._right and self._right[0] is not best:
                self._arrival.pop(id(self._right.popleft()), None)
                self.unpaired += 1
            if self._right:
                self._right.popleft()
            arrival = max(self._arrival.pop(id(left), 0.0), self._arrival.pop(id(best), 0.0))
            self._pairs.append((left, best, arrival))
            self.pairs_made += 1

    def _imu_until(self, t_ns: int) -> ImuChunk | None:
        take = []
        while self._imu and int(self._imu[0].t_ns) <= t_ns:
            take.append(self._imu.popleft())
        if not take:
            return None
        return ImuChunk(t_ns=np.array([s.t_ns for s in take], np.int64),
                        accel_mps2=np.array([s.accel_mps2 for s in take], np.float64),
                        gyro_radps=np.array([s.gyro_radps for s in take], np.float64))

    def _check_imu_clock(self, t_ns: int) -> None:
        """Once, at the first pair after the first IMU sample (under the lock)."""
        from sea3d.pipeline.odometry import imu_clock_check

        if self._imu_checked or self._imu_first_t is None or self._imu_last_t is None:
            return
        self._imu_checked = True
        why = imu_clock_check(np.array([t_ns], np.int64),
                              np.array([self._imu_first_t, self._imu_last_t], np.int64),
                              self.imu_time_offset_s, tolerance_s=self.imu_tolerance_s)
        if why is not None:
            self.imu_clock_note = f"stream imu: {why}"
            self.has_imu = False  # pairs stop waiting for samples that will not come
            log.warning("live: %s", self.imu_clock_note)

    # -- the live loop's side ------------------------------------------------------------------
    def __iter__(self) -> Iterator[LiveFrame]:
        while True:
            with self._cv:
                while not self._pairs and not self._ended:
                    self._cv.wait(0.5)
                if not self._pairs:
                    break
                left, right, arrival = self._pairs.popleft()
                t = int(left.t_ns)
                if self.has_imu and not self._ended:
                    end = time.monotonic() + self.imu_wait_s
                    while ((self._imu_last_t is None or self._imu_last_t < t)
                           and not self._ended and time.monotonic() < end):
                        self._cv.wait(0.02)
                self._check_imu_clock(t)
                imu = self._imu_until(t)
                self.backlog = len(self._pairs) + 1
            yield LiveFrame(t_ns=t, left=_read_only(left.image), right=_read_only(right.image),
                            imu=imu, arrival_s=arrival)
        self.stop_reason = self._end_reason or "the recorder stopped"


@dataclass(eq=False)
class _Depth:
    """A depth frame started on the worker."""

    future: Any
    submitted: float
    done: list[float] = field(default_factory=list)  # when the worker finished (its callback)


@dataclass(eq=False)
class _Pending:
    frame: LiveFrame
    arrival: float
    rect: tuple[NDArray[np.uint8], NDArray[np.uint8]]
    future: Any = None
    submitted: float = 0.0
    done: list[float] = field(default_factory=list)  # when the worker finished (its callback)
    est: OdometryEstimate | None = None
    index: int = -1  # its place in the ordered stages' per-frame lists
    anchor_rel: tuple[int, F64] | None = None  # (anchor keyframe, T_anchor_cam) at odometry


def _depth_frame(config: FrameStageConfig, t_ns: int, left: NDArray[Any], right: NDArray[Any],
                 geometry: StereoDepth | None = None) -> FrameResult:
    """:func:`~sea3d.pipeline.frame_stage.process_frame` on the worker, with the worker's CPU
    for it in ``timings_s["worker_cpu_s"]`` (taken out by the loop before the stages see it)."""
    c0 = time.process_time()
    res = process_frame(config, t_ns, left, right, geometry)
    res.timings_s["worker_cpu_s"] = time.process_time() - c0
    return res


def _nbytes(frame: LiveFrame, rect: _Rect) -> int:
    return int(frame.left.nbytes + frame.right.nbytes + sum(int(r.nbytes) for r in rect))


class _Prefetch:
    """The source read and rectified by a thread of its own, ahead of the live loop (decoding
    and rectification off the loop's thread; cv2 lets the GIL go), holding at most
    ``max_bytes`` of images and ``max_frames`` frames (at least one frame).
    ``start_depth(frame, lag_s, backlog)``, if given, is called in that thread as each frame
    is read, before it is rectified, with the age of the oldest frame waiting for the loop
    (itself included) and the frames waiting (itself included): the depth it starts goes
    with the frame. ``backlog``: the frames waiting here plus the source's own."""

    def __init__(self, frames: Iterable[LiveFrame], stereo: StereoDepth, *, max_bytes: float,
                 max_frames: int | None = None,
                 start_depth: Callable[[LiveFrame, float, int], _Depth | None] | None = None
                 ) -> None:
        self.source = _as_source(frames)
        self.max_bytes, self.max_frames = float(max_bytes), max_frames
        self.start_depth = start_depth
        self._items: deque[tuple[LiveFrame, _Rect, _Depth | None, int] | None] = deque()
        self._bytes = 0
        self._cv = threading.Condition()
        self._stop = False
        self._error: BaseException | None = None
        self.cpu_s = 0.0
        self._thread = threading.Thread(target=self._run, args=(stereo,), daemon=True,
                                        name="sea3d-live-prefetch")
        self._thread.start()

    def _put(self, item: tuple[LiveFrame, _Rect, _Depth | None, int] | None) -> bool:
        with self._cv:
            size = item[3] if item is not None else 0
            while (not self._stop and self._items and item is not None
                   and (self._bytes + size > self.max_bytes
                        or (self.max_frames is not None
                            and len(self._items) >= self.max_frames))):
                self._cv.wait(0.1)
            if self._stop:
                return False
            self._items.append(item)
            self._bytes += size
            self._cv.notify_all()
            return True

    def _waiting(self, frame: LiveFrame) -> tuple[float, int]:
        """(age of the oldest frame waiting for the loop, frames waiting), both counting
        ``frame``."""
        now = time.monotonic()
        with self._cv:
            first = next((it[0] for it in self._items if it is not None), frame)
            n = sum(1 for it in self._items if it is not None)
        arrival = first.arrival_s if first.arrival_s is not None else now
        return max(0.0, now - arrival), n + int(self.source.backlog or 1)

    def _run(self, stereo: StereoDepth) -> None:
        c0 = time.thread_time()
        try:
            for frame in self.source:
                depth = None
                if self.start_depth is not None:
                    depth = self.start_depth(frame, *self._waiting(frame))
                rect = rectify_pair(stereo, frame.left, frame.right)
                if not self._put((frame, rect, depth, _nbytes(frame, rect))):
                    return
        except BaseException as err:  # handed to the loop's thread
            self._error = err
        finally:
            self.cpu_s = time.thread_time() - c0
        self._put(None)

    @property
    def backlog(self) -> int:
        with self._cv:
            n = sum(1 for it in self._items if it is not None)
        return n + int(self.source.backlog or 1)

    def __iter__(self) -> Iterator[tuple[LiveFrame, _Rect, _Depth | None]]:
        while True:
            with self._cv:
                while not self._items:
                    self._cv.wait(0.5)
                item = self._items.popleft()
                if item is not None:
                    self._bytes -= item[3]
                self._cv.notify_all()
            if item is None:
                if self._error is not None:
                    raise self._error
                return
            yield item[0], item[1], item[2]

    def close(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        self._thread.join(timeout=1)


def run_live(frames: Iterable[LiveFrame], stage: FrameStageConfig, stereo: StereoDepth,
             stages: OrderedStages, executor: Executor, config: LiveConfig | None = None, *,
             on_update: Callable[[LiveUpdate], object] | None = None) -> LiveStats:
    """Odometry on every frame, depth and fusion on those the depth worker keeps up with.

    The source is read and rectified ahead by a thread (:class:`_Prefetch`). A frame's
    odometry does not wait for its own depth once a depth map exists
    (``LiveConfig.odometry_waits_for_depth``): it takes the seeds a frame without depth gets,
    and its depth is fused when it comes, in time order, at the frame's pose then.

    Args:
        frames: the source (:class:`ReplayFrames`, :class:`RecorderFrames`); its
            ``stop_reason`` (if it has one) is copied into the stats at the end, its
            ``backlog`` (frames waiting) read after each frame.
        stage: the per-frame stage's configuration. stereo: its ``StereoDepth``.
        stages: the ordered stages (fed in time order).
        executor: where depth runs (a process pool: the loop must not wait for it).
        config: :class:`LiveConfig`.
        on_update: called after each frame's odometry with a :class:`LiveUpdate` (the hook
            of :class:`~sea3d.pipeline.live_publish.LiveFeed`), and after each late fusion;
            what it raises is logged once and the loop goes on without it.

    Returns:
        :class:`LiveStats`.
    """
    cfg = config or LiveConfig()
    stats = LiveStats()
    c0, t0 = time.process_time(), time.thread_time()
    loop = _Loop(stage, stereo, stages, executor, cfg, stats, on_update)
    newest = cfg.depth_pick == "newest"
    source = _Prefetch(frames, stereo, max_bytes=cfg.read_ahead_mb * 1e6,
                       max_frames=None if newest else cfg.read_ahead,
                       start_depth=loop.start_depth if newest else None)
    try:
        for frame, rect, depth in source:
            loop.take(frame, rect, int(source.backlog), depth)
        loop.drain(block=True)
    finally:
        source.close()
    stats.stop_reason = source.source.stop_reason or "source ended"
    stats.cpu_s = time.process_time() - c0
    stats.loop_thread_cpu_s = time.thread_time() - t0
    stats.read_cpu_s = source.cpu_s
    return stats


class _Loop:
    """The live loop's state: frames waiting for their odometry, then for their fusion."""

    def __init__(self, stage: FrameStageConfig, stereo: StereoDepth, stages: OrderedStages,
                 executor: Executor, cfg: LiveConfig, stats: LiveStats,
                 on_update: Callable[[LiveUpdate], object] | None) -> None:
        from sea3d.pipeline.depth_rate import DepthRate

        self.stage, self.stages, self.executor, self.cfg, self.stats = (
            stage, stages, executor, cfg, stats)
        self.shared = executor.share(stereo)
        self.odo_queue: deque[_Pending] = deque()  # waiting for the odometry, in order
        self.fuse_queue: deque[_Pending] = deque()  # odometry done, waiting for their depth
        self.last_depth: list[NDArray[np.float32]] = []
        self.depth_t = -1  # stamp of the frame whose depth the seeds come from
        self.started_depth = False
        self._lock = threading.Lock()
        self._in_flight = 0  # depth frames started and not finished
        # seeds of a frame without depth: the last depth map moved to its predicted pose
        self.seeder = DepthRate("all", K=stages.K, width_px=int(stereo.maps.width),
                                trusted=TRUSTED)
        self.hook: list[Callable[[LiveUpdate], object]] = [on_update] if on_update else []

    def start_depth(self, frame: LiveFrame, lag_s: float, backlog: int) -> _Depth | None:
        """Depth for ``frame`` if the worker has room and the frame is not stale (see
        :class:`LiveConfig`), else None and the drop counted. ``lag_s``: the age of the
        oldest frame waiting for the loop; ``backlog``: the frames waiting; both counting
        this one. Called by the read-ahead thread (``depth_pick="newest"``) or the loop's."""
        cfg, stats = self.cfg, self.stats
        with self._lock:
            busy = self._in_flight
        stale = self.started_depth and (
            (cfg.depth_max_backlog is not None and backlog > cfg.depth_max_backlog)
            or (cfg.depth_max_lag_s is not None and lag_s > cfg.depth_max_lag_s))
        if busy >= cfg.depth_in_flight or stale:
            stats.depth_dropped += 1
            stats.depth_stale += int(busy < cfg.depth_in_flight)
            stats.fell_behind("depth", (
                f"frame t_ns={frame.t_ns} came while {busy} depth frame(s) were computing"
                if busy >= cfg.depth_in_flight else
                f"frame t_ns={frame.t_ns} was stale ({backlog} frames waiting, the oldest "
                f"{lag_s:.2f} s old)")
                + "; frames get depth as the worker keeps up, the others are tracked on "
                "seeds and not fused")
            return None
        self.started_depth = True
        stats.depth_frames += 1
        with self._lock:
            self._in_flight += 1
        depth = _Depth(future=None, submitted=time.monotonic())
        depth.future = self.executor.submit(_depth_frame, self.stage, frame.t_ns, frame.left,
                                            frame.right, self.shared)
        depth.future.add_done_callback(lambda _f, d=depth.done: self._finished(d))
        return depth

    def _finished(self, done: list[float]) -> None:
        done.append(time.monotonic())
        with self._lock:
            self._in_flight -= 1

    def take(self, frame: LiveFrame, rect: _Rect, backlog: int,
             depth: _Depth | None = None) -> None:
        """A frame from the source (with the depth started for it as it was read, or, with
        ``depth_pick="in-order"``, depth for it now if the worker has room), then the loop."""
        stats = self.stats
        taken = time.monotonic()
        arrival = taken if frame.arrival_s is None else frame.arrival_s
        stats.frames += 1
        stats.wait_s.append(max(0.0, taken - arrival))
        if taken - arrival > self.cfg.behind_after_s:
            stats.fell_behind("odometry", (
                f"frame t_ns={frame.t_ns} waited {taken - arrival:.2f} s for the live loop "
                f"(odometry, fusion and publishing; {backlog} frames waiting)"))
        stats.backlog_max = max(stats.backlog_max, backlog)
        if self.cfg.depth_pick == "in-order":
            depth = self.start_depth(frame, max(0.0, taken - arrival), backlog)
        entry = _Pending(frame=frame, arrival=arrival, rect=rect)
        if depth is not None:
            entry.future, entry.submitted, entry.done = depth.future, depth.submitted, depth.done
        self.odo_queue.append(entry)
        self.drain(block=False)

    def _blocker(self, head: _Pending) -> Any:
        """The depth still computing that the head frame's odometry waits for, or None:
        its own when there is nothing to seed from yet (or ``odometry_waits_for_depth``);
        when the seeds are older than ``seed_max_age_s``, the oldest depth in flight."""
        own = head.future
        if own is not None and own.done():
            return None
        if own is not None and (self.cfg.odometry_waits_for_depth or not self.last_depth):
            return own
        age_s = (head.frame.t_ns - self.depth_t) * 1e-9
        if self.last_depth and age_s <= self.cfg.seed_max_age_s:
            return None
        pending = next((p.future for p in self.fuse_queue if not p.future.done()), None)
        return pending if pending is not None else own

    def drain(self, block: bool) -> None:
        """Odometry on every frame it can run on, then fusion of the depth that has come."""
        while self.odo_queue:
            self._fuse(block=False)
            blocker = self._blocker(self.odo_queue[0])
            if blocker is not None:
                if not block:
                    return
                blocker.result()
                continue
            self._odometry(self.odo_queue.popleft())
        self._fuse(block=block)

    def _odometry(self, head: _Pending) -> None:
        stages, stats, seeder = self.stages, self.stats, self.seeder
        own = head.future is not None and head.future.done()
        if own:
            res: FrameResult = self._result(head)
            if res.status == "ok":
                self.last_depth[:] = [res.depth_m]
                self.depth_t = int(res.t_ns)
            res = replace(res, timings_s={})  # the worker's timings are counted at fusion
        else:
            if self.last_depth:
                before = seeder.warped
                seed = seeder.seed(self.last_depth[0])
                if head.future is None:
                    stats.seeds_moved += seeder.warped - before
            else:
                seed = np.full(head.rect[0].shape[:2], np.nan, np.float32)
            res = FrameResult(t_ns=head.frame.t_ns, status="ok", rect_left=head.rect[0],
                              rect_right=head.rect[1], depth_m=seed, seeded=True,
                              valid_fraction=float(np.isfinite(seed).mean()))
        est = stages.step(res, head.frame.imu, fuse=False)
        if est is None:
            return
        stats.pose_latency_s.append(time.monotonic() - head.arrival)
        T_cam = np.asarray(est.T_world_left) @ stages.T_left_rect
        seeder.observe(res.t_ns, est.status, T_cam, own_depth=own and res.status == "ok")
        stats.tracked += int(est.status in TRUSTED)
        if head.future is not None:
            head.est, head.index = est, len(stages.estimates) - 1
            a = est.anchor_keyframe_id
            if a is not None and a in stages.kf_rect:
                head.anchor_rel = (a, np.linalg.inv(stages.kf_rect[a]) @ T_cam)
            stats.depth_after_odometry += int(not own)
            self.fuse_queue.append(head)
        self._publish(head, est, fused=False, late=False)

    def _fuse(self, block: bool) -> None:
        """Fuse the frames whose depth has come, in time order."""
        stages, stats = self.stages, self.stats
        while self.fuse_queue:
            head = self.fuse_queue[0]
            if not head.future.done() and not block:
                return
            self.fuse_queue.popleft()
            res: FrameResult = self._result(head)
            assert head.est is not None
            if res.status == "ok" and int(res.t_ns) > self.depth_t:  # the seeds' depth now
                self.last_depth[:] = [res.depth_m]
                self.depth_t = int(res.t_ns)
                pose = self._pose_now(head)
                if pose is None:
                    pose = np.asarray(head.est.T_world_left) @ stages.T_left_rect
                self.seeder.depth_of(pose if head.est.status in TRUSTED else None)
            status = stages.fuse_late(head.index, res, head.est, self._pose_now(head))
            fused = status == "integrated"
            if fused:
                stats.fused += 1
                now = time.monotonic()
                stats.latency_s.append(now - head.arrival)
                done = head.done[0] if head.done else now
                stats.depth_s.append(done - head.submitted)
                stats.hold_s.append(now - done)
            if fused:
                self._publish(head, head.est, fused=True, late=True)

    def _result(self, head: _Pending) -> FrameResult:
        """The frame's depth result (waiting for it); the worker's CPU for it, once, into
        the stats."""
        res: FrameResult = head.future.result()
        cpu = res.timings_s.pop("worker_cpu_s", None)
        if cpu is not None:
            self.stats.depth_cpu_s.append(float(cpu))
        return res

    def _pose_now(self, head: _Pending) -> F64 | None:
        """The frame's ``T_world_rect`` now: moved with its anchor keyframe by loop closures
        since its odometry (None: its estimate's)."""
        if head.anchor_rel is None:
            return None
        a, rel = head.anchor_rel
        T = self.stages.kf_rect.get(a)
        return None if T is None else np.asarray(T) @ rel

    def _publish(self, head: _Pending, est: OdometryEstimate, *, fused: bool,
                 late: bool) -> None:
        if not self.hook:
            return
        try:
            self.hook[0](LiveUpdate(estimate=est, fused=fused, arrival_s=head.arrival,
                                    frame=head.frame, stats=self.stats, stages=self.stages,
                                    late=late))
        except Exception as err:  # a viewer never stops the reconstruction
            log.warning("live update hook failed, going on without it: %s: %s",
                        type(err).__name__, err)
            self.hook.clear()


class _Run:
    """The stages of one live run over a rig (shared by replay and cameras)."""

    def __init__(self, config: ProcessConfig, native_rig: StereoRig, out: Path, *,
                 choose_odometry: Callable[[StereoDepth], OdometryChoice],
                 feed: LiveFeed | None = None) -> None:
        from sea3d.pipeline.depth_scheduler import StageTimer
        from sea3d.pipeline.executors import ProcessExecutor
        from sea3d.pipeline.frame_stage import install_geometry, stage_depth
        from sea3d.pipeline.lock import clear_stale_temps
        from sea3d.pipeline.submap_store import DiskSubmapStore
        from sea3d.recon.submaps import SubmapFusion

        self.config, self.out, self.feed = config, out, feed
        out.mkdir(parents=True, exist_ok=True)
        clear_stale_temps(out)
        self.timer = StageTimer()
        self.stage = config.frame_stage(native_rig)
        self.stereo = stage_depth(self.stage)
        odometry = choose_odometry(self.stereo)
        self.odo, self.odometry_name, self.imu_used, self.imu_note = odometry
        disk = DiskSubmapStore(out / "submaps")
        disk.clear()
        self.store: SubmapStore = disk
        # every voxel seen: live fuses only the depth frames it keeps up with, so a surface
        # may reach one of them (process keeps voxels seen twice, MapConfig.min_observations)
        self.fusion_cfg = config.map.fusion(self.stereo.depth_range_m, min_observations=1)
        if feed is not None:  # finished submaps are meshed once for the live view
            self.store = feed.wrap_store(self.store, self.fusion_cfg.tsdf)
        self.stages = OrderedStages(self.odo, SubmapFusion(self.fusion_cfg), self.store,
                                    self.stereo.maps, use_imu=self.imu_used, timer=self.timer)
        self.executor = ProcessExecutor(1, setup=(install_geometry, (self.stage, self.stereo)))

    def warm(self) -> float:
        """Start the depth worker and run its first (kernel-compiling) frame on a textured
        pair before the source starts, so the first frames are not held behind the worker's
        start; returns the seconds it took."""
        t0 = time.monotonic()
        rig = self.stage.rig
        noise = np.random.default_rng(0).integers(0, 256, (rig.height, rig.width + 8),
                                                  dtype=np.uint8)
        left, right = noise[:, 8:].copy(), noise[:, :-8].copy()  # 8 px of disparity
        try:
            first = self.executor.submit(process_frame, self.stage, 0, left, right,
                                         self.executor.share(self.stereo))
            import open3d  # noqa: F401  (meanwhile: the TSDF's library, not at the first fusion)

            from sea3d.pipeline.depth_rate import warp_depth

            # the seeds' kernel loaded (numba's cache) now, not in the loop at the first seed
            warp_depth(np.ones((2, 2), np.float32), np.eye(3), np.eye(4))
            first.result()
        except BaseException:
            self.executor.close()
            if self.feed is not None:
                self.feed.close()
            raise
        return time.monotonic() - t0

    def run(self, frames: Iterable[LiveFrame], live: LiveConfig | None) -> LiveStats:
        hook = self.feed.on_update if self.feed is not None else None
        try:
            return run_live(frames, self.stage, self.stereo, self.stages, self.executor, live,
                            on_update=hook)
        except BaseException:
            if self.feed is not None:
                self.feed.close()
            raise
        finally:
            self.executor.close()

    def finish(self, stats: LiveStats, live: LiveConfig | None,
               source: ReplaySource | CameraSource, **extra: Any) -> dict[str, Any]:
        """The finish step of ``process`` (merge, outputs, summary.json with its ``fusion``
        block) and summary.json's ``live`` block; the feed publishes the merged mesh and the
        final status."""
        from sea3d.io.process_outputs import write_summary_json
        from sea3d.pipeline.finish import FinishOptions, finish_run, fusion_summary
        from sea3d.pipeline.progress import no_progress

        config, stages = self.config, self.stages
        stages.finish_fusion()
        done = finish_run(
            stages, self.store, self.fusion_cfg.tsdf, self.out, self.stereo.rig,
            FinishOptions.of_map(config.map), progress=no_progress, timer=self.timer,
            summary_extra=dict(odometry=self.odometry_name, imu_used=self.imu_used,
                               imu_note=self.imu_note, voxel_m=config.map.voxel_m, **extra))
        rec, files, summary = done.rec, done.files, done.summary
        summary["fusion"] = fusion_summary(config.map, self.fusion_cfg.tsdf)
        if self.feed is not None:
            self.feed.finish(stats, rec)
        summary["live"] = stats.summary(
            source, depth_in_flight=(live or LiveConfig()).depth_in_flight).to_json()
        summary["timings_s"] = dict(self.timer.s)
        write_summary_json(files["summary"], summary)
        return summary


@locks_out_dir  # as process: a second run into the folder is refused (OutputInUseError)
def run_live_replay(session_path: str | os.PathLike[str], config: ProcessConfig,
                    live: LiveConfig | None = None, *, rate: float = 1.0,
                    feed: LiveFeed | None = None,
                    stop: Callable[[], str | None] | None = None,
                    ) -> tuple[dict[str, Any], LiveStats]:
    """``sea3d live --replay``: a recorded session replayed at its rate through the live loop,
    depth on one worker process, then the finish step and the outputs of ``sea3d process``
    (trajectory, mesh, cloud, status.csv, results.mcap, summary.json with a ``live`` block).

    Args:
        session_path: an MCAP file or session folder.
        config: a :class:`~sea3d.pipeline.process.ProcessConfig` (depth, fusion, output).
        live: :class:`LiveConfig`. rate: replay speed (1: the recorded rate).
        feed: a :class:`~sea3d.pipeline.live_publish.LiveFeed` publishing while it runs.
        stop: polled before each frame; a reason it returns ends the replay there (Ctrl-C),
            and the frames so far are finished and written as at the end of the session.

    Returns:
        ``(summary, stats)``.

    Raises:
        SessionError, ConfigError: as :func:`~sea3d.pipeline.process.run_process`; a
            ``rate`` not > 0 (ConfigError) before the session opens.
        OutputInUseError: another run (``live`` or ``process``) writes into the folder.
    """
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import open_session

    if not rate > 0:  # before the session opens and the depth worker warms up
        raise ConfigError(f"rate must be > 0, got {rate}")
    path = Path(session_path)
    with open_session(path) as session:
        source = SessionFrames(session, path, resolve_rig(config.rig_path, session),
                               max_frames=config.max_frames)
        run = _Run(config, source.native_rig, Path(config.out_dir), feed=feed,
                   choose_odometry=lambda stereo: choose_session_odometry(config.poses, stereo,
                                                                          source))
        warm_s = run.warm()
        replay = ReplayFrames(source, rate=rate, stop=stop)
        stats = run.run(replay, live)
    summary = run.finish(stats, live, session=str(path),
                         pairs_in_session=source.pairs_in_session,
                         source=ReplaySource(rate=rate, warmup_s=warm_s,
                                             frames_unreadable=replay.unreadable))
    return summary, stats


class _RigText:
    """What :func:`~sea3d.io.rig_file.resolve_rig` reads of a session: its stored rig."""

    def __init__(self, path: Path, rig_yaml: str | None) -> None:
        self.path, self.rig_yaml = path, rig_yaml


@locks_out_dir
def run_live_cameras(recorder: Recorder, config: ProcessConfig,
                     live: LiveConfig | None = None, *, feed: LiveFeed | None = None,
                     pair_tolerance_ns: int | None = None,
                     ) -> tuple[dict[str, Any], LiveStats, RecordSummary]:
    """``sea3d live --record``: record the cameras (the recorder writes its session as it
    would alone) and reconstruct them live through the recorder's listener hook; when the
    recording stops (a camera that stops, the duration, Ctrl-C, a full disk), the frames
    already received are finished, the mesh so far is merged and written with the outputs of
    ``sea3d process``, and ``live.stop_reason`` says why it stopped.

    Args:
        recorder: a :class:`~sea3d.capture.recorder.Recorder`, not started (this runs it, in
            a thread of its own, and returns when both have finished).
        config: a :class:`~sea3d.pipeline.process.ProcessConfig`; its rig file, else the
            rig stored with the recording (``RecorderConfig.rig_yaml``).
        live: :class:`LiveConfig`. feed: a :class:`~sea3d.pipeline.live_publish.LiveFeed`.
        pair_tolerance_ns: see :class:`RecorderFrames`.

    Returns:
        ``(summary, stats, record_summary)``.

    Raises:
        SessionError: the recorder's output holds a session already (before any warm-up).
        ConfigError: no rig; RigFileError: a bad one; CaptureError: the recorder could not
            start (nothing was recorded). OutputInUseError: another run (``live`` or
            ``process``) writes into the output folder (nothing was recorded). An error of
            the live loop stops the recording cleanly (what was written stays readable) and
            is raised.
    """
    from sea3d.io.rig_file import resolve_rig
    from sea3d.io.session import check_new_session

    rc = recorder.config
    check_new_session(rc.out_path, rc.format)  # the recorder does too, after the warm-up
    if config.rig_path is None and not rc.rig_yaml:
        raise ConfigError("live reconstruction from cameras needs the rig: give a rig file "
                          "(rig_path), stored with the recording as well")
    rig = resolve_rig(config.rig_path, _RigText(rc.out_path, rc.rig_yaml))
    # the IMU's samples are still to come: its clock is checked on the first pair
    imu_t_ns = None if "imu" in recorder.sources else np.zeros(0, np.int64)
    run = _Run(config, rig, Path(config.out_dir), feed=feed,
               choose_odometry=lambda stereo: choose_odometry(config.poses, stereo, None,
                                                              imu_t_ns, where="live"))
    warm_s = run.warm()  # before the cameras start
    frames = RecorderFrames(
        recorder, pair_tolerance_ns=pair_tolerance_ns,
        imu_time_offset_s=rig.imu.time_offset_s if rig.imu is not None else 0.0,
        imu_tolerance_s=config.poses.imu_max_clock_offset_s,
        image_size=(rig.width, rig.height))
    result: dict[str, Any] = {}

    def record() -> None:
        try:
            result["summary"] = recorder.run()
        except BaseException as err:  # handed to the caller below
            result["error"] = err
        finally:
            reason = (result["summary"].stop_reason if "summary" in result
                      else f"the recorder failed: {result.get('error')}")
            errors = result["summary"].errors if "summary" in result else ["failed"]
            frames.end(f"camera stopped: {reason}" if errors else f"recording ended: {reason}")

    thread = threading.Thread(target=record, name="sea3d-live-recorder", daemon=True)
    thread.start()
    try:
        stats = run.run(frames, live)
    except BaseException:
        recorder.request_stop("live reconstruction failed")
        thread.join()
        raise
    thread.join()
    if "error" in result:
        raise result["error"]
    summary = run.finish(stats, live, session=str(rc.out_path), pairs_in_session=frames.pairs_made,
                         source=CameraSource(unpaired_frames=frames.unpaired, warmup_s=warm_s,
                                             imu_clock=frames.imu_clock_note))
    return summary, stats, result["summary"]
