"""The per-frame status file of an odometry run: ``t_ns,status,segment``, one line a frame;
and the trusted stamps of any such status file (``sea3d process`` writes one too).

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

__all__ = ["read_trusted_stamps", "write_odometry_status"]


def write_odometry_status(path: str | os.PathLike[str], t_ns: Sequence[int],
                          statuses: Sequence[str], segments: Sequence[int]) -> None:
    """Write ``t_ns,status,segment`` per frame, atomically.

    Args:
        path: the CSV file.
        t_ns: (N,) frame stamps, nanoseconds.
        statuses: (N,) tracking statuses (``TrackingStatus`` members are strings too).
        segments: (N,) segment ids.

    Raises:
        OdometryError: lengths differ, or the file cannot be written.
    """
    if not len(t_ns) == len(statuses) == len(segments):
        raise OdometryError(f"status file {path}: {len(t_ns)} stamps, {len(statuses)} statuses "
                            f"and {len(segments)} segments")
    lines = ["t_ns,status,segment"]
    lines += [f"{int(t)},{s},{int(g)}"
              for t, s, g in zip(t_ns, statuses, segments, strict=True)]
    try:
        atomic_write(Path(path), "\n".join(lines) + "\n")
    except OSError as err:
        raise OdometryError(f"cannot write status file {path}: {err}") from err


def read_trusted_stamps(path: str | os.PathLike[str],
                        trusted: Sequence[str] = ("tracking", "relocalised")) -> Any:
    """The ``t_ns`` of the frames whose ``status`` is one of ``trusted`` in a status file
    (this module's, or the ``status.csv`` of ``sea3d process``: any CSV with ``t_ns`` and
    ``status`` columns), as an (N,) int64 array; None when there is no such file.

    Raises:
        OdometryError: a row without a whole-number ``t_ns``.
    """
    import csv

    import numpy as np

    p = Path(path)
    if not p.is_file():
        return None
    with open(p, newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("status") in trusted]
    try:
        return np.array([int(r["t_ns"]) for r in rows], np.int64)
    except (KeyError, TypeError, ValueError) as err:
        raise OdometryError(f"{p}: a row has no whole-number t_ns ({err})") from err
