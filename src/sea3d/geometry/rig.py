"""A stereo rig: two camera models and the transform between them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sea3d.errors import GeometryError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.se3 import check_T, invert_T

__all__ = ["StereoRig"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Left and right camera models and ``T_left_right``.

    Attributes:
        left, right: camera models (pinhole, dome-port or flat-port), same image size.
        T_left_right: 4x4, maps points in the right camera's frame into the left's (metres);
            its translation is the right camera's centre in the left frame (about +B along x).

    Raises:
        GeometryError: different image sizes, or a ``T_left_right`` that is not rigid.
    """

    left: CameraModel
    right: CameraModel
    T_left_right: FloatArray

    def __post_init__(self) -> None:
        T = check_T(self.T_left_right, "T_left_right")
        T.setflags(write=False)
        object.__setattr__(self, "T_left_right", T)
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            raise GeometryError(
                f"left and right image sizes differ: {self.left.width}x{self.left.height} and "
                f"{self.right.width}x{self.right.height}"
            )

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.left.width

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.left.height

    @property
    def T_right_left(self) -> FloatArray:
        """4x4, maps left-frame points into the right frame (OpenCV's ``R, T``)."""
        return invert_T(self.T_left_right)

    @property
    def baseline_m(self) -> float:
        """Distance between the two camera centres, metres."""
        return float(np.linalg.norm(self.T_left_right[:3, 3]))
