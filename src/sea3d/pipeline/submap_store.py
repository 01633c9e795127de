"""Finished TSDF submaps on disk, so fusion holds only the active one in memory.

Each submap is one entry of the process pipeline's cache format
(:func:`sea3d.io.result_cache.write_entry`: checksummed, atomic), ``<root>/<id>.s3c``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
from sea3d.io.result_cache import CacheEntryError, read_entry, write_entry
from sea3d.recon.types import Submap, VoxelBlocks

__all__ = ["DiskSubmapStore"]

_SUFFIX = ".s3c"


class DiskSubmapStore:
    """Finished TSDF submaps on disk (``<root>/<id>.s3c``): a
    :class:`~sea3d.recon.submaps.SubmapStore`.

    Args:
        root: the folder (created; existing entries are removed by :meth:`clear`).
    """

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self.bytes_written = 0

    def clear(self) -> None:
        """Remove every stored submap."""
        if self.root.is_dir():
            for p in self.root.glob(f"*{_SUFFIX}"):
                p.unlink()

    def put(self, submap: Submap) -> None:
        b = submap.blocks
        arrays: dict[str, NDArray[Any]] = {
            "keys": b.keys, "tsdf": b.tsdf, "weight": b.weight, "color": b.color,
            "T_anchor_grid": submap.T_anchor_grid,
        }
        meta = {
            "submap_id": submap.submap_id,
            "anchor_keyframe_id": submap.anchor_keyframe_id,
            "frames": submap.frames,
            "keyframe_ids": list(submap.keyframe_ids),
            "t_first_ns": submap.t_first_ns,
            "t_last_ns": submap.t_last_ns,
            "voxel_m": b.voxel_m,
            "trunc_voxels": b.trunc_voxels,
        }
        self.bytes_written += write_entry(self.root / f"{submap.submap_id}{_SUFFIX}", arrays, meta)

    def get(self, submap_id: int) -> Submap:
        try:
            a, m = read_entry(self.root / f"{int(submap_id)}{_SUFFIX}")
            return Submap(
                submap_id=int(m["submap_id"]),
                anchor_keyframe_id=int(m["anchor_keyframe_id"]),
                T_anchor_grid=np.asarray(a["T_anchor_grid"], np.float64),
                blocks=VoxelBlocks(keys=a["keys"], tsdf=a["tsdf"], weight=a["weight"],
                                   color=a["color"], voxel_m=float(m["voxel_m"]),
                                   trunc_voxels=float(m["trunc_voxels"])),
                frames=int(m["frames"]),
                keyframe_ids=tuple(int(k) for k in m["keyframe_ids"]),
                t_first_ns=int(m["t_first_ns"]),
                t_last_ns=int(m["t_last_ns"]),
            )
        except (CacheEntryError, KeyError, ValueError) as err:
            raise ReconError(f"submap {submap_id} in {self.root} is damaged: {err}") from err

    def ids(self) -> list[int]:
        if not self.root.is_dir():
            return []
        out = []
        for p in self.root.glob(f"*{_SUFFIX}"):
            try:
                out.append(int(p.stem))
            except ValueError:
                continue
        return sorted(out)
