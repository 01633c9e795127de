"""RGB-D and mesh files: scales, invalid depth, colour conversion, mesh round trip."""

import cv2
import numpy as np
import pytest

from sea3d.errors import ReconError, StereoError
from sea3d.geometry.mesh import Mesh
from sea3d.io.depth_files import read_depth
from sea3d.io.image_files import natural_key
from sea3d.io.mesh_files import read_mesh, read_point_cloud, write_mesh, write_point_cloud
from sea3d.io.rgbd_files import read_color


def test_depth_scales_and_invalid_pixels(tmp_path):
    mm = np.array([[0, 1000], [2500, 65535]], np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), mm)
    z = read_depth(tmp_path / "d.png", 1000.0)
    assert np.isnan(z[0, 0]) and z[0, 1] == 1.0 and z[1, 0] == 2.5
    tum = read_depth(tmp_path / "d.png", 5000.0)  # TUM RGB-D stores metres x 5000
    assert tum[1, 0] == pytest.approx(0.5)
    f = np.array([[1.5, -1.0], [np.nan, 0.0]], np.float32)
    np.save(tmp_path / "d.npy", f)
    zf = read_depth(tmp_path / "d.npy")
    assert zf[0, 0] == 1.5 and np.isnan(zf[0, 1]) and np.isnan(zf[1, 1])
    with pytest.raises(StereoError, match="not found"):
        read_depth(tmp_path / "nope.png")
    # integer .npy with the frames' scale; negative values are invalid like in float depth
    np.save(tmp_path / "i.npy", np.array([[5000, -5000], [0, 2500]], np.int32))
    zi = read_depth(tmp_path / "i.npy", 5000.0)
    assert zi[0, 0] == 1.0 and zi[1, 1] == 0.5 and np.isnan(zi[0, 1]) and np.isnan(zi[1, 0])


def test_colour_is_rgb(tmp_path):
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[..., 0] = 255  # blue in OpenCV's order
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    rgb = read_color(tmp_path / "c.png")
    assert rgb[0, 0].tolist() == [0, 0, 255]


def test_natural_order():
    from pathlib import Path

    names = ["f10.png", "f2.png", "f1.png"]
    assert sorted(names, key=lambda n: natural_key(Path(n))) == ["f1.png", "f2.png", "f10.png"]
    # Frames of several folders (7-Scenes' seq-01, seq-02, ...) stay folder by folder.
    paths = [Path(p) for p in ("seq-2/f1.png", "seq-10/f0.png", "seq-2/f0.png", "seq-10/f2.png")]
    assert sorted(paths, key=natural_key) == [
        Path(p) for p in ("seq-2/f0.png", "seq-2/f1.png", "seq-10/f0.png", "seq-10/f2.png")]


def test_mesh_and_cloud_round_trip(tmp_path, rng):
    v = rng.random((30, 3))
    f = rng.integers(0, 30, (20, 3))
    c = rng.integers(0, 255, (30, 3)).astype(np.uint8)
    write_mesh(tmp_path / "m.ply", Mesh(vertices=v, triangles=f, colors_rgb=c))
    m = read_mesh(tmp_path / "m.ply")
    np.testing.assert_allclose(m.vertices, v, atol=1e-12)
    np.testing.assert_array_equal(m.triangles, f)
    np.testing.assert_array_equal(m.colors_rgb, c)
    write_point_cloud(tmp_path / "p.ply", v, c)
    p, pc = read_point_cloud(tmp_path / "p.ply")
    np.testing.assert_allclose(p, v, atol=1e-12)
    np.testing.assert_array_equal(pc, c)
    as_mesh = read_mesh(tmp_path / "p.ply")  # a cloud reads as a mesh without triangles
    assert as_mesh.triangles.shape == (0, 3) and len(as_mesh.vertices) == 30
    with pytest.raises(ReconError, match="match points"):
        write_point_cloud(tmp_path / "q.ply", v, c[:3])
