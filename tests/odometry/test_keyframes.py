"""Keyframes by parallax and track overlap, and re-links across lost stretches told apart from
loop closures."""

from __future__ import annotations

import numpy as np
import pytest

from sea3d.geometry.se3 import rotvec_to_R
from sea3d.odometry import OdometryConfig, TrackingStatus, create_odometry
from sea3d.odometry.stereo_geometry import RectifiedStereo
from sea3d.odometry.vio import StereoInertialOdometry, _Keyframe, _Segment


def _project(g, T_world_cam, X):
    T = np.linalg.inv(T_world_cam)
    P = X @ T[:3, :3].T + T[:3, 3]
    return np.stack([g.fx * P[:, 0] / P[:, 2] + g.cx, g.fy * P[:, 1] / P[:, 2] + g.cy], 1)


def _odometry_at_keyframe(g, X):
    odo = StereoInertialOdometry(g)
    odo._keyframes[0] = _Keyframe(id=0, t_ns=0, segment=0, T_odom=np.eye(4),
                                  correction=np.eye(4))
    seg = _Segment(id=0, backend=None, correction=np.eye(4))  # type: ignore[arg-type]
    seg.last_kf = 0
    seg.track_ids = np.arange(X.shape[0], dtype=np.int64)[::-1].copy()  # any order
    seg.track_uv = _project(g, np.eye(4), X)[::-1].copy()
    odo._mark_keyframe_tracks(seg, None)
    return odo, seg


def test_parallax_ignores_rotation_and_measures_translation(rng) -> None:
    g = RectifiedStereo.pinhole(500.0, 500.0, 320.0, 240.0, 640, 480, 0.1)
    X = np.column_stack([rng.uniform(-2, 2, 200), rng.uniform(-1.5, 1.5, 200),
                         np.full(200, 5.0)])
    odo, seg = _odometry_at_keyframe(g, X)
    # a camera that only turns (5 deg about a skew axis): every pixel moves, none triangulates
    T_turn = np.eye(4)
    T_turn[:3, :3] = rotvec_to_R(np.deg2rad(5.0) * np.array([0.3, 0.9, 0.3]) / np.sqrt(0.99))
    seg.track_uv = _project(g, T_turn, X)[::-1].copy()
    moved = np.median(np.linalg.norm(seg.track_uv - seg.kf_uv[::-1], axis=1))
    assert moved > 30.0  # pixels the points moved
    assert odo._parallax_px(seg, T_turn) == pytest.approx(0.0, abs=1e-6)
    # a sideways step of 0.2 m at 5 m depth: f t / z = 20 px of parallax, turned or not
    T_step = T_turn.copy()
    T_step[:3, 3] = T_turn[:3, :3] @ np.array([0.2, 0.0, 0.0])
    seg.track_uv = _project(g, T_step, X)[::-1].copy()
    assert odo._parallax_px(seg, T_step) == pytest.approx(20.0, rel=0.01)
    # the default threshold: 0.1 rad times the focal length (50 px at f = 500 px), since the
    # stereo disparity of these points (f B / z = 10 px) is smaller
    seg.track_X = X
    assert odo._parallax_threshold_px(seg, T_step) == pytest.approx(50.0)
    near = X * np.array([1.0, 1.0, 0.1])  # about 0.5 m away: the disparity (~100 px) rules
    seg.track_X = near
    z = (near - T_step[:3, 3]) @ T_step[:3, :3]  # in the current camera
    want = np.median(g.fx * g.baseline_m / z[:, 2])
    assert 90.0 < want < 110.0
    assert odo._parallax_threshold_px(seg, T_step) == pytest.approx(want, rel=1e-9)


def _blank(o):
    import dataclasses

    return dataclasses.replace(
        o,
        rect_left=np.full_like(o.rect_left, 90),
        rect_right=np.full_like(o.rect_right, 90),
        depth_m=np.full_like(o.depth_m, np.nan),
    )


def test_a_relink_across_a_lost_stretch_is_not_counted_as_a_loop_closure(sim_survey) -> None:
    """Visual-only over the first 70 frames (7 s, under three quarters of the orbit: the path
    never returns to a place seen before, and the default loop gap is 20 s), with one blank
    frame (lost) at one of three places: the segment that starts after it may join the one
    before it through neighbouring keyframes (ORB verification holds over a few frames of
    this orbit; after frame 30 it does). Such a join is a re-link, never a loop closure."""
    relinks = 0
    for lost in (20, 30, 45):
        obs = list(sim_survey.observations[:70])
        obs[lost] = _blank(obs[lost])
        odo = create_odometry(sim_survey.rig_true, sim_survey.maps, use_imu=False,
                              config=OdometryConfig(vocabulary_train_keyframes=10))
        est = [odo.step(o) for o in obs]
        assert est[lost].status is TrackingStatus.LOST
        assert odo.loop_closures == 0
        joined = [e for e in est if e.loop_closure]
        assert all(e.relink for e in joined) and len(joined) == odo.relinks
        if joined:
            assert est[est.index(joined[0])].status is TrackingStatus.RELOCALISED
        relinks += odo.relinks
    assert relinks >= 1


@pytest.mark.data
@pytest.mark.slow
def test_a_still_real_camera_makes_few_keyframes(data_dir) -> None:
    """The real EuRoC micro clip (40 frames, 2 s, the drone still on the ground): a keyframe
    rule by feature count made 26 keyframes (its images offer about 100 features, under the
    120-feature floor); by parallax and overlap a still camera needs the first and about one
    more."""
    from sea3d.pipeline.odometry import session_odometry
    from sea3d.stereo.recipe import DepthConfig

    run = session_odometry(data_dir / "vio/euroc_v101_micro",
                           observe=DepthConfig(engine="opencv"))
    s = run.summary
    assert s.frames == 40 and s.frames_lost == 0 and s.imu
    assert 1 <= s.keyframes <= 3
