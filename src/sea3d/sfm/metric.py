"""Making a monocular SfM model metric from the IMU, and applying a scale to a result.

Pure functions that ``sea3d sfm`` calls (the CLI only loads, calls and saves): where the IMU
sits on the camera (:func:`imu_extrinsics`), the IMU's scale estimate with the decision whether
to apply it (:func:`imu_scale_for`), and the scaled trajectory, points and COLMAP model
(:func:`scaled_outputs`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from sea3d._typing import F64
from sea3d.errors import SfmError

if TYPE_CHECKING:
    from sea3d.geometry.rig import StereoRig

__all__ = ["ImuScaleDecision", "imu_extrinsics", "imu_scale_for", "scaled_outputs"]


def imu_extrinsics(rig: StereoRig | None, file_T: F64 | None = None) -> F64:
    """``T_left_imu`` (the IMU in the left camera frame): ``file_T`` when given, else the
    rig's IMU block.

    Raises:
        SfmError: neither is available.
    """
    if file_T is not None:
        return np.asarray(file_T, dtype=np.float64)
    imu = rig.imu if rig is not None else None
    if imu is None:
        raise SfmError("the IMU scale needs the IMU's place on the camera: the rig has no IMU "
                       "block and no extrinsics file was given (T_left_imu or T_body_left)")
    return np.asarray(imu.T_left_imu, dtype=np.float64)


@dataclass(frozen=True, kw_only=True)
class ImuScaleDecision:
    """The IMU's scale estimate (None when skipped), the factor to apply (1.0 unless the
    estimate is trustworthy) and the figures for ``summary.json``'s ``imu_scale``."""

    estimate: Any
    scale: float
    summary: dict[str, Any]


def imu_scale_for(result: Any, imu: Any, T_cam_body: F64) -> ImuScaleDecision:
    """Estimate the metric scale of a monocular model from the IMU and decide whether to use it.

    Args:
        result: a :class:`~sea3d.sfm.SfmResult` (its ``t_s``, ``T_world_left``, ``metric``).
        imu: IMU samples (``t_ns``, ``accel_mps2``, ``gyro_radps``).
        T_cam_body: (4, 4) the IMU in the left camera frame.

    Returns:
        :class:`ImuScaleDecision`: scale 1.0 for a model that is metric already or an estimate
        whose status is not ``ok``.
    """
    from sea3d.sfm.imu_scale import estimate_imu_scale

    if result.metric:
        return ImuScaleDecision(estimate=None, scale=1.0, summary={
            "status": "skipped", "message": "the model is metric already"})
    # with the gyroscope: measured -0.9 % against -5.9 % (lawnmower) and -0.17 % against
    # +1.0 % (hand-held) without it, benchmarks/bench_sfm.py --only imu
    est = estimate_imu_scale(result.t_s, result.T_world_left,
                             imu.t_ns.astype(np.float64) * 1e-9, imu.accel_mps2, T_cam_body,
                             gyro_radps=imu.gyro_radps)
    ok = est.status == "ok"
    return ImuScaleDecision(estimate=est, scale=float(est.scale) if ok else 1.0, summary={
        "status": est.status, "message": est.message, "scale": est.scale,
        "scale_std": est.scale_std, "relative_std": est.relative_std,
        "gravity_model_mps2": list(est.gravity_model_mps2),
        "accel_bias_mps2": list(est.accel_bias_mps2), "windows": est.windows,
        "chi2_per_dof": est.chi2_per_dof, "applied": ok,
    })


def scaled_outputs(result: Any, scale: float) -> tuple[F64, F64]:
    """Scale a result's model by ``scale``: its COLMAP reconstruction in place (a Sim(3) with
    no rotation), and the returned ``(T_world_left (N, 4, 4), points_world (M, 3))``."""
    T = np.array(result.T_world_left, dtype=np.float64, copy=True)
    T[:, :3, 3] *= scale
    if scale != 1.0 and result.reconstruction is not None:
        import pycolmap

        result.reconstruction.transform(
            pycolmap.Sim3d(scale, pycolmap.Rotation3d(np.eye(3)), np.zeros(3)))
    return T, np.asarray(result.points_world, dtype=np.float64) * scale
