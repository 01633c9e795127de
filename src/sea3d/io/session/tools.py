"""Whole-session tools: :func:`convert_session` (one storage into the other, damage never
copied) and :func:`verify_session` (read, check and decode everything, list every problem)."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from sea3d.errors import SessionError
from sea3d.io.session.common import (
    IMAGE_STREAMS,
    SessionWriteError,
)
from sea3d.io.session.reader import layout_of, open_session
from sea3d.io.session.writer import SessionWriter

__all__ = ["convert_session", "verify_session"]

_log = logging.getLogger(__name__)


def _remove_output(path: Path) -> None:
    import shutil

    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists():
        path.unlink()


def convert_session(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    image_encoding: str | None = None,
    strict: bool = False,
    progress: Any = None,
) -> dict[str, Any]:
    """Copy a session into the other layout (chosen by ``dst``'s extension).

    PNG, JPEG XL and JPEG images are copied byte for byte when the encoding stays the same
    (after a completeness check), so a lossless session converts losslessly both ways. Damage
    is never copied silently: damaged records are skipped and listed in ``problems``, or, with
    ``strict``, the conversion is refused before anything is left behind.

    Args:
        src: session to read (MCAP file or folder).
        dst: output path; ``*.mcap`` writes MCAP, anything else a folder. Must not exist.
        image_encoding: output encoding; None keeps the source's (png when it is raw and the
            output is a folder).
        strict: refuse (raise, and remove the partial output) at the first damaged record.
        progress: optional callable ``progress(done, total)`` called after each image.

    Returns:
        ``{"left", "right", "imu", "sonar"}`` records written, ``"skipped"`` (damaged records
        left out) and ``"problems"`` (one message per problem, naming file and stamp).

    Raises:
        SessionError: unreadable input, an existing output, or damage with ``strict``;
            :class:`SessionWriteError` when the output cannot be written (disk full...).
    """
    dst_path = Path(dst)
    problems: list[str] = []
    skipped = 0

    def damaged(message: str, records: int = 1) -> None:
        nonlocal skipped
        if strict:
            raise SessionError(f"{message}; refusing to convert a damaged session (strict)")
        problems.append(message)
        skipped += records

    with open_session(src) as reader:
        if strict:
            reader.check()
            if reader.problems:
                raise SessionError(
                    f"{reader.problems[0]}; refusing to convert a damaged session (strict)"
                )
        try:
            rig_yaml = reader.rig_yaml
        except SessionError as err:
            damaged(str(err))
            rig_yaml = None
        enc = image_encoding or reader.image_encoding or "png"
        if enc == "raw" and layout_of(dst_path) == "folder":
            enc = "png"
        if dst_path.exists() and not (dst_path.is_dir() and not any(dst_path.iterdir())):
            raise SessionError(f"{dst_path} already exists; refusing to overwrite it")
        total = sum(int(reader.stamps(s).size) for s in IMAGE_STREAMS)
        done = 0
        writer = SessionWriter(dst_path, rig_yaml=rig_yaml, image_encoding=enc)
        try:
            with writer:
                # The small streams first: a disk that fills up with images keeps them.
                imu = reader.imu()
                for k in range(len(imu)):
                    writer.write_imu(int(imu.t_ns[k]), imu.accel_mps2[k], imu.gyro_radps[k])
                sonar = reader.sonar()
                for k in range(len(sonar)):
                    writer.write_sonar(
                        int(sonar.t_ns[k]), float(sonar.range_m[k]), float(sonar.confidence[k])
                    )
                writer.flush()
                for stream in IMAGE_STREAMS:
                    stamps = reader.stamps(stream)
                    for i in range(stamps.size):
                        t_ns = int(stamps[i])
                        try:
                            data, fmt = reader.image_bytes(stream, i)
                            if fmt == enc:
                                writer.write_image_bytes(stream, t_ns, data, fmt)
                            else:
                                writer.write_image(
                                    stream, t_ns, reader.image(stream, i, by="index")
                                )
                        except SessionWriteError:
                            raise
                        except SessionError as err:
                            damaged(f"{stream} t_ns={t_ns}: {err}")
                        done += 1
                        if progress is not None:
                            progress(done, total)
                for stream, n in reader.skipped.items():
                    if n:
                        damaged(f"{src}: {n} damaged {stream} records left out", n)
                for msg in reader.problems:
                    if msg not in problems:
                        problems.append(msg)
                if strict and reader.problems:
                    raise SessionError(
                        f"{reader.problems[0]}; refusing to convert a damaged session (strict)"
                    )
        except SessionWriteError:
            raise
        except BaseException:
            if strict:
                _remove_output(dst_path)
            raise
        counts: dict[str, Any] = dict(writer.counts)
    counts["skipped"] = skipped
    counts["problems"] = problems
    return counts


class _WarningCollector(logging.Handler):
    def __init__(self) -> None:
        super().__init__(level=logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def verify_session(path: str | os.PathLike[str], *, name_unit: str = "ns") -> dict[str, Any]:
    """Read, check and decode every record of a session and collect every problem found.

    For MCAP files this checks every chunk's CRC and records, the message indexes, the data
    section and summary CRCs, the attachments' CRCs and the summary's record counts; for
    folders the images against ``checksums.csv``. Every image is decoded (incomplete PNG,
    JPEG and JPEG XL data is refused), every IMU and sonar record read, and the stored rig
    parsed and checked as a rig.

    Returns:
        ``{"path", "ok", "records": {stream: readable count}, "problems": [message, ...],
        "damaged_chunks": [{offset, start_ns, end_ns, streams, reason}], "damaged_frames":
        [{stream, t_ns, reason}]}``; each problem names the file or topic and the stamp.

    Raises:
        SessionError: if the path is not a session at all.
    """
    from dataclasses import asdict

    collector = _WarningCollector()
    io_logger = logging.getLogger("sea3d.io")
    io_logger.addHandler(collector)
    # The verdict must not depend on the caller's logging set-up: warnings reach the collector
    # even where the application logs only errors or called logging.disable, and only the
    # collector (they come back in "problems").
    old_level, old_propagate = io_logger.level, io_logger.propagate
    old_disable = logging.root.manager.disable
    if io_logger.getEffectiveLevel() > logging.WARNING:
        io_logger.setLevel(logging.WARNING)
    io_logger.propagate = False
    if old_disable >= logging.WARNING:
        logging.disable(logging.NOTSET)
    problems: list[str] = []
    records: dict[str, int] = {}
    frames: list[dict[str, Any]] = []
    chunks: list[dict[str, Any]] = []
    try:
        with open_session(path, name_unit=name_unit) as reader:
            reader.check()
            for stream in IMAGE_STREAMS:
                ok = 0
                stamps = reader.stamps(stream)
                for i in range(stamps.size):
                    try:
                        reader.image(stream, i, by="index")
                        ok += 1
                    except SessionError as err:
                        problems.append(str(err))
                        frames.append(
                            {"stream": stream, "t_ns": int(stamps[i]), "reason": str(err)}
                        )
                records[stream] = ok
            records["imu"] = len(reader.imu())
            records["sonar"] = len(reader.sonar())
            try:
                _ = reader.rig_yaml  # parsed and checked as a rig; a problem if unusable
            except SessionError as err:
                problems.append(str(err))
            chunks = [asdict(c) for c in reader.damaged_chunks]
            for c in chunks:
                c["streams"] = list(c["streams"])
            problems = reader.problems + problems
            for stream, n in reader.skipped.items():
                if n:
                    problems.append(f"{path}: {n} damaged {stream} records skipped")
    finally:
        io_logger.removeHandler(collector)
        io_logger.setLevel(old_level)
        io_logger.propagate = old_propagate
        if old_disable >= logging.WARNING:
            logging.disable(old_disable)
    seen: set[str] = set()
    unique = []
    for msg in collector.messages + problems:
        if msg not in seen:
            seen.add(msg)
            unique.append(msg)
    return {
        "path": os.fspath(path),
        "ok": not unique,
        "records": records,
        "problems": unique,
        "damaged_chunks": chunks,
        "damaged_frames": frames,
    }
