"""Trajectories and the IMU: noiseless IMU readings integrate back to the ground-truth poses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from sea3d.errors import SimulationError
from sea3d.sim.motion import (
    GRAVITY_WORLD,
    HandHeld,
    ImuNoise,
    Lawnmower,
    Orbit,
    imu_samples,
    make_trajectory,
    poses,
    sample_times_ns,
)

IMU_RATE_HZ = 200.0
INTEGRATION_DURATION_S = 10.0
POSITION_TOL_M = 1e-3  # issue: 10 s of noiseless IMU reproduces the pose within 1 mm
ROTATION_TOL_RAD = 1e-4


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def _integrate(traj, t_ns: np.ndarray, accel: np.ndarray, gyro: np.ndarray) -> np.ndarray:
    """Strapdown integration, RK4 in (R, v, p) with the IMU signals interpolated by cubic splines
    between samples (independent of how the simulator computes them)."""
    t = t_ns * 1e-9
    fa = CubicSpline(t, accel)
    fg = CubicSpline(t, gyro)
    T0 = poses(traj, t[:1])[0]
    R, p = T0[:3, :3].copy(), T0[:3, 3].copy()
    hp = 1e-4
    v = (traj.position_m(t[:1] + hp) - traj.position_m(t[:1] - hp))[0] / (2 * hp)

    def deriv(tt: float, R: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return R @ _skew(fg(tt)), R @ fa(tt) + GRAVITY_WORLD, v

    out = [np.eye(4)]
    out[0][:3, :3], out[0][:3, 3] = R, p
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        k1 = deriv(t[k], R, v)
        k2 = deriv(t[k] + h / 2, R + h / 2 * k1[0], v + h / 2 * k1[1])
        k3 = deriv(t[k] + h / 2, R + h / 2 * k2[0], v + h / 2 * k2[1])
        k4 = deriv(t[k] + h, R + h * k3[0], v + h * k3[1])
        R = R + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        p = p + h / 6 * (v + 2 * (v + h / 2 * k1[1]) + 2 * (v + h / 2 * k2[1]) + (v + h * k3[1]))
        v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        u, _, vt = np.linalg.svd(R)
        R = u @ vt
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        out.append(T)
    return np.array(out)


@pytest.mark.parametrize(
    "traj",
    [Lawnmower(duration_s=10), Orbit(duration_s=10, period_s=20), HandHeld(duration_s=10)],
    ids=["lawnmower", "orbit", "handheld"],
)
def test_noiseless_imu_integrates_to_ground_truth_pose_within_1mm(traj) -> None:
    t_ns = sample_times_ns(INTEGRATION_DURATION_S, IMU_RATE_HZ)
    imu = imu_samples(traj, t_ns)
    est = _integrate(traj, t_ns, imu.accel_mps2, imu.gyro_radps)
    gt = poses(traj, t_ns * 1e-9)
    pos_err = np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1)
    dR = np.einsum("nji,njk->nik", gt[:, :3, :3], est[:, :3, :3])
    rot_err = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert pos_err.max() < POSITION_TOL_M, pos_err.max()
    assert rot_err.max() < ROTATION_TOL_RAD, rot_err.max()


def test_imu_at_rest_reads_gravity_up_and_no_rotation() -> None:
    traj = HandHeld(velocity_mps=(0, 0, 0), shake_m=0.0, shake_deg=0.0, pitch_deg=0.0, yaw_deg=30.0)
    imu = imu_samples(traj, sample_times_ns(1.0, IMU_RATE_HZ))
    np.testing.assert_allclose(imu.accel_mps2, np.tile([0, 0, 9.81], (201, 1)), atol=1e-9)
    np.testing.assert_allclose(imu.gyro_radps, 0, atol=1e-9)


def test_imu_white_noise_matches_the_datasheet_density() -> None:
    rng = np.random.default_rng(0)
    traj = HandHeld(velocity_mps=(0, 0, 0), shake_m=0.0, shake_deg=0.0, pitch_deg=0.0)
    noise = ImuNoise(gyro_bias_rw_radps_sqrts=0.0, accel_bias_rw_mps2_sqrts=0.0)
    imu = imu_samples(traj, sample_times_ns(50.0, IMU_RATE_HZ), noise=noise, rng=rng)
    expected = noise.gyro_noise_density_radps_sqrthz * np.sqrt(IMU_RATE_HZ)
    assert abs(imu.gyro_radps.std() / expected - 1) < 0.05
    expected_a = noise.accel_noise_density_mps2_sqrthz * np.sqrt(IMU_RATE_HZ)
    assert abs((imu.accel_mps2 - [0, 0, 9.81]).std() / expected_a - 1) < 0.05


def test_imu_noise_needs_a_generator_and_unknown_trajectory_is_rejected() -> None:
    with pytest.raises(SimulationError):
        imu_samples(Orbit(), sample_times_ns(1.0, IMU_RATE_HZ), noise=ImuNoise())
    with pytest.raises(SimulationError, match="spiral"):
        make_trajectory("spiral", duration_s=1.0)


def test_sample_times_are_integer_nanoseconds_at_the_rate() -> None:
    t = sample_times_ns(1.0, 200.0, start_ns=7)
    assert t.dtype == np.int64 and t[0] == 7 and t[-1] == 7 + 1_000_000_000 and len(t) == 201
