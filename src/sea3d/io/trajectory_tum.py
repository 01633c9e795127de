"""TUM trajectory files: ``t tx ty tz qx qy qz qw`` per line, ``t`` in seconds.

Written by ``sea3d odometry`` (the poses are ``T_world_left``). Lines starting with ``#`` are
comments. (``sea3d.eval.trajectory`` reads TUM, KITTI and EuRoC files for evaluation.)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import SessionError
from sea3d.geometry.se3 import R_to_quat_wxyz, quat_wxyz_to_R

__all__ = ["read_tum", "write_tum"]


def write_tum(
    path: str | os.PathLike[str],
    t_s: NDArray[np.float64],
    T: NDArray[np.float64],
    *,
    header: str = "t tx ty tz qx qy qz qw",
) -> Path:
    """Write poses ``T (N, 4, 4)`` at times ``t_s (N,)`` seconds; returns the path.

    The file is written under a temporary name and renamed, so a failure leaves no half file.

    Raises:
        SessionError: mismatched lengths or an unwritable path.
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    P = np.asarray(T, dtype=np.float64)
    if P.shape != (t.size, 4, 4):
        raise SessionError(f"{path}: expected {t.size} poses (N, 4, 4), got {P.shape}")
    q = R_to_quat_wxyz(P[:, :3, :3]) if t.size else np.zeros((0, 4))
    lines = [f"# {header}"]
    for i in range(t.size):
        x, y, z = P[i, :3, 3]
        w, qx, qy, qz = q[i]
        lines.append(f"{t[i]:.9f} {x:.9f} {y:.9f} {z:.9f} {qx:.12f} {qy:.12f} {qz:.12f} {w:.12f}")
    out = Path(path)
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, out)
    except OSError as err:
        if tmp.exists():
            tmp.unlink()
        raise SessionError(f"{out}: cannot write the trajectory: {err}") from err
    return out


def read_tum(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(t_s (N,), T (N, 4, 4))`` of a TUM file.

    Raises:
        SessionError: a missing file or a line that is not 8 numbers.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise SessionError(f"{p}: cannot read: {err}") from err
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise SessionError(f"{p}: line {n}: not numbers: {s!r}") from err
        if len(vals) != 8:
            raise SessionError(
                f"{p}: line {n}: expected 8 numbers (t x y z qx qy qz qw), got {len(vals)}"
            )
        rows.append(vals)
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
    T = np.tile(np.eye(4), (a.shape[0], 1, 1))
    if a.shape[0]:
        T[:, :3, :3] = quat_wxyz_to_R(np.c_[a[:, 7], a[:, 4:7]])
        T[:, :3, 3] = a[:, 1:4]
    return a[:, 0], T
