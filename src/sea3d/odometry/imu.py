"""IMU handling for the odometry: sample buffering on the camera clock, gravity alignment, and
gtsam preintegration parameters from the rig's :class:`~sea3d.geometry.rig.ImuSpec`.

Frames: ``body`` is the IMU frame; ``world`` has gravity along -z (``g = (0, 0, -|g|)``). The IMU
measures specific force ``f = R_world_body^T (a_world - g)``, so at rest it reads
``R_world_body^T (0, 0, +|g|)``.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sea3d._typing import F64
from sea3d.geometry.rig import ImuSpec
from sea3d.odometry.types import ImuChunk

__all__ = ["ImuBuffer", "gravity_aligned_rotation", "preintegration_params"]

log = logging.getLogger(__name__)


def gravity_aligned_rotation(accel_mean_mps2: F64) -> F64:
    """``R_world_body`` (3x3) that turns a resting accelerometer reading to +z, with the least
    rotation (so heading is whatever the body had: the world's yaw is free)."""
    f = np.asarray(accel_mean_mps2, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(f))
    if not n > 1e-6:
        return np.eye(3)
    a = f / n
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, z)
    c = float(a @ z)
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.asarray(np.eye(3) + vx + vx @ vx * ((1 - c) / (s * s)), dtype=np.float64)


# Floors on the bias random walks: a navigation-grade figure (the simulated MTi-300's bias moves
# by 1.5e-6 m/s^2 per sqrt(s)) makes the bias blocks of the window's information matrix ~1e10
# times stiffer than the rest and iSAM2's Cholesky reports an indeterminate system.
_MIN_ACCEL_RW = 1e-4
_MIN_GYRO_RW = 1e-5


def preintegration_params(imu: ImuSpec, noise_scale: float = 1.0) -> Any:
    """gtsam ``PreintegrationCombinedParams`` (continuous-time densities, gravity along -z)."""
    import gtsam

    p = gtsam.PreintegrationCombinedParams.MakeSharedU(imu.gravity_mps2)
    s2 = noise_scale * noise_scale
    p.setAccelerometerCovariance(np.eye(3) * s2 * imu.accel_noise_density_mps2_sqrthz**2)
    p.setGyroscopeCovariance(np.eye(3) * s2 * imu.gyro_noise_density_radps_sqrthz**2)
    p.setIntegrationCovariance(np.eye(3) * 1e-8)
    ba = max(noise_scale * imu.accel_random_walk_mps2_sqrts, _MIN_ACCEL_RW)
    bg = max(noise_scale * imu.gyro_random_walk_radps_sqrts, _MIN_GYRO_RW)
    p.setBiasAccCovariance(np.eye(3) * ba**2)
    p.setBiasOmegaCovariance(np.eye(3) * bg**2)
    return p


@dataclass
class ImuBuffer:
    """IMU samples on the camera clock, waiting to be integrated.

    Samples arrive in :class:`ImuChunk` s; their stamps are shifted to camera time
    (``t_cam = t_imu - time_offset_s``) and kept in order. Samples at or before the last
    integrated time (duplicates, out-of-order repeats) are dropped and counted.

    Attributes:
        offset_ns: ``time_offset_s`` of the rig in nanoseconds.
        t_ns, accel, gyro: pending samples (camera clock).
        last_t_ns: time up to which samples were consumed, or None.
        last_accel, last_gyro: the last consumed sample (held over the rest of an interval).
        dropped: samples dropped as duplicates or out of order.
    """

    offset_ns: int = 0
    t_ns: deque[int] = field(default_factory=deque)
    accel: deque[F64] = field(default_factory=deque)
    gyro: deque[F64] = field(default_factory=deque)
    last_t_ns: int | None = None
    last_accel: F64 | None = None
    last_gyro: F64 | None = None
    dropped: int = 0

    def push(self, chunk: ImuChunk) -> None:
        """Add a chunk's samples (shifted to camera time)."""
        t = np.asarray(chunk.t_ns, dtype=np.int64) - self.offset_ns
        acc = np.asarray(chunk.accel_mps2, dtype=np.float64).reshape(-1, 3)
        gyr = np.asarray(chunk.gyro_radps, dtype=np.float64).reshape(-1, 3)
        ok = np.asarray(np.isfinite(acc).all(axis=1) & np.isfinite(gyr).all(axis=1), dtype=bool)
        newest = self.t_ns[-1] if self.t_ns else self.last_t_ns
        for i in range(t.shape[0]):
            ti = int(t[i])
            if not ok[i] or (newest is not None and ti <= newest):
                self.dropped += 1
                continue
            self.t_ns.append(ti)
            self.accel.append(acc[i])
            self.gyro.append(gyr[i])
            newest = ti

    def mean_accel(self, until_ns: int, window_ns: int) -> F64 | None:
        """Mean pending accelerometer reading over ``(until - window, until]``, or None."""
        sel = [
            a
            for t, a in zip(self.t_ns, self.accel, strict=True)
            if until_ns - window_ns < t <= until_ns
        ]
        if not sel and self.last_accel is not None:
            return self.last_accel
        return np.mean(sel, axis=0) if sel else None

    def start(self, t_ns: int) -> None:
        """Begin integrating at ``t_ns``: older samples are dropped, the last of them is held."""
        while self.t_ns and self.t_ns[0] <= t_ns:
            self.last_accel, self.last_gyro = self.accel.popleft(), self.gyro.popleft()
            self.t_ns.popleft()
        if self.last_accel is None and self.accel:
            self.last_accel, self.last_gyro = self.accel[0], self.gyro[0]
        self.last_t_ns = t_ns

    def consume(self, until_ns: int) -> tuple[list[tuple[F64, F64, float]], float]:
        """Samples to integrate from the last consumed time to ``until_ns``.

        Each sample is held from its stamp to the next (zero-order hold); the last one is held to
        ``until_ns``. Returns ``[(accel, gyro, dt_s), ...]`` and the longest gap without a
        sample (seconds) in that interval, so the caller can refuse to bridge long holes.
        """
        out: list[tuple[F64, F64, float]] = []
        if self.last_t_ns is None:
            self.start(until_ns)
            return out, 0.0
        t_prev = self.last_t_ns
        max_gap = 0.0
        while self.t_ns and self.t_ns[0] <= until_ns:
            t = self.t_ns.popleft()
            a, g = self.accel.popleft(), self.gyro.popleft()
            dt = (t - t_prev) * 1e-9
            if dt > 0 and self.last_accel is not None and self.last_gyro is not None:
                out.append((self.last_accel, self.last_gyro, dt))
            max_gap = max(max_gap, dt)
            self.last_accel, self.last_gyro = a, g
            t_prev = t
        dt = (until_ns - t_prev) * 1e-9
        if dt > 0 and self.last_accel is not None and self.last_gyro is not None:
            out.append((self.last_accel, self.last_gyro, dt))
        if self.last_accel is None:
            max_gap = max(max_gap, (until_ns - self.last_t_ns) * 1e-9)
        max_gap = max(max_gap, dt)
        self.last_t_ns = until_ns
        return out, max_gap

    def trim(self, before_ns: int) -> None:
        """Drop pending samples at or before ``before_ns`` (bounds memory while not integrating)."""
        while self.t_ns and self.t_ns[0] <= before_ns:
            self.t_ns.popleft()
            self.accel.popleft()
            self.gyro.popleft()

    def pending_span_ns(self) -> tuple[int, int] | None:
        """First and last pending stamp (camera clock), or None when nothing is pending."""
        if not self.t_ns:
            return None
        return self.t_ns[0], self.t_ns[-1]

    def clear(self) -> None:
        """Forget every pending sample."""
        self.t_ns.clear()
        self.accel.clear()
        self.gyro.clear()
