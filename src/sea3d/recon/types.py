"""Data types of the reconstruction stage: voxel blocks and submaps (and :class:`Mesh`,
which lives in :mod:`sea3d.geometry.mesh` and is re-exported here).

Frames: a submap's voxels live in its own ``grid`` frame; ``T_anchor_grid`` fixes the grid to
the submap's anchor keyframe (a raw left camera pose), so that the submap's place in the world
is ``T_world_grid = T_world_anchor @ T_anchor_grid`` with whatever ``T_world_anchor`` the
odometry holds now: a loop closure that moves the keyframe moves the submap, no voxel changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F32, F64
from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh  # moved down to geometry (io reads and writes meshes)

__all__ = ["Mesh", "Submap", "VoxelBlocks"]


@dataclass(frozen=True, kw_only=True, eq=False)
class VoxelBlocks:
    """The observed voxel blocks of a TSDF volume, as plain arrays.

    A block of key ``k`` holds the voxels with integer coordinates ``k * R + (x, y, z)`` for
    ``0 <= x, y, z < R`` (``R = block_resolution``), stored ``[z, y, x]``; a voxel of integer
    coordinates ``c`` sits at ``c * voxel_m`` in the volume's frame.

    Attributes:
        keys: (M, 3) int32 block coordinates.
        tsdf: (M, R, R, R) float32 truncated signed distance in units of the truncation
            distance, in [-1, 1].
        weight: (M, R, R, R) float32 number of observations (0 = never seen).
        color: (M, R, R, R, 3) float32 mean colour in [0, 1], RGB.
        voxel_m: voxel edge, metres.
        trunc_voxels: truncation distance in voxels.
    """

    keys: NDArray[np.int32]
    tsdf: F32
    weight: F32
    color: F32
    voxel_m: float
    trunc_voxels: float

    def __post_init__(self) -> None:
        m = self.keys.shape[0]
        r = self.tsdf.shape[1] if self.tsdf.ndim == 4 else -1
        if (self.keys.ndim != 2 or self.keys.shape[1] != 3 or self.tsdf.shape != (m, r, r, r)
                or self.weight.shape != (m, r, r, r) or self.color.shape != (m, r, r, r, 3)):
            raise ReconError(
                f"voxel blocks have inconsistent shapes: keys {self.keys.shape}, tsdf "
                f"{self.tsdf.shape}, weight {self.weight.shape}, color {self.color.shape}"
            )

    @property
    def block_resolution(self) -> int:
        """Voxels along a block edge."""
        return int(self.tsdf.shape[1])

    @property
    def nbytes(self) -> int:
        """Bytes held by the arrays."""
        return int(self.keys.nbytes + self.tsdf.nbytes + self.weight.nbytes + self.color.nbytes)

    def __len__(self) -> int:
        return int(self.keys.shape[0])


@dataclass(frozen=True, kw_only=True, eq=False)
class Submap:
    """A finished part of the map: voxels in its grid frame, fixed to an anchor keyframe.

    Attributes:
        submap_id: 0, 1, ... in creation order.
        anchor_keyframe_id: the odometry keyframe it is fixed to.
        T_anchor_grid: (4, 4) float64, the grid frame in the anchor camera's frame.
        blocks: the voxels (:class:`VoxelBlocks`).
        frames: frames integrated.
        keyframe_ids: keyframes integrated (the anchor first).
        t_first_ns, t_last_ns: stamps of the first and last integrated frame.
        view_keyframe_ids: the keyframes integrated with depth, in order;
        T_grid_views: (K, 4, 4) their cameras' poses in the grid frame as they were
            integrated; view_depth_m: (K,) the median depth of each: what
            :func:`~sea3d.recon.submaps.merge_submaps` places the submap by.
    """

    submap_id: int
    anchor_keyframe_id: int
    T_anchor_grid: F64
    blocks: VoxelBlocks
    frames: int
    keyframe_ids: tuple[int, ...] = field(default_factory=tuple)
    t_first_ns: int = 0
    t_last_ns: int = 0
    view_keyframe_ids: tuple[int, ...] = field(default_factory=tuple)
    T_grid_views: F64 = field(default_factory=lambda: np.zeros((0, 4, 4)))
    view_depth_m: F64 = field(default_factory=lambda: np.zeros(0))
