"""Dense frame-to-keyframe RGB-D odometry (``sea3d.odometry.rgbd_dense``) on 7-Scenes chess,
against Open3D's frame-to-frame ``rgbd_odometry_multi_scale`` (Hybrid, the paper's method) on
the same frames in the same run, and its behaviour on frames it cannot align."""

from __future__ import annotations

import numpy as np

from odometry._chess import INTR, ate_m, obs, open3d_f2f
from sea3d.odometry import TrackingStatus, create_dense_rgbd_odometry

ATE_MARGIN = 0.85
"""Ours must be below this fraction of Open3D frame-to-frame's ATE on the same frames; the
benchmark measured 0.41 cm against 0.57 cm, a ratio of 0.73."""


def test_dense_tracker_drifts_less_than_open3d_frame_to_frame(chess) -> None:
    frames, gt = chess
    odo = create_dense_rgbd_odometry(*INTR)
    est = [odo.step(obs(i, rgb, z)) for i, (rgb, z) in enumerate(frames)]
    assert all(e.status is TrackingStatus.TRACKING for e in est)
    assert all(e.segment == 0 for e in est)
    t, T = odo.trajectory()
    np.testing.assert_array_equal(t, np.arange(len(frames)) * 10**9)
    kf = [e.keyframe_id for e in est if e.keyframe_id is not None]
    assert kf[0] == 0 and 1 <= len(kf) < len(frames) // 2  # keyframes, not frame to frame
    assert set(odo.keyframe_poses()) == set(kf)
    ours, ref = ate_m(T, gt), ate_m(open3d_f2f(frames), gt)
    assert ours < ATE_MARGIN * ref, (ours, ref)


def test_frame_without_depth_is_lost_then_a_new_segment_starts(chess) -> None:
    frames, _ = chess
    odo = create_dense_rgbd_odometry(*INTR)
    statuses, segments = [], []
    for i, (rgb, z) in enumerate(frames[:5]):
        if i == 2:
            z = np.full_like(z, np.nan)
        e = odo.step(obs(i, rgb, z))
        statuses.append(e.status)
        segments.append(e.segment)
        assert np.all(np.isfinite(e.T_world_left))
    assert statuses[2] is TrackingStatus.LOST
    assert [s for i, s in enumerate(statuses) if i != 2] == [TrackingStatus.TRACKING] * 4
    assert segments == [0, 0, 0, 1, 1]
    # the lost frame's pose is the constant-velocity bridge of frames 0 and 1
    _, T = odo.trajectory()
    step = np.linalg.inv(T[0]) @ T[1]
    np.testing.assert_allclose(T[2], T[1] @ step, atol=1e-9)
    assert len(T) == 5


def test_first_frame_without_depth_is_lost_not_a_crash(chess) -> None:
    frames, _ = chess
    odo = create_dense_rgbd_odometry(*INTR)
    rgb, z = frames[0]
    e = odo.step(obs(0, rgb, np.full_like(z, np.nan)))
    assert e.status is TrackingStatus.LOST
    e = odo.step(obs(1, *frames[1]))
    assert e.status is TrackingStatus.TRACKING and e.keyframe_id == 0


JUMP = [*range(0, 10), *range(45, 55)]
"""Ten frames, a jump of 36 frames (12 cm, 4 deg: the velocity guess is off by all of it), ten
frames; benchmarks/bench_real.py measured 0.38 cm with the feature pose, 4.58 cm without,
Open3D frame-to-frame 3.05 cm."""
JUMP_ATE_MAX_M = 0.01


def test_a_jump_is_tracked_from_the_feature_pose(chess) -> None:
    from sea3d.odometry.rgbd_dense import DenseRgbdConfig, DenseRgbdOdometry

    frames, gt = chess
    K = np.array([[INTR[0], 0, INTR[2]], [0, INTR[1], INTR[3]], [0, 0, 1.0]])
    out = {}
    for feature_init in (True, False):
        odo = DenseRgbdOdometry(K, DenseRgbdConfig(feature_init=feature_init))
        est = [odo.step(obs(k, *frames[i])) for k, i in enumerate(JUMP)]
        assert all(e.status is TrackingStatus.TRACKING for e in est)
        out[feature_init] = (ate_m(odo.trajectory()[1], gt[JUMP]), odo.feature_inits)
    assert out[True][0] < JUMP_ATE_MAX_M and out[True][1] >= 1, out
    assert out[False][0] > 2 * JUMP_ATE_MAX_M, out  # the velocity guess alone slips
