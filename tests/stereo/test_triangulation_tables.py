"""Triangulation from ray tables against the per-pixel reference and the pinhole closed form.

The reference is :func:`triangulate_disparity` (raw pixel interpolated along the rectified
row, then unprojected through the port); the tables interpolate the ray instead, a second-order
difference in the one-pixel step (measured: below 6e-6 of the depth on the dome and pinhole
rigs, 2e-5 on the flat-port rig, at 640x360 over 0.5-4 m). The tolerance is 1e-4 of the depth,
10x below the matcher's 0.1 px noise at 10 px disparity (1e-2).
"""

from __future__ import annotations

import numpy as np
import pytest

from _rigs import real_sea3d_rig
from sea3d.errors import StereoError
from sea3d.rectify import rectify_rig
from sea3d.stereo.depth import disparity_to_points, ray_tables, triangulate_disparity
from sea3d.stereo.triangulation import RayTables, triangulate_frame, triangulate_with_tables

DEPTH_REL_TOL = 1e-4
SIZE = (320, 180)


def _disparity(maps, rng):
    """Disparities of depths 0.5-4 m (10 % invalid) whose right column stays in the image."""
    z = rng.uniform(0.5, 4.0, (maps.height, maps.width))
    d = (maps.focal_px * maps.baseline_m / z).astype(np.float32)
    d[rng.random(d.shape) < 0.1] = np.nan
    u = np.arange(maps.width)[None, :]
    d[u - d < 0] = np.nan
    return d


@pytest.mark.parametrize("port", ["dome", "flat", "none"])
def test_tables_match_the_per_pixel_triangulation(port, rng):
    rig = real_sea3d_rig(port, SIZE)
    maps = rectify_rig(rig, depth_range_m=(0.5, 4.0))
    d = _disparity(maps, rng)
    pe, ze, me = triangulate_disparity(maps, d)
    pf, zf, mf = triangulate_with_tables(RayTables.from_maps(maps), d)
    assert me.sum() > 0.8 * np.isfinite(d).sum()
    assert (me != mf).sum() <= 1e-4 * me.sum()  # rays at the gap limit may fall either side
    ze_full = np.full(me.shape, np.nan)
    ze_full[me] = ze
    zf_full = np.full(me.shape, np.nan)
    zf_full[mf] = zf
    both = me & mf
    rel = np.abs(ze_full[both] - zf_full[both]) / ze_full[both]
    assert rel.max() < DEPTH_REL_TOL
    pe_full = np.full(me.shape + (3,), np.nan)
    pe_full[me] = pe
    pf_full = np.full(me.shape + (3,), np.nan)
    pf_full[mf] = pf
    gap = np.linalg.norm(pe_full[both] - pf_full[both], axis=1)
    assert (gap / ze_full[both]).max() < DEPTH_REL_TOL


def test_tables_give_the_pinhole_closed_form(rng):
    rig = real_sea3d_rig("none", SIZE)
    maps = rectify_rig(rig)
    d = _disparity(maps, rng)
    _, z, mask = triangulate_with_tables(RayTables.from_maps(maps), d)
    closed = maps.focal_px * maps.baseline_m / d[mask].astype(np.float64)
    assert mask.sum() == np.isfinite(d).sum()
    np.testing.assert_allclose(z, closed, rtol=DEPTH_REL_TOL)


def test_disparity_to_points_uses_tables_built_once(rng):
    maps = rectify_rig(real_sea3d_rig("dome", SIZE), depth_range_m=(0.5, 4.0))
    assert ray_tables(maps) is ray_tables(maps)
    t = ray_tables(maps)
    assert t.shape == (maps.height, maps.width) and t.nbytes == 4 * 3 * 4 * 320 * 180
    d = _disparity(maps, rng)
    _p1, z1, m1 = disparity_to_points(maps, d)
    _p2, z2, m2 = triangulate_with_tables(t, d)
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(z1, z2)


def test_one_pass_frame_triangulation_gathers_depth_map_and_colours(rng):
    maps = rectify_rig(real_sea3d_rig("dome", SIZE), depth_range_m=(0.5, 4.0))
    t = ray_tables(maps)
    d = _disparity(maps, rng)
    img = rng.integers(0, 256, (maps.height, maps.width, 3), dtype=np.uint8)
    far = 2.5
    p1, z1, m1 = triangulate_with_tables(t, d)
    p2, depth, m2, colours = triangulate_frame(t, d, img, max_depth_m=far)
    near = m1.copy()
    near[m1] = z1.astype(np.float32) <= far  # the far ones are left out, nothing else
    assert 0 < near.sum() < m1.sum()
    np.testing.assert_array_equal(m2, near)
    np.testing.assert_array_equal(p2, p1[near[m1]])
    np.testing.assert_array_equal(colours, img[m2])
    want = np.full(d.shape, np.nan, np.float32)
    want[m1] = z1
    want[~near] = np.nan
    np.testing.assert_array_equal(depth, want)
    with pytest.raises(StereoError, match="image"):
        triangulate_frame(t, d, img[:, :-1])


def test_tables_refuse_a_disparity_of_another_size():
    maps = rectify_rig(real_sea3d_rig("dome", SIZE), depth_range_m=(0.5, 4.0))
    with pytest.raises(StereoError, match="does not match the ray tables 180x320"):
        triangulate_with_tables(ray_tables(maps), np.zeros((10, 10), np.float32))


def test_stereo_depth_holds_the_tables_of_its_maps():
    from sea3d.stereo.recipe import DepthConfig, StereoDepth

    dome = StereoDepth(real_sea3d_rig("dome", SIZE), DepthConfig(min_depth_m=0.5,
                                                                  max_depth_m=4.0))
    assert dome.tables is ray_tables(dome.maps) and dome.tables.shape == (180, 320)
    assert StereoDepth(real_sea3d_rig("none", SIZE)).tables is None
