"""The exceptions sea3d raises: one base class, one subclass per area.

Catch :class:`Sea3dError` to handle anything sea3d reports about bad input or a failed stage.
Shape and value problems also derive from :class:`ValueError`, so generic code that expects a
``ValueError`` for bad arguments keeps working. Third-party errors are wrapped once, at the
boundary, with ``raise XError(msg) from err``.

Every exception class of sea3d is defined here. Two are internal signals, not errors a caller
sees, and so are not :class:`Sea3dError` subclasses nor in ``__all__``: :class:`SmootherFailure`
(the odometry turns it into a lost-tracking status) and :class:`ReserveReached` (the MCAP
session writer turns it into :class:`SessionWriteError`).
"""

from __future__ import annotations

__all__ = [
    "CacheEntryError",
    "CalibrationError",
    "CameraModelError",
    "CaptureError",
    "ConfigError",
    "CsvError",
    "EnhanceError",
    "ExecutorError",
    "GeometryError",
    "MonoDepthError",
    "OdometryError",
    "OutputInUseError",
    "ReconError",
    "RectifyError",
    "RefractionError",
    "RigFileError",
    "Sea3dError",
    "SessionError",
    "SessionWriteError",
    "SfmError",
    "SimulationError",
    "StereoError",
]


class Sea3dError(Exception):
    """Base class of every error sea3d raises on purpose."""


class ConfigError(Sea3dError, ValueError):
    """A configuration value or command-line option is invalid."""


class GeometryError(Sea3dError, ValueError):
    """An array has the wrong shape or holds values outside the valid range."""


class CameraModelError(GeometryError):
    """A camera model's parameters are invalid (e.g. an unknown distortion length)."""


class RefractionError(CameraModelError):
    """A refractive port's parameters are invalid (e.g. a dome centre outside the dome)."""


class RigFileError(Sea3dError, ValueError):
    """A rig or calibration file is missing, malformed, or holds invalid values."""


class SessionError(Sea3dError):
    """A recorded session (MCAP file or folder layout) cannot be read or written."""


class OutputInUseError(SessionError):
    """An output folder is held by another running ``sea3d`` process (its lock is taken)."""


class SessionWriteError(SessionError):
    """Writing a session failed (disk full, free space at the reserve, no permission, I/O
    error). Everything written before stays readable; ``kept`` says what that is.

    Attributes:
        kept: the records on disk, e.g. ``"120 left, 120 right, 2400 imu up to t_ns=..."``.
    """

    def __init__(self, message: str, *, kept: str) -> None:
        super().__init__(message + (f"; kept {kept}" if kept else ""))
        self.kept = kept


class CacheEntryError(SessionError):
    """A cache entry of ``sea3d process`` is damaged (truncated, wrong checksum, unreadable
    arrays)."""


class CsvError(Sea3dError, ValueError):
    """A CSV file is missing, lacks a column, or holds a non-numeric value."""


class CaptureError(Sea3dError):
    """A live source (camera, IMU, echosounder) cannot be opened or read."""


class CalibrationError(Sea3dError):
    """Calibration input is unusable (too few detections, mixed sizes, ...)."""


class RectifyError(Sea3dError):
    """Rectification maps cannot be built for the given rig."""


class StereoError(Sea3dError, ValueError):
    """Stereo matching input is invalid (image sizes, disparity range, ...)."""


class EnhanceError(Sea3dError, ValueError):
    """Image enhancement input is invalid."""


class ExecutorError(Sea3dError):
    """The workers of the per-frame stage were lost: a local worker process that died on
    every try, or a Dask cluster that cannot be reached or lost what it was computing."""


class OdometryError(Sea3dError):
    """Odometry or pose-graph input is invalid."""


class ReconError(Sea3dError):
    """Reconstruction (point clouds, TSDF, meshes) failed or got invalid input."""


class SimulationError(Sea3dError):
    """A simulated scene or session cannot be built from the given configuration."""


class SfmError(Sea3dError):
    """Structure-from-motion input is unusable (too few images, mixed sizes, no rig ...)."""


class MonoDepthError(Sea3dError, ValueError):
    """A monocular depth model or its input is unusable (not ONNX, unexpected input shape ...)."""


# ---------------------------------------------------------------- internal control flow
class SmootherFailure(RuntimeError):
    """gtsam could not solve the window (an indeterminate system after too few observations).

    Internal: raised by ``odometry.backend.SmootherBackend`` and caught in ``odometry.vio``,
    which ends the tracking segment and reports it as a status; it never reaches a caller.
    """


class ReserveReached(Exception):
    """The disk under a session being written has no more than its reserve free.

    Internal: raised by ``io.session.mcap_chunks`` and turned by ``io.session.storage_mcap``
    into :class:`SessionWriteError` (what was written stays readable).

    Attributes:
        free: free bytes on the disk when it was noticed.
    """

    def __init__(self, free: int) -> None:
        super().__init__(f"{free} bytes free")
        self.free = free
