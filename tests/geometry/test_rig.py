"""StereoRig: validation of its transform and image sizes, and the quantities derived."""

import numpy as np
import pytest

from sea3d.errors import GeometryError
from sea3d.geometry import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import make_T, rotvec_to_R

# Derived quantities are one matrix product or norm away from the input: float64 rounding.
EXACT = 1e-12


def _cam(width: int = 640, height: int = 480) -> PinholeCamera:
    return PinholeCamera(fx=500.0, fy=500.0, cx=width / 2, cy=height / 2, width=width,
                         height=height)


def test_transform_is_validated_converted_and_frozen():
    T = make_T(rotvec_to_R([0.01, -0.02, 0.005]), [0.12, 0.001, -0.002])
    rig = StereoRig(left=_cam(), right=_cam(), T_left_right=T.tolist())
    assert isinstance(rig.T_left_right, np.ndarray) and rig.T_left_right.dtype == np.float64
    np.testing.assert_array_equal(rig.T_left_right, T)
    with pytest.raises(ValueError, match="read-only"):
        rig.T_left_right[0, 3] = 1.0
    assert rig.baseline_m == pytest.approx(np.linalg.norm([0.12, 0.001, -0.002]), abs=EXACT)
    np.testing.assert_allclose(rig.T_right_left @ T, np.eye(4), atol=EXACT)
    assert (rig.width, rig.height) == (640, 480)
    bad = T.copy()
    bad[:3, 0] *= 1.01  # not a rotation
    with pytest.raises(GeometryError, match="T_left_right's rotation block"):
        StereoRig(left=_cam(), right=_cam(), T_left_right=bad)


def test_different_image_sizes_are_refused_with_both_sizes_named():
    with pytest.raises(GeometryError, match="640x480 and 640x512"):
        StereoRig(left=_cam(), right=_cam(640, 512), T_left_right=np.eye(4))
    with pytest.raises(GeometryError, match="differ"):
        StereoRig(left=_cam(), right=_cam(320, 480), T_left_right=np.eye(4))
