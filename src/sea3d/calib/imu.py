"""Camera-IMU rotation and time offset from a recorded session: the gyro against vision.

Most users have no Kalibr calibration. A rigidly mounted IMU turns with the camera, so the
camera's angular velocity (from the visual odometry's orientations) and the gyro's agree up to
the mounting rotation, a clock offset and the gyro bias:

    omega_cam(t) = R_cam_imu (omega_imu(t + dt) - b_g),      t_imu = t_cam + dt

The offset is found first from the rotation-free speeds ``|omega|`` (cross-correlation over
``[-max_offset_s, max_offset_s]``, refined by a parabola), the rotation then in closed form
(orthogonal Procrustes, Kabsch/Umeyama, on mean-free rates), and all three are refined together
by robust least squares (scipy, soft-L1). The rotation needs motion about at least two axes;
the result's status says when it lacked them (the rotation's standard deviation, from the
Gauss-Newton covariance, above ``max_rotation_sigma_deg``).

The translation of ``T_left_imu`` cannot be seen from rotations; the rig's own (or zero) stays.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.errors import CalibrationError

__all__ = ["CameraImuCalibration", "CameraImuStatus", "angular_velocity", "estimate_camera_imu"]

log = logging.getLogger(__name__)


class CameraImuStatus(enum.StrEnum):
    """How the estimate went."""

    OK = "ok"
    """Rotation, offset and bias estimated."""
    WEAK_EXCITATION = "weak_excitation"
    """The motion turned about fewer than two axes: the rotation is not determined."""
    TOO_FEW = "too_few_samples"
    """Too few frames with a known orientation overlap the IMU."""
    NO_MATCH = "no_match"
    """Gyro and vision do not agree at any offset (wrong data, or an offset beyond the range)."""


@dataclass(frozen=True, kw_only=True)
class CameraImuCalibration:
    """The estimate.

    Attributes:
        status: :class:`CameraImuStatus`.
        R_cam_imu: 3x3 rotation mapping IMU vectors into the camera frame.
        time_offset_s: ``t_imu = t_cam + time_offset_s`` (the rig file's ``time_offset_s``).
        gyro_bias_radps: (3,) gyro bias, rad/s.
        residual_rms_radps: RMS of ``omega_cam - R (omega_imu - b)`` at the solution.
        correlation: normalised cross-correlation of the speeds at the chosen offset (0..1).
        samples: camera rate samples used.
        excitation_radps: (3,) singular values of the camera rates (motion about each axis).
        rotation_sigma_deg: largest standard deviation of the rotation (about any axis).
        time_offset_sigma_s: standard deviation of the offset.
    """

    status: CameraImuStatus
    R_cam_imu: F64
    time_offset_s: float
    gyro_bias_radps: F64
    residual_rms_radps: float
    correlation: float
    samples: int
    excitation_radps: F64
    rotation_sigma_deg: float = float("nan")
    time_offset_sigma_s: float = float("nan")
    duration_s: float = 0.0
    """Time span of the camera rates used, seconds."""
    axis_rate_rms_radps: F64 = field(default_factory=lambda: np.zeros(3))
    """(3,) RMS of the camera's mean-free angular rate about its own x, y, z axes."""
    advice: list[str] = field(default_factory=list)
    """What motion to record for an answer (empty when the status is OK)."""

    def as_dict(self) -> dict[str, object]:
        """Plain values for JSON."""
        return {
            "duration_s": self.duration_s,
            "axis_rate_rms_radps": np.asarray(self.axis_rate_rms_radps).tolist(),
            "advice": list(self.advice),
            "status": self.status.value,
            "R_cam_imu": self.R_cam_imu.tolist(),
            "time_offset_s": self.time_offset_s,
            "gyro_bias_radps": self.gyro_bias_radps.tolist(),
            "residual_rms_radps": self.residual_rms_radps,
            "correlation": self.correlation,
            "samples": self.samples,
            "excitation_radps": self.excitation_radps.tolist(),
            "rotation_sigma_deg": self.rotation_sigma_deg,
            "time_offset_sigma_s": self.time_offset_sigma_s,
        }


def _log_so3(R: F64) -> F64:
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.from_matrix(R).as_rotvec(), dtype=np.float64)


def angular_velocity(t_ns: NDArray[np.int64], R_world_cam: F64) -> tuple[F64, F64]:
    """Camera angular velocity in its own frame between consecutive orientations.

    Args:
        t_ns: (N,) increasing stamps.
        R_world_cam: (N, 3, 3) orientations.

    Returns:
        ``t_mid_s (N-1,)`` midpoints in seconds and ``omega_cam (N-1, 3)`` rad/s, from
        ``log(R_k^T R_{k+1}) / dt``.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    R = np.asarray(R_world_cam, dtype=np.float64)
    dt = np.diff(t) * 1e-9
    rel = np.einsum("nji,njk->nik", R[:-1], R[1:])
    w = _log_so3(rel) / dt[:, None]
    return np.asarray((t[:-1] + t[1:]) * 0.5e-9, dtype=np.float64), w


def _interp(t_query: F64, t: F64, values: F64) -> F64:
    return np.stack([np.interp(t_query, t, values[:, i]) for i in range(values.shape[1])], axis=1)


def _box_average(t_query: F64, half_s: F64, t: F64, values: F64) -> F64:
    """Mean of ``values`` over ``[t_query - half, t_query + half]`` (trapezoid on a cumulative
    integral), matching a finite-difference camera rate to the gyro."""
    dt = np.diff(t)
    mid = 0.5 * (values[1:] + values[:-1]) * dt[:, None]
    cum = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(mid, axis=0)])
    a = _interp(t_query - half_s, t, cum)
    b = _interp(t_query + half_s, t, cum)
    return (b - a) / (2 * half_s)[:, None]


# Advice on motion: an axis turning with under this fraction of the best axis's RMS rate is
# called idle; a hand-held rig tracks well at up to about 1 rad/s (blur beyond) and a clip
# needs at least this long for the offset's cross-correlation to find one peak
_IDLE_AXIS_FRACTION = 0.25
_GOOD_RATE_RADPS = (0.3, 1.0)
_MIN_CLIP_S = 10.0
_MAX_ADVISED_S = 120.0
_AXIS_NAMES = ("x (tilt up-down)", "y (pan left-right)", "z (roll about the view)")


def _advice(status: CameraImuStatus, *, duration_s: float, axis_rms: F64, directions: F64,
            rot_sigma_deg: float,
            max_sigma_deg: float, samples: int, correlation: float,
            max_offset_s: float) -> list[str]:
    """What motion would give an answer, from what this clip lacked.

    ``axis_rms`` (3,) are the RMS rates along the principal ``directions`` (3, 3 rows, camera
    frame) of the camera's mean-free angular rate, largest first."""
    if status is CameraImuStatus.OK:
        return []
    lo, hi = _GOOD_RATE_RADPS
    turn = (f"turn the rig by 15-30 deg back and forth about each axis in turn at "
            f"{lo:g}-{hi:g} rad/s ({np.degrees(lo):.0f}-{np.degrees(hi):.0f} deg/s), "
            "keeping the scene in view")
    if status is CameraImuStatus.TOO_FEW:
        return [f"only {samples} camera rates overlap the IMU with a tracked orientation: record "
                f"at least {_MIN_CLIP_S:g} s of tracked frames with the IMU running; {turn}"]
    if status is CameraImuStatus.NO_MATCH:
        return [f"the gyro and the camera's rotation do not agree at any offset within "
                f"+-{max_offset_s:g} s (best correlation {correlation:.2f}): check the IMU "
                "belongs to this rig, or widen max_offset_s; if the clip barely turns, "
                + turn]
    out = []
    # principal directions of the rate: a survey turns about one (its heading), whatever
    # the camera's tilt, so name the idle directions by their nearest camera axis
    top = float(axis_rms[0]) if axis_rms.size else 0.0
    idle = [k for k in range(3) if axis_rms[k] < _IDLE_AXIS_FRACTION * top]
    if top <= 0:
        idle = [0, 1, 2]
    if idle:
        parts = []
        for k in idle:
            v = directions[k]
            i = int(np.argmax(np.abs(v)))
            parts.append(f"{'' if abs(v[i]) > 0.9 else 'mostly '}{_AXIS_NAMES[i]} "
                         f"({axis_rms[k]:.3f} rad/s)")
        out.append(f"too little rotation about the camera's {' and '.join(parts)}, against "
                   f"{top:.3f} rad/s about its best-turned direction (RMS rates): the mounting "
                   "rotation about those directions is not determined")
    # the rotation's sigma falls as 1/sqrt(duration) and as 1/rate
    need = max(rot_sigma_deg / max(max_sigma_deg, 1e-9), 1.0)
    longer = min(max(duration_s * need**2, _MIN_CLIP_S), _MAX_ADVISED_S)
    if top < lo or idle:
        out.append(f"{turn}; about {max(_MIN_CLIP_S, min(longer, 30.0)):.0f} s of such motion "
                   f"should bring the rotation's sigma ({rot_sigma_deg:.2f} deg) under "
                   f"{max_sigma_deg:g} deg")
    else:
        out.append(f"the motion is good but the clip is short ({duration_s:.1f} s): record about "
                   f"{longer:.0f} s to bring the rotation's sigma ({rot_sigma_deg:.2f} deg) under "
                   f"{max_sigma_deg:g} deg")
    return out


def _usable_rates(
    t_cam: NDArray[np.int64],
    R: F64,
    keep: NDArray[np.bool_],
    t_imu_s: F64,
    max_offset_s: float,
) -> tuple[F64, F64, F64]:
    """Camera rates from trusted frame pairs whose gyro window stays inside the IMU's span.

    Returns ``(t_mid_s, w_cam_radps, half_s)``: (K,) mid times, (K, 3) rates, (K,) half-gaps.
    """
    t_mid, w_cam = angular_velocity(t_cam, R)
    pair_ok = keep[:-1] & keep[1:] & np.isfinite(w_cam).all(axis=1)
    half = np.diff(t_cam) * 0.5e-9
    t_mid, w_cam, half = t_mid[pair_ok], w_cam[pair_ok], half[pair_ok]
    # camera rates whose gyro window stays inside the IMU's span at every offset searched
    inside = (t_mid - half - max_offset_s >= t_imu_s[0]) & (
        t_mid + half + max_offset_s <= t_imu_s[-1]
    )
    return t_mid[inside], w_cam[inside], half[inside]


def _with_advice(
    res: CameraImuCalibration,
    t_mid: F64,
    w_cam: F64,
    *,
    max_offset_s: float,
    max_rotation_sigma_deg: float,
) -> CameraImuCalibration:
    """``res`` with the data's duration, per-axis rate RMS and the advice for its status."""
    dur = float(t_mid[-1] - t_mid[0]) if t_mid.size > 1 else 0.0
    rms = (np.sqrt(np.mean((w_cam - w_cam.mean(axis=0)) ** 2, axis=0)) if t_mid.size
           else np.zeros(3))
    pr, dirs = np.zeros(3), np.eye(3)
    if t_mid.size >= 3:
        wc = w_cam - w_cam.mean(axis=0)
        _, sv_, dirs = np.linalg.svd(wc, full_matrices=False)
        pr = sv_ / np.sqrt(wc.shape[0])
    adv = _advice(res.status, duration_s=dur, axis_rms=pr, directions=dirs,
                  rot_sigma_deg=res.rotation_sigma_deg, max_sigma_deg=max_rotation_sigma_deg,
                  samples=int(t_mid.size), correlation=res.correlation,
                  max_offset_s=max_offset_s)
    return dataclasses.replace(res, duration_s=dur, axis_rate_rms_radps=rms, advice=adv)


def _offset_from_speeds(
    speed_cam: F64, t_mid: F64, half: F64, t_imu_s: F64, g: F64, max_offset_s: float
) -> tuple[float, float]:
    """Step 1: the offset that best correlates camera and gyro speeds.

    Returns ``(offset_s, correlation)``: the peak, refined by a parabola through its
    neighbours, and the correlation at the sampled peak.
    """
    step = float(np.median(np.diff(t_imu_s)))
    offsets = np.arange(-max_offset_s, max_offset_s + step / 2, step / 2)
    corr = np.empty(offsets.size)
    a = speed_cam - speed_cam.mean()
    for i, dt in enumerate(offsets):
        s = np.linalg.norm(_box_average(t_mid + dt, half, t_imu_s, g), axis=1)
        b = s - s.mean()
        den = float(np.sqrt((a @ a) * (b @ b)))
        corr[i] = float(a @ b) / den if den > 0 else 0.0
    best = int(np.argmax(corr))
    dt0 = float(offsets[best])
    if 0 < best < offsets.size - 1:
        y0, y1, y2 = corr[best - 1], corr[best], corr[best + 1]
        den = y0 - 2 * y1 + y2
        if den < 0:
            dt0 += 0.5 * (y0 - y2) / den * (offsets[1] - offsets[0])
    return dt0, float(corr[best])


def _closed_form_rotation(
    w_cam: F64, w_imu: F64, R_cam_imu_guess: F64 | None
) -> tuple[F64, F64, F64]:
    """Step 2: rotation in closed form on mean-free rates (the bias drops out).

    Returns ``(R0, bias0_radps, excitation_radps)``.
    """
    A = w_imu - w_imu.mean(axis=0)
    Bc = w_cam - w_cam.mean(axis=0)
    sv = np.linalg.svd(Bc, compute_uv=False) / np.sqrt(Bc.shape[0])
    if R_cam_imu_guess is not None:
        R0 = np.asarray(R_cam_imu_guess, dtype=np.float64)
    else:
        U, _, Vt = np.linalg.svd(Bc.T @ A)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        R0 = U @ D @ Vt
    b0 = w_imu.mean(axis=0) - R0.T @ w_cam.mean(axis=0)
    return R0, b0, sv


def _refine_jointly(
    R0: F64,
    dt0: float,
    b0: F64,
    speed_cam: F64,
    t_mid: F64,
    w_cam: F64,
    half: F64,
    t_imu_s: F64,
    g: F64,
) -> tuple[F64, F64, float, F64]:
    """Step 3: joint robust refinement of rotation, offset and bias.

    Returns ``(R_cam_imu, x, residual_rms_radps, sigmas)``: ``x`` is (7,) rotation vector
    (about ``R0``), offset (s) and bias (rad/s); ``sigmas`` their (7,) standard deviations
    from the Gauss-Newton covariance at the solution.
    """
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    scale = max(float(np.median(speed_cam)), 1e-3)

    def residual(x: F64) -> F64:
        Rx = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        wi = _box_average(t_mid + x[3], half, t_imu_s, g)
        return ((wi - x[4:7]) @ Rx.T - w_cam).ravel()

    x0 = np.r_[np.zeros(3), dt0, b0]
    sol = least_squares(residual, x0, loss="soft_l1", f_scale=0.1 * scale, x_scale="jac")
    x = sol.x
    R_final = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
    res = residual(x).reshape(-1, 3)
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    # standard deviations from the Gauss-Newton covariance at the solution
    J = sol.jac
    dof = max(J.shape[0] - J.shape[1], 1)
    s2 = float(np.sum(sol.fun**2)) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        sig = np.full(7, np.inf)
    return np.asarray(R_final), x, rms, sig


def estimate_camera_imu(
    t_cam_ns: NDArray[np.int64],
    R_world_cam: F64,
    imu_t_ns: NDArray[np.int64],
    gyro_radps: F64,
    *,
    max_offset_s: float = 0.5,
    R_cam_imu_guess: F64 | None = None,
    valid: NDArray[np.bool_] | None = None,
    max_rotation_sigma_deg: float = 0.5,
) -> CameraImuCalibration:
    """Estimate ``R_cam_imu``, the time offset and the gyro bias (see the module docstring).

    Args:
        t_cam_ns: (N,) camera stamps (camera clock).
        R_world_cam: (N, 3, 3) camera orientations (any world), e.g. from the visual odometry.
        imu_t_ns: (M,) IMU stamps (IMU clock).
        gyro_radps: (M, 3) gyro readings.
        max_offset_s: the offset searched, ``[-max, +max]``.
        R_cam_imu_guess: a starting rotation (skips the closed form when given).
        valid: (N,) frames whose orientation is trustworthy (e.g. odometry status tracking).
        max_rotation_sigma_deg: a rotation less certain than this (about its worst axis) is
            reported as ``WEAK_EXCITATION``.

    Returns:
        :class:`CameraImuCalibration` (a status, never an exception, for data that will not do).

    Raises:
        CalibrationError: arrays of the wrong shape.
    """
    t_cam = np.asarray(t_cam_ns, dtype=np.int64)
    R = np.asarray(R_world_cam, dtype=np.float64)
    ti = np.asarray(imu_t_ns, dtype=np.int64)
    g = np.asarray(gyro_radps, dtype=np.float64)
    if R.shape != (t_cam.size, 3, 3) or g.shape != (ti.size, 3):
        raise CalibrationError(
            f"expected R_world_cam (N, 3, 3) for N stamps and gyro (M, 3) for M stamps, got "
            f"{R.shape} for {t_cam.size} and {g.shape} for {ti.size}"
        )
    eye = np.eye(3)
    empty = CameraImuCalibration(
        status=CameraImuStatus.TOO_FEW,
        R_cam_imu=eye,
        time_offset_s=0.0,
        gyro_bias_radps=np.zeros(3),
        residual_rms_radps=float("nan"),
        correlation=0.0,
        samples=0,
        excitation_radps=np.zeros(3),
    )
    if valid is not None:
        keep = np.asarray(valid, dtype=bool)
    else:
        keep = np.ones(t_cam.size, dtype=bool)
    t_imu_s = np.asarray(ti * 1e-9, dtype=np.float64)
    t_mid, w_cam, half = _usable_rates(t_cam, R, keep, t_imu_s, max_offset_s)

    def finish(res: CameraImuCalibration) -> CameraImuCalibration:
        return _with_advice(res, t_mid, w_cam, max_offset_s=max_offset_s,
                            max_rotation_sigma_deg=max_rotation_sigma_deg)

    if t_mid.size < 20:
        return finish(empty)
    speed_cam = np.linalg.norm(w_cam, axis=1)
    dt0, correlation = _offset_from_speeds(speed_cam, t_mid, half, t_imu_s, g, max_offset_s)
    if correlation < 0.5:
        return finish(CameraImuCalibration(
            status=CameraImuStatus.NO_MATCH,
            R_cam_imu=eye,
            time_offset_s=dt0,
            gyro_bias_radps=np.zeros(3),
            residual_rms_radps=float("nan"),
            correlation=correlation,
            samples=int(t_mid.size),
            excitation_radps=np.zeros(3),
        ))
    w_imu = _box_average(t_mid + dt0, half, t_imu_s, g)
    R0, b0, sv = _closed_form_rotation(w_cam, w_imu, R_cam_imu_guess)
    R_final, x, rms, sig = _refine_jointly(R0, dt0, b0, speed_cam, t_mid, w_cam, half, t_imu_s, g)
    rot_sigma_deg = float(np.degrees(np.max(sig[:3])))
    weak = bool(rot_sigma_deg > max_rotation_sigma_deg)
    status = CameraImuStatus.WEAK_EXCITATION if weak else CameraImuStatus.OK
    return finish(CameraImuCalibration(
        status=status,
        R_cam_imu=R_final,
        time_offset_s=float(x[3]),
        gyro_bias_radps=np.asarray(x[4:7]),
        residual_rms_radps=rms,
        correlation=correlation,
        samples=int(t_mid.size),
        excitation_radps=sv,
        rotation_sigma_deg=rot_sigma_deg,
        time_offset_sigma_s=float(sig[3]),
    ))
