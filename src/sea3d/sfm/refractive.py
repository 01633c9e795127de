"""Refractive bundle adjustment over per-observation rays (scipy).

COLMAP models every camera as a pinhole. For a port camera it sees the images remapped into a
virtual pinhole (:mod:`sea3d.rectify.virtual`), which is exact only at one depth; flat ports
close up and domes far off centre leave a depth-dependent error. This module refines the poses
and points of a COLMAP model with the true camera model: every observation's pixel (in the raw
image) is unprojected through the refractive camera (:meth:`CameraModel.unproject`, origins on
the outer port surface, directions in the water) once, and the residual of a point ``X`` seen
in frame ``f`` is its offset from that ray, as an angle scaled by the focal length (pixels):

    q = R_f X + t_f - o,       r = f_px [b1 . q, b2 . q] / (d . q)

with the ray ``(o, d)`` in the left camera frame (right-camera rays moved there with the rig's
``T_left_right``) and ``b1, b2`` a basis orthogonal to ``d``. The poses ``T_left_world`` (of the
left camera, for the stereo rig the right camera follows through the fixed extrinsics) and the
points are solved by ``scipy.optimize.least_squares`` (trust region reflective, sparse Jacobian
with the exact derivatives; a Huber loss of 1 px by iteratively reweighted least squares),
starting from COLMAP's pinhole solution.
Gauge: the first registered frame is held fixed; for a monocular model (no metric scale) so is
the distance between the first two registered frames.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from sea3d._typing import F64
from sea3d.geometry.rig import StereoRig
from sea3d.geometry.se3 import invert_T
from sea3d.sfm.types import RefractiveBaReport

__all__ = ["RayObservations", "ray_bundle_adjust", "refine"]

log = logging.getLogger(__name__)
IntArray = NDArray[np.intp]


class RayObservations:
    """Observations as rays in the left camera frame.

    Attributes:
        frame: ``(M,)`` frame index of each observation.
        point: ``(M,)`` point index.
        origins, directions: ``(M, 3)`` the ray in the left camera frame (metres, unit).
        focal_px: ``(M,)`` focal length that turns angles into pixels.
    """

    def __init__(self, frame: IntArray, point: IntArray, origins: F64, directions: F64,
                 focal_px: F64) -> None:
        ok = np.isfinite(origins).all(axis=1) & np.isfinite(directions).all(axis=1)
        self.frame = np.asarray(frame, dtype=np.intp)[ok]
        self.point = np.asarray(point, dtype=np.intp)[ok]
        self.origins = np.asarray(origins, dtype=np.float64)[ok]
        d = np.asarray(directions, dtype=np.float64)[ok]
        self.directions = d / np.linalg.norm(d, axis=1, keepdims=True)
        self.focal_px = np.asarray(focal_px, dtype=np.float64)[ok]
        # an orthonormal basis (b1, b2) of the plane orthogonal to each ray
        helper = np.where(np.abs(self.directions[:, :1]) < 0.9, [[1.0, 0.0, 0.0]],
                          [[0.0, 1.0, 0.0]])
        b1 = np.cross(self.directions, helper)
        self.b1 = b1 / np.linalg.norm(b1, axis=1, keepdims=True)
        self.b2 = np.cross(self.directions, self.b1)

    def __len__(self) -> int:
        return int(self.frame.shape[0])


def _skew(v: F64) -> F64:
    z = np.zeros(v.shape[0])
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], 1),
                     np.stack([v[:, 2], z, -v[:, 0]], 1),
                     np.stack([-v[:, 1], v[:, 0], z], 1)], 1)


def _exp_and_left_jacobian(w: F64) -> tuple[F64, F64]:
    """``(N, 3, 3)`` rotations ``Exp(w)`` and their left Jacobians ``J_l(w)``."""
    th = np.linalg.norm(w, axis=1)
    W = _skew(w)
    W2 = W @ W
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(ths) / ths)
    b = np.where(small, 0.5, (1 - np.cos(ths)) / ths**2)
    c = np.where(small, 1.0 / 6.0, (ths - np.sin(ths)) / ths**3)
    eye = np.eye(3)[None]
    R = eye + a[:, None, None] * W + b[:, None, None] * W2
    J = eye + b[:, None, None] * W + c[:, None, None] * W2
    return R, J


def ray_bundle_adjust(
    T_left_world: F64,
    points_world: F64,
    obs: RayObservations,
    *,
    fixed_frames: tuple[int, ...] = (0,),
    fix_scale_between: tuple[int, int] | None = None,
    huber_px: float = 1.0,
    max_nfev: int = 30,
    irls_rounds: int = 3,
) -> tuple[F64, F64, dict[str, float]]:
    """Refine poses and points so that every point lies on its observations' rays.

    Args:
        T_left_world: ``(F, 4, 4)`` initial poses (world to left camera).
        points_world: ``(P, 3)`` initial points, metres.
        obs: the observations (:class:`RayObservations`).
        fixed_frames: frames whose poses are held fixed (the gauge).
        fix_scale_between: two frames whose camera-centre distance is held (soft, strongly
            weighted) for models without metric scale; None when the rig fixes the scale.
        huber_px: Huber loss threshold, pixels.
        max_nfev: most function evaluations per reweighting round.
        irls_rounds: reweighting rounds of the Huber loss.

    Returns:
        ``(T_left_world, points_world, info)`` refined, with ``rms_before_px``,
        ``rms_after_px``, ``nfev``.
    """
    n_f = T_left_world.shape[0]
    n_p = points_world.shape[0]
    free = np.array([f not in fixed_frames for f in range(n_f)])
    free_idx = -np.ones(n_f, dtype=np.intp)
    free_idx[free] = np.arange(int(free.sum()))
    n_free = int(free.sum())
    R0 = T_left_world[:, :3, :3].copy()
    t0 = T_left_world[:, :3, 3].copy()
    m = len(obs)
    fo, po = obs.frame, obs.point

    def centres(x: F64) -> F64:
        R, t = unpack(x)[:2]
        return -np.einsum("fji,fj->fi", R, t)

    def unpack(x: F64) -> tuple[F64, F64, F64, F64]:
        w = np.zeros((n_f, 3))
        t = t0.copy()
        pose = x[: 6 * n_free].reshape(n_free, 6)
        w[free] = pose[:, :3]
        t[free] = pose[:, 3:]
        dR, J = _exp_and_left_jacobian(w)
        R = dR @ R0
        X = x[6 * n_free:].reshape(n_p, 3)
        return R, t, X, J

    scale_ref = None
    if fix_scale_between is not None:
        a, b = fix_scale_between
        c0 = -np.einsum("fji,fj->fi", R0, t0)
        scale_ref = float(np.linalg.norm(c0[a] - c0[b]))
    w_scale = 1e4
    sqrt_w = np.ones(m)  # per-observation weights of the Huber IRLS

    def residuals(x: F64) -> F64:
        R, t, X, _ = unpack(x)
        q = np.einsum("mij,mj->mi", R[fo], X[po]) + t[fo] - obs.origins
        dq = np.einsum("mi,mi->m", obs.directions, q)
        r = np.stack([np.einsum("mi,mi->m", obs.b1, q), np.einsum("mi,mi->m", obs.b2, q)], 1)
        r *= (sqrt_w * obs.focal_px / dq)[:, None]
        out: np.ndarray = r.ravel()
        if scale_ref is not None and fix_scale_between is not None:
            c = centres(x)
            a, b = fix_scale_between
            out = np.append(out, w_scale * (np.linalg.norm(c[a] - c[b]) - scale_ref))
        return np.asarray(out, dtype=np.float64)

    def jacobian(x: F64) -> csr_matrix:
        R, t, X, J = unpack(x)
        y = np.einsum("mij,mj->mi", R[fo], X[po])  # rotated point
        q = y + t[fo] - obs.origins
        dq = np.einsum("mi,mi->m", obs.directions, q)
        s = sqrt_w * obs.focal_px / dq
        e1 = np.einsum("mi,mi->m", obs.b1, q) / dq
        e2 = np.einsum("mi,mi->m", obs.b2, q) / dq
        # dr/dq, (M, 2, 3)
        Dq = np.stack([obs.b1 - e1[:, None] * obs.directions,
                       obs.b2 - e2[:, None] * obs.directions], 1) * s[:, None, None]
        dX = Dq @ R[fo]  # (M, 2, 3)
        rows_p = (2 * np.arange(m))[:, None, None] + np.arange(2)[None, :, None]
        rows_p = np.broadcast_to(rows_p, (m, 2, 3))
        cols_p = (6 * n_free + 3 * po)[:, None, None] + np.arange(3)[None, None, :]
        cols_p = np.broadcast_to(cols_p, (m, 2, 3))
        data: list[np.ndarray] = [dX.ravel()]
        rows: list[np.ndarray] = [rows_p.ravel()]
        cols: list[np.ndarray] = [cols_p.ravel()]
        fr = free[fo]
        if fr.any():
            # d(Exp(w) R0 X)/dw = -[Exp(w) R0 X]x J_l(w)
            dw = -np.einsum("mij,mjk->mik", Dq[fr], _skew(y[fr]) @ J[fo[fr]])
            dt = Dq[fr]
            blk = np.concatenate([dw, dt], axis=2)  # (Mf, 2, 6)
            mf = np.nonzero(fr)[0]
            rws = np.broadcast_to((2 * mf)[:, None, None] + np.arange(2)[None, :, None],
                                  blk.shape)
            cls = np.broadcast_to((6 * free_idx[fo[fr]])[:, None, None] + np.arange(6),
                                  blk.shape)
            data.append(blk.ravel())
            rows.append(rws.ravel())
            cols.append(cls.ravel())
        n_rows = 2 * m
        if scale_ref is not None and fix_scale_between is not None:
            # numeric derivative of the soft scale constraint (12 entries at most)
            a, b = fix_scale_between
            base = residuals(x)[-1]
            for f in (a, b):
                if not free[f]:
                    continue
                for k in range(6):
                    xx = x.copy()
                    xx[6 * free_idx[f] + k] += 1e-7
                    data.append(np.array([(residuals(xx)[-1] - base) / 1e-7]))
                    rows.append(np.array([n_rows]))
                    cols.append(np.array([6 * free_idx[f] + k]))
            n_rows += 1
        return csr_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n_rows, 6 * n_free + 3 * n_p))

    x = np.concatenate([np.column_stack([np.zeros((n_free, 3)), t0[free]]).ravel(),
                        points_world.ravel()])
    r0 = residuals(x)[: 2 * m]
    x, nfev = _huber_irls(residuals, jacobian, x, sqrt_w, huber_px=huber_px,
                          irls_rounds=irls_rounds, max_nfev=max_nfev)
    R, t, X, _ = unpack(x)
    r1 = residuals(x)[: 2 * m]
    T = np.tile(np.eye(4), (n_f, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    return T, X, _fit_info(r0, r1, huber_px=huber_px, nfev=nfev)


def _huber_irls(
    residuals: Callable[[F64], F64],
    jacobian: Callable[[F64], csr_matrix],
    x: F64,
    sqrt_w: F64,
    *,
    huber_px: float,
    irls_rounds: int,
    max_nfev: int,
) -> tuple[F64, int]:
    """Minimise the Huber loss of ``residuals`` by iteratively reweighted least squares.

    ``residuals`` and ``jacobian`` read the per-observation weights ``sqrt_w`` (``(M,)``),
    which this sets in place each round and leaves at 1 on return; the first ``2 M``
    residuals are the observations' pixel pairs.

    Returns:
        The solution and the number of function evaluations.
    """
    m = sqrt_w.shape[0]
    nfev = 0
    # Huber by iteratively reweighted least squares: scipy's robust losses converge slowly on
    # this problem; a plain Gauss-Newton solve per reweighting converges in a few steps.
    # The last round drops observations still beyond 4 Huber widths (gross outliers, which
    # Huber alone only down-weights).
    for rnd in range(irls_rounds):
        sqrt_w[:] = 1.0
        e = np.hypot(*residuals(x)[: 2 * m].reshape(-1, 2).T)
        sqrt_w[:] = np.sqrt(np.minimum(1.0, huber_px / np.maximum(e, 1e-12)))
        if rnd == irls_rounds - 1:
            sqrt_w[e > 4 * huber_px] = 0.0
        sol = least_squares(residuals, x, jac=jacobian, method="trf", loss="linear",
                            x_scale="jac", tr_solver="lsmr", max_nfev=max_nfev, xtol=1e-12,
                            ftol=1e-12, gtol=1e-12)
        x = sol.x
        nfev += int(sol.nfev)
    sqrt_w[:] = 1.0
    return x, nfev


def _fit_info(r0: F64, r1: F64, *, huber_px: float, nfev: int) -> dict[str, float]:
    """RMS pixel error before and after, over the initial solution's inliers.

    Outliers (beyond 4 Huber widths at the start) would dominate both figures.
    """
    e0 = np.hypot(r0[0::2], r0[1::2])
    e1 = np.hypot(r1[0::2], r1[1::2])
    inl = e0 < 4 * huber_px
    return {
        "rms_before_px": float(np.sqrt(np.mean(e0[inl] ** 2))) if inl.any() else float("nan"),
        "rms_after_px": float(np.sqrt(np.mean(e1[inl] ** 2))) if inl.any() else float("nan"),
        "nfev": float(nfev),
    }


def refine(rec: Any, sensors: list[Any], rig: StereoRig, *, fix_scale: bool,
           huber_px: float = 1.0, max_nfev: int = 50) -> RefractiveBaReport:
    """Refine a COLMAP reconstruction built from virtual pinholes with the true cameras, in
    place (frame poses and points; the COLMAP cameras stay the virtual pinholes).

    Args:
        rec: ``pycolmap.Reconstruction`` (frames ``1..F``, rig frame = reference virtual cam).
        sensors: the ``_Sensor`` list of :mod:`sea3d.sfm.colmap` (reference first).
        rig: the stereo rig.
        fix_scale: hold the scale (models without metric scale).

    Returns:
        :class:`RefractiveBaReport`.
    """
    t_start = time.perf_counter()
    by_cam = {s.camera_id: s for s in sensors}
    ref = sensors[0]
    # Everything in the frame of the physical reference camera ("left" below, whichever it is).
    T_ref_sensor = {s.camera_id: (np.eye(4) if s is ref else
                                  (rig.T_left_right if ref.name == "left" else rig.T_right_left))
                    for s in sensors}
    frame_ids = sorted(fid for fid, fr in rec.frames.items() if fr.has_pose())
    fidx = {fid: k for k, fid in enumerate(frame_ids)}
    point_ids = list(rec.points3D.keys())
    pidx = {pid: k for k, pid in enumerate(point_ids)}
    T_vref_ref = invert_T(ref.T_cam_virtual)
    T_ref_world = np.stack([
        invert_T(T_vref_ref) @ _T_of(rec.frames[fid].rig_from_world) for fid in frame_ids
    ])
    # T_ref_world = T_ref_vref @ T_vref_world
    X = np.stack([np.asarray(rec.points3D[p].xyz, dtype=np.float64) for p in point_ids])
    fr_l, pt_l, o_l, d_l, f_l = [], [], [], [], []
    for img in rec.images.values():
        if not img.has_pose or img.frame_id not in fidx:
            continue
        s = by_cam[img.camera_id]
        p2d = [(p.xy, p.point3D_id) for p in img.points2D if p.has_point3D()]
        if not p2d:
            continue
        uv = np.array([xy for xy, _ in p2d], dtype=np.float64) - 0.5  # COLMAP -> our pixels
        raw = s.maps.to_raw(uv) if s.maps is not None else uv
        rays = s.model.unproject(raw)
        T = T_ref_sensor[img.camera_id]
        o_l.append(rays.origins @ T[:3, :3].T + T[:3, 3])
        d_l.append(rays.directions @ T[:3, :3].T)
        fr_l.append(np.full(len(p2d), fidx[img.frame_id]))
        pt_l.append(np.array([pidx[pid] for _, pid in p2d]))
        f_l.append(np.full(len(p2d), float(s.params[0])))
    obs = RayObservations(np.concatenate(fr_l), np.concatenate(pt_l), np.concatenate(o_l),
                          np.concatenate(d_l), np.concatenate(f_l))
    fix_pair = (0, 1) if fix_scale and len(frame_ids) > 1 else None
    T_new, X_new, info = ray_bundle_adjust(T_ref_world, X, obs, fixed_frames=(0,),
                                           fix_scale_between=fix_pair, huber_px=huber_px,
                                           max_nfev=max_nfev)
    import pycolmap

    for k, fid in enumerate(frame_ids):
        T_vref_world = T_vref_ref @ T_new[k]
        rec.frames[fid].rig_from_world = pycolmap.Rigid3d(
            pycolmap.Rotation3d(np.ascontiguousarray(T_vref_world[:3, :3])),
            np.ascontiguousarray(T_vref_world[:3, 3]))
    for k, pid in enumerate(point_ids):
        rec.points3D[pid].xyz = X_new[k]
    rec.update_point_3d_errors()
    log.info("refractive BA: %d observations, ray RMS %.3f -> %.3f px in %d evaluations",
             len(obs), info["rms_before_px"], info["rms_after_px"], int(info["nfev"]))
    return RefractiveBaReport(observations=len(obs), rms_before_px=info["rms_before_px"],
                              rms_after_px=info["rms_after_px"], iterations=int(info["nfev"]),
                              time_s=time.perf_counter() - t_start)


def _T_of(rigid: Any) -> F64:
    T = np.eye(4)
    T[:3, :4] = np.asarray(rigid.matrix(), dtype=np.float64)
    return T

