"""The per-frame status file of an odometry run: ``t_ns,status,segment``, one line a frame.

``t_ns`` is the frame stamp (integer nanoseconds), ``status`` a
:class:`~sea3d.odometry.types.TrackingStatus` value (``tracking``, ``imu_only``, ``lost``,
``relocalised``, ``initialising``) and ``segment`` the id of the trajectory segment the frame
was reported in. The trajectory itself is a TUM file (:func:`sea3d.io.trajectory_files.write_tum`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sea3d.errors import OdometryError
from sea3d.io._atomic import atomic_write

__all__ = ["write_odometry_status"]


def write_odometry_status(path: str | os.PathLike[str], t_ns: Sequence[int],
                          statuses: Sequence[Any], segments: Sequence[int]) -> None:
    """Write ``t_ns,status,segment`` per frame, atomically.

    Args:
        path: the CSV file.
        t_ns: (N,) frame stamps, nanoseconds.
        statuses: (N,) tracking statuses (enum members with a ``value``, or strings).
        segments: (N,) segment ids.

    Raises:
        OdometryError: lengths differ, or the file cannot be written.
    """
    if not len(t_ns) == len(statuses) == len(segments):
        raise OdometryError(f"status file {path}: {len(t_ns)} stamps, {len(statuses)} statuses "
                            f"and {len(segments)} segments")
    lines = ["t_ns,status,segment"]
    lines += [f"{int(t)},{getattr(s, 'value', s)},{int(g)}"
              for t, s, g in zip(t_ns, statuses, segments, strict=True)]
    try:
        atomic_write(Path(path), "\n".join(lines) + "\n")
    except OSError as err:
        raise OdometryError(f"cannot write status file {path}: {err}") from err
