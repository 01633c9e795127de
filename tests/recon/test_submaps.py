"""Keyframe-anchored submaps: exact merge, loop closures move anchors, bounded memory."""

from dataclasses import replace

import numpy as np
import pytest

from sea3d.errors import ReconError
from sea3d.geometry.se3 import rotvec_to_R
from sea3d.pipeline.submap_store import DiskSubmapStore
from sea3d.recon.submaps import (
    FusionConfig,
    MemorySubmapStore,
    SubmapFusion,
    merge_submaps,
    submap_placement,
)
from sea3d.recon.tsdf import TsdfConfig, TsdfVolume
from synthetic_views import BOX_HI, K, render, survey_poses

VOXEL_M = 0.02
TSDF = TsdfConfig(voxel_m=VOXEL_M)
# Merging submaps whose grids coincide with the world is a weighted mean of the same values a
# single volume accumulates: equal up to float32 rounding.
EXACT_MERGE_TOL_M = 1e-6
# Where the box top must be after fusion (a quarter voxel; a wrongly placed submap is off by
# the whole planted error, 10 cm).
PLACE_TOL_M = VOXEL_M / 4


def _sorted(v):
    return v[np.lexsort(v.T[::-1])]


def _run(poses_used, keyframes, fusion, store, kf_poses=None):
    kf = {} if kf_poses is None else kf_poses
    for i, T in enumerate(poses_used):
        d, c = render(_TRUE[i])  # images from the true poses, integrated with poses_used
        kid = keyframes.get(i)
        if kid is not None:
            kf[kid] = T
        st = fusion.step(t_ns=i, trusted=True, keyframe_id=kid, depth_m=d, color_rgb=c, K=K,
                         T_world_cam=T, keyframe_poses=kf)
        for sm in st.finished:
            store.put(sm)
    last = fusion.finish()
    if last is not None:
        store.put(last)
    return kf


_TRUE = survey_poses(12)
_KEYFRAMES = {i: i // 2 for i in range(0, 12, 2)}


@pytest.fixture(scope="module")
def single_volume_mesh():
    vol = TsdfVolume(TSDF)
    for T in _TRUE:
        d, c = render(T)
        vol.integrate(d, c, K, T)
    return vol.extract_mesh()


def test_merge_without_loop_closure_equals_one_volume(single_volume_mesh):
    store = MemorySubmapStore()
    fusion = SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=2))
    kf = _run(_TRUE, _KEYFRAMES, fusion, store)
    assert store.ids() == [0, 1, 2]
    merged = merge_submaps(store, kf, TSDF, tile_m=None)
    assert merged.moved == 0
    a, b = _sorted(merged.mesh.vertices), _sorted(single_volume_mesh.vertices)
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, atol=EXACT_MERGE_TOL_M)


def test_tiled_merge_equals_the_whole_merge():
    store = MemorySubmapStore()
    kf = _run(_TRUE, _KEYFRAMES, SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=3)),
              store)
    whole = merge_submaps(store, kf, TSDF, tile_m=None).mesh
    tiled = merge_submaps(store, kf, TSDF, tile_m=1.2).mesh  # several tiles: seams cross the map
    assert len(tiled.triangles) == len(whole.triangles)
    np.testing.assert_allclose(_sorted(tiled.vertices), _sorted(whole.vertices), atol=1e-9)


def _box_top(mesh):
    v = mesh.vertices
    top = v[(v[:, 2] > 0.15) & (np.abs(v[:, 0]) < 0.15) & (np.abs(v[:, 1]) < 0.1)]
    return np.median(top, axis=0), len(top)


def _fuse_frames(store, poses=_TRUE, frames=range(6, 12)):
    """``frames`` (rendered at their true poses; by default 6-11: one submap of keyframes
    3, 4, 5 at frames 6, 8, 10) integrated at ``poses`` into submaps of three keyframes;
    returns their keyframe poses."""
    fusion = SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=3))
    kf: dict[int, np.ndarray] = {}
    for i in frames:
        d, c = render(_TRUE[i])
        kid = _KEYFRAMES.get(i)
        if kid is not None:
            kf[kid] = poses[i]
        for sm in fusion.step(t_ns=i, trusted=True, keyframe_id=kid, depth_m=d, color_rgb=c,
                              K=K, T_world_cam=poses[i], keyframe_poses=kf).finished:
            store.put(sm)
    store.put(fusion.finish())
    return kf


def test_a_loop_closure_moves_the_submaps_anchor_not_its_voxels():
    # The odometry drifted: from frame 6 on every pose is 10 cm too high and turned 3 degrees.
    drift = np.eye(4)
    drift[:3, :3] = rotvec_to_R(np.array([0.0, 0.0, np.deg2rad(3.0)]))
    drift[:3, 3] = (0.0, 0.0, 0.10)
    drifted = [T if i < 6 else drift @ T for i, T in enumerate(_TRUE)]
    only_late = {i: k for i, k in _KEYFRAMES.items() if i >= 6}
    store = MemorySubmapStore()
    # Frames 6-11 only, so the drifted part is one submap we can look at alone.
    kf = _fuse_frames(store, drifted)
    before = merge_submaps(store, kf, TSDF, tile_m=None)
    top_before, _ = _box_top(before.mesh)
    assert top_before[2] == pytest.approx(BOX_HI[2] + 0.10, abs=PLACE_TOL_M)
    # The loop closure puts the keyframes back where they belong; no frame is integrated again.
    corrected = {k: _TRUE[i] for i, k in only_late.items()}
    after = merge_submaps(store, corrected, TSDF, tile_m=None)
    assert after.moved == 1
    top_after, n = _box_top(after.mesh)
    assert n > 100
    assert top_after[2] == pytest.approx(BOX_HI[2], abs=PLACE_TOL_M)
    assert abs(top_after[0]) < 0.02


def _raised(T, dz):
    out = T.copy()
    out[2, 3] += dz
    return out


def test_a_submap_is_placed_where_it_fits_all_its_keyframes():
    store = MemorySubmapStore()
    kf = _fuse_frames(store)
    sm = store.get(0)
    assert sm.view_keyframe_ids == (3, 4, 5) and sm.T_grid_views.shape == (3, 4, 4)
    assert np.all(sm.view_depth_m > 0.3)
    # Unmoved: the identity, so the merge stays exact.
    np.testing.assert_allclose(submap_placement(sm, kf), np.eye(4), atol=1e-12)
    # Every keyframe moved alike: the submap moves with them, as its anchor would move it.
    up = {k: _raised(T, 0.03) for k, T in kf.items()}
    np.testing.assert_allclose(submap_placement(sm, up)[:3, 3], (0, 0, 0.03), atol=1e-9)
    # Only the anchor corrected by 3 cm (the other two keyframes stay): placed by its anchor,
    # the whole submap would move 3 cm; it moves by the least-squares fit of all three views,
    # a third of that where its keyframes looked, and the box top follows.
    anchor_only = {**kf, 3: _raised(kf[3], 0.03)}
    T = submap_placement(sm, anchor_only)
    seen = np.array([Tv[:3, :3] @ (0.0, 0.0, z) + Tv[:3, 3]
                     for Tv, z in zip(sm.T_grid_views, sm.view_depth_m, strict=True)])
    shift = (seen @ T[:3, :3].T + T[:3, 3] - seen).mean(axis=0)
    np.testing.assert_allclose(shift, (0, 0, 0.01), atol=1e-3)
    top, n = _box_top(merge_submaps(store, anchor_only, TSDF, tile_m=None).mesh)
    assert n > 100
    assert top[2] == pytest.approx(BOX_HI[2] + 0.01, abs=PLACE_TOL_M)


def test_a_submap_without_views_is_placed_by_its_anchor(tmp_path):
    store = MemorySubmapStore()
    kf = _fuse_frames(store)
    sm = replace(store.get(0), view_keyframe_ids=(), T_grid_views=np.zeros((0, 4, 4)),
                 view_depth_m=np.zeros(0))
    anchor_only = {**kf, 3: _raised(kf[3], 0.03)}
    np.testing.assert_allclose(submap_placement(sm, anchor_only)[:3, 3], (0, 0, 0.03),
                               atol=1e-9)
    # The disk store keeps the views (and reads a submap written without them).
    disk = DiskSubmapStore(tmp_path / "submaps")
    disk.put(store.get(0))
    disk.put(replace(sm, submap_id=1))
    back, _ = disk.head(0)
    assert back.view_keyframe_ids == (3, 4, 5)
    np.testing.assert_array_equal(back.T_grid_views, store.get(0).T_grid_views)
    np.testing.assert_array_equal(disk.get(0).view_depth_m, store.get(0).view_depth_m)
    assert disk.get(1).view_keyframe_ids == ()


def test_a_moved_merge_in_small_batches_equals_the_whole_merge(monkeypatch):
    """The merge splats a moved submap in chunks and sums its accumulator when it grows
    (bounded memory); with chunks and sums of a few hundred voxels the mesh is the same."""
    import sea3d.recon.submaps as submaps

    store = MemorySubmapStore()
    kf = _fuse_frames(store, frames=range(6))
    nudge = np.eye(4)
    nudge[:3, :3] = rotvec_to_R(np.array([0.0, 0.0, np.deg2rad(1.0)]))
    nudge[:3, 3] = (0.013, 0.0, 0.0)
    moved = {k: nudge @ T for k, T in kf.items()}
    whole = merge_submaps(store, moved, TSDF, tile_m=None)
    assert whole.moved >= 1
    monkeypatch.setattr(submaps, "_SPLAT_CHUNK", 500)
    monkeypatch.setattr(submaps, "_COMPACT_AT", 3000)
    small = merge_submaps(store, moved, TSDF, tile_m=None)
    assert len(small.mesh.triangles) == len(whole.mesh.triangles) > 1000

    def ordered(v: np.ndarray) -> np.ndarray:  # the mesh's vertex order is the hash map's
        # sorted on the exact coordinates: with rounded ones, two vertices closer than the
        # rounding tie and come out in either order (the 4.4e-6 m "differences" seen once)
        return v[np.lexsort(v.T[::-1])]

    # Bit-identical: every summand is fixed-point, so neither the chunks, the compactions nor
    # the order of the submaps' blocks (Open3D's hash map order) changes a sum.
    np.testing.assert_array_equal(ordered(small.mesh.vertices), ordered(whole.mesh.vertices))
    shuffled = MemorySubmapStore()
    rng = np.random.default_rng(0)
    for sid in store.ids():
        sm = store.get(sid)
        b = sm.blocks
        perm = rng.permutation(len(b))
        shuffled.put(replace(sm, blocks=replace(b, keys=b.keys[perm], tsdf=b.tsdf[perm],
                                                weight=b.weight[perm], color=b.color[perm])))
    again = merge_submaps(shuffled, moved, TSDF, tile_m=None)
    np.testing.assert_array_equal(ordered(again.mesh.vertices), ordered(whole.mesh.vertices))
    np.testing.assert_array_equal(np.sort(again.colors, axis=0), np.sort(whole.colors, axis=0))


def test_a_tiled_merge_of_moved_submaps_equals_the_whole_merge():
    """Each tile reads only the blocks of a submap that can reach it (moved ones: by their
    moved centres); with tiles far smaller than a submap the mesh is the whole merge's."""
    store = MemorySubmapStore()
    kf = _run(_TRUE, _KEYFRAMES, SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=2)),
              store)
    nudge = np.eye(4)
    nudge[:3, :3] = rotvec_to_R(np.array([0.02, -0.01, np.deg2rad(2.0)]))
    nudge[:3, 3] = (0.013, -0.021, 0.007)
    # anchors are keyframes 0, 2, 4: the middle submap moves, the others stay
    moved = {k: (nudge @ T if k in (2, 3) else T) for k, T in kf.items()}
    whole = merge_submaps(store, moved, TSDF, tile_m=None)
    assert 0 < whole.moved < len(store.ids())
    tiled = merge_submaps(store, moved, TSDF, tile_m=0.3)
    assert len(tiled.mesh.triangles) == len(whole.mesh.triangles) > 1000
    np.testing.assert_allclose(_sorted(tiled.mesh.vertices), _sorted(whole.mesh.vertices),
                               atol=1e-9)
    assert tiled.voxels == whole.voxels


def test_dense_and_sparse_tile_sums_give_the_same_merge(monkeypatch):
    """A small tile's voxels are summed in dense arrays, a large one's in sorted batches:
    fixed-point summands make the two bit-identical (moved submaps included)."""
    import sea3d.recon.submaps as submaps

    store = MemorySubmapStore()
    kf = _run(_TRUE, _KEYFRAMES, SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=2)),
              store)
    nudge = np.eye(4)
    nudge[:3, :3] = rotvec_to_R(np.array([0.0, 0.0, np.deg2rad(1.0)]))
    nudge[:3, 3] = (0.013, 0.0, 0.0)
    moved = {k: (nudge @ T if k in (2, 3) else T) for k, T in kf.items()}
    monkeypatch.setattr(submaps, "_DENSE_AT", 10**9)
    dense = merge_submaps(store, moved, TSDF, tile_m=0.6)
    monkeypatch.setattr(submaps, "_DENSE_AT", 0)
    monkeypatch.setattr(submaps, "_COMPACT_AT", 5000)
    sparse = merge_submaps(store, moved, TSDF, tile_m=0.6)
    assert dense.voxels == sparse.voxels and dense.moved == 1
    assert len(dense.mesh.triangles) == len(sparse.mesh.triangles) > 1000
    np.testing.assert_array_equal(_sorted(dense.mesh.vertices), _sorted(sparse.mesh.vertices))
    # the points come in Open3D's hash-map order: compare them sorted, colours with them
    a, b = np.lexsort(dense.points.T[::-1]), np.lexsort(sparse.points.T[::-1])
    np.testing.assert_array_equal(dense.points[a], sparse.points[b])
    np.testing.assert_array_equal(dense.colors[a], sparse.colors[b])


def test_memory_is_bounded_by_the_active_submap():
    cfg = FusionConfig(tsdf=TSDF, keyframes_per_submap=100, max_blocks=150)
    fusion = SubmapFusion(cfg)
    store = MemorySubmapStore()
    poses = survey_poses(16, span_m=3.0)
    kf: dict[int, np.ndarray] = {}
    for i, T in enumerate(poses):
        d, c = render(T)
        kid = i if i % 4 == 0 else None  # full submaps end between keyframes too
        if kid is not None:
            kf[kid] = T
        for sm in fusion.step(t_ns=i, trusted=True, keyframe_id=kid, depth_m=d, color_rgb=c,
                              K=K, T_world_cam=T, keyframe_poses=kf).finished:
            assert len(sm.blocks) <= 2 * cfg.max_blocks  # one frame's blocks past the limit
            store.put(sm)
        # What fusion holds stays bounded however far the survey goes.
        assert fusion.memory_bytes() <= 1024 * TSDF.block_bytes
    store.put(fusion.finish())
    assert len(store.ids()) >= 3


def test_untrusted_frames_and_non_keyframes_by_policy():
    d, c = render(_TRUE[0])
    f = SubmapFusion(FusionConfig(tsdf=TSDF, integrate="keyframes"))
    kf = {0: _TRUE[0]}
    args = {"depth_m": d, "color_rgb": c, "K": K, "T_world_cam": _TRUE[0]}
    assert f.step(t_ns=0, trusted=False, keyframe_id=0, keyframe_poses=kf,
                  **args).status == "skipped_untrusted"
    assert f.step(t_ns=1, trusted=True, keyframe_id=None, keyframe_poses=kf,
                  **args).status == "skipped_not_keyframe"
    assert f.step(t_ns=2, trusted=True, keyframe_id=0, keyframe_poses=kf,
                  **args).status == "integrated"
    g = SubmapFusion(FusionConfig(tsdf=TSDF))
    assert g.step(t_ns=0, trusted=True, keyframe_id=None, keyframe_poses={},
                  **args).status == "skipped_no_anchor"


def test_disk_store_round_trip_and_damage(tmp_path):
    store = DiskSubmapStore(tmp_path / "submaps")
    fusion = SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=2))
    kf = _run(_TRUE[:6], {0: 0, 2: 1, 4: 2}, fusion, store)
    mem = merge_submaps(store, kf, TSDF).mesh
    back = store.get(0)
    assert back.frames == 4 and back.keyframe_ids == (0, 1)
    assert len(mem.triangles) > 1000
    p = tmp_path / "submaps" / "1.s3c"
    data = bytearray(p.read_bytes())
    data[-10] ^= 0xFF
    p.write_bytes(bytes(data))
    with pytest.raises(ReconError, match=r"submap 1 .* damaged.*checksum"):
        store.get(1)
    with pytest.raises(ReconError, match="anchor keyframe"):
        merge_submaps(store, {}, TSDF)


def test_a_merge_from_chunks_on_disk_equals_the_merge_in_memory(tmp_path, monkeypatch):
    """On disk a submap's blocks are stored in chunks and each tile reads only the chunks
    that reach it; with chunks of 64 blocks and small tiles, moved and unmoved submaps, the
    mesh and the voxel count are those of the merge from memory."""
    import sea3d.pipeline.submap_store as submap_store

    monkeypatch.setattr(submap_store, "CHUNK_BLOCKS", 64)
    mem = MemorySubmapStore()
    kf = _run(_TRUE, _KEYFRAMES, SubmapFusion(FusionConfig(tsdf=TSDF, keyframes_per_submap=2)),
              mem)
    disk = DiskSubmapStore(tmp_path / "submaps")
    for sid in mem.ids():
        disk.put(mem.get(sid))
    chunks = list((tmp_path / "submaps").glob("*.c*.s3c"))
    assert len(chunks) > 3 * len(mem.ids())  # several chunks per submap
    assert disk.ids() == mem.ids()
    back, keys = disk.head(1)
    assert len(back.blocks) == 0 and len(keys) == len(mem.get(1).blocks)
    nudge = np.eye(4)
    nudge[:3, :3] = rotvec_to_R(np.array([0.0, 0.01, np.deg2rad(1.5)]))
    nudge[:3, 3] = (0.011, 0.0, -0.006)
    moved = {k: (nudge @ T if k in (2, 3) else T) for k, T in kf.items()}
    want = merge_submaps(mem, moved, TSDF, tile_m=None)
    got = merge_submaps(disk, moved, TSDF, tile_m=0.3)
    assert got.moved == want.moved == 1 and got.voxels == want.voxels
    assert len(got.mesh.triangles) == len(want.mesh.triangles) > 1000
    np.testing.assert_allclose(_sorted(got.mesh.vertices), _sorted(want.mesh.vertices),
                               atol=1e-9)
    whole = disk.get(1)  # read back whole: the same blocks, in key order
    ref = mem.get(1).blocks
    order = np.lexsort(ref.keys.T[::-1])
    np.testing.assert_array_equal(whole.blocks.keys, ref.keys[order])
    np.testing.assert_array_equal(whole.blocks.tsdf, ref.tsdf[order])
    # tiles that share chunks read each chunk file once while it is kept; none kept, the
    # merge reads them again for every tile that reaches them, and gives the same mesh
    reads: list[str] = []
    real_read = submap_store.read_entry

    def counted(path):
        reads.append(path.name)
        return real_read(path)

    monkeypatch.setattr(submap_store, "read_entry", counted)
    for cache_bytes in (submap_store.CHUNK_CACHE_BYTES, 0):
        reads.clear()
        again = merge_submaps(DiskSubmapStore(tmp_path / "submaps", cache_bytes=cache_bytes),
                              moved, TSDF, tile_m=0.3)
        chunk_reads = [r for r in reads if ".c" in r]
        np.testing.assert_allclose(_sorted(again.mesh.vertices), _sorted(got.mesh.vertices),
                                   atol=1e-9)
        if cache_bytes:
            assert len(chunk_reads) == len(set(chunk_reads))
        else:
            assert len(chunk_reads) > len(set(chunk_reads))


def test_a_surface_seen_once_is_dropped_when_two_observations_are_required():
    """A floater: one frame's depth holds a blob 40 cm in front of the floor. Merged with
    voxels seen once kept, the mesh has vertices there; requiring two observations (the
    process default, MapConfig.min_observations) drops them and keeps the box top, which
    every frame sees."""
    from sea3d.pipeline.config import MapConfig

    cfg2 = MapConfig().fusion((0.1, 5.0)).tsdf
    assert cfg2.weight_threshold == 1.5
    cfg1 = TsdfConfig(voxel_m=VOXEL_M, min_depth_m=0.1, max_depth_m=5.0, weight_threshold=0.5)
    store = MemorySubmapStore()
    fusion = SubmapFusion(FusionConfig(tsdf=cfg2, keyframes_per_submap=2))
    kf: dict = {}
    for i, T in enumerate(_TRUE):
        d, c = render(T)
        if i == 5:  # the wrong depth: a 40 x 40 px patch 0.4 m nearer than what it sees
            h = d.shape[0]
            d = d.copy()
            d[h // 2 - 20:h // 2 + 20, 10:50] -= 0.4
        kid = _KEYFRAMES.get(i)
        if kid is not None:
            kf[kid] = T
        st = fusion.step(t_ns=i, trusted=True, keyframe_id=kid, depth_m=d, color_rgb=c, K=K,
                         T_world_cam=T, keyframe_poses=kf)
        for sm in st.finished:
            store.put(sm)
    store.put(fusion.finish())
    T5 = _TRUE[5]
    h = d.shape[0]
    # the blob's points in the world: where the wrong depth puts them
    d5, _ = render(T5)
    vv, uu = np.mgrid[h // 2 - 20:h // 2 + 20, 10:50]
    z = d5[vv, uu] - 0.4
    x = (uu - K[0, 2]) * z / K[0, 0]
    y = (vv - K[1, 2]) * z / K[1, 1]
    blob = np.stack([x.ravel(), y.ravel(), z.ravel()], 1) @ T5[:3, :3].T + T5[:3, 3]
    centre = np.nanmean(blob, axis=0)

    def near_blob(mesh):
        return int(np.sum(np.linalg.norm(mesh.vertices - centre, axis=1) < 0.05))

    once = merge_submaps(store, kf, cfg1, tile_m=None).mesh
    twice = merge_submaps(store, kf, cfg2, tile_m=None).mesh
    assert near_blob(once) > 20  # the floater is in the mesh that keeps voxels seen once
    assert near_blob(twice) == 0
    (_, n_once), (z_twice, n_twice) = _box_top(once), _box_top(twice)
    assert n_twice > 0.9 * n_once
    assert abs(z_twice[2] - BOX_HI[2]) < PLACE_TOL_M


@pytest.mark.parametrize("moved", [False, True])
def test_the_one_pass_dense_sum_equals_the_splat_and_sort_sum(moved):
    """A tile's box summed in dense arrays by one pass over the samples gives the sums the
    sparse path gives from the splat's targets (sorted and reduced), to the bit."""
    from sea3d.recon.submaps import _Accumulator

    rng = np.random.default_rng(5)
    coords = rng.integers(-20, 60, (5000, 3))
    tsdf = rng.uniform(-1, 1, 5000)
    weight = rng.integers(1, 40, 5000).astype(np.float64)
    color = rng.uniform(0, 1, (5000, 3))
    T = np.eye(4)
    T[:3, :3] = rotvec_to_R(np.array([0.02, -0.01, 0.03]))
    T[:3, 3] = (0.013, -0.027, 0.004)
    lo, hi = np.array([0, -5, 3]), np.array([40, 50, 45])
    sums = []
    for dense_at in (10**9, 0):
        acc = _Accumulator(lo, hi, dense_at=dense_at)
        assert acc.dense == (dense_at > 0)
        acc.add_samples(coords, tsdf, weight, color, T if moved else None, 0.02)
        sums.append(acc.reduce())
    for a, b in zip(*sums, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(sums[0][0]) > 500
