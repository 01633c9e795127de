"""Rigid transforms in SE(3) and rotation conversions.

``T_a_b`` is a 4x4 float64 matrix that maps points in frame b into frame a: ``p_a = T_a_b @ p_b``
(see ``docs/conventions.md``). Quaternions are ``(w, x, y, z)`` (Hamilton, unit norm) unless a
name says otherwise (``quat_xyzw`` for TUM files).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sea3d._typing import FloatArray
from sea3d.errors import GeometryError

__all__ = [
    "R_to_quat_wxyz",
    "R_to_rotvec",
    "check_T",
    "compose",
    "invert_T",
    "look_at",
    "make_T",
    "quat_wxyz_to_R",
    "rotvec_to_R",
    "transform_points",
    "umeyama",
]


_ORTHO_TOL = 1e-6


def check_T(T: object, name: str = "T") -> FloatArray:
    """Validate a 4x4 rigid transform and return it as float64.

    Raises:
        GeometryError: wrong shape, non-finite values, a last row other than ``[0, 0, 0, 1]``,
            or a rotation block that is not orthonormal with determinant +1 (tolerance 1e-6).
    """
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise GeometryError(f"{name} must be a 4x4 matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise GeometryError(f"{name} has non-finite values")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=_ORTHO_TOL):
        raise GeometryError(f"{name} must end with the row [0, 0, 0, 1], got {arr[3].tolist()}")
    R = arr[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=_ORTHO_TOL) or np.linalg.det(R) < 0:
        raise GeometryError(f"{name}'s rotation block is not a proper rotation: {R.tolist()}")
    return arr


def make_T(R: object, t: object) -> FloatArray:
    """Build ``T`` (4x4) from a rotation ``R`` (3x3) and a translation ``t`` (3,) in metres."""
    R_arr = np.asarray(R, dtype=np.float64)
    t_arr = np.asarray(t, dtype=np.float64).reshape(-1)
    if R_arr.shape != (3, 3) or t_arr.shape != (3,):
        raise GeometryError(f"make_T needs R (3, 3) and t (3,), got {R_arr.shape}, {t_arr.shape}")
    T = np.eye(4)
    T[:3, :3] = R_arr
    T[:3, 3] = t_arr
    return T


def invert_T(T: object) -> FloatArray:
    """Inverse of a rigid transform: ``invert_T(T_a_b) == T_b_a``, exact up to rounding."""
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise GeometryError(f"invert_T needs a 4x4 matrix, got {arr.shape}")
    R = arr[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ arr[:3, 3]
    return out


def compose(*transforms: object) -> FloatArray:
    """Product ``T1 @ T2 @ ...``; inner frame letters cancel (``T_a_b @ T_b_c = T_a_c``)."""
    out = np.eye(4)
    for T in transforms:
        out = out @ np.asarray(T, dtype=np.float64)
    return out


def transform_points(T_a_b: object, points_b: object) -> FloatArray:
    """Map ``(N, 3)`` points from frame b into frame a: ``R @ p + t`` row-wise."""
    T = np.asarray(T_a_b, dtype=np.float64)
    pts = np.asarray(points_b, dtype=np.float64)
    if T.shape != (4, 4) or pts.ndim != 2 or pts.shape[1] != 3:
        raise GeometryError(
            f"transform_points needs T (4, 4) and points (N, 3), got {T.shape}, {pts.shape}"
        )
    return pts @ T[:3, :3].T + T[:3, 3]


def rotvec_to_R(rotvec: object) -> FloatArray:
    """Rotation matrix (3x3, or (N, 3, 3)) of rotation vectors (axis times angle, radians)."""
    rv = np.asarray(rotvec, dtype=np.float64)
    return np.asarray(Rotation.from_rotvec(rv).as_matrix(), dtype=np.float64)


def R_to_rotvec(R: object) -> FloatArray:
    """Rotation vector (axis times angle in radians, angle in [0, pi]) of a rotation matrix."""
    return np.asarray(Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec())


def quat_wxyz_to_R(quat_wxyz: object) -> FloatArray:
    """Rotation matrix of a ``(w, x, y, z)`` quaternion (normalised first; ``(4,)`` or ``(N, 4)``).

    Raises:
        GeometryError: a zero or non-finite quaternion.
    """
    q = np.asarray(quat_wxyz, dtype=np.float64)
    if q.shape[-1] != 4:
        raise GeometryError(f"a wxyz quaternion needs 4 values, got shape {q.shape}")
    norm = np.linalg.norm(q, axis=-1)
    if not np.all(np.isfinite(q)) or np.any(norm < 1e-12):
        raise GeometryError("quaternion must be finite and non-zero")
    xyzw = np.roll(q, -1, axis=-1)
    return np.asarray(Rotation.from_quat(xyzw).as_matrix(), dtype=np.float64)


def R_to_quat_wxyz(R: object) -> FloatArray:
    """``(w, x, y, z)`` unit quaternion of a rotation matrix, with ``w >= 0``."""
    xyzw = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    wxyz = np.roll(xyzw, 1, axis=-1)
    sign = np.where(wxyz[..., :1] < 0, -1.0, 1.0)
    return np.asarray(wxyz * sign, dtype=np.float64)


def look_at(eye_m: object, target_m: object, up: object = (0.0, 0.0, 1.0)) -> FloatArray:
    """``T_world_cam`` of a camera at ``eye_m`` looking at ``target_m`` (OpenCV axes: z forward,
    y down, so the image's "up" is ``up`` projected into the image plane).

    Raises:
        GeometryError: eye and target coincide, or the view direction is parallel to ``up``.
    """
    eye = np.asarray(eye_m, dtype=np.float64).reshape(3)
    z = np.asarray(target_m, dtype=np.float64).reshape(3) - eye
    if np.linalg.norm(z) < 1e-12:
        raise GeometryError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64).reshape(3))
    if np.linalg.norm(x) < 1e-9:
        raise GeometryError("look_at: view direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), eye)


def umeyama(src: object, dst: object, *, with_scale: bool) -> tuple[FloatArray, FloatArray, float]:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991).

    Args:
        src, dst: (N, 3) matched points, N >= 3 not all collinear for a unique rotation.
        with_scale: estimate ``s``; otherwise ``s = 1``.

    Returns:
        ``(R (3, 3), t (3,), s)``.

    Raises:
        GeometryError: fewer than 3 points or a degenerate (zero-spread) source.
    """
    x = np.asarray(src, dtype=np.float64)
    y = np.asarray(dst, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or len(x) < 3:
        raise GeometryError(f"alignment needs at least 3 matched positions, got {len(x)}")
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    var_x = float(np.mean(np.sum(xc * xc, axis=1)))
    if var_x <= 1e-18:
        raise GeometryError("alignment is undefined: the estimated positions do not move")
    cov = yc.T @ xc / len(x)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_x) if with_scale else 1.0
    t = my - s * R @ mx
    return R, t, s
