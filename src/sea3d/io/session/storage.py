"""The storage protocol: what :class:`~sea3d.io.session.writer.SessionWriter` asks of a
storage, and the storages by name (as rosbags has a storage plugin per format).

A storage writer receives records already checked (stream names, stamps in order, image
shapes) and encoded; it owns the file format, the free-space reserve and what ``committed``
means (a record counts once it reached the disk).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sea3d.errors import SessionError

__all__ = ["STORAGES", "StorageWriter", "create_storage_writer"]


class StorageWriter(Protocol):
    """One storage's writer (MCAP file, folder)."""

    bytes_written: int

    def committed(self, stream: str) -> int:
        """Records of ``stream`` on disk (what a reader will find)."""
        ...

    def write_encoded(
        self, stream: str, t_ns: int, data: bytes, fmt: str, height: int, width: int
    ) -> None:
        """One encoded (png, jxl, jpeg) image of ``height`` x ``width`` pixels."""
        ...

    def write_raw(self, stream: str, t_ns: int, image: np.ndarray) -> None:
        """One raw image (storages without raw images refuse them when created)."""
        ...

    def write_imu(self, t_ns: int, accel: np.ndarray, gyro: np.ndarray) -> None:
        """One IMU reading: (3,) m/s^2 and (3,) rad/s."""
        ...

    def write_sonar(self, t_ns: int, range_m: np.float32, confidence: np.float32) -> None:
        """One echosounder reading."""
        ...

    def flush(self) -> None:
        """Hand everything written so far to the OS."""
        ...

    def close(self, counts: dict[str, int]) -> None:
        """Finish the storage (summary, session.json)."""
        ...


# Storage name -> the module whose ``create_writer(path, rig_yaml, image_encoding,
# **options)`` makes its writer (imported when first used).
STORAGES = {
    "mcap": "sea3d.io.session.storage_mcap",
    "folder": "sea3d.io.session.storage_folder",
}


def create_storage_writer(
    storage: str, path: Path, rig_yaml: str | None, image_encoding: str, **options: Any
) -> StorageWriter:
    """The writer of ``storage`` for ``path``.

    Raises:
        SessionError: an unknown storage, or what the storage refuses (encoding, rig, an
            existing session); :class:`~sea3d.errors.SessionWriteError` when it cannot be
            created.
    """
    if storage not in STORAGES:
        raise SessionError(f"format must be one of {sorted(STORAGES)}, got {storage!r}")
    module = importlib.import_module(STORAGES[storage])
    writer: StorageWriter = module.create_writer(path, rig_yaml, image_encoding, **options)
    return writer
