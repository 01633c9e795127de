"""Record sources into a session: capture threads, encoder threads, one ordered writer.

::

    camera thread ──► [slot?] ──► encoder pool (PNG/JPEG, GIL released) ──┐
    camera thread ──► [slot?] ──► encoder pool ───────────────────────────┤► writer thread ► session
    IMU / sonar threads ──────────────────────────────────────────────────┘ (written directly)

At most ``queue_frames`` images are between capture and disk. When a camera delivers a frame
and no slot is free, the frame is dropped and counted (``block_when_full=True`` makes replay
sources wait instead). Free disk space is checked before starting, by the session writer
before every write (so the reserve ``min_free_bytes`` is never overshot) and every
``disk_check_interval_s`` for the figures; the recording stops cleanly at the reserve, and a
disk that fills anyway (``min_free_bytes=0``) or fails ends the recording with one reason that
says what was kept. The counts reported are what a reader finds in the file.
:meth:`Recorder.request_stop` (called by the CLI on Ctrl-C / SIGTERM) stops capture, drains
what is queued, and closes the session so that everything written stays readable.
"""

from __future__ import annotations

import collections
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from sea3d.capture.sources import ImageFrame, Source
from sea3d.errors import CaptureError, ConfigError, SessionError
from sea3d.io.disk_space import disk_free_bytes
from sea3d.io.session import (
    ImuSample,
    SessionWriteError,
    SessionWriter,
    SonarSample,
    layout_of,
)

__all__ = ["RecordSummary", "Recorder", "RecorderConfig"]

_log = logging.getLogger(__name__)

_STREAMS = ("left", "right", "imu", "sonar")
_SAMPLE_DRAIN_S = 2.0
"""Wall seconds the IMU and echosounder may take, once the cameras have ended, to deliver the
samples stamped within the last frame's time."""


@dataclass(frozen=True, kw_only=True)
class RecorderConfig:
    """How to record.

    Attributes:
        out_path: session to create (``*.mcap`` file or folder); must not exist.
        format: ``"mcap"`` or ``"folder"``; None chooses from ``out_path``'s extension.
        duration_s: stop after this many seconds (None: until stopped or the sources end).
        image_encoding: ``"jxl"`` (JPEG XL lossless, the default: keeps up with 2 x 30 fps at
            1080p on 2 cores), ``"png"``, ``"jpeg"`` or ``"raw"`` (MCAP only).
        png_compression: zlib level 0..9.
        jpeg_quality: 0..100.
        queue_frames: most images waiting between capture and disk (both cameras together;
            each camera gets half).
        encoder_threads: image encoder threads.
        block_when_full: sources wait for a free slot instead of dropping (replay only).
        min_free_bytes: stop when free disk space falls below this.
        disk_check_interval_s: how often free space is checked.
        rig_yaml: rig file text stored in the session.
        chunk_compression: MCAP only: ``"lz4"``, ``"zstd"`` or ``"none"``; None: LZ4 for raw
            images, none for encoded ones.
        stall_warn_s: a camera whose source has been blocked in a read this many seconds
            (it delivers nothing, nor fails) is named in one warning, with how long.
        stall_stop_s: a camera stalled this long stops the recording, its stop reason naming
            it; None: it is waited for as long as it takes.
    """

    out_path: Path
    format: str | None = None
    duration_s: float | None = None
    image_encoding: str = "jxl"
    png_compression: int = 1
    jpeg_quality: int = 95
    queue_frames: int = 16
    encoder_threads: int = 2
    block_when_full: bool = False
    min_free_bytes: int = 2 * 1024**3
    disk_check_interval_s: float = 1.0
    rig_yaml: str | None = None
    chunk_compression: str | None = None
    stall_warn_s: float = 2.0
    stall_stop_s: float | None = 10.0

    def __post_init__(self) -> None:
        # one field a message, so that a command can name its option for it
        if self.duration_s is not None and not self.duration_s > 0:
            raise ConfigError(f"duration_s must be > 0, got {self.duration_s}")
        for name, low in (("queue_frames", 1), ("encoder_threads", 1), ("min_free_bytes", 0)):
            if getattr(self, name) < low:
                raise ConfigError(f"{name} must be >= {low}, got {getattr(self, name)}")
        if not self.disk_check_interval_s > 0:
            raise ConfigError(f"disk_check_interval_s must be > 0, got "
                              f"{self.disk_check_interval_s}")
        if self.image_encoding not in ("jxl", "png", "jpeg", "raw"):
            raise ConfigError(
                f"image_encoding must be jxl, png, jpeg or raw, got {self.image_encoding!r}"
            )
        if self.image_encoding == "raw" and (self.format or layout_of(self.out_path)) != "mcap":
            raise ConfigError(f"image_encoding raw is written to MCAP only; {self.out_path} is "
                              "a folder session (png, jxl or jpeg)")
        for name, high in (("png_compression", 9), ("jpeg_quality", 100)):
            if not 0 <= getattr(self, name) <= high:
                raise ConfigError(f"{name} must be 0..{high}, got {getattr(self, name)}")
        if not self.stall_warn_s > 0:
            raise ConfigError(f"stall_warn_s must be > 0, got {self.stall_warn_s}")
        if self.stall_stop_s is not None and not self.stall_stop_s >= self.stall_warn_s:
            raise ConfigError(
                f"stall_stop_s must be >= stall_warn_s ({self.stall_warn_s:g}), got "
                f"{self.stall_stop_s}"
            )


@dataclass(frozen=True, kw_only=True)
class RecordSummary:
    """What a recording did.

    Attributes:
        path: the session written.
        format: ``"mcap"`` or ``"folder"``.
        duration_s: wall-clock seconds from start to stop.
        frames: records per stream on disk, readable (equal to what a reader finds).
        captured: records delivered by each source.
        dropped: records captured but not on disk (``captured - frames``: queue full, bad
            stamps, the open chunk when the disk failed).
        fps: images written per second of wall clock, per camera.
        bytes_written: payload bytes written.
        bytes_on_disk: size of the session on disk after closing.
        stop_reason: why recording stopped.
        errors: error messages from sources and the writer.
    """

    path: str
    format: str
    duration_s: float
    frames: dict[str, int]
    captured: dict[str, int]
    dropped: dict[str, int]
    fps: dict[str, float]
    bytes_written: int
    bytes_on_disk: int
    stop_reason: str
    errors: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (JSON-ready)."""
        return asdict(self)


def _size_text(shape: tuple[int, ...], dtype: Any, *, full: bool = False) -> str:
    """``320x180`` (``full``: ``320x180x3 uint8``) for an image's shape and dtype."""
    size = f"{shape[1]}x{shape[0]}"
    if not full:
        return size
    return f"{size}x{shape[2]} {dtype}" if len(shape) == 3 else f"{size} {dtype}"


class Recorder:
    """Record the given sources into one session.

    Args:
        config: :class:`RecorderConfig`.
        sources: stream name (``left``, ``right``, ``imu``, ``sonar``) to source.

    Raises:
        ConfigError: unknown stream names or a source of the wrong kind.
    """

    def __init__(self, config: RecorderConfig, sources: Mapping[str, Source]) -> None:
        for name, src in sources.items():
            want = "image" if name in ("left", "right") else name
            if name not in _STREAMS:
                raise ConfigError(f"unknown stream {name!r}; expected one of {_STREAMS}")
            if src.kind != want:
                raise ConfigError(f"stream {name} needs {want} records, got {src!r} ({src.kind})")
        self.config = config
        self.sources = dict(sources)
        self._stop = threading.Event()
        self._stop_reason = ""
        self._lock = threading.Lock()
        self.captured = dict.fromkeys(_STREAMS, 0)
        self.written = dict.fromkeys(_STREAMS, 0)
        self.dropped = dict.fromkeys(_STREAMS, 0)
        self.errors: list[str] = []
        self._latest: dict[str, Any] = {}
        self._seq = dict.fromkeys(_STREAMS, 0)
        self._recent: dict[str, collections.deque[float]] = {
            s: collections.deque(maxlen=120) for s in _STREAMS
        }
        self._ended: set[str] = set()
        self._writer: SessionWriter | None = None
        self._writer_thread: threading.Thread | None = None
        self._t_start = 0.0
        self._t_stop: float | None = None
        self._disk_free = 0
        self._listeners: list[Callable[[str, Any], None]] = []
        self._write_error: str | None = None
        # per camera: when its pending read began (None: not in a read), the size of its
        # first frame, and whether its stall was warned about / stopped the recording
        self._reading_since: dict[str, float | None] = {}
        self._first_image: dict[str, tuple[tuple[int, ...], Any]] = {}
        self._stall_warned: set[str] = set()
        self._stalled: set[str] = set()
        self.running = False

    def add_listener(self, fn: Callable[[str, Any], None]) -> None:
        """Also hand every captured record to ``fn(stream, record)`` (live views such as
        Foxglove). Called in the capture threads: it must return at once; what it raises is
        logged and never stops the recording."""
        self._listeners.append(fn)

    def _notify(self, stream: str, rec: Any) -> None:
        for fn in self._listeners:
            try:
                fn(stream, rec)
            except Exception as err:
                _log.warning("listener %r failed on a %s record: %s", fn, stream, err)

    # -- control --------------------------------------------------------------------------
    def request_stop(self, reason: str = "stopped by user") -> None:
        """Ask the recording to stop (thread- and signal-safe); the first reason is kept."""
        if not self._stop.is_set():
            self._stop_reason = reason
            self._stop.set()

    def _fail(self, msg: str, *, stop: bool = True) -> None:
        with self._lock:
            self.errors.append(msg)
        _log.error("%s", msg)
        if stop:
            self.request_stop(msg)

    def _write_failed(self, err: SessionWriteError) -> None:
        """The disk is full, at the reserve, or failing: stop once, with what was kept."""
        with self._lock:
            first = self._write_error is None
            if first:
                self._write_error = str(err)
        if first:
            self._fail(str(err))

    # -- live figures (also used by the monitor) -----------------------------------------------
    def latest(self, stream: str) -> tuple[int, Any] | None:
        """(sequence number, last record) of a stream, or None before the first one."""
        rec = self._latest.get(stream)
        return None if rec is None else (self._seq[stream], rec)

    def stats(self) -> dict[str, Any]:
        """Live figures: frames, drops, fps over the last seconds, disk, IMU and range."""
        now = time.monotonic()
        fps = {}
        for s in ("left", "right"):
            times = [t for t in self._recent[s] if now - t <= 2.0]
            fps[s] = (
                (len(times) - 1) / (times[-1] - times[0])
                if len(times) >= 2 and times[-1] > times[0]
                else 0.0
            )
        elapsed = ((self._t_stop or now) - self._t_start) if self._t_start else 0.0
        written = self._writer.bytes_written if self._writer is not None else 0
        frames = self._writer.counts if self._writer is not None else dict(self.written)
        rate = written / elapsed if elapsed > 0 else 0.0
        left_bytes = max(self._disk_free - self.config.min_free_bytes, 0)
        imu = self._latest.get("imu")
        sonar = self._latest.get("sonar")
        return {
            "running": self.running,
            "elapsed_s": elapsed,
            "frames": frames,
            "captured": dict(self.captured),
            "dropped": dict(self.dropped),
            "pending": {s: self.written[s] - frames.get(s, 0) for s in ("left", "right")},
            "fps": fps,
            "bytes_written": written,
            "disk_free_bytes": self._disk_free,
            "disk_left_s": left_bytes / rate if rate > 0 else None,
            "imu": None
            if imu is None
            else {
                "t_ns": imu.t_ns,
                "accel_mps2": [float(v) for v in imu.accel_mps2],
                "gyro_radps": [float(v) for v in imu.gyro_radps],
            },
            "sonar": None
            if sonar is None
            else {
                "t_ns": sonar.t_ns,
                "range_m": float(sonar.range_m),
                "confidence": float(sonar.confidence),
            },
            "stop_reason": self._stop_reason or None,
            "mode": "recording",
        }

    # -- threads ----------------------------------------------------------------------------
    def _capture_images(
        self,
        stream: str,
        src: Source,
        pool: ThreadPoolExecutor,
        q: queue.Queue[Any],
        slots: threading.Semaphore,
    ) -> None:
        writer = self._writer
        assert writer is not None
        while not self._stop.is_set():
            self._reading_since[stream] = time.monotonic()
            try:
                rec = src.read()
            except (CaptureError, SessionError, OSError) as err:
                self._fail(f"{stream} source {src.name}: {err}")
                return
            finally:
                self._reading_since[stream] = None
            if stream in self._stalled:  # came back after the recording stopped without it
                return
            if stream in self._stall_warned:
                self._stall_warned.discard(stream)
                _log.info("%s camera %s delivers again", stream, src.name)
            if rec is None:
                break
            if not isinstance(rec, ImageFrame):
                self._fail(
                    f"{stream} source {src.name} delivered {type(rec).__name__}, not an image"
                )
                return
            if not self._same_size(stream, src, rec):
                break
            self.captured[stream] += 1
            self._latest[stream] = rec
            self._seq[stream] += 1
            self._notify(stream, rec)
            if self.config.block_when_full:
                # Wait for the writer even after a stop request: it drains the queue.
                while not slots.acquire(timeout=0.1):
                    if self._writer_thread is not None and not self._writer_thread.is_alive():
                        self.dropped[stream] += 1
                        return
            elif not slots.acquire(blocking=False):
                self.dropped[stream] += 1
                continue
            fut = pool.submit(writer.encode, rec.image)
            q.put((stream, rec, fut))
        self._ended.add(stream)

    def _same_size(self, stream: str, src: Source, rec: ImageFrame) -> bool:
        """Whether the frame has its camera's first frame's size (and channels, depth); a
        camera that changes resolution ends the recording there, cleanly (the session keeps
        one size per camera), with one warning naming the frame and both sizes."""
        image = rec.image
        first = self._first_image.setdefault(stream, (image.shape, image.dtype))
        if (image.shape, image.dtype) == first:
            return True
        was, now = _size_text(*first), _size_text(image.shape, image.dtype)
        if was == now:  # the same width and height: name the layout that changed
            was, now = _size_text(*first, full=True), _size_text(image.shape, image.dtype,
                                                                 full=True)
        reason = (
            f"{stream} camera {src.name} changed resolution at frame "
            f"{self.captured[stream] + 1} (t_ns={rec.t_ns}): {now}, its earlier frames {was}; "
            "the recording stops there"
        )
        _log.warning("%s", reason)
        self.request_stop(reason)
        return False

    def _watch_cameras(self, now: float) -> None:
        """Warn once about a camera blocked in a read for ``stall_warn_s``; stop the
        recording when one is blocked for ``stall_stop_s``."""
        cfg = self.config
        for stream, since in list(self._reading_since.items()):
            if since is None:
                continue
            waited = now - since
            name = self.sources[stream].name
            if waited >= cfg.stall_warn_s and stream not in self._stall_warned:
                self._stall_warned.add(stream)
                _log.warning(
                    "%s camera %s has delivered nothing for %.1f s (stalled?)", stream, name,
                    waited,
                )
            if cfg.stall_stop_s is not None and waited >= cfg.stall_stop_s:
                self._stalled.add(stream)
                self.request_stop(
                    f"{stream} camera {name} stalled: nothing delivered for {waited:.1f} s "
                    f"(the limit is {cfg.stall_stop_s:g} s)"
                )

    def _samples_caught_up(self, image_streams: list[str]) -> bool:
        """True when every sample stream has ended or delivered a sample at or after the
        last camera frame's stamp."""
        last = [getattr(self._latest.get(s), "t_ns", None) for s in image_streams]
        t_last = max((t for t in last if t is not None), default=None)
        for stream in self.sources:
            if stream in image_streams or stream in self._ended:
                continue
            t = getattr(self._latest.get(stream), "t_ns", None)
            if t_last is not None and (t is None or t < t_last):
                return False
        return True

    def _capture_samples(self, stream: str, src: Source) -> None:
        writer = self._writer
        assert writer is not None
        while not self._stop.is_set():
            try:
                rec = src.read()
            except (CaptureError, SessionError, OSError) as err:
                self._fail(f"{stream} source {src.name}: {err}", stop=False)
                break
            if rec is None:
                break
            self.captured[stream] += 1
            try:
                if isinstance(rec, ImuSample) and stream == "imu":
                    writer.write_imu(rec.t_ns, rec.accel_mps2, rec.gyro_radps)
                elif isinstance(rec, SonarSample) and stream == "sonar":
                    writer.write_sonar(rec.t_ns, rec.range_m, rec.confidence)
                else:
                    raise SessionError(f"{stream} source delivered {type(rec).__name__}")
            except SessionWriteError as err:
                self.dropped[stream] += 1
                self._write_failed(err)
                break
            except SessionError as err:
                self.dropped[stream] += 1
                _log.warning("%s sample dropped: %s", stream, err)
                continue
            self._latest[stream] = rec
            self._seq[stream] += 1
            self.written[stream] += 1
            self._notify(stream, rec)
        self._ended.add(stream)

    def _write_images(self, q: queue.Queue[Any], slots: dict[str, threading.Semaphore]) -> None:
        writer = self._writer
        assert writer is not None
        while True:
            item = q.get()
            if item is None:
                return
            stream, rec, fut = item
            fut_typed: Future[bytes] = fut
            try:
                data = fut_typed.result()
                writer.write_image(stream, rec.t_ns, rec.image, encoded=data)
                self.written[stream] += 1
                self._recent[stream].append(time.monotonic())
            except SessionWriteError as err:
                self.dropped[stream] += 1
                self._write_failed(err)
            except SessionError as err:
                self.dropped[stream] += 1
                _log.warning("%s frame t_ns=%d dropped: %s", stream, rec.t_ns, err)
            finally:
                slots[stream].release()

    # -- main -------------------------------------------------------------------------------
    def run(self) -> RecordSummary:
        """Record until the duration passes, the sources end, the disk fills or
        :meth:`request_stop` is called; return the summary.

        Raises:
            CaptureError: not enough free disk space to start, or a source that cannot open.
            SessionError: the output exists already.
        """
        cfg = self.config
        out = Path(cfg.out_path)
        self._disk_free = disk_free_bytes(out.parent if out.suffix else out)
        if self._disk_free < cfg.min_free_bytes:
            raise CaptureError(
                f"only {self._disk_free / 1e9:.2f} GB free for {out}; recording needs more than "
                f"the {cfg.min_free_bytes / 1e9:.2f} GB reserve (lower min_free_bytes)"
            )
        opened: list[Source] = []
        try:
            for src in self.sources.values():
                src.open()
                opened.append(src)
            self._writer = SessionWriter(
                out,
                format=cfg.format,
                rig_yaml=cfg.rig_yaml,
                image_encoding=cfg.image_encoding,
                png_compression=cfg.png_compression,
                jpeg_quality=cfg.jpeg_quality,
                min_free_bytes=cfg.min_free_bytes,
                chunk_compression=cfg.chunk_compression,
                handle_signals=False,
            )
        except BaseException:
            for src in opened:
                src.close()
            raise
        return self._record(opened)

    def _record(self, opened: list[Source]) -> RecordSummary:
        cfg = self.config
        writer = self._writer
        assert writer is not None
        q: queue.Queue[Any] = queue.Queue()
        pool = ThreadPoolExecutor(
            max_workers=cfg.encoder_threads, thread_name_prefix="sea3d-encode"
        )
        threads: list[threading.Thread] = []
        image_streams: list[str] = [s for s in ("left", "right") if s in self.sources]
        # Each camera gets its share of the queue, so one cannot starve the other.
        per_camera = max(1, cfg.queue_frames // max(len(image_streams), 1))
        slots = {s: threading.Semaphore(per_camera) for s in image_streams}
        for stream, src in self.sources.items():
            if stream in ("left", "right"):
                target, args = self._capture_images, (stream, src, pool, q, slots[stream])
            else:
                target, args = self._capture_samples, (stream, src)  # type: ignore[assignment]
            threads.append(
                threading.Thread(target=target, args=args, name=f"sea3d-{stream}", daemon=True)
            )
        writer_thread = threading.Thread(
            target=self._write_images, args=(q, slots), name="sea3d-writer", daemon=True
        )
        self._writer_thread = writer_thread
        self._t_start = time.monotonic()
        self.running = True
        writer_thread.start()
        for t in threads:
            t.start()
        _log.info("recording to %s (%s)", cfg.out_path, writer.format)
        drain_until: float | None = None
        try:
            while not self._stop.is_set():
                self._stop.wait(min(cfg.disk_check_interval_s, 0.1))
                now = time.monotonic()
                if cfg.duration_s is not None and now - self._t_start >= cfg.duration_s:
                    self.request_stop(f"duration of {cfg.duration_s:g} s reached")
                elif image_streams and all(s in self._ended for s in image_streams):
                    # The IMU and echosounder threads may still hold samples stamped within
                    # the last frame's time (a loaded machine): give them a bounded moment
                    # to deliver those before stopping, so none of the camera span is lost.
                    if drain_until is None:
                        drain_until = now + _SAMPLE_DRAIN_S
                    if now >= drain_until or self._samples_caught_up(image_streams):
                        self.request_stop("the camera sources ended")
                elif not image_streams and all(s in self._ended for s in self.sources):
                    self.request_stop("the sources ended")
                self._watch_cameras(now)
                if now - getattr(self, "_last_disk_check", 0.0) >= cfg.disk_check_interval_s:
                    self._last_disk_check = now
                    self._disk_free = disk_free_bytes(Path(cfg.out_path).parent)
                    if self._disk_free < cfg.min_free_bytes:
                        self.request_stop(
                            f"disk nearly full: {self._disk_free / 1e9:.2f} GB free, under the "
                            f"{cfg.min_free_bytes / 1e9:.2f} GB reserve"
                        )
        except KeyboardInterrupt:
            self.request_stop("interrupted (Ctrl-C)")
        finally:
            self._t_stop = time.monotonic()
            for stream, t in zip(self.sources, threads, strict=True):
                # a camera stalled past the limit is blocked in its read: its stop reason
                # says so, and it is not waited for again
                t.join(timeout=0.2 if stream in self._stalled else 5.0)
                if t.is_alive() and stream not in self._stalled:
                    self._fail(f"{t.name} did not stop within 5 s (blocked in read?)", stop=False)
            q.put(None)
            writer_thread.join()
            pool.shutdown(wait=True)
            self.running = False
            try:
                writer.close()
            except SessionWriteError as err:  # what is on disk stays readable
                if self._write_error is None:
                    self._fail(str(err), stop=False)
            finally:
                for src in opened:
                    try:
                        src.close()
                    except Exception as err:
                        _log.warning("closing %s: %s", src.name, err)
        return self._summary()

    def _summary(self) -> RecordSummary:
        writer = self._writer
        assert writer is not None
        duration = (self._t_stop or time.monotonic()) - self._t_start
        path = Path(self.config.out_path)
        if path.is_dir():
            on_disk = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
        else:
            on_disk = path.stat().st_size if path.exists() else 0
        streams = [s for s in _STREAMS if s in self.sources]
        on_file = writer.counts
        return RecordSummary(
            path=os.fspath(path),
            format=writer.format,
            duration_s=duration,
            frames={s: on_file[s] for s in streams},
            captured={s: self.captured[s] for s in streams},
            dropped={s: max(self.captured[s] - on_file[s], 0) for s in streams},
            fps={
                s: on_file[s] / duration if duration > 0 else 0.0
                for s in streams
                if s in ("left", "right")
            },
            bytes_written=writer.bytes_written,
            bytes_on_disk=on_disk,
            stop_reason=self._stop_reason or "stopped",
            errors=list(self.errors),
        )
