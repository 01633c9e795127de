"""TSDF fusion on Open3D's VoxelBlockGrid: surface really integrated, poses, colours, arrays.

Open3D's legacy ScalableTSDFVolume has been seen to integrate nothing in CPU wheels; these
tests would see that (no triangles, or triangles off the surface).
"""

import numpy as np
import open3d as o3d
import open3d.core as o3c
import pytest

from sea3d.errors import ReconError
from sea3d.geometry.se3 import look_at
from sea3d.recon.tsdf import TsdfConfig, TsdfVolume
from synthetic_views import BOX_HI, BOX_LO, K, render, survey_poses

VOXEL_M = 0.02
# Marching cubes on a TSDF of a plane puts vertices within a small fraction of a voxel of it;
# a quarter voxel (5 mm) is far below what a pose or extrinsic bug (decimetres) would give.
ON_SURFACE_TOL_M = VOXEL_M / 4
COLOUR_TOL = 2  # grey levels: float accumulation and rounding


def _sorted_rows(a):
    return a[np.lexsort(a.T[::-1])]


def test_volume_holds_the_surface_after_integration():
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M))
    T = look_at((0.3, -0.5, 1.2), (0.0, 0.0, 0.0), up=(0, 1, 0))
    depth, col = render(T, box=False)
    assert vol.integrate(depth, col, K, T) > 0
    mesh = vol.extract_mesh()
    # The floor seen from 1.3 m covers about 2 m^2: tens of thousands of triangles.
    assert len(mesh.triangles) > 5000
    assert np.abs(mesh.vertices[:, 2]).max() < ON_SURFACE_TOL_M
    pts, _, nrm = vol.extract_points()
    assert len(pts) > 1000 and np.abs(pts[:, 2]).max() < ON_SURFACE_TOL_M
    # Normals of the floor point up or down, never sideways.
    assert np.median(np.abs(nrm[:, 2])) > 0.99


def test_poses_place_the_box_in_the_world():
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M))
    for T in survey_poses(6):
        d, c = render(T)
        vol.integrate(d, c, K, T)
    m = vol.extract_mesh()
    v = m.vertices
    top = v[(v[:, 2] > 0.15) & (np.abs(v[:, 0]) < 0.2) & (np.abs(v[:, 1]) < 0.15)]
    # The box top is at z = 0.3 m over x in [-0.25, 0.25]: from every camera pose alike.
    assert abs(np.median(top[:, 2]) - BOX_HI[2]) < ON_SURFACE_TOL_M
    assert abs(np.median(top[:, 0])) < 0.05


def _open3d_direct(frames, K_o3d, max_depth_m=3.0):
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=VOXEL_M, block_resolution=8,
        block_count=1000, device=o3c.Device("CPU:0"))
    Kt = o3c.Tensor(K_o3d)
    for T, d, c in frames:
        E = o3c.Tensor(np.linalg.inv(T))
        di = o3d.t.geometry.Image(o3c.Tensor(np.nan_to_num(d, nan=0.0)))
        ci = o3d.t.geometry.Image(o3c.Tensor(c.astype(np.float32) / 255.0))
        blocks = vbg.compute_unique_block_coordinates(di, Kt, E, 1.0, max_depth_m, 4.0)
        vbg.integrate(blocks, di, ci, Kt, Kt, E, 1.0, max_depth_m, 4.0)
    return vbg.extract_triangle_mesh(0.5).vertex.positions.numpy().astype(np.float64)


def test_same_mesh_as_open3d_called_directly_with_pixel_centres_at_integers():
    ours = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, max_depth_m=3.0))
    frames = [(T, *render(T)) for T in survey_poses(4)]
    for T, d, c in frames:
        ours.integrate(d, c, K, T)
    a = ours.extract_mesh().vertices
    K_half = K.copy()
    K_half[:2, 2] += 0.5  # Open3D truncates projections: this makes it read the nearest pixel
    b = _open3d_direct(frames, K_half)
    assert a.shape == b.shape
    np.testing.assert_allclose(_sorted_rows(a), _sorted_rows(b), atol=1e-6)


def test_half_pixel_convention_removes_a_depth_bias_on_slanted_surfaces():
    T = look_at((0.3, -0.9, 1.0), (0.0, 0.0, 0.0), up=(0, 1, 0))  # the floor at about 45 deg
    d, c = render(T, box=False)
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M))
    vol.integrate(d, c, K, T)
    ours = np.median(vol.extract_mesh().vertices[:, 2])
    naive = np.median(_open3d_direct([(T, d, c)], K)[:, 2])
    # Open3D with K as it is reads the pixel up and left of the projection: the floor comes
    # out 6.6 mm low (measured); ours is centred on it.
    assert abs(ours) < 0.5e-3
    assert naive < -3e-3


def test_colours_are_the_images_colours():
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M))
    T = look_at((0.0, -0.2, 1.0), (0.0, 0.0, 0.0), up=(0, 1, 0))
    d, _ = render(T, box=False)
    col = np.zeros((*d.shape, 3), np.uint8)
    col[:] = (200, 30, 90)
    vol.integrate(d, col, K, T)
    m = vol.extract_mesh()
    assert m.colors_rgb is not None
    assert np.abs(m.colors_rgb.astype(int) - [200, 30, 90]).max() <= COLOUR_TOL


def test_blocks_round_trip_to_an_identical_mesh():
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M))
    for T in survey_poses(3):
        d, c = render(T)
        vol.integrate(d, c, K, T)
    blocks = vol.export_blocks()
    # Blocks allocated around the surface but never observed are left out.
    assert 0 < len(blocks) <= vol.block_count and blocks.weight.max() == 3
    back = TsdfVolume.from_blocks(blocks)
    m1, m2 = vol.extract_mesh(), back.extract_mesh()
    np.testing.assert_array_equal(_sorted_rows(m1.vertices), _sorted_rows(m2.vertices))


def test_invalid_and_out_of_range_depth_is_ignored():
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, max_depth_m=2.0))
    d = np.full((20, 30), np.nan, np.float32)
    assert vol.integrate(d, None, K, np.eye(4)) == 0
    d[:] = 3.0  # beyond max_depth_m
    assert vol.integrate(d, None, K, np.eye(4)) == 0
    assert vol.extract_mesh().empty and vol.frames == 0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"voxel_m": 0.0}, "voxel_m"), ({"block_resolution": 5}, "block_resolution"),
     ({"min_depth_m": 2.0, "max_depth_m": 1.0}, "min_depth_m")],
)
def test_bad_config(kwargs, message):
    with pytest.raises(ReconError, match=message):
        TsdfConfig(**kwargs)


def test_bad_inputs():
    vol = TsdfVolume()
    with pytest.raises(ReconError, match="colour"):
        vol.integrate(np.ones((4, 4), np.float32), np.zeros((4, 5, 3), np.uint8), K, np.eye(4))
    with pytest.raises(ReconError, match="intrinsics"):
        vol.integrate(np.ones((4, 4), np.float32), None, np.eye(2), np.eye(4))
    with pytest.raises(ReconError, match="T_volume_cam"):
        vol.integrate(np.ones((4, 4), np.float32), None, K, np.full((4, 4), np.nan))


# -- free-space carving ---------------------------------------------------------------------

FLOATER_M = 0.05  # a vertex this far from the floor and the box is off the scene (2.5 voxels)


def _scene_distance(p):
    """Distance (m) of points to the synthetic scene: the floor z = 0 and the box's faces."""
    lo, hi = BOX_LO, BOX_HI
    outside = np.linalg.norm(np.maximum(np.maximum(lo - p, 0.0), p - hi), axis=1)
    inside = np.minimum(p - lo, hi - p).min(axis=1)
    box = np.where(outside > 0, outside, inside)
    return np.minimum(np.abs(p[:, 2]), box)


def _survey_with_floater(carve, *, floater=True, n=8):
    """The box survey; the first frame's depth wrong by 30 % on a 24 x 24 patch (a
    mismatched region: a surface 0.3-0.4 m in front of the floor, in free space)."""
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, carve_free_space=carve))
    for i, T in enumerate(survey_poses(n, span_m=0.6)):
        d, c = render(T)
        if floater and i == 0:
            d[20:44, 20:44] *= 0.7
        vol.integrate(d, c, K, T)
    return vol


def test_carving_removes_a_floater_that_later_frames_see_through():
    plain = _survey_with_floater(False).extract_mesh()
    carved_vol = _survey_with_floater(True)
    carved = carved_vol.extract_mesh()
    # Without carving the patch stays in the mesh, hundreds of vertices off the scene
    # (Open3D updates only the blocks near each frame's own surface).
    assert (_scene_distance(plain.vertices) > FLOATER_M).sum() > 100
    assert (_scene_distance(carved.vertices) > FLOATER_M).sum() == 0
    assert carved_vol.voxels_carved > 0


def test_carving_keeps_the_true_surface_and_its_edges():
    # No floater: the box's silhouette edges have background depth beside them in every
    # view, and carving must not eat them (the 3x3 minimum of the depth guards them).
    plain = _survey_with_floater(False, floater=False).extract_mesh()
    carved = _survey_with_floater(True, floater=False).extract_mesh()
    near_p = _scene_distance(plain.vertices) < ON_SURFACE_TOL_M
    near_c = _scene_distance(carved.vertices) < ON_SURFACE_TOL_M
    # The same surface to within 1 % of its vertices, none moved off it.
    assert near_c.sum() >= 0.99 * near_p.sum()
    assert np.abs(_scene_distance(carved.vertices)).max() <= np.abs(
        _scene_distance(plain.vertices)).max() + 1e-9
    top = carved.vertices[(carved.vertices[:, 2] > 0.25)]
    assert len(top) > 0.99 * (plain.vertices[:, 2] > 0.25).sum()


def test_carving_needs_a_finite_noise_model():
    with pytest.raises(ReconError, match="depth_noise_per_m"):
        TsdfConfig(depth_noise_per_m=-1.0)


def test_hole_margin_leaves_out_the_wrong_depth_around_a_hole():
    # A stereo hole (20 x 30 px without depth) rimmed by 2 px of depth 20 % short: the rim is
    # where a matcher's wrong depth gathers. hole_margin_px = 2 fuses none of it and keeps
    # the floor elsewhere (its grid cells of 2 cm: vertex counts within 5 %).
    T = look_at((0.0, -0.6, 1.2), (0.0, 0.0, 0.0), up=(0, 1, 0))
    d, c = render(T, box=False)
    d[38:62, 58:92] *= 0.8
    d[40:60, 60:90] = np.nan
    meshes = []
    for margin in (0, 2):
        vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, hole_margin_px=margin))
        vol.integrate(d, c, K, T)
        meshes.append(vol.extract_mesh())
    plain, kept = meshes
    assert (_scene_distance(plain.vertices) > FLOATER_M).sum() > 20
    assert (_scene_distance(kept.vertices) > FLOATER_M).sum() == 0
    on_floor = [(np.abs(m.vertices[:, 2]) < ON_SURFACE_TOL_M).sum() for m in meshes]
    assert on_floor[1] >= 0.95 * on_floor[0]
    with pytest.raises(ReconError, match="hole_margin_px"):
        TsdfConfig(hole_margin_px=-1)


# -- confidence ------------------------------------------------------------------------------

def _floor_twice(cfg, conf_a, conf_b, *, dz=0.01):
    """The floor seen from above at 1.2 m, twice: once at its true depth with confidence
    ``conf_a``, once ``dz`` too far with ``conf_b``; the mesh's median height."""
    T = look_at((0.0, 0.0, 1.2), (0.0, 0.0, 0.0), up=(0, 1, 0))
    d, c = render(T, box=False)
    vol = TsdfVolume(cfg)
    vol.integrate(d, c, K, T, confidence=np.full(d.shape, conf_a, np.float32))
    vol.integrate(d + np.float32(dz), c, K, T, confidence=np.full(d.shape, conf_b, np.uint8)
                  if isinstance(conf_b, int) else np.full(d.shape, conf_b, np.float32))
    m = vol.extract_mesh(0.0)
    return vol, float(np.median(m.vertices[:, 2]))


def test_confidence_weights_each_observation():
    # Two views of the floor, the second 1 cm too far: with weights 0.8 and 0.2 the
    # surface sits at 0.2 of the way (2 mm below the floor), unweighted at half (5 mm).
    # Depth along the camera's z is height below it: a farther depth is a lower floor.
    cfg = TsdfConfig(voxel_m=VOXEL_M, confidence_full=1.0)
    vol, z = _floor_twice(cfg, 0.8, 0.2)
    assert z == pytest.approx(-0.002, abs=0.0005)
    blocks = vol.export_blocks()
    w = blocks.weight[blocks.weight > 0]
    np.testing.assert_allclose(np.median(w), 1.0, atol=1e-5)  # 0.8 + 0.2
    plain, zp = _floor_twice(TsdfConfig(voxel_m=VOXEL_M), 0.8, 0.2)
    assert zp == pytest.approx(-0.005, abs=0.0005)
    bp = plain.export_blocks()
    assert np.median(bp.weight[bp.weight > 0]) == 2.0  # unit weights without confidence_full


def test_confidence_full_caps_weights_at_one_and_reads_uint8():
    # Full at 0.5: confidence 0.9 weighs 1, uint8 64 (0.25) weighs half.
    cfg = TsdfConfig(voxel_m=VOXEL_M, confidence_full=0.5)
    vol, z = _floor_twice(cfg, 0.9, 64)
    w = vol.export_blocks().weight
    assert np.median(w[w > 0]) == pytest.approx(1.0 + (64 / 255) / 0.5, abs=1e-5)
    # the observation of weight 0.502 pulls the surface a third of the 1 cm
    assert z == pytest.approx(-0.01 * 0.502 / 1.502, abs=0.0005)


def test_weighting_drops_a_low_confidence_surface_seen_once():
    # With confidence_full 0.5 a view at confidence 0.3 weighs 0.6: two of them (1.2) stay
    # below the "seen twice" threshold (1.5), two confident views (2.0) pass it.
    T = look_at((0.0, 0.0, 1.2), (0.0, 0.0, 0.0), up=(0, 1, 0))
    d, c = render(T, box=False)
    counts = []
    for conf in (0.3, 0.9):
        vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, confidence_full=0.5,
                                    weight_threshold=1.5))
        for _ in range(2):
            vol.integrate(d, c, K, T, confidence=np.full(d.shape, conf, np.float32))
        counts.append(len(vol.extract_mesh().vertices))
    assert counts[0] == 0 and counts[1] > 1000


def test_min_confidence_leaves_out_unconfident_pixels():
    T = look_at((0.0, 0.0, 1.2), (0.0, 0.0, 0.0), up=(0, 1, 0))
    d, c = render(T, box=False)
    conf = np.ones(d.shape, np.float32)
    conf[:, : d.shape[1] // 2] = 0.1  # the left half of the image unconfident
    meshes = {}
    for cmin in (0.0, 0.2):
        vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, min_confidence=cmin))
        vol.integrate(d, c, K, T, confidence=conf)
        meshes[cmin] = vol.extract_mesh().vertices
    # the camera looks down with image x along world x: the left half is x < 0
    assert (meshes[0.0][:, 0] < -0.05).sum() > 500
    assert (meshes[0.2][:, 0] < -0.05).sum() == 0
    assert (meshes[0.2][:, 0] > 0.05).sum() >= 0.95 * (meshes[0.0][:, 0] > 0.05).sum()
    # no confidence given: every pixel fused
    vol = TsdfVolume(TsdfConfig(voxel_m=VOXEL_M, min_confidence=0.2))
    vol.integrate(d, c, K, T)
    assert len(vol.extract_mesh().vertices) == len(meshes[0.0])
    with pytest.raises(ReconError, match="confidence"):
        vol.integrate(d, c, K, T, confidence=conf[:, :10])
    with pytest.raises(ReconError, match="min_confidence"):
        TsdfConfig(min_confidence=1.0)
    with pytest.raises(ReconError, match="confidence_full"):
        TsdfConfig(confidence_full=0.0)
