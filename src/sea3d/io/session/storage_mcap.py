"""Sessions as one MCAP file of ROS 2 messages (``ros2`` profile, ``cdr`` encoding).

Topics and types (from ``sensor_msgs`` / ``std_msgs`` of ROS 2 Humble, serialised by rosbags):

===========================  ===========================================================
``/cam/left/image``          ``sensor_msgs/msg/CompressedImage`` (png, jxl or jpeg) or
                             ``sensor_msgs/msg/Image`` (raw)
``/cam/right/image``         same as left
``/cam/left/camera_info``    ``sensor_msgs/msg/CameraInfo``, one per image (from the rig)
``/cam/right/camera_info``   same as left
``/imu``                     ``sensor_msgs/msg/Imu`` (orientation unknown: covariance[0] = -1)
``/sonar``                   ``sensor_msgs/msg/Range`` (ULTRASOUND)
``/sonar/confidence``        ``std_msgs/msg/Float32``, same stamps as ``/sonar``
===========================  ===========================================================

The rig file is an attachment ``rig.yaml`` (``application/yaml``) written before any message
and again when the file is closed, and a metadata record ``sea3d`` holds the format version
and image encoding. Message log and publish times are the sensor stamps in nanoseconds; header
stamps carry the same value.

Writing. Records are serialised with the official ``mcap`` package's record classes; the
chunking is ours because a recording must stay honest when the disk fills or the process is
killed: every chunk carries the schema and channel records of the messages in it (so any
intact chunk can be read on its own), goes to the operating system in one piece when it closes
(every ``chunk_size`` bytes or ``chunk_interval_s`` seconds), and counts as written only once
it is there. A failed write (disk full, I/O error) truncates the file back to its last complete
chunk and raises :class:`~sea3d.errors.SessionWriteError`; the summary written at
close then lists exactly what is on disk. Before each write the free space is compared with a
reserve (``min_free_bytes``), so a recording stops before the reserve, never after it.

Reading checks every CRC the file offers (chunk, attachment, summary; the data section's in
:meth:`McapSessionReader.check`). Channels and schemas come from the summary (when its CRC
holds) or from any intact chunk. A damaged chunk is reported with its byte offset, time range
and streams and skipped: its bytes are never decoded into values. The reader walks the file's
records itself, so a truncated file (killed recorder) opens with everything in its complete
chunks, and a damaged record length is bridged through the summary's chunk index.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path

import numpy as np

from sea3d.errors import ReserveReached, SessionError
from sea3d.io.disk_space import disk_free_bytes
from sea3d.io.session.common import (
    SessionWriteError,
)
from sea3d.io.session.mcap_chunks import (
    ChunkedMcap,
    FdWriter,
)
from sea3d.io.session.mcap_reader import DamagedChunk, McapSessionReader
from sea3d.io.session.ros_messages import (
    METADATA_NAME,
    RIG_ATTACHMENT,
    TOPICS,
    camera_info_cdr,
    camera_info_params,
    compressed_image_cdr,
    float32_cdr,
    imu_cdr,
    range_cdr,
    raw_image_cdr,
    typestore,
)

__all__ = ["TOPICS", "DamagedChunk", "McapSessionReader", "McapSessionWriter"]

_log = logging.getLogger(__name__)


def create_writer(
    path: Path,
    rig_yaml: str | None,
    image_encoding: str,
    *,
    chunk_size: int = 4 << 20,
    chunk_interval_s: float = 1.0,
    chunk_compression: str | None = None,
    min_free_bytes: int = 0,
) -> McapSessionWriter:
    """The MCAP storage's writer.

    Raises:
        SessionError: bad options, an invalid rig, an existing file; SessionWriteError: the
            file or its folder cannot be created.
    """
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SessionWriteError(
            f"cannot create {path.parent}: {err.strerror or err}", kept=""
        ) from err
    return McapSessionWriter(
        path,
        rig_yaml,
        image_encoding,
        chunk_size=chunk_size,
        chunk_interval_s=chunk_interval_s,
        chunk_compression=chunk_compression,
        min_free_bytes=min_free_bytes,
    )


class McapSessionWriter:
    """Backend of :class:`~sea3d.io.session.SessionWriter` for MCAP files (not public).

    ``counts`` (records per stream) and ``bytes_written`` only ever include what reached the
    file; messages of the open chunk are ``pending``.
    """

    def __init__(
        self,
        path: Path,
        rig_yaml: str | None,
        image_encoding: str,
        *,
        chunk_size: int = 4 << 20,
        chunk_interval_s: float = 1.0,
        chunk_compression: str | None = None,
        min_free_bytes: int = 0,
    ) -> None:
        from sea3d import __version__

        self.path = path
        self.image_encoding = image_encoding
        self.chunk_size = int(chunk_size)
        self.chunk_interval_s = float(chunk_interval_s)
        self.min_free_bytes = int(min_free_bytes)
        if chunk_compression is None:
            chunk_compression = "lz4" if image_encoding == "raw" else "none"
        if chunk_compression not in ("none", "zstd", "lz4"):
            raise SessionError(
                f"chunk_compression must be none, zstd or lz4, got {chunk_compression!r}"
            )
        self.cam_params = camera_info_params(rig_yaml, path)
        self.ts = typestore()
        self.rig_bytes = None if rig_yaml is None else rig_yaml.encode("utf-8")
        self._free_checked_at = -1.0
        self._free = 0
        self._spent_since_check = 0
        self.broken: str | None = None
        self._closing = False
        self.channels: dict[str, int] = {}
        self.bytes_written = 0
        self.out = FdWriter(path)
        self.mcap = ChunkedMcap(
            self.out, compression=chunk_compression, zstd_level=1, reserve=self._reserve
        )
        try:
            self.mcap.start("ros2", f"sea3d {__version__}")
            now = time.time_ns()
            if self.rig_bytes is not None:
                self.mcap.add_attachment(RIG_ATTACHMENT, "application/yaml", self.rig_bytes, now)
            self.mcap.add_metadata(
                METADATA_NAME,
                {"format": "sea3d-session", "version": "1", "image_encoding": image_encoding},
            )
        except (OSError, ReserveReached) as err:
            self.out.close(sync=False)
            with contextlib.suppress(OSError):  # it holds nothing; do not block a new attempt
                path.unlink()
            if isinstance(err, OSError):
                why = err.strerror or str(err)
            elif self.min_free_bytes > 0:
                why = (
                    f"{err.free / 1e9:.2f} GB free, under the "
                    f"{self.min_free_bytes / 1e9:.2f} GB reserve"
                )
            else:
                why = f"the disk is full ({err.free} bytes free)"
            raise SessionWriteError(f"cannot write {path}: {why}", kept="nothing") from err
        image_type = (
            "sensor_msgs/msg/Image"
            if image_encoding == "raw"
            else "sensor_msgs/msg/CompressedImage"
        )
        types = {
            "left": image_type,
            "right": image_type,
            "left_info": "sensor_msgs/msg/CameraInfo",
            "right_info": "sensor_msgs/msg/CameraInfo",
            "imu": "sensor_msgs/msg/Imu",
            "sonar": "sensor_msgs/msg/Range",
            "sonar_confidence": "std_msgs/msg/Float32",
        }
        schema_ids: dict[str, int] = {}
        self._stream_of_channel: dict[int, str] = {}
        for stream, typename in types.items():
            if typename not in schema_ids:
                msgdef, _md5 = self.ts.generate_msgdef(typename, ros_version=2)
                schema_ids[typename] = self.mcap.add_schema(typename, "ros2msg", msgdef.encode())
            cid = self.mcap.add_channel(TOPICS[stream], "cdr", schema_ids[typename])
            self.channels[stream] = cid
            self._stream_of_channel[cid] = stream
        self.pending_since: float | None = None

    # -- disk ------------------------------------------------------------------------------
    def _free_estimate(self, size: int) -> int:
        """Free bytes on the disk, re-read at most every 0.2 s unless the margin is small."""
        now = time.monotonic()
        if now - self._free_checked_at > 0.2 or self._free - self._spent_since_check < (
            self.min_free_bytes + 4 * max(size, self.chunk_size)
        ):
            self._free = disk_free_bytes(self.path.parent)
            self._free_checked_at = now
            self._spent_since_check = 0
        return self._free - self._spent_since_check

    def _floor(self) -> int:
        """Free bytes a write must leave: the reserve, plus (until closing) room for what
        :meth:`close` writes after the last chunk (the second rig copy and the summary)."""
        if self._closing:
            return self.min_free_bytes
        room = 64 * 1024 + len(self.rig_bytes or b"") + 256 * len(self.mcap.chunk_indexes)
        return self.min_free_bytes + room

    def _reserve(self, size: int) -> None:
        """Refuse a write that would take free space under the reserve (called per write;
        with no reserve, a write the disk has no room for)."""
        free = self._free_estimate(size)
        if free - size < self._floor():
            raise ReserveReached(free)
        self._spent_since_check += size

    def _admit(self, size: int) -> None:
        """Before a message of ``size`` bytes joins the open chunk: if the chunk would then no
        longer fit above the reserve, write what is pending (it still fits) and stop. Also
        with no reserve: a chunk is never made larger than the room left on the disk."""
        need = self.mcap.pending_bytes + size + 4096  # chunk header and message indexes
        free = self._free_estimate(need)
        if free - need < self._floor():
            self.flush()
            raise self._fail(ReserveReached(disk_free_bytes(self.path.parent)), 0)

    @property
    def counts(self) -> dict[str, int]:
        """Messages per stream that reached the file."""
        committed = self.mcap.committed if hasattr(self, "mcap") else {}
        return {stream: committed.get(cid, 0) for stream, cid in self.channels.items()}

    def _kept(self) -> str:
        parts = [f"{n} {s}" for s, n in self.counts.items() if n and not s.endswith("_info")]
        if not parts:
            return "no records"
        return ", ".join(parts) + f" up to t_ns={self.mcap.message_end}"

    def _fail(self, err: BaseException, lost: int) -> SessionWriteError:
        if isinstance(err, ReserveReached) and self.min_free_bytes > 0:
            self.broken = (
                f"{self.path}: free space would fall under the {self.min_free_bytes / 1e9:.2f} "
                f"GB reserve ({err.free / 1e9:.2f} GB free)"
            )
        elif isinstance(err, ReserveReached):
            self.broken = f"{self.path}: the disk is full ({err.free} bytes free)"
        else:
            why = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
            self.broken = f"{self.path}: writing failed: {why}"
        if lost:
            self.broken += f"; the last {lost} messages did not fit and were not written"
        return SessionWriteError(self.broken, kept=self._kept())

    def _check_open(self) -> None:
        if self.broken is not None:
            raise SessionWriteError(self.broken, kept=self._kept())

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS.

        Raises:
            SessionWriteError: the chunk could not be written (disk full, reserve reached, I/O
                error); the file keeps every earlier chunk and as much of this one as fitted.
        """
        self._check_open()
        size = self.mcap.pending_bytes
        pending = len(self.mcap.pending)
        before = sum(self.mcap.committed.values())
        try:
            self.mcap.flush_chunk()
        except (OSError, ReserveReached) as err:
            lost = pending - (sum(self.mcap.committed.values()) - before)
            raise self._fail(err, lost) from err
        self.bytes_written += size
        self.pending_since = None

    def _add(self, stream: str, t_ns: int, data: memoryview | bytes) -> None:
        self._admit(len(data))
        self.mcap.add_message(self.channels[stream], t_ns, data)
        now = time.monotonic()
        if self.pending_since is None:
            self.pending_since = now
        if (
            self.mcap.pending_bytes >= self.chunk_size
            or now - self.pending_since >= self.chunk_interval_s
        ):
            self.flush()

    def committed(self, stream: str) -> int:
        return self.counts.get(stream, 0)

    # -- messages (built in ros_messages) ----------------------------------------------------
    def _camera_info(self, stream: str, t_ns: int, height: int, width: int) -> None:
        k, dist = self.cam_params.get(stream, (np.zeros((3, 3)), np.zeros(0)))
        self._add(f"{stream}_info", t_ns, camera_info_cdr(self.ts, stream, t_ns, height, width,
                                                          k, dist))  # fmt: skip

    def write_encoded(
        self, stream: str, t_ns: int, data: bytes, fmt: str, height: int, width: int
    ) -> None:
        self._check_open()
        cdr = compressed_image_cdr(self.ts, stream, t_ns, data, fmt)
        self._admit(len(cdr) + 1024)
        self.mcap.add_message(self.channels[stream], t_ns, cdr)
        self._camera_info(stream, t_ns, height, width)

    def write_raw(self, stream: str, t_ns: int, image: np.ndarray) -> None:
        self._check_open()
        cdr = raw_image_cdr(self.ts, stream, t_ns, image)
        self._admit(len(cdr) + 1024)
        self.mcap.add_message(self.channels[stream], t_ns, cdr)
        self._camera_info(stream, t_ns, image.shape[0], image.shape[1])

    def write_imu(self, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> None:
        self._check_open()
        self._add("imu", t_ns, imu_cdr(self.ts, t_ns, accel, gyro))

    def write_sonar(self, t_ns: int, range_m: np.float32, confidence: np.float32) -> None:
        self._check_open()
        self._admit(256)
        self.mcap.add_message(self.channels["sonar"], t_ns, range_cdr(self.ts, t_ns, range_m))
        self._add("sonar_confidence", t_ns, float32_cdr(self.ts, confidence))

    def close(self, counts: dict[str, int]) -> None:
        """Write the last chunk, the second rig copy and the summary; on a failure the file
        keeps its complete chunks (readable without a summary).

        Raises:
            SessionWriteError: when the last chunk or the summary could not be written.
        """
        del counts
        error: SessionWriteError | None = None
        try:
            if self.broken is None:
                try:
                    self.flush()
                except SessionWriteError as err:
                    error = err
            self.mcap.discard_chunk()
            self._closing = True
            good_end = self.out.pos
            try:
                if self.rig_bytes is not None:
                    self.mcap.add_attachment(
                        RIG_ATTACHMENT, "application/yaml", self.rig_bytes, time.time_ns()
                    )
                self.mcap.finish()
            except (OSError, ReserveReached) as err:
                self.out.rollback(good_end)
                why = err.strerror if isinstance(err, OSError) and err.strerror else "reserve"
                _log.warning(
                    "%s: the summary could not be written (%s); the file ends after its last "
                    "complete chunk and stays readable",
                    self.path,
                    why,
                )
                if error is None and self.broken is None:
                    error = SessionWriteError(
                        f"{self.path}: the summary could not be written ({why})", kept=self._kept()
                    )
        finally:
            try:
                self.out.close(sync=True)
            except OSError as err:
                if error is None:
                    error = SessionWriteError(
                        f"{self.path}: closing failed: {err.strerror or err}", kept=self._kept()
                    )
        if error is not None:
            raise error


