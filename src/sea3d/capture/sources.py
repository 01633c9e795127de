"""Live and replay sources behind one interface.

A :class:`Source` yields records one at a time from :meth:`Source.read` until it returns None
(end of stream). Image sources yield :class:`ImageFrame` (RGB, integer-nanosecond stamp); IMU
sources yield :class:`~sea3d.io.session.ImuSample`; echosounder sources yield
:class:`~sea3d.io.session.SonarSample`. The recorder runs each source in its own thread.

Live cameras stamp frames with the host clock (``time.time_ns``) right after the grab, as the
paper's recorder did; replay sources keep the stamps they read (file names, session stamps,
video positions) and can pace themselves to real time.
"""

from __future__ import annotations

import importlib
import logging
import os
import re
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from sea3d.errors import CaptureError
from sea3d.io.session import ImuSample, SonarSample

__all__ = [
    "ArraySource",
    "CallableSource",
    "ImageFolderSource",
    "ImageFrame",
    "OpenCVCameraSource",
    "Record",
    "SessionReplaySource",
    "Source",
    "VideoFileSource",
    "gstreamer_available",
]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ImageFrame:
    """One camera frame.

    Attributes:
        t_ns: stamp in integer nanoseconds.
        image: (H, W) or (H, W, 3) RGB, uint8 or uint16.
    """

    t_ns: int
    image: np.ndarray = field(repr=False)


Record = ImageFrame | ImuSample | SonarSample


class Source(ABC):
    """A stream of records; ``kind`` is ``"image"``, ``"imu"`` or ``"sonar"``.

    Use as a context manager (``open``/``close``) and call :meth:`read` until it returns None.
    """

    kind: str = "image"

    def __init__(self, name: str) -> None:
        self.name = name

    def open(self) -> None:  # noqa: B027 - optional hook
        """Acquire the device or file. Raises CaptureError when it cannot be opened."""

    @abstractmethod
    def read(self) -> Record | None:
        """The next record (blocking until it is there), or None at the end of the stream.

        Raises:
            CaptureError: when the device fails in a way that will not recover.
        """

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the device or file."""

    def __enter__(self) -> Source:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[Record]:
        while (rec := self.read()) is not None:
            yield rec

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


class _Pacer:
    """Sleep so that stamps are delivered at ``speed`` times real time (0: no pacing)."""

    def __init__(self, speed: float) -> None:
        if speed < 0:
            raise CaptureError(f"replay speed must be >= 0, got {speed}")
        self.speed = speed
        self.t0_stamp: int | None = None
        self.t0_wall = 0.0

    def wait(self, t_ns: int) -> None:
        if self.speed == 0:
            return
        now = time.monotonic()
        if self.t0_stamp is None:
            self.t0_stamp, self.t0_wall = t_ns, now
            return
        due = self.t0_wall + (t_ns - self.t0_stamp) * 1e-9 / self.speed
        if due > now:
            time.sleep(due - now)


def gstreamer_available() -> bool:
    """True when this OpenCV build can open GStreamer pipelines."""
    m = re.search(r"GStreamer:\s*(\w+)", cv2.getBuildInformation())
    return bool(m and m.group(1).upper() == "YES")


def _to_rgb(frame: np.ndarray) -> np.ndarray:
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
    if frame.ndim == 3 and frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2RGB)
    if frame.ndim == 3 and frame.shape[2] == 1:
        return frame[:, :, 0]
    return frame


class OpenCVCameraSource(Source):
    """A live camera through OpenCV: a V4L2 device, a camera index or a GStreamer pipeline.

    Args:
        device: ``/dev/videoN``, an index, or a GStreamer pipeline string ending in ``appsink``.
        api: ``"v4l2"``, ``"gstreamer"``, ``"ffmpeg"`` or ``"any"`` (default: GStreamer for a
            string containing ``!``, V4L2 for ``/dev/video*``, otherwise any).
        width, height, fps: requested capture mode (None leaves the device's default).
        fourcc: requested pixel format, e.g. ``"MJPG"``.
        max_failures: consecutive failed grabs before the camera counts as lost.
        clock: stamp source in nanoseconds (default ``time.time_ns``).

    Raises:
        CaptureError: from :meth:`open` if the device cannot be opened (GStreamer missing from
            the OpenCV build is named), from :meth:`read` when the camera is lost.
    """

    kind = "image"
    _APIS: ClassVar[dict[str, int]] = {
        "any": cv2.CAP_ANY,
        "v4l2": cv2.CAP_V4L2,
        "gstreamer": cv2.CAP_GSTREAMER,
        "ffmpeg": cv2.CAP_FFMPEG,
    }

    def __init__(
        self,
        device: str | int,
        *,
        api: str | None = None,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        fourcc: str | None = None,
        max_failures: int = 30,
        clock: Callable[[], int] = time.time_ns,
        name: str | None = None,
    ) -> None:
        super().__init__(name or str(device))
        if api is None:
            if isinstance(device, str) and "!" in device:
                api = "gstreamer"
            elif isinstance(device, str) and device.startswith("/dev/video"):
                api = "v4l2"
            else:
                api = "any"
        if api not in self._APIS:
            raise CaptureError(f"unknown capture api {api!r}; expected one of {sorted(self._APIS)}")
        self.device, self.api = device, api
        self.width, self.height, self.fps, self.fourcc = width, height, fps, fourcc
        self.max_failures = int(max_failures)
        self.clock = clock
        self._cap: Any = None
        self._failures = 0

    def open(self) -> None:
        if self.api == "gstreamer" and not gstreamer_available():
            raise CaptureError(
                f"cannot open GStreamer pipeline {self.device!r}: this OpenCV build has no "
                "GStreamer support (cv2.getBuildInformation() says GStreamer: NO); use a V4L2 "
                "device or an OpenCV build with GStreamer"
            )
        cap = cv2.VideoCapture(self.device, self._APIS[self.api])
        if not cap.isOpened():
            raise CaptureError(f"cannot open camera {self.device!r} with api {self.api}")
        if self.fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc[:4]))
        if self.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        if self.fps:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        self._cap = cap

    def read(self) -> ImageFrame | None:
        if self._cap is None:
            self.open()
        while True:
            ok = self._cap.grab()
            t_ns = self.clock()
            if ok:
                ok, frame = self._cap.retrieve()
            if ok and frame is not None:
                self._failures = 0
                return ImageFrame(t_ns, _to_rgb(frame))
            self._failures += 1
            if self._failures >= self.max_failures:
                raise CaptureError(
                    f"camera {self.device!r}: {self._failures} grabs failed in a row; camera lost"
                )
            time.sleep(0.005)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class VideoFileSource(Source):
    """Replay a video file; stamps are the video positions (from 0) plus ``t0_ns``.

    Args:
        path: any video OpenCV (FFmpeg) can read.
        speed: 1.0 paces frames in real time, 0 delivers them as fast as possible.
        t0_ns: stamp of the first frame.

    Raises:
        CaptureError: if the file cannot be opened.
    """

    kind = "image"

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        speed: float = 0.0,
        t0_ns: int = 0,
        name: str | None = None,
    ) -> None:
        super().__init__(name or os.fspath(path))
        self.path = Path(path)
        self.t0_ns = int(t0_ns)
        self._pacer = _Pacer(speed)
        self._cap: Any = None
        self._index = 0
        self._fps = 0.0

    def open(self) -> None:
        if not self.path.is_file():
            raise CaptureError(f"video file {self.path} does not exist")
        cap = cv2.VideoCapture(os.fspath(self.path))
        if not cap.isOpened():
            raise CaptureError(f"cannot open video {self.path} (not a video OpenCV can read?)")
        self._fps = float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
        self._cap = cap

    def read(self) -> ImageFrame | None:
        if self._cap is None:
            self.open()
        ok, frame = self._cap.read()
        if not ok or frame is None:
            return None
        t_ns = self.t0_ns + round(self._index * 1e9 / self._fps)
        self._index += 1
        self._pacer.wait(t_ns)
        return ImageFrame(t_ns, _to_rgb(frame))

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


_SUFFIXES = (".png", ".jpg", ".jpeg", ".jxl", ".tif", ".tiff", ".bmp", ".pgm", ".ppm")


class ImageFolderSource(Source):
    """Replay a folder of images in name order.

    Stamps come from integer file names (``<t_ns>.png``, scaled by ``name_unit``) when every
    name is an integer, otherwise they are made at ``rate_hz`` from ``t0_ns``.

    Args:
        folder: the image folder.
        speed: 1.0 paces frames in real time, 0 delivers them as fast as possible.
        rate_hz: frame rate used for names that are not stamps.
        loop: start again at the end (stamps keep increasing).
        name_unit: ``"ns"`` or ``"us"`` for stamped names.

    Raises:
        CaptureError: if the folder is missing or holds no images.
    """

    kind = "image"

    def __init__(
        self,
        folder: str | os.PathLike[str],
        *,
        speed: float = 0.0,
        rate_hz: float = 30.0,
        loop: bool = False,
        t0_ns: int = 0,
        name_unit: str = "ns",
        name: str | None = None,
    ) -> None:
        super().__init__(name or os.fspath(folder))
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise CaptureError(f"image folder {self.folder} does not exist")
        files = sorted(
            p
            for p in self.folder.iterdir()
            if p.suffix.lower() in _SUFFIXES and not p.name.startswith(".")
        )
        if not files:
            raise CaptureError(
                f"image folder {self.folder} holds no images ({', '.join(_SUFFIXES)})"
            )
        scale = 1000 if name_unit == "us" else 1
        if all(p.stem.isdigit() for p in files):
            files.sort(key=lambda p: int(p.stem))
            self.stamps = np.array([int(p.stem) * scale for p in files], dtype=np.int64)
        else:
            step = round(1e9 / rate_hz)
            self.stamps = int(t0_ns) + np.arange(len(files), dtype=np.int64) * step
        self.files = files
        self.loop = loop
        self.skipped = 0
        self._pacer = _Pacer(speed)
        self._i = 0
        span = int(self.stamps[-1] - self.stamps[0])
        self._period = span + (
            span // max(len(files) - 1, 1) if len(files) > 1 else round(1e9 / rate_hz)
        )

    def read(self) -> ImageFrame | None:
        from sea3d.errors import SessionError
        from sea3d.io.session.common import read_image_file

        n = len(self.files)
        misses = 0
        while True:
            if self._i >= n and not self.loop:
                return None
            k, lap = self._i % n, self._i // n
            self._i += 1
            path = self.files[k]
            try:  # refuses cut or damaged files instead of replaying them half grey
                img = read_image_file(path)
            except SessionError as err:
                self.skipped += 1
                misses += 1
                _log.warning("replay %s: skipping %s", self.name, err)
                if misses >= n:
                    raise CaptureError(f"image folder {self.folder}: no readable image") from err
                continue
            t_ns = int(self.stamps[k]) + lap * self._period
            self._pacer.wait(t_ns)
            return ImageFrame(t_ns, img)


class ArraySource(Source):
    """Deliver in-memory images at a fixed rate (benchmarks, tests, synthetic replay).

    Args:
        images: images cycled in order, (H, W) or (H, W, 3) RGB.
        rate_hz: nominal frame rate; stamps are ``t0_ns + i / rate_hz``.
        count: number of frames to deliver (None: until ``duration_s``).
        duration_s: stop after this many seconds of stamps (None with count None: forever).
        speed: 1.0 paces frames in real time, 0 delivers them as fast as possible.
    """

    kind = "image"

    def __init__(
        self,
        images: Sequence[np.ndarray],
        *,
        rate_hz: float = 30.0,
        count: int | None = None,
        duration_s: float | None = None,
        t0_ns: int = 0,
        speed: float = 1.0,
        name: str = "array",
    ) -> None:
        super().__init__(name)
        if not images:
            raise CaptureError("ArraySource needs at least one image")
        self.images = list(images)
        self.step_ns = round(1e9 / rate_hz)
        if count is None and duration_s is not None:
            count = round(duration_s * rate_hz)
        self.count = count
        self.t0_ns = int(t0_ns)
        self._pacer = _Pacer(speed)
        self._i = 0

    def read(self) -> ImageFrame | None:
        if self.count is not None and self._i >= self.count:
            return None
        t_ns = self.t0_ns + self._i * self.step_ns
        img = self.images[self._i % len(self.images)]
        self._i += 1
        self._pacer.wait(t_ns)
        return ImageFrame(t_ns, img)


class SessionReplaySource(Source):
    """Replay one stream of a recorded session (``left``, ``right``, ``imu`` or ``sonar``).

    Stands in for the cameras and the serial sensors in tests and for ``sea3d monitor``.

    Args:
        path: the session (MCAP file or folder).
        stream: which stream to replay.
        speed: 1.0 paces records in real time, 0 delivers them as fast as possible.

    Raises:
        CaptureError: unknown stream; SessionError for an unreadable session.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        stream: str,
        *,
        speed: float = 0.0,
        name: str | None = None,
    ) -> None:
        super().__init__(name or f"{os.fspath(path)}#{stream}")
        if stream not in ("left", "right", "imu", "sonar"):
            raise CaptureError(
                f"unknown session stream {stream!r}; expected left, right, imu, sonar"
            )
        self.path, self.stream = Path(path), stream
        self.kind = "image" if stream in ("left", "right") else stream
        self._pacer = _Pacer(speed)
        self._session: Any = None
        self._i = 0

    def open(self) -> None:
        from sea3d.io.session import open_session

        if self._session is None:
            self._session = open_session(self.path)
            if self.stream == "imu":
                self._series: Any = self._session.imu()
            elif self.stream == "sonar":
                self._series = self._session.sonar()

    def read(self) -> Record | None:
        from sea3d.errors import SessionError

        self.open()
        s = self._session
        stamps = s.stamps(self.stream)
        while self._i < stamps.size:
            i = self._i
            self._i += 1
            t_ns = int(stamps[i])
            self._pacer.wait(t_ns)
            if self.stream == "imu":
                sr = self._series
                return ImuSample(t_ns, sr.accel_mps2[i].copy(), sr.gyro_radps[i].copy())
            if self.stream == "sonar":
                sr = self._series
                return SonarSample(t_ns, float(sr.range_m[i]), float(sr.confidence[i]))
            try:
                return ImageFrame(t_ns, s.image(self.stream, i, by="index"))
            except SessionError as err:
                _log.warning("replay %s: skipping t_ns=%d: %s", self.name, t_ns, err)
        return None

    def close(self) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None


class CallableSource(Source):
    """Wrap a function as a source: the simulator hook.

    ``fn()`` returns the next record (an :class:`ImageFrame`, ``ImuSample``, ``SonarSample``,
    or a ``(t_ns, image)`` tuple for image sources) or None at the end.

    Args:
        fn: the producer.
        kind: ``"image"``, ``"imu"`` or ``"sonar"``.
        speed: 1.0 paces records in real time, 0 as fast as possible.
    """

    def __init__(
        self,
        fn: Callable[[], Any],
        *,
        kind: str = "image",
        speed: float = 0.0,
        name: str | None = None,
    ) -> None:
        super().__init__(name or str(getattr(fn, "__qualname__", "callable")))
        if kind not in ("image", "imu", "sonar"):
            raise CaptureError(f"kind must be image, imu or sonar, got {kind!r}")
        self.kind = kind
        self.fn = fn
        self._pacer = _Pacer(speed)

    @classmethod
    def from_spec(cls, spec: str, **kwargs: Any) -> CallableSource:
        """Build from ``"package.module:function"``; the function is called with no
        arguments and must return the producer callable (a factory), or be it.

        Raises:
            CaptureError: if the module or attribute cannot be imported.
        """
        module_name, _, attr = spec.partition(":")
        try:
            obj = getattr(importlib.import_module(module_name), attr)
        except (ImportError, AttributeError, ValueError) as err:
            raise CaptureError(f"cannot import simulator hook {spec!r}: {err}") from err
        fn = obj()
        if not callable(fn):
            raise CaptureError(f"simulator hook {spec!r} must return a callable producer")
        return cls(fn, name=spec, **kwargs)

    def read(self) -> Record | None:
        rec = self.fn()
        if rec is None:
            return None
        if isinstance(rec, tuple):
            rec = ImageFrame(int(rec[0]), rec[1])
        self._pacer.wait(rec.t_ns)
        return rec  # type: ignore[no-any-return,unused-ignore]
