"""Live publishing over the Foxglove WebSocket protocol (foxglove-sdk): what the ROV sees,
on a top-side machine with Foxglove or Lichtblick and no ROS install.

- :class:`FoxglovePublisher` owns the server and its channels (topics and schemas in
  :mod:`sea3d.io.foxglove_msgs`) and publishes images, IMU, echosounder, depth, poses, point
  clouds and meshes. Images are JPEG-encoded only while a client subscribes to them.
- :class:`FoxgloveBridge` feeds a publisher from a running
  :class:`~sea3d.capture.recorder.Recorder` (``sea3d record --foxglove``) or a
  :class:`~sea3d.capture.monitor.SessionPlayer` (``sea3d monitor --foxglove``): the newest frame
  of each camera (polled, so a slow link never holds the recorder back), every IMU and
  echosounder sample (the recorder's listener hook, or the session's series in replay), and,
  when its caller gives it a depth provider (e.g.
  :class:`sea3d.pipeline.live_preview.DepthPreview`), a depth image in a thread of its own.
  Capture runs no stage itself: without a provider no depth is published.

The server listens on loopback (127.0.0.1) unless another address is given; it has no
authentication, so expose it only on a trusted tether network. A client that goes away
mid-stream is dropped by the server and nothing else notices; a port that is taken is a
:class:`~sea3d.errors.CaptureError` naming the address.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from sea3d.errors import CaptureError, ConfigError
from sea3d.io import foxglove_msgs as fm

__all__ = [
    "LIVE_STATUS_SCHEMA",
    "LIVE_STATUS_TOPIC",
    "FoxgloveBridge",
    "FoxgloveConfig",
    "FoxglovePublisher",
]

_log = logging.getLogger(__name__)

SONAR_FOV_RAD = 0.5236  # the Ping echosounder's 30 degree beam (Blue Robotics datasheet)

LIVE_STATUS_TOPIC = "/live/status"
"""Topic of the live reconstruction's status (``sea3d live``)."""

_NUM = {"type": ["number", "null"]}
_INT = {"type": ["integer", "null"]}
LIVE_STATUS_SCHEMA: dict[str, Any] = {
    "title": "sea3d.LiveStatus",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                       "nsec": {"type": "integer"}}},
        "running": {"type": "boolean"},
        "frames": _INT,
        "tracked": _INT,
        "fused": _INT,
        "depth_dropped": _INT,
        "backlog": _INT,
        "odometry_status": {"type": ["string", "null"]},
        "latency_p50_s": _NUM,
        "mesh_latency_p50_s": _NUM,
        "trajectory_poses": _INT,
        "mesh_vertices": _INT,
        "mesh_triangles": _INT,
        "stop_reason": {"type": ["string", "null"]},
    },
}
"""JSON schema of ``/live/status``: frames seen, tracked (trusted pose), fused, depth frames
dropped to keep up, frames waiting, the last frame's odometry status, latency medians
(frame to fusion, frame to published mesh), poses in ``/odometry/trajectory``, the mesh
published so far, and why the run stopped (null while it runs)."""


@dataclass(frozen=True, kw_only=True)
class FoxgloveConfig:
    """How to serve.

    Attributes:
        host: address to listen on (loopback by default).
        port: TCP port (0 picks a free one; see :attr:`FoxglovePublisher.port`).
        name: server name shown by the client.
        jpeg_quality: 0..100 for the camera images.
        max_width_px: downscale camera images to at most this width for the link (None: full
            resolution); the published camera calibration is scaled to match.
        image_rate_hz: at most this many images per second per camera (None: every new frame).
        depth_rate_hz: depth (or disparity) images per second; 0 turns them off.
        depth_width_px: width of the depth image, for the caller's depth provider (see
            :class:`FoxgloveBridge`; the rig is scaled to it).
        backlog_messages: outgoing messages buffered per client; a client that falls this far
            behind is disconnected by the server (it can reconnect).
        accept_old_subprotocol: also accept clients that offer only ``foxglove.websocket.v1``
            (Lichtblick before its ``foxglove.sdk.v1`` support), through
            :class:`~sea3d.capture.foxglove_shim.SubprotocolShim`; False serves the SDK's
            server on the address directly (new-name clients only).
    """

    host: str = "127.0.0.1"
    port: int = 8765
    name: str = "sea3d"
    jpeg_quality: int = 80
    max_width_px: int | None = 960
    image_rate_hz: float | None = 10.0
    depth_rate_hz: float = 2.0
    depth_width_px: int = 480
    backlog_messages: int = 256
    accept_old_subprotocol: bool = True

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"Foxglove port must be 0..65535, got {self.port}")
        if not 0 <= self.jpeg_quality <= 100:
            raise ConfigError(f"jpeg_quality must be 0..100, got {self.jpeg_quality}")
        if self.max_width_px is not None and self.max_width_px < 16:
            raise ConfigError(f"max_width_px must be >= 16, got {self.max_width_px}")
        if self.image_rate_hz is not None and not self.image_rate_hz > 0:
            raise ConfigError(f"image_rate_hz must be > 0, got {self.image_rate_hz}")
        if self.depth_rate_hz < 0 or self.depth_width_px < 32 or self.backlog_messages < 1:
            raise ConfigError(
                "need depth_rate_hz >= 0, depth_width_px >= 32 and backlog_messages >= 1"
            )


class _ClientGoneFilter(logging.Filter):
    """foxglove-sdk logs a client that vanishes (a tether that drops) as an ERROR; for a live
    view that is an everyday event: say it once at INFO instead."""

    _PHRASES = ("without closing handshake", "Broken pipe", "Connection reset")

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        if any(p in msg for p in self._PHRASES):
            _log.info("a Foxglove client went away: %s", msg)
            return False
        return True


_CLIENT_GONE = _ClientGoneFilter()
for _name in ("foxglove.websocket.connected_client.poller", "foxglove.websocket.connected_client"):
    logging.getLogger(_name).addFilter(_CLIENT_GONE)


class _Listener:
    """Counts subscriptions per channel id (foxglove-sdk calls it from its own threads)."""

    def __init__(self) -> None:
        self.subscribers: collections.Counter[int] = collections.Counter()
        self.clients: set[int] = set()
        self.lock = threading.Lock()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            self.subscribers[int(channel.id)] += 1
            self.clients.add(int(client.id))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            self.subscribers[int(channel.id)] -= 1


class FoxglovePublisher:
    """A Foxglove WebSocket server with sea3d's channels.

    Every ``publish_*`` method is thread-safe and cheap when nobody subscribes.

    Args:
        config: :class:`FoxgloveConfig`.
        rig: the stereo rig (camera calibrations and ``left`` -> ``right`` in ``/tf``), or None.

    Raises:
        CaptureError: the address cannot be bound (a port that is taken is named).
    """

    def __init__(self, config: FoxgloveConfig | None = None, *, rig: Any = None) -> None:
        import foxglove
        from foxglove.channels import (
            CameraCalibrationChannel,
            CompressedImageChannel,
            FrameTransformsChannel,
            PointCloudChannel,
            PoseInFrameChannel,
            PosesInFrameChannel,
            RawImageChannel,
        )

        self.config = cfg = config or FoxgloveConfig()
        self.rig = rig
        self._ctx = ctx = foxglove.Context()
        self._listener = _Listener()
        from sea3d.capture.foxglove_shim import SubprotocolShim

        # The SDK's server on a loopback port behind a shim on the public address, which also
        # accepts clients of the protocol's old name (foxglove.websocket.v1).
        self._shim = SubprotocolShim(cfg.host, cfg.port) if cfg.accept_old_subprotocol else None
        try:
            self._server = foxglove.start_server(
                name=cfg.name,
                host="127.0.0.1" if self._shim is not None else cfg.host,
                port=0 if self._shim is not None else cfg.port,
                context=ctx,
                server_listener=self._listener,  # type: ignore[arg-type]
                message_backlog_size=cfg.backlog_messages,
            )
        except RuntimeError as err:
            if self._shim is not None:
                self._shim.close()
            reason = str(err).removeprefix("FoxgloveError: ")
            hint = " (another program, or another sea3d, holds it)" if "in use" in reason else ""
            raise CaptureError(
                f"cannot serve Foxglove on {cfg.host}:{cfg.port}: {reason}{hint}"
            ) from err
        if self._shim is not None:
            self._shim.start(int(self._server.port))  # clients wait until the server runs
        if cfg.host not in ("127.0.0.1", "localhost", "::1"):
            _log.warning(
                "Foxglove server listens on %s, reachable from other machines; it has no "
                "authentication",
                cfg.host,
            )
        self.image = {
            s: CompressedImageChannel(fm.TOPICS[s], context=ctx) for s in ("left", "right")
        }
        self.info = {
            s: CameraCalibrationChannel(fm.TOPICS[f"{s}_info"], context=ctx)
            for s in ("left", "right")
        }
        self.imu = foxglove.Channel(fm.TOPICS["imu"], schema=fm.IMU_SCHEMA, context=ctx)
        self.sonar = foxglove.Channel(fm.TOPICS["sonar"], schema=fm.SONAR_SCHEMA, context=ctx)
        self.depth = RawImageChannel(fm.TOPICS["depth"], context=ctx)
        self.disparity = RawImageChannel(fm.TOPICS["disparity"], context=ctx)
        self.tf = FrameTransformsChannel(fm.TOPICS["tf"], context=ctx)
        self.pose = PoseInFrameChannel(fm.TOPICS["pose"], context=ctx)
        self.trajectory = PosesInFrameChannel(fm.TOPICS["trajectory"], context=ctx)
        self.cloud = PointCloudChannel(fm.TOPICS["cloud"], context=ctx)
        # foxglove.SceneUpdate bytes encoded from the arrays (fm.mesh_scene)
        self.mesh = foxglove.Channel(fm.TOPICS["mesh"], schema=fm.SCENE_UPDATE_SCHEMA,
                                     message_encoding="protobuf", context=ctx)
        self.live_status = foxglove.Channel(LIVE_STATUS_TOPIC, schema=LIVE_STATUS_SCHEMA,
                                            context=ctx)
        self.counts: collections.Counter[str] = collections.Counter()
        self._count_lock = threading.Lock()
        self._last_image_t: dict[str, float] = {}
        self._last_rig_tf = 0.0
        self._stopped = False
        _log.info("Foxglove server on %s:%d", cfg.host, self.port)

    # -- properties ---------------------------------------------------------------------
    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return self._shim.port if self._shim is not None else int(self._server.port)

    @property
    def url(self) -> str:
        """``ws://HOST:PORT`` for Foxglove's 'Open connection' dialog."""
        host = f"[{self.config.host}]" if ":" in self.config.host else self.config.host
        return f"ws://{host}:{self.port}"

    def subscribed(self, channel: Any) -> bool:
        """True while some client subscribes to ``channel``."""
        return bool(channel.has_sinks())

    def clients_seen(self) -> int:
        """Number of different clients that subscribed to anything so far."""
        with self._listener.lock:
            return len(self._listener.clients)

    def _count(self, topic: str) -> None:
        with self._count_lock:
            self.counts[topic] += 1

    # -- publishing ------------------------------------------------------------------------
    def publish_image(self, stream: str, t_ns: int, image: np.ndarray) -> bool:
        """JPEG-encode and publish one camera image (and its calibration) if a client
        subscribes and the rate limit allows; returns whether it was sent.

        Args:
            stream: ``left`` or ``right``.
            t_ns: stamp, nanoseconds.
            image: (H, W) or (H, W, 3) RGB, uint8 or uint16.
        """
        ch = self.image[stream]
        info_wanted = self.subscribed(self.info[stream])
        if not (self.subscribed(ch) or info_wanted):
            return False
        rate = self.config.image_rate_hz
        now = time.monotonic()
        if rate is not None and now - self._last_image_t.get(stream, -1e9) < 1.0 / rate:
            return False
        self._last_image_t[stream] = now
        data, scale = fm.encode_preview_jpeg(
            image, quality=self.config.jpeg_quality, max_width_px=self.config.max_width_px
        )
        if self.subscribed(ch):
            ch.log(fm.compressed_image(t_ns, data, "jpeg", stream), log_time=int(t_ns))
            self._count(fm.TOPICS[stream])
        if info_wanted and self.rig is not None:
            pin = (self.rig.left if stream == "left" else self.rig.right).lens
            h, w = image.shape[:2]
            msg = fm.camera_calibration(t_ns, stream, pin.K, pin.dist, w, h, scale=scale)
            self.info[stream].log(msg, log_time=int(t_ns))
            self._count(fm.TOPICS[f"{stream}_info"])
        if stream == "left" and self.rig is not None and now - self._last_rig_tf >= 1.0:
            self._last_rig_tf = now
            tf = fm.frame_transform(t_ns, "left", "right", np.asarray(self.rig.T_left_right))
            self.tf.log(fm.frame_transforms([tf]), log_time=int(t_ns))
            self._count(fm.TOPICS["tf"])
        return True

    def publish_imu(self, t_ns: int, accel_mps2: Any, gyro_radps: Any) -> None:
        """One IMU sample (m/s^2, rad/s, IMU frame) as JSON ``sea3d.Imu``."""
        if self.subscribed(self.imu):
            self.imu.log(fm.imu_message(t_ns, accel_mps2, gyro_radps), log_time=int(t_ns))
            self._count(fm.TOPICS["imu"])

    def publish_sonar(self, t_ns: int, range_m: float, confidence: float) -> None:
        """One echosounder reading as JSON ``sea3d.Range`` (NaN -> null)."""
        if self.subscribed(self.sonar):
            msg = fm.sonar_message(t_ns, range_m, confidence, SONAR_FOV_RAD)
            self.sonar.log(msg, log_time=int(t_ns))
            self._count(fm.TOPICS["sonar"])

    def publish_depth(self, t_ns: int, depth_m: np.ndarray, *, disparity: bool = False) -> None:
        """A float image: depth in metres on ``/depth`` (rectified left frame ``rect_left``)
        or, with ``disparity=True``, disparity in pixels on ``/disparity``."""
        ch = self.disparity if disparity else self.depth
        if self.subscribed(ch):
            ch.log(fm.float_image(t_ns, depth_m, "rect_left"), log_time=int(t_ns))
            self._count(fm.TOPICS["disparity" if disparity else "depth"])

    def publish_pose(self, t_ns: int, T_world_left: np.ndarray) -> None:
        """The left camera's pose: ``/tf`` (``world`` -> ``left``) and ``/odometry/pose``."""
        t = int(t_ns)
        tf = fm.frame_transform(t, "world", "left", T_world_left)
        self.tf.log(fm.frame_transforms([tf]), log_time=t)
        self._count(fm.TOPICS["tf"])
        if self.subscribed(self.pose):
            self.pose.log(fm.pose_in_frame(t, "world", T_world_left), log_time=t)
            self._count(fm.TOPICS["pose"])

    def publish_trajectory(self, t_ns: int, T_world_left: np.ndarray) -> None:
        """The path so far, ``(N, 4, 4)`` poses, on ``/odometry/trajectory``."""
        if self.subscribed(self.trajectory):
            self.trajectory.log(fm.poses_in_frame(t_ns, "world", T_world_left), log_time=int(t_ns))
            self._count(fm.TOPICS["trajectory"])

    def publish_cloud(
        self,
        t_ns: int,
        points: np.ndarray,
        colors_rgb: np.ndarray | None = None,
        frame_id: str = "world",
    ) -> None:
        """A point cloud, ``(N, 3)`` metres in ``frame_id``, optional uint8 RGB."""
        if self.subscribed(self.cloud):
            self.cloud.log(fm.point_cloud(t_ns, frame_id, points, colors_rgb), log_time=int(t_ns))
            self._count(fm.TOPICS["cloud"])

    def publish_mesh(
        self,
        t_ns: int,
        vertices: np.ndarray,
        triangles: np.ndarray,
        vertex_colors_rgb: np.ndarray | None = None,
        frame_id: str = "world",
        *,
        entity_id: str = "mesh",
    ) -> None:
        """A mesh as a scene update (see :func:`sea3d.io.foxglove_msgs.mesh_scene`); a later
        mesh of the same ``entity_id`` replaces it in the client (live: one entity per
        submap)."""
        if self.subscribed(self.mesh):
            msg = fm.mesh_scene(t_ns, frame_id, vertices, triangles, vertex_colors_rgb,
                                entity_id=entity_id)
            self.mesh.log(msg, log_time=int(t_ns))
            self._count(fm.TOPICS["mesh"])

    def publish_live_status(self, t_ns: int, status: dict[str, Any]) -> None:
        """The live reconstruction's status (:data:`LIVE_STATUS_SCHEMA`) on ``/live/status``."""
        if self.subscribed(self.live_status):
            t = int(t_ns)
            msg = {"timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000},
                   **{k: status.get(k) for k in LIVE_STATUS_SCHEMA["properties"]
                      if k != "timestamp"}}
            self.live_status.log(msg, log_time=t)
            self._count(LIVE_STATUS_TOPIC)

    def stop(self) -> None:
        """Stop the server (clients are disconnected). Safe to call twice."""
        if self._stopped:
            return
        self._stopped = True
        if self._shim is not None:
            self._shim.close()
        self._server.stop()

    def __enter__(self) -> FoxglovePublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class FoxgloveBridge:
    """Feed a :class:`FoxglovePublisher` from a recorder or a session player.

    Args:
        publisher: the server.
        provider: anything with ``latest(stream) -> (seq, record) | None`` (the recorder, the
            monitor's :class:`~sea3d.capture.monitor.SessionPlayer`).
        imu, sonar: in replay, the session's :class:`~sea3d.io.session.ImuSeries` and
            :class:`~sea3d.io.session.SonarSeries`: their samples up to each frame are
            published with it. With the recorder, pass None and register :meth:`on_record`
            with ``recorder.add_listener``.
        restamp: shift stamps so that the first frame is "now" and every loop of a replay
            continues forward in time (replays look live; Foxglove's live view wants time to
            advance).
        poll_interval_s: how often the provider is asked for new frames.
        depth: the depth provider: a callable ``(left, right) -> (image, is_disparity)`` or
            an object with such a ``compute`` method (e.g.
            :class:`sea3d.pipeline.live_preview.DepthPreview`); it is called with the newest
            pair at most ``depth_rate_hz`` times a second while a client subscribes to
            ``/depth`` or ``/disparity``, and switched off for good when it raises. None (the
            default): no depth is published.

    Raises:
        ConfigError: a provider without ``latest``, or a depth provider that is neither
            callable nor has ``compute``.
    """

    def __init__(
        self,
        publisher: FoxglovePublisher,
        provider: Any,
        *,
        imu: Any = None,
        sonar: Any = None,
        restamp: bool = False,
        poll_interval_s: float = 0.005,
        depth: Any = None,
    ) -> None:
        if not callable(getattr(provider, "latest", None)):
            raise ConfigError(f"{provider!r} has no latest(stream) method to feed Foxglove from")
        compute = getattr(depth, "compute", depth)
        if depth is not None and not callable(compute):
            raise ConfigError(f"{depth!r} is neither callable nor has compute(left, right)")
        self.publisher = publisher
        self.provider = provider
        self.imu, self.sonar = imu, sonar
        self.restamp = restamp
        self.poll_interval_s = float(poll_interval_s)
        self._samples: collections.deque[tuple[str, Any]] = collections.deque(maxlen=4096)
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._threads: list[threading.Thread] = []
        self._seen: dict[str, int] = {}
        self._offset_ns: int | None = None
        self._last_src_t: int | None = None
        self._lap_ns = 0
        self._series_t = -1
        self.errors: list[str] = []
        self._depth: Callable[[Any, Any], tuple[np.ndarray, bool]] | None = compute
        self._depth_failed = False
        self._pair_lock = threading.Lock()
        self._pair: tuple[int, Any, Any] | None = None

    # -- recorder hook -------------------------------------------------------------------
    def on_record(self, stream: str, record: Any) -> None:
        """Listener for :meth:`Recorder.add_listener`: queues IMU and echosounder samples
        (images are polled). Never blocks; the oldest samples go when 4096 are waiting."""
        if stream in ("imu", "sonar"):
            self._samples.append((stream, record))
            self._wake.set()

    # -- control -------------------------------------------------------------------------
    def start(self) -> FoxgloveBridge:
        """Start the publishing (and depth) threads; returns self."""
        t = threading.Thread(target=self._run, name="sea3d-foxglove", daemon=True)
        self._threads = [t]
        if self._depth is not None and self.publisher.config.depth_rate_hz > 0:
            self._threads.append(
                threading.Thread(target=self._run_depth, name="sea3d-foxglove-depth", daemon=True)
            )
        for th in self._threads:
            th.start()
        return self

    def stop(self) -> None:
        """Stop the threads (the publisher's server keeps running; stop it separately)."""
        self._stop.set()
        self._wake.set()
        for th in self._threads:
            th.join(timeout=5)

    def __enter__(self) -> FoxgloveBridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- stamps ----------------------------------------------------------------------------
    def _stamp(self, t_ns: int) -> int:
        if not self.restamp:
            return int(t_ns)
        if self._offset_ns is None:
            self._offset_ns = time.time_ns() - int(t_ns)
        return int(t_ns) + self._offset_ns + self._lap_ns

    def _new_frame_time(self, t_ns: int) -> None:
        """Called with each new left frame's source stamp; detects replay loops."""
        if self.restamp and self._last_src_t is not None and t_ns <= self._last_src_t:
            # The replay started again: continue one frame interval after the last stamp.
            assert self._offset_ns is not None
            last_pub = self._last_src_t + self._offset_ns + self._lap_ns
            self._lap_ns = last_pub + 100_000_000 - (int(t_ns) + self._offset_ns)
            self._series_t = -1
        self._last_src_t = int(t_ns)

    # -- threads ---------------------------------------------------------------------------
    def _run(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        pub = self.publisher
        # left and right are JPEG-encoded side by side (OpenCV releases the GIL): on two
        # cores about twice the frames of one encoder thread
        pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="sea3d-foxglove-jpeg")
        try:
            self._loop(pub, pool)
        finally:
            pool.shutdown(wait=True)

    def _loop(self, pub: FoxglovePublisher, pool: Any) -> None:
        while not self._stop.is_set():
            self._wake.wait(self.poll_interval_s)
            self._wake.clear()
            try:
                self._publish_samples()
                jobs = []
                for stream in ("left", "right"):
                    latest = self.provider.latest(stream)
                    if latest is None or latest[0] == self._seen.get(stream):
                        continue
                    seq, rec = latest
                    self._seen[stream] = seq
                    if stream == "left":
                        self._new_frame_time(rec.t_ns)
                        self._publish_series_until(rec.t_ns)
                    t_pub = self._stamp(rec.t_ns)
                    jobs.append(pool.submit(pub.publish_image, stream, t_pub, rec.image))
                for job in jobs:
                    job.result()
                self._remember_pair()
            except Exception as err:  # never take the recorder down with the live view
                msg = f"Foxglove publishing: {type(err).__name__}: {err}"
                if msg not in self.errors:
                    self.errors.append(msg)
                    _log.warning("%s", msg)
                self._stop.wait(0.1)

    def _publish_samples(self) -> None:
        pub = self.publisher
        while self._samples:
            stream, rec = self._samples.popleft()
            if stream == "imu":
                pub.publish_imu(self._stamp(rec.t_ns), rec.accel_mps2, rec.gyro_radps)
            else:
                pub.publish_sonar(self._stamp(rec.t_ns), rec.range_m, rec.confidence)

    def _publish_series_until(self, t_ns: int) -> None:
        """Replay: the session's IMU and echosounder samples in (previous frame, t_ns]."""
        pub = self.publisher
        lo = self._series_t
        if self.imu is not None and len(self.imu):
            a, b = np.searchsorted(self.imu.t_ns, [lo, t_ns], side="right")
            for k in range(int(a), int(b)):
                pub.publish_imu(
                    self._stamp(int(self.imu.t_ns[k])),
                    self.imu.accel_mps2[k],
                    self.imu.gyro_radps[k],
                )
        if self.sonar is not None and len(self.sonar):
            a, b = np.searchsorted(self.sonar.t_ns, [lo, t_ns], side="right")
            for k in range(int(a), int(b)):
                pub.publish_sonar(
                    self._stamp(int(self.sonar.t_ns[k])),
                    float(self.sonar.range_m[k]),
                    float(self.sonar.confidence[k]),
                )
        self._series_t = int(t_ns)

    def _remember_pair(self) -> None:
        left, right = self.provider.latest("left"), self.provider.latest("right")
        if left is None or right is None:
            return
        with self._pair_lock:
            self._pair = (self._stamp(left[1].t_ns), left[1].image, right[1].image)

    def _run_depth(self) -> None:
        pub = self.publisher
        period = 1.0 / pub.config.depth_rate_hz
        last_t: int | None = None
        while not self._stop.wait(period):
            with self._pair_lock:
                pair = self._pair
            if pair is None or pair[0] == last_t:
                continue
            wanted = pub.subscribed(pub.depth) or pub.subscribed(pub.disparity)
            if not wanted or self._depth_failed or self._depth is None:
                continue
            last_t = pair[0]
            try:
                img, is_disp = self._depth(pair[1], pair[2])
                pub.publish_depth(pair[0], img, disparity=is_disp)
            except Exception as err:
                self._depth_failed = True
                msg = f"Foxglove depth preview off: {type(err).__name__}: {err}"
                self.errors.append(msg)
                _log.warning("%s", msg)
