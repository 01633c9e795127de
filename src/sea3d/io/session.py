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
    SonarSample,
    SonarSeries,
    StereoPair,
    check_image,
    check_stamp,
    encode_image,
    png_size,
)

__all__ = [
    "ImuSample",
    "ImuSeries",
    "PairMatch",
    "SessionReader",
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
        image_encoding: ``"png"`` (lossless), ``"jpeg"``, or ``"raw"`` (MCAP only:
            ``sensor_msgs/Image``).
        png_compression: zlib level 0..9 for PNG.
        jpeg_quality: 0..100 for JPEG.
        chunk_size: MCAP only: close a chunk after this many bytes.
        chunk_interval_s: MCAP only: close a chunk at least this often (bounds what SIGKILL loses).
        handle_signals: install the SIGTERM/SIGINT handlers described above.

    Raises:
        SessionError: for an unknown format or encoding, or an output that already exists.
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
        handle_signals: bool = True,
    ) -> None:
        self.path = Path(path)
        self.format = format or layout_of(self.path)
        if self.format not in ("mcap", "folder"):
            raise SessionError(f"format must be 'mcap' or 'folder', got {self.format!r}")
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
        self.counts: dict[str, int] = {"left": 0, "right": 0, "imu": 0, "sonar": 0}
        self._closed = False
        self._busy = 0
        self._pending_signal: int | None = None
        self._old_handlers: dict[int, Any] = {}
        self._backend: Any
        if self.format == "mcap":
            from sea3d.io.session_mcap import McapSessionWriter

            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._backend = McapSessionWriter(
                self.path,
                rig_yaml,
                image_encoding,
                chunk_size=chunk_size,
                chunk_interval_s=chunk_interval_s,
            )
        else:
            from sea3d.io.session_folder import FolderSessionWriter

            self._backend = FolderSessionWriter(self.path, rig_yaml, image_encoding)
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
    def encode(self, image: np.ndarray) -> bytes:
        """Encode an image with this writer's settings (thread-safe, no lock held).

        Returns PNG or JPEG bytes; for ``image_encoding="raw"`` returns b"" (nothing to do).
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
                self.counts[stream] += 1
        finally:
            self._leave()

    def write_image_bytes(self, stream: str, t_ns: int, data: bytes, fmt: str) -> None:
        """Write an already-encoded PNG or JPEG image as it is (used for lossless conversion).

        ``fmt`` must match this writer's ``image_encoding``.

        Raises:
            SessionError: unknown stream, format mismatch, or a stamp not increasing.
        """
        if stream not in IMAGE_STREAMS:
            raise SessionError(f"unknown image stream {stream!r}; expected one of {IMAGE_STREAMS}")
        t_ns = check_stamp(t_ns, f"{stream} image")
        if fmt != self.image_encoding:
            raise SessionError(f"cannot store {fmt} bytes in a {self.image_encoding} session")
        size = png_size(data) if fmt == "png" else None
        if size is None:
            from sea3d.io.session_common import decode_image

            img = decode_image(data, f"{stream} image at t_ns={t_ns}")
            size = (img.shape[1], img.shape[0])
        self._enter()
        try:
            with self._lock:
                self._check_order(stream, t_ns)
                if self.format == "mcap":
                    self._backend.write_encoded(stream, t_ns, data, fmt, size[1], size[0])
                else:
                    self._backend.write_encoded(stream, t_ns, data)
                self._last[stream] = t_ns
                self.counts[stream] += 1
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
                self.counts["imu"] += 1
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
                self.counts["sonar"] += 1
        finally:
            self._leave()

    def flush(self) -> None:
        """Push everything written so far to the OS (closes the open MCAP chunk)."""
        with self._lock:
            self._backend.flush()

    @property
    def bytes_written(self) -> int:
        """Payload bytes written so far (images, messages, CSV lines)."""
        return int(self._backend.bytes_written)

    def close(self) -> None:
        """Finish the session (MCAP summary / session.json). Safe to call twice."""
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

    def __exit__(self, *exc: object) -> None:
        self.close()


def convert_session(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    *,
    image_encoding: str | None = None,
) -> dict[str, int]:
    """Copy a session into the other layout (chosen by ``dst``'s extension).

    PNG and JPEG images are copied byte for byte when the encoding stays the same, so a PNG
    session converts losslessly both ways. Damaged records are skipped with a warning.

    Args:
        src: session to read (MCAP file or folder).
        dst: output path; ``*.mcap`` writes MCAP, anything else a folder. Must not exist.
        image_encoding: output encoding; None keeps the source's (png when it is raw and the
            output is a folder).

    Returns:
        Counts of records written per stream, plus ``skipped``.

    Raises:
        SessionError: unreadable input or an existing output.
    """
    skipped = 0
    with open_session(src) as reader:
        enc = image_encoding
        if enc is None:
            enc = str(getattr(reader, "meta", {}).get("image_encoding", "")) or None
        if enc is None:
            enc = getattr(reader, "metadata", {}).get("sea3d", {}).get("image_encoding", "png")
        if enc == "raw" and layout_of(dst) == "folder":
            enc = "png"
        with SessionWriter(dst, rig_yaml=reader.rig_yaml, image_encoding=enc) as writer:
            for stream in IMAGE_STREAMS:
                stamps = reader.stamps(stream)
                for i in range(stamps.size):
                    t_ns = int(stamps[i])
                    try:
                        data, fmt = reader.image_bytes(stream, i)
                        if fmt == enc:
                            writer.write_image_bytes(stream, t_ns, data, fmt)
                        else:
                            writer.write_image(stream, t_ns, reader.image(stream, i, by="index"))
                    except SessionError as err:
                        _log.warning("convert: skipping %s t_ns=%d: %s", stream, t_ns, err)
                        skipped += 1
            imu = reader.imu()
            for k in range(len(imu)):
                writer.write_imu(int(imu.t_ns[k]), imu.accel_mps2[k], imu.gyro_radps[k])
            sonar = reader.sonar()
            for k in range(len(sonar)):
                writer.write_sonar(
                    int(sonar.t_ns[k]), float(sonar.range_m[k]), float(sonar.confidence[k])
                )
            counts = dict(writer.counts)
    counts["skipped"] = skipped
    return counts


class _WarningCollector(logging.Handler):
    def __init__(self) -> None:
        super().__init__(level=logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def verify_session(path: str | os.PathLike[str], *, name_unit: str = "ns") -> dict[str, Any]:
    """Read and decode every record of a session and collect every problem found.

    Returns:
        ``{"path", "ok", "records": {stream: readable count}, "problems": [message, ...]}``;
        each problem names the file or topic and the stamp (truncation, damaged chunks,
        undecodable images, size changes, bad CSV lines, duplicate or disordered stamps).

    Raises:
        SessionError: if the path is not a session at all.
    """
    collector = _WarningCollector()
    io_logger = logging.getLogger("sea3d.io")
    io_logger.addHandler(collector)
    problems: list[str] = []
    records: dict[str, int] = {}
    try:
        with open_session(path, name_unit=name_unit) as reader:
            for stream in IMAGE_STREAMS:
                ok = 0
                for i in range(reader.stamps(stream).size):
                    try:
                        reader.image(stream, i, by="index")
                        ok += 1
                    except SessionError as err:
                        problems.append(str(err))
                records[stream] = ok
            records["imu"] = len(reader.imu())
            records["sonar"] = len(reader.sonar())
    finally:
        io_logger.removeHandler(collector)
    problems = collector.messages + problems
    return {"path": os.fspath(path), "ok": not problems, "records": records, "problems": problems}
