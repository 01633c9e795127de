"""Files of structure from motion: the COLMAP model and the run summary.

``OUT/sparse/`` holds the COLMAP model twice, in COLMAP's binary (``cameras.bin``,
``images.bin``, ``points3D.bin``, ``rigs.bin``, ``frames.bin``) and text (``*.txt``) formats, as
``pycolmap.Reconstruction.write_binary``/``write_text`` write them (COLMAP reads the binary
files when both are present). COLMAP's pixel convention: the centre of the top-left pixel is at
``(0.5, 0.5)``. Image names are ``left/<name>.png`` and ``right/<name>.png``; for port cameras
they refer to the images remapped into the virtual pinhole (``sea3d sfm --export-images``).
Beside the model, :func:`write_sfm_model` writes ``points.ply`` (the points, metres when
metric) and ``trajectory.tum`` (``T_world_left`` of every registered frame).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from sea3d.errors import SfmError
from sea3d.io._atomic import atomic_write

__all__ = ["SFM_TRAJECTORY_HEADER", "read_colmap_model", "read_imu_extrinsics",
           "write_colmap_model", "write_sfm_model", "write_summary"]

SFM_TRAJECTORY_HEADER = "t x y z qx qy qz qw (T_world_left, metres when metric)"


def write_colmap_model(reconstruction: Any, out_dir: str | os.PathLike[str]) -> None:
    """Write a ``pycolmap.Reconstruction`` as binary and text files into ``out_dir``.

    Raises:
        SfmError: the folder cannot be written.
    """
    d = Path(out_dir)
    try:
        d.mkdir(parents=True, exist_ok=True)
        reconstruction.write_binary(str(d))
        reconstruction.write_text(str(d))
    except (OSError, RuntimeError, ValueError) as err:
        raise SfmError(f"cannot write the COLMAP model to {d}: {err}") from err


def write_sfm_model(out_dir: str | os.PathLike[str], reconstruction: Any, *, t_ns: Any,
                    T_world_left: Any, points_world: Any, colors_rgb: Any) -> None:
    """Write a model's files into ``out_dir``: ``sparse/`` (:func:`write_colmap_model`),
    ``points.ply`` and ``trajectory.tum``.

    Args:
        reconstruction: the ``pycolmap.Reconstruction``.
        t_ns: (N,) int64 stamps of the registered frames.
        T_world_left: (N, 4, 4) float64 poses of the left camera.
        points_world: (M, 3) float64 points; colors_rgb: (M, 3) uint8 or None.

    Raises:
        SfmError: the COLMAP model cannot be written; StereoError (the PLY) or OdometryError
            (the TUM file) when those cannot.
    """
    from sea3d.io.depth_files import write_ply
    from sea3d.io.trajectory_files import write_tum

    d = Path(out_dir)
    write_colmap_model(reconstruction, d / "sparse")
    write_ply(d / "points.ply", points_world, colors_rgb)
    write_tum(d / "trajectory.tum", t_ns, T_world_left, header=SFM_TRAJECTORY_HEADER)


def read_colmap_model(model_dir: str | os.PathLike[str]) -> Any:
    """Read a COLMAP model folder (binary or text) as a ``pycolmap.Reconstruction``.

    Raises:
        SfmError: the folder holds no readable COLMAP model.
    """
    import pycolmap

    d = Path(model_dir)
    if not ((d / "cameras.bin").is_file() or (d / "cameras.txt").is_file()):
        raise SfmError(f"{d}: not a COLMAP model folder (no cameras.bin or cameras.txt)")
    try:
        return pycolmap.Reconstruction(str(d))
    except (RuntimeError, ValueError) as err:
        raise SfmError(f"{d}: cannot read the COLMAP model: {err}") from err


def write_summary(path: str | os.PathLike[str], summary: dict[str, Any]) -> None:
    """Write a JSON summary atomically (a temporary file, then renamed).

    Raises:
        SfmError: the file cannot be written.
    """
    p = Path(path)
    try:
        atomic_write(p, json.dumps(summary, indent=2, allow_nan=True) + "\n")
    except OSError as err:
        raise SfmError(f"cannot write {p}: {err}") from err


def read_imu_extrinsics(path: str | os.PathLike[str]) -> Any:
    """``T_left_imu`` (4, 4) from a JSON/YAML file holding ``T_left_imu`` or ``T_body_left``
    (a simulation's ``gt/sim.json``), at the top level or under ``imu``.

    Raises:
        SfmError: unreadable, or neither transform (or not a rigid 4x4) in it.
    """
    from pathlib import Path

    import numpy as np
    import yaml

    from sea3d.errors import SfmError
    from sea3d.geometry.se3 import check_T, invert_T

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise SfmError(f"{p}: cannot read IMU extrinsics: {err}") from err
    if isinstance(data, dict) and isinstance(data.get("imu"), dict):
        data = data["imu"]
    for key, inverse in (("T_left_imu", False), ("T_body_left", True)):
        if isinstance(data, dict) and key in data:
            try:
                T = check_T(np.asarray(data[key], dtype=np.float64), key)
            except (ValueError, TypeError) as err:
                raise SfmError(f"{p}: {key} is not a rigid 4x4 transform: {err}") from err
            return invert_T(T) if inverse else T
    raise SfmError(f"{p}: holds neither T_left_imu nor T_body_left")
