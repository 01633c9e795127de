"""Live capture: sources, camera sync, the recorder and the live monitor.

- :mod:`sea3d.capture.sources`: the :class:`Source` interface; OpenCV cameras (V4L2,
  GStreamer), image-folder / video / session replay, and a callable hook for the simulator.
- :mod:`sea3d.capture.serial_sensors`: MTi IMU and Ping echosounder readers.
- :mod:`sea3d.capture.v4l2_sync`: hardware sync of the two cameras with ``v4l2-ctl``.
- :mod:`sea3d.capture.recorder`: record sources into a session (``sea3d record``).
- :mod:`sea3d.capture.monitor`: the live monitor web page (``--monitor``, ``sea3d monitor``).
- :mod:`sea3d.capture.spec`: command-line source descriptions.

See ``docs/sessions.md``.
"""

from sea3d.capture.recorder import Recorder, RecorderConfig, RecordSummary
from sea3d.capture.sources import (
    ArraySource,
    CallableSource,
    ImageFolderSource,
    ImageFrame,
    OpenCVCameraSource,
    SessionReplaySource,
    Source,
    VideoFileSource,
)
from sea3d.capture.spec import open_source

__all__ = [
    "ArraySource",
    "CallableSource",
    "ImageFolderSource",
    "ImageFrame",
    "OpenCVCameraSource",
    "RecordSummary",
    "Recorder",
    "RecorderConfig",
    "SessionReplaySource",
    "Source",
    "VideoFileSource",
    "open_source",
]
