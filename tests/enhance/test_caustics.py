"""Caustic removal over registered frames, on simulated shallow-water views with ground truth."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from sea3d.enhance import CausticConfig, remove_caustics
from sea3d.enhance._image import luminance, srgb_to_linear
from sea3d.enhance.caustics import points_from_depth, warp_to
from sea3d.errors import EnhanceError
from sea3d.geometry.se3 import look_at
from sea3d.refraction.presets import paper_rig
from sea3d.sim import Imaging, Renderer, builtin_scene

ERROR_RATIO_MAX = 0.75  # measured about 0.6 at 160x120 with 5 frames (benchmarks: 480x270)
WARP_TOL = 1e-4  # linear luminance, bilinear sampling at exact pixel centres


def _y(img: np.ndarray) -> np.ndarray:
    return luminance(srgb_to_linear(img.astype(np.float32) / 255.0))


@pytest.fixture(scope="module")
def frames() -> dict[str, Any]:
    cam = paper_rig("none", size_px=(160, 120)).left
    r = Renderer(builtin_scene("lake"), supersample=1)
    im = dataclasses.replace(Imaging.underwater("clear"), vehicle_light=0.0, vignetting=0.0)
    imgs, poses = [], []
    for k in range(5):
        T = look_at((0.35 + 0.03 * k, -1.6, 0.9), (0.03 * k, 0.0, 0.1))
        v = r.render(cam, T, im, time_s=2.0 * k, rng=np.random.default_rng(k))
        imgs.append(v.image)
        poses.append(T)
        if k == 2:
            depth = v.gt.depth_m
            clean = r.render(cam, T, dataclasses.replace(im, caustics=0.0), time_s=4.0,
                             rng=np.random.default_rng(k)).image
    return {"cam": cam, "imgs": imgs, "poses": poses, "depth": depth, "clean": clean}


def test_registered_neighbours_remove_most_of_the_caustics(frames: dict[str, Any]) -> None:
    res = remove_caustics(frames["imgs"], 2, frames["depth"], frames["cam"], frames["poses"])
    seen = res.frames_seen >= 3
    assert seen.mean() > 0.5
    before = np.abs(_y(frames["imgs"][2]) - _y(frames["clean"]))[seen].mean()
    after = np.abs(_y(res.image) - _y(frames["clean"]))[seen].mean()
    assert after < ERROR_RATIO_MAX * before
    # Pixels no neighbour saw are left exactly as they were.
    untouched = res.frames_seen < 3
    assert np.all(res.caustic_map[untouched] == 1.0)


def test_nothing_changes_when_nothing_flickers(frames: dict[str, Any]) -> None:
    same = [frames["imgs"][2]] * 3
    poses = [frames["poses"][2]] * 3
    res = remove_caustics(same, 1, frames["depth"], frames["cam"], poses,
                          CausticConfig(sigma_px=0.0))
    np.testing.assert_allclose(res.caustic_map, 1.0, atol=1e-5)
    assert np.abs(res.image.astype(int) - same[1].astype(int)).max() <= 1


def test_warp_with_identity_pose_is_the_identity(frames: dict[str, Any]) -> None:
    cam, depth = frames["cam"], frames["depth"]
    y = _y(frames["imgs"][0])
    pts, ok = points_from_depth(cam, depth)
    warped, inside = warp_to(y, cam, pts, ok, np.eye(4), depth.shape)
    good = inside & ok.reshape(depth.shape)
    assert good.mean() > 0.5
    np.testing.assert_allclose(warped[good], y[good], atol=WARP_TOL)


def test_bad_input_is_refused(frames: dict[str, Any]) -> None:
    imgs, poses, cam = frames["imgs"], frames["poses"], frames["cam"]
    with pytest.raises(EnhanceError, match="two frames"):
        remove_caustics(imgs[:1], 0, frames["depth"], cam, poses[:1])
    with pytest.raises(EnhanceError, match="no valid pixel"):
        remove_caustics(imgs, 0, np.full_like(frames["depth"], np.nan), cam, poses)
    with pytest.raises(EnhanceError, match="depth map is 80x60"):
        remove_caustics(imgs, 0, frames["depth"][::2, ::2], cam, poses)
