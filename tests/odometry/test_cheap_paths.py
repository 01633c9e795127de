"""The odometry's cheaper keyframes: landmarks leave the smoother's window with the keyframe
that first saw them (no dense marginal over the window's landmarks), and the window still
holds the true poses."""

from __future__ import annotations

import cv2
import numpy as np

from sea3d.geometry.se3 import invert_T, make_T, rotvec_to_R
from sea3d.odometry.backend import SmootherBackend
from sea3d.odometry.stereo_geometry import RectifiedStereo


def _rot_err(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.linalg.norm(cv2.Rodrigues(Ra.T @ Rb)[0]))


def _stereo_obs(geom: RectifiedStereo, T_world_cam: np.ndarray, X: np.ndarray):
    P = (X - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]  # world -> camera
    uL = geom.fx * P[:, 0] / P[:, 2] + geom.cx
    uR = geom.fx * (P[:, 0] - geom.baseline_m) / P[:, 2] + geom.cx
    v = geom.fy * P[:, 1] / P[:, 2] + geom.cy
    return np.stack([uL, uR, v], axis=1)


def _landmarks_per_factor(be: SmootherBackend) -> int:
    import gtsam

    graph = be.smoother.getFactors()
    most = 0
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None:
            continue
        keys = f.keys()
        most = max(most, sum(1 for key in keys if gtsam.Symbol(key).chr() == ord("l")))
    return most


def test_landmarks_leave_the_window_with_their_first_keyframe(rng) -> None:
    """A landmark seen by the keyframe that leaves the window, and by later ones, is
    marginalised with it: the marginal ties the remaining poses only. (With the landmark
    stamped by its last sighting it stayed, and the marginal tied it, and every other such
    landmark, to the window in one dense factor that iSAM2 re-factorised at every update.)
    The window still holds the true poses."""
    geom = RectifiedStereo.pinhole(350.0, 350.0, 320.0, 180.0, 640, 360, 0.1)
    lag = 1.5
    be = SmootherBackend(geom, T_body_rect=np.eye(4), imu_params=None, lag_s=lag,
                         pixel_sigma_px=0.5, huber_k=1.345)
    X_old = rng.uniform([-1, -0.6, 3], [1, 0.6, 5], (40, 3))  # seen at t = 0, 0.5, 1
    X_new = rng.uniform([-1, -0.6, 3], [1, 0.6, 5], (40, 3))  # seen from t = 1 on
    old_ids, new_ids = list(range(40)), list(range(100, 140))
    poses = {}
    for k in range(6):
        t_s = 0.5 * k
        T = make_T(rotvec_to_R(np.array([0.0, 0.01 * k, 0.0])), np.array([0.05 * k, 0, 0]))
        poses[k] = T
        obs, new = [], {}
        if k <= 2:
            obs += list(zip(old_ids, _stereo_obs(geom, T, X_old), strict=True))
            if k == 0:
                new.update(zip(old_ids, X_old, strict=True))
        if k >= 2:
            obs += list(zip(new_ids, _stereo_obs(geom, T, X_new), strict=True))
            if k == 2:
                new.update(zip(new_ids, X_new, strict=True))
        prior = {"rotation_rad": 1e-6, "translation_m": 1e-6} if k == 0 else None
        be.add_keyframe(k, t_s, T, obs, new, prior_sigmas=prior)
        if k == 3:  # still inside the window: the front end would give a fresh landmark
            assert all(be.has_landmark(j) for j in old_ids)
            assert be.expiring(0, t_s + 0.5) and not be.expiring(100, t_s + 0.5)
    # t = 2.5: the keyframes of t = 0 and 0.5 and the landmarks first seen there are gone
    assert not any(be.has_landmark(j) for j in old_ids)
    assert all(be.has_landmark(j) for j in new_ids)
    assert _landmarks_per_factor(be) <= 1
    for k, T in be.window_poses().items():
        err = invert_T(poses[k]) @ T
        assert np.linalg.norm(err[:3, 3]) < 1e-6
        assert _rot_err(err[:3, :3], np.eye(3)) < 1e-6
