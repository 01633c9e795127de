"""A stereo rig: two camera models and the transform between them, and the rig's other sensors.

The IMU (:class:`ImuSpec`) and the echosounder (:class:`SonarSpec`) are optional: a rig file
without them still loads, and a session recorded with them is self-describing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sea3d._typing import FloatArray
from sea3d.errors import GeometryError
from sea3d.geometry.camera import CameraModel
from sea3d.geometry.se3 import check_T, invert_T

__all__ = ["ImuSpec", "SonarSpec", "StereoRig"]


def _positive(value: float, name: str, *, allow_zero: bool = False) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise GeometryError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, "
                            f"got {value!r}")
    return v


@dataclass(frozen=True, kw_only=True, eq=False)
class ImuSpec:
    """An IMU rigidly mounted on the rig: where it sits, how fast and how noisy it is.

    The noise figures are continuous-time densities, the way Kalibr's ``imu.yaml`` and most
    datasheets give them: white noise per sqrt(Hz) and bias random walk per sqrt(s). The
    default figures are those of the ADIS16448 in EuRoC's ``imu0/sensor.yaml`` (a typical MEMS
    IMU), for rigs whose IMU has no figures of its own.

    Attributes:
        T_left_imu: 4x4, maps IMU (``body``) points into the left camera frame, metres.
        rate_hz: sample rate, Hz.
        gyro_noise_density_radps_sqrthz: gyroscope white noise, rad/s/sqrt(Hz).
        gyro_random_walk_radps_sqrts: gyroscope bias random walk, rad/s/sqrt(s)
            (= rad/s^2/sqrt(Hz), Kalibr's ``gyroscope_random_walk``).
        accel_noise_density_mps2_sqrthz: accelerometer white noise, m/s^2/sqrt(Hz).
        accel_random_walk_mps2_sqrts: accelerometer bias random walk, m/s^2/sqrt(s)
            (= m/s^3/sqrt(Hz), Kalibr's ``accelerometer_random_walk``).
        gravity_mps2: magnitude of gravity where the rig dives, m/s^2.
        time_offset_s: clock offset, ``t_imu = t_cam + time_offset_s`` (Kalibr's
            ``timeshift_cam_imu``); an IMU stamp ``t`` is camera time ``t - time_offset_s``.

    Raises:
        GeometryError: a ``T_left_imu`` that is not rigid, or a non-positive rate or noise.
    """

    T_left_imu: FloatArray
    rate_hz: float = 200.0
    gyro_noise_density_radps_sqrthz: float = 1.6968e-4
    gyro_random_walk_radps_sqrts: float = 1.9393e-5
    accel_noise_density_mps2_sqrthz: float = 2.0e-3
    accel_random_walk_mps2_sqrts: float = 3.0e-3
    gravity_mps2: float = 9.81
    time_offset_s: float = 0.0

    def __post_init__(self) -> None:
        T = check_T(self.T_left_imu, "T_left_imu")
        T.setflags(write=False)
        object.__setattr__(self, "T_left_imu", T)
        for name in (
            "rate_hz",
            "gyro_noise_density_radps_sqrthz",
            "gyro_random_walk_radps_sqrts",
            "accel_noise_density_mps2_sqrthz",
            "accel_random_walk_mps2_sqrts",
            "gravity_mps2",
        ):
            object.__setattr__(self, name, _positive(getattr(self, name), name))
        offset = float(self.time_offset_s)
        if not math.isfinite(offset):
            raise GeometryError(f"time_offset_s must be finite, got {self.time_offset_s!r}")
        object.__setattr__(self, "time_offset_s", offset)

    @property
    def T_imu_left(self) -> FloatArray:
        """4x4, maps left-camera points into the IMU frame."""
        return invert_T(self.T_left_imu)


@dataclass(frozen=True, kw_only=True, eq=False)
class SonarSpec:
    """A single-beam echosounder on the rig; its beam points along its own -z axis.

    Attributes:
        T_left_sonar: 4x4, maps echosounder points into the left camera frame, metres.
        beam_deg: full cone angle of the beam, degrees (0: an ideal single ray, as simulated).

    Raises:
        GeometryError: a ``T_left_sonar`` that is not rigid, or a beam outside [0, 180).
    """

    T_left_sonar: FloatArray
    beam_deg: float = 0.0

    def __post_init__(self) -> None:
        T = check_T(self.T_left_sonar, "T_left_sonar")
        T.setflags(write=False)
        object.__setattr__(self, "T_left_sonar", T)
        beam = _positive(self.beam_deg, "beam_deg", allow_zero=True)
        if beam >= 180.0:
            raise GeometryError(f"beam_deg must be < 180, got {beam}")
        object.__setattr__(self, "beam_deg", beam)


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Left and right camera models and ``T_left_right``.

    Attributes:
        left, right: camera models (pinhole, dome-port or flat-port), same image size.
        T_left_right: 4x4, maps points in the right camera's frame into the left's (metres);
            its translation is the right camera's centre in the left frame (about +B along x).
        imu: the rig's IMU, or None.
        sonar: the rig's echosounder, or None.

    Raises:
        GeometryError: different image sizes, or a ``T_left_right`` that is not rigid.
    """

    left: CameraModel
    right: CameraModel
    T_left_right: FloatArray
    imu: ImuSpec | None = None
    sonar: SonarSpec | None = None

    def __post_init__(self) -> None:
        T = check_T(self.T_left_right, "T_left_right")
        T.setflags(write=False)
        object.__setattr__(self, "T_left_right", T)
        if (self.left.width, self.left.height) != (self.right.width, self.right.height):
            raise GeometryError(
                f"left and right image sizes differ: {self.left.width}x{self.left.height} and "
                f"{self.right.width}x{self.right.height}"
            )
        if self.imu is not None and not isinstance(self.imu, ImuSpec):
            raise GeometryError(f"imu must be an ImuSpec or None, got {type(self.imu).__name__}")
        if self.sonar is not None and not isinstance(self.sonar, SonarSpec):
            raise GeometryError(
                f"sonar must be a SonarSpec or None, got {type(self.sonar).__name__}"
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

    def scaled(self, width: int, height: int) -> StereoRig:
        """The same rig for images resized to ``width x height`` pixels: both cameras
        :meth:`~sea3d.geometry.camera.CameraModel.scaled` (focal lengths and principal points
        scale, pixel centres stay pixel centres; distortion and ports are kept); the
        extrinsics, IMU and echosounder are unchanged. The rig itself when the size is its own.

        Raises:
            CameraModelError: a non-positive size.
        """
        w, h = int(width), int(height)
        if (w, h) == (self.width, self.height):
            return self
        return StereoRig(
            left=self.left.scaled(w, h),
            right=self.right.scaled(w, h),
            T_left_right=self.T_left_right,
            imu=self.imu,
            sonar=self.sonar,
        )

    @property
    def in_air(self) -> StereoRig:
        """The rig's bare lenses (ports removed): the rig as it sees in air."""
        return StereoRig(
            left=self.left.lens,
            right=self.right.lens,
            T_left_right=self.T_left_right,
            imu=self.imu,
            sonar=self.sonar,
        )

    @property
    def is_refractive(self) -> bool:
        """True if either camera's port bends rays."""
        return bool(self.left.is_refractive or self.right.is_refractive)

    @property
    def baseline_m(self) -> float:
        """Distance between the two camera centres, metres."""
        return float(np.linalg.norm(self.T_left_right[:3, 3]))
