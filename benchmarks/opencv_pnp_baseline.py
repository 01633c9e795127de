"""A plain stereo visual odometry written with OpenCV only: the reference of bench_real.py.

Per frame: rectify (``cv2.stereoRectify``), disparity by ``cv2.StereoSGBM`` (left view), Shi-Tomasi
corners on the previous left image, pyramidal Lucas-Kanade into the current one
(forward-backward checked), 3D points from the previous frame's disparity, and the current pose
by ``cv2.solvePnPRansac`` (then refined on the inliers); poses are chained frame to frame, the
world being the first left camera. No keyframes, no bundle adjustment, no IMU: the baseline a
new user would write from OpenCV's samples. Only the sequence's calibration and file list are
read through sea3d's EuRoC reader; every vision step is OpenCV's.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def load_stereo_sequence(root: Path) -> dict:
    """An EuRoC-layout sequence with ground truth: calibration, images, stamps, and the
    ground-truth ``T_world_left`` (body ground truth times ``T_body_left``)."""
    from sea3d.geometry.se3 import invert_T
    from sea3d.io.euroc import read_euroc

    seq = read_euroc(root)
    if seq.gt_t_ns.size == 0:
        raise SystemExit(f"{root}: no ground truth (state_groundtruth_estimate0)")
    T_body_left = (invert_T(seq.rig.imu.T_left_imu) if seq.rig.imu is not None else np.eye(4))
    return {"session": root, "seq": seq, "t_ns": seq.t_ns, "gt_t_ns": seq.gt_t_ns,
            "gt_T_world_left": seq.gt_T_world_body @ T_body_left}


def pnp_baseline(data: dict, *, num_disparities: int = 96, features: int = 500,
                 max_depth_m: float = 40.0) -> np.ndarray:
    """``(N, 4, 4)`` ``T_world_left`` of every frame (identity increments where PnP fails)."""
    seq = data["seq"]
    rig = seq.rig
    L, R = rig.left, rig.right
    KL = np.array([[L.fx, 0, L.cx], [0, L.fy, L.cy], [0, 0, 1.0]])
    KR = np.array([[R.fx, 0, R.cx], [0, R.fy, R.cy], [0, 0, 1.0]])
    size = (int(L.width), int(L.height))
    T_rl = np.linalg.inv(rig.T_left_right)  # right <- left
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(KL, np.asarray(L.dist), KR, np.asarray(R.dist),
                                                size, T_rl[:3, :3], T_rl[:3, 3], alpha=0)
    ml = cv2.initUndistortRectifyMap(KL, np.asarray(L.dist), R1, P1, size, cv2.CV_32FC1)
    mr = cv2.initUndistortRectifyMap(KR, np.asarray(R.dist), R2, P2, size, cv2.CV_32FC1)
    f = float(P1[0, 0])
    fb = -float(P2[0, 3])  # P2[0, 3] = -f B
    K = P1[:3, :3]
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    lk = {"winSize": (21, 21), "maxLevel": 3,
          "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)}
    T = [np.eye(4)]
    prev = prev_depth = None
    for i in range(len(seq.t_ns)):
        left = cv2.remap(seq.image("left", i), ml[0], ml[1], cv2.INTER_LINEAR)
        right = cv2.remap(seq.image("right", i), mr[0], mr[1], cv2.INTER_LINEAR)
        disp = sgbm.compute(left, right).astype(np.float32) / 16.0
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(disp > 0.5, fb / disp, np.nan)
        depth[depth > max_depth_m] = np.nan
        if prev is None:
            prev, prev_depth = left, depth
            continue
        step = np.eye(4)
        pts = cv2.goodFeaturesToTrack(prev, features, 0.01, 10)
        if pts is not None:
            nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, left, pts, None, **lk)
            back, st2, _ = cv2.calcOpticalFlowPyrLK(left, prev, nxt, None, **lk)
            ok = (st.ravel() == 1) & (st2.ravel() == 1) & (
                np.linalg.norm((back - pts).reshape(-1, 2), axis=1) < 1.0)
            p0, p1 = pts.reshape(-1, 2)[ok], nxt.reshape(-1, 2)[ok]
            u = np.clip(np.round(p0[:, 0]).astype(int), 0, size[0] - 1)
            v = np.clip(np.round(p0[:, 1]).astype(int), 0, size[1] - 1)
            z = prev_depth[v, u]
            good = np.isfinite(z)
            if np.count_nonzero(good) >= 8:
                X = np.stack([(p0[good, 0] - K[0, 2]) * z[good] / f,
                              (p0[good, 1] - K[1, 2]) * z[good] / f, z[good]], axis=1)
                found, rvec, tvec, inl = cv2.solvePnPRansac(
                    X, p1[good], K, None, iterationsCount=200, reprojectionError=2.0,
                    confidence=0.999)
                if found and inl is not None and len(inl) >= 8:
                    idx = inl.ravel()
                    _, rvec, tvec = cv2.solvePnP(X[idx], p1[good][idx], K, None, rvec, tvec,
                                                 useExtrinsicGuess=True)
                    T_cur_prev = np.eye(4)
                    T_cur_prev[:3, :3] = cv2.Rodrigues(rvec)[0]
                    T_cur_prev[:3, 3] = tvec.ravel()
                    step = np.linalg.inv(T_cur_prev)
        T.append(T[-1] @ step)
        prev, prev_depth = left, depth
    # rectified left camera -> raw left camera: T_world_left = T_w_rect @ R1 (rect <- left)
    T_rect_left = np.eye(4)
    T_rect_left[:3, :3] = R1
    out = np.stack(T)
    return np.linalg.inv(T_rect_left) @ out @ T_rect_left
