"""Built-in rigs: the paper's Sea3D camera.

Figures from the paper (file ../shared/paper, cited in DESIGN.md): 1920x1080 depth images,
in-air intrinsics of the left camera fx 1082.4, fy 1074.4, cx 949.5, cy 535.7 (used for both
cameras; the paper gives no right-camera figures at this size), baseline 107 mm, acrylic domes of
inner radius 31.25 mm and thickness 3.1 mm (Table 2.5), indices air 1.000292, acrylic 1.492,
water 1.333 (Table 2.4), dome centre (-0.54, 0.58, 2.10) mm (Table 3.7; used for both cameras).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from sea3d.errors import ConfigError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import StereoRig
from sea3d.refraction.ports import (
    N_ACRYLIC,
    N_AIR,
    N_WATER,
    DomePort,
    DomePortCamera,
    FlatPort,
    FlatPortCamera,
)

__all__ = [
    "PAPER_BASELINE_M",
    "PAPER_DOME_CENTER_M",
    "PAPER_DOME_INNER_RADIUS_M",
    "PAPER_DOME_THICKNESS_M",
    "PortKind",
    "paper_rig",
    "with_ports",
]

PortKind = Literal["dome", "flat", "none"]

PAPER_SIZE_PX = (1920, 1080)
PAPER_INTRINSICS_PX = (1082.4, 1074.4, 949.5, 535.7)
PAPER_BASELINE_M = 0.107
PAPER_DOME_INNER_RADIUS_M = 0.03125
PAPER_DOME_THICKNESS_M = 0.0031
PAPER_DOME_CENTER_M = (-0.54e-3, 0.58e-3, 2.10e-3)
# A typical flat port (not from the paper): window 10 mm in front of the centre, 10 mm acrylic.
DEFAULT_FLAT_DISTANCE_M = 0.010
DEFAULT_FLAT_THICKNESS_M = 0.010


def _with_port(
    pinhole: PinholeCamera,
    port: PortKind,
    *,
    dome_center_m: Sequence[float],
    inner_radius_m: float,
    thickness_m: float,
    n_glass: float,
    n_water: float,
    n_air: float,
    flat_distance_m: float,
) -> CameraModel:
    if port == "none":
        return pinhole
    if port == "dome":
        return DomePortCamera(
            pinhole,
            DomePort(
                center_m=np.asarray(dome_center_m, dtype=np.float64),
                inner_radius_m=inner_radius_m,
                thickness_m=thickness_m,
                n_air=n_air,
                n_glass=n_glass,
                n_water=n_water,
            ),
        )
    if port == "flat":
        return FlatPortCamera(
            pinhole,
            FlatPort(
                normal=np.array([0.0, 0.0, 1.0]),
                distance_m=flat_distance_m,
                thickness_m=thickness_m,
                n_air=n_air,
                n_glass=n_glass,
                n_water=n_water,
            ),
        )
    raise ConfigError(f"unknown port type {port!r}; expected dome, flat or none")


def with_ports(
    rig: StereoRig,
    port: PortKind,
    *,
    dome_center_left_m: Sequence[float] = PAPER_DOME_CENTER_M,
    dome_center_right_m: Sequence[float] = PAPER_DOME_CENTER_M,
    inner_radius_m: float = PAPER_DOME_INNER_RADIUS_M,
    thickness_m: float | None = None,
    n_glass: float = N_ACRYLIC,
    n_water: float = N_WATER,
    n_air: float = N_AIR,
    flat_distance_m: float = DEFAULT_FLAT_DISTANCE_M,
) -> StereoRig:
    """The same rig with new ports on both cameras (any existing ports are replaced).

    Raises:
        ConfigError: an unknown port type. RefractionError: invalid port parameters.
    """
    pins = [rig.left.lens, rig.right.lens]
    if thickness_m is None:
        thickness_m = PAPER_DOME_THICKNESS_M if port == "dome" else DEFAULT_FLAT_THICKNESS_M
    common: dict[str, Any] = {
        "inner_radius_m": inner_radius_m,
        "thickness_m": thickness_m,
        "n_glass": n_glass,
        "n_water": n_water,
        "n_air": n_air,
        "flat_distance_m": flat_distance_m,
    }
    left = _with_port(pins[0], port, dome_center_m=dome_center_left_m, **common)
    right = _with_port(pins[1], port, dome_center_m=dome_center_right_m, **common)
    return StereoRig(
        left=left, right=right, T_left_right=rig.T_left_right, imu=rig.imu, sonar=rig.sonar
    )


def paper_rig(
    port: PortKind = "dome",
    *,
    size_px: tuple[int, int] = PAPER_SIZE_PX,
    fx_px: float | None = None,
    baseline_m: float = PAPER_BASELINE_M,
    **port_options: float | Sequence[float],
) -> StereoRig:
    """The paper's Sea3D rig at 1920x1080, optionally with other size, focal length or baseline.

    Args:
        port: ``"dome"`` (the paper's acrylic domes), ``"flat"`` or ``"none"`` (in air).
        size_px: ``(width, height)``; intrinsics scale with the width.
        fx_px: focal length override (fy keeps the paper's aspect ratio).
        baseline_m: distance between the cameras along the left camera's x axis.
        **port_options: passed to :func:`with_ports` (``dome_center_left_m``, ``n_water`` ...).

    Raises:
        ConfigError: bad sizes or baseline. RefractionError: invalid port parameters.
    """
    width, height = int(size_px[0]), int(size_px[1])
    if width <= 0 or height <= 0:
        raise ConfigError(f"image size must be positive, got {width}x{height}")
    if not baseline_m > 0:
        raise ConfigError(f"baseline must be > 0 m, got {baseline_m}")
    fx0, fy0, cx0, cy0 = PAPER_INTRINSICS_PX
    sx, sy = width / PAPER_SIZE_PX[0], height / PAPER_SIZE_PX[1]
    fx = fx0 * sx if fx_px is None else float(fx_px)
    if not fx > 0:
        raise ConfigError(f"focal length must be > 0 px, got {fx}")
    fy = fx * fy0 / fx0
    pin = PinholeCamera(
        fx=fx,
        fy=fy,
        cx=(cx0 + 0.5) * sx - 0.5,
        cy=(cy0 + 0.5) * sy - 0.5,
        width=width,
        height=height,
    )
    T_left_right = np.eye(4)
    T_left_right[0, 3] = baseline_m
    rig = StereoRig(left=pin, right=pin, T_left_right=T_left_right)
    return with_ports(rig, port, **port_options)  # type: ignore[arg-type]
