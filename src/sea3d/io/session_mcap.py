"""Sessions as one MCAP file of ROS 2 messages (``ros2`` profile, ``cdr`` encoding).

Topics and types (from ``sensor_msgs`` / ``std_msgs`` of ROS 2 Humble, serialised by rosbags):

===========================  ===========================================================
``/cam/left/image``          ``sensor_msgs/msg/CompressedImage`` (png or jpeg) or ``Image``
``/cam/right/image``         same as left
``/cam/left/camera_info``    ``sensor_msgs/msg/CameraInfo``, one per image (from the rig)
``/cam/right/camera_info``   same as left
``/imu``                     ``sensor_msgs/msg/Imu`` (orientation unknown: covariance[0] = -1)
``/sonar``                   ``sensor_msgs/msg/Range`` (ULTRASOUND)
``/sonar/confidence``        ``std_msgs/msg/Float32``, same stamps as ``/sonar``
===========================  ===========================================================

The rig file is an attachment ``rig.yaml`` (``application/yaml``) written before any message,
and a metadata record ``sea3d`` holds the format version and image encoding. Message log and
publish times are the sensor stamps in nanoseconds; header stamps carry the same value.

Writing closes a chunk every ``chunk_size`` bytes or ``chunk_interval_s`` seconds and hands it
to the operating system at once, so a process killed with SIGKILL leaves a file that is
readable up to its last complete chunk. Reading walks the file's records itself (it does not
need the summary section at the end), so a truncated or partly damaged file still opens: the
reader warns about what it had to skip.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import threading
import time
import zlib
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import Attachment, Channel, ChunkIndex, Metadata, Schema
from mcap.writer import CompressionType, Writer

from sea3d.errors import SessionError
from sea3d.io.session_common import (
    ImuSeries,
    SessionReader,
    SonarSeries,
    decode_image,
    sort_stamps,
)

__all__ = ["TOPICS", "McapSessionReader", "McapSessionWriter"]

_log = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_CHUNK_INDEX = 0x06, 0x07, 0x08
_OP_ATTACHMENT, _OP_METADATA, _OP_DATA_END = 0x09, 0x0C, 0x0F

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


class _FdWriter:
    """Unbuffered file sink for mcap's Writer: every write reaches the OS at once."""

    def __init__(self, path: Path) -> None:
        try:
            self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError as err:
            raise SessionError(f"{path} already exists; refusing to overwrite it") from err
        except OSError as err:
            raise SessionError(f"cannot create {path}: {err}") from err
        self.pos = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            done += os.write(self.fd, view[done:])
        self.pos += done
        return done

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        pass

    def close(self, *, sync: bool) -> None:
        if sync:
            os.fsync(self.fd)
        os.close(self.fd)


def _stamp_msg(ts: Any, t_ns: int, frame_id: str) -> Any:
    time_t = ts.types["builtin_interfaces/msg/Time"]
    header_t = ts.types["std_msgs/msg/Header"]
    return header_t(
        stamp=time_t(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000), frame_id=frame_id
    )


def _camera_info_params(rig_yaml: str | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """K (3,3) and distortion per side from the rig text, or {} if it cannot be parsed."""
    if rig_yaml is None:
        return {}
    try:
        from sea3d.io.rig_file import rig_from_yaml  # type: ignore[import-not-found,unused-ignore]

        rig = rig_from_yaml(rig_yaml)
        out = {}
        for side in ("left", "right"):
            cam = getattr(rig, side)
            pin = getattr(cam, "pinhole", cam)
            out[side] = (
                np.asarray(pin.K, dtype=np.float64),
                np.asarray(pin.dist, dtype=np.float64),
            )
        return out
    except Exception as err:
        _log.debug("camera_info without intrinsics: rig not parsed (%s)", err)
        return {}


class McapSessionWriter:
    """Backend of :class:`~sea3d.io.session.SessionWriter` for MCAP files (not public)."""

    def __init__(
        self,
        path: Path,
        rig_yaml: str | None,
        image_encoding: str,
        *,
        chunk_size: int = 4 << 20,
        chunk_interval_s: float = 1.0,
        chunk_compression: str | None = None,
    ) -> None:
        from sea3d import __version__

        self.path = path
        self.image_encoding = image_encoding
        self.chunk_size = int(chunk_size)
        self.chunk_interval_s = float(chunk_interval_s)
        if chunk_compression is None:
            chunk_compression = "zstd" if image_encoding == "raw" else "none"
        comp = {
            "none": CompressionType.NONE,
            "zstd": CompressionType.ZSTD,
            "lz4": CompressionType.LZ4,
        }.get(chunk_compression)
        if comp is None:
            raise SessionError(
                f"chunk_compression must be none, zstd or lz4, got {chunk_compression!r}"
            )
        self.ts = _typestore()
        self.out = _FdWriter(path)
        # Chunks are closed by this class (size or age), never by mcap's own threshold.
        self.w = Writer(self.out, chunk_size=1 << 62, compression=comp)  # type: ignore[arg-type]
        self.w.start(profile="ros2", library=f"sea3d {__version__}")
        now = time.time_ns()
        if rig_yaml is not None:
            self.w.add_attachment(
                create_time=now,
                log_time=now,
                name=RIG_ATTACHMENT,
                media_type="application/yaml",
                data=rig_yaml.encode("utf-8"),
            )
        self.w.add_metadata(
            METADATA_NAME,
            {"format": "sea3d-session", "version": "1", "image_encoding": image_encoding},
        )
        self.cam_params = _camera_info_params(rig_yaml)
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
        self.channels: dict[str, int] = {}
        for stream, typename in types.items():
            if typename not in schema_ids:
                msgdef, _md5 = self.ts.generate_msgdef(typename, ros_version=2)
                schema_ids[typename] = self.w.register_schema(typename, "ros2msg", msgdef.encode())
            self.channels[stream] = self.w.register_channel(
                TOPICS[stream], "cdr", schema_ids[typename]
            )
        self.pending_bytes = 0
        self.pending_since: float | None = None
        self.bytes_written = 0
        self.w.flush()

    def _add(self, stream: str, t_ns: int, data: memoryview | bytes) -> None:
        self.w.add_message(
            self.channels[stream], log_time=t_ns, data=bytes(data), publish_time=t_ns
        )
        self.pending_bytes += len(data) + 31
        self.bytes_written += len(data) + 31
        now = time.monotonic()
        if self.pending_since is None:
            self.pending_since = now
        if (
            self.pending_bytes >= self.chunk_size
            or now - self.pending_since >= self.chunk_interval_s
        ):
            self.flush()

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS."""
        self.w.flush()
        self.pending_bytes = 0
        self.pending_since = None

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
        ts = self.ts
        msg = ts.types["sensor_msgs/msg/CompressedImage"](
            header=_stamp_msg(ts, t_ns, stream),
            format=fmt,
            data=np.frombuffer(data, dtype=np.uint8),
        )
        self._add(stream, t_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/CompressedImage"))
        self._camera_info(stream, t_ns, height, width)

    def write_raw(self, stream: str, t_ns: int, image: np.ndarray) -> None:
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
        self._add(stream, t_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/Image"))
        self._camera_info(stream, t_ns, h, w)

    def write_imu(self, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> None:
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
        ts = self.ts
        msg = ts.types["sensor_msgs/msg/Range"](
            header=_stamp_msg(ts, t_ns, "sonar"),
            radiation_type=0,
            field_of_view=SONAR_FOV_RAD,
            min_range=SONAR_MIN_RANGE_M,
            max_range=SONAR_MAX_RANGE_M,
            range=float(range_m),
        )
        self._add("sonar", t_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/Range"))
        conf = ts.types["std_msgs/msg/Float32"](data=float(confidence))
        self._add("sonar_confidence", t_ns, ts.serialize_cdr(conf, "std_msgs/msg/Float32"))

    def close(self, counts: dict[str, int]) -> None:
        del counts
        try:
            self.w.finish()
        finally:
            self.out.close(sync=True)


# ----------------------------------------------------------------------------- reader


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
    damaged: bool = False
    index: dict[int, list[tuple[int, int]]] = field(default_factory=dict)


class McapSessionReader(SessionReader):
    """Reader for sea3d MCAP sessions (and other ROS 2 MCAP files with the same topics).

    The constructor walks the file's top-level records (chunks, message indexes, attachments,
    metadata) without decompressing image data, so opening an hour-long recording is quick.
    A file cut short (killed recorder, full disk) opens with a warning and holds every message
    of its complete chunks.

    Raises:
        SessionError: if the file is missing, empty, or not an MCAP file.
    """

    format = "mcap"

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        try:
            self._f = open(self.path, "rb")
        except OSError as err:
            raise SessionError(f"cannot open session file {self.path}: {err}") from err
        self._size = os.fstat(self._f.fileno()).st_size
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunks: list[_Chunk] = []
        self._top_messages: dict[int, list[tuple[int, int]]] = {}
        self._rig: str | None = None
        self.metadata: dict[str, dict[str, str]] = {}
        self.complete = False
        self._cache: OrderedDict[int, bytes] = OrderedDict()
        self._cache_lock = threading.Lock()  # pairs() decodes in worker threads
        try:
            self._scan()
        except Exception:
            self._f.close()
            raise
        self._build_streams()
        self._imu: ImuSeries | None = None
        self._sonar: SonarSeries | None = None

    # -- scanning -----------------------------------------------------------------------
    def _pread(self, offset: int, length: int) -> bytes:
        return os.pread(self._f.fileno(), length, offset)

    def _scan(self) -> None:
        if self._size < len(MCAP_MAGIC) or self._pread(0, 8) != MCAP_MAGIC:
            raise SessionError(f"{self.path} is not an MCAP file (missing magic bytes)")
        pos = 8
        while True:
            if pos + 9 > self._size:
                _log.warning(
                    "%s ends at byte %d without its summary (interrupted recording?); "
                    "reading the %d complete chunks",
                    self.path,
                    self._size,
                    len(self._chunks),
                )
                break
            opcode, length = struct.unpack("<BQ", self._pread(pos, 9))
            start, end = pos + 9, pos + 9 + length
            if end > self._size:
                _log.warning(
                    "%s is truncated inside a record (opcode 0x%02x at byte %d); "
                    "reading the %d complete chunks before it",
                    self.path,
                    opcode,
                    pos,
                    len(self._chunks),
                )
                break
            try:
                self._scan_record(opcode, start, length)
            except (struct.error, ValueError, UnicodeDecodeError, EOFError) as err:
                _log.warning(
                    "%s: damaged record 0x%02x at byte %d (%s); skipped",
                    self.path,
                    opcode,
                    pos,
                    err,
                )
            if opcode in (_OP_DATA_END, _OP_FOOTER):
                self.complete = True
                break
            pos = end
        if not self.complete:
            self._recover_from_summary(pos)
        for k, chunk in enumerate(self._chunks):
            unknown = any(cid not in self._channels for cid in chunk.index)
            if not chunk.indexed or unknown:
                self._index_chunk(k, chunk)

    def _recover_from_summary(self, stopped_at: int) -> None:
        """After the walk stopped early (a damaged record length, say), find the chunks
        behind the damage through the summary's chunk indexes, when the file has one."""
        footer_at = self._size - 8 - 29
        if footer_at <= stopped_at or self._pread(self._size - 8, 8) != MCAP_MAGIC:
            return
        opcode, length = struct.unpack("<BQ", self._pread(footer_at, 9))
        if opcode != _OP_FOOTER or length != 20:
            return
        (summary_start,) = struct.unpack("<Q", self._pread(footer_at + 9, 8))
        if not 8 <= summary_start < footer_at:
            return
        known = {c.file_offset for c in self._chunks}
        recovered = 0
        pos = summary_start
        while pos + 9 <= footer_at:
            opcode, length = struct.unpack("<BQ", self._pread(pos, 9))
            if pos + 9 + length > footer_at:
                break
            content = self._pread(pos + 9, length)
            pos += 9 + length
            try:
                if opcode in (_OP_SCHEMA, _OP_CHANNEL):
                    self._add_def(opcode, content)
                elif opcode == _OP_CHUNK_INDEX:
                    ci = ChunkIndex.read(ReadDataStream(io.BytesIO(content)))
                    if ci.chunk_start_offset in known or ci.chunk_start_offset < stopped_at:
                        continue
                    op, clen = struct.unpack("<BQ", self._pread(ci.chunk_start_offset, 9))
                    if op != _OP_CHUNK or ci.chunk_start_offset + 9 + clen > self._size:
                        continue
                    self._scan_record(_OP_CHUNK, ci.chunk_start_offset + 9, clen)
                    for mi_offset in ci.message_index_offsets.values():
                        op, mlen = struct.unpack("<BQ", self._pread(mi_offset, 9))
                        if op == _OP_MESSAGE_INDEX and mi_offset + 9 + mlen <= self._size:
                            self._scan_record(_OP_MESSAGE_INDEX, mi_offset + 9, mlen)
                    recovered += 1
            except (struct.error, ValueError, UnicodeDecodeError, EOFError) as err:
                _log.warning(
                    "%s: damaged summary record 0x%02x (%s); skipped", self.path, opcode, err
                )
        if recovered:
            _log.warning(
                "%s: found %d more chunks after the damage at byte %d through the summary",
                self.path,
                recovered,
                stopped_at,
            )

    def _scan_record(self, opcode: int, start: int, length: int) -> None:
        if opcode == _OP_CHUNK:
            head = self._pread(start, 32)
            t0, t1, usize, crc, clen = struct.unpack("<QQQII", head)
            comp = self._pread(start + 32, clen).decode("utf-8")
            (dlen,) = struct.unpack("<Q", self._pread(start + 32 + clen, 8))
            doff = start + 40 + clen
            if doff + dlen > start + length:
                raise ValueError("chunk data longer than its record")
            self._chunks.append(_Chunk(start - 9, t0, t1, usize, crc, comp, doff, dlen))
        elif opcode == _OP_MESSAGE_INDEX:
            if not self._chunks:
                return
            raw = self._pread(start, length)
            cid, rlen = struct.unpack_from("<HI", raw, 0)
            entries = np.frombuffer(raw, dtype="<u8", count=rlen // 8, offset=6).reshape(-1, 2)
            chunk = self._chunks[-1]
            chunk.index[cid] = [(int(t), int(o)) for t, o in entries.tolist()]
            chunk.indexed = True
        elif opcode == _OP_MESSAGE:
            cid, _seq, log_time = struct.unpack("<HIQ", self._pread(start, 14))
            self._top_messages.setdefault(cid, []).append((log_time, start - 9))
        elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
            self._add_def(opcode, self._pread(start, length))
        elif opcode == _OP_ATTACHMENT:
            att = Attachment.read(ReadDataStream(io.BytesIO(self._pread(start, length))))
            if att.name == RIG_ATTACHMENT:
                self._rig = att.data.decode("utf-8")
        elif opcode == _OP_METADATA:
            meta = Metadata.read(ReadDataStream(io.BytesIO(self._pread(start, length))))
            self.metadata[meta.name] = dict(meta.metadata)
            if meta.name == METADATA_NAME and "rig_yaml" in meta.metadata and self._rig is None:
                self._rig = meta.metadata["rig_yaml"]

    def _add_def(self, opcode: int, content: bytes) -> None:
        stream = ReadDataStream(io.BytesIO(content))
        if opcode == _OP_SCHEMA:
            schema = Schema.read(stream)
            self._schemas[schema.id] = schema
        else:
            channel = Channel.read(stream)
            self._channels[channel.id] = channel

    def _chunk_data(self, k: int) -> bytes:
        """Decompressed records of chunk ``k`` (CRC checked), cached for the last four chunks."""
        with self._cache_lock:
            if k in self._cache:
                self._cache.move_to_end(k)
                return self._cache[k]
        c = self._chunks[k]
        raw = self._pread(c.data_offset, c.data_length)
        try:
            if c.compression == "zstd":
                import zstandard

                data = zstandard.ZstdDecompressor().decompress(
                    raw, max_output_size=c.uncompressed_size
                )
            elif c.compression == "lz4":
                import lz4.frame

                data = lz4.frame.decompress(raw)
            elif c.compression == "":
                data = raw
            else:
                raise SessionError(f"unsupported chunk compression {c.compression!r}")
        except SessionError:
            raise
        except Exception as err:
            raise SessionError(
                f"{self.path}: chunk at byte {c.file_offset} cannot be decompressed ({err})"
            ) from err
        if c.crc and zlib.crc32(data) != c.crc:
            raise SessionError(
                f"{self.path}: chunk at byte {c.file_offset} (t_ns {c.start_ns}.."
                f"{c.end_ns}) is damaged (CRC mismatch)"
            )
        with self._cache_lock:
            self._cache[k] = data
            while len(self._cache) > 4:
                self._cache.popitem(last=False)
        return data

    def _index_chunk(self, k: int, chunk: _Chunk) -> None:
        try:
            data = self._chunk_data(k)
        except SessionError as err:
            _log.warning("%s; its messages are skipped", err)
            chunk.damaged = True
            chunk.index = {}
            return
        pos, rebuild = 0, not chunk.indexed
        index: dict[int, list[tuple[int, int]]] = {}
        while pos + 9 <= len(data):
            opcode, length = struct.unpack_from("<BQ", data, pos)
            if pos + 9 + length > len(data):
                break
            if opcode in (_OP_SCHEMA, _OP_CHANNEL):
                self._add_def(opcode, data[pos + 9 : pos + 9 + length])
            elif opcode == _OP_MESSAGE and rebuild:
                cid, _seq, log_time = struct.unpack_from("<HIQ", data, pos + 9)
                index.setdefault(cid, []).append((log_time, pos))
            elif opcode == _OP_MESSAGE:
                break  # definitions precede messages; the index is already known
            pos += 9 + length
        if rebuild:
            chunk.index = index
            chunk.indexed = True

    def _build_streams(self) -> None:
        per_stream: dict[str, list[tuple[int, int, int]]] = {}
        self._stream_channel: dict[str, int] = {}
        for cid, ch in self._channels.items():
            stream = _STREAM_OF_TOPIC.get(ch.topic)
            if stream is None:
                _log.info("%s: topic %s is not a sea3d stream; ignored", self.path, ch.topic)
                continue
            self._stream_channel[stream] = cid
        for stream, cid in self._stream_channel.items():
            rows = per_stream.setdefault(stream, [])
            for k, chunk in enumerate(self._chunks):
                if chunk.damaged:
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
        if k < 0:
            head, base, limit = self._pread(off, 9), off, self._size
            content_at = off + 9
        elif self._chunks[k].compression == "":
            c = self._chunks[k]
            head, base, limit = (
                self._pread(c.data_offset + off, 9),
                c.data_offset + off,
                c.data_offset + c.data_length,
            )
            content_at = base + 9
        else:
            data = self._chunk_data(k)
            head, base, limit, content_at = data[off : off + 9], off, len(data), -1
        if len(head) < 9:
            raise SessionError(f"{where}: record cut short")
        opcode, length = struct.unpack("<BQ", head)
        if opcode != _OP_MESSAGE or base + 9 + length > limit or length < 22:
            raise SessionError(f"{where}: damaged message record (opcode 0x{opcode:02x})")
        if content_at >= 0:
            content = self._pread(content_at, length)
        else:
            data = self._chunk_data(k)
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
    def rig_yaml(self) -> str | None:
        return self._rig

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
        """The stored bytes of an image and their format: ``png``/``jpeg`` for CompressedImage;
        for a raw ``Image`` message, PNG bytes made from it (lossless) and ``png``."""
        msg = self._decode(stream, index)
        if hasattr(msg, "format"):
            fmt = str(msg.format).lower()
            fmt = "jpeg" if ("jpeg" in fmt or "jpg" in fmt) else ("png" if "png" in fmt else fmt)
            return bytes(msg.data), fmt
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
        if raw.size < h * step or step < w * ch * itemsize:
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
                _log.warning("%s; skipped", err)

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
