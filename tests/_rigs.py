"""Rigs for tests that must not be as parallel as the presets.

``real_sea3d_rig`` is the original Sea3D rig's in-air calibration
(``calib/sea3d_yaml/in_air_stereo.yml`` in the shared data: intrinsics, distortion, R and T; the
numbers are copied here so tests need no data folder), scaled from 1920x1080. Its cameras are
0.5-0.6 degrees apart and its baseline has a 1.5 mm forward component, so its rectifying
rotation is about a degree, where the presets' is the identity.
"""

from __future__ import annotations

import numpy as np

from sea3d.geometry import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.refraction.presets import with_ports

# OpenCV convention X_right = R X_left + T, T in millimetres, intrinsics at 1920x1080
_K_L = (1157.6193, 1151.253417, 948.435858, 539.787047)
_K_R = (1160.519202, 1154.174892, 955.758573, 527.755446)
_D_L = (0.043977, -0.008485, 0.0, 0.0, 0.0)
_D_R = (0.049307, -0.014554, 0.0, 0.0, 0.0)
_R = np.array([[0.999959, -0.008374, -0.003428], [0.008406, 0.999920, 0.009435],
               [0.003349, -0.009463, 0.999950]])
_T_MM = np.array([-107.166011, 0.054609, 1.497043])


def real_sea3d_rig(port: str = "none", size_px: tuple[int, int] = (480, 270)) -> StereoRig:
    """The Sea3D rig's real calibration at ``size_px``, in air or with the paper's ``"dome"``
    (or ``"flat"``) ports."""
    s = size_px[0] / 1920.0

    def cam(k: tuple[float, ...], d: tuple[float, ...]) -> PinholeCamera:
        return PinholeCamera(k[0] * s, k[1] * s, (k[2] + 0.5) * s - 0.5, (k[3] + 0.5) * s - 0.5,
                             size_px[0], size_px[1], np.asarray(d))

    u, _, vt = np.linalg.svd(_R)  # orthonormalise the printed (6-decimal) rotation
    T_right_left = np.eye(4)
    T_right_left[:3, :3] = u @ vt
    T_right_left[:3, 3] = _T_MM / 1000.0
    rig = StereoRig(cam(_K_L, _D_L), cam(_K_R, _D_R), np.linalg.inv(T_right_left))
    return rig if port == "none" else with_ports(rig, port)  # type: ignore[arg-type]
