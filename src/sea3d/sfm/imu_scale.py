"""Metric scale of a monocular trajectory from the IMU's accelerations (the paper's closing
suggestion), with its uncertainty.

A monocular SfM or odometry trajectory ``T_model_cam(t)`` is right up to a scale ``s`` (metres
per model unit) and a rotation of its world. Its rotations are metric already, and the IMU
measures the body's specific force ``f = R_body_model (a_model - g_model) + b + noise``. With
``T_cam_body`` (where the IMU sits on the camera) the body position in the model world is
``p_body(t) = s c(t) + R_model_cam(t) t_cam_body``, ``c`` the camera centre, and double
integration of ``R_model_body (f - b)`` from the start ``t_a`` of a window gives, at every
frame ``k`` of the window (``tau_k = t_k - t_a``)::

    s c(t_k) + R_model_cam(t_k) t_cam_body
        = p_a + v_a tau_k + g tau_k^2 / 2 + Phi_k - Psi_k b

    Phi_k = int_{t_a}^{t_k} (t_k - tau) R_model_body(tau) f(tau) dtau
    Psi_k = int_{t_a}^{t_k} (t_k - tau) R_model_body(tau) dtau

which is linear in the scale ``s``, gravity ``g`` (model frame), the accelerometer bias ``b``
(shared by all windows) and each window's start position ``p_a`` and velocity ``v_a``. It is
solved by generalised least squares (with a zero-mean prior on the bias) with the covariance
of doubly integrated white accelerometer noise of density ``q`` (per axis, for
``tau_k, tau_l`` and ``m = min``)::

    Cov(Phi_k, Phi_l) = q^2 (tau_k tau_l m - (tau_k + tau_l) m^2 / 2 + m^3 / 3)

plus the trajectory's own position noise, then refined with ``|g|`` fixed to local gravity
(Gauss-Newton on the direction of ``g``). The standard deviation of ``s`` comes from the
solution's covariance, scaled up by the reduced chi-square when the residuals are larger than
the noise model says (rotation errors of the trajectory, unmodelled bias drift).

Rotations between frames are interpolated (slerp) from the trajectory's, or, when the
gyroscope's rates are given, the frames' rotations are first smoothed with the gyroscope
(:func:`smooth_rotations`) and followed by it in between. Scale is observable
only when the camera accelerates: a window moving at constant velocity constrains nothing, and
the result then says so (``status="weak"``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from sea3d._typing import F64
from sea3d.errors import SfmError

__all__ = ["ImuScaleResult", "estimate_imu_scale", "smooth_rotations"]

log = logging.getLogger(__name__)
# Movella MTi-300 noise densities (as in sea3d.sim.motion): accelerometer 60 ug/sqrt(Hz),
# gyroscope 0.01 deg/s/sqrt(Hz).
DEFAULT_ACCEL_NOISE_MPS2_SQRTHZ = 60.0 * 9.81e-6
DEFAULT_GYRO_NOISE_RADPS_SQRTHZ = 0.01 * np.pi / 180.0
# its in-run gyroscope bias stability, 10 deg/h: the prior on the bias the smoother estimates
DEFAULT_GYRO_BIAS_STD_RADPS = 10.0 * np.pi / 180.0 / 3600.0


@dataclass(frozen=True, kw_only=True)
class ImuScaleResult:
    """The metric scale of a monocular trajectory.

    Attributes:
        status: ``ok``, ``weak`` (relative uncertainty above ``max_relative_std``: too little
            acceleration) or ``failed`` (no IMU over the trajectory, too few frames).
        message: one line for the user.
        scale: metres per model unit (multiply the trajectory and points by it); NaN if failed.
        scale_std: one standard deviation of ``scale``.
        gravity_model_mps2: ``(3,)`` gravity in the model's world frame, m/s^2.
        accel_bias_mps2: ``(3,)`` accelerometer bias, body frame, m/s^2.
        windows: number of integration windows used.
        frames: frames used.
        chi2_per_dof: reduced chi-square of the fit (about 1 when the noise model holds).
    """

    status: str
    message: str
    scale: float
    scale_std: float
    gravity_model_mps2: tuple[float, float, float]
    accel_bias_mps2: tuple[float, float, float]
    windows: int
    frames: int
    chi2_per_dof: float

    @property
    def relative_std(self) -> float:
        """``scale_std / scale``."""
        return float(self.scale_std / self.scale) if self.scale > 0 else float("inf")


def _failed(message: str, frames: int = 0) -> ImuScaleResult:
    nan = float("nan")
    return ImuScaleResult(status="failed", message=message, scale=nan, scale_std=nan,
                          gravity_model_mps2=(nan, nan, nan), accel_bias_mps2=(nan, nan, nan),
                          windows=0, frames=frames, chi2_per_dof=nan)


def _cumulative_trapezoid(y: F64, t: F64) -> F64:
    """``int_{t_0}^{t_i} y`` along axis 0 (``y`` of shape ``(N, ...)``)."""
    dt = np.diff(t).reshape((-1,) + (1,) * (y.ndim - 1))
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1]) * dt, axis=0)
    return out


def _double_integrals(t: F64, a: F64, t_frames: F64) -> F64:
    """``int_{t_0}^{t_k} (t_k - tau) a(tau) dtau`` at ``t_frames`` (trapezoid, then linear
    between samples), for ``a`` of shape ``(N, ...)``."""
    vel = _cumulative_trapezoid(a, t)
    pos = _cumulative_trapezoid(vel, t)
    flat = pos.reshape(len(t), -1)
    out = np.stack([np.interp(t_frames, t, flat[:, j]) for j in range(flat.shape[1])], axis=1)
    return out.reshape((len(t_frames),) + a.shape[1:])


def _integrate_gyro(ti: F64, gyro: F64) -> Rotation:
    """``R_first_body`` at every IMU time (trapezoidal rates, rotation vectors composed)."""
    dt = np.diff(ti)
    steps = Rotation.from_rotvec(0.5 * (gyro[1:] + gyro[:-1]) * dt[:, None]).as_matrix()
    out = np.empty((len(ti), 3, 3))
    out[0] = np.eye(3)
    for i in range(len(steps)):
        out[i + 1] = out[i] @ steps[i]
    return Rotation.from_matrix(out)


def smooth_rotations(t: F64, R_mb: F64, ti: F64, gyro: F64, gyro_noise_density: float,
                     rotation_noise_rad: float,
                     gyro_bias_std_radps: float | None = None) -> tuple[F64, F64]:
    """Body rotations at the frames from the trajectory's (noisy, absolute) and the gyroscope's
    (precise, relative), with the gyroscope bias.

    Least squares over small corrections ``d_k`` (``R_k = Exp(d_k) R_traj_k``) and the bias
    ``b``: ``|d_k| / rotation_noise_rad`` and, between frames, ``|log(G_k^T R_k^T R_k+1) + b
    dt_k| / (q sqrt(dt_k))`` with ``G_k`` the gyroscope's rotation from frame ``k`` to ``k+1``
    (linearised, two Gauss-Newton steps).

    Returns:
        ``(R_model_body (K, 3, 3), gyro_bias (3,))``.
    """
    C = _integrate_gyro(ti, gyro)
    Ck = Slerp(ti, C)(np.clip(t, ti[0], ti[-1])).as_matrix()
    G = np.einsum("kji,kjl->kil", Ck[:-1], Ck[1:])  # gyro rotation k -> k+1 (bias included)
    dt = np.diff(t)
    K = len(t)
    R0 = np.asarray(R_mb, dtype=np.float64)
    R = R0.copy()
    bias: F64 = np.zeros(3)
    w_abs = 1.0 / rotation_noise_rad
    w_rel = 1.0 / (gyro_noise_density * np.sqrt(dt))
    for _ in range(2):
        rel = np.einsum("kji,kjl->kil", R[:-1], R[1:])
        r = Rotation.from_matrix(np.einsum("kji,kjl->kil", G, rel)).as_rotvec() + bias * dt[:, None]
        n = 3 * K + 3
        A = np.zeros((3 * K + 3 * (K - 1) + 3, n))
        y = np.zeros(A.shape[0])
        if gyro_bias_std_radps is not None:  # zero-mean prior on the bias (last 3 rows)
            A[-3:, 3 * K:] = np.eye(3) / gyro_bias_std_radps
        A[: 3 * K, : 3 * K] = np.eye(3 * K) * w_abs
        # the prior holds the total correction (not this step's) near zero
        e = Rotation.from_matrix(np.einsum("kij,klj->kil", R, R0)).as_rotvec()
        y[: 3 * K] = -e.reshape(-1) * w_abs
        for k in range(K - 1):
            rows = slice(3 * K + 3 * k, 3 * K + 3 * k + 3)
            Rt = R[k + 1].T * w_rel[k]
            A[rows, 3 * (k + 1): 3 * (k + 2)] = Rt
            A[rows, 3 * k: 3 * (k + 1)] = -Rt
            A[rows, 3 * K:] = np.eye(3) * dt[k] * w_rel[k]
            y[rows] = -(r[k] - bias * dt[k]) * w_rel[k]
        sol, *_ = np.linalg.lstsq(A, y, rcond=None)
        d = sol[: 3 * K].reshape(K, 3)
        R = Rotation.from_rotvec(d).as_matrix() @ R
        bias = np.asarray(sol[3 * K:], dtype=np.float64)
    return R, bias


class _GyroTrack:
    """``R_model_body(tau)``: smoothed frame rotations, the gyroscope in between."""

    def __init__(self, t: F64, R_mb: F64, ti: F64, gyro: F64, q: float, sigma: float,
                 bias_std: float | None) -> None:
        R, bias = smooth_rotations(t, R_mb, ti, gyro, q, sigma, bias_std)
        self.t = t
        self.R = R
        self.ti = ti
        self.C = _integrate_gyro(ti, gyro - bias)
        self.Ck = Slerp(ti, self.C)(np.clip(t, ti[0], ti[-1])).as_matrix()
        log.debug("gyro bias %s rad/s; rotation corrections up to %.4f rad", bias.tolist(),
                  float(np.max(np.linalg.norm(Rotation.from_matrix(np.einsum(
                      "kij,kjl->kil", R, np.transpose(R_mb, (0, 2, 1)))).as_rotvec(),
                      axis=1))))

    def __call__(self, ts: F64) -> F64:
        k = np.clip(np.searchsorted(self.t, ts, side="right") - 1, 0, len(self.t) - 1)
        Cs = Slerp(self.ti, self.C)(np.clip(ts, self.ti[0], self.ti[-1])).as_matrix()
        # R(tau) = R_k C(t_k)^T C(tau)
        return np.asarray(np.einsum("nij,nkj,nkl->nil", self.R[k], self.Ck[k], Cs),
                          dtype=np.float64)


def _noise_cov(tau: F64, q: float, sigma_pos: float) -> F64:
    tk, tl = tau[:, None], tau[None, :]
    m = np.minimum(tk, tl)
    c = q**2 * (tk * tl * m - (tk + tl) * m**2 / 2.0 + m**3 / 3.0)
    return np.asarray(c + sigma_pos**2 * np.eye(len(tau)), dtype=np.float64)


def _window_rows(
    wi: int,
    idx: NDArray[np.intp],
    *,
    t: F64,
    c: F64,
    R_mc: F64,
    t_cb: F64,
    ti: F64,
    f: F64,
    R_model_body: Callable[[F64], F64],
    n_x: int,
) -> tuple[F64, F64, F64]:
    """The linear rows of window ``wi`` (frames ``idx``): ``s c_k - g tau^2/2 + Psi b - p_a -
    v_a tau = Phi - R_mc t_cb``.

    Returns:
        ``A`` ``(k, 3, n_x)``, ``y`` ``(k, 3)`` and ``tau`` ``(k,)`` seconds since the window's
        first frame.
    """
    ta, tb = t[idx[0]], t[idx[-1]]
    sel = (ti >= ta) & (ti <= tb)
    ts = np.concatenate([[ta], ti[sel], [tb]])

    def f_at(tq: float) -> F64:
        return np.array([[np.interp(tq, ti, f[:, j]) for j in range(3)]])

    fs = np.concatenate([f_at(ta), f[sel], f_at(tb)])
    ts, keep = np.unique(ts, return_index=True)
    fs = fs[keep]
    R_mb = R_model_body(ts)
    Phi = _double_integrals(ts, np.einsum("nij,nj->ni", R_mb, fs), t[idx])
    Psi = _double_integrals(ts, R_mb, t[idx])
    tau = t[idx] - ta
    k = len(idx)
    A = np.zeros((k, 3, n_x))
    A[:, :, 0] = c[idx]
    A[:, :, 1:4] = -0.5 * tau[:, None, None] ** 2 * np.eye(3)[None]
    A[:, :, 4:7] = Psi
    A[:, :, 7 + 6 * wi: 10 + 6 * wi] = -np.eye(3)[None]
    A[:, :, 10 + 6 * wi: 13 + 6 * wi] = -tau[:, None, None] * np.eye(3)[None]
    y = Phi - np.einsum("kij,j->ki", R_mc[idx], t_cb)
    return A, y, tau


def _whitened_system(
    rows: list[tuple[F64, F64]], covs: list[F64], accel_bias_std_mps2: float | None, n_x: int
) -> tuple[F64, F64]:
    """Stack the windows' rows whitened by their noise, plus the accelerometer bias prior.

    Raises:
        SfmError: ``accel_bias_std_mps2`` is not positive.
    """
    # Whitening per window and axis: L^-1 with C = L L^T (axes independent, same C).
    Aw, yw = [], []
    for (A, y), C in zip(rows, covs, strict=True):
        L = np.linalg.cholesky(C)
        for ax in range(3):
            Aw.append(np.linalg.solve(L, A[:, ax, :]))
            yw.append(np.linalg.solve(L, y[:, ax]))
    if accel_bias_std_mps2 is not None:
        if not accel_bias_std_mps2 > 0:
            raise SfmError(f"accel_bias_std_mps2 must be > 0, got {accel_bias_std_mps2}")
        prior = np.zeros((3, n_x))
        prior[:, 4:7] = np.eye(3) / accel_bias_std_mps2
        Aw.append(prior)
        yw.append(np.zeros(3))
    return np.concatenate(Aw), np.concatenate(yw)


def _fix_gravity_magnitude(
    Aw_m: F64, yw_v: F64, x: F64, gravity_mps2: float
) -> tuple[F64, F64, F64, F64]:
    """Gauss-Newton on the whitened system with ``g = gravity_mps2 * u(theta, phi)``.

    Starts from the linear solution ``x`` (whose ``x[1:4]`` has a direction).

    Returns:
        ``full`` (the state with ``g`` in place), ``g`` ``(3,)``, the reduced parameters
        ``z`` and the Jacobian of the last step.
    """
    n_x = Aw_m.shape[1]
    g = x[1:4]
    u = g / np.linalg.norm(g)
    th, ph = np.arccos(np.clip(u[2], -1, 1)), np.arctan2(u[1], u[0])
    keep_cols = [0] + list(range(4, n_x))

    def split(z: F64) -> tuple[F64, F64]:
        th_, ph_ = z[-2], z[-1]
        gv = gravity_mps2 * np.array([np.sin(th_) * np.cos(ph_), np.sin(th_) * np.sin(ph_),
                                      np.cos(th_)])
        full = np.zeros(n_x)
        full[keep_cols] = z[:-2]
        full[1:4] = gv
        return full, gv

    z = np.concatenate([x[keep_cols], [th, ph]])
    for _ in range(20):
        full, gv = split(z)
        r = Aw_m @ full - yw_v
        dg_dth = gravity_mps2 * np.array([np.cos(z[-2]) * np.cos(z[-1]),
                                          np.cos(z[-2]) * np.sin(z[-1]), -np.sin(z[-2])])
        dg_dph = gravity_mps2 * np.array([-np.sin(z[-2]) * np.sin(z[-1]),
                                          np.sin(z[-2]) * np.cos(z[-1]), 0.0])
        J = np.column_stack([Aw_m[:, keep_cols], Aw_m[:, 1:4] @ dg_dth, Aw_m[:, 1:4] @ dg_dph])
        step, *_ = np.linalg.lstsq(J, -r, rcond=None)
        z = z + step
        if np.max(np.abs(step)) < 1e-12 * (1 + np.max(np.abs(z))):
            break
    full, gv = split(z)
    return full, gv, z, J


def estimate_imu_scale(
    t_s: F64,
    T_model_cam: F64,
    imu_t_s: F64,
    accel_mps2: F64,
    T_cam_body: F64,
    *,
    accel_noise_density_mps2_sqrthz: float = DEFAULT_ACCEL_NOISE_MPS2_SQRTHZ,
    position_noise_m: float = 0.002,
    gravity_mps2: float = 9.81,
    accel_bias_std_mps2: float | None = 0.05,
    window_s: float = 10.0,
    max_relative_std: float = 0.05,
    gyro_radps: F64 | None = None,
    gyro_noise_density_radps_sqrthz: float = DEFAULT_GYRO_NOISE_RADPS_SQRTHZ,
    rotation_noise_rad: float = 0.003,
    gyro_bias_std_radps: float | None = DEFAULT_GYRO_BIAS_STD_RADPS,
) -> ImuScaleResult:
    """Scale (metres per unit) of a monocular trajectory from IMU accelerations.

    Args:
        t_s: ``(F,)`` frame times, seconds, increasing (the IMU's clock).
        T_model_cam: ``(F, 4, 4)`` camera poses in the model world, up to scale.
        imu_t_s: ``(N,)`` IMU sample times, seconds, increasing.
        accel_mps2: ``(N, 3)`` specific force in the body (IMU) frame, m/s^2.
        T_cam_body: ``(4, 4)`` the IMU in the camera frame (metres).
        accel_noise_density_mps2_sqrthz: accelerometer white noise density.
        position_noise_m: noise of the trajectory's positions (after scaling), metres.
        gravity_mps2: local gravity magnitude.
        accel_bias_std_mps2: prior standard deviation of the accelerometer bias (zero mean),
            m/s^2; None estimates it freely. Without a prior a constant-speed orbit with the
            heading locked to it is degenerate (its acceleration is constant in the body frame,
            like a bias); the default, 5 mg, is a loose bound for a calibrated MEMS IMU.
        window_s: length of one integration window; longer sequences are split.
        max_relative_std: above this relative uncertainty the status is ``weak``.
        gyro_radps: ``(N, 3)`` the IMU's angular rates (body frame, rad/s), or None. When
            given (recommended), the trajectory's rotations are smoothed with the gyroscope
            (:func:`smooth_rotations`) and the rotations between frames follow the gyroscope;
            otherwise they are interpolated (slerp). Rotation errors tilt gravity into the
            integrated acceleration. Measured (tests/sfm/test_imu_scale.py's lawnmower, 15 s,
            10 fps, MTi-300, 0.2 degrees of white rotation noise, seeds 0-2): scale errors
            1.06, 0.63, 0.24 % without the gyroscope and 0.35, 0.36, 1.15 % with it. The
            smoothed rotations are 5-10x closer to the truth, but what remains is a slowly
            varying tilt (the gyroscope's angle random walk, about 4e-4 rad) that double
            integration does not average out, while white per-frame noise partly does. On a
            real monocular SfM model, whose rotation errors drift slowly, the gyroscope (with
            the bias prior below) is what makes the scale usable (docs/sfm.md).
        gyro_noise_density_radps_sqrthz: gyroscope white noise density (the smoother's
            weight of the gyroscope).
        rotation_noise_rad: the trajectory's rotation noise (the smoother's weight of it).
        gyro_bias_std_radps: prior standard deviation of the gyroscope bias (zero mean), or
            None to estimate it freely. A free bias absorbs a slow rotation drift of the
            trajectory (the gyroscope then inherits it): on the simulated lawnmower's monocular
            SfM (0.29 degrees rotation error) the scale error was -4.2 % with a free bias and
            -0.9 % with this default (the MTi-300's in-run stability, 10 deg/h), against
            -5.9 % without the gyroscope (benchmarks/bench_sfm.py --only imu).

    Returns:
        :class:`ImuScaleResult` (a status, never an exception, for valid input that does not
        constrain the scale).

    Raises:
        SfmError: arrays of the wrong shape or times not increasing.
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    T = np.asarray(T_model_cam, dtype=np.float64)
    ti = np.asarray(imu_t_s, dtype=np.float64).reshape(-1)
    f = np.asarray(accel_mps2, dtype=np.float64)
    Tcb = np.asarray(T_cam_body, dtype=np.float64)
    if T.shape != (len(t), 4, 4) or f.shape != (len(ti), 3) or Tcb.shape != (4, 4):
        raise SfmError(f"shapes: t_s {t.shape}, T_model_cam {T.shape}, imu_t_s {ti.shape}, "
                       f"accel {f.shape}, T_cam_body {Tcb.shape}")
    if np.any(np.diff(t) <= 0) or np.any(np.diff(ti) <= 0):
        raise SfmError("frame and IMU times must increase strictly")
    inside = (t >= ti[0]) & (t <= ti[-1]) if len(ti) > 1 else np.zeros(len(t), bool)
    if inside.sum() < 4:
        return _failed(f"only {int(inside.sum())} frames lie inside the IMU's time span "
                       f"(at least 4 are needed)", len(t))
    t, T = t[inside], T[inside]
    R_mc = T[:, :3, :3]
    c = T[:, :3, 3]
    R_cb = Tcb[:3, :3]
    t_cb = Tcb[:3, 3]
    # Windows of about window_s, each with at least 4 frames.
    n_win = max(1, int(np.floor((t[-1] - t[0]) / window_s)))
    edges = np.linspace(t[0], t[-1], n_win + 1)
    win = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_win - 1)
    windows = [np.nonzero(win == w)[0] for w in range(n_win)]
    windows = [w for w in windows if len(w) >= 4]
    if not windows:
        return _failed("no window holds 4 frames", len(t))
    slerp = Slerp(t, Rotation.from_matrix(R_mc))
    track = None
    if gyro_radps is not None:
        g_arr = np.asarray(gyro_radps, dtype=np.float64)
        if g_arr.shape != f.shape:
            raise SfmError(f"gyro {g_arr.shape} and accel {f.shape} must have the same shape")
        track = _GyroTrack(t, R_mc @ R_cb, ti, g_arr, gyro_noise_density_radps_sqrthz,
                           rotation_noise_rad, gyro_bias_std_radps)
    n_w = len(windows)
    n_x = 1 + 3 + 3 + 6 * n_w  # s, g, b, then (p_a, v_a) per window

    def R_model_body(ts: F64) -> F64:
        return slerp(ts).as_matrix() @ R_cb if track is None else track(ts)

    rows = [
        _window_rows(wi, idx, t=t, c=c, R_mc=R_mc, t_cb=t_cb, ti=ti, f=f,
                     R_model_body=R_model_body, n_x=n_x)
        for wi, idx in enumerate(windows)
    ]
    covs = [_noise_cov(tau, accel_noise_density_mps2_sqrthz, position_noise_m)
            for _, _, tau in rows]
    Aw_m, yw_v = _whitened_system([(A, y) for A, y, _ in rows], covs, accel_bias_std_mps2, n_x)
    x, *_ = np.linalg.lstsq(Aw_m, yw_v, rcond=None)
    log.debug("linear solution: scale %.6g, |g| %.4f", x[0], np.linalg.norm(x[1:4]))
    # Gauss-Newton with |g| fixed: g = gravity * u(theta, phi).
    g = x[1:4]
    if not np.all(np.isfinite(g)) or np.linalg.norm(g) < 1e-9:
        return _failed("the linear solution has no gravity direction", len(t))
    full, gv, z, J = _fix_gravity_magnitude(Aw_m, yw_v, np.asarray(x, np.float64), gravity_mps2)
    r = Aw_m @ full - yw_v
    dof = max(1, len(r) - len(z))
    chi2 = float(r @ r / dof)
    try:
        cov = np.linalg.inv(J.T @ J) * max(1.0, chi2)
    except np.linalg.LinAlgError:
        return _failed("the scale is not observable (singular system)", len(t))
    s = float(full[0])
    s_std = float(np.sqrt(max(cov[0, 0], 0.0)))
    if not s > 0:
        return _failed(f"the scale came out non-positive ({s:.4g}): too little acceleration "
                       "or a wrong T_cam_body", len(t))
    rel = s_std / s
    status = "ok" if rel <= max_relative_std else "weak"
    msg = (f"IMU scale {s:.5g} m/unit +- {100 * rel:.2f} % (1 sigma) from {len(t)} frames in "
           f"{len(windows)} window(s), chi2/dof {chi2:.2f}")
    if status == "weak":
        msg += f"; uncertainty above {100 * max_relative_std:.0f} %: the camera hardly " \
               "accelerates"
    log.info(msg)
    b = full[4:7]
    return ImuScaleResult(status=status, message=msg, scale=s, scale_std=s_std,
                          gravity_model_mps2=(float(gv[0]), float(gv[1]), float(gv[2])),
                          accel_bias_mps2=(float(b[0]), float(b[1]), float(b[2])),
                          windows=len(windows), frames=len(t), chi2_per_dof=chi2)
