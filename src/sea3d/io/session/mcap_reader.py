"""The salvaging MCAP reader: every CRC checked, damaged chunks reported and skipped, a
truncated file read up to its last complete chunk (see :mod:`sea3d.io.session.storage_mcap`)."""

from __future__ import annotations

import io
import logging
import os
import struct
import threading
import zlib
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    Footer,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)
from mcap.stream_reader import CRCValidationError, get_chunk_data_stream

from sea3d.errors import SessionError
from sea3d.io.session.common import (
    DamagedChunk,
    ImuSeries,
    SonarSeries,
    decode_image,
    sort_stamps,
)
from sea3d.io.session.mcap_chunks import (
    MAX_CHUNK_BYTES,
    MAX_SUMMARY_BYTES,
    MCAP_MAGIC,
    OP_ATTACHMENT,
    OP_ATTACHMENT_INDEX,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_METADATA_INDEX,
    OP_SCHEMA,
    OP_STATISTICS,
    PARSE_ERRORS,
)
from sea3d.io.session.reader import SessionReader
from sea3d.io.session.ros_messages import (
    METADATA_NAME,
    RIG_ATTACHMENT,
    STREAM_OF_TOPIC,
    TOPICS,
    raw_image_array,
    typestore,
)

__all__ = ["DamagedChunk", "McapSessionReader"]

_log = logging.getLogger(__name__)

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

    def checks(self) -> tuple[str, str]:
        indexed = "the summary and message indexes" if self.complete else "a scan of the file"
        return (
            f"{indexed} and the rig attachment's CRC-32",
            "chunk CRCs and image data: the counts are what the index lists (run "
            "`sea3d session verify`)",
        )

    # -- problems ------------------------------------------------------------------------
    def _problem(self, message: str) -> None:
        self.problems.append(message)
        _log.warning("%s", message)

    def _chunk_streams(self, chunk: _Chunk) -> tuple[str, ...]:
        names = []
        for cid in chunk.index:
            ch = self._channels.get(cid)
            names.append(STREAM_OF_TOPIC.get(ch.topic, ch.topic) if ch else f"channel {cid}")
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
            if len(head) < 9 or same < 7 or head[8] != OP_HEADER:
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
            except PARSE_ERRORS as err:
                self._problem(f"{self.path}: damaged record 0x{opcode:02x} at byte {pos} ({err})")
            if opcode == OP_DATA_END:
                self.complete = True
                self.data_end_at = pos
                break
            if opcode == OP_FOOTER:
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
        if opcode != OP_FOOTER or length != 20:
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
                if opcode == OP_SCHEMA:
                    s = Schema.read(stream)
                    summary.schemas[s.id] = s
                elif opcode == OP_CHANNEL:
                    c = Channel.read(stream)
                    summary.channels[c.id] = c
                elif opcode == OP_CHUNK_INDEX:
                    ci = ChunkIndex.read(stream)
                    summary.chunk_indexes.append(ci)
                    summary.anchors.append(ci.chunk_start_offset)
                elif opcode == OP_ATTACHMENT_INDEX:
                    summary.anchors.append(AttachmentIndex.read(stream).offset)
                elif opcode == OP_METADATA_INDEX:
                    summary.anchors.append(MetadataIndex.read(stream).offset)
                elif opcode == OP_STATISTICS:
                    summary.statistics = Statistics.read(stream)
        except PARSE_ERRORS as err:
            self._problem(f"{self.path}: summary cannot be parsed ({err}); it is not used")
            return None
        data_end_at = footer.summary_start - 13
        head = self._pread(data_end_at, 9)
        if len(head) == 9 and struct.unpack("<BQ", head) == (OP_DATA_END, 4):
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
                    STREAM_OF_TOPIC.get(ch.topic, ch.topic)
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
            if op != OP_CHUNK or at + 9 + length > limit:
                return False
            self._scan_record(OP_CHUNK, at, at + 9, length)
        except PARSE_ERRORS:
            return False
        if len(self._chunks) == n:
            return False
        chunk = self._chunks[-1]
        try:
            for mi_at in ci.message_index_offsets.values():
                op, mlen = struct.unpack("<BQ", self._pread(mi_at, 9))
                if op != OP_MESSAGE_INDEX or mi_at + 9 + mlen > limit:
                    raise ValueError("message index missing")
                self._scan_record(OP_MESSAGE_INDEX, mi_at, mi_at + 9, mlen)
        except PARSE_ERRORS:
            chunk.indexed, chunk.index = False, {}  # rebuilt from the chunk's own records
        return True

    def _scan_record(self, opcode: int, pos: int, start: int, length: int) -> None:
        if opcode == OP_CHUNK:
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
        elif opcode == OP_MESSAGE_INDEX:
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
        elif opcode == OP_MESSAGE:
            cid, _seq, log_time = struct.unpack("<HIQ", self._pread(start, 14))
            self._top_messages.setdefault(cid, []).append((log_time, pos))
        elif opcode in (OP_SCHEMA, OP_CHANNEL):
            self._add_def(opcode, self._pread(start, length), overwrite=False)
        elif opcode == OP_ATTACHMENT:
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
        elif opcode == OP_METADATA:
            meta = Metadata.read(ReadDataStream(io.BytesIO(self._pread(start, length))))
            self.metadata[meta.name] = dict(meta.metadata)
        elif opcode == OP_DATA_END:
            (self.data_section_crc,) = struct.unpack("<I", self._pread(start, 4))

    def _add_def(self, opcode: int, content: bytes, *, overwrite: bool) -> None:
        stream = ReadDataStream(io.BytesIO(content))
        if opcode == OP_SCHEMA:
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
            if opcode in (OP_SCHEMA, OP_CHANNEL):
                defs.append(data[pos : pos + 9 + length])
            elif opcode == OP_MESSAGE:
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
            except PARSE_ERRORS as err:
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
                stream = STREAM_OF_TOPIC.get(ch.topic) if ch is not None else None
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
            stream = STREAM_OF_TOPIC.get(ch.topic)
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
            if opcode != OP_MESSAGE or off + 9 + length > self._size or length < 22:
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
            if opcode != OP_MESSAGE or off + 9 + length > len(data) or length < 22:
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
            return typestore().deserialize_cdr(data, typename)
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
        from sea3d.io.session.common import encode_image

        return encode_image(self._raw_to_array(msg, stream, index), "png"), "png"

    def _raw_to_array(self, msg: Any, stream: str, index: int) -> np.ndarray:
        return raw_image_array(msg, self._record_name(stream, index))

    def _read_image(self, stream: str, index: int) -> np.ndarray:
        msg = self._decode(stream, index)
        where = f"{self._record_name(stream, index)} (t_ns={int(self._stamps[stream][index])})"
        if hasattr(msg, "format"):
            return decode_image(np.asarray(msg.data, dtype=np.uint8), where)
        return self._raw_to_array(msg, stream, index)

    def _each(self, stream: str) -> Any:
        """Every readable record of a sample stream, in stamp order. The records of a damaged
        chunk are skipped with one warning for the chunk (its offset and how many), not one
        per record (an IMU chunk holds hundreds)."""
        lost: dict[int, int] = {}  # damaged chunk -> records of this stream skipped in it
        try:
            for i in range(self.stamps(stream).size):
                try:
                    yield i, self._decode(stream, i)
                except SessionError as err:
                    k = int(self._loc[stream][i][0])
                    if k >= 0 and self._chunks[k].damaged is not None:
                        lost[k] = lost.get(k, 0) + 1
                        self.skipped[stream] = self.skipped.get(stream, 0) + 1
                    else:
                        self._skipped(stream, str(err))
        finally:
            for k, n in lost.items():
                c = self._chunks[k]
                _log.warning(
                    "%s topic %s: %d %s in the damaged chunk at byte %d (t_ns %d..%d) skipped",
                    self.path, TOPICS.get(stream, stream), n, "record" if n == 1 else "records",
                    c.file_offset, c.start_ns, c.end_ns,
                )

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
