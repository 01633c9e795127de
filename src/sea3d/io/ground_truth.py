"""A session's ground truth on disk: where it lives, what its files are called, how to read them.

The simulator (:func:`sea3d.sim.survey.simulate_survey`) writes through this module and every
reader (``sea3d process``'s evaluation, the demo, ``sea3d eval sonar``, benchmarks) reads
through it, so the rule and the names are written once:

- where: ``gt/`` inside a folder session, ``<stem>_gt/`` beside an MCAP file
  (:func:`ground_truth_dir`);
- what (:class:`GroundTruth`):

  - ``depth/<t_ns>.tiff``: left depth, float32 metres along the raw left camera's z axis, NaN
    where nothing is hit, bit for bit (TIFF, deflate with the floating-point predictor; the
    ``.npy`` files of earlier versions still read); ``object_id/<t_ns>.png``: 16-bit object
    id + 1 (0 = nothing);
  - ``poses_left.tum``, ``poses_body.tum``: ``T_world_left`` and ``T_world_body`` (TUM);
  - ``scene.ply``: the scene mesh (world frame, vertex colours);
  - ``imu_bias.csv``: the IMU's true biases;
  - ``sim.json``: scene, water, seed, rates, ``T_body_left``, ``T_body_sonar``, water model;
  - ``clean/{left,right}/<t_ns>.png``: the same views without water (optional);
  - of a simulated calibration set (``gt/`` beside its ``left/`` and ``right/`` images):
    ``boards.json`` (each view's ``t_ns`` and ``T_left_board``) and ``board.json`` (the board).

Everything but the per-frame images is written atomically (a reader never sees half a file).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import SessionError, SimulationError
from sea3d.io._atomic import atomic_open, atomic_path, atomic_write
from sea3d.io.image_files import write_image_rgb

__all__ = [
    "BOARD",
    "BOARDS",
    "CLEAN_DIR",
    "DEPTH_DIR",
    "GT_DEPTH_SUFFIX",
    "IMU_BIAS",
    "OBJECT_ID_DIR",
    "POSES_BODY",
    "POSES_LEFT",
    "SCENE_MESH",
    "SIM_META",
    "GroundTruth",
    "find_ground_truth",
    "ground_truth_dir",
    "gt_depth_path",
    "read_gt_depth",
    "write_calibration_truth",
    "write_gt_depth",
]

GT_FOLDER = "gt"
"""The ground truth's folder inside a folder session."""
GT_SUFFIX = "_gt"
"""Appended to an MCAP file's stem for the folder beside it."""
DEPTH_DIR = "depth"
OBJECT_ID_DIR = "object_id"
CLEAN_DIR = "clean"
POSES_LEFT = "poses_left.tum"
POSES_BODY = "poses_body.tum"
SCENE_MESH = "scene.ply"
IMU_BIAS = "imu_bias.csv"
SIM_META = "sim.json"
BOARDS = "boards.json"
BOARD = "board.json"

# Ground-truth depth on disk: float32 TIFF, deflate (zlib level 1) with the floating-point
# predictor (TIFF predictor 3). Lossless; on the lake scene 0.36 of the .npy size at level 1,
# 0.34 at level 6 for twice the encoding time (benchmarks/bench_sim_storage.py).
GT_DEPTH_SUFFIX = ".tiff"
_GT_DEPTH_ZLIB_LEVEL = 1


def ground_truth_dir(session: str | os.PathLike[str], *, folder: bool | None = None) -> Path:
    """Where the ground truth of ``session`` lives: ``gt/`` inside a folder session,
    ``<stem>_gt/`` beside an MCAP file.

    Args:
        session: the session's path.
        folder: whether it is a folder session; None: whether ``session`` is a directory
            now (give it for a session not yet written).
    """
    s = Path(session)
    is_folder = s.is_dir() if folder is None else bool(folder)
    return s / GT_FOLDER if is_folder else s.with_name(s.stem + GT_SUFFIX)


def gt_depth_path(depth_dir: str | os.PathLike[str], t_ns: int) -> Path:
    """The ground-truth depth file of frame ``t_ns`` in a ``depth`` folder: ``<t_ns>.tiff``,
    else the ``.npy`` of earlier versions (which need not exist: :func:`read_gt_depth` then
    names the missing file)."""
    d = Path(depth_dir)
    tiff, npy = d / f"{int(t_ns)}{GT_DEPTH_SUFFIX}", d / f"{int(t_ns)}.npy"
    return npy if npy.is_file() and not tiff.is_file() else tiff


def write_gt_depth(path: str | os.PathLike[str], depth_m: NDArray[np.float32]) -> None:
    """Write one ground-truth depth map losslessly (float32 TIFF, see the module docstring).

    Args:
        path: output file (``.tiff``).
        depth_m: ``(H, W)`` depth, metres, NaN where nothing is hit.
    """
    import tifffile

    # Atomic (a crash never leaves half a map under the final name); not synced: a lost
    # map is rendered again.
    with atomic_path(path, fsync=False) as tmp:
        tifffile.imwrite(
            tmp,
            np.ascontiguousarray(depth_m, dtype=np.float32),
            compression="zlib",
            predictor=3,
            compressionargs={"level": _GT_DEPTH_ZLIB_LEVEL},
        )


def read_gt_depth(path: str | os.PathLike[str]) -> NDArray[np.float32]:
    """Read a ground-truth depth map (``depth/<t_ns>.tiff``, or ``.npy`` of earlier versions).

    Returns:
        ``(H, W)`` float32 metres, NaN where nothing was hit.

    Raises:
        SimulationError: the file is missing or not a one-channel float32 depth map.
    """
    p = Path(path)
    try:
        if p.suffix.lower() == ".npy":
            depth = np.load(p, allow_pickle=False)
        else:
            import tifffile

            depth = tifffile.imread(p)
    except (OSError, ValueError) as err:
        raise SimulationError(f"cannot read ground-truth depth {p}: {err}") from err
    if depth.ndim != 2 or depth.dtype != np.float32:
        raise SimulationError(
            f"{p}: expected a 2-D float32 depth map, got {depth.dtype} {depth.shape}"
        )
    return np.asarray(depth)


def _have(p: Path) -> Path | None:
    return p if p.exists() else None


@dataclass(frozen=True)
class GroundTruth:
    """A session's ground-truth folder (see the module docstring for its files).

    Attributes:
        root: the folder.
    """

    root: Path

    # -- where each file is (whether or not it exists) ------------------------------------
    @property
    def depth_folder(self) -> Path:
        """``depth/``."""
        return self.root / DEPTH_DIR

    @property
    def object_id_folder(self) -> Path:
        """``object_id/``."""
        return self.root / OBJECT_ID_DIR

    @property
    def poses_left_path(self) -> Path:
        """``poses_left.tum`` (``T_world_left``)."""
        return self.root / POSES_LEFT

    @property
    def poses_body_path(self) -> Path:
        """``poses_body.tum`` (``T_world_body``)."""
        return self.root / POSES_BODY

    @property
    def scene_mesh_path(self) -> Path:
        """``scene.ply``."""
        return self.root / SCENE_MESH

    @property
    def imu_bias_path(self) -> Path:
        """``imu_bias.csv``."""
        return self.root / IMU_BIAS

    @property
    def sim_meta_path(self) -> Path:
        """``sim.json``."""
        return self.root / SIM_META

    def clean_folder(self, side: str) -> Path:
        """``clean/<side>/`` (``left`` or ``right``)."""
        return self.root / CLEAN_DIR / side

    def depth_path(self, t_ns: int) -> Path:
        """The depth map of frame ``t_ns`` (see :func:`gt_depth_path`)."""
        return gt_depth_path(self.depth_folder, t_ns)

    def new_depth_path(self, t_ns: int) -> Path:
        """Where the simulator writes the depth map of frame ``t_ns``."""
        return self.depth_folder / f"{int(t_ns)}{GT_DEPTH_SUFFIX}"

    # -- what is there -----------------------------------------------------------------------
    @property
    def poses_left(self) -> Path | None:
        """``poses_left.tum`` if it exists."""
        return _have(self.poses_left_path)

    @property
    def scene_mesh(self) -> Path | None:
        """``scene.ply`` if it exists."""
        return _have(self.scene_mesh_path)

    @property
    def depth_dir(self) -> Path | None:
        """``depth/`` if it exists."""
        return _have(self.depth_folder)

    @property
    def sim_meta(self) -> Path | None:
        """``sim.json`` if it exists."""
        return _have(self.sim_meta_path)

    # -- reading -----------------------------------------------------------------------------
    def read_depth(self, t_ns: int) -> NDArray[np.float32]:
        """The depth map of frame ``t_ns``, ``(H, W)`` float32 metres (NaN: no hit).

        Raises:
            SimulationError: missing or not a float32 depth map.
        """
        return read_gt_depth(self.depth_path(t_ns))

    def read_meta(self) -> dict[str, Any]:
        """``sim.json`` as a dict.

        Raises:
            SessionError: missing or not JSON.
        """
        p = self.sim_meta_path
        try:
            meta = json.loads(p.read_text())
        except (OSError, ValueError) as err:
            raise SessionError(f"cannot read {p}: {err}") from err
        if not isinstance(meta, dict):
            raise SessionError(f"{p}: expected a JSON object, got {type(meta).__name__}")
        return meta


    # -- writing (the simulator) --------------------------------------------------------------
    def write_meta(self, meta: dict[str, Any]) -> None:
        """Write ``sim.json`` (atomic).

        Raises:
            OSError: it cannot be written.
        """
        atomic_write(self.sim_meta_path, json.dumps(meta, indent=1))

    def write_scene_mesh(self, mesh: Any) -> None:
        """Write ``scene.ply`` from an Open3D ``TriangleMesh`` (world frame, vertex colours;
        atomic).

        Raises:
            OSError: it cannot be written.
        """
        import open3d as o3d

        with atomic_path(self.scene_mesh_path) as tmp:
            if not o3d.io.write_triangle_mesh(tmp, mesh):
                raise OSError(f"Open3D could not write {self.scene_mesh_path}")

    def write_imu_bias(self, t_ns: NDArray[np.int64], accel_bias_mps2: NDArray[np.float64],
                       gyro_bias_radps: NDArray[np.float64]) -> None:
        """Write ``imu_bias.csv``: ``t_ns,ba_x,ba_y,ba_z,bg_x,bg_y,bg_z`` per IMU sample
        (``(N,)`` ns, ``(N, 3)`` m/s^2 and rad/s; atomic).

        Raises:
            OSError: it cannot be written.
        """
        with atomic_open(self.imu_bias_path, "w") as fh:
            np.savetxt(fh, np.column_stack([t_ns, accel_bias_mps2, gyro_bias_radps]),
                       delimiter=",", header="t_ns,ba_x,ba_y,ba_z,bg_x,bg_y,bg_z", comments="",
                       fmt=["%d"] + ["%.9e"] * 6)

    def write_object_id(self, t_ns: int, object_id: NDArray[np.uint16]) -> None:
        """Write ``object_id/<t_ns>.png``: ``(H, W)`` uint16, object index + 1, 0 = no hit.

        Raises:
            SimulationError: it cannot be written.
        """
        write_image_rgb(self.object_id_folder / f"{int(t_ns)}.png",
                        np.asarray(object_id, np.uint16), SimulationError)

    def write_clean_pair(self, t_ns: int, left_rgb: NDArray[Any], right_rgb: NDArray[Any]
                         ) -> None:
        """Write ``clean/{left,right}/<t_ns>.png``: the views without water, ``(H, W, 3)`` RGB.

        Raises:
            SimulationError: they cannot be written.
        """
        for side, img in (("left", left_rgb), ("right", right_rgb)):
            write_image_rgb(self.clean_folder(side) / f"{int(t_ns)}.png", img, SimulationError)


def write_calibration_truth(root: str | os.PathLike[str], boards: list[dict[str, Any]],
                            board: dict[str, Any]) -> None:
    """Write a simulated calibration set's truth: ``gt/boards.json`` (each view's ``t_ns`` and
    ``T_left_board``) and ``gt/board.json`` (the board) under ``root`` (atomic).

    Raises:
        OSError: they cannot be written.
    """
    gt = Path(root) / GT_FOLDER
    atomic_write(gt / BOARDS, json.dumps(boards, indent=1))
    atomic_write(gt / BOARD, json.dumps(board, indent=1))


def find_ground_truth(session: str | os.PathLike[str]) -> GroundTruth | None:
    """The ground truth of ``session`` if the simulator left one beside it (a folder holding
    poses, a scene mesh, depth maps or ``sim.json``), else None."""
    root = ground_truth_dir(session)
    if not root.is_dir():
        return None
    gt = GroundTruth(root)
    if gt.poses_left is None and gt.scene_mesh is None and gt.depth_dir is None \
            and gt.sim_meta is None:
        return None
    return gt
