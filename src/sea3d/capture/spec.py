"""Turn a source description from the command line into a :class:`~sea3d.capture.sources.Source`.

==============================  ===============================================================
``/dev/video0``, ``v4l2:DEV``   V4L2 camera through OpenCV
``0``, ``cam:0``                camera index through OpenCV
``gst:PIPELINE`` (or a string   GStreamer pipeline through OpenCV (needs an OpenCV build
containing `` ! ``)             with GStreamer)
``folder:DIR`` or a folder      replay the images of a folder (stamps from ``<t_ns>`` names)
``video:FILE`` or a video file  replay a video file
``session:PATH[#STREAM]``       replay one stream of a recorded session (default: the same
or an ``.mcap`` / session dir   stream as the role it fills: left, right, imu, sonar)
``sim:MODULE:FACTORY``          simulator hook: ``FACTORY()`` returns a producer callable
``mti:PORT[@BAUD]``             Xsens MTi IMU on a serial port (pyserial)
``ping:PORT[@BAUD]``            Ping echosounder on a serial port (pyserial)
==============================  ===============================================================
"""

from __future__ import annotations

import os
from pathlib import Path

from sea3d.capture.sources import (
    CallableSource,
    ImageFolderSource,
    OpenCVCameraSource,
    SessionReplaySource,
    Source,
    VideoFileSource,
)
from sea3d.errors import CaptureError

__all__ = ["open_source"]

_VIDEO_SUFFIXES = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".m4v", ".mpg", ".mpeg")


def _port(rest: str, default_baud: int) -> tuple[str, int]:
    port, _, baud = rest.partition("@")
    try:
        return port, int(baud) if baud else default_baud
    except ValueError as err:
        raise CaptureError(f"bad baud rate {baud!r} in {rest!r}") from err


def open_source(spec: str, role: str, *, replay_speed: float = 1.0) -> Source:
    """Build the source that ``spec`` describes for ``role`` (``left``, ``right``, ``imu``,
    ``sonar``); see the module docstring for the forms.

    Args:
        spec: the description.
        role: which stream it fills; decides the kind a session replay or simulator delivers.
        replay_speed: pacing of replay sources (1.0 real time, 0 as fast as possible).

    Raises:
        CaptureError: an unknown form, a missing file, or a kind that does not fit the role.
    """
    kind = "image" if role in ("left", "right") else role
    scheme, sep, rest = spec.partition(":")
    scheme = scheme.lower() if sep else ""
    src: Source
    if scheme == "session" or (
        not sep and (spec.lower().endswith(".mcap") or (Path(spec) / "session.json").is_file())
    ):
        path, _, stream = (rest if scheme else spec).partition("#")
        src = SessionReplaySource(path, stream or role, speed=replay_speed)
    elif scheme == "sim":
        src = CallableSource.from_spec(rest, kind=kind, speed=replay_speed)
    elif scheme == "mti":
        from sea3d.capture.serial_sensors import MtiImuSource

        port, baud = _port(rest, 115200)
        src = MtiImuSource(port, baudrate=baud)
    elif scheme == "ping":
        from sea3d.capture.serial_sensors import PingEchosounderSource

        port, baud = _port(rest, 115200)
        src = PingEchosounderSource(port, baudrate=baud)
    elif scheme == "gst" or " ! " in spec:
        src = OpenCVCameraSource(rest if scheme == "gst" else spec, api="gstreamer")
    elif scheme == "v4l2" or spec.startswith("/dev/video"):
        src = OpenCVCameraSource(rest if scheme == "v4l2" else spec, api="v4l2")
    elif scheme == "cam" or spec.isdigit():
        num = rest if scheme == "cam" else spec
        if not num.isdigit():
            raise CaptureError(f"camera index must be a number, got {num!r}")
        src = OpenCVCameraSource(int(num), api="any")
    elif scheme == "folder" or (not sep and os.path.isdir(spec)):
        src = ImageFolderSource(rest if scheme == "folder" else spec, speed=replay_speed)
    elif scheme == "video" or (not sep and spec.lower().endswith(_VIDEO_SUFFIXES)):
        src = VideoFileSource(rest if scheme == "video" else spec, speed=replay_speed)
    else:
        raise CaptureError(
            f"cannot tell what source {spec!r} is; use /dev/videoN, gst:PIPELINE, folder:DIR, "
            "video:FILE, session:PATH, sim:MODULE:FACTORY, mti:PORT or ping:PORT"
        )
    if src.kind != kind:
        raise CaptureError(
            f"the {role} source needs {kind} records, but {spec!r} gives {src.kind} records"
        )
    return src
