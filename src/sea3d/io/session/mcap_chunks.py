"""The MCAP file layout as sea3d writes it: an unbuffered file sink that rolls back a failed
write, and chunks that carry their own schemas and channels and count as written only once
they reached the file (see :mod:`sea3d.io.session.storage_mcap` for why)."""

from __future__ import annotations

import logging
import os
import struct
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mcap.data_stream import RecordBuilder
from mcap.exceptions import McapError
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from sea3d.errors import ReserveReached, SessionError
from sea3d.io.session.common import (
    SessionWriteError,
)

_log = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT = 0x06, 0x07, 0x08, 0x09
OP_ATTACHMENT_INDEX, OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX = 0x0A, 0x0B, 0x0C, 0x0D
OP_SUMMARY_OFFSET, OP_DATA_END = 0x0E, 0x0F
MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, length, channel, sequence, log, publish
CHUNK_HEAD = struct.Struct("<BQQQQI")  # opcode, length, start, end, uncompressed size, crc
# What parsing a damaged record can raise (mcap's readers raise EndOfFile, a McapError).
PARSE_ERRORS = (struct.error, ValueError, UnicodeDecodeError, EOFError, OverflowError, McapError)
# A chunk's records are decompressed into memory: refuse absurd sizes (a damaged header)
# instead of allocating them. Our chunks are a few MiB.
MAX_CHUNK_BYTES = 1 << 30
MAX_SUMMARY_BYTES = 256 << 20  # a day of recording has a summary of about 13 MB


def record_bytes(record: Any) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return bytes(builder.end())


# ----------------------------------------------------------------------------- writer


class FdWriter:
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


class ChunkedMcap:
    """The MCAP file layout: header, top-level attachments and metadata, chunks with their
    message indexes, then data end, summary and footer (not public).

    Every byte goes through :meth:`_commit`, which keeps the statistics and indexes of the
    summary in step with what actually reached the file.
    """

    def __init__(
        self,
        out: FdWriter,
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
        self._commit([MCAP_MAGIC, record_bytes(Header(profile=profile, library=library))])

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self.schemas) + 1
        schema = Schema(id=sid, name=name, encoding=encoding, data=data)
        self.schemas[sid] = schema
        self._schema_bytes[sid] = record_bytes(schema)
        return sid

    def add_channel(self, topic: str, encoding: str, schema_id: int) -> int:
        cid = len(self.channels) + 1
        channel = Channel(
            id=cid, topic=topic, message_encoding=encoding, schema_id=schema_id, metadata={}
        )
        self.channels[cid] = channel
        self._channel_bytes[cid] = record_bytes(channel)
        self._sequence[cid] = 0
        return cid

    def add_attachment(self, name: str, media_type: str, data: bytes, t_ns: int) -> None:
        self.flush_chunk()
        record = record_bytes(
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
        record = record_bytes(Metadata(name=name, metadata=values))
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
            buf += MESSAGE_HEAD.pack(
                OP_MESSAGE, 22 + len(data), cid, seq & 0xFFFFFFFF, log_time, log_time
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
        head = CHUNK_HEAD.pack(OP_CHUNK, body_len, start, end, len(buf), crc)
        head += struct.pack("<I", len(comp)) + comp + struct.pack("<Q", len(payload))
        chunk_length = len(head) + len(payload)
        parts: list[bytes | bytearray] = [head, payload]
        offsets: dict[int, int] = {}
        rel = chunk_length
        for cid, entries in index.items():
            rec = record_bytes(MessageIndex(channel_id=cid, records=entries))
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
            OSError, ReserveReached: the write failed; the file ends after its last complete
                chunk.
        """
        messages = self.pending
        self._reset_chunk()
        if not messages:
            return
        try:
            self._write_chunk(messages)
        except (OSError, ReserveReached) as err:
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
        except (OSError, ReserveReached):
            return self._salvage(messages[:half])
        try:
            self._write_chunk(messages[half:])
        except (OSError, ReserveReached):
            return half + self._salvage(messages[half:])
        return len(messages)

    def discard_chunk(self) -> None:
        self._reset_chunk()

    # -- end ---------------------------------------------------------------------------------
    def finish(self) -> None:
        """Data end, summary (schemas, channels, statistics, indexes) and footer."""
        data_end = record_bytes(DataEnd(data_section_crc=0))
        # The data section CRC covers everything before the DataEnd record.
        data_end = data_end[:9] + struct.pack("<I", self.data_crc)
        self._commit([data_end])
        summary_start = self.out.pos
        groups: list[tuple[int, list[bytes]]] = [
            (OP_SCHEMA, list(self._schema_bytes.values())),
            (OP_CHANNEL, list(self._channel_bytes.values())),
            (
                OP_STATISTICS,
                [
                    record_bytes(
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
            (OP_CHUNK_INDEX, [record_bytes(c) for c in self.chunk_indexes]),
            (OP_ATTACHMENT_INDEX, [record_bytes(a) for a in self.attachment_indexes]),
            (OP_METADATA_INDEX, [record_bytes(m) for m in self.metadata_indexes]),
        ]
        parts: list[bytes] = []
        offsets: list[bytes] = []
        pos = summary_start
        for opcode, records in groups:
            if not records:
                continue
            length = sum(len(r) for r in records)
            offsets.append(
                record_bytes(
                    SummaryOffset(group_opcode=opcode, group_start=pos, group_length=length)
                )
            )
            parts.extend(records)
            pos += length
        offset_start = pos
        parts.extend(offsets)
        footer_head = struct.pack("<BQQQ", OP_FOOTER, 20, summary_start, offset_start)
        crc = 0
        for p in parts:
            crc = zlib.crc32(p, crc)
        crc = zlib.crc32(footer_head, crc)
        self._commit([*parts, footer_head, struct.pack("<I", crc), MCAP_MAGIC])


