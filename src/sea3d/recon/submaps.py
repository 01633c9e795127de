"""Submap fusion: TSDF submaps anchored to keyframes, so loop closures move anchors, not voxels.

The ordered fusion stage (:class:`SubmapFusion`) integrates frames into one *active* submap.
A submap is anchored to the keyframe that started it; its voxels live in a grid frame fixed
to that keyframe (``T_anchor_grid``, chosen so that the grid is the world as it stood when
the submap started, which keeps the final merge exact when nothing moved). Every
``keyframes_per_submap`` keyframes, or when the active submap reaches ``max_blocks`` voxel
blocks, it is *finished*: its voxels are copied out (:class:`~sea3d.recon.types.Submap`) and
handed to the caller, who stores them (the process pipeline spills them to disk) and may
drop them from memory. So memory holds one active submap: its hash map starts with room for
``min(initial_blocks, max_blocks)`` blocks and grows by doubling, and the submap is finished
once it holds ``max_blocks`` (at the next keyframe, or at once, keeping its anchor), so what it
holds stays below ``2 (max_blocks + b) B`` with ``b`` the blocks one frame adds and ``B`` the
bytes of a block (``block_resolution^3`` voxels of 20 bytes: tsdf, weight, RGB as float32;
10 KB at 8^3). :meth:`SubmapFusion.memory_bytes` reports what is held.

After the last frame, :func:`merge_submaps` places every submap with the keyframe poses the
odometry holds *then* (after every loop closure): where it best fits the views of all the
keyframes it integrated (:func:`submap_placement`; at ``T_world_anchor @ T_anchor_grid``
when it integrated none), and fuses them into one world grid: voxel values are combined by
their observation weights (the weighted mean a single volume would have computed), exactly
where a submap's grid still coincides with the world grid, and by trilinear splatting where
the odometry moved it. Spatial tiles bound the memory of that merge as well.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any, Literal, Protocol

import numpy as np
from numba import njit
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import ReconError
from sea3d.geometry.mesh import Mesh
from sea3d.geometry.se3 import invert_T, make_T, umeyama
from sea3d.recon.tsdf import TsdfConfig, TsdfVolume
from sea3d.recon.types import Submap, VoxelBlocks

__all__ = [
    "FuseStatus",
    "FusionConfig",
    "FusionStep",
    "MemorySubmapStore",
    "SubmapFusion",
    "SubmapStore",
    "merge_submaps",
    "submap_placement",
]

log = logging.getLogger(__name__)

IntegratePolicy = Literal["keyframes", "trusted"]
FuseStatus = Literal["integrated", "skipped_untrusted", "skipped_not_keyframe", "skipped_no_depth",
                     "skipped_no_anchor"]

_IDENTITY_TOL = 1e-9


@dataclass(frozen=True, kw_only=True)
class FusionConfig:
    """What the fusion stage integrates and how it cuts the map into submaps."""

    tsdf: TsdfConfig = field(default_factory=TsdfConfig)
    """Voxel size, truncation, depth range."""
    integrate: IntegratePolicy = "trusted"
    """``trusted``: every frame with a trustworthy pose (tracking or relocalised);
    ``keyframes``: only keyframes among those."""
    keyframes_per_submap: int = 20
    """Keyframes after which a new submap starts."""
    max_blocks: int = 20_000
    """Voxel blocks after which a new submap starts (bounds memory: 20,000 blocks of 8^3
    voxels hold 205 MB; about 250 m^2 of surface at 2 cm voxels)."""

    def __post_init__(self) -> None:
        if self.integrate not in ("keyframes", "trusted"):
            raise ReconError(f"integrate must be 'keyframes' or 'trusted', got {self.integrate!r}")
        if self.keyframes_per_submap < 1 or self.max_blocks < 1:
            raise ReconError("keyframes_per_submap and max_blocks must be >= 1")


@dataclass(frozen=True, kw_only=True, eq=False)
class FusionStep:
    """What fusion did with one frame.

    Attributes:
        status: ``integrated`` or why not.
        submap_id: the submap it went into (None when skipped).
        finished: submaps finished by this step (hand them to a :class:`SubmapStore`).
        blocks_touched: voxel blocks the frame updated.
    """

    status: FuseStatus
    submap_id: int | None = None
    finished: tuple[Submap, ...] = ()
    blocks_touched: int = 0


class SubmapStore(Protocol):
    """Where finished submaps go, and where the merge reads them back."""

    def put(self, submap: Submap) -> None:
        """Keep a finished submap (replacing one of the same id)."""
        ...

    def get(self, submap_id: int) -> Submap:
        """The submap of that id."""
        ...

    def ids(self) -> list[int]:
        """Ids of every stored submap, ascending."""
        ...

    def head(self, submap_id: int) -> tuple[Submap, NDArray[np.int32]]:
        """The submap of that id, its voxels left out where the store can (the merge places
        it from the rest), and its blocks' keys (K, 3) int32."""
        ...

    def blocks_of(self, submap_id: int,
                  select: Callable[[NDArray[np.int32]], NDArray[np.bool_]]) -> VoxelBlocks:
        """The blocks of a submap that ``select(keys) -> (K,) mask`` picks (a store on disk
        reads only the chunks that hold them)."""
        ...


class MemorySubmapStore:
    """A :class:`SubmapStore` in memory (for short sequences and tests)."""

    def __init__(self) -> None:
        self._maps: dict[int, Submap] = {}

    def put(self, submap: Submap) -> None:
        self._maps[submap.submap_id] = submap

    def get(self, submap_id: int) -> Submap:
        try:
            return self._maps[submap_id]
        except KeyError as err:
            raise ReconError(f"no submap {submap_id} in the store") from err

    def ids(self) -> list[int]:
        return sorted(self._maps)

    def head(self, submap_id: int) -> tuple[Submap, NDArray[np.int32]]:
        sm = self.get(submap_id)
        return sm, sm.blocks.keys

    def blocks_of(self, submap_id: int,
                  select: Callable[[NDArray[np.int32]], NDArray[np.bool_]]) -> VoxelBlocks:
        b = self.get(submap_id).blocks
        which = select(b.keys)
        return VoxelBlocks(keys=b.keys[which], tsdf=b.tsdf[which], weight=b.weight[which],
                           color=b.color[which], voxel_m=b.voxel_m,
                           trunc_voxels=b.trunc_voxels)


class SubmapFusion:
    """The ordered fusion stage: feed frames in time order with their odometry poses.

    Args:
        config: :class:`FusionConfig`.
    """

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        self._active: TsdfVolume | None = None
        self._active_id = -1
        self._anchor_id = -1
        self._T_anchor_grid = np.eye(4)
        self._keyframes: list[int] = []
        self._views: list[tuple[int, F64, float]] = []
        self._t_first = 0
        self._t_last = 0
        self.submaps_finished = 0
        self.frames_integrated = 0
        self.peak_memory_bytes = 0

    @property
    def active_submap_id(self) -> int | None:
        """Id of the submap being filled, or None."""
        return self._active_id if self._active is not None else None

    def memory_bytes(self) -> int:
        """Bytes the active submap's voxel arrays hold now."""
        return self._active.memory_bytes if self._active is not None else 0

    def _start(self, anchor_id: int, T_world_anchor: F64, t_ns: int) -> None:
        tsdf = self.config.tsdf
        self._active = TsdfVolume(
            replace(tsdf, initial_blocks=min(tsdf.initial_blocks, self.config.max_blocks)))
        self._active_id += 1
        self._anchor_id = anchor_id
        self._T_anchor_grid = invert_T(T_world_anchor)  # grid = world, now
        self._keyframes = []
        self._views = []
        self._t_first = t_ns

    def _finish(self) -> Submap | None:
        if self._active is None:
            return None
        vol = self._active
        self._active = None
        self.submaps_finished += 1
        return Submap(
            submap_id=self._active_id,
            anchor_keyframe_id=self._anchor_id,
            T_anchor_grid=self._T_anchor_grid.copy(),
            blocks=vol.export_blocks(),
            frames=vol.frames,
            keyframe_ids=tuple(self._keyframes),
            t_first_ns=self._t_first,
            t_last_ns=self._t_last,
            view_keyframe_ids=tuple(v[0] for v in self._views),
            T_grid_views=(np.stack([v[1] for v in self._views]) if self._views
                          else np.zeros((0, 4, 4))),
            view_depth_m=np.array([v[2] for v in self._views], np.float64),
        )

    def step(
        self,
        *,
        t_ns: int,
        trusted: bool,
        keyframe_id: int | None,
        depth_m: NDArray[np.floating] | None,
        color_rgb: NDArray[np.uint8] | None,
        K: F64,
        T_world_cam: F64,
        keyframe_poses: dict[int, F64],
        confidence: NDArray[Any] | None = None,
    ) -> FusionStep:
        """Integrate one frame (or say why not).

        Args:
            t_ns: the frame's stamp.
            trusted: its pose is trustworthy (odometry status tracking or relocalised).
            keyframe_id: the keyframe it created, or None.
            depth_m: (H, W) float32 metres in the pinhole camera of ``K`` (for refractive rigs
                already passed through
                :func:`~sea3d.recon.depth_resample.virtual_pinhole_depth`), NaN invalid.
            color_rgb: (H, W, 3) uint8 colours registered to the depth, or None.
            K: (3, 3) intrinsics of that pinhole.
            T_world_cam: (4, 4) pose of that camera (for the rectified view:
                ``T_world_left @ R_rect_left_left^T`` as a 4x4).
            keyframe_poses: the odometry's current keyframe poses ``T_world_cam`` by id (only
                the active anchor's is read).
            confidence: (H, W) the matcher's confidence of each depth pixel (uint8 255 = 1,
                or float in [0, 1]) for :attr:`~sea3d.recon.tsdf.TsdfConfig.min_confidence`
                and ``confidence_full``; None: fully confident.

        Returns:
            :class:`FusionStep`; its ``finished`` submaps belong to the caller now.
        """
        self._t_last = max(self._t_last, int(t_ns))
        finished: list[Submap] = []
        if not trusted:
            return FusionStep(status="skipped_untrusted")
        if keyframe_id is None and self.config.integrate == "keyframes":
            return FusionStep(status="skipped_not_keyframe")
        if keyframe_id is not None:
            need_new = self._active is None or (
                len(self._keyframes) >= self.config.keyframes_per_submap
            )
            if not need_new and self._active is not None:
                need_new = self._active.block_count >= self.config.max_blocks
            if need_new:
                done = self._finish()
                if done is not None:
                    finished.append(done)
                self._start(keyframe_id, np.asarray(T_world_cam, np.float64), int(t_ns))
            self._keyframes.append(int(keyframe_id))
        elif self._active is not None and self._active.block_count >= self.config.max_blocks:
            # Full, and no keyframe to start the next one: the next submap keeps the anchor.
            T_anchor = keyframe_poses.get(self._anchor_id)
            if T_anchor is not None:
                anchor, kfs = self._anchor_id, list(self._keyframes)
                done = self._finish()
                if done is not None:
                    finished.append(done)
                self._start(anchor, np.asarray(T_anchor, np.float64), int(t_ns))
                self._keyframes = kfs[:1]
        if self._active is None:
            # Trusted frames before the first keyframe have nothing to be anchored to.
            return FusionStep(status="skipped_no_anchor", finished=tuple(finished))
        if depth_m is None or not np.isfinite(depth_m).any():
            return FusionStep(status="skipped_no_depth", submap_id=self._active_id,
                              finished=tuple(finished))
        T_world_anchor = keyframe_poses.get(self._anchor_id)
        if T_world_anchor is None:
            raise ReconError(f"keyframe_poses lacks the active anchor keyframe {self._anchor_id}")
        T_world_grid = np.asarray(T_world_anchor, np.float64) @ self._T_anchor_grid
        T_grid_cam = invert_T(T_world_grid) @ np.asarray(T_world_cam, np.float64)
        touched = self._active.integrate(depth_m, color_rgb, K, T_grid_cam, confidence)
        self.frames_integrated += 1
        if keyframe_id is not None:
            self._views.append((int(keyframe_id), T_grid_cam, _median_depth(depth_m)))
        self.peak_memory_bytes = max(self.peak_memory_bytes, self._active.memory_bytes)
        return FusionStep(status="integrated", submap_id=self._active_id,
                          finished=tuple(finished), blocks_touched=touched)

    def finish(self) -> Submap | None:
        """Finish the active submap (after the last frame) and return it, or None."""
        return self._finish()

    def active_mesh(self, keyframe_poses: dict[int, F64]) -> tuple[int, Mesh] | None:
        """The active submap's mesh in the world, placed at its anchor's pose in
        ``keyframe_poses`` (what a live view shows of it): ``(submap_id, mesh)``, or None
        without an active submap or without its anchor's pose."""
        if self._active is None:
            return None
        T_anchor = keyframe_poses.get(self._anchor_id)
        if T_anchor is None:
            return None
        mesh = self._active.extract_mesh()
        return self._active_id, mesh.transformed(np.asarray(T_anchor, np.float64)
                                                 @ self._T_anchor_grid)


# ------------------------------------------------------------------------------------ merging

# Points of a keyframe's view that place its submap: the optical axis and four rays towards the
# corners of a typical view, at the view's median depth (camera frame, per metre of depth).
_VIEW_RAYS = np.array([[0.0, 0.0, 1.0], [-0.4, -0.25, 1.0], [0.4, -0.25, 1.0],
                       [0.4, 0.25, 1.0], [-0.4, 0.25, 1.0]])


def _median_depth(depth_m: NDArray[np.floating]) -> float:
    """Median of a depth map's valid pixels (every 4th row and column; all where that
    sample holds none); NaN where none is valid."""
    for d in (depth_m[::4, ::4], depth_m):
        v = d[np.isfinite(d) & (d > 0)]
        if len(v):
            return float(np.median(v))
    return float("nan")


def submap_placement(submap: Submap, keyframe_poses: dict[int, F64]) -> F64:
    """``T_world_grid`` of a submap at the keyframe poses given.

    A submap is rigid, while the odometry may since have corrected each of its keyframes a
    little differently (a loop closure, the smoother's later estimates). It is placed where
    it best fits all of them: the rigid motion that carries the surface points each keyframe
    saw (five points of its view at its median depth, :data:`_VIEW_RAYS`) from where they
    were fused to where the keyframe's pose puts them now, by least squares
    (:func:`~sea3d.geometry.se3.umeyama`). Where nothing moved, that is the identity (the
    grid is the world as it stood when the submap started), so the merge stays exact. A
    submap without such views (no keyframe integrated with depth) is placed by its anchor.

    Raises:
        ReconError: the anchor keyframe has no pose.
    """
    T_wa = keyframe_poses.get(submap.anchor_keyframe_id)
    if T_wa is None:
        raise ReconError(f"submap {submap.submap_id}: its anchor keyframe "
                         f"{submap.anchor_keyframe_id} has no pose")
    src, dst = [], []
    for kf, T_gc, z in zip(submap.view_keyframe_ids, submap.T_grid_views, submap.view_depth_m,
                           strict=True):
        T_wc = keyframe_poses.get(kf)
        if T_wc is None or not z > 0:
            continue
        q = z * _VIEW_RAYS
        src.append(q @ T_gc[:3, :3].T + T_gc[:3, 3])
        dst.append(q @ np.asarray(T_wc)[:3, :3].T + np.asarray(T_wc)[:3, 3])
    if not src:
        return np.asarray(T_wa, np.float64) @ submap.T_anchor_grid
    R, t, _ = umeyama(np.concatenate(src), np.concatenate(dst), with_scale=False)
    return make_T(R, t)



def _voxel_samples(blocks: VoxelBlocks) -> tuple[NDArray[np.int64], F64, F64, F64]:
    """Integer voxel coordinates (K, 3), tsdf, weight, colour (K, 3) of the observed voxels."""
    r = blocks.block_resolution
    keys, tsdf, weight, color = blocks.keys, blocks.tsdf, blocks.weight, blocks.color
    n = len(keys)
    w = weight.reshape(n, -1)
    b, loc = np.nonzero(w > 0)
    z, y, x = loc // (r * r), (loc // r) % r, loc % r
    coords = keys[b].astype(np.int64) * r + np.stack([x, y, z], axis=1)
    return (np.asarray(coords, np.int64),
            tsdf.reshape(n, -1)[b, loc].astype(np.float64),
            w[b, loc].astype(np.float64),
            color.reshape(n, -1, 3)[b, loc].astype(np.float64))


def _head(store: SubmapStore, sid: int) -> tuple[Submap, NDArray[np.int32]]:
    """A stored submap (its voxels left out where the store can) and its blocks' keys."""
    sm, keys = store.head(sid)
    return sm, np.asarray(keys)


def _reaching(store: SubmapStore, sid: int, r: int, voxel_m: float, T_world_grid: F64,
              moved: bool, m_lo: NDArray[np.int64], m_hi: NDArray[np.int64]) -> VoxelBlocks:
    """The blocks of submap ``sid`` that can reach the world voxels ``[m_lo, m_hi)``
    (:func:`_blocks_reaching`), read alone where the store can (by chunks on disk)."""
    def select(keys: NDArray[np.int32]) -> NDArray[np.bool_]:
        return _blocks_reaching(keys, r, voxel_m, T_world_grid, moved, m_lo, m_hi)

    return store.blocks_of(sid, select)


def _blocks_reaching(keys_: NDArray[np.int32], r: int, v: float, T_world_grid: F64,
                     moved: bool, m_lo: NDArray[np.int64], m_hi: NDArray[np.int64]
                     ) -> NDArray[np.bool_]:
    """The blocks of a submap whose voxels can reach the world voxels ``[m_lo, m_hi)``: where
    it was not moved, those that intersect the box; where it was, those whose centre, moved,
    lies within half the block's diagonal and the splat's one voxel of it. Only blocks that
    cannot contribute are left out, so the merge reads no more of a submap than a tile needs
    and its result is unchanged."""
    keys = np.asarray(keys_, np.int64).reshape(-1, 3)
    if not moved:
        b_lo = keys * r
        return np.asarray(np.all((b_lo + r > m_lo) & (b_lo < m_hi), axis=1))
    centre = (keys * r + (r - 1) / 2.0) * v
    q = (centre @ T_world_grid[:3, :3].T + T_world_grid[:3, 3]) / v
    reach = (r - 1) / 2.0 * np.sqrt(3.0) + 1.5
    return np.asarray(np.all((q + reach >= m_lo) & (q - reach < m_hi), axis=1))


_COMPACT_AT = 1_000_000
"""Entries an :class:`_Accumulator` holds before it sums them (48 bytes each: 48 MB, and
about as much again while they are summed)."""


_QUANTUM = 2.0 ** -28
"""Every summand is rounded to a multiple of this before it is summed. Sums of such float64
values are exact while they stay below 2**25 (a weight of 33 million observations), so a voxel's
sum does not depend on the order its contributions arrive in: the order of Open3D's hash map,
the splat chunks and the compactions. Without it, a merge or a rerun from the cache could differ
in the last bit and, after float32 storage and marching cubes, move a vertex by micrometres or a
colour by one level (seen once each). The rounding, 3.7e-9, is far below float32's resolution
of the stored tsdf and weight."""


def _fixed(x: F64) -> F64:
    return np.round(np.asarray(x, np.float64) / _QUANTUM) * _QUANTUM


_DENSE_AT = 2_500_000
"""Boxes of at most this many voxels are summed in dense arrays (41 bytes a voxel: about
100 MB at most; a 2 m tile at 2 cm voxels, with its margin, is 1.56 million): no batches to
sort, and memory fixed by the box, however many submaps overlap it."""


class _Accumulator:
    """Weighted sums per voxel of a box of a world grid, voxels keyed by a linear index.

    A box of at most ``dense_at`` voxels is summed in dense arrays. A larger one keeps parts
    and sums them into one (unique keys) once they hold ``compact_at`` entries, so memory
    stays at about the box's observed voxels plus one batch, however many submaps overlap it
    and however many splats a moved submap adds (8 per voxel). Every summand is fixed-point
    (:data:`_QUANTUM`), so both give the same sums to the bit.
    """

    def __init__(self, lo: NDArray[np.int64], hi: NDArray[np.int64], *,
                 compact_at: int | None = None, dense_at: int | None = None) -> None:
        self.lo = np.asarray(lo, np.int64)
        self.dims = np.asarray(hi, np.int64) - self.lo
        self.parts: list[tuple[NDArray[np.int64], F64, F64, F64]] = []
        self.compact_at = int(_COMPACT_AT if compact_at is None else compact_at)
        self._entries = 0
        self._compacted = 0
        self._n = int(np.prod(self.dims))
        self.dense = self._n <= int(_DENSE_AT if dense_at is None else dense_at)
        self._seen: NDArray[np.bool_] | None = None
        self._sums_dense: F64 | None = None  # (5, n): weight, weight x tsdf, weight x RGB

    def _add_dense(self, key: NDArray[np.int64], w: F64, wt: F64, wc: F64) -> None:
        if self._seen is None or self._sums_dense is None:
            self._seen = np.zeros(self._n, bool)
            self._sums_dense = np.zeros((5, self._n), np.float64)
        self._seen[key] = True
        acc = self._sums_dense
        for row, x in enumerate((w, wt, wc[:, 0], wc[:, 1], wc[:, 2])):
            acc[row] += np.bincount(key, weights=x, minlength=self._n)

    def add_samples(self, coords: NDArray[np.int64], tsdf: F64, weight: F64, color: F64,
                    T_world_grid: F64 | None, voxel_m: float) -> None:
        """Add a submap's voxel samples (:func:`_voxel_samples`): where ``T_world_grid`` is
        None (the submap was not moved) at their own coordinates, else splatted trilinearly
        at their moved ones; only the targets inside the box count. Dense boxes sum in one
        pass (:func:`_accumulate_dense`), the same sums as :meth:`add` of the splat's targets."""
        if not len(coords):
            return
        if self.dense:
            if self._seen is None or self._sums_dense is None:
                self._seen = np.zeros(self._n, bool)
                self._sums_dense = np.zeros((5, self._n), np.float64)
            T = np.eye(4) if T_world_grid is None else np.asarray(T_world_grid, np.float64)
            _accumulate_dense(np.ascontiguousarray(coords, np.int64),
                              np.ascontiguousarray(tsdf, np.float64),
                              np.ascontiguousarray(weight, np.float64),
                              np.ascontiguousarray(color, np.float64), T, float(voxel_m),
                              T_world_grid is not None, self.lo, self.dims, 1.0 / _QUANTUM,
                              self._sums_dense, self._seen)
            return
        m_lo, m_hi = self.lo, self.lo + self.dims
        if T_world_grid is None:
            sel = np.all((coords >= m_lo) & (coords < m_hi), axis=1)
            self.add(coords[sel], tsdf[sel], weight[sel], color[sel])
            return
        for a in range(0, len(coords), _SPLAT_CHUNK):
            b = min(a + _SPLAT_CHUNK, len(coords))
            tc, tw = _splat(coords[a:b], T_world_grid, voxel_m)
            rep = np.tile(np.arange(a, b), 8)
            sel = np.all((tc >= m_lo) & (tc < m_hi), axis=1) & (tw > 1e-6)
            self.add(tc[sel], tsdf[rep[sel]], weight[rep[sel]] * tw[sel], color[rep[sel]])
            del tc, tw, rep, sel

    def add(self, coords: NDArray[np.int64], tsdf: F64, weight: F64, color: F64) -> None:
        if len(coords) and self.dense:
            c = coords - self.lo
            key = (c[:, 0] * self.dims[1] + c[:, 1]) * self.dims[2] + c[:, 2]
            self._add_dense(key, _fixed(weight), _fixed(weight * tsdf),
                            _fixed(weight[:, None] * color))
        elif len(coords):
            c = coords - self.lo
            key = (c[:, 0] * self.dims[1] + c[:, 1]) * self.dims[2] + c[:, 2]
            self.parts.append((key, _fixed(weight), _fixed(weight * tsdf),
                               _fixed(weight[:, None] * color)))
            self._entries += len(key)
            if self._entries - self._compacted > self.compact_at:
                self.parts = [self._sums()]
                self._entries = self._compacted = len(self.parts[0][0])

    def _sums(self) -> tuple[NDArray[np.int64], F64, F64, F64]:
        """Unique keys with the summed weight, weight x tsdf and weight x colour."""
        key = np.concatenate([p[0] for p in self.parts])
        w = np.concatenate([p[1] for p in self.parts])
        wt = np.concatenate([p[2] for p in self.parts])
        wc = np.concatenate([p[3] for p in self.parts])
        self.parts = []
        uniq, inv = np.unique(key, return_inverse=True)
        del key
        n = len(uniq)
        sw = np.asarray(np.bincount(inv, weights=w, minlength=n), np.float64)
        st = np.asarray(np.bincount(inv, weights=wt, minlength=n), np.float64)
        sc = np.stack([np.bincount(inv, weights=wc[:, k], minlength=n) for k in range(3)],
                      axis=1).astype(np.float64)
        return np.asarray(uniq, np.int64), sw, st, sc

    def reduce(self) -> tuple[NDArray[np.int64], F64, F64, F64]:
        """Unique voxel coordinates with summed weight, tsdf mean and colour mean."""
        if self.dense and self._seen is not None and self._sums_dense is not None:
            uniq = np.flatnonzero(self._seen).astype(np.int64)  # ascending, as np.unique
            acc = self._sums_dense
            sw, st, sc = acc[0, uniq], acc[1, uniq], np.ascontiguousarray(acc[2:, uniq].T)
            self._seen = self._sums_dense = None
        elif not self.parts:
            return np.zeros((0, 3), np.int64), np.zeros(0), np.zeros(0), np.zeros((0, 3))
        else:
            uniq, sw, st, sc = self._sums()
        self._entries = self._compacted = 0
        z = uniq % self.dims[2]
        y = (uniq // self.dims[2]) % self.dims[1]
        x = uniq // (self.dims[2] * self.dims[1])
        coords = np.asarray(np.stack([x, y, z], axis=1) + self.lo, np.int64)
        return coords, sw, st / sw, sc / sw[:, None]


_SPLAT_CHUNK = 100_000
"""Voxels of a moved submap splatted at once (8 targets each: about 40 MB of temporaries)."""


@njit(cache=True)
def _accumulate_dense(coords: Any, tsdf: Any, weight: Any, color: Any, T: Any, voxel_m: float,
                      moved: bool, lo: Any, dims: Any, inv_quantum: float, sums: Any,
                      seen: Any) -> None:  # pragma: no cover - numba
    """Sum voxel samples into a dense box in one pass: each sample at its own voxel, or (moved)
    splatted over the 8 voxels round its moved centre with trilinear weights above 1e-6; every
    summand rounded to the quantum (``round(x * inv_quantum) / inv_quantum``), as
    :func:`_fixed` rounds it. ``sums`` (5, n): weight, weight x tsdf, weight x RGB."""
    n0, n1, n2 = dims[0], dims[1], dims[2]
    q = 1.0 / inv_quantum
    for i in range(coords.shape[0]):
        if moved:
            px = coords[i, 0] * voxel_m
            py = coords[i, 1] * voxel_m
            pz = coords[i, 2] * voxel_m
            qx = (T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]) / voxel_m
            qy = (T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]) / voxel_m
            qz = (T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]) / voxel_m
            fx0, fy0, fz0 = np.floor(qx), np.floor(qy), np.floor(qz)
            fx, fy, fz = qx - fx0, qy - fy0, qz - fz0
            bx, by, bz = int(fx0) - lo[0], int(fy0) - lo[1], int(fz0) - lo[2]
            corners = 8
        else:
            bx, by, bz = coords[i, 0] - lo[0], coords[i, 1] - lo[1], coords[i, 2] - lo[2]
            fx = fy = fz = 0.0
            corners = 1
        for c in range(corners):
            dx, dy, dz = (c >> 2) & 1, (c >> 1) & 1, c & 1
            x, y, z = bx + dx, by + dy, bz + dz
            if x < 0 or y < 0 or z < 0 or x >= n0 or y >= n1 or z >= n2:
                continue
            if moved:
                wt = ((fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
                      * (fz if dz else 1.0 - fz))
                if not wt > 1e-6:
                    continue
                w = weight[i] * wt
            else:
                w = weight[i]
            key = (x * n1 + y) * n2 + z
            seen[key] = True
            sums[0, key] += np.rint(w * inv_quantum) * q
            sums[1, key] += np.rint(w * tsdf[i] * inv_quantum) * q
            sums[2, key] += np.rint(w * color[i, 0] * inv_quantum) * q
            sums[3, key] += np.rint(w * color[i, 1] * inv_quantum) * q
            sums[4, key] += np.rint(w * color[i, 2] * inv_quantum) * q


def _splat(coords: NDArray[np.int64], T: F64, voxel_m: float
           ) -> tuple[NDArray[np.int64], F64]:
    """Trilinear splat of voxel centres moved by ``T``: target coordinates (8K, 3), weights."""
    p = coords.astype(np.float64) * voxel_m
    q = (p @ T[:3, :3].T + T[:3, 3]) / voxel_m
    q0 = np.floor(q)
    f = q - q0
    base = q0.astype(np.int64)
    out_c, out_w = [], []
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                wgt = ((f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                       * (f[:, 2] if dz else 1 - f[:, 2]))
                out_c.append(base + np.array([dx, dy, dz]))
                out_w.append(wgt)
    return np.concatenate(out_c), np.concatenate(out_w)


def _to_blocks(coords: NDArray[np.int64], weight: F64, tsdf: F64, color: F64,
               config: TsdfConfig) -> VoxelBlocks:
    r = config.block_resolution
    if len(coords) == 0:
        return VoxelBlocks(keys=np.zeros((0, 3), np.int32), tsdf=np.zeros((0, r, r, r), np.float32),
                           weight=np.zeros((0, r, r, r), np.float32),
                           color=np.zeros((0, r, r, r, 3), np.float32), voxel_m=config.voxel_m,
                           trunc_voxels=config.trunc_voxels)
    keys = np.floor_divide(coords, r)
    local = coords - keys * r
    k0 = keys.min(axis=0)
    dims = keys.max(axis=0) - k0 + 1
    kk = keys - k0
    lin = (kk[:, 0] * dims[1] + kk[:, 1]) * dims[2] + kk[:, 2]
    ulin, inv = np.unique(lin, return_inverse=True)
    inv = inv.reshape(-1)
    ukeys = np.stack([ulin // (dims[1] * dims[2]), (ulin // dims[2]) % dims[1], ulin % dims[2]],
                     axis=1) + k0
    m = len(ukeys)
    T = np.zeros((m, r, r, r), np.float32)
    W = np.zeros((m, r, r, r), np.float32)
    C = np.zeros((m, r, r, r, 3), np.float32)
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    T[inv, z, y, x] = tsdf
    W[inv, z, y, x] = weight
    C[inv, z, y, x] = color
    return VoxelBlocks(keys=ukeys.astype(np.int32), tsdf=T, weight=W, color=C,
                       voxel_m=config.voxel_m, trunc_voxels=config.trunc_voxels)


def _submap_bounds(keys_: NDArray[np.int32], r: int, voxel_m: float, T_world_grid: F64
                   ) -> tuple[F64, F64]:
    keys = np.asarray(keys_, np.float64)
    lo = keys.min(axis=0) * r * voxel_m
    hi = (keys.max(axis=0) + 1) * r * voxel_m
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    cw = corners @ T_world_grid[:3, :3].T + T_world_grid[:3, 3]
    return cw.min(axis=0), cw.max(axis=0)


@dataclass(frozen=True, kw_only=True, eq=False)
class MergedMap:
    """The result of :func:`merge_submaps`.

    Attributes:
        mesh: the world mesh (metres, vertex colours and normals).
        points: (N, 3) world surface points; colors (N, 3) uint8; normals (N, 3).
        submaps: submaps merged; moved: those a loop closure had moved (splatted).
        voxels: observed voxels of the merged grid.
    """

    mesh: Mesh
    points: F64
    colors: NDArray[np.uint8]
    normals: F64
    submaps: int
    moved: int
    voxels: int


def merge_submaps(
    store: SubmapStore,
    keyframe_poses: dict[int, F64],
    config: TsdfConfig,
    *,
    tile_m: float | None = 2.0,
    progress: Callable[[int], None] | None = None,
) -> MergedMap:
    """Fuse every stored submap into one world grid and extract its mesh and surface points.

    Args:
        store: the finished submaps.
        keyframe_poses: final ``T_world_cam`` of each anchor keyframe (the same camera as the
            one fusion integrated with).
        config: the TSDF layout the submaps were built with.
        tile_m: merge cubes of this edge one at a time (bounds memory to the submaps that
            overlap one tile); None merges everything at once.
        progress: called with 1 per submap read.

    Returns:
        :class:`MergedMap`.

    Raises:
        ReconError: a submap whose anchor keyframe has no pose, or whose voxel layout differs.
    """
    ids = store.ids()
    placed: list[tuple[int, F64, F64, F64, bool]] = []
    for sid in ids:
        sm, keys = _head(store, sid)
        if sm.blocks.voxel_m != config.voxel_m or (
            len(keys) and sm.blocks.block_resolution != config.block_resolution
        ):
            raise ReconError(f"submap {sid} has another voxel layout than the merge's config")
        T_wg = submap_placement(sm, keyframe_poses)
        moved = not np.allclose(T_wg, np.eye(4), atol=_IDENTITY_TOL)
        if len(keys):
            lo, hi = _submap_bounds(keys, sm.blocks.block_resolution, sm.blocks.voxel_m, T_wg)
            placed.append((sid, T_wg, lo, hi, moved))
        if progress is not None:
            progress(1)
    if not placed:
        empty = Mesh(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int64))
        return MergedMap(mesh=empty, points=np.zeros((0, 3)), colors=np.zeros((0, 3), np.uint8),
                         normals=np.zeros((0, 3)), submaps=len(ids), moved=0, voxels=0)
    lo_all = np.min([p[2] for p in placed], axis=0)
    hi_all = np.max([p[3] for p in placed], axis=0)
    tiles = list(_tiles(lo_all, hi_all, tile_m, config.voxel_m))
    meshes: list[Mesh] = []
    pts, cols, nrms = [], [], []
    voxels = 0
    v = config.voxel_m
    r = config.block_resolution
    for c_lo, c_hi in tiles:
        # Voxels of this tile: integer coordinates in [c_lo, c_hi) (the tiles partition the
        # voxels); one block of margin so that marching cubes sees the neighbours of the
        # tile's border voxels.
        t_lo, t_hi = (c_lo * v).astype(np.float64), (c_hi * v).astype(np.float64)
        m_lo, m_hi = c_lo - r, c_hi + r
        acc = _Accumulator(m_lo, m_hi)
        for sid, T_wg, lo, hi, moved in placed:
            if np.any(hi < t_lo - r * v) or np.any(lo > t_hi + r * v):
                continue
            blocks = _reaching(store, sid, r, v, T_wg, moved, m_lo, m_hi)
            if not len(blocks):
                continue
            coords, tsdf, weight, color = _voxel_samples(blocks)
            del blocks
            acc.add_samples(coords, tsdf, weight, color, T_wg if moved else None, v)
        coords, wsum, tmean, cmean = acc.reduce()
        if len(coords) == 0:
            continue
        inner = np.all((coords >= c_lo) & (coords < c_hi), axis=1)
        voxels += int(np.count_nonzero(inner & (wsum > config.weight_threshold)))
        vol = TsdfVolume.from_blocks(_to_blocks(coords, wsum, tmean, cmean, config), config)
        mesh = vol.extract_mesh()
        if len(tiles) > 1 and not mesh.empty:
            mesh = _crop_mesh(mesh, t_lo, t_hi)
        meshes.append(mesh)
        p, c, n = vol.extract_points()
        if len(tiles) > 1 and len(p):
            keep = np.all((p >= t_lo) & (p < t_hi), axis=1)
            p, c, n = p[keep], c[keep], n[keep]
        pts.append(p)
        cols.append(c)
        nrms.append(n)
    mesh = _weld(Mesh.concatenate(meshes)) if len(meshes) > 1 else (
        meshes[0] if meshes else Mesh(vertices=np.zeros((0, 3)),
                                      triangles=np.zeros((0, 3), np.int64)))
    return MergedMap(
        mesh=mesh,
        points=np.concatenate(pts) if pts else np.zeros((0, 3)),
        colors=np.concatenate(cols) if cols else np.zeros((0, 3), np.uint8),
        normals=np.concatenate(nrms) if nrms else np.zeros((0, 3)),
        submaps=len(ids),
        moved=sum(1 for p in placed if p[4]),
        voxels=voxels,
    )


def _tiles(lo: F64, hi: F64, tile_m: float | None, voxel_m: float
           ) -> Iterator[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Boxes of integer voxel coordinates ``[c_lo, c_hi)`` that cover ``[lo, hi]`` (metres):
    cubes of ``tile_m`` rounded to whole voxels, or one box with a metre to spare. Their
    corners are whole voxels, so neighbouring tiles share their faces exactly."""
    if tile_m is None:
        yield (np.floor((lo - 1.0) / voxel_m).astype(np.int64),
               np.floor((hi + 1.0) / voxel_m).astype(np.int64) + 1)
        return
    if not tile_m > 0:
        raise ReconError(f"tile_m must be > 0, got {tile_m}")
    edge = max(round(tile_m / voxel_m), 1)
    start = np.floor(np.asarray(lo, np.float64) / voxel_m).astype(np.int64)
    stop = np.floor(np.asarray(hi, np.float64) / voxel_m).astype(np.int64) + 1
    n = np.maximum(-(-(stop - start) // edge), 1)
    for i in range(n[0]):
        for j in range(n[1]):
            for k in range(n[2]):
                c_lo = start + np.array([i, j, k], np.int64) * edge
                yield c_lo, c_lo + edge


def _crop_mesh(mesh: Mesh, lo: F64, hi: F64) -> Mesh:
    """Triangles whose centroid lies in ``[lo, hi)`` (each lies in exactly one tile)."""
    cen = mesh.vertices[mesh.triangles].mean(axis=1)
    keep = np.all((cen >= lo) & (cen < hi), axis=1)
    tri = mesh.triangles[keep]
    used = np.unique(tri)
    remap = np.full(len(mesh.vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    return Mesh(vertices=mesh.vertices[used], triangles=remap[tri],
                colors_rgb=None if mesh.colors_rgb is None else mesh.colors_rgb[used],
                normals=None if mesh.normals is None else mesh.normals[used])


def _weld(mesh: Mesh, tol_m: float = 1e-6) -> Mesh:
    """Merge vertices that coincide (tile seams) into one."""
    if mesh.empty:
        return mesh
    q = np.round(mesh.vertices / tol_m).astype(np.int64)
    _, first, inv = np.unique(q, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    return Mesh(vertices=mesh.vertices[first], triangles=inv[mesh.triangles],
                colors_rgb=None if mesh.colors_rgb is None else mesh.colors_rgb[first],
                normals=None if mesh.normals is None else mesh.normals[first])


def iter_submaps(store: SubmapStore) -> Iterable[Submap]:
    """Every stored submap in id order."""
    for sid in store.ids():
        yield store.get(sid)


__all__ += ["MergedMap", "iter_submaps"]
