"""Finished TSDF submaps on disk, so fusion holds only the active one in memory.

A submap is stored as entries of the process pipeline's cache format
(:func:`sea3d.io.result_cache.write_entry`: checksummed, atomic): ``<root>/<id>.s3c`` holds
its anchor, frames and every block's key, and ``<root>/<id>.c<k>.s3c`` the voxels of its
blocks in chunks of :data:`CHUNK_BLOCKS` (sorted by key, so a chunk is a slab of space). The
merge reads a submap chunk by chunk, only the chunks with blocks that reach the tile at hand
(:meth:`DiskSubmapStore.blocks_of`), so neither the whole submap nor every chunk is held or
decoded again for each tile. A submap written whole (one entry with its voxels, as before
the chunks) is read as well.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import ReconError
from sea3d.io.result_cache import CacheEntryError, read_entry, write_entry
from sea3d.recon.types import Submap, VoxelBlocks

__all__ = ["CHUNK_BLOCKS", "CHUNK_CACHE_BYTES", "DiskSubmapStore"]

_SUFFIX = ".s3c"

CHUNK_BLOCKS = 2048
"""Blocks per chunk entry (20 MB of voxels at 8^3)."""

CHUNK_CACHE_BYTES = 256 << 20
"""Decoded chunks a store keeps for the merge's next reads (about 12 chunks)."""


def _views(a: dict[str, NDArray[Any]], m: dict[str, Any]) -> dict[str, Any]:
    """The keyframe views a submap is placed by (none in a store written before they were
    kept: such a submap is placed by its anchor)."""
    ids = tuple(int(k) for k in m.get("view_keyframe_ids", ()))
    T = np.asarray(a.get("T_grid_views", np.zeros((0, 4, 4))), np.float64)
    z = np.asarray(a.get("view_depth_m", np.zeros(0)), np.float64)
    if T.shape != (len(ids), 4, 4) or z.shape != (len(ids),):
        raise ValueError(f"{len(ids)} views with poses {T.shape} and depths {z.shape}")
    return {"view_keyframe_ids": ids, "T_grid_views": T, "view_depth_m": z}


class DiskSubmapStore:
    """Finished TSDF submaps on disk (see the module): a
    :class:`~sea3d.recon.submaps.SubmapStore`.

    The merge reads a chunk once for every tile it reaches; the last chunks read are kept,
    decoded, up to ``cache_bytes`` (the tiles are visited in order, so a chunk is mostly asked
    for again while it is still held).

    Args:
        root: the folder (created; existing entries are removed by :meth:`clear`).
        cache_bytes: decoded chunks kept in memory for the next reads (0: none).
    """

    def __init__(self, root: Path, *, cache_bytes: int = CHUNK_CACHE_BYTES) -> None:
        self.root = Path(root)
        self.bytes_written = 0
        self.cache_bytes = int(cache_bytes)
        self._chunks: OrderedDict[tuple[int, int], tuple[dict[str, NDArray[Any]], int]] = (
            OrderedDict())
        self._held = 0

    def _chunk(self, submap_id: int, k: int) -> dict[str, NDArray[Any]]:
        """Chunk ``k`` of a submap, decoded: from the kept ones, or read (and kept)."""
        key = (int(submap_id), int(k))
        got = self._chunks.get(key)
        if got is not None:
            self._chunks.move_to_end(key)
            return got[0]
        c, _ = self._read(self._chunk_path(submap_id, k), submap_id)
        size = sum(int(np.asarray(v).nbytes) for v in c.values())
        if size <= self.cache_bytes:
            self._chunks[key] = (c, size)
            self._held += size
            while self._held > self.cache_bytes:
                self._held -= self._chunks.popitem(last=False)[1][1]
        return c

    def _forget_chunks(self) -> None:
        self._chunks.clear()
        self._held = 0

    def clear(self) -> None:
        """Remove every stored submap."""
        self._forget_chunks()
        if self.root.is_dir():
            for p in self.root.glob(f"*{_SUFFIX}"):
                p.unlink()

    def put(self, submap: Submap) -> None:
        self._forget_chunks()
        b = submap.blocks
        order = np.lexsort(b.keys.T[::-1]) if len(b) else np.zeros(0, np.int64)
        starts = np.arange(0, len(b), CHUNK_BLOCKS, dtype=np.int64)
        sid = int(submap.submap_id)
        for k, a in enumerate(starts):
            sel = order[a:a + CHUNK_BLOCKS]
            self.bytes_written += write_entry(
                self._chunk_path(sid, k),
                {"tsdf": b.tsdf[sel], "weight": b.weight[sel], "color": b.color[sel]},
                {"submap_id": sid, "chunk": k})
        meta = {
            "submap_id": sid,
            "anchor_keyframe_id": submap.anchor_keyframe_id,
            "frames": submap.frames,
            "keyframe_ids": list(submap.keyframe_ids),
            "view_keyframe_ids": list(submap.view_keyframe_ids),
            "t_first_ns": submap.t_first_ns,
            "t_last_ns": submap.t_last_ns,
            "voxel_m": b.voxel_m,
            "trunc_voxels": b.trunc_voxels,
            "block_resolution": b.block_resolution,
            "chunk_blocks": CHUNK_BLOCKS,
        }
        # the header last: a submap is listed (ids) once all its chunks are on disk
        self.bytes_written += write_entry(
            self.root / f"{sid}{_SUFFIX}",
            {"keys": b.keys[order], "T_anchor_grid": submap.T_anchor_grid,
             "T_grid_views": submap.T_grid_views, "view_depth_m": submap.view_depth_m}, meta)

    def _chunk_path(self, submap_id: int, k: int) -> Path:
        return self.root / f"{int(submap_id)}.c{int(k)}{_SUFFIX}"

    def _read(self, path: Path, submap_id: int) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
        try:
            return read_entry(path)
        except CacheEntryError as err:
            raise ReconError(f"submap {submap_id} in {self.root} is damaged: {err}") from err

    def _voxels(self, submap_id: int, a: dict[str, NDArray[Any]], m: dict[str, Any],
                which: NDArray[np.bool_] | None) -> VoxelBlocks:
        keys = np.asarray(a["keys"])
        if "tsdf" in a:  # written whole
            arrays = {n: np.asarray(a[n]) for n in ("tsdf", "weight", "color")}
            if which is not None:
                keys, arrays = keys[which], {n: v[which] for n, v in arrays.items()}
        else:
            n_blocks, step = len(keys), int(m["chunk_blocks"])
            r = int(m["block_resolution"])
            sel = np.ones(n_blocks, bool) if which is None else np.asarray(which, bool)
            parts: dict[str, list[NDArray[Any]]] = {"tsdf": [], "weight": [], "color": []}
            for k, a0 in enumerate(range(0, n_blocks, step)):
                want = sel[a0:a0 + step]
                if not want.any():
                    continue
                c = self._chunk(submap_id, k)
                for n in parts:
                    got = np.asarray(c[n])
                    if len(got) != len(want):
                        raise ReconError(f"submap {submap_id} in {self.root} is damaged: "
                                         f"chunk {k} holds {len(got)} blocks, not {len(want)}")
                    parts[n].append(got if want.all() else got[want])
            keys = keys[sel]
            empty = {"tsdf": (r, r, r), "weight": (r, r, r), "color": (r, r, r, 3)}
            arrays = {n: (np.concatenate(v) if v else np.zeros((0, *empty[n]), np.float32))
                      for n, v in parts.items()}
        return VoxelBlocks(keys=keys, tsdf=arrays["tsdf"], weight=arrays["weight"],
                           color=arrays["color"], voxel_m=float(m["voxel_m"]),
                           trunc_voxels=float(m["trunc_voxels"]))

    def get(self, submap_id: int) -> Submap:
        a, m = self._read(self.root / f"{int(submap_id)}{_SUFFIX}", submap_id)
        try:
            return Submap(
                submap_id=int(m["submap_id"]),
                anchor_keyframe_id=int(m["anchor_keyframe_id"]),
                T_anchor_grid=np.asarray(a["T_anchor_grid"], np.float64),
                blocks=self._voxels(submap_id, a, m, None),
                frames=int(m["frames"]),
                keyframe_ids=tuple(int(k) for k in m["keyframe_ids"]),
                t_first_ns=int(m["t_first_ns"]),
                t_last_ns=int(m["t_last_ns"]),
                **_views(a, m),
            )
        except (KeyError, ValueError) as err:
            raise ReconError(f"submap {submap_id} in {self.root} is damaged: {err}") from err

    def head(self, submap_id: int) -> tuple[Submap, NDArray[np.int32]]:
        """A submap without its voxels (no blocks), and its blocks' keys (K, 3): what the
        merge needs to place it, read from its header alone."""
        a, m = self._read(self.root / f"{int(submap_id)}{_SUFFIX}", submap_id)
        try:
            r = int(m.get("block_resolution", np.asarray(a["tsdf"]).shape[1] if "tsdf" in a
                          else 8))
            none = VoxelBlocks(keys=np.zeros((0, 3), np.int32),
                               tsdf=np.zeros((0, r, r, r), np.float32),
                               weight=np.zeros((0, r, r, r), np.float32),
                               color=np.zeros((0, r, r, r, 3), np.float32),
                               voxel_m=float(m["voxel_m"]), trunc_voxels=float(m["trunc_voxels"]))
            return Submap(
                submap_id=int(m["submap_id"]), anchor_keyframe_id=int(m["anchor_keyframe_id"]),
                T_anchor_grid=np.asarray(a["T_anchor_grid"], np.float64), blocks=none,
                frames=int(m["frames"]), keyframe_ids=tuple(int(k) for k in m["keyframe_ids"]),
                t_first_ns=int(m["t_first_ns"]), t_last_ns=int(m["t_last_ns"]), **_views(a, m),
            ), np.asarray(a["keys"])
        except (KeyError, ValueError, IndexError) as err:
            raise ReconError(f"submap {submap_id} in {self.root} is damaged: {err}") from err

    def blocks_of(self, submap_id: int,
                  select: Callable[[NDArray[np.int32]], NDArray[np.bool_]]) -> VoxelBlocks:
        """The blocks of a submap that ``select(keys) -> mask`` picks, reading only the
        chunks that hold them."""
        a, m = self._read(self.root / f"{int(submap_id)}{_SUFFIX}", submap_id)
        try:
            return self._voxels(submap_id, a, m, np.asarray(select(np.asarray(a["keys"]))))
        except (KeyError, ValueError) as err:
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
