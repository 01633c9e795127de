"""``StereoDepth(rig, DepthConfig)``: the one stereo-depth recipe.

References: the hand-written recipe it replaces (``rectify_rig -> max_disparity_for_depth ->
make_config -> compute_depth``) must give bit-identical depth for the same range; the depth
range rule (``sea3d.stereo.recipe``'s docstring) must keep a car rig's depths to 80 m (the KITTI
rig: ``B = 0.54 m``, ``f = 718 px`` at 1241x376, depths to about 80 m in its benchmark) and the
simulator scenes' 0.5-4 m with the paper's dome rig.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from sea3d.errors import ConfigError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import look_at
from sea3d.rectify import rectify_rig
from sea3d.refraction.presets import paper_rig
from sea3d.stereo import make_config
from sea3d.stereo.depth import compute_depth, max_disparity_for_depth
from sea3d.stereo.recipe import (
    MIN_USEFUL_DISPARITY_PX,
    DepthConfig,
    StereoDepth,
    default_max_disparity,
)


def _car_rig() -> StereoRig:
    cam = PinholeCamera(fx=718.856, fy=718.856, cx=607.19, cy=185.22, width=1241, height=376)
    T = np.eye(4)
    T[0, 3] = 0.54
    return StereoRig(left=cam, right=cam, T_left_right=T)


@pytest.fixture(scope="module")
def dome_pair() -> tuple[StereoRig, np.ndarray, np.ndarray]:
    from sea3d.sim import simulate_pair

    rig = paper_rig("dome", size_px=(320, 180))
    T = look_at([0.6, -1.4, 1.3], [0.0, 0.0, 0.0])
    left, right, _ = simulate_pair(rig, "lake", T, "clear")
    return rig, left, right


def test_car_rig_keeps_depths_out_to_80_m() -> None:
    sd = StereoDepth(_car_rig())
    lo, hi = sd.depth_range_m
    fb = 718.856 * 0.54
    assert sd.max_disparity_px == 159  # ((1241 / 8) + 15) & -16 = 160 disparities
    # stereoRectify returns the focal length to ~1e-7 (float32 inside OpenCV)
    assert lo == pytest.approx(fb / 159, rel=1e-6) and 2.0 < lo < 3.0
    assert hi == pytest.approx(fb / MIN_USEFUL_DISPARITY_PX, rel=1e-6) and hi >= 80.0


@pytest.mark.parametrize("size", [(640, 360), (1920, 1080)])
def test_paper_dome_rig_range_holds_the_simulator_scenes(size: tuple[int, int]) -> None:
    sd = StereoDepth(paper_rig("dome", size_px=size))
    lo, hi = sd.depth_range_m
    assert lo <= 0.5 and hi >= 4.0
    # the range follows f B of the rectified views and the disparity range
    fb = sd.maps.focal_px * sd.maps.baseline_m
    assert lo == pytest.approx(fb / sd.max_disparity_px, rel=1e-12)
    assert hi == pytest.approx(fb / MIN_USEFUL_DISPARITY_PX, rel=1e-12)


@pytest.mark.parametrize("width", [160, 320, 640, 1241, 1920, 3856])
def test_default_max_disparity_is_an_eighth_of_the_width_in_sixteens(width: int) -> None:
    d = default_max_disparity(width)
    assert (d + 1) % 16 == 0 and d + 1 < width
    assert width / 8 <= d + 1 < width / 8 + 16


def test_default_max_disparity_refuses_a_sliver() -> None:
    with pytest.raises(ConfigError, match="too narrow"):
        default_max_disparity(12)


@pytest.mark.parametrize(("min_m", "max_m", "max_d"), [(0.5, 4.0, None), (0.3, 6.0, 95)])
def test_same_range_gives_the_hand_built_recipe_bit_for_bit(
    dome_pair: tuple[StereoRig, np.ndarray, np.ndarray], min_m: float, max_m: float,
    max_d: int | None
) -> None:
    rig, left, right = dome_pair
    maps = rectify_rig(rig, depth_range_m=(min_m, max_m))
    d = max_d or max_disparity_for_depth(maps, min_m)
    old = compute_depth(maps, left, right, make_config("sea3d", d), max_depth_m=max_m)
    sd = StereoDepth(rig, DepthConfig(min_depth_m=min_m, max_depth_m=max_m, max_disparity_px=max_d))
    new = sd.compute(left, right)
    assert sd.max_disparity_px == d and sd.depth_range_m == (min_m, max_m)
    np.testing.assert_array_equal(new.depth_m, old.depth_m)
    np.testing.assert_array_equal(new.points_left, old.points_left)
    assert np.isfinite(new.depth_m).mean() > 0.3


def test_pickled_round_trip_gives_bit_identical_depth(
    dome_pair: tuple[StereoRig, np.ndarray, np.ndarray]
) -> None:
    rig, left, right = dome_pair
    sd = StereoDepth(rig)
    back = pickle.loads(pickle.dumps(sd))
    assert back.depth_range_m == sd.depth_range_m and back.max_disparity_px == sd.max_disparity_px
    a, b = sd.compute(left, right), back.compute(left, right)
    np.testing.assert_array_equal(a.depth_m, b.depth_m)
    np.testing.assert_array_equal(a.points_left, b.points_left)
    lo, hi = sd.depth_range_m
    z = a.depth_m[np.isfinite(a.depth_m)]
    assert z.size > 0 and z.max() <= hi and lo <= 0.5


def test_engine_options_reach_the_engine() -> None:
    sd = StereoDepth(paper_rig("none", size_px=(320, 180)),
                     DepthConfig(engine_options={"paths": 16, "fill_max_px": 0}))
    assert sd.engine_config.fill_max_px == 0 and sd.engine_config.paths == 16  # type: ignore[union-attr]
    assert sd.config.engine_options == (("fill_max_px", 0), ("paths", 16))
    hash(sd.config)  # frozen and hashable: usable as a cache key


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"engine": "nope"}, "unknown engine"),
        ({"max_disparity_px": 0}, "max disparity"),
        ({"min_depth_m": 0.0}, "min_depth_m"),
        ({"max_depth_m": float("inf")}, "max_depth_m"),
        ({"min_depth_m": 3.0, "max_depth_m": 2.0}, "min_depth_m < max_depth_m"),
        ({"min_confidence": -1.0}, "min_confidence"),
    ],
)
def test_depth_config_refuses_bad_values(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        DepthConfig(**kwargs)  # type: ignore[arg-type]


def test_a_disparity_range_wider_than_the_image_is_refused() -> None:
    with pytest.raises(ConfigError, match="does not fit"):
        StereoDepth(paper_rig("none", size_px=(160, 90)), DepthConfig(max_disparity_px=200))
