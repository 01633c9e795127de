"""The writer side of a session: :class:`SessionWriter` checks every record (stream names,
stamps in order, image shapes), encodes images, defers SIGTERM/SIGINT to a safe point, and
hands the records to a storage (:mod:`sea3d.io.session.storage`) chosen by name."""

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
from sea3d.io.session.common import (
    IMAGE_ENCODINGS,
    IMAGE_STREAMS,
    check_encoded_image,
    check_image,
    check_stamp,
    encode_image,
    image_size_of,
)
from sea3d.io.session.reader import layout_of
from sea3d.io.session.storage import STORAGES, StorageWriter, create_storage_writer

__all__ = ["SessionWriter", "check_new_session"]

_log = logging.getLogger(__name__)


def check_new_session(path: str | os.PathLike[str], format: str | None = None) -> None:
    """Refuse, before any work, a session path that :class:`SessionWriter` would refuse.

    Args:
        path: the session to create: an ``.mcap`` file or a folder.
        format: ``"mcap"``, ``"folder"``, or None to choose from the extension.

    Raises:
        SessionError: an MCAP file that exists, a file where a folder session goes, or a
            folder that holds a session already.
    """
    p = Path(path)
    if (format or layout_of(p)) == "mcap":
        if p.exists():
            raise SessionError(f"{p} already exists; refusing to overwrite it")
        return
    if p.exists() and not p.is_dir():
        raise SessionError(f"{p} exists and is not a folder")
    if (p / "session.json").exists() or any(
        (p / s).is_dir() and any((p / s).iterdir()) for s in ("left", "right")
    ):
        raise SessionError(f"{p} already holds a session; refusing to overwrite it")


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
        if self.format not in STORAGES:
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
        self._closed = False
        self._busy = 0
        self._pending_signal: int | None = None
        self._old_handlers: dict[int, Any] = {}
        self._backend: StorageWriter = create_storage_writer(
            self.format,
            self.path,
            rig_yaml,
            image_encoding,
            chunk_size=chunk_size,
            chunk_interval_s=chunk_interval_s,
            chunk_compression=chunk_compression,
            min_free_bytes=min_free_bytes,
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
                if self.image_encoding == "raw":
                    self._backend.write_raw(stream, t_ns, image)
                else:
                    self._backend.write_encoded(
                        stream, t_ns, data, self.image_encoding, image.shape[0], image.shape[1]
                    )
                self._last[stream] = t_ns
        finally:
            self._leave()

    def write_image_bytes(self, stream: str, t_ns: int, data: bytes, fmt: str) -> None:
        """Write an already-encoded PNG, JPEG XL or JPEG image as it is (lossless conversion).

        ``fmt`` must match this writer's ``image_encoding``; the bytes are checked for
        completeness first (:func:`~sea3d.io.session.common.check_encoded_image`), so damage
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
                self._backend.write_encoded(stream, t_ns, data, fmt, height, width)
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
