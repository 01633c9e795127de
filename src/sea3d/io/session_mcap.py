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
chunk and raises :class:`~sea3d.io.session_common.SessionWriteError`; the summary written at
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
import io
import logging
import os
import struct
import threading
import time
import zlib
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import CRCValidationError, get_chunk_data_stream

from sea3d.errors import SessionError
from sea3d.io.session_common import (
    ImuSeries,
    SessionReader,
    SessionWriteError,
    SonarSeries,
    decode_image,
    sort_stamps,
)

__all__ = ["TOPICS", "DamagedChunk", "McapSessionReader", "McapSessionWriter"]

_log = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_CHUNK_INDEX, _OP_ATTACHMENT = 0x06, 0x07, 0x08, 0x09
_OP_ATTACHMENT_INDEX, _OP_STATISTICS, _OP_METADATA, _OP_METADATA_INDEX = 0x0A, 0x0B, 0x0C, 0x0D
_OP_SUMMARY_OFFSET, _OP_DATA_END = 0x0E, 0x0F
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log, publish
_CHUNK_HEAD = struct.Struct("<BQQQQI")  # opcode, length, start, end, uncompressed size, crc
# What parsing a damaged record can raise (mcap's readers raise EndOfFile, a McapError).
_PARSE_ERRORS = (struct.error, ValueError, UnicodeDecodeError, EOFError, OverflowError, McapError)
# A chunk's records are decompressed into memory: refuse absurd sizes (a damaged header)
# instead of allocating them. Our chunks are a few MiB.
MAX_CHUNK_BYTES = 1 << 30
MAX_SUMMARY_BYTES = 256 << 20  # a day of recording has a summary of about 13 MB

TOPICS = {
    "left": "/cam/left/image",
    "right": "/cam/right/image",
    "left_info": "/cam/left/camera_info",
    "right_info": "/cam/right/camera_info",
    "imu": "/imu",
    "sonar": "/sonar",
    "sonar_confidence": "/sonar/confidence",
}
_STREAM_OF_TOPIC = {v: k for k, v in TOPICS.items()}
# Also accept image_transport's conventional names when reading other tools' files.
_STREAM_OF_TOPIC.update(
    {"/cam/left/image/compressed": "left", "/cam/right/image/compressed": "right"}
)

RIG_ATTACHMENT = "rig.yaml"
METADATA_NAME = "sea3d"
SONAR_FOV_RAD = 0.5236  # 30 degree beam of a Ping-style echosounder
SONAR_MIN_RANGE_M = 0.3
SONAR_MAX_RANGE_M = 100.0


@lru_cache(maxsize=1)
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _record_bytes(record: Any) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())


def _disk_free_bytes(path: Path) -> int:
    st = os.statvfs(path)
    return int(st.f_bavail) * int(st.f_frsize)


# ----------------------------------------------------------------------------- writer


class _FdWriter:
    """Unbuffered file sink: each :meth:`write_all` reaches the OS in one piece or not at all
    (on failure the file is truncated back to where the write started)."""

    def __init__(self, path: Path) -> None:
        try:
            self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError as err:
            raise SessionError(f"{path} already exists; refusing to overwrite it") from err
        except OSError as err:
            raise SessionWriteError(
                f"cannot create {path}: {err.strerror or err}", kept=""
            ) from err
        self.path = path
        self.pos = 0

    def write_all(self, parts: Sequence[bytes | bytearray | memoryview]) -> None:
        start = self.pos
        views = [memoryview(p).cast("B") for p in parts if len(p)]
        try:
            while views:
                n = os.writev(self.fd, views)
                self.pos += n
                while views and n >= len(views[0]):
                    n -= len(views[0])
                    views.pop(0)
                if n:
                    views[0] = views[0][n:]
        except OSError:
            self.rollback(start)
            raise

    def rollback(self, pos: int) -> None:
        """Cut the file back to ``pos`` bytes (best effort: the disk may be gone)."""
        try:
            os.ftruncate(self.fd, pos)
            os.lseek(self.fd, pos, os.SEEK_SET)
        except OSError as err:
            _log.error("%s: cannot cut the file back to byte %d: %s", self.path, pos, err)
        self.pos = pos

    def close(self, *, sync: bool) -> None:
        try:
            if sync:
                os.fsync(self.fd)
        finally:
            os.close(self.fd)


class _ChunkedMcap:
    """The MCAP file layout: header, top-level attachments and metadata, chunks with their
    message indexes, then data end, summary and footer (not public).

    Every byte goes through :meth:`_commit`, which keeps the statistics and indexes of the
    summary in step with what actually reached the file.
    """

    def __init__(
        self,
        out: _FdWriter,
        *,
        compression: str,
        zstd_level: int,
        reserve: Callable[[int], None],
    ) -> None:
        self.out = out
        self.compression = compression
        self.reserve = reserve
        self._zstd: Any = None
        if compression == "zstd":
            import zstandard

            self._zstd = zstandard.ZstdCompressor(level=zstd_level)
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self._schema_bytes: dict[int, bytes] = {}
        self._channel_bytes: dict[int, bytes] = {}
        self._sequence: dict[int, int] = {}
        self.chunk_indexes: list[ChunkIndex] = []
        self.attachment_indexes: list[AttachmentIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.message_counts: dict[int, int] = {}
        self.committed: dict[int, int] = {}  # messages per channel that reached the file
        self.message_start = 0
        self.message_end = 0
        self.data_crc = 0
        self._reset_chunk()

    # -- low level -------------------------------------------------------------------------
    def _commit(self, parts: Sequence[bytes | bytearray | memoryview]) -> int:
        """Write ``parts`` at the end of the file; return the offset they start at."""
        size = sum(len(p) for p in parts)
        self.reserve(size)
        at = self.out.pos
        self.out.write_all(parts)
        for p in parts:
            self.data_crc = zlib.crc32(p, self.data_crc)
        return at

    def _reset_chunk(self) -> None:
        self.pending: list[tuple[int, int, bytes | memoryview]] = []
        self._pending_bytes = 0

    # -- definitions and top-level records ---------------------------------------------------
    def start(self, profile: str, library: str) -> None:
        self._commit([MCAP_MAGIC, _record_bytes(Header(profile=profile, library=library))])

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self.schemas) + 1
        schema = Schema(id=sid, name=name, encoding=encoding, data=data)
        self.schemas[sid] = schema
        self._schema_bytes[sid] = _record_bytes(schema)
        return sid

    def add_channel(self, topic: str, encoding: str, schema_id: int) -> int:
        cid = len(self.channels) + 1
        channel = Channel(
            id=cid, topic=topic, message_encoding=encoding, schema_id=schema_id, metadata={}
        )
        self.channels[cid] = channel
        self._channel_bytes[cid] = _record_bytes(channel)
        self._sequence[cid] = 0
        return cid

    def add_attachment(self, name: str, media_type: str, data: bytes, t_ns: int) -> None:
        self.flush_chunk()
        record = _record_bytes(
            Attachment(create_time=t_ns, log_time=t_ns, name=name, media_type=media_type, data=data)
        )
        at = self._commit([record])
        self.attachment_indexes.append(
            AttachmentIndex(
                offset=at,
                length=len(record),
                log_time=t_ns,
                create_time=t_ns,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        self.flush_chunk()
        record = _record_bytes(Metadata(name=name, metadata=values))
        at = self._commit([record])
        self.metadata_indexes.append(MetadataIndex(offset=at, length=len(record), name=name))

    # -- messages and chunks -----------------------------------------------------------------
    def add_message(self, cid: int, log_time: int, data: bytes | memoryview) -> None:
        """Append a message to the open chunk (nothing is written until it closes)."""
        self.pending.append((cid, log_time, data))
        self._pending_bytes += 31 + len(data)

    @property
    def pending_bytes(self) -> int:
        return self._pending_bytes

    def _chunk_parts(
        self, messages: Sequence[tuple[int, int, bytes | memoryview]]
    ) -> tuple[list[bytes | bytearray], ChunkIndex, dict[int, int]]:
        """The chunk record (with the definitions its messages need) and message indexes, as
        parts for one write; the chunk index with offsets relative to the chunk start."""
        buf = bytearray()
        schemas: set[int] = set()
        channels: set[int] = set()
        index: dict[int, list[tuple[int, int]]] = {}
        counts: dict[int, int] = {}
        start, end = messages[0][1], messages[0][1]
        for cid, log_time, data in messages:
            if cid not in channels:
                sid = self.channels[cid].schema_id
                if sid and sid not in schemas:
                    buf += self._schema_bytes[sid]
                    schemas.add(sid)
                buf += self._channel_bytes[cid]
                channels.add(cid)
            seq = self._sequence[cid]
            self._sequence[cid] = seq + 1
            index.setdefault(cid, []).append((log_time, len(buf)))
            buf += _MESSAGE_HEAD.pack(
                _OP_MESSAGE, 22 + len(data), cid, seq & 0xFFFFFFFF, log_time, log_time
            )
            buf += data
            counts[cid] = counts.get(cid, 0) + 1
            start, end = min(start, log_time), max(end, log_time)
        crc = zlib.crc32(buf)
        if self.compression == "zstd":
            payload: bytes | bytearray = self._zstd.compress(buf)
        elif self.compression == "lz4":
            import lz4.frame

            payload = lz4.frame.compress(buf)
        else:
            payload = buf
        comp = self.compression.encode() if self.compression != "none" else b""
        body_len = 8 + 8 + 8 + 4 + 4 + len(comp) + 8 + len(payload)
        head = _CHUNK_HEAD.pack(_OP_CHUNK, body_len, start, end, len(buf), crc)
        head += struct.pack("<I", len(comp)) + comp + struct.pack("<Q", len(payload))
        chunk_length = len(head) + len(payload)
        parts: list[bytes | bytearray] = [head, payload]
        offsets: dict[int, int] = {}
        rel = chunk_length
        for cid, entries in index.items():
            rec = _record_bytes(MessageIndex(channel_id=cid, records=entries))
            offsets[cid] = rel
            rel += len(rec)
            parts.append(rec)
        ci = ChunkIndex(
            message_start_time=start,
            message_end_time=end,
            chunk_start_offset=0,
            chunk_length=chunk_length,
            message_index_offsets=offsets,
            message_index_length=rel - chunk_length,
            compression=comp.decode(),
            compressed_size=len(payload),
            uncompressed_size=len(buf),
        )
        return parts, ci, counts

    def _write_chunk(self, messages: Sequence[tuple[int, int, bytes | memoryview]]) -> None:
        parts, ci, counts = self._chunk_parts(messages)
        at = self._commit(parts)
        ci.chunk_start_offset = at
        ci.message_index_offsets = {c: at + o for c, o in ci.message_index_offsets.items()}
        for cid, n in counts.items():
            self.message_counts[cid] = self.message_counts.get(cid, 0) + n
            self.committed[cid] = self.committed.get(cid, 0) + n
        if not self.chunk_indexes:
            self.message_start = ci.message_start_time
        self.message_start = min(self.message_start, ci.message_start_time)
        self.message_end = max(self.message_end, ci.message_end_time)
        self.chunk_indexes.append(ci)

    def flush_chunk(self) -> None:
        """Write the open chunk and its message indexes in one piece.

        If that fails (disk full, reserve reached), as many of its messages as fit are
        written in smaller chunks, in order, before the error is raised; the rest are dropped.
        :attr:`committed` counts, per channel, the messages that reached the file.

        Raises:
            OSError, _ReserveReached: the write failed; the file ends after its last complete
                chunk.
        """
        messages = self.pending
        self._reset_chunk()
        if not messages:
            return
        try:
            self._write_chunk(messages)
        except (OSError, _ReserveReached) as err:
            self._salvage(messages)
            raise err

    def _salvage(self, messages: Sequence[tuple[int, int, bytes | memoryview]]) -> int:
        """Write a prefix of ``messages`` in halves for as long as writes succeed; return how
        many were written."""
        if len(messages) <= 1:
            return 0
        half = len(messages) // 2
        try:
            self._write_chunk(messages[:half])
        except (OSError, _ReserveReached):
            return self._salvage(messages[:half])
        try:
            self._write_chunk(messages[half:])
        except (OSError, _ReserveReached):
            return half + self._salvage(messages[half:])
        return len(messages)

    def discard_chunk(self) -> None:
        self._reset_chunk()

    # -- end ---------------------------------------------------------------------------------
    def finish(self) -> None:
        """Data end, summary (schemas, channels, statistics, indexes) and footer."""
        data_end = _record_bytes(DataEnd(data_section_crc=0))
        # The data section CRC covers everything before the DataEnd record.
        data_end = data_end[:9] + struct.pack("<I", self.data_crc)
        self._commit([data_end])
        summary_start = self.out.pos
        groups: list[tuple[int, list[bytes]]] = [
            (_OP_SCHEMA, list(self._schema_bytes.values())),
            (_OP_CHANNEL, list(self._channel_bytes.values())),
            (
                _OP_STATISTICS,
                [
                    _record_bytes(
                        Statistics(
                            message_count=sum(self.message_counts.values()),
                            schema_count=len(self.schemas),
                            channel_count=len(self.channels),
                            attachment_count=len(self.attachment_indexes),
                            metadata_count=len(self.metadata_indexes),
                            chunk_count=len(self.chunk_indexes),
                            message_start_time=self.message_start,
                            message_end_time=self.message_end,
                            channel_message_counts=dict(self.message_counts),
                        )
                    )
                ],
            ),
            (_OP_CHUNK_INDEX, [_record_bytes(c) for c in self.chunk_indexes]),
            (_OP_ATTACHMENT_INDEX, [_record_bytes(a) for a in self.attachment_indexes]),
            (_OP_METADATA_INDEX, [_record_bytes(m) for m in self.metadata_indexes]),
        ]
        parts: list[bytes] = []
        offsets: list[bytes] = []
        pos = summary_start
        for opcode, records in groups:
            if not records:
                continue
            length = sum(len(r) for r in records)
            offsets.append(
                _record_bytes(
                    SummaryOffset(group_opcode=opcode, group_start=pos, group_length=length)
                )
            )
            parts.extend(records)
            pos += length
        offset_start = pos
        parts.extend(offsets)
        footer_head = struct.pack("<BQQQ", _OP_FOOTER, 20, summary_start, offset_start)
        crc = 0
        for p in parts:
            crc = zlib.crc32(p, crc)
        crc = zlib.crc32(footer_head, crc)
        self._commit([*parts, footer_head, struct.pack("<I", crc), MCAP_MAGIC])


def _camera_info_params(
    rig_yaml: str | None, path: Path
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """K (3,3) and distortion per side from the rig text; {} without a rig.

    Raises:
        SessionError: the rig text is not a valid rig (it would give K = 0 in every
            camera_info while claiming a calibrated session).
    """
    if rig_yaml is None:
        return {}
    from sea3d.errors import RigFileError
    from sea3d.io.rig_file import rig_from_yaml

    try:
        rig = rig_from_yaml(rig_yaml, f"rig stored in {path}")
    except RigFileError as err:
        raise SessionError(f"cannot store an invalid rig: {err}") from err
    out = {}
    for side in ("left", "right"):
        pin = (rig.left if side == "left" else rig.right).lens
        out[side] = (np.asarray(pin.K, dtype=np.float64), np.asarray(pin.dist, dtype=np.float64))
    return out


def _stamp_msg(ts: Any, t_ns: int, frame_id: str) -> Any:
    time_t = ts.types["builtin_interfaces/msg/Time"]
    header_t = ts.types["std_msgs/msg/Header"]
    return header_t(
        stamp=time_t(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame_id
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
        self.cam_params = _camera_info_params(rig_yaml, path)
        self.ts = _typestore()
        self.rig_bytes = None if rig_yaml is None else rig_yaml.encode("utf-8")
        self._free_checked_at = -1.0
        self._free = 0
        self._spent_since_check = 0
        self.broken: str | None = None
        self._closing = False
        self.channels: dict[str, int] = {}
        self.bytes_written = 0
        self.out = _FdWriter(path)
        self.mcap = _ChunkedMcap(
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
        except (OSError, _ReserveReached) as err:
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
            self._free = _disk_free_bytes(self.path.parent)
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
            raise _ReserveReached(free)
        self._spent_since_check += size

    def _admit(self, size: int) -> None:
        """Before a message of ``size`` bytes joins the open chunk: if the chunk would then no
        longer fit above the reserve, write what is pending (it still fits) and stop. Also
        with no reserve: a chunk is never made larger than the room left on the disk."""
        need = self.mcap.pending_bytes + size + 4096  # chunk header and message indexes
        free = self._free_estimate(need)
        if free - need < self._floor():
            self.flush()
            raise self._fail(_ReserveReached(_disk_free_bytes(self.path.parent)), 0)

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
        if isinstance(err, _ReserveReached) and self.min_free_bytes > 0:
            self.broken = (
                f"{self.path}: free space would fall under the {self.min_free_bytes / 1e9:.2f} "
                f"GB reserve ({err.free / 1e9:.2f} GB free)"
            )
        elif isinstance(err, _ReserveReached):
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
        except (OSError, _ReserveReached) as err:
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

    # -- messages --------------------------------------------------------------------------------
    def _camera_info(self, stream: str, t_ns: int, height: int, width: int) -> None:
        ts = self.ts
        k, dist = self.cam_params.get(stream, (np.zeros((3, 3)), np.zeros(0)))
        p = np.zeros((3, 4))
        p[:, :3] = k
        model = "rational_polynomial" if dist.size >= 8 else "plumb_bob"
        roi_t = ts.types["sensor_msgs/msg/RegionOfInterest"]
        msg = ts.types["sensor_msgs/msg/CameraInfo"](
            header=_stamp_msg(ts, t_ns, stream),
            height=height,
            width=width,
            distortion_model=model,
            d=np.asarray(dist, np.float64),
            k=k.reshape(9).astype(np.float64),
            r=np.eye(3).reshape(9),
            p=p.reshape(12),
            binning_x=0,
            binning_y=0,
            roi=roi_t(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
        )
        self._add(f"{stream}_info", t_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/CameraInfo"))

    def write_encoded(
        self, stream: str, t_ns: int, data: bytes, fmt: str, height: int, width: int
    ) -> None:
        self._check_open()
        ts = self.ts
        msg = ts.types["sensor_msgs/msg/CompressedImage"](
            header=_stamp_msg(ts, t_ns, stream),
            format=fmt,
            data=np.frombuffer(data, dtype=np.uint8),
        )
        cdr = ts.serialize_cdr(msg, "sensor_msgs/msg/CompressedImage")
        self._admit(len(cdr) + 1024)
        self.mcap.add_message(self.channels[stream], t_ns, cdr)
        self._camera_info(stream, t_ns, height, width)

    def write_raw(self, stream: str, t_ns: int, image: np.ndarray) -> None:
        self._check_open()
        ts = self.ts
        channels = 1 if image.ndim == 2 else 3
        bits = 8 if image.dtype == np.uint8 else 16
        encoding = {(1, 8): "mono8", (3, 8): "rgb8", (1, 16): "mono16", (3, 16): "rgb16"}[
            (channels, bits)
        ]
        data = (
            np.ascontiguousarray(image, dtype=image.dtype.newbyteorder("<"))
            .view(np.uint8)
            .reshape(-1)
        )
        h, w = image.shape[:2]
        msg = ts.types["sensor_msgs/msg/Image"](
            header=_stamp_msg(ts, t_ns, stream),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=w * channels * bits // 8,
            data=data,
        )
        cdr = ts.serialize_cdr(msg, "sensor_msgs/msg/Image")
        self._admit(len(cdr) + 1024)
        self.mcap.add_message(self.channels[stream], t_ns, cdr)
        self._camera_info(stream, t_ns, h, w)

    def write_imu(self, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> None:
        self._check_open()
        ts = self.ts
        vec_t = ts.types["geometry_msgs/msg/Vector3"]
        quat_t = ts.types["geometry_msgs/msg/Quaternion"]
        unknown = np.zeros(9)
        unknown[0] = -1.0
        msg = ts.types["sensor_msgs/msg/Imu"](
            header=_stamp_msg(ts, t_ns, "imu"),
            orientation=quat_t(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=unknown,
            angular_velocity=vec_t(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vec_t(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
            linear_acceleration_covariance=np.zeros(9),
        )
        self._add("imu", t_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/Imu"))

    def write_sonar(self, t_ns: int, range_m: np.float32, confidence: np.float32) -> None:
        self._check_open()
        ts = self.ts
        msg = ts.types["sensor_msgs/msg/Range"](
            header=_stamp_msg(ts, t_ns, "sonar"),
            radiation_type=0,
            field_of_view=SONAR_FOV_RAD,
            min_range=SONAR_MIN_RANGE_M,
            max_range=SONAR_MAX_RANGE_M,
            range=float(range_m),
        )
        conf = ts.types["std_msgs/msg/Float32"](data=float(confidence))
        self._admit(256)
        self.mcap.add_message(
            self.channels["sonar"], t_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/Range")
        )
        self._add("sonar_confidence", t_ns, ts.serialize_cdr(conf, "std_msgs/msg/Float32"))

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
            except (OSError, _ReserveReached) as err:
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


class _ReserveReached(Exception):
    def __init__(self, free: int) -> None:
        super().__init__(f"{free} bytes free")
        self.free = free


# ----------------------------------------------------------------------------- reader


@dataclass(frozen=True)
class DamagedChunk:
    """A chunk whose bytes failed a check; none of its records is decoded.

    Attributes:
        offset: byte offset of the chunk record in the file.
        start_ns, end_ns: stamps of its first and last message (from its header).
        streams: the streams (topics) its message index names, or ``("unknown",)``.
        reason: what failed (CRC mismatch, decompression, cut short, ...).
    """

    offset: int
    start_ns: int
    end_ns: int
    streams: tuple[str, ...]
    reason: str

    def describe(self, path: Path) -> str:
        span = (self.end_ns - self.start_ns) * 1e-9
        return (
            f"{path}: chunk at byte {self.offset} (t_ns {self.start_ns}..{self.end_ns}, "
            f"{span:.3f} s; streams {', '.join(self.streams)}) is damaged ({self.reason}); its "
            "records are skipped"
        )


@dataclass
class _Chunk:
    file_offset: int
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data_offset: int
    data_length: int
    indexed: bool = False
    damaged: str | None = None
    index: dict[int, list[tuple[int, int]]] = field(default_factory=dict)


@dataclass
class _Summary:
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    chunk_indexes: list[ChunkIndex]
    statistics: Statistics | None
    summary_start: int
    # Offsets of the data section's indexed records (chunks, attachments, metadata, data
    # end): where a walk stopped by a damaged record length can resume.
    anchors: list[int] = field(default_factory=list)


class McapSessionReader(SessionReader):
    """Reader for sea3d MCAP sessions (and other ROS 2 MCAP files with the same topics).

    The constructor walks the file's top-level records (chunks, message indexes, attachments,
    metadata) without decompressing image data, so opening an hour-long recording is quick.
    A file cut short (killed recorder, full disk) opens with a warning and holds every message
    of its complete chunks. Every chunk's CRC is checked before any of its records is used.

    Attributes:
        problems: what was found damaged or missing so far (also logged as warnings).
        damaged_chunks: :class:`DamagedChunk` for each chunk found damaged so far.
        complete: the file ends with its data-end record (it was closed properly).

    Raises:
        SessionError: if the file is missing, empty, or not an MCAP file.
    """

    format = "mcap"

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        try:
            self._f = open(self.path, "rb")
        except OSError as err:
            raise SessionError(
                f"cannot open session file {self.path}: {err.strerror or err}"
            ) from err
        self._size = os.fstat(self._f.fileno()).st_size
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunks: list[_Chunk] = []
        self._top_messages: dict[int, list[tuple[int, int]]] = {}
        self._rig_copies = 0
        self._rig_damaged = False
        self._footer_missing = False
        self.metadata: dict[str, dict[str, str]] = {}
        self.complete = False
        self.data_end_at: int | None = None
        self.data_section_crc = 0
        self.damaged_chunks: list[DamagedChunk] = []
        self._summary: _Summary | None = None
        self._cache: OrderedDict[int, bytes] = OrderedDict()
        self._cache_lock = threading.Lock()  # pairs() decodes in worker threads
        self._imu: ImuSeries | None = None
        self._sonar: SonarSeries | None = None
        try:
            self._scan()
            self._build_streams()
            if self._rig is None and self._rig_damaged:
                self._rig_problem = (
                    f"{self.path}: the stored rig.yaml is damaged and has no intact copy"
                )
        except Exception:
            self._f.close()
            raise

    # -- problems ------------------------------------------------------------------------
    def _problem(self, message: str) -> None:
        self.problems.append(message)
        _log.warning("%s", message)

    def _chunk_streams(self, chunk: _Chunk) -> tuple[str, ...]:
        names = []
        for cid in chunk.index:
            ch = self._channels.get(cid)
            names.append(_STREAM_OF_TOPIC.get(ch.topic, ch.topic) if ch else f"channel {cid}")
        return tuple(sorted(set(names))) or ("unknown",)

    def _mark_damaged(self, k: int, reason: str) -> None:
        c = self._chunks[k]
        if c.damaged is not None:
            return
        c.damaged = reason
        info = DamagedChunk(c.file_offset, c.start_ns, c.end_ns, self._chunk_streams(c), reason)
        self.damaged_chunks.append(info)
        self._problem(info.describe(self.path))

    # -- scanning -----------------------------------------------------------------------
    def _pread(self, offset: int, length: int) -> bytes:
        return os.pread(self._f.fileno(), length, offset)

    def _scan(self) -> None:
        head = self._pread(0, 9)
        if len(head) < 9 or head[:8] != MCAP_MAGIC:
            same = sum(a == b for a, b in zip(head[:8], MCAP_MAGIC, strict=False))
            if len(head) < 9 or same < 7 or head[8] != _OP_HEADER:
                raise SessionError(f"{self.path} is not an MCAP file (missing magic bytes)")
            self._problem(f"{self.path}: the magic bytes at the start are damaged; read anyway")
        self._summary = self._read_summary()
        anchors = self._summary.anchors if self._summary is not None else []
        pos = 8
        while True:
            if pos + 9 > self._size:
                self._problem(
                    f"{self.path} ends at byte {self._size} without its summary (interrupted "
                    f"recording?); reading the {len(self._chunks)} complete chunks"
                )
                break
            opcode, length = struct.unpack("<BQ", self._pread(pos, 9))
            start, end = pos + 9, pos + 9 + length
            limit = self._summary.summary_start if self._summary else self._size
            if end > limit:
                # The last chunk's message indexes may be cut short (some channels indexed,
                # others not): index it from its own records.
                if self._chunks:
                    self._chunks[-1].indexed = False
                resume = next((a for a in anchors if a > pos), None)
                self._problem(
                    f"{self.path}: record 0x{opcode:02x} at byte {pos} claims {length} bytes, "
                    f"past the {'data section' if self._summary else 'file'} end (cut short or "
                    "a damaged length); "
                    + (
                        f"resuming at byte {resume} through the summary's index"
                        if resume is not None
                        else f"reading the {len(self._chunks)} complete chunks before it"
                    )
                )
                if resume is None:
                    break
                pos = resume
                continue
            try:
                self._scan_record(opcode, pos, start, length)
            except _PARSE_ERRORS as err:
                self._problem(f"{self.path}: damaged record 0x{opcode:02x} at byte {pos} ({err})")
            if opcode == _OP_DATA_END:
                self.complete = True
                self.data_end_at = pos
                break
            if opcode == _OP_FOOTER:
                self.complete = True
                break
            pos = end
        if not self.complete and self._chunks:
            # Cut short: the last chunk's message indexes may be partial (some channels
            # indexed, others not), so index it from its own records.
            self._chunks[-1].indexed = False
        if self._summary is not None:
            self._check_against_summary()
            for sid, schema in self._summary.schemas.items():
                self._schemas.setdefault(sid, schema)
            for cid, channel in self._summary.channels.items():
                self._channels.setdefault(cid, channel)
        for k, chunk in enumerate(self._chunks):
            unknown = any(cid not in self._channels for cid in chunk.index)
            if not chunk.indexed or unknown:
                self._index_chunk(k)

    def _read_summary(self) -> _Summary | None:
        """The summary section, when the file has one and its CRC holds (else None)."""
        footer_at = self._size - 8 - 29
        if footer_at < 8 or self._pread(self._size - 8, 8) != MCAP_MAGIC:
            self._footer_missing = True
            return None
        raw = self._pread(footer_at, 29)
        opcode, length = struct.unpack_from("<BQ", raw, 0)
        if opcode != _OP_FOOTER or length != 20:
            self._problem(f"{self.path}: footer is damaged; the summary is not used")
            self._footer_missing = True
            return None
        footer = Footer.read(ReadDataStream(io.BytesIO(raw[9:])))
        if footer.summary_start == 0:
            return None
        if not 8 <= footer.summary_start < footer_at:
            self._problem(f"{self.path}: footer points outside the file; summary not used")
            return None
        if footer_at - footer.summary_start > MAX_SUMMARY_BYTES:
            self._problem(f"{self.path}: the footer points at an implausibly large summary")
            return None
        section = self._pread(footer.summary_start, footer_at - footer.summary_start)
        if footer.summary_crc != 0:
            crc = zlib.crc32(raw[:25], zlib.crc32(section))
            if crc != footer.summary_crc:
                self._problem(
                    f"{self.path}: summary at byte {footer.summary_start} is damaged (CRC "
                    "mismatch); it is not used"
                )
                return None
        summary = _Summary({}, {}, [], None, footer.summary_start)
        pos = 0
        try:
            while pos + 9 <= len(section):
                opcode, length = struct.unpack_from("<BQ", section, pos)
                content = section[pos + 9 : pos + 9 + length]
                if len(content) < length:
                    raise ValueError("summary record cut short")
                pos += 9 + length
                stream = ReadDataStream(io.BytesIO(content))
                if opcode == _OP_SCHEMA:
                    s = Schema.read(stream)
                    summary.schemas[s.id] = s
                elif opcode == _OP_CHANNEL:
                    c = Channel.read(stream)
                    summary.channels[c.id] = c
                elif opcode == _OP_CHUNK_INDEX:
                    ci = ChunkIndex.read(stream)
                    summary.chunk_indexes.append(ci)
                    summary.anchors.append(ci.chunk_start_offset)
                elif opcode == _OP_ATTACHMENT_INDEX:
                    summary.anchors.append(AttachmentIndex.read(stream).offset)
                elif opcode == _OP_METADATA_INDEX:
                    summary.anchors.append(MetadataIndex.read(stream).offset)
                elif opcode == _OP_STATISTICS:
                    summary.statistics = Statistics.read(stream)
        except _PARSE_ERRORS as err:
            self._problem(f"{self.path}: summary cannot be parsed ({err}); it is not used")
            return None
        data_end_at = footer.summary_start - 13
        head = self._pread(data_end_at, 9)
        if len(head) == 9 and struct.unpack("<BQ", head) == (_OP_DATA_END, 4):
            summary.anchors.append(data_end_at)
        summary.anchors = sorted(a for a in set(summary.anchors) if 8 <= a < footer.summary_start)
        return summary

    def _check_against_summary(self) -> None:
        assert self._summary is not None
        found = {c.file_offset for c in self._chunks}
        missing = []
        for ci in self._summary.chunk_indexes:
            if ci.chunk_start_offset in found:
                continue
            # The walk skipped it (a record length damaged into a larger, plausible value
            # swallows the records behind it): read it where the summary says it is.
            if self._scan_indexed_chunk(ci):
                continue
            missing.append(ci)
        self._chunks.sort(key=lambda c: c.file_offset)
        for ci in missing:
            topics = sorted(
                {
                    _STREAM_OF_TOPIC.get(ch.topic, ch.topic)
                    for cid in ci.message_index_offsets
                    if (ch := self._summary.channels.get(cid)) is not None
                }
            )
            self._problem(
                f"{self.path}: chunk at byte {ci.chunk_start_offset} (t_ns "
                f"{ci.message_start_time}..{ci.message_end_time}; streams "
                f"{', '.join(topics) or 'unknown'}) listed in the summary cannot be read; its "
                "records are lost"
            )

    def _scan_indexed_chunk(self, ci: ChunkIndex) -> bool:
        """Add the chunk (and its message indexes) a summary chunk index points at."""
        at = ci.chunk_start_offset
        limit = self._summary.summary_start if self._summary is not None else self._size
        n = len(self._chunks)
        try:
            op, length = struct.unpack("<BQ", self._pread(at, 9))
            if op != _OP_CHUNK or at + 9 + length > limit:
                return False
            self._scan_record(_OP_CHUNK, at, at + 9, length)
        except _PARSE_ERRORS:
            return False
        if len(self._chunks) == n:
            return False
        chunk = self._chunks[-1]
        try:
            for mi_at in ci.message_index_offsets.values():
                op, mlen = struct.unpack("<BQ", self._pread(mi_at, 9))
                if op != _OP_MESSAGE_INDEX or mi_at + 9 + mlen > limit:
                    raise ValueError("message index missing")
                self._scan_record(_OP_MESSAGE_INDEX, mi_at, mi_at + 9, mlen)
        except _PARSE_ERRORS:
            chunk.indexed, chunk.index = False, {}  # rebuilt from the chunk's own records
        return True

    def _scan_record(self, opcode: int, pos: int, start: int, length: int) -> None:
        if opcode == _OP_CHUNK:
            head = self._pread(start, 32)
            t0, t1, usize, crc, clen = struct.unpack("<QQQII", head)
            if clen > 64:
                raise ValueError(f"compression name of {clen} bytes")
            comp = self._pread(start + 32, clen).decode("utf-8")
            (dlen,) = struct.unpack("<Q", self._pread(start + 32 + clen, 8))
            doff = start + 40 + clen
            if doff + dlen > start + length:
                raise ValueError("chunk data longer than its record")
            if dlen > MAX_CHUNK_BYTES or usize > MAX_CHUNK_BYTES:
                raise ValueError(f"chunk of {max(dlen, usize)} bytes, larger than any sea3d writes")
            self._chunks.append(_Chunk(pos, t0, t1, usize, crc, comp, doff, dlen))
        elif opcode == _OP_MESSAGE_INDEX:
            if not self._chunks:
                return
            raw = self._pread(start, length)
            cid, rlen = struct.unpack_from("<HI", raw, 0)
            if rlen % 16 or 6 + rlen > len(raw):
                raise ValueError("message index length does not fit its record")
            entries = np.frombuffer(raw, dtype="<u8", count=rlen // 8, offset=6).reshape(-1, 2)
            chunk = self._chunks[-1]
            rows = [(int(t), int(o)) for t, o in entries.tolist()]
            bad = [
                (t, o)
                for t, o in rows
                if not chunk.start_ns <= t <= chunk.end_ns or o + 31 > chunk.uncompressed_size
            ]
            if bad:  # a damaged index: rebuild it from the chunk's (CRC-checked) records
                chunk.indexed = False
                raise ValueError(
                    f"message index of the chunk at byte {chunk.file_offset} points outside "
                    "it; the index is rebuilt from the chunk"
                )
            chunk.index[cid] = rows
            chunk.indexed = True
        elif opcode == _OP_MESSAGE:
            cid, _seq, log_time = struct.unpack("<HIQ", self._pread(start, 14))
            self._top_messages.setdefault(cid, []).append((log_time, pos))
        elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
            self._add_def(opcode, self._pread(start, length), overwrite=False)
        elif opcode == _OP_ATTACHMENT:
            content = self._pread(start, length)
            att = Attachment.read(ReadDataStream(io.BytesIO(content)))
            (stored_crc,) = struct.unpack_from("<I", content, len(content) - 4)
            if stored_crc and zlib.crc32(content[:-4]) != stored_crc:
                self._rig_damaged |= att.name == RIG_ATTACHMENT
                self._problem(
                    f"{self.path}: attachment {att.name!r} at byte {pos} is damaged (CRC "
                    "mismatch); it is not used"
                )
                return
            if att.name == RIG_ATTACHMENT:
                self._rig_copies += 1
                if self._rig is None:
                    try:
                        self._rig = att.data.decode("utf-8")
                    except UnicodeDecodeError as err:
                        self._rig_damaged = True
                        self._problem(
                            f"{self.path}: stored rig.yaml is not UTF-8 text ({err}); not used"
                        )
        elif opcode == _OP_METADATA:
            meta = Metadata.read(ReadDataStream(io.BytesIO(self._pread(start, length))))
            self.metadata[meta.name] = dict(meta.metadata)
        elif opcode == _OP_DATA_END:
            (self.data_section_crc,) = struct.unpack("<I", self._pread(start, 4))

    def _add_def(self, opcode: int, content: bytes, *, overwrite: bool) -> None:
        stream = ReadDataStream(io.BytesIO(content))
        if opcode == _OP_SCHEMA:
            schema = Schema.read(stream)
            if overwrite or schema.id not in self._schemas:
                self._schemas[schema.id] = schema
        else:
            channel = Channel.read(stream)
            if overwrite or channel.id not in self._channels:
                self._channels[channel.id] = channel

    def _chunk_data(self, k: int) -> bytes:
        """Decompressed records of chunk ``k``, CRC checked; cached for the last four chunks.

        Raises:
            SessionError: the chunk is damaged (CRC mismatch, bad compression, cut short).
        """
        with self._cache_lock:
            if k in self._cache:
                self._cache.move_to_end(k)
                return self._cache[k]
        c = self._chunks[k]
        if c.damaged is not None:
            raise SessionError(
                DamagedChunk(
                    c.file_offset, c.start_ns, c.end_ns, self._chunk_streams(c), c.damaged
                ).describe(self.path)
            )
        reason = None
        if c.compression not in ("", "zstd", "lz4"):
            reason = f"unsupported compression {c.compression!r}"
        elif c.uncompressed_size > MAX_CHUNK_BYTES:
            reason = f"claims {c.uncompressed_size} bytes uncompressed"
        elif c.compression == "" and c.uncompressed_size != c.data_length:
            reason = "uncompressed size differs from the stored size"
        data = b""
        if reason is None:
            raw = self._pread(c.data_offset, c.data_length)
            record = Chunk(
                compression=c.compression,
                data=raw,
                message_start_time=c.start_ns,
                message_end_time=c.end_ns,
                uncompressed_crc=c.crc,
                uncompressed_size=c.uncompressed_size,
            )
            try:
                stream, n = get_chunk_data_stream(record, validate_crc=True)
                data = stream.read(n) if n else b""
                if len(data) != c.uncompressed_size:
                    reason = f"{len(data)} bytes after decompression, header says " + str(
                        c.uncompressed_size
                    )
            except CRCValidationError:
                reason = "CRC mismatch"
            except Exception as err:  # zstandard.ZstdError, lz4's RuntimeError, ...
                reason = f"cannot be decompressed: {err}"
        if reason is not None:
            self._mark_damaged(k, reason)
            with self._cache_lock:
                self._cache.pop(k, None)
            return self._chunk_data(k)  # raises with the description
        with self._cache_lock:
            self._cache[k] = data
            while len(self._cache) > 4:
                self._cache.popitem(last=False)
        return data

    def _walk_chunk(self, data: bytes) -> tuple[dict[int, list[tuple[int, int]]], list[bytes]]:
        """Message index and definition records rebuilt from a chunk's records."""
        pos = 0
        index: dict[int, list[tuple[int, int]]] = {}
        defs: list[bytes] = []
        while pos + 9 <= len(data):
            opcode, length = struct.unpack_from("<BQ", data, pos)
            if pos + 9 + length > len(data):
                raise ValueError(f"record at chunk byte {pos} runs past the chunk end")
            if opcode in (_OP_SCHEMA, _OP_CHANNEL):
                defs.append(data[pos : pos + 9 + length])
            elif opcode == _OP_MESSAGE:
                if length < 22:
                    raise ValueError(f"message at chunk byte {pos} is {length} bytes")
                cid, _seq, log_time = struct.unpack_from("<HIQ", data, pos + 9)
                index.setdefault(cid, []).append((log_time, pos))
            pos += 9 + length
        if pos != len(data):
            raise ValueError(f"{len(data) - pos} stray bytes at the chunk end")
        return index, defs

    def _index_chunk(self, k: int) -> None:
        """Load chunk ``k`` (CRC checked), take its definitions and, if its message index is
        missing or damaged, rebuild it from its records."""
        chunk = self._chunks[k]
        try:
            data = self._chunk_data(k)
            index, defs = self._walk_chunk(data)
        except SessionError:
            return
        except (ValueError, struct.error) as err:
            self._mark_damaged(k, str(err))
            return
        for rec in defs:
            try:
                self._add_def(rec[0], rec[9:], overwrite=False)
            except _PARSE_ERRORS as err:
                self._mark_damaged(k, f"damaged definition record ({err})")
                return
        if not chunk.indexed:
            chunk.index = index
            chunk.indexed = True

    def check(self) -> list[str]:
        """Read every chunk and the whole data section and check them (what ``session
        verify`` does beyond decoding every record).

        Checks each chunk's CRC and records, compares its message index with its records,
        and the data section CRC. Returns the new problems (also in :attr:`problems`).
        """
        before = len(self.problems)
        for k, chunk in enumerate(self._chunks):
            if chunk.damaged is not None:
                continue
            try:
                data = self._chunk_data(k)
                index, _defs = self._walk_chunk(data)
            except SessionError:
                continue
            except (ValueError, struct.error) as err:
                self._mark_damaged(k, str(err))
                continue
            if index != chunk.index:
                self._problem(
                    f"{self.path}: the message index of the chunk at byte {chunk.file_offset} "
                    "does not match its records (damaged index)"
                )
        if self.data_end_at is not None and self.data_section_crc:
            crc = 0
            pos = 0
            while pos < self.data_end_at:
                block = self._pread(pos, min(8 << 20, self.data_end_at - pos))
                crc = zlib.crc32(block, crc)
                pos += len(block)
            if crc != self.data_section_crc:
                self._problem(
                    f"{self.path}: data section CRC mismatch: some bytes outside the checked "
                    "chunks and attachments are damaged (message indexes, metadata, "
                    "definitions)"
                )
        if self.data_end_at is not None and self._footer_missing:
            self._problem(
                f"{self.path}: the file was closed (it has its data-end record) but its footer "
                "is missing or damaged"
            )
        stats = self._summary.statistics if self._summary is not None else None
        if stats is not None:
            for cid, expected in stats.channel_message_counts.items():
                ch = self._channels.get(cid)
                stream = _STREAM_OF_TOPIC.get(ch.topic) if ch is not None else None
                if stream is None:
                    continue
                got = int(self._stamps.get(stream, np.zeros(0)).size)
                good = sum(
                    len(c.index.get(cid, ())) for c in self._chunks if c.damaged is None
                ) + len(self._top_messages.get(cid, ()))
                if min(got, good) < expected:
                    self._problem(
                        f"{self.path}: topic {ch.topic}: the summary counts {expected} records, "  # type: ignore[union-attr]
                        f"{min(got, good)} are readable"
                    )
        return self.problems[before:]

    def _build_streams(self) -> None:
        per_stream: dict[str, list[tuple[int, int, int]]] = {}
        self._stream_channel: dict[str, int] = {}
        for cid, ch in sorted(self._channels.items()):
            stream = _STREAM_OF_TOPIC.get(ch.topic)
            if stream is None:
                _log.info("%s: topic %s is not a sea3d stream; ignored", self.path, ch.topic)
                continue
            self._stream_channel.setdefault(stream, cid)
        for stream, cid in self._stream_channel.items():
            rows = per_stream.setdefault(stream, [])
            for k, chunk in enumerate(self._chunks):
                if chunk.damaged is not None:
                    continue
                rows.extend((t, k, off) for t, off in chunk.index.get(cid, ()))
            rows.extend((t, -1, off) for t, off in self._top_messages.get(cid, ()))
        self._loc: dict[str, np.ndarray] = {}
        self._stamps: dict[str, np.ndarray] = {}
        for stream, rows in per_stream.items():
            arr = np.asarray(rows, dtype=np.int64).reshape(-1, 3)
            order = sort_stamps(arr[:, 0], f"{self.path} topic {TOPICS.get(stream, stream)}")
            self._loc[stream] = arr[order, 1:]
            self._stamps[stream] = arr[order, 0]

    # -- record access ------------------------------------------------------------------
    def _message(self, stream: str, index: int) -> tuple[bytes, str]:
        """CDR bytes and ROS type name of record ``index`` of ``stream``."""
        k, off = (int(v) for v in self._loc[stream][index])
        t_ns = int(self._stamps[stream][index])
        cid = self._stream_channel[stream]
        where = f"{self.path} topic {self._channels[cid].topic} t_ns={t_ns}"
        if k < 0:  # a message outside chunks (other tools' files): no CRC to check
            head = self._pread(off, 9)
            if len(head) < 9:
                raise SessionError(f"{where}: record cut short")
            opcode, length = struct.unpack("<BQ", head)
            if opcode != _OP_MESSAGE or off + 9 + length > self._size or length < 22:
                raise SessionError(f"{where}: damaged message record (opcode 0x{opcode:02x})")
            content = self._pread(off + 9, length)
        else:
            try:
                data = self._chunk_data(k)
            except SessionError as err:
                raise SessionError(f"{where}: {err}") from err
            if off + 9 > len(data):
                raise SessionError(f"{where}: message index points past its chunk")
            opcode, length = struct.unpack_from("<BQ", data, off)
            if opcode != _OP_MESSAGE or off + 9 + length > len(data) or length < 22:
                raise SessionError(f"{where}: damaged message index (opcode 0x{opcode:02x})")
            content = data[off + 9 : off + 9 + length]
        mcid, _seq, log_time = struct.unpack_from("<HIQ", content, 0)
        if mcid != cid or log_time != t_ns:
            raise SessionError(f"{where}: message index points at another record")
        schema = self._schemas.get(self._channels[cid].schema_id)
        if schema is None:
            raise SessionError(f"{where}: channel has no schema")
        return content[22:], schema.name

    def _decode(self, stream: str, index: int) -> Any:
        data, typename = self._message(stream, index)
        try:
            return _typestore().deserialize_cdr(data, typename)
        except Exception as err:
            raise SessionError(
                f"{self._record_name(stream, index)} "
                f"(t_ns={int(self._stamps[stream][index])}): cannot decode "
                f"{typename} ({err})"
            ) from err

    def _record_name(self, stream: str, index: int) -> str:
        return f"{self.path} topic {TOPICS.get(stream, stream)} message {index}"

    @property
    def image_encoding(self) -> str | None:
        return self.metadata.get(METADATA_NAME, {}).get("image_encoding")

    def stamps(self, stream: str) -> np.ndarray:
        if stream not in (
            "left",
            "right",
            "imu",
            "sonar",
            "left_info",
            "right_info",
            "sonar_confidence",
        ):
            raise SessionError(f"unknown stream {stream!r}; expected left, right, imu or sonar")
        return self._stamps.get(stream, np.zeros(0, dtype=np.int64))

    def image_bytes(self, stream: str, index: int) -> tuple[bytes, str]:
        """The stored bytes of an image and their format: ``png``/``jxl``/``jpeg`` for
        CompressedImage; for a raw ``Image`` message, PNG bytes made from it (lossless)."""
        msg = self._decode(stream, index)
        if hasattr(msg, "format"):
            return bytes(msg.data), _format_name(str(msg.format))
        from sea3d.io.session_common import encode_image

        return encode_image(self._raw_to_array(msg, stream, index), "png"), "png"

    def _raw_to_array(self, msg: Any, stream: str, index: int) -> np.ndarray:
        enc = str(msg.encoding).lower()
        table = {
            "mono8": (1, np.uint8),
            "8uc1": (1, np.uint8),
            "rgb8": (3, np.uint8),
            "bgr8": (3, np.uint8),
            "8uc3": (3, np.uint8),
            "mono16": (1, np.uint16),
            "16uc1": (1, np.uint16),
            "rgb16": (3, np.uint16),
            "bgr16": (3, np.uint16),
        }
        if enc not in table:
            raise SessionError(
                f"{self._record_name(stream, index)}: unsupported image encoding {enc!r}"
            )
        ch, dtype = table[enc]
        stored = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
        itemsize = np.dtype(dtype).itemsize
        h, w, step = int(msg.height), int(msg.width), int(msg.step)
        raw = np.asarray(msg.data, dtype=np.uint8)
        if h <= 0 or w <= 0 or raw.size < h * step or step < w * ch * itemsize:
            raise SessionError(
                f"{self._record_name(stream, index)}: image data is {raw.size} bytes, "
                f"expected {h} rows of {step}"
            )
        rows = raw[: h * step].reshape(h, step)[:, : w * ch * itemsize]
        img = np.ascontiguousarray(rows).view(stored).astype(dtype)
        img = img.reshape(h, w, ch) if ch == 3 else img.reshape(h, w)
        if enc.startswith("bgr"):
            img = np.ascontiguousarray(img[:, :, ::-1])
        return img

    def _read_image(self, stream: str, index: int) -> np.ndarray:
        msg = self._decode(stream, index)
        where = f"{self._record_name(stream, index)} (t_ns={int(self._stamps[stream][index])})"
        if hasattr(msg, "format"):
            return decode_image(np.asarray(msg.data, dtype=np.uint8), where)
        return self._raw_to_array(msg, stream, index)

    def _each(self, stream: str) -> Any:
        for i in range(self.stamps(stream).size):
            try:
                yield i, self._decode(stream, i)
            except SessionError as err:
                self._skipped(stream, str(err))

    def _skipped(self, stream: str, message: str) -> None:
        self.skipped[stream] = self.skipped.get(stream, 0) + 1
        _log.warning("%s; skipped", message)

    def imu(self) -> ImuSeries:
        if self._imu is None:
            t, acc, gyr = [], [], []
            stamps = self.stamps("imu")
            for i, msg in self._each("imu"):
                a, g = msg.linear_acceleration, msg.angular_velocity
                t.append(int(stamps[i]))
                acc.append((a.x, a.y, a.z))
                gyr.append((g.x, g.y, g.z))
            self._imu = ImuSeries(
                t_ns=np.asarray(t, dtype=np.int64),
                accel_mps2=np.asarray(acc, dtype=np.float64).reshape(-1, 3),
                gyro_radps=np.asarray(gyr, dtype=np.float64).reshape(-1, 3),
            )
        return self._imu

    def sonar(self) -> SonarSeries:
        if self._sonar is None:
            t, r = [], []
            stamps = self.stamps("sonar")
            for i, msg in self._each("sonar"):
                t.append(int(stamps[i]))
                r.append(msg.range)
            conf_t = self.stamps("sonar_confidence")
            conf_v = np.full(conf_t.size, np.nan, dtype=np.float32)
            for i, msg in self._each("sonar_confidence"):
                conf_v[i] = msg.data
            t_arr = np.asarray(t, dtype=np.int64)
            conf = np.full(t_arr.size, np.nan, dtype=np.float32)
            if conf_t.size:
                j = np.clip(np.searchsorted(conf_t, t_arr), 0, conf_t.size - 1)
                hit = conf_t[j] == t_arr
                conf[hit] = conf_v[j[hit]]
            self._sonar = SonarSeries(
                t_ns=t_arr, range_m=np.asarray(r, dtype=np.float32), confidence=conf
            )
        return self._sonar

    def size_bytes(self) -> int:
        return self._size

    def close(self) -> None:
        self._cache.clear()
        self._f.close()


def _format_name(fmt: str) -> str:
    """``png``, ``jpeg``, ``jxl`` from a CompressedImage format string (image_transport writes
    e.g. ``"rgb8; jpeg compressed bgr8"``)."""
    fmt = fmt.lower()
    if "jpeg" in fmt or "jpg" in fmt:
        return "jpeg"
    if "png" in fmt:
        return "png"
    if "jxl" in fmt or "jpegxl" in fmt:
        return "jxl"
    return fmt
