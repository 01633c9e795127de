"""Camera-IMU rotation and time offset from orientations and the gyro (sea3d.calib.imu)."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.calib.imu import CameraImuStatus, estimate_camera_imu
from sea3d.errors import CalibrationError
from sea3d.geometry.se3 import R_to_rotvec, rotvec_to_R
from sea3d.sim.motion import (
    HandHeld,
    ImuNoise,
    Lawnmower,
    Mount,
    imu_samples,
    poses,
    sample_times_ns,
)

# Orientation noise 0.5 mrad per frame (a good visual odometry) and MTi-300 gyro noise; the
# estimate then lands within these (measured: 0.03 deg and 0.2 ms), with margin.
ROTATION_TOL_DEG = 0.2
OFFSET_TOL_S = 0.002


def _data(traj, offset_s, seed, R_cam_imu=None, duration=20.0):
    mount = Mount.default()
    T_body_left = mount.T_body_left.copy()
    if R_cam_imu is not None:
        T_body_left[:3, :3] = R_cam_imu.T
    t_cam = sample_times_ns(duration, 10.0)
    T_wl = poses(traj, t_cam * 1e-9) @ T_body_left
    t_imu = sample_times_ns(duration, 200.0)
    imu = imu_samples(traj, t_imu, noise=ImuNoise.mti300(), rng=np.random.default_rng(seed))
    g = np.random.default_rng(seed + 1)
    R = T_wl[:, :3, :3] @ np.stack([rotvec_to_R(g.normal(0, 5e-4, 3)) for _ in t_cam])
    # the IMU clock runs offset_s ahead: a sample taken at camera time t is stamped t + offset
    return t_cam, R, t_imu + round(offset_s * 1e9), imu.gyro_radps, T_body_left[:3, :3].T


@pytest.mark.parametrize("offset_s", [0.037, -0.12])
def test_recovers_rotation_and_planted_offset(offset_s) -> None:
    R_true = rotvec_to_R([0.4, -2.0, 0.9])
    t_cam, R, t_imu, gyro, R_ci = _data(HandHeld(duration_s=20.0), offset_s, 5, R_true)
    res = estimate_camera_imu(t_cam, R, t_imu, gyro)
    assert res.status is CameraImuStatus.OK
    err_deg = np.degrees(np.linalg.norm(R_to_rotvec(res.R_cam_imu.T @ R_ci)))
    assert err_deg < ROTATION_TOL_DEG
    assert abs(res.time_offset_s - offset_s) < OFFSET_TOL_S
    assert res.correlation > 0.9
    assert res.rotation_sigma_deg < ROTATION_TOL_DEG
    assert res.time_offset_sigma_s < OFFSET_TOL_S


def test_turning_about_one_axis_is_reported_as_weak() -> None:
    # a lawnmower barely rolls or pitches: essentially yaw only
    traj = Lawnmower(duration_s=40.0, width_m=3.0, speed_mps=0.3)
    t_cam, R, t_imu, gyro, _ = _data(traj, 0.0, 2, duration=40.0)
    res = estimate_camera_imu(t_cam, R, t_imu, gyro)
    assert res.excitation_radps[1] < 0.1 * res.excitation_radps[0]
    assert res.status is CameraImuStatus.WEAK_EXCITATION
    assert res.rotation_sigma_deg > 0.5


def test_unrelated_gyro_and_too_few_frames_are_statuses_not_exceptions() -> None:
    t_cam, R, t_imu, _gyro, _ = _data(HandHeld(duration_s=20.0), 0.0, 3)
    noise = np.random.default_rng(9).normal(0, 0.2, (t_imu.size, 3))
    assert estimate_camera_imu(t_cam, R, t_imu, noise).status is CameraImuStatus.NO_MATCH
    few = estimate_camera_imu(t_cam[:5], R[:5], t_imu, noise)
    assert few.status is CameraImuStatus.TOO_FEW
    with pytest.raises(CalibrationError, match="expected R_world_cam"):
        estimate_camera_imu(t_cam, R[:3], t_imu, noise)


def test_weak_excitation_names_the_idle_axes_and_the_motion_to_record() -> None:
    traj = Lawnmower(duration_s=40.0, width_m=3.0, speed_mps=0.3)
    t_cam, R, t_imu, gyro, _ = _data(traj, 0.0, 2, duration=40.0)
    res = estimate_camera_imu(t_cam, R, t_imu, gyro)
    assert res.status is CameraImuStatus.WEAK_EXCITATION
    text = " ".join(res.advice)
    # a level lawnmower turns about the world vertical only: two camera axes idle
    assert "too little rotation about the camera's" in text
    idle = [n for n in ("x (tilt", "y (pan", "z (roll") if n in res.advice[0]]
    assert len(idle) == 2
    assert "turn the rig by 15-30 deg" in text and "rad/s" in text
    assert res.duration_s == pytest.approx(39.0, abs=0.2)  # 40 s less the +-0.5 s searched
    assert res.as_dict()["advice"] == res.advice


def test_a_short_good_clip_is_told_how_long_to_record() -> None:
    R_true = rotvec_to_R([0.4, -2.0, 0.9])
    t_cam, R, t_imu, gyro, _ = _data(HandHeld(duration_s=4.0), 0.0, 5, R_true, duration=4.0)
    res = estimate_camera_imu(t_cam, R, t_imu, gyro, max_rotation_sigma_deg=0.02)
    assert res.status is CameraImuStatus.WEAK_EXCITATION
    assert any("record about" in a for a in res.advice) or any(
        "too little rotation" in a for a in res.advice
    )
    ok = estimate_camera_imu(t_cam, R, t_imu, gyro)
    assert ok.advice == [] if ok.status is CameraImuStatus.OK else ok.advice


def test_too_few_and_no_match_say_what_to_do() -> None:
    t_cam, R, t_imu, _gyro, _ = _data(HandHeld(duration_s=20.0), 0.0, 3)
    noise = np.random.default_rng(9).normal(0, 0.2, (t_imu.size, 3))
    nm = estimate_camera_imu(t_cam, R, t_imu, noise)
    assert nm.status is CameraImuStatus.NO_MATCH and "max_offset_s" in nm.advice[0]
    few = estimate_camera_imu(t_cam[:5], R[:5], t_imu, noise)
    assert "record at least 10 s" in few.advice[0]
