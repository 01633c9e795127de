"""Vehicle motion and the sensors that follow it: trajectories, IMU, echosounder.

Frames: ``world`` is z up (gravity ``(0, 0, -9.81)`` m/s^2); ``body`` is the IMU/vehicle frame,
x forward, y left, z up (FLU). A trajectory gives ``T_world_body(t)`` as a smooth (C-infinity)
function of time; its orientation is ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` with positive pitch
tipping the nose down. The cameras hang on the body through :class:`Mount`.

The IMU measures, in the body frame, the specific force ``f = R_world_body^T (a_world - g)`` and
the angular rate ``omega`` with ``dR_world_body/dt = R_world_body [omega]x``. Both are computed
from the trajectory by 4th-order central differences (errors ~1e-9), so integrating the noiseless
IMU reproduces the trajectory.

Noise (:class:`ImuNoise`): white noise plus a bias random walk per axis. The default figures are
the typical values of the Movella (Xsens) MTi-300 datasheet (May 2023,
https://cdn.shopify.com/s/files/1/0716/3048/7831/files/MTi-300.pdf): gyroscope noise density
0.01 deg/s/sqrt(Hz), in-run bias stability 10 deg/h; accelerometer noise density 60 ug/sqrt(Hz),
in-run bias stability 15 ug. A bias random walk has no single datasheet
figure; we choose its density so the bias wanders by about the in-run stability in 100 s
(``sigma_rw = stability / sqrt(100 s)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import FloatArray
from sea3d.errors import SimulationError

__all__ = [
    "GRAVITY_WORLD",
    "HandHeld",
    "ImuNoise",
    "ImuSamples",
    "Lawnmower",
    "Mount",
    "Orbit",
    "Trajectory",
    "imu_samples",
    "make_trajectory",
    "sample_times_ns",
]

GRAVITY_WORLD = np.array([0.0, 0.0, -9.81])
_DEG = np.pi / 180.0
_UG = 9.81e-6  # one micro-g in m/s^2


def _rot_zyx(yaw: FloatArray, pitch: FloatArray, roll: FloatArray) -> FloatArray:
    """``(N, 3, 3)`` rotation matrices Rz(yaw) Ry(pitch) Rx(roll)."""
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    R = np.empty((yaw.shape[0], 3, 3))
    R[:, 0, 0] = cy * cp
    R[:, 0, 1] = cy * sp * sr - sy * cr
    R[:, 0, 2] = cy * sp * cr + sy * sr
    R[:, 1, 0] = sy * cp
    R[:, 1, 1] = sy * sp * sr + cy * cr
    R[:, 1, 2] = sy * sp * cr - cy * sr
    R[:, 2, 0] = -sp
    R[:, 2, 1] = cp * sr
    R[:, 2, 2] = cp * cr
    return R


class Trajectory(Protocol):
    """A smooth body trajectory."""

    @property
    def duration_s(self) -> float:
        """Length of the trajectory, seconds."""
        ...

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """``(N, 3)`` body origin in the world frame, metres, at times ``t_s`` ``(N,)``."""
        ...

    def rotation(self, t_s: FloatArray) -> FloatArray:
        """``(N, 3, 3)`` ``R_world_body`` at times ``t_s`` ``(N,)``."""
        ...


def poses(traj: Trajectory, t_s: FloatArray) -> FloatArray:
    """``(N, 4, 4)`` ``T_world_body`` at times ``t_s``."""
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
    T = np.tile(np.eye(4), (t.shape[0], 1, 1))
    T[:, :3, :3] = traj.rotation(t)
    T[:, :3, 3] = traj.position_m(t)
    return T


@dataclass(frozen=True, kw_only=True)
class Lawnmower:
    """A survey of parallel lanes along x, advancing along y, at constant height, with rounded
    turns (x = W/2 tanh(a sin(phi)) / tanh(a), y advances while x turns), body level, heading
    along the velocity.

    Attributes:
        center_m: ``(x, y)`` centre of the first lane's sweep, world metres.
        z_m: world height of the body.
        width_m: lane length.
        lane_spacing_m: distance between lanes.
        speed_mps: approximate speed along a lane.
        duration_s: trajectory length, seconds.
        bob_m: amplitude of a slow vertical bob.
    """

    center_m: tuple[float, float] = (0.0, -1.0)
    z_m: float = 1.5
    width_m: float = 3.0
    lane_spacing_m: float = 0.5
    speed_mps: float = 0.3
    duration_s: float = 60.0
    bob_m: float = 0.03
    sharpness: float = 2.0

    @property
    def _omega(self) -> float:
        return float(np.pi * self.speed_mps / (1.3 * self.width_m))

    def _vxy(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        w, a = self._omega, self.sharpness
        phi = w * t
        c = 2.0 * w * self.lane_spacing_m / np.pi
        vx = self.width_m / 2 * a * np.cos(phi) * w / np.cosh(a * np.sin(phi)) ** 2 / np.tanh(a)
        vy = c * np.sin(phi) ** 2
        return vx, vy

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """See :class:`Trajectory`."""
        t = np.asarray(t_s, dtype=np.float64)
        w, a = self._omega, self.sharpness
        phi = w * t
        c = 2.0 * w * self.lane_spacing_m / np.pi
        x = self.center_m[0] + self.width_m / 2 * np.tanh(a * np.sin(phi)) / np.tanh(a)
        y = self.center_m[1] + c * (t / 2 - np.sin(2 * phi) / (4 * w))
        z = self.z_m + self.bob_m * np.sin(0.5 * t)
        return np.stack([x, y, z], axis=1)

    def rotation(self, t_s: FloatArray) -> FloatArray:
        """See :class:`Trajectory`."""
        t = np.asarray(t_s, dtype=np.float64)
        vx, vy = self._vxy(t)
        yaw = np.arctan2(vy, vx)
        return _rot_zyx(yaw, 0.02 * np.sin(0.9 * t), 0.02 * np.sin(0.7 * t + 1.0))


@dataclass(frozen=True, kw_only=True)
class Orbit:
    """A circle around a target at constant height, the body's nose pitched down towards it.

    Attributes:
        target_m: ``(x, y, z)`` point orbited, world metres.
        radius_m: horizontal radius.
        height_m: height of the body above the target.
        period_s: time for one full circle.
        duration_s: trajectory length, seconds.
        camera_tilt_deg: the mount's camera tilt; the body pitches by the rest so the camera's
            optical axis points at the target.
    """

    target_m: tuple[float, float, float] = (0.0, 0.0, 0.1)
    radius_m: float = 1.2
    height_m: float = 0.8
    period_s: float = 60.0
    duration_s: float = 60.0
    camera_tilt_deg: float = 30.0

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """See :class:`Trajectory`."""
        t = np.asarray(t_s, dtype=np.float64)
        th = 2 * np.pi * t / self.period_s
        tx, ty, tz = self.target_m
        return np.stack(
            [
                tx + self.radius_m * np.cos(th),
                ty + self.radius_m * np.sin(th),
                np.full_like(t, tz + self.height_m),
            ],
            axis=1,
        )

    def rotation(self, t_s: FloatArray) -> FloatArray:
        """See :class:`Trajectory`."""
        t = np.asarray(t_s, dtype=np.float64)
        th = 2 * np.pi * t / self.period_s
        pitch = np.arctan2(self.height_m, self.radius_m) - self.camera_tilt_deg * _DEG
        return _rot_zyx(th + np.pi, np.full_like(t, pitch), np.zeros_like(t))


@dataclass(frozen=True, kw_only=True)
class HandHeld:
    """A diver's hand-held pass: a slow drift plus sums of sinusoids (seeded) in position and
    orientation, like an unsteady hand.

    Attributes:
        start_m: ``(x, y, z)`` start position, world metres.
        velocity_mps: ``(vx, vy, vz)`` mean drift, world.
        yaw_deg: mean heading.
        pitch_deg: mean nose-down pitch.
        shake_m: amplitude scale of the positional wobble.
        shake_deg: amplitude scale of the angular wobble.
        duration_s: trajectory length, seconds.
        seed: chooses the wobble.
    """

    start_m: tuple[float, float, float] = (-1.0, -1.0, 1.2)
    velocity_mps: tuple[float, float, float] = (0.05, 0.04, 0.0)
    yaw_deg: float = 40.0
    pitch_deg: float = 15.0
    shake_m: float = 0.04
    shake_deg: float = 3.0
    duration_s: float = 30.0
    seed: int = 0
    _terms: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        g = np.random.default_rng(self.seed)
        # 6 channels (x, y, z, yaw, pitch, roll) x 4 sinusoids x (amplitude, frequency Hz, phase)
        amp = g.uniform(0.3, 1.0, (6, 4)) / np.arange(1, 5)[None, :]
        freq = g.uniform(0.1, 1.2, (6, 4))
        phase = g.uniform(0, 2 * np.pi, (6, 4))
        object.__setattr__(self, "_terms", np.stack([amp, freq, phase], axis=-1))

    def _wobble(self, t: FloatArray) -> FloatArray:
        a, f, p = self._terms[..., 0], self._terms[..., 1], self._terms[..., 2]
        s = np.sin(2 * np.pi * f[None] * t[:, None, None] + p[None]) - np.sin(p[None])
        return (a[None] * s).sum(axis=2)  # (N, 6), zero at t = 0

    def position_m(self, t_s: FloatArray) -> FloatArray:
        """See :class:`Trajectory`."""
        t = np.asarray(t_s, dtype=np.float64)
        w = self._wobble(t)
        return (
            np.asarray(self.start_m)[None]
            + t[:, None] * np.asarray(self.velocity_mps)[None]
            + self.shake_m * w[:, :3]
        )

    def rotation(self, t_s: FloatArray) -> FloatArray:
        """See :class:`Trajectory`."""
        t = np.asarray(t_s, dtype=np.float64)
        w = self._wobble(t) * self.shake_deg * _DEG
        return _rot_zyx(self.yaw_deg * _DEG + w[:, 3], self.pitch_deg * _DEG + w[:, 4], w[:, 5])


def make_trajectory(
    kind: str,
    *,
    duration_s: float,
    scene_center_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
    floor_z_m: float = 0.0,
    camera_tilt_deg: float = 30.0,
    seed: int = 0,
    scale_m: float = 1.0,
) -> Trajectory:
    """A default trajectory of a kind (``lawnmower``, ``orbit``, ``handheld``) for a scene.

    Args:
        kind: trajectory kind.
        duration_s: length, seconds.
        scene_center_m: the point of interest (world).
        floor_z_m: floor height there.
        camera_tilt_deg: the mount's camera tilt (orbit keeps the camera on the target).
        seed: hand-held wobble.
        scale_m: scales distances (0.4 for the tank).

    Raises:
        SimulationError: for an unknown kind or a non-positive duration.
    """
    if duration_s <= 0:
        raise SimulationError(f"trajectory duration must be positive, got {duration_s} s")
    cx, cy, cz = scene_center_m
    if kind == "lawnmower":
        return Lawnmower(
            center_m=(cx, cy - 1.0 * scale_m),
            z_m=floor_z_m + 1.5 * scale_m,
            width_m=3.0 * scale_m,
            lane_spacing_m=0.5 * scale_m,
            speed_mps=0.3 * scale_m,
            duration_s=duration_s,
        )
    if kind == "orbit":
        return Orbit(
            target_m=(cx, cy, cz),
            radius_m=1.2 * scale_m,
            height_m=0.8 * scale_m,
            period_s=max(duration_s, 20.0),
            duration_s=duration_s,
            camera_tilt_deg=camera_tilt_deg,
        )
    if kind in ("handheld", "hand-held"):
        return HandHeld(
            start_m=(cx - 0.9 * scale_m, cy - 0.9 * scale_m, floor_z_m + 1.0 * scale_m),
            velocity_mps=(0.04 * scale_m, 0.04 * scale_m, 0.0),
            yaw_deg=45.0,
            pitch_deg=25.0,
            duration_s=duration_s,
            seed=seed,
        )
    raise SimulationError(f"unknown trajectory {kind!r}; choose lawnmower, orbit or handheld")


@dataclass(frozen=True, kw_only=True)
class Mount:
    """Where the sensors sit on the body.

    Attributes:
        T_body_left: ``(4, 4)`` left camera in the body frame.
        T_body_sonar: ``(4, 4)`` echosounder; its beam points along its own -z.
    """

    T_body_left: FloatArray
    T_body_sonar: FloatArray

    @classmethod
    def default(cls, *, baseline_m: float = 0.107, camera_tilt_deg: float = 30.0) -> Mount:
        """Cameras looking forward along body x, tilted down by ``camera_tilt_deg``, 15 cm ahead of
        the IMU with the stereo pair centred on the body's x axis; the echosounder 10 cm below the
        IMU, looking straight down the body's -z."""
        base = np.array(
            [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
        )  # columns: cam x, y, z in body
        th = camera_tilt_deg * _DEG
        Ry = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
        T = np.eye(4)
        T[:3, :3] = Ry @ base
        T[:3, 3] = (0.15, baseline_m / 2, 0.0)
        S = np.eye(4)
        S[:3, 3] = (0.0, 0.0, -0.10)
        return cls(T_body_left=T, T_body_sonar=S)


@dataclass(frozen=True, kw_only=True)
class ImuNoise:
    """IMU noise: white noise densities and bias random walks (see the module docstring).

    Attributes:
        gyro_noise_density_radps_sqrthz: gyroscope white noise, rad/s/sqrt(Hz).
        gyro_bias_rw_radps_sqrts: gyroscope bias random walk, rad/s/sqrt(s).
        accel_noise_density_mps2_sqrthz: accelerometer white noise, m/s^2/sqrt(Hz).
        accel_bias_rw_mps2_sqrts: accelerometer bias random walk, m/s^2/sqrt(s).
    """

    gyro_noise_density_radps_sqrthz: float = 0.01 * _DEG
    gyro_bias_rw_radps_sqrts: float = 10.0 * _DEG / 3600.0 / 10.0
    accel_noise_density_mps2_sqrthz: float = 60.0 * _UG
    accel_bias_rw_mps2_sqrts: float = 15.0 * _UG / 10.0

    @classmethod
    def mti300(cls) -> ImuNoise:
        """The MTi-300 figures (the defaults)."""
        return cls()


@dataclass(frozen=True, kw_only=True, eq=False)
class ImuSamples:
    """IMU samples.

    Attributes:
        t_ns: ``(N,)`` int64 timestamps, nanoseconds.
        accel_mps2: ``(N, 3)`` float64 specific force in the body frame, m/s^2.
        gyro_radps: ``(N, 3)`` float64 angular rate in the body frame, rad/s.
        accel_bias_mps2: ``(N, 3)`` the accelerometer bias included in ``accel_mps2``.
        gyro_bias_radps: ``(N, 3)`` the gyroscope bias included in ``gyro_radps``.
    """

    t_ns: NDArray[np.int64]
    accel_mps2: FloatArray
    gyro_radps: FloatArray
    accel_bias_mps2: FloatArray
    gyro_bias_radps: FloatArray


def sample_times_ns(duration_s: float, rate_hz: float, start_ns: int = 0) -> NDArray[np.int64]:
    """Integer-nanosecond timestamps ``start_ns + round(k * 1e9 / rate_hz)`` covering
    ``[0, duration_s]``."""
    n = int(np.floor(duration_s * rate_hz + 1e-9)) + 1
    return start_ns + np.round(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)


def kinematics(
    traj: Trajectory, t_s: FloatArray, h_s: float = 1e-3
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """World velocity, world acceleration and body angular rate by 4th-order central differences.

    Returns:
        ``v_world (N, 3)`` m/s, ``a_world (N, 3)`` m/s^2, ``omega_body (N, 3)`` rad/s.
    """
    t = np.asarray(t_s, dtype=np.float64)
    hp = 1e-2  # position: accuracy ~ h^4 * p^(6) / 90, round-off ~ 1e-16 * |p| / h^2
    p = [traj.position_m(t + k * hp) for k in (-2, -1, 0, 1, 2)]
    v = (p[0] - 8 * p[1] + 8 * p[3] - p[4]) / (12 * hp)
    a = (-p[0] + 16 * p[1] - 30 * p[2] + 16 * p[3] - p[4]) / (12 * hp * hp)
    R = [traj.rotation(t + k * h_s) for k in (-2, -1, 0, 1, 2)]
    Rdot = (R[0] - 8 * R[1] + 8 * R[3] - R[4]) / (12 * h_s)
    W = np.einsum("nji,njk->nik", R[2], Rdot)  # R^T Rdot = [omega]x
    omega = 0.5 * np.stack(
        [W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1
    )
    return v, a, omega


def imu_samples(
    traj: Trajectory,
    t_ns: NDArray[np.int64],
    *,
    noise: ImuNoise | None = None,
    rng: np.random.Generator | None = None,
) -> ImuSamples:
    """IMU readings consistent with a trajectory.

    Args:
        traj: the body trajectory.
        t_ns: ``(N,)`` int64 sample times (uniformly spaced for noise), nanoseconds.
        noise: noise model, None for exact readings.
        rng: generator (required with noise).

    Returns:
        :class:`ImuSamples`.

    Raises:
        SimulationError: noise without a generator, or fewer than 2 samples with noise.
    """
    t = np.asarray(t_ns, dtype=np.int64).astype(np.float64) * 1e-9
    _, a_world, omega = kinematics(traj, t)
    R = traj.rotation(t)
    f_body = np.einsum("nji,nj->ni", R, a_world - GRAVITY_WORLD[None, :])
    zeros = np.zeros_like(f_body)
    if noise is None:
        return ImuSamples(
            t_ns=np.asarray(t_ns, dtype=np.int64),
            accel_mps2=f_body,
            gyro_radps=omega,
            accel_bias_mps2=zeros,
            gyro_bias_radps=zeros.copy(),
        )
    if rng is None:
        raise SimulationError("IMU noise is on but no random generator was given")
    if t.shape[0] < 2:
        raise SimulationError("IMU noise needs at least 2 samples")
    dt = float(np.median(np.diff(t)))
    n = t.shape[0]
    bg = np.cumsum(rng.normal(0, noise.gyro_bias_rw_radps_sqrts * np.sqrt(dt), (n, 3)), axis=0)
    ba = np.cumsum(rng.normal(0, noise.accel_bias_rw_mps2_sqrts * np.sqrt(dt), (n, 3)), axis=0)
    wg = rng.normal(0, noise.gyro_noise_density_radps_sqrthz / np.sqrt(dt), (n, 3))
    wa = rng.normal(0, noise.accel_noise_density_mps2_sqrthz / np.sqrt(dt), (n, 3))
    return ImuSamples(
        t_ns=np.asarray(t_ns, dtype=np.int64),
        accel_mps2=f_body + ba + wa,
        gyro_radps=omega + bg + wg,
        accel_bias_mps2=ba,
        gyro_bias_radps=bg,
    )
