"""A self-calibrated camera no lens can have fails the model."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.sfm.colmap import FOV_RANGE_DEG, implausible_camera


def _cam(f: float, width: int = 320, *, fixed: bool = False, model: str = "SIMPLE_RADIAL"):
    return {"model": model, "params": [f, width / 2, 120.0, 0.0], "width": width,
            "height": 240, "fixed": fixed, "virtual_pinhole": False}  # fmt: skip


def test_a_4418_px_focal_length_on_a_320_px_image_fails_with_its_field_of_view():
    # the case of the issue: 8 low-resolution frames, "partial" with f = 4,418 px
    why = implausible_camera({"left": _cam(4418.0)})
    assert why is not None
    assert "4,418 px on a 320-px-wide image is a 4.1 deg field of view" in why
    assert "10-170 deg" in why


@pytest.mark.parametrize("fov_deg", [11.0, 60.0, 120.0, 169.0])
def test_lenses_inside_the_range_pass(fov_deg):
    f = 320 / (2 * np.tan(np.radians(fov_deg) / 2))
    assert implausible_camera({"left": _cam(f), "right": _cam(f, model="PINHOLE")}) is None


@pytest.mark.parametrize("fov_deg", [9.0, 171.0])
def test_the_bounds_are_the_stated_field_of_view(fov_deg):
    lo, hi = FOV_RANGE_DEG
    assert (lo, hi) == (10.0, 170.0)
    f = 320 / (2 * np.tan(np.radians(fov_deg) / 2))
    assert implausible_camera({"right": _cam(f)}) is not None


def test_a_camera_fixed_by_the_rig_is_not_judged():
    assert implausible_camera({"left": _cam(4418.0, fixed=True)}) is None
