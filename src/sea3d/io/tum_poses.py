"""TUM trajectory files: one pose a line, ``t x y z qx qy qz qw`` (t in seconds, quaternion
scalar last), as the TUM RGB-D benchmark, evo and sea3d's simulator (``gt/poses_left.tum``)
write them. ``#`` starts a comment."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from sea3d.errors import SessionError
from sea3d.geometry.se3 import quat_wxyz_to_R

__all__ = ["read_tum_poses"]


def read_tum_poses(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory.

    Returns:
        ``(t_ns (N,) int64, T (N, 4, 4) float64)`` sorted by time; ``T`` maps the moving frame
        into the fixed one (e.g. ``T_world_left``).

    Raises:
        SessionError: a missing file, a line without 8 numbers (line number named), a
            zero quaternion, or no poses at all.
    """
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except OSError as err:
        raise SessionError(f"cannot read trajectory {p}: {err}") from err
    rows = []
    for k, line in enumerate(lines, start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = text.replace(",", " ").split()
        try:
            values = [float(v) for v in parts]
        except ValueError as err:
            raise SessionError(f"{p} line {k}: not a number in {text!r}") from err
        if len(values) != 8:
            raise SessionError(
                f"{p} line {k}: expected 8 numbers (t x y z qx qy qz qw), got {len(values)}"
            )
        rows.append(values)
    if not rows:
        raise SessionError(f"{p} holds no poses")
    arr = np.asarray(rows, dtype=np.float64)
    arr = arr[np.argsort(arr[:, 0], kind="stable")]
    t_ns = np.round(arr[:, 0] * 1e9).astype(np.int64)
    T = np.repeat(np.eye(4)[None], len(arr), axis=0)
    for i, (_t, x, y, z, qx, qy, qz, qw) in enumerate(arr):
        q = np.array([qw, qx, qy, qz])
        n = np.linalg.norm(q)
        if not n > 0:
            raise SessionError(f"{p}: pose at t={_t:.9f} s has a zero quaternion")
        T[i, :3, :3] = quat_wxyz_to_R(q / n)
        T[i, :3, 3] = (x, y, z)
    return t_ns, T
