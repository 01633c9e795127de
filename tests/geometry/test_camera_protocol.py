"""The camera protocol's parts: ``lens``, ``port``, ``is_refractive``, ``scaled``, ``with_lens``.

Expected values: resizing an image by ``s`` maps the pixel centre ``u`` to ``(u + 0.5) s - 0.5``
(docs/conventions.md: integer pixels are centres, the image spans -0.5 .. W - 0.5), for any lens
distortion (it acts on normalised coordinates) and any port (it lives in metres).
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from sea3d.errors import CameraModelError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.refraction.ports import DomePort, DomePortCamera, FlatPort, FlatPortCamera
from sea3d.refraction.presets import paper_rig

PIXEL_TOL_PX = 1e-7  # the port's Newton solve converges to 1e-14 rad; pixels to ~1e-9 px


def _lens(width: int = 1920, height: int = 1080) -> PinholeCamera:
    return PinholeCamera(fx=1082.4, fy=1074.4, cx=949.5, cy=535.7, width=width, height=height,
                         dist=np.array([0.04, -0.01, 0.001, -0.0005, 0.002]))


def _cameras() -> dict[str, CameraModel]:
    lens = _lens()
    dome = DomePort(center_m=np.array([-0.54e-3, 0.58e-3, 2.10e-3]), inner_radius_m=0.03125,
                    thickness_m=0.0031)
    flat = FlatPort(distance_m=0.01, thickness_m=0.008)
    return {"pinhole": lens, "dome": DomePortCamera(lens, dome), "flat": FlatPortCamera(lens, flat)}


def _points(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    z = rng.uniform(0.5, 5.0, n)
    x = rng.uniform(-0.6, 0.6, n) * z
    y = rng.uniform(-0.35, 0.35, n) * z
    return np.stack([x, y, z], axis=1)


@pytest.mark.parametrize("kind", ["pinhole", "dome", "flat"])
@pytest.mark.parametrize("size", [(640, 360), (960, 540), (1000, 700)])
def test_scaled_camera_projects_a_point_to_the_scaled_pixel(
    kind: str, size: tuple[int, int], rng: np.random.Generator
) -> None:
    cam = _cameras()[kind]
    small = cam.scaled(*size)
    sx, sy = size[0] / cam.width, size[1] / cam.height
    pts = _points(rng)
    uv, ok = cam.project(pts)
    uv_small, ok_small = small.project(pts)
    assert ok.sum() > 150
    np.testing.assert_array_equal(ok, ok_small)
    expected = np.stack([(uv[:, 0] + 0.5) * sx - 0.5, (uv[:, 1] + 0.5) * sy - 0.5], axis=1)
    np.testing.assert_allclose(uv_small[ok], expected[ok], atol=PIXEL_TOL_PX, rtol=0)
    assert (small.width, small.height) == size
    assert type(small) is type(cam) and small.port is cam.port


@pytest.mark.parametrize("kind", ["pinhole", "dome", "flat"])
def test_scaled_there_and_back_is_the_camera(kind: str) -> None:
    cam = _cameras()[kind]
    back = cam.scaled(640, 360).scaled(cam.width, cam.height)
    for name in ("fx", "fy", "cx", "cy"):
        assert getattr(back.lens, name) == pytest.approx(getattr(cam.lens, name), abs=1e-9)
    np.testing.assert_array_equal(back.lens.dist, cam.lens.dist)
    assert cam.scaled(cam.width, cam.height) is cam


@pytest.mark.parametrize("kind", ["pinhole", "dome", "flat"])
def test_scaled_refuses_a_non_positive_size(kind: str) -> None:
    with pytest.raises(CameraModelError, match="positive"):
        _cameras()[kind].scaled(0, 360)


def test_lens_port_and_is_refractive_of_each_camera() -> None:
    cams = _cameras()
    lens = cams["pinhole"]
    assert lens.lens is lens and lens.port is None and lens.is_refractive is False
    for kind, port_type in (("dome", DomePort), ("flat", FlatPort)):
        cam = cams[kind]
        assert cam.lens is lens and isinstance(cam.port, port_type)
        assert cam.is_refractive is True
        assert isinstance(cam, CameraModel)


def test_a_port_that_bends_no_ray_is_not_refractive() -> None:
    lens = _lens()
    centred = DomePortCamera(lens, DomePort(center_m=np.zeros(3), inner_radius_m=0.03,
                                            thickness_m=0.003))
    same_n = DomePortCamera(lens, DomePort(center_m=np.array([1e-3, 0, 2e-3]),
                                           inner_radius_m=0.03, thickness_m=0.003,
                                           n_air=1.2, n_glass=1.2, n_water=1.2))
    flat_same_n = FlatPortCamera(lens, FlatPort(n_air=1.0, n_glass=1.0, n_water=1.0))
    for cam in (centred, same_n, flat_same_n):
        assert cam.is_refractive is False
        assert cam.port is not None  # it still has a port; it just reduces to the lens


def test_with_lens_keeps_the_port() -> None:
    cams = _cameras()
    other = _lens(640, 360)
    assert cams["pinhole"].with_lens(other) is other
    for kind in ("dome", "flat"):
        moved = cams[kind].with_lens(other)
        assert moved.lens is other and moved.port is cams[kind].port


def test_rig_scaled_scales_both_cameras_and_keeps_extrinsics(rng: np.random.Generator) -> None:
    rig = paper_rig("dome")
    small = rig.scaled(640, 360)
    assert (small.width, small.height) == (640, 360)
    np.testing.assert_array_equal(small.T_left_right, rig.T_left_right)
    assert small.left.port is rig.left.port and small.right.port is rig.right.port
    pts = _points(rng)
    uv, ok = rig.right.project(pts)
    uv_s, _ = small.right.project(pts)
    np.testing.assert_allclose(uv_s[ok], (uv[ok] + 0.5) / 3 - 0.5, atol=PIXEL_TOL_PX, rtol=0)
    assert rig.scaled(rig.width, rig.height) is rig
    assert small.is_refractive and not small.in_air.is_refractive
    assert small.in_air.left is small.left.lens


def test_rig_scaled_pickles() -> None:
    small = paper_rig("flat").scaled(480, 270)
    back = pickle.loads(pickle.dumps(small))
    assert isinstance(back, StereoRig) and back.left.lens.fx == small.left.lens.fx
