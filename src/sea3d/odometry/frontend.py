"""The odometry's front end: corners, KLT tracking, left-right matching, pose by PnP RANSAC.

All of it runs in the rectified images. Features are Shi-Tomasi corners, tracked frame to frame
by pyramidal Lucas-Kanade (OpenCV) with a forward-backward check; predicted positions (from the
IMU or a constant-velocity model) seed the search. Features that KLT loses are searched once
more with their patch warped by the local affine map that the predicted motion and the
landmark's depth give (:func:`track_warped`: a step towards a near point magnifies its patch, a
roll turns it, and a translational window follows neither). Each tracked corner is matched into the
rectified right image by Lucas-Kanade seeded with the depth map's disparity, checked backwards,
on the row and against the depth map; the match is triangulated exactly
(:meth:`RectifiedStereo.points_from_stereo`). Without a right image (RGB-D mode) the depth alone
gives the point. The pose of a frame comes from OpenCV's PnP RANSAC on the landmarks' world
positions, refined by Levenberg-Marquardt on the inliers.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from sea3d._typing import F64
from sea3d.odometry.config import OdometryConfig
from sea3d.odometry.stereo_geometry import RectifiedStereo
from sea3d.odometry.stereo_match import refine_on_row

_NO_DIST = np.zeros(4)  # rectified, virtual-pinhole consistent pixels: no distortion

__all__ = [
    "StereoPoints",
    "detect_corners",
    "predicted_affine",
    "sample_depth",
    "solve_pnp",
    "stereo_points",
    "to_grey",
    "track_klt",
    "track_warped",
]

B = NDArray[np.bool_]


def to_grey(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``(H, W)`` uint8 grey of a grey or RGB image."""
    if image.ndim == 2:
        return np.ascontiguousarray(image)
    return np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))


def sample_depth(depth_m: NDArray[np.float32], uv: F64, *, max_step: float = 0.05) -> F64:
    """Depth at pixels ``uv`` (nearest pixel), NaN where the 3x3 neighbourhood is incomplete or
    spans a depth step larger than ``max_step`` of the depth (edges, where a corner's depth is
    ambiguous)."""
    h, w = depth_m.shape
    u = np.rint(uv[:, 0]).astype(np.int64)
    v = np.rint(uv[:, 1]).astype(np.int64)
    inside = (u >= 1) & (u < w - 1) & (v >= 1) & (v < h - 1)
    out = np.full(uv.shape[0], np.nan)
    if not inside.any():
        return out
    ui, vi = u[inside], v[inside]
    patch = np.stack(
        [depth_m[vi + dv, ui + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1
    ).astype(np.float64)
    with np.errstate(invalid="ignore"):
        lo, hi = patch.min(axis=1), patch.max(axis=1)
        centre = patch[:, 4]
        ok = np.isfinite(patch).all(axis=1) & (hi - lo <= max_step * centre) & (centre > 0)
    vals = np.where(ok, centre, np.nan)
    out[inside] = vals
    return out


def detect_corners(
    grey: NDArray[np.uint8],
    existing_uv: F64,
    count: int,
    config: OdometryConfig,
    valid_mask: NDArray[np.bool_] | None = None,
) -> F64:
    """Up to ``count`` new Shi-Tomasi corners away from ``existing_uv`` and the border.

    Returns:
        ``(M, 2)`` float64 pixels.
    """
    if count <= 0:
        return np.zeros((0, 2))
    h, w = grey.shape
    scale = w / 640.0
    min_dist = max(3.0, config.min_feature_distance_px * scale)
    border = int(max(8, round(10 * scale)))
    mask = np.zeros((h, w), np.uint8)
    mask[border : h - border, border : w - border] = 255
    if valid_mask is not None:
        mask[~valid_mask] = 0
    r = round(min_dist)
    for u, v in existing_uv:
        if np.isfinite(u) and np.isfinite(v):
            cv2.circle(mask, (round(u), round(v)), r, 0, -1)
    pts = cv2.goodFeaturesToTrack(
        grey,
        maxCorners=int(count),
        qualityLevel=config.feature_quality,
        minDistance=min_dist,
        mask=mask,
        blockSize=5,
    )
    if pts is None:
        return np.zeros((0, 2))
    pts = cv2.cornerSubPix(
        grey,
        pts.astype(np.float32),
        (3, 3),
        (-1, -1),
        (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.01),
    )
    return np.asarray(pts.reshape(-1, 2), dtype=np.float64)


def track_klt(
    prev: NDArray[np.uint8],
    cur: NDArray[np.uint8],
    prev_uv: F64,
    guess_uv: F64 | None,
    config: OdometryConfig,
) -> tuple[F64, B]:
    """Track ``prev_uv`` from ``prev`` into ``cur``; ``guess_uv`` seeds the search.

    Returns:
        ``uv (N, 2)`` and ``ok (N,)``: found, inside the image, forward-backward error below
        ``config.forward_backward_px``.
    """
    n = prev_uv.shape[0]
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    win = (config.klt_window_px, config.klt_window_px)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
    p0 = prev_uv.astype(np.float32).reshape(-1, 1, 2)
    seed = p0.copy() if guess_uv is None else guess_uv.astype(np.float32).reshape(-1, 1, 2)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(
        prev,
        cur,
        p0,
        np.ascontiguousarray(seed),
        winSize=win,
        maxLevel=config.klt_levels,
        criteria=crit,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    p0b, stb, _ = cv2.calcOpticalFlowPyrLK(
        cur,
        prev,
        p1,
        p0.copy(),
        winSize=win,
        maxLevel=config.klt_levels,
        criteria=crit,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    uv = p1.reshape(-1, 2).astype(np.float64)
    fb = np.linalg.norm(p0b.reshape(-1, 2) - prev_uv, axis=1)
    h, w = cur.shape
    ok = (
        (st.ravel() == 1)
        & (stb.ravel() == 1)
        & (fb < config.forward_backward_px)
        & (uv[:, 0] >= 2)
        & (uv[:, 0] <= w - 3)
        & (uv[:, 1] >= 2)
        & (uv[:, 1] <= h - 3)
    )
    return uv, ok


def predicted_affine(uv_prev: F64, z_prev: F64, T_cur_prev: F64, K: F64) -> F64:
    """Local affine maps ``(N, 2, 2)`` from the previous image to the current one at features
    ``uv_prev`` (pixels) of depth ``z_prev`` (metres, previous camera), for the camera motion
    ``T_cur_prev`` (4x4): the derivative of the pixel's motion, with the surface taken
    fronto-parallel in the previous view. A forward step of ``dz`` to a point at depth ``z``
    scales its neighbourhood by ``z / (z - dz)``; a roll turns it: both defeat a translational
    Lucas-Kanade window, not this warp. NaN where a point is behind either camera."""
    Kinv = np.linalg.inv(K)
    R, t = T_cur_prev[:3, :3], T_cur_prev[:3, 3]
    out = np.full((uv_prev.shape[0], 2, 2), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        proj = []
        for du, dv in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)):
            h = np.stack([uv_prev[:, 0] + du, uv_prev[:, 1] + dv, np.ones(len(uv_prev))], 1)
            P = (h @ Kinv.T) * z_prev[:, None]
            Pc = P @ R.T + t
            q = Pc @ K.T
            proj.append(np.where(Pc[:, 2:3] > 0, q[:, :2] / q[:, 2:3], np.nan))
        out[:, :, 0] = proj[1] - proj[0]
        out[:, :, 1] = proj[2] - proj[0]
        out[~(z_prev > 0)] = np.nan
    return out


def track_warped(
    prev: NDArray[np.uint8],
    cur: NDArray[np.uint8],
    prev_uv: F64,
    affine: F64,
    guess_uv: F64,
    config: OdometryConfig,
    *,
    levels: int = 2,
    iterations: int = 15,
    min_zncc: float = 0.85,
    min_warp: float = 0.05,
) -> tuple[F64, B]:
    """Track ``prev_uv`` into ``cur`` with each feature's patch first warped by its predicted
    local affine map (:func:`predicted_affine`): the patch is made to look as it should in
    the current view, then its translation is found by inverse-compositional Gauss-Newton on
    zero-mean, unit-norm patches (the exposure may change), coarse to fine over ``levels``
    levels, from ``guess_uv`` (the predicted projections). Only features whose warp departs
    from the identity by ``min_warp`` or more (5 %: a scale change or about 3 deg of roll) and
    whose prediction lies inside the image are searched.

    A check of the forward-backward kind needs the warp's inverse; a match is kept instead
    when the alignment converged and the aligned patches' zero-normalised cross-correlation
    is at least ``min_zncc``.

    Returns:
        ``uv (N, 2)`` and ``ok (N,)``: converged, correlated, inside the image.
    """
    n = prev_uv.shape[0]
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    win = config.klt_window_px
    offs = np.arange(-(win // 2), win // 2 + 1, dtype=np.float64)
    ox, oy = np.meshgrid(offs, offs)
    o = np.stack([ox.ravel(), oy.ravel()], 0)  # (2, W*W) offsets in the current view
    with np.errstate(invalid="ignore"):
        det = affine[:, 0, 0] * affine[:, 1, 1] - affine[:, 0, 1] * affine[:, 1, 0]
    h, w = cur.shape
    r = win // 2
    with np.errstate(invalid="ignore"):
        # a warp near the identity is what KLT already tried; a patch predicted off the image
        # has left the view
        warps = np.abs(affine - np.eye(2)).max(axis=(1, 2)) >= min_warp
        inside = ((guess_uv[:, 0] >= r) & (guess_uv[:, 0] <= w - 1 - r)
                  & (guess_uv[:, 1] >= r) & (guess_uv[:, 1] <= h - 1 - r))
        usable = np.isfinite(det) & (det > 0.1) & (det < 10.0) & warps & inside
    uv = np.where(usable[:, None], guess_uv, prev_uv).astype(np.float64)
    ok = usable.copy()
    if not usable.any():
        return uv, ok
    idx = np.flatnonzero(usable)
    A_inv = np.linalg.inv(affine[idx])
    src = np.einsum("nij,jk->nik", A_inv, o)  # (M, 2, W*W) offsets in the previous view
    m, ww = idx.size, o.shape[1]
    pyr_prev, pyr_cur = [prev], [cur]
    for _ in range(1, levels):
        pyr_prev.append(np.asarray(cv2.pyrDown(pyr_prev[-1]), np.uint8))
        pyr_cur.append(np.asarray(cv2.pyrDown(pyr_cur[-1]), np.uint8))
    fprev = [a.astype(np.float32) for a in pyr_prev]
    fcur = [a.astype(np.float32) for a in pyr_cur]

    def sample(img: NDArray[np.float32], x: F64, y: F64) -> NDArray[np.float32]:
        out = cv2.remap(img, x.astype(np.float32).reshape(m, ww),
                        y.astype(np.float32).reshape(m, ww), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        return np.asarray(out, dtype=np.float32)

    def normed(a: NDArray[np.float32]) -> NDArray[np.float32]:
        z = a - a.mean(axis=1, keepdims=True)
        return np.asarray(z / (np.linalg.norm(z, axis=1, keepdims=True) + 1e-6), np.float32)

    p = uv[idx].copy()
    step: F64 = np.full(m, np.inf)
    for level in range(levels - 1, -1, -1):
        s = 0.5**level
        c0 = prev_uv[idx] * s
        T = normed(sample(fprev[level], c0[:, 0:1] + src[:, 0], c0[:, 1:2] + src[:, 1]))
        Tg = T.reshape(m, win, win)
        J = np.stack([np.gradient(Tg, axis=2).reshape(m, ww),
                      np.gradient(Tg, axis=1).reshape(m, ww)], 2)  # (M, W*W, 2)
        H = np.einsum("nki,nkj->nij", J, J) + 1e-9 * np.eye(2)
        H_inv = np.linalg.inv(H)
        q = p * s
        step = np.full(m, np.inf)
        for _ in range(iterations):
            active = step >= 0.03
            if not active.any():
                break
            I = normed(sample(fcur[level], q[:, 0:1] + o[0], q[:, 1:2] + o[1]))
            d = np.einsum("nij,nj->ni", H_inv, np.einsum("nki,nk->ni", J, I - T))
            d = np.clip(d, -2.0, 2.0)
            q = np.where(active[:, None], q - d, q)
            step = np.where(active, np.linalg.norm(d, axis=1), step)
        p = q / s
    I = normed(sample(fcur[0], p[:, 0:1] + o[0], p[:, 1:2] + o[1]))
    zncc = (I * T).sum(axis=1)
    good = (
        (step < 0.1)
        & (zncc >= min_zncc)
        & (p[:, 0] >= 2) & (p[:, 0] <= w - 3) & (p[:, 1] >= 2) & (p[:, 1] <= h - 3)
    )
    uv[idx] = p
    ok[idx] = good
    return uv, ok


@dataclass(frozen=True, kw_only=True, eq=False)
class StereoPoints:
    """Stereo measurements of features.

    Attributes:
        ok: ``(N,)`` features with a good match and a point in range.
        points_rect: ``(N, 3)`` exact points in ``rect_left`` (NaN where not ok).
        measurement: ``(N, 3)`` virtual stereo projection ``(u_left, u_right, v)`` of the
            points (what the back end's stereo factors measure), NaN where not ok.
    """

    ok: B
    points_rect: F64
    measurement: F64


def stereo_points(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8] | None,
    depth_m: NDArray[np.float32],
    uv: F64,
    geometry: RectifiedStereo,
    config: OdometryConfig,
) -> StereoPoints:
    """3D points and stereo measurements of left features ``uv``.

    With a right image the depth map seeds a Lucas-Kanade match on the row; without one (RGB-D)
    the depth is used as it is.
    """
    n = uv.shape[0]
    nan3 = np.full((n, 3), np.nan)
    if n == 0:
        return StereoPoints(ok=np.zeros(0, bool), points_rect=nan3, measurement=nan3)
    z_seed = sample_depth(depth_m, uv)
    fb = geometry.focal_baseline
    with np.errstate(invalid="ignore", divide="ignore"):
        d_seed = fb / z_seed
    seeded = np.isfinite(d_seed) & (d_seed > 0)
    ok = seeded.copy()
    if right is None:
        pts, okp = geometry.points_from_depth(uv, z_seed)
        ok &= okp
    else:
        idx = np.flatnonzero(seeded)
        pts = nan3.copy()
        if idx.size:
            pl = uv[idx].astype(np.float32).reshape(-1, 1, 2)
            guess = pl.copy()
            guess[:, 0, 0] -= d_seed[idx].astype(np.float32)
            win = (config.stereo_window_px, config.stereo_window_px)
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 0.001)
            pr, st, _ = cv2.calcOpticalFlowPyrLK(
                left,
                right,
                pl,
                guess,
                winSize=win,
                maxLevel=1,
                criteria=crit,
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            )
            pb, stb, _ = cv2.calcOpticalFlowPyrLK(
                right,
                left,
                pr,
                pl.copy(),
                winSize=win,
                maxLevel=1,
                criteria=crit,
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            )
            uv_r = pr.reshape(-1, 2).astype(np.float64)
            back = np.linalg.norm(pb.reshape(-1, 2) - uv[idx], axis=1)
            disp = uv[idx, 0] - uv_r[:, 0]
            w = right.shape[1]
            good = (
                (st.ravel() == 1)
                & (stb.ravel() == 1)
                & (back < 0.5)
                & (np.abs(uv_r[:, 1] - uv[idx, 1]) < config.stereo_row_px)
                & (np.abs(disp - d_seed[idx]) < config.stereo_depth_agreement_px)
                & (uv_r[:, 0] >= 1)
                & (uv_r[:, 0] <= w - 2)
            )
            good &= _on_row(left, right, uv[idx], uv_r, geometry, config)
            p, okp = geometry.points_from_stereo(uv[idx], uv_r)
            good &= okp
            pts[idx[good]] = p[good]
            ok[idx[~good]] = False
        ok &= np.isfinite(pts).all(axis=1)
    z = pts[:, 2]
    with np.errstate(invalid="ignore"):
        ok &= z > (config.min_depth_m if config.min_depth_m is not None else 0.0)
        if config.max_depth_m is not None:
            ok &= z < config.max_depth_m
    meas = geometry.project(pts)
    with np.errstate(invalid="ignore"):
        ok &= (meas[:, 0] - meas[:, 1]) > config.min_disparity_px
    pts[~ok] = np.nan
    meas[~ok] = np.nan
    return StereoPoints(ok=ok, points_rect=pts, measurement=meas)


def _on_row(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    uv: F64,
    uv_r: F64,
    geometry: RectifiedStereo,
    config: OdometryConfig,
) -> B:
    """Move 2D matches ``uv_r`` (in place) onto their left pixels' rows with the disparity
    refined there (pinhole geometry, ``config.stereo_on_row``); ``ok`` of each match."""
    if geometry.refractive or not config.stereo_on_row or uv.shape[0] == 0:
        return np.ones(uv.shape[0], bool)
    u1, ok = refine_on_row(left, right, uv, uv_r[:, 0], window_px=config.stereo_window_px)
    ok &= np.abs(u1 - uv_r[:, 0]) < 1.0
    uv_r[:, 0] = u1
    uv_r[:, 1] = uv[:, 1]
    return ok


def solve_pnp(
    points_world: F64,
    uv: F64,
    K: F64,
    T_rect_world_guess: F64 | None,
    config: OdometryConfig,
) -> tuple[F64 | None, NDArray[np.int64]]:
    """Pose of the rectified left camera from 3D-2D correspondences.

    Returns:
        ``(T_rect_world 4x4 or None, inlier indices)``.
    """
    n = points_world.shape[0]
    if n < max(6, config.min_inliers):
        return None, np.zeros(0, np.int64)
    obj = np.ascontiguousarray(points_world, dtype=np.float64)
    img = np.ascontiguousarray(uv, dtype=np.float64)
    if T_rect_world_guess is not None:
        rvec0, _ = cv2.Rodrigues(T_rect_world_guess[:3, :3])
        tvec0 = T_rect_world_guess[:3, 3].reshape(3, 1).copy()
    else:
        rvec0, tvec0 = np.zeros((3, 1)), np.zeros((3, 1))
    try:
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            obj,
            img,
            K,
            _NO_DIST,
            rvec0.copy(),
            tvec0.copy(),
            useExtrinsicGuess=T_rect_world_guess is not None,
            iterationsCount=100,
            reprojectionError=config.pnp_threshold_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_ITERATIVE if T_rect_world_guess is not None else cv2.SOLVEPNP_AP3P,
        )
    except cv2.error:
        return None, np.zeros(0, np.int64)
    if not found or inl is None or len(inl) < config.min_inliers:
        return None, np.zeros(0, np.int64)
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, _NO_DIST, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, _NO_DIST)
    err = np.linalg.norm(proj.reshape(-1, 2) - img, axis=1)
    inl = np.flatnonzero(err < config.pnp_threshold_px)
    if inl.size < config.min_inliers:
        return None, np.zeros(0, np.int64)
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = tvec.ravel()
    return T, inl.astype(np.int64)
