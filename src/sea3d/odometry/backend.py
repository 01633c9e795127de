"""The odometry's back end: tightly coupled stereo(-inertial) fixed-lag smoothing in gtsam.

Variables per keyframe ``k``: the pose ``x_k`` (``T_world_body`` with an IMU, ``T_world_rect``
without), and with an IMU the velocity ``v_k`` (world, m/s) and the IMU bias ``b_k``; per
landmark ``l_j`` its world position. Factors:

- ``GenericStereoFactor3D`` for every stereo observation (left u, right u, v of the virtual
  rectified pair: see :mod:`sea3d.odometry.stereo_geometry` for why that stays exact through
  ports), with a Huber kernel, the camera placed on the body by ``body_P_sensor``;
- ``CombinedImuFactor`` between consecutive keyframes: on-manifold preintegration (Forster et
  al., RSS 2015) with the bias random walk inside the factor;
- priors on the first keyframe (attitude from gravity, zero-mean velocity and biases).

gtsam's ``IncrementalFixedLagSmoother`` (iSAM2 underneath) keeps the last ``lag`` seconds and
marginalises older variables into a prior, so the cost of a keyframe stays bounded over hours.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from sea3d._typing import F64
from sea3d.errors import SmootherFailure  # defined with every error class; re-exported
from sea3d.odometry.stereo_geometry import RectifiedStereo

__all__ = ["KeyframeState", "SmootherBackend", "SmootherFailure"]

log = logging.getLogger(__name__)

LANDMARK_PRIOR_SIGMA_M = 50.0
"""Standard deviation of the weak prior on each new landmark (see ``add_keyframe``), metres."""


def _X(k: int) -> int:
    import gtsam

    return int(gtsam.symbol("x", k))


def _V(k: int) -> int:
    import gtsam

    return int(gtsam.symbol("v", k))


def _B(k: int) -> int:
    import gtsam

    return int(gtsam.symbol("b", k))


def _L(j: int) -> int:
    import gtsam

    return int(gtsam.symbol("l", j))


@dataclass(frozen=True, kw_only=True, eq=False)
class KeyframeState:
    """The smoother's estimate of one keyframe.

    Attributes:
        T_world_body: 4x4 pose of the state frame (``body`` with IMU, ``rect_left`` without).
        velocity_mps: (3,) world velocity (zeros without IMU).
        accel_bias_mps2, gyro_bias_radps: (3,) IMU biases (zeros without IMU).
    """

    T_world_body: F64
    velocity_mps: F64
    accel_bias_mps2: F64
    gyro_bias_radps: F64


class SmootherBackend:
    """One segment's fixed-lag smoother.

    Args:
        geometry: the rectified stereo pair (its virtual intrinsics and baseline).
        T_body_rect: 4x4 camera (``rect_left``) in the state frame; identity without IMU.
        imu_params: gtsam ``PreintegrationCombinedParams`` or None for visual-only.
        lag_s: smoother window, seconds.
        pixel_sigma_px: stereo measurement standard deviation.
        huber_k: Huber threshold, standard deviations.
    """

    def __init__(
        self,
        geometry: RectifiedStereo,
        *,
        T_body_rect: F64,
        imu_params: object | None,
        lag_s: float,
        pixel_sigma_px: float,
        huber_k: float,
    ) -> None:
        import gtsam

        self._gtsam = gtsam
        self.geometry = geometry
        self.imu_params = imu_params
        self.K = gtsam.Cal3_S2Stereo(
            geometry.fx, geometry.fy, 0.0, geometry.cx, geometry.cy, geometry.baseline_m
        )
        self.body_P_sensor = gtsam.Pose3(np.asarray(T_body_rect, dtype=np.float64))
        base = gtsam.noiseModel.Isotropic.Sigma(3, pixel_sigma_px)
        self.stereo_noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(huber_k), base
        )
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        params.findUnusedFactorSlots = True
        self.smoother = gtsam.IncrementalFixedLagSmoother(lag_s, params)
        self.lag_s = lag_s
        self.failed = False
        self.keyframes: list[int] = []
        self.times_s: dict[int, float] = {}
        self.estimate = gtsam.Values()
        self.landmarks_in_window: set[int] = set()
        self._first_seen_s: dict[int, float] = {}

    @property
    def inertial(self) -> bool:
        """True when the smoother has IMU factors."""
        return self.imu_params is not None

    def new_preintegration(self, accel_bias: F64, gyro_bias: F64) -> Any:
        """A fresh ``PreintegratedCombinedMeasurements`` with the given bias (IMU only)."""
        gtsam = self._gtsam
        bias = gtsam.imuBias.ConstantBias(np.asarray(accel_bias), np.asarray(gyro_bias))
        return gtsam.PreintegratedCombinedMeasurements(self.imu_params, bias)

    # ------------------------------------------------------------------ building the window
    def _stereo_factors(self, graph: object, k: int, observations: list[tuple[int, F64]]) -> None:
        gtsam = self._gtsam
        for j, meas in observations:
            sp = gtsam.StereoPoint2(float(meas[0]), float(meas[1]), float(meas[2]))
            graph.add(  # type: ignore[attr-defined]
                gtsam.GenericStereoFactor3D(
                    sp, self.stereo_noise, _X(k), _L(j), self.K, self.body_P_sensor
                )
            )

    def add_keyframe(
        self,
        k: int,
        t_s: float,
        T_world_body: F64,
        observations: list[tuple[int, F64]],
        new_landmarks: dict[int, F64],
        *,
        velocity_mps: F64 | None = None,
        bias: tuple[F64, F64] | None = None,
        preintegrated: object | None = None,
        prior_sigmas: dict[str, float] | None = None,
        imu_gap_bias_sigma: tuple[float, float] | None = None,
        extra_iterations: int = 1,
    ) -> None:
        """Add keyframe ``k`` and its observations, then update the window.

        Args:
            k: keyframe id (increasing).
            t_s: its time, seconds.
            T_world_body: 4x4 initial guess of its state pose.
            observations: ``[(landmark id, (u_left, u_right, v)), ...]`` of this keyframe.
            new_landmarks: initial world positions of landmarks first seen here.
            velocity_mps, bias: initial guesses (IMU only).
            preintegrated: IMU measurements since the previous keyframe (IMU only; None for
                the first keyframe, or when the IMU link is cut: then ``imu_gap_bias_sigma``).
            prior_sigmas: for the first keyframe of the segment: ``rotation_rad``,
                ``translation_m`` and with IMU ``velocity_mps``, ``accel_bias_mps2``,
                ``gyro_bias_radps``.
            imu_gap_bias_sigma: ``(accel, gyro)`` standard deviations of the bias change over an
                interval without IMU data (then the velocity gets a loose prior).
            extra_iterations: extra iSAM2 passes after the update (relinearisation).

        Raises:
            SmootherFailure: when gtsam cannot solve the window.
        """
        gtsam = self._gtsam
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps: dict[int, float] = {}
        pose = gtsam.Pose3(np.asarray(T_world_body, dtype=np.float64))
        values.insert(_X(k), pose)
        stamps[_X(k)] = t_s
        if self.inertial:
            v = np.zeros(3) if velocity_mps is None else np.asarray(velocity_mps, np.float64)
            ba, bg = (np.zeros(3), np.zeros(3)) if bias is None else bias
            values.insert(_V(k), v)
            values.insert(_B(k), gtsam.imuBias.ConstantBias(np.asarray(ba), np.asarray(bg)))
            stamps[_V(k)] = t_s
            stamps[_B(k)] = t_s
        if prior_sigmas is not None:
            rot, trans = prior_sigmas["rotation_rad"], prior_sigmas["translation_m"]
            graph.add(
                gtsam.PriorFactorPose3(
                    _X(k), pose, gtsam.noiseModel.Diagonal.Sigmas(np.r_[[rot] * 3, [trans] * 3])
                )
            )
            if self.inertial:
                graph.add(
                    gtsam.PriorFactorVector(
                        _V(k),
                        values.atVector(_V(k)),
                        gtsam.noiseModel.Isotropic.Sigma(3, prior_sigmas["velocity_mps"]),
                    )
                )
                sig = np.r_[
                    [prior_sigmas["accel_bias_mps2"]] * 3, [prior_sigmas["gyro_bias_radps"]] * 3
                ]
                graph.add(
                    gtsam.PriorFactorConstantBias(
                        _B(k), values.atConstantBias(_B(k)), gtsam.noiseModel.Diagonal.Sigmas(sig)
                    )
                )
        elif self.keyframes and self.inertial:
            prev = self.keyframes[-1]
            if preintegrated is not None:
                graph.add(
                    gtsam.CombinedImuFactor(
                        _X(prev), _V(prev), _X(k), _V(k), _B(prev), _B(k), preintegrated
                    )
                )
            else:
                sa, sg = imu_gap_bias_sigma or (0.01, 0.001)
                graph.add(
                    gtsam.BetweenFactorConstantBias(
                        _B(prev),
                        _B(k),
                        gtsam.imuBias.ConstantBias(),
                        gtsam.noiseModel.Diagonal.Sigmas(np.r_[[sa] * 3, [sg] * 3]),
                    )
                )
                graph.add(
                    gtsam.PriorFactorVector(
                        _V(k), values.atVector(_V(k)), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
                    )
                )
        # A stereo factor whose point falls behind the camera gives gtsam zero Jacobians (no
        # cheirality exception), which left a landmark seen only that way undetermined and the
        # whole update failing ("indeterminate linear system near l..."). A weak prior (metres,
        # against sub-millimetre to centimetre stereo information) keeps every new landmark
        # determined without pulling it measurably.
        lm_prior = gtsam.noiseModel.Isotropic.Sigma(3, LANDMARK_PRIOR_SIGMA_M)
        for j, X in new_landmarks.items():
            Xj = np.asarray(X, dtype=np.float64)
            values.insert(_L(j), Xj)
            graph.add(gtsam.PriorFactorPoint3(_L(j), Xj, lm_prior))
        # a landmark keeps the stamp of the keyframe that first saw it, so it leaves the window
        # with that keyframe (see ``expiring``)
        for j in new_landmarks:
            stamps[_L(j)] = t_s
            self._first_seen_s[j] = t_s
        self._stereo_factors(graph, k, observations)
        if self.failed:
            raise SmootherFailure("the smoother failed before; its segment must end")
        try:
            self.smoother.update(graph, values, stamps)  # type: ignore[arg-type]
            for _ in range(extra_iterations):
                self.smoother.update()
            self.estimate = self.smoother.calculateEstimate()
        except (RuntimeError, IndexError, ValueError) as err:
            # gtsam's IndeterminantLinearSystem, Cheirality, ...; a failed update leaves the
            # smoother's Bayes tree unusable (later updates raise IndexError), so the segment
            # that owns it must end
            self.failed = True
            raise SmootherFailure(str(err)) from err
        self.keyframes.append(k)
        self.times_s[k] = t_s
        oldest = t_s - self.lag_s
        self.keyframes = [
            q
            for q in self.keyframes
            if self.times_s[q] >= oldest - 1e-9 and self.estimate.exists(_X(q))
        ]
        for q in list(self.times_s):
            if q not in self.keyframes and q != k:
                del self.times_s[q]
        if len(self._first_seen_s) > 4 * max(self.estimate.size(), 1):
            self._first_seen_s = {
                j: s for j, s in self._first_seen_s.items() if self.estimate.exists(_L(j))
            }

    # ------------------------------------------------------------------ reading the window
    def expiring(self, j: int, t_s: float) -> bool:
        """True when landmark ``j`` leaves the window at a keyframe at ``t_s`` (the keyframe
        that first saw it falls out of the lag): the front end then observes a fresh landmark
        in its place."""
        first = self._first_seen_s.get(j)
        return first is None or first <= t_s - self.lag_s + 1e-6

    def has_landmark(self, j: int) -> bool:
        """True when landmark ``j`` is still a variable of the window."""
        return bool(self.estimate.exists(_L(j)))

    def landmark(self, j: int) -> F64:
        """World position of landmark ``j``, metres."""
        return np.asarray(self.estimate.atPoint3(_L(j)), dtype=np.float64)

    def state(self, k: int) -> KeyframeState:
        """The current estimate of keyframe ``k`` (must be in the window)."""
        T = np.asarray(self.estimate.atPose3(_X(k)).matrix(), dtype=np.float64)
        if self.inertial:
            v = np.asarray(self.estimate.atVector(_V(k)), dtype=np.float64)
            b = self.estimate.atConstantBias(_B(k))
            ba = np.asarray(b.accelerometer(), dtype=np.float64)
            bg = np.asarray(b.gyroscope(), dtype=np.float64)
        else:
            v = ba = bg = np.zeros(3)
        return KeyframeState(T_world_body=T, velocity_mps=v, accel_bias_mps2=ba, gyro_bias_radps=bg)

    def window_poses(self) -> dict[int, F64]:
        """``T_world_body`` of every keyframe still in the window."""
        return {
            k: np.asarray(self.estimate.atPose3(_X(k)).matrix(), dtype=np.float64)
            for k in self.keyframes
        }
