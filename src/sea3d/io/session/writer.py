"""Recorded sessions: one writer and one reader interface over two layouts.

- An MCAP file of ROS 2 messages (``*.mcap``), readable by other ROS 2 tools; see
  :mod:`sea3d.io.session_mcap` for topics and types.
- The paper's folder layout (``left/<t_ns>.png``, ``right/<t_ns>.png``, ``imu.csv``,
  ``sonar.csv``, ``rig.yaml``, ``session.json``); see :mod:`sea3d.io.session_folder`.

Write::

    with SessionWriter("dive.mcap", rig_yaml=rig_text) as w:
        w.write_stereo(t_ns, left_rgb, right_rgb)
        w.write_imu(t_ns, accel_mps2, gyro_radps)
        w.write_sonar(t_ns, range_m, confidence)

Read::

    with open_session("dive.mcap") as s:
        for pair in s.pairs():          # nearest stamps within half a frame interval
            ...
        imu = s.imu()                   # ImuSeries: t_ns (N,), accel_mps2 (N,3), gyro_radps (N,3)

Stamps are integer nanoseconds. Within one stream the writer accepts only increasing stamps;
readers sort what they find and warn about duplicates and disorder.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np

from sea3d.errors import SessionError
from sea3d.io.session_common import (
    IMAGE_ENCODINGS,
    IMAGE_STREAMS,
    ImuSample,
    ImuSeries,
    PairMatch,
    SessionReader,
    SessionWriteError,
    SonarSample,
    SonarSeries,
    StereoPair,
    check_encoded_image,
    check_image,
    check_stamp,
    encode_image,
    image_size_of,
)

__all__ = [
    "ImuSample",
    "ImuSeries",
    "PairMatch",
    "SessionReader",
    "SessionWriteError",
    "SessionWriter",
    "SonarSample",
    "SonarSeries",
    "StereoPair",
    "convert_session",
    "layout_of",
    "open_session",
    "verify_session",
]

_log = logging.getLogger(__name__)


def layout_of(path: str | os.PathLike[str]) -> str:
    """``"mcap"`` for a path ending in ``.mcap``, ``"folder"`` otherwise."""
    return "mcap" if os.fspath(path).lower().endswith(".mcap") else "folder"


def open_session(path: str | os.PathLike[str], *, name_unit: str = "ns") -> SessionReader:
    """Open a recorded session, choosing the reader from what ``path`` is.

    Args:
        path: an ``.mcap`` file (or any file starting with the MCAP magic) or a session folder.
        name_unit: for folders only: unit of the numbers in image file names, ``"ns"`` or
            ``"us"`` (the paper's recordings use microseconds).

    Returns:
        A :class:`SessionReader`; use it as a context manager.

    Raises:
        SessionError: if the path does not exist or is neither an MCAP file nor a session folder.
    """
    p = Path(path)
    if p.is_dir():
        from sea3d.io.session_folder import FolderSessionReader

        return FolderSessionReader(p, name_unit=name_unit)
    if p.is_file():
        from sea3d.io.session_mcap import McapSessionReader

        return McapSessionReader(p)
    raise SessionError(f"session {p} does not exist")


class SessionWriter:
    """Write a session as an MCAP file or a folder, whichever ``format`` says.

    Thread-safe: the recorder's capture and encoder threads may call the ``write_*`` methods
    concurrently. Within one stream, stamps must increase.

    While open, SIGTERM (and SIGINT) are turned into exceptions at a safe point between two
    records, so ``with SessionWriter(...)`` closes the file properly when the process is asked
    to stop (only when created in the main thread and the signal has its default handler).

    Args:
        path: output file (``.mcap``) or folder; must not hold a session already.
        format: ``"mcap"``, ``"folder"``, or None to choose from the extension.
        rig_yaml: the rig file's YAML text, stored with the session.
        image_encoding: ``"png"`` (lossless), ``"jxl"`` (JPEG XL, lossless, about 5x less
            CPU than PNG and half its size), ``"jpeg"`` (lossy), or ``"raw"`` (MCAP only:
            ``sensor_msgs/Image`` in LZ4-compressed chunks).
        png_compression: zlib level 0..9 for PNG.
        jpeg_quality: 0..100 for JPEG.
        chunk_size: MCAP only: close a chunk after this many bytes.
        chunk_interval_s: MCAP only: close a chunk at least this often (bounds what SIGKILL loses).
        chunk_compression: MCAP only: ``"none"``, ``"lz4"`` or ``"zstd"`` (level 1); None: LZ4
            for raw images, none for encoded ones (they do not compress further).
        min_free_bytes: refuse any write that would leave less free disk space than this
            (:class:`SessionWriteError`); 0 writes until the disk is full.
        handle_signals: install the SIGTERM/SIGINT handlers described above.

    ``counts`` holds the records per stream that reached the disk (for MCAP: whose chunk was
    written), so it always equals what a reader finds.

    Raises:
        SessionError: for an unknown format or encoding, an invalid ``rig_yaml``, or an output
            that already exists; :class:`SessionWriteError` when the output cannot be created.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        format: str | None = None,
        rig_yaml: str | None = None,
        image_encoding: str = "png",
        *,
        png_compression: int = 1,
        jpeg_quality: int = 95,
        chunk_size: int = 4 << 20,
        chunk_interval_s: float = 1.0,
        chunk_compression: str | None = None,
        min_free_bytes: int = 0,
        handle_signals: bool = True,
    ) -> None:
        self.path = Path(path)
        self.format = format or layout_of(self.path)
        if self.format not in ("mcap", "folder"):
            raise SessionError(f"format must be 'mcap' or 'folder', got {self.format!r}")
        if self.format == "folder" and image_encoding == "raw":
            raise SessionError(
                f"{self.path}: a folder session stores png, jxl or jpeg images, not 'raw'"
            )
        if image_encoding not in IMAGE_ENCODINGS:
            raise SessionError(
                f"image_encoding must be one of {IMAGE_ENCODINGS}, got {image_encoding!r}"
            )
        if rig_yaml is not None and not isinstance(rig_yaml, str):
            raise SessionError(
                f"rig_yaml must be the YAML text (str), got {type(rig_yaml).__name__}"
            )
        self.image_encoding = image_encoding
        self.png_compression = int(png_compression)
        self.jpeg_quality = int(jpeg_quality)
        self._lock = threading.RLock()
        self._last: dict[str, int] = {}
        self._shape: dict[str, tuple[tuple[int, ...], np.dtype]] = {}
        self._closed = False
        self._busy = 0
        self._pending_signal: int | None = None
        self._old_handlers: dict[int, Any] = {}
        self._backend: Any
        if self.format == "mcap":
            from sea3d.io.session_mcap import McapSessionWriter

            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise SessionWriteError(
                    f"cannot create {self.path.parent}: {err.strerror or err}", kept=""
                ) from err
            self._backend = McapSessionWriter(
                self.path,
                rig_yaml,
                image_encoding,
                chunk_size=chunk_size,
                chunk_interval_s=chunk_interval_s,
                chunk_compression=chunk_compression,
                min_free_bytes=min_free_bytes,
            )
        else:
            from sea3d.io.session_folder import FolderSessionWriter

            if rig_yaml is not None:
                from sea3d.io.session_mcap import _camera_info_params

                _camera_info_params(rig_yaml, self.path)  # the same check as for MCAP
            try:
                self.path.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise SessionWriteError(
                    f"cannot create {self.path}: {err.strerror or err}", kept=""
                ) from err
            self._backend = FolderSessionWriter(
                self.path, rig_yaml, image_encoding, min_free_bytes=min_free_bytes
            )
        if handle_signals:
            self._install_signal_handlers()

    # -- signals ----------------------------------------------------------------------------
    def _install_signal_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig, default in (
            (signal.SIGTERM, signal.SIG_DFL),
            (signal.SIGINT, signal.default_int_handler),
        ):
            if signal.getsignal(sig) is default:
                self._old_handlers[sig] = signal.signal(sig, self._on_signal)

    def _restore_signal_handlers(self) -> None:
        for sig, old in self._old_handlers.items():
            try:
                signal.signal(sig, old)
            except ValueError:  # not the main thread
                pass
        self._old_handlers.clear()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        del frame
        if self._busy:
            self._pending_signal = signum
            return
        self._raise_for(signum)

    @staticmethod
    def _raise_for(signum: int) -> None:
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)

    def _enter(self) -> None:
        if self._closed:
            raise SessionError(f"{self.path}: session writer is closed")
        # Signal handlers run in the main thread: only its writes defer a signal.
        if threading.current_thread() is threading.main_thread():
            self._busy += 1

    def _leave(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        self._busy -= 1
        if self._pending_signal is not None and not self._busy:
            signum, self._pending_signal = self._pending_signal, None
            self._raise_for(signum)

    def _check_order(self, stream: str, t_ns: int) -> None:
        last = self._last.get(stream)
        if last is not None and t_ns <= last:
            kind = "duplicate" if t_ns == last else "out-of-order"
            raise SessionError(f"{self.path}: {kind} {stream} stamp t_ns={t_ns} (previous {last})")

    # -- writing ------------------------------------------------------------------------------
    @property
    def counts(self) -> dict[str, int]:
        """Records per stream that reached the disk (what a reader will find)."""
        return {s: int(self._backend.committed(s)) for s in ("left", "right", "imu", "sonar")}

    def encode(self, image: np.ndarray) -> bytes:
        """Encode an image with this writer's settings (thread-safe, no lock held).

        Returns PNG, JPEG XL or JPEG bytes; for ``image_encoding="raw"`` returns b"".
        """
        if self.image_encoding == "raw":
            return b""
        return encode_image(
            image,
            self.image_encoding,
            png_compression=self.png_compression,
            jpeg_quality=self.jpeg_quality,
        )

    def write_image(
        self, stream: str, t_ns: int, image: np.ndarray, *, encoded: bytes | None = None
    ) -> None:
        """Write one camera image.

        Args:
            stream: ``"left"`` or ``"right"``.
            t_ns: stamp in nanoseconds, greater than the stream's previous stamp.
            image: (H, W) or (H, W, 3) RGB, uint8 or uint16; same size and dtype for the whole
                stream.
            encoded: the image already encoded by :meth:`encode` (lets worker threads encode).

        Raises:
            SessionError: unknown stream, bad image, size change, or a stamp not increasing.
            SessionWriteError: the disk is full, at the reserve, or failing; what was
                written before stays readable (the error says what).
        """
        if stream not in IMAGE_STREAMS:
            raise SessionError(f"unknown image stream {stream!r}; expected one of {IMAGE_STREAMS}")
        t_ns = check_stamp(t_ns, f"{stream} image")
        image = check_image(image, f"{stream} image at t_ns={t_ns}")
        ref = self._shape.setdefault(stream, (image.shape, image.dtype))
        if image.shape != ref[0] or image.dtype != ref[1]:
            raise SessionError(
                f"{stream} image at t_ns={t_ns} is {image.shape} {image.dtype}; "
                f"this stream's images are {ref[0]} {ref[1]}"
            )
        data = encoded if encoded is not None else self.encode(image)
        self._enter()
        try:
            with self._lock:
                self._check_order(stream, t_ns)
                if self.format == "mcap":
                    if self.image_encoding == "raw":
                        self._backend.write_raw(stream, t_ns, image)
                    else:
                        self._backend.write_encoded(
                            stream, t_ns, data, self.image_encoding, image.shape[0], image.shape[1]
                        )
                else:
                    self._backend.write_encoded(stream, t_ns, data)
                self._last[stream] = t_ns
        finally:
            self._leave()

    def write_image_bytes(self, stream: str, t_ns: int, data: bytes, fmt: str) -> None:
        """Write an already-encoded PNG, JPEG XL or JPEG image as it is (lossless conversion).

        ``fmt`` must match this writer's ``image_encoding``; the bytes are checked for
        completeness first (:func:`~sea3d.io.session_common.check_encoded_image`), so damage
        is never copied.

        Raises:
            SessionError: unknown stream, format mismatch, incomplete or damaged bytes, or a
                stamp not increasing.
        """
        if stream not in IMAGE_STREAMS:
            raise SessionError(f"unknown image stream {stream!r}; expected one of {IMAGE_STREAMS}")
        t_ns = check_stamp(t_ns, f"{stream} image")
        if fmt != self.image_encoding:
            raise SessionError(f"cannot store {fmt} bytes in a {self.image_encoding} session")
        where = f"{stream} image at t_ns={t_ns}"
        found = check_encoded_image(data, where)
        if found != fmt:
            raise SessionError(f"{where}: the bytes are {found}, not {fmt}")
        width, height = image_size_of(data, fmt, where)
        self._enter()
        try:
            with self._lock:
                self._check_order(stream, t_ns)
                if self.format == "mcap":
                    self._backend.write_encoded(stream, t_ns, data, fmt, height, width)
                else:
                    self._backend.write_encoded(stream, t_ns, data)
                self._last[stream] = t_ns
        finally:
            self._leave()

    def write_stereo(self, t_ns: int, left: np.ndarray, right: np.ndarray) -> None:
        """Write a synchronised pair: both images get stamp ``t_ns``."""
        self.write_image("left", t_ns, left)
        self.write_image("right", t_ns, right)

    def write_imu(self, t_ns: int, accel_mps2: Any, gyro_radps: Any) -> None:
        """Write one IMU sample.

        Args:
            t_ns: stamp in nanoseconds, increasing.
            accel_mps2: (3,) specific force in m/s^2, IMU frame.
            gyro_radps: (3,) angular rate in rad/s, IMU frame.

        Raises:
            SessionError: wrong shapes or a stamp not increasing (NaN readings are kept).
        """
        t_ns = check_stamp(t_ns, "imu sample")
        acc = np.asarray(accel_mps2, dtype=np.float64).reshape(-1)
        gyr = np.asarray(gyro_radps, dtype=np.float64).reshape(-1)
        if acc.shape != (3,) or gyr.shape != (3,):
            raise SessionError(
                f"imu sample at t_ns={t_ns}: expected (3,) accel and gyro, "
                f"got {acc.shape} and {gyr.shape}"
            )
        self._enter()
        try:
            with self._lock:
                self._check_order("imu", t_ns)
                self._backend.write_imu(t_ns, acc, gyr)
                self._last["imu"] = t_ns
        finally:
            self._leave()

    def write_sonar(self, t_ns: int, range_m: float, confidence: float = float("nan")) -> None:
        """Write one echosounder reading (range and confidence are stored as float32).

        Raises:
            SessionError: a stamp not increasing.
        """
        t_ns = check_stamp(t_ns, "sonar sample")
        self._enter()
        try:
            with self._lock:
                self._check_order("sonar", t_ns)
                self._backend.write_sonar(t_ns, np.float32(range_m), np.float32(confidence))
                self._last["sonar"] = t_ns
        finally:
            self._leave()

    def flush(self) -> None:
        """Push everything written so far to the OS (closes the open MCAP chunk).

        Raises:
            SessionWriteError: the open chunk could not be written.
        """
        with self._lock:
            self._backend.flush()

    @property
    def bytes_written(self) -> int:
        """Payload bytes written so far (images, messages, CSV lines)."""
        return int(self._backend.bytes_written)

    def close(self) -> None:
        """Finish the session (MCAP summary / session.json). Safe to call twice.

        Raises:
            SessionWriteError: the last records or the summary could not be written; the
                file keeps everything written before (readable without a summary).
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._backend.close(dict(self.counts))
            finally:
                self._restore_signal_handlers()
        _log.info("wrote %s: %s", self.path, self.counts)

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc is None:
            self.close()
            return
        try:  # an error is on its way already: close as well as possible, keep that error
            self.close()
        except SessionError as err:
            _log.warning("%s", err)


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
            raise SessionError(f"{message}; refusing to convert a damaged session (--strict)")
        problems.append(message)
        skipped += records

    with open_session(src) as reader:
        if strict:
            check = getattr(reader, "check", None)
            if check is not None:
                check()
            if reader.problems:
                raise SessionError(
                    f"{reader.problems[0]}; refusing to convert a damaged session (--strict)"
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
                        f"{reader.problems[0]}; refusing to convert a damaged session (--strict)"
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
            check = getattr(reader, "check", None)
            if check is not None:
                check()
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
            chunks = [asdict(c) for c in getattr(reader, "damaged_chunks", [])]
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
