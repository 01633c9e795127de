"""Trajectory files: TUM, KITTI and EuRoC ground-truth CSV, read into one shape.

- **TUM** (``t tx ty tz qx qy qz qw``, one pose a line, ``#`` comments): ``t`` in seconds,
  the pose ``T_world_x`` as translation (metres) and unit quaternion (x, y, z, w).
- **KITTI** (12 numbers a line, the row-major 3x4 ``[R | t]`` of ``T_world_cam``): no stamps;
  the poses are numbered, or stamped from a KITTI ``times.txt`` (seconds, one a line).
- **EuRoC** ground-truth CSV (``#time(ns),px,py,pz,qw,qx,qy,qz,...``): stamps in integer
  nanoseconds, quaternion (w, x, y, z); further columns (velocity, biases) are ignored.

Stamps are kept as integer nanoseconds. TUM seconds are parsed from the text digit by digit,
so a stamp such as ``1305031102.160407`` becomes exactly ``1305031102160407000`` ns (a float64
would round it to the nearest 0.2 microsecond).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import GeometryError, OdometryError
from sea3d.geometry.se3 import R_to_quat_wxyz, quat_wxyz_to_R
from sea3d.io._atomic import atomic_write

__all__ = [
    "TRAJECTORY_FORMATS",
    "TrajectoryFile",
    "format_tum_stamp",
    "parse_seconds_ns",
    "read_kitti_times",
    "read_trajectory",
    "write_tum",
]

log = logging.getLogger(__name__)

TRAJECTORY_FORMATS = ("tum", "kitti", "euroc")


@dataclass(frozen=True, kw_only=True, eq=False)
class TrajectoryFile:
    """Poses read from a trajectory file.

    Attributes:
        t_ns: (N,) int64 stamps, nanoseconds, increasing; for an unstamped KITTI file the pose
            index times 1 s (see ``timed``).
        T_world_x: (N, 4, 4) float64 poses (maps points of the tracked frame into the world).
        format: ``tum``, ``kitti`` or ``euroc``.
        timed: False when the file carries no stamps (KITTI without ``times.txt``).
        path: where it was read from.
        duplicates_dropped: poses dropped because their stamp repeats an earlier one (the
            first pose of each stamp is kept).
        duplicates_kept: poses whose stamp repeats an earlier one, kept (``duplicates="keep"``).
        unsorted: the file's stamps were not in order (they were sorted).
    """

    t_ns: NDArray[np.int64]
    T_world_x: NDArray[np.float64]
    format: str
    timed: bool
    path: Path
    duplicates_dropped: int = 0
    duplicates_kept: int = 0
    unsorted: bool = False

    @property
    def notes(self) -> list[str]:
        """What was repaired while reading, for the user (empty for a clean file)."""
        out = []
        if self.unsorted:
            out.append(f"{self.path}: stamps were not in order; sorted")
        if self.duplicates_dropped:
            out.append(
                f"{self.path}: {self.duplicates_dropped} pose(s) with a repeated stamp dropped "
                "(the first pose of each stamp kept)"
            )
        if self.duplicates_kept:
            out.append(
                f"{self.path}: {self.duplicates_kept} pose(s) repeat an earlier stamp; kept and "
                "paired as evo pairs them (each paired when this trajectory is the shorter, "
                "the first otherwise)"
            )
        return out

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


def parse_seconds_ns(text: str) -> int:
    """Seconds written in decimal (``"1305031102.160407"``, ``"-0.5"``, ``"1e-3"``) to integer
    nanoseconds, exactly for plain decimals (digits beyond the ninth decimal are rounded).

    Raises:
        ValueError: not a number.
    """
    s = text.strip()
    if "e" in s.lower() or s.lower() in ("nan", "inf", "-inf", "+inf"):
        value = float(s)
        if not np.isfinite(value):
            raise ValueError(f"stamp {text!r} is not finite")
        return round(value * 1e9)
    neg = s.startswith("-")
    s = s.lstrip("+-")
    whole, _, frac = s.partition(".")
    if not (whole or frac) or not (whole or "0").isdigit() or not (frac or "0").isdigit():
        raise ValueError(f"not a number of seconds: {text!r}")
    frac_ns = int((frac + "0" * 10)[:10])  # ten digits, rounded below to nine
    ns = int(whole or "0") * 1_000_000_000 + (frac_ns + 5) // 10
    return -ns if neg else ns


def format_tum_stamp(t_ns: int) -> str:
    """Integer nanoseconds as TUM seconds with nine decimals, exactly (``"12.000000001"``)."""
    t = int(t_ns)
    sign = "-" if t < 0 else ""
    t = abs(t)
    return f"{sign}{t // 1_000_000_000}.{t % 1_000_000_000:09d}"


def _sniff(path: Path, first: list[str]) -> str:
    if path.suffix.lower() == ".csv" or (first and "," in first[0]):
        return "euroc"
    n = len(first[0].split()) if first else 8
    if n == 12:
        return "kitti"
    if n == 8:
        return "tum"
    raise OdometryError(
        f"{path}: cannot tell the trajectory format from a first line of {n} numbers "
        "(TUM has 8: t tx ty tz qx qy qz qw; KITTI 12; EuRoC is comma-separated)"
    )


def _data_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise OdometryError(f"cannot read trajectory {path}: {err}") from err
    out = []
    for k, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((k, s))
    return out


def read_kitti_times(path: str | os.PathLike[str]) -> NDArray[np.int64]:
    """A KITTI ``times.txt``: one stamp in seconds a line, to int64 nanoseconds.

    Raises:
        OdometryError: unreadable file or a line that is not a number.
    """
    p = Path(path)
    stamps = []
    for k, s in _data_lines(p):
        try:
            stamps.append(parse_seconds_ns(s.split()[0]))
        except ValueError as err:
            raise OdometryError(f"{p}:{k}: {err}") from err
    return np.asarray(stamps, dtype=np.int64)


def read_trajectory(
    path: str | os.PathLike[str],
    format: str | None = None,
    *,
    kitti_times: str | os.PathLike[str] | None = None,
    duplicates: Literal["first", "keep"] = "first",
) -> TrajectoryFile:
    """Read a TUM, KITTI or EuRoC CSV trajectory.

    Args:
        path: the file.
        format: ``tum``, ``kitti``, ``euroc`` or None to tell from the extension (``.csv`` is
            EuRoC) and the number of values on the first line (8 TUM, 12 KITTI).
        kitti_times: for KITTI, a ``times.txt`` with one stamp per pose.
        duplicates: ``first`` keeps the first pose of a repeated stamp (one pose per stamp,
            for every use that needs a function of time); ``keep`` keeps them all in file
            order, for :func:`sea3d.eval.trajectory.evaluate_trajectory`, which pairs them as
            evo does (``eval trajectory`` then gives evo's figure on such files).

    Returns:
        :class:`TrajectoryFile`, sorted by stamp, one pose per stamp (with ``first``).
        Stamps out of order are sorted (stably) and repeated stamps keep their first pose
        (as estimators such as open VIO systems write them at a re-initialisation; ``keep``
        keeps them all), each with a logged warning and a count in
        the result (``unsorted``, ``duplicates_dropped`` or ``duplicates_kept``, ``notes``).

    Raises:
        OdometryError: missing file, unknown format, a malformed line (file and line named),
            a non-unit quaternion, or a times file of another length.
    """
    p = Path(path)
    if not p.is_file():
        raise OdometryError(f"trajectory {p} does not exist")
    lines = _data_lines(p)
    if not lines:
        raise OdometryError(f"trajectory {p} holds no poses")
    fmt = format or _sniff(p, [lines[0][1]])
    if fmt not in TRAJECTORY_FORMATS:
        raise OdometryError(f"unknown trajectory format {fmt!r}; use one of {TRAJECTORY_FORMATS}")
    n = len(lines)
    T = np.tile(np.eye(4), (n, 1, 1))
    t_ns: NDArray[np.int64] = np.zeros(n, dtype=np.int64)
    want = {"tum": 8, "kitti": 12, "euroc": 8}[fmt]
    for i, (k, s) in enumerate(lines):
        fields = s.replace(",", " ").split() if fmt == "euroc" else s.split()
        if len(fields) < want or (fmt != "euroc" and len(fields) != want):
            raise OdometryError(
                f"{p}:{k}: expected {want} values for a {fmt.upper()} pose, got {len(fields)}"
            )
        try:
            if fmt == "kitti":
                T[i, :3, :] = np.asarray([float(v) for v in fields], np.float64).reshape(3, 4)
                t_ns[i] = i * 1_000_000_000
                continue
            if fmt == "tum":
                t_ns[i] = parse_seconds_ns(fields[0])
                xyz = [float(v) for v in fields[1:4]]
                qx, qy, qz, qw = (float(v) for v in fields[4:8])
            else:
                t_ns[i] = int(fields[0])
                xyz = [float(v) for v in fields[1:4]]
                qw, qx, qy, qz = (float(v) for v in fields[4:8])
        except ValueError as err:
            raise OdometryError(f"{p}:{k}: not a number: {err}") from err
        q = np.array([qw, qx, qy, qz])
        norm = float(np.linalg.norm(q))
        if not np.isfinite(norm) or abs(norm - 1.0) > 1e-2:
            raise OdometryError(f"{p}:{k}: quaternion norm is {norm:.4g}, expected 1")
        try:
            T[i, :3, :3] = quat_wxyz_to_R(q)
        except GeometryError as err:  # pragma: no cover - the norm check catches it first
            raise OdometryError(f"{p}:{k}: {err}") from err
        T[i, :3, 3] = xyz
    if not np.all(np.isfinite(T)):
        raise OdometryError(f"{p}: non-finite pose values")
    timed = fmt != "kitti"
    if fmt == "kitti" and kitti_times is not None:
        t_ns = read_kitti_times(kitti_times)
        if len(t_ns) != n:
            raise OdometryError(f"{kitti_times} has {len(t_ns)} stamps but {p} has {n} poses")
        timed = True
    unsorted = bool(np.any(np.diff(t_ns) < 0))
    if unsorted:
        log.warning("%s: stamps are not in order; sorting them", p)
        order = np.argsort(t_ns, kind="stable")  # equal stamps keep their order in the file
        t_ns, T = t_ns[order], T[order]
    if duplicates not in ("first", "keep"):
        raise OdometryError(f"duplicates must be 'first' or 'keep', got {duplicates!r}")
    keep = np.concatenate([[True], np.diff(t_ns) != 0])
    dropped = int(keep.size - np.count_nonzero(keep))
    if dropped and duplicates == "keep":
        first = int(t_ns[np.flatnonzero(~keep)[0]])
        log.warning(
            "%s: %d pose(s) repeat an earlier stamp (the first at t = %s s); kept, each paired "
            "as evo pairs them",
            p, dropped, format_tum_stamp(first),
        )
        return TrajectoryFile(t_ns=t_ns, T_world_x=T, format=fmt, timed=timed, path=p,
                              duplicates_kept=dropped, unsorted=unsorted)
    if dropped:
        first = int(t_ns[np.flatnonzero(~keep)[0]])
        log.warning(
            "%s: %d pose(s) repeat an earlier stamp (the first at t = %s s); keeping the first "
            "pose of each stamp",
            p, dropped, format_tum_stamp(first),
        )
        t_ns, T = t_ns[keep], T[keep]
    return TrajectoryFile(t_ns=t_ns, T_world_x=T, format=fmt, timed=timed, path=p,
                          duplicates_dropped=dropped, unsorted=unsorted)


def write_tum(
    path: str | os.PathLike[str],
    t_ns: NDArray[np.integer] | list[int],
    T_world_x: NDArray[np.float64],
    *,
    header: str = "t x y z qx qy qz qw (t in seconds, T_world_x, metres)",
) -> None:
    """Write poses as a TUM trajectory, atomically (a temporary file renamed into place).

    Args:
        path: output file.
        t_ns: (N,) integer nanoseconds, written as seconds with nine decimals.
        T_world_x: (N, 4, 4) poses.
        header: the comment line at the top.

    Raises:
        OdometryError: mismatched lengths or an unwritable file.
    """
    p = Path(path)
    stamps = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    T = np.asarray(T_world_x, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] != stamps.shape[0]:
        raise OdometryError(f"write_tum needs (N,) stamps and (N, 4, 4) poses, got "
                            f"{stamps.shape} and {T.shape}")
    q = R_to_quat_wxyz(T[:, :3, :3]) if len(T) else np.zeros((0, 4))
    lines = [f"# {header}"]
    for t, Ti, qi in zip(stamps.tolist(), T, q, strict=True):
        x, y, z = Ti[:3, 3]
        lines.append(
            f"{format_tum_stamp(t)} {x:.9f} {y:.9f} {z:.9f} "
            f"{qi[1]:.12f} {qi[2]:.12f} {qi[3]:.12f} {qi[0]:.12f}"
        )
    if p.is_dir():
        raise OdometryError(f"cannot write trajectory {p}: it is a folder")
    try:
        atomic_write(p, "\n".join(lines) + "\n")
    except OSError as err:
        raise OdometryError(f"cannot write trajectory {p}: {err}") from err
