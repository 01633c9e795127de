"""Kalibr calibration files: ``camchain-imucam.yaml`` (camera-IMU) and ``imu.yaml`` (noise).

Kalibr (github.com/ethz-asl/kalibr) writes, per camera ``camN``: ``intrinsics [fu fv pu pv]``,
``distortion_model`` / ``distortion_coeffs``, ``resolution [w h]``, ``T_cn_cnm1`` (camera N-1
into camera N, for N >= 1), and after a camera-IMU calibration ``T_cam_imu`` (IMU into this
camera) and ``timeshift_cam_imu`` (seconds, ``t_imu = t_cam + shift``). Its ``imu.yaml`` gives
the IMU's noise: ``gyroscope_noise_density`` (rad/s/sqrt(Hz)), ``gyroscope_random_walk``
(rad/s^2/sqrt(Hz)), ``accelerometer_noise_density`` (m/s^2/sqrt(Hz)),
``accelerometer_random_walk`` (m/s^3/sqrt(Hz)) and ``update_rate`` (Hz), either at the top
level or under ``imu0``.

``cam0`` is taken as the left camera and ``cam1`` as the right one.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sea3d.errors import RigFileError, Sea3dError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import ImuSpec, StereoRig
from sea3d.geometry.se3 import check_T, invert_T

__all__ = ["imu_from_kalibr", "is_kalibr_camchain", "rig_from_kalibr", "with_kalibr_imu"]

log = logging.getLogger(__name__)

_DEFAULT = ImuSpec(T_left_imu=np.eye(4))


def _load_yaml(path: Path) -> Mapping[str, Any]:
    if not path.is_file():
        raise RigFileError(f"{path}: file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise RigFileError(f"{path}: not a readable YAML file: {err}") from err
    if not isinstance(data, Mapping):
        raise RigFileError(f"{path}: expected a mapping at the top level")
    return data


def is_kalibr_camchain(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a YAML file whose ``cam0`` block has Kalibr's ``intrinsics``."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return False
    return (
        isinstance(data, Mapping)
        and isinstance(data.get("cam0"), Mapping)
        and "intrinsics" in data["cam0"]
    )


def _matrix(block: Mapping[str, Any], key: str, where: str) -> np.ndarray:
    if key not in block:
        raise RigFileError(f"{where}: key '{key}': missing")
    try:
        T = check_T(np.asarray(block[key], dtype=np.float64), key)
    except (TypeError, ValueError, Sea3dError) as err:
        raise RigFileError(f"{where}: key '{key}': {err}") from err
    return T


def _number(block: Mapping[str, Any], key: str, where: str) -> float:
    value = block.get(key)
    if isinstance(value, str):  # YAML 1.1 reads hand-written 1e-4 (no dot) as a string
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise RigFileError(f"{where}: key '{key}': expected a finite number, got {value!r}")
    return float(value)


def _camera(block: Any, name: str, path: Path) -> PinholeCamera:
    where = f"{path}: {name}"
    if not isinstance(block, Mapping):
        raise RigFileError(f"{where}: expected a mapping")
    model = block.get("camera_model", "pinhole")
    if model != "pinhole":
        raise RigFileError(f"{where}: key 'camera_model': only pinhole is read, got {model!r}")
    dmodel = block.get("distortion_model", "radtan")
    if dmodel not in ("radtan", "none"):
        raise RigFileError(
            f"{where}: key 'distortion_model': only radtan (OpenCV k1 k2 p1 p2) is read, "
            f"got {dmodel!r}"
        )
    try:
        fu, fv, pu, pv = (float(v) for v in block["intrinsics"])
        w, h = (int(v) for v in block["resolution"])
        dist = np.asarray(block.get("distortion_coeffs", []), dtype=np.float64).reshape(-1)
        return PinholeCamera(fx=fu, fy=fv, cx=pu, cy=pv, width=w, height=h, dist=dist)
    except KeyError as err:
        raise RigFileError(f"{where}: key {err}: missing") from err
    except (TypeError, ValueError, Sea3dError) as err:
        raise RigFileError(f"{where}: {err}") from err


def _imu_noise(imu_yaml: Path | None) -> dict[str, float]:
    if imu_yaml is None:
        log.warning(
            "no Kalibr imu.yaml given: using typical MEMS noise figures (EuRoC's ADIS16448); "
            "give the IMU's own figures for a well-weighted odometry"
        )
        return {}
    data = _load_yaml(imu_yaml)
    block = data.get("imu0", data)
    if not isinstance(block, Mapping):
        raise RigFileError(f"{imu_yaml}: key 'imu0': expected a mapping")
    where = str(imu_yaml)
    out = {
        "gyro_noise_density_radps_sqrthz": _number(block, "gyroscope_noise_density", where),
        "gyro_random_walk_radps_sqrts": _number(block, "gyroscope_random_walk", where),
        "accel_noise_density_mps2_sqrthz": _number(block, "accelerometer_noise_density", where),
        "accel_random_walk_mps2_sqrts": _number(block, "accelerometer_random_walk", where),
    }
    if "update_rate" in block:
        out["rate_hz"] = _number(block, "update_rate", where)
    return out


def imu_from_kalibr(
    camchain: str | os.PathLike[str], imu_yaml: str | os.PathLike[str] | None = None
) -> ImuSpec:
    """The IMU of a Kalibr camera-IMU calibration, relative to ``cam0`` (the left camera).

    Args:
        camchain: ``camchain-imucam.yaml`` (``cam0.T_cam_imu``, ``cam0.timeshift_cam_imu``).
        imu_yaml: Kalibr's ``imu.yaml`` with the noise figures and rate; without it the typical
            MEMS figures of :class:`~sea3d.geometry.rig.ImuSpec` are used (a warning is logged).

    Raises:
        RigFileError: a missing file or key, or a ``T_cam_imu`` that is not rigid.
    """
    path = Path(camchain)
    data = _load_yaml(path)
    cam0 = data.get("cam0")
    if not isinstance(cam0, Mapping):
        raise RigFileError(f"{path}: key 'cam0': missing")
    T_left_imu = _matrix(cam0, "T_cam_imu", f"{path}: cam0")
    shift = (
        _number(cam0, "timeshift_cam_imu", f"{path}: cam0") if "timeshift_cam_imu" in cam0 else 0.0
    )
    noise = _imu_noise(Path(imu_yaml) if imu_yaml is not None else None)
    try:
        return ImuSpec(T_left_imu=T_left_imu, time_offset_s=shift, **noise)
    except Sea3dError as err:
        raise RigFileError(f"{path}: {err}") from err


def rig_from_kalibr(
    camchain: str | os.PathLike[str], imu_yaml: str | os.PathLike[str] | None = None
) -> StereoRig:
    """A pinhole stereo rig (``cam0`` left, ``cam1`` right) from a Kalibr camchain, with its IMU
    when the file holds ``T_cam_imu``.

    Raises:
        RigFileError: a missing file or key, a camera model other than pinhole-radtan, or
            cameras of different sizes.
    """
    path = Path(camchain)
    data = _load_yaml(path)
    left = _camera(data.get("cam0"), "cam0", path)
    right = _camera(data.get("cam1"), "cam1", path)
    cam1 = data["cam1"]
    if "T_cn_cnm1" in cam1:
        T_right_left = _matrix(cam1, "T_cn_cnm1", f"{path}: cam1")
    elif "T_cam_imu" in cam1 and "T_cam_imu" in data["cam0"]:
        T_right_left = _matrix(cam1, "T_cam_imu", f"{path}: cam1") @ invert_T(
            _matrix(data["cam0"], "T_cam_imu", f"{path}: cam0")
        )
    else:
        raise RigFileError(f"{path}: cam1: key 'T_cn_cnm1': missing")
    imu = imu_from_kalibr(path, imu_yaml) if "T_cam_imu" in data["cam0"] else None
    try:
        return StereoRig(left=left, right=right, T_left_right=invert_T(T_right_left), imu=imu)
    except Sea3dError as err:
        raise RigFileError(f"{path}: {err}") from err


def with_kalibr_imu(
    rig: StereoRig,
    camchain: str | os.PathLike[str],
    imu_yaml: str | os.PathLike[str] | None = None,
    *,
    max_baseline_mismatch_m: float = 0.005,
) -> StereoRig:
    """The rig with the IMU of a Kalibr camchain attached (``cam0`` = the rig's left camera).

    When the camchain also has ``cam1.T_cam_imu``, the stereo extrinsics it implies are checked
    against the rig's ``T_left_right``; a mismatch over ``max_baseline_mismatch_m`` means the
    files do not belong together.

    Raises:
        RigFileError: bad files, or a camchain whose stereo extrinsics contradict the rig's.
    """
    imu = imu_from_kalibr(camchain, imu_yaml)
    data = _load_yaml(Path(camchain))
    cam1 = data.get("cam1")
    if isinstance(cam1, Mapping) and "T_cam_imu" in cam1:
        T_right_imu = _matrix(cam1, "T_cam_imu", f"{camchain}: cam1")
        T_left_right = imu.T_left_imu @ invert_T(T_right_imu)
        gap = float(np.linalg.norm(T_left_right[:3, 3] - rig.T_left_right[:3, 3]))
        if gap > max_baseline_mismatch_m:
            raise RigFileError(
                f"{camchain}: cam0/cam1 T_cam_imu put the right camera {gap * 1e3:.1f} mm from "
                f"where the rig has it ({np.round(T_left_right[:3, 3], 4).tolist()} m against "
                f"{np.round(rig.T_left_right[:3, 3], 4).tolist()} m); is cam0 the left camera "
                "and are both files from the same rig?"
            )
    import dataclasses

    return dataclasses.replace(rig, imu=imu)
