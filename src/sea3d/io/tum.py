"""TUM trajectory files: one pose per line, ``t tx ty tz qx qy qz qw``.

``t`` is in seconds; the pose maps the camera (or body) frame into the world (``T_world_cam``,
metres); the quaternion is Hamilton, scalar last as the TUM RGB-D benchmark writes it. Lines
starting with ``#`` and blank lines are comments.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import GeometryError, SessionError
from sea3d.geometry.se3 import R_to_quat_wxyz, quat_wxyz_to_R

__all__ = ["read_tum", "write_tum"]

F64 = NDArray[np.float64]


def write_tum(path: str | os.PathLike[str], t_s: F64, T_world_cam: F64) -> None:
    """Write poses ``(N, 4, 4)`` at times ``(N,)`` seconds (atomically: a temporary file, then
    renamed).

    Raises:
        SessionError: mismatched shapes or an unwritable file.
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    T = np.asarray(T_world_cam, dtype=np.float64)
    if T.shape != (len(t), 4, 4):
        raise SessionError(f"{path}: need (N,) times and (N, 4, 4) poses, got {t.shape}, "
                           f"{T.shape}")
    lines = ["# t tx ty tz qx qy qz qw"]
    for ti, Ti in zip(t, T, strict=True):
        q = R_to_quat_wxyz(Ti[:3, :3])
        x, y, z = Ti[:3, 3]
        lines.append(f"{ti:.9f} {x:.9f} {y:.9f} {z:.9f} {q[1]:.12f} {q[2]:.12f} {q[3]:.12f} "
                     f"{q[0]:.12f}")
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    try:
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, p)
    except OSError as err:
        raise SessionError(f"cannot write {p}: {err}") from err


def read_tum(path: str | os.PathLike[str]) -> tuple[F64, F64]:
    """Read a TUM trajectory.

    Returns:
        ``(t_s (N,), T_world_cam (N, 4, 4))`` sorted by time.

    Raises:
        SessionError: a missing file, a line without 8 numbers or with a zero quaternion
            (naming the line), or no poses at all.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise SessionError(f"{p}: cannot read trajectory: {err}") from err
    rows = []
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise SessionError(f"{p}:{n}: not a number in {s!r}") from err
        if len(vals) != 8 or not np.all(np.isfinite(vals)):
            raise SessionError(f"{p}:{n}: expected 8 finite numbers 't tx ty tz qx qy qz qw', "
                               f"got {len(vals)}")
        rows.append(vals)
    if not rows:
        raise SessionError(f"{p}: no poses in the trajectory file")
    a = np.array(rows, dtype=np.float64)
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    T = np.tile(np.eye(4), (len(a), 1, 1))
    try:
        T[:, :3, :3] = quat_wxyz_to_R(a[:, [7, 4, 5, 6]])
    except GeometryError as err:
        raise SessionError(f"{p}: {err}") from err
    T[:, :3, 3] = a[:, 1:4]
    return a[:, 0].copy(), T
