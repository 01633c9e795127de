"""EuRoC MAV dataset folders (ASL layout): stereo images, IMU, calibration, ground truth.

Layout (Burri et al., IJRR 2016)::

    <sequence>/mav0/cam0/data.csv        #timestamp [ns],filename     (cam0 = left)
                    cam0/data/<t_ns>.png
                    cam0/sensor.yaml       T_BS (body from sensor), intrinsics [fu fv cu cv],
                                           radial-tangential distortion, resolution
                    cam1/...               (right)
                    imu0/data.csv          #timestamp [ns], w_x w_y w_z [rad/s], a_x a_y a_z [m/s^2]
                    imu0/sensor.yaml       T_BS, noise densities and random walks, rate_hz
                    state_groundtruth_estimate0/data.csv   (optional) p_RS_R, q_RS (w first), ...

The body frame is EuRoC's (the IMU's, ``T_BS`` of imu0 is the identity). The rig's
``T_left_imu`` is ``T_BS(cam0)^-1 T_BS(imu0)``. Rows of ``data.csv`` whose image is missing are
skipped with a warning (the micro excerpt in the test data lists four such rows in cam1).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from sea3d.errors import Sea3dError, SessionError
from sea3d.geometry.pinhole import PinholeCamera
from sea3d.geometry.rig import ImuSpec, StereoRig
from sea3d.geometry.se3 import invert_T

__all__ = ["EurocSequence", "is_euroc", "read_euroc"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True, eq=False)
class EurocSequence:
    """An EuRoC sequence on disk.

    Attributes:
        root: the ``mav0`` folder.
        rig: pinhole stereo rig (cam0 left, cam1 right) with the IMU.
        t_ns: (N,) stamps of the stereo frames (both cameras share them).
        left_paths, right_paths: image files of those frames.
        imu_t_ns: (M,) IMU stamps; ``accel_mps2`` (M, 3), ``gyro_radps`` (M, 3).
        gt_t_ns: (G,) ground-truth stamps (empty without ground truth).
        gt_T_world_body: (G, 4, 4) ground-truth body poses.
    """

    root: Path
    rig: StereoRig
    t_ns: NDArray[np.int64]
    left_paths: list[Path]
    right_paths: list[Path]
    imu_t_ns: NDArray[np.int64]
    accel_mps2: NDArray[np.float64]
    gyro_radps: NDArray[np.float64]
    gt_t_ns: NDArray[np.int64]
    gt_T_world_body: NDArray[np.float64]

    def image(self, side: str, index: int) -> NDArray[np.uint8]:
        """The grey image of frame ``index`` (``side`` ``left`` or ``right``).

        Raises:
            SessionError: an unreadable file.
        """
        import cv2

        path = (self.left_paths if side == "left" else self.right_paths)[index]
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise SessionError(f"{path}: cannot read the image")
        return np.asarray(img, dtype=np.uint8)


def _mav0(path: str | os.PathLike[str]) -> Path | None:
    p = Path(path)
    for cand in (p / "mav0", p):
        if (cand / "cam0" / "data.csv").is_file() and (cand / "cam1" / "data.csv").is_file():
            return cand
    return None


def is_euroc(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` (or its ``mav0``) holds EuRoC's ``cam0``/``cam1`` folders."""
    return _mav0(path) is not None


def _yaml(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text()
    except OSError as err:
        raise SessionError(f"{path}: cannot read: {err}") from err
    lines = [ln for ln in text.splitlines() if not ln.startswith("%YAML")]
    try:
        data = yaml.safe_load("\n".join(lines))
    except yaml.YAMLError as err:
        raise SessionError(f"{path}: not valid YAML: {err}") from err
    if not isinstance(data, dict):
        raise SessionError(f"{path}: expected a mapping")
    return data


def _T_BS(data: dict[str, Any], path: Path) -> NDArray[np.float64]:
    try:
        T = np.asarray(data["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
    except (KeyError, TypeError, ValueError) as err:
        raise SessionError(f"{path}: key 'T_BS': expected 16 numbers ({err})") from err
    return T


def _camera(path: Path) -> tuple[PinholeCamera, NDArray[np.float64]]:
    data = _yaml(path)
    try:
        fu, fv, cu, cv = (float(v) for v in data["intrinsics"])
        w, h = (int(v) for v in data["resolution"])
        dist = np.asarray(data.get("distortion_coefficients", []), dtype=np.float64)
        if data.get("distortion_model", "radial-tangential") != "radial-tangential":
            raise SessionError(
                f"{path}: only radial-tangential distortion is read, got "
                f"{data.get('distortion_model')!r}"
            )
        return PinholeCamera(fx=fu, fy=fv, cx=cu, cy=cv, width=w, height=h, dist=dist), _T_BS(
            data, path
        )
    except KeyError as err:
        raise SessionError(f"{path}: key {err}: missing") from err
    except (TypeError, ValueError) as err:
        raise SessionError(f"{path}: {err}") from err


def _frames(cam: Path) -> tuple[NDArray[np.int64], list[Path]]:
    csv = cam / "data.csv"
    stamps, paths, missing = [], [], 0
    for line in csv.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        parts = [s.strip() for s in line.split(",")]
        try:
            t = int(parts[0])
        except ValueError as err:
            raise SessionError(f"{csv}: bad stamp {parts[0]!r}") from err
        f = cam / "data" / (parts[1] if len(parts) > 1 else f"{t}.png")
        if not f.is_file():
            missing += 1
            continue
        stamps.append(t)
        paths.append(f)
    if missing:
        log.warning("%s: %d listed images are missing; skipped", csv, missing)
    order = np.argsort(stamps, kind="stable")
    return np.asarray(stamps, dtype=np.int64)[order], [paths[i] for i in order]


def _imu_spec(root: Path, T_B_c0: NDArray[np.float64]) -> ImuSpec:
    imu_path = root / "imu0" / "sensor.yaml"
    imu_data = _yaml(imu_path)
    T_B_imu = _T_BS(imu_data, imu_path)
    try:
        return ImuSpec(
            T_left_imu=invert_T(T_B_c0) @ T_B_imu,
            rate_hz=float(imu_data.get("rate_hz", 200.0)),
            gyro_noise_density_radps_sqrthz=float(imu_data["gyroscope_noise_density"]),
            gyro_random_walk_radps_sqrts=float(imu_data["gyroscope_random_walk"]),
            accel_noise_density_mps2_sqrthz=float(imu_data["accelerometer_noise_density"]),
            accel_random_walk_mps2_sqrts=float(imu_data["accelerometer_random_walk"]),
        )
    except KeyError as err:
        raise SessionError(f"{imu_path}: key {err}: missing") from err
    except Sea3dError as err:
        raise SessionError(f"{imu_path}: {err}") from err


def read_euroc(path: str | os.PathLike[str], *, imu: bool = True) -> EurocSequence:
    """Read an EuRoC sequence folder (the one holding ``mav0``, or ``mav0`` itself).

    Only what is used is read: ``imu=False`` (visual-only) ignores ``imu0`` entirely; with
    ``imu=True`` a folder without ``imu0`` gives a rig without an IMU block and no samples
    (the odometry then runs visual-only and says so), while a damaged ``imu0`` is an error.

    Raises:
        SessionError: not an EuRoC folder, or unreadable calibration or CSV files.
    """
    root = _mav0(path)
    if root is None:
        raise SessionError(f"{path}: not an EuRoC folder (expected mav0/cam0/data.csv and "
                           "mav0/cam1/data.csv)")
    left, T_B_c0 = _camera(root / "cam0" / "sensor.yaml")
    right, T_B_c1 = _camera(root / "cam1" / "sensor.yaml")
    spec: ImuSpec | None = None
    has_imu = imu and (root / "imu0").is_dir()
    if imu and not has_imu:
        log.warning("%s: no imu0 folder: the sequence has no IMU", root)
    if has_imu:
        spec = _imu_spec(root, T_B_c0)
    try:
        rig = StereoRig(left=left, right=right, T_left_right=invert_T(T_B_c0) @ T_B_c1, imu=spec)
    except Sea3dError as err:
        raise SessionError(f"{root}: {err}") from err
    tl, pl = _frames(root / "cam0")
    tr, pr = _frames(root / "cam1")
    common, il, ir = np.intersect1d(tl, tr, return_indices=True)
    if common.size < tl.size:
        log.warning(
            "%s: %d left frames have no right frame with the same stamp",
            root,
            tl.size - common.size,
        )
    raw: NDArray[np.float64] = np.zeros((0, 7))
    t_imu: NDArray[np.int64] = np.zeros(0, np.int64)
    if has_imu:
        imu_csv = root / "imu0" / "data.csv"
        try:
            raw = np.loadtxt(imu_csv, delimiter=",", comments="#", dtype=np.float64, ndmin=2)
            t_imu = np.loadtxt(imu_csv, delimiter=",", comments="#", usecols=0, dtype=np.int64,
                               ndmin=1)
        except (OSError, ValueError) as err:
            raise SessionError(f"{imu_csv}: cannot read: {err}") from err
        if raw.shape[1] < 7:
            raise SessionError(f"{imu_csv}: {raw.shape[1]} columns, expected 7 (t, gyro, accel)")
    gt_csv = root / "state_groundtruth_estimate0" / "data.csv"
    gt_t: NDArray[np.int64] = np.zeros(0, np.int64)
    gt_T: NDArray[np.float64] = np.zeros((0, 4, 4))
    if gt_csv.is_file():
        from sea3d.geometry.se3 import quat_wxyz_to_R

        g = np.loadtxt(gt_csv, delimiter=",", comments="#", dtype=np.float64, ndmin=2)
        gt_t = np.loadtxt(gt_csv, delimiter=",", comments="#", usecols=0, dtype=np.int64, ndmin=1)
        gt_T = np.tile(np.eye(4), (g.shape[0], 1, 1))
        for i in range(g.shape[0]):
            gt_T[i, :3, :3] = quat_wxyz_to_R(g[i, 4:8])
            gt_T[i, :3, 3] = g[i, 1:4]
    return EurocSequence(
        root=root,
        rig=rig,
        t_ns=common.astype(np.int64),
        left_paths=[pl[i] for i in il],
        right_paths=[pr[i] for i in ir],
        imu_t_ns=t_imu,
        accel_mps2=raw[:, 4:7],
        gyro_radps=raw[:, 1:4],
        gt_t_ns=gt_t,
        gt_T_world_body=gt_T,
    )
